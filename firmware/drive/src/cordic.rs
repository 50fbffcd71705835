//! The STM32G4 CORDIC co-processor as the core's [`mras::Trig`]: the portable part.
//!
//! The firmware implements [`CordicPort`] with two register accesses (RM0440 §17:
//! WDATA starts a calculation, RDATA returns RES1 then RES2); what is here, and tested
//! on the host, is the scaling between the core's f32 radians and the co-processor's
//! q1.31 arguments (angle/π in [-1, 1)) and results, and the order of the reads.
//! Configured for cosine with two results (RES1 = cos θ, RES2 = sin θ, modulus 1),
//! one 32-bit argument and 24 iterations; the accuracy of the hardware itself is a
//! bench item (docs/hardware.md).

use core::f32::consts::FRAC_1_PI;

/// 2^31 as f32 (exact).
const Q31_ONE: f32 = 2_147_483_648.0;

/// The two registers a calculation needs.
pub trait CordicPort {
    /// Write the q1.31 argument (starts the calculation).
    fn write_arg(&self, q31: i32);
    /// Read the next q1.31 result (stalls the bus until it is ready).
    fn read_result(&self) -> i32;
}

/// [`mras::Trig`] on the CORDIC. The port must be used by one context only (the
/// control interrupt): a calculation is a write followed by two reads.
#[derive(Clone, Copy, Debug)]
pub struct CordicTrig<P: CordicPort>(pub P);

impl<P: CordicPort> mras::Trig for CordicTrig<P> {
    #[inline]
    fn sin_cos(&self, x_rad: f32) -> (f32, f32) {
        self.0.write_arg(angle_to_q31(x_rad));
        let cos = self.0.read_result();
        let sin = self.0.read_result();
        (q31_to_f32(sin), q31_to_f32(cos))
    }
}

/// `x_rad/π` wrapped into [-1, 1] as q1.31: the nearest even number of half-turns
/// taken off by [`mras::round_f32_fast`], with no branch for the observer's angle in
/// [0, 2π) nor for any other (a compare and its flag transfer cost more).
#[inline]
pub fn angle_to_q31(x_rad: f32) -> i32 {
    let t = x_rad * FRAC_1_PI;
    let t = t - 2.0 * mras::round_f32_fast(0.5 * t);
    // `as` saturates: t at or just below 1 may round to 2^31, which becomes i32::MAX
    // (1 - 2^-31, π minus 1.5e-9 rad); NaN becomes 0.
    (t * Q31_ONE) as i32
}

/// q1.31 to f32.
#[inline]
pub fn q31_to_f32(v: i32) -> f32 {
    v as f32 * (1.0 / Q31_ONE)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_angle_wraps_within_a_q31_step_of_its_exact_wrap() {
        // Against f64: x/π rounds in f32 (2^-24 of it), and the q31 step is 2^-31.
        let mut worst: f64 = 0.0;
        for i in -300_000..300_000 {
            let x = i as f32 * 1.3e-3;
            let exact = {
                let t = x as f64 / PI;
                t - 2.0 * (0.5 * t).round()
            };
            let got = angle_to_q31(x) as f64 / 2_147_483_648.0;
            // ±1 are the same angle.
            let d = (got - exact).abs().min(2.0 - (got - exact).abs());
            let allowed = (x as f64 / PI).abs() * 1.2e-7 + 1e-9;
            worst = worst.max(d / allowed);
        }
        assert!(worst <= 1.0, "worst {worst} of its allowance");
    }

    use core::cell::Cell;
    use core::f64::consts::PI;
    use mras::Trig;

    /// An exact co-processor: f64 cosine and sine of the q1.31 argument, rounded.
    struct ExactCordic {
        arg: Cell<i32>,
        reads: Cell<u32>,
    }

    impl CordicPort for &ExactCordic {
        fn write_arg(&self, q31: i32) {
            self.arg.set(q31);
            self.reads.set(0);
        }
        fn read_result(&self) -> i32 {
            let th = self.arg.get() as f64 / 2_147_483_648.0 * PI;
            let n = self.reads.get();
            self.reads.set(n + 1);
            let v = if n == 0 { th.cos() } else { th.sin() };
            (v * 2_147_483_648.0)
                .round()
                .clamp(i32::MIN as f64, i32::MAX as f64) as i32
        }
    }

    #[test]
    fn argument_scaling_wraps_into_minus_one_to_one() {
        assert_eq!(angle_to_q31(0.0), 0);
        assert_eq!(angle_to_q31(core::f32::consts::FRAC_PI_2), 1 << 30);
        // 3π/2 is -π/2.
        assert_eq!(angle_to_q31(1.5 * core::f32::consts::PI), -(1 << 30));
        // Just below 2π is just below 0; far angles wrap too.
        assert!(angle_to_q31(core::f32::consts::TAU - 1e-6) < 0);
        let x = 101.0 * core::f32::consts::PI + 0.5;
        let t = x as f64 / PI - 102.0;
        let expect = (t * 2_147_483_648.0) as i64;
        // x/π in f32 carries ~2^-16 of 102 relative error: 2^31·102·2^-24 ≈ 13 000 q31 units.
        let far = angle_to_q31(x);
        assert!((far as i64 - expect).abs() < 20_000, "{far} vs {expect}");
        assert!(t > -1.0 && t < 0.0);
        assert_eq!(angle_to_q31(f32::NAN), 0);
        assert_eq!(q31_to_f32(1 << 30), 0.5);
        assert_eq!(q31_to_f32(i32::MIN), -1.0);
    }

    #[test]
    fn sin_cos_through_an_exact_port_matches_f64() {
        let port = ExactCordic {
            arg: Cell::new(0),
            reads: Cell::new(0),
        };
        let trig = CordicTrig(&port);
        let mut worst: f64 = 0.0;
        for i in 0..20_000 {
            let x = core::f32::consts::TAU * i as f32 / 20_000.0;
            let (s, c) = trig.sin_cos(x);
            let (es, ec) = ((x as f64).sin(), (x as f64).cos());
            worst = worst.max((s as f64 - es).abs()).max((c as f64 - ec).abs());
        }
        // f32 argument and results: a few ulps of the angle, no more.
        assert!(worst < 5e-7, "worst {worst:e}");
    }
}

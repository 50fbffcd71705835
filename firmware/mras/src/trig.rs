//! Trigonometry and square root behind small seams, so that the firmware can plug in the
//! STM32G4 CORDIC while host and tests share one portable default.
//!
//! The default, [`F32Trig`], is pure f32 arithmetic (Cody-Waite reduction and minimax
//! polynomials): `libm::sincosf` evaluates in f64, which a Cortex-M4F does in software
//! (about 2 700 of 5 700 cycles per step measured on the emulator, docs/performance.md).
//! Pure f32 code gives bit-identical results on the host and the MCU.

/// The only transcendental the control path needs: the reference unit vector.
pub trait Trig {
    /// `(sin x, cos x)`; the observer passes its wrapped angle in `[0, 2π)`.
    fn sin_cos(&self, x_rad: f32) -> (f32, f32);
}

/// Portable f32 sine/cosine: |error| < 2e-7 over [-100, 100] rad (tested).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct F32Trig;

impl Trig for F32Trig {
    #[inline]
    fn sin_cos(&self, x_rad: f32) -> (f32, f32) {
        sin_cos_f32(x_rad)
    }
}

/// `libm::sincosf`: correctly rounded on the host, slow on the MCU (f64 in software).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LibmTrig;

impl Trig for LibmTrig {
    #[inline]
    fn sin_cos(&self, x_rad: f32) -> (f32, f32) {
        libm::sincosf(x_rad)
    }
}

/// sin and cos by quadrant reduction (π/2 split in three parts, Cody-Waite) and the
/// Cephes single-precision polynomials on [-π/4, π/4].
#[inline]
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    const FRAC_2_PI: f32 = core::f32::consts::FRAC_2_PI;
    const DP1: f32 = 1.570_312_5;
    const DP2: f32 = 4.837_513e-4;
    const DP3: f32 = 7.549_79e-8;
    // Nearest quadrant; `as i32` saturates, and |x| beyond ~1e6 rad is not an angle the
    // observer produces (it wraps to [0, 2π)).
    let qf = x * FRAC_2_PI;
    let q = if qf >= 0.0 {
        (qf + 0.5) as i32
    } else {
        (qf - 0.5) as i32
    };
    let qf = q as f32;
    let r = ((x - qf * DP1) - qf * DP2) - qf * DP3;
    let z = r * r;
    let s = r + r * z * (-1.666_665_5e-1 + z * (8.332_161e-3 + z * -1.951_529_6e-4));
    let c = 1.0 - 0.5 * z + z * z * (4.166_664_6e-2 + z * (-1.388_731_6e-3 + z * 2.443_315_7e-5));
    match q & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Square root, the one seam for it: `libm::sqrtf` (correctly rounded, so identical on
/// every target). On the MCU it is software, ~300 cycles per call measured
/// (docs/performance.md); the FPU's VSQRT would give the same bits in 14.
#[inline]
pub fn sqrt_f32(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// `min`/`max` for finite values as plain comparisons: `f32::min` is a call to
/// `fminf` on the MCU (NaN handling the hot path does not need: inputs are checked).
#[inline]
pub(crate) fn min_f32(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

#[inline]
pub(crate) fn max_f32(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_accuracy_over_a_wide_range() {
        let mut worst: f64 = 0.0;
        for i in -2_000_000..=2_000_000 {
            let x = i as f32 * 5.0e-5;
            let (s, c) = sin_cos_f32(x);
            let (es, ec) = ((x as f64).sin(), (x as f64).cos());
            worst = worst.max((s as f64 - es).abs()).max((c as f64 - ec).abs());
        }
        assert!(worst < 2.0e-7, "worst error {worst:e}");
        // Quadrant boundaries and the observer's wrap point.
        let below_tau = f32::from_bits(core::f32::consts::TAU.to_bits() - 1);
        for x in [
            0.0f32,
            core::f32::consts::FRAC_PI_2,
            core::f32::consts::PI,
            below_tau,
        ] {
            let (s, c) = sin_cos_f32(x);
            assert!((s as f64 - (x as f64).sin()).abs() < 2e-7);
            assert!((c as f64 - (x as f64).cos()).abs() < 2e-7);
        }
    }
}

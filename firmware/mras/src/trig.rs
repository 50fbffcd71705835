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

/// Entries of the unit-circle table: one per 2π/64.
const TABLE_LEN: usize = 64;

/// `[cos, sin]` of `2πk/64`, correctly rounded to f32 (checked by a test against f64).
#[rustfmt::skip]
const UNIT_CIRCLE: [[f32; 2]; TABLE_LEN] = [
    [1.0, 0.0],
    [0.9951847, 0.09801714],
    [0.98078525, 0.19509032],
    [0.95694035, 0.29028466],
    [0.9238795, 0.38268343],
    [0.8819213, 0.47139674],
    [0.8314696, 0.55557024],
    [0.77301043, 0.6343933],
    [0.70710677, 0.70710677],
    [0.6343933, 0.77301043],
    [0.55557024, 0.8314696],
    [0.47139674, 0.8819213],
    [0.38268343, 0.9238795],
    [0.29028466, 0.95694035],
    [0.19509032, 0.98078525],
    [0.09801714, 0.9951847],
    [0.0, 1.0],
    [-0.09801714, 0.9951847],
    [-0.19509032, 0.98078525],
    [-0.29028466, 0.95694035],
    [-0.38268343, 0.9238795],
    [-0.47139674, 0.8819213],
    [-0.55557024, 0.8314696],
    [-0.6343933, 0.77301043],
    [-0.70710677, 0.70710677],
    [-0.77301043, 0.6343933],
    [-0.8314696, 0.55557024],
    [-0.8819213, 0.47139674],
    [-0.9238795, 0.38268343],
    [-0.95694035, 0.29028466],
    [-0.98078525, 0.19509032],
    [-0.9951847, 0.09801714],
    [-1.0, 0.0],
    [-0.9951847, -0.09801714],
    [-0.98078525, -0.19509032],
    [-0.95694035, -0.29028466],
    [-0.9238795, -0.38268343],
    [-0.8819213, -0.47139674],
    [-0.8314696, -0.55557024],
    [-0.77301043, -0.6343933],
    [-0.70710677, -0.70710677],
    [-0.6343933, -0.77301043],
    [-0.55557024, -0.8314696],
    [-0.47139674, -0.8819213],
    [-0.38268343, -0.9238795],
    [-0.29028466, -0.95694035],
    [-0.19509032, -0.98078525],
    [-0.09801714, -0.9951847],
    [0.0, -1.0],
    [0.09801714, -0.9951847],
    [0.19509032, -0.98078525],
    [0.29028466, -0.95694035],
    [0.38268343, -0.9238795],
    [0.47139674, -0.8819213],
    [0.55557024, -0.8314696],
    [0.6343933, -0.77301043],
    [0.70710677, -0.70710677],
    [0.77301043, -0.6343933],
    [0.8314696, -0.55557024],
    [0.8819213, -0.47139674],
    [0.9238795, -0.38268343],
    [0.95694035, -0.29028466],
    [0.98078525, -0.19509032],
    [0.9951847, -0.09801714],
];

/// 2π/64 split in a 12-bit part, whose products with step counts below 2^12 are exact,
/// and the rest (Cody-Waite): the remainder keeps its precision for |x| up to ~400 rad.
const STEP_HI: f32 = 0.098_144_53; // 0.09814453125 exactly (0x3DC9_0000)
const STEP_LO: f32 = 3.023_917_5e-5;

/// sin and cos from the nearest of 64 table points and a short Taylor series of the
/// remainder `r` (|r| ≤ π/64, so `r⁵/120` and `r⁶/720` are below 3e-9), rotated by
/// one complex multiplication: about half the cycles of a quadrant reduction with full
/// minimax polynomials, with the same pure-f32 determinism.
#[inline]
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    const STEPS_PER_RAD: f32 = TABLE_LEN as f32 / core::f32::consts::TAU;
    let kf = x * STEPS_PER_RAD;
    // Nearest step; `as i32` saturates, and |x| beyond ~1e6 rad is not an angle the
    // observer produces (it wraps to [0, 2π)).
    let k = if kf >= 0.0 {
        (kf + 0.5) as i32
    } else {
        (kf - 0.5) as i32
    };
    let kf = k as f32;
    let r = (x - kf * STEP_HI) - kf * STEP_LO;
    let r2 = r * r;
    let sin_r = r - r * r2 * (1.0 / 6.0);
    let cos_r = 1.0 - r2 * (0.5 - r2 * (1.0 / 24.0));
    let [c, s] = UNIT_CIRCLE[(k as u32 as usize) & (TABLE_LEN - 1)];
    (s * cos_r + c * sin_r, c * cos_r - s * sin_r)
}

/// Square root, the one seam for it. IEEE-754 square root is correctly rounded, so the
/// FPU instruction and `libm::sqrtf` give the same bits: on a Cortex-M with the FPU
/// (hard-float ABI) it is `VSQRT.F32` (14 cycles), elsewhere `libm::sqrtf` (the
/// instruction on x86-64; ~300 cycles of integer code on an M4, docs/performance.md).
#[inline]
pub fn sqrt_f32(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        vsqrt::sqrt(x)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

/// 1/√x for positive, normal, finite `x`, in pure f32 arithmetic with no call: a seed
/// from the exponent bits (relative error ≤ 3.5 %) and three Newton steps
/// `y ← y(3/2 − x y²/2)` (3.5 % → 1.8e-3 → 5e-6 → 4e-11, so rounding alone remains,
/// ≤ 3e-7 tested). The control path uses it for 1/|Zd| so that the step function makes
/// no calls (a call would make it save the FPU's callee-saved registers every sample).
#[inline(always)]
pub fn inv_sqrt_f32(x: f32) -> f32 {
    inv_sqrt_steps_f32::<3>(x)
}

/// [`inv_sqrt_f32`] with `STEPS` Newton steps from the same seed (relative error after
/// 1: 1.8e-3, 2: 5e-6), for a caller that needs less than f32's precision. Finite at
/// 0 (the seed is then 1.3e19, each step scales it by 1.5).
#[inline(always)]
pub fn inv_sqrt_steps_f32<const STEPS: usize>(x: f32) -> f32 {
    let mut y = f32::from_bits(0x5f37_5a86_u32.wrapping_sub(x.to_bits() >> 1));
    let h = 0.5 * x;
    for _ in 0..STEPS {
        y *= 1.5 - h * y * y;
    }
    y
}

/// √x by [`inv_sqrt_f32`] (0 for x ≤ 0 or subnormal): no call, for the control path.
#[inline(always)]
pub(crate) fn sqrt_inline_f32(x: f32) -> f32 {
    if x >= f32::MIN_POSITIVE {
        x * inv_sqrt_f32(x)
    } else {
        0.0
    }
}

/// `VSQRT.F32` as a leaf function. Stable Rust has no `sqrt` in `core`, and `asm!`
/// cannot name single-precision registers on `thumbv7em-none-eabihf` (the `sreg` class
/// requires the `vfp2` feature, which implies double precision the M4 lacks); a
/// global-assembly function taking and returning `s0` under the hard-float ABI needs
/// neither.
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
#[allow(unsafe_code)] // the crate's only unsafe: one FPU instruction
mod vsqrt {
    core::arch::global_asm!(
        ".section .text.mras_vsqrt_f32,\"ax\",%progbits",
        ".fpu fpv4-sp-d16",
        ".global mras_vsqrt_f32",
        ".type mras_vsqrt_f32,%function",
        ".p2align 1",
        ".thumb_func",
        "mras_vsqrt_f32:",
        "vsqrt.f32 s0, s0",
        "bx lr",
        ".size mras_vsqrt_f32, . - mras_vsqrt_f32",
    );

    extern "C" {
        fn mras_vsqrt_f32(x: f32) -> f32;
    }

    #[inline]
    pub fn sqrt(x: f32) -> f32 {
        // SAFETY: a leaf function that reads s0 and writes s0 only, per the AAPCS-VFP
        // calling convention of this target.
        unsafe { mras_vsqrt_f32(x) }
    }
}

/// `min`/`max` for finite values as plain comparisons: `f32::min` is a call to
/// `fminf` on the MCU (NaN handling the hot path does not need: inputs are checked).
#[inline]
pub fn min_f32(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

#[inline]
pub fn max_f32(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `x` rounded to the nearest integer (ties to even) by adding and taking off
/// 1.5·2^23, where the sum has no fraction bits left: exact for |x| < 2^22; beyond, `x`
/// itself or an integer within one of it. NaN stays NaN.
#[inline(always)]
pub fn round_f32_fast(x: f32) -> f32 {
    const SHIFTER: f32 = 12_582_912.0;
    (x + SHIFTER) - SHIFTER
}

/// `x` clamped to [-1, 1] by a saturating conversion to Q31 and back: on the MCU two
/// `vcvt`s, which saturate in hardware, where two compares each cost a flag transfer
/// and a branch. Exact for |x| >= 2^-8; below, within 2^-31 (the Q31 step). NaN gives 0.
#[inline(always)]
pub fn clamp_unit_f32(x: f32) -> f32 {
    const Q31: f32 = 2_147_483_648.0;
    // `as` saturates (Rust's float-to-int semantics, VCVT's on the MCU).
    ((x * Q31) as i32) as f32 * (1.0 / Q31)
}

/// `x` clamped to [0, 1] as [`clamp_unit_f32`] does to [-1, 1], through an unsigned
/// Q32: exact for x >= 2^-9, within 2^-32 below. NaN gives 0.
#[inline(always)]
pub fn clamp_01_f32(x: f32) -> f32 {
    const Q32: f32 = 4_294_967_296.0;
    ((x * Q32) as u32) as f32 * (1.0 / Q32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_rounding_is_round_half_even_within_its_range() {
        let mut x = 4_194_303.5f32;
        for _ in 0..400 {
            for x in [x, -x, x + 0.5, -x - 0.5, x + 0.25] {
                assert_eq!(round_f32_fast(x), libm::rintf(x), "{x}");
            }
            x *= 0.93;
        }
        for i in -100_000..100_000 {
            let x = i as f32 * 0.013;
            assert_eq!(round_f32_fast(x), libm::rintf(x), "{x}");
        }
        assert!(round_f32_fast(f32::NAN).is_nan());
    }

    #[test]
    fn clamps_saturate_and_keep_what_is_inside() {
        for (x, want) in [
            (2.5, 1.0),
            (1.0, 1.0),
            (-1.0, -1.0),
            (-7e9, -1.0),
            (f32::INFINITY, 1.0),
            (f32::NEG_INFINITY, -1.0),
            (0.0, 0.0),
            (0.75, 0.75),
            (-0.003_906_25, -0.003_906_25),
        ] {
            assert_eq!(clamp_unit_f32(x), want, "{x}");
        }
        assert_eq!(clamp_unit_f32(f32::NAN), 0.0);
        for (x, want) in [(1.5, 1.0), (1.0, 1.0), (-0.2, 0.0), (0.0, 0.0), (0.5, 0.5)] {
            assert_eq!(clamp_01_f32(x), want, "{x}");
        }
        assert_eq!(clamp_01_f32(f32::NAN), 0.0);
        assert_eq!(
            clamp_01_f32(1.0 - f32::EPSILON / 2.0),
            1.0 - f32::EPSILON / 2.0
        );
        // Inside, bit for bit down to 2^-8, then within the Q31 step.
        let mut x = 1.0f32;
        while x > 1e-12 {
            for v in [x, -x, x * 0.6, -x * 0.3] {
                let got = clamp_unit_f32(v);
                if v.abs() >= 1.0 / 256.0 {
                    assert_eq!(got, v);
                } else {
                    assert!((got - v).abs() <= 1.0 / 2_147_483_648.0, "{v}: {got}");
                }
                let (got, v) = (clamp_01_f32(v.abs()), v.abs());
                if v >= 1.0 / 512.0 {
                    assert_eq!(got, v);
                } else {
                    assert!((got - v).abs() <= 1.0 / 4_294_967_296.0, "{v}: {got}");
                }
            }
            x *= 0.83;
        }
    }

    #[test]
    fn inverse_square_root_is_accurate_over_the_normal_range() {
        let mut worst: f64 = 0.0;
        let mut x = f32::MIN_POSITIVE;
        while x < 1.0e37 {
            for k in 0..64 {
                let v = x * (1.0 + k as f32 / 64.0);
                let e = 1.0 / (v as f64).sqrt();
                worst = worst.max(((inv_sqrt_f32(v) as f64) - e).abs() / e);
            }
            x *= 2.0;
        }
        assert!(worst < 3.0e-7, "worst relative error {worst:e}");
        assert_eq!(sqrt_inline_f32(0.0), 0.0);
        assert!((sqrt_inline_f32(2.0) - core::f32::consts::SQRT_2).abs() < 3e-7);
    }

    #[test]
    fn step_split_is_exact_to_f32() {
        assert_eq!(STEP_HI.to_bits(), 0x3DC9_0000);
        let step = core::f64::consts::TAU / TABLE_LEN as f64;
        assert!((STEP_HI as f64 + STEP_LO as f64 - step).abs() < 1e-12);
    }

    #[test]
    fn table_is_the_unit_circle_correctly_rounded() {
        for (k, [c, s]) in UNIT_CIRCLE.iter().enumerate() {
            let x = core::f64::consts::TAU * k as f64 / TABLE_LEN as f64;
            // Correct rounding: within half an ulp of the f64 value (zeros exact).
            for (v, e) in [(*c, x.cos()), (*s, x.sin())] {
                let ulp = f32::EPSILON as f64 * (e.abs() as f32).max(f32::MIN_POSITIVE) as f64;
                assert!(
                    (v as f64 - e).abs() <= 0.5 * ulp + 1e-15,
                    "k {k}: {v} vs {e}"
                );
            }
        }
    }

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

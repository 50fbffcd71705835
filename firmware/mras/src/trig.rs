//! Trigonometry behind a trait, so that the firmware can plug in the STM32G4 CORDIC
//! while host and tests use the portable `libm` default.

/// The only transcendental the control path needs: the reference unit vector.
pub trait Trig {
    /// `(sin x, cos x)` for `x` in `[0, 2π)` (the observer keeps its angle wrapped).
    fn sin_cos(&self, x_rad: f32) -> (f32, f32);
}

/// Portable default: `libm::sincosf` (bit-identical on every target that runs it in software).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LibmTrig;

impl Trig for LibmTrig {
    #[inline]
    fn sin_cos(&self, x_rad: f32) -> (f32, f32) {
        libm::sincosf(x_rad)
    }
}

//! A minimal `f32` complex number.
//!
//! Hand-written rather than `num-complex` so that the order of every floating-point
//! operation in the hot path is explicit (bit-exact host/target comparison relies on it).

use core::ops::{Add, AddAssign, Mul, Neg, Sub};

/// `re + j·im`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Cplx {
    pub re: f32,
    pub im: f32,
}

impl Cplx {
    pub const ZERO: Self = Self::new(0.0, 0.0);
    pub const ONE: Self = Self::new(1.0, 0.0);

    pub const fn new(re: f32, im: f32) -> Self {
        Self { re, im }
    }

    #[inline]
    pub fn conj(self) -> Self {
        Self::new(self.re, -self.im)
    }

    /// Multiplication by `j`.
    #[inline]
    pub fn mul_j(self) -> Self {
        Self::new(-self.im, self.re)
    }

    #[inline]
    pub fn scale(self, k: f32) -> Self {
        Self::new(self.re * k, self.im * k)
    }

    #[inline]
    pub fn norm_sqr(self) -> f32 {
        self.re * self.re + self.im * self.im
    }

    #[inline]
    pub fn abs(self) -> f32 {
        crate::trig::sqrt_f32(self.norm_sqr())
    }

    #[inline]
    pub fn is_finite(self) -> bool {
        self.re.is_finite() && self.im.is_finite()
    }
}

impl Add for Cplx {
    type Output = Self;
    #[inline]
    fn add(self, o: Self) -> Self {
        Self::new(self.re + o.re, self.im + o.im)
    }
}

impl AddAssign for Cplx {
    #[inline]
    fn add_assign(&mut self, o: Self) {
        *self = *self + o;
    }
}

impl Sub for Cplx {
    type Output = Self;
    #[inline]
    fn sub(self, o: Self) -> Self {
        Self::new(self.re - o.re, self.im - o.im)
    }
}

impl Neg for Cplx {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        Self::new(-self.re, -self.im)
    }
}

impl Mul for Cplx {
    type Output = Self;
    #[inline]
    fn mul(self, o: Self) -> Self {
        Self::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
}

impl Mul<f32> for Cplx {
    type Output = Self;
    #[inline]
    fn mul(self, k: f32) -> Self {
        self.scale(k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn algebra() {
        let a = Cplx::new(1.0, 2.0);
        let b = Cplx::new(-3.0, 0.5);
        assert_eq!(a * b, Cplx::new(-3.0 - 1.0, 0.5 - 6.0));
        assert_eq!(a.mul_j(), a * Cplx::new(0.0, 1.0));
        assert_eq!((a * a.conj()).re, a.norm_sqr());
    }
}

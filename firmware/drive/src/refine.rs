//! The commissioning's refinement: the mean of the coefficients over a stretch of
//! adaptation at speed, and the separation of the rotor's motion ripple from the sensor
//! error across two speeds.
//!
//! Why two speeds: a torque ripple fixed to the shaft angle (cogging, a load that varies
//! with angle) moves the rotor by T_k/(J·(kω)²) at its harmonic k, a motion the torque
//! feedforward does not predict. The MRAS sees it in ε at the same harmonic as the
//! sensor's own error and, at one speed, learns both: its coefficients converge to
//! `a(ω) = e + M/ω²`, the sensor's `e` plus the motion's `M/ω²` (docs/theory.md §9). Two
//! speeds give both: `e = a2 + (a2 - a1)·ω1²/(ω2² - ω1²)`. The relation is linear to
//! first order in the coefficients, which are small (a few % of |Z|).

use mras::{Bank, Coefficients, Cplx};

/// Running mean of the coefficients and of |ω̂| over a refinement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoefficientMean {
    /// The first snapshot: the sums are of the differences to it, which keeps the f32
    /// sums' rounding at the differences' size rather than the coefficients'.
    first: Coefficients,
    sum: [Cplx; mras::MAX_PATHS],
    speed_sum_rad_s: f32,
    n: u32,
}

/// Why no refined coefficients could be formed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RefineError {
    /// No snapshot was added.
    Empty,
    /// The two refinements ran on different banks.
    BankChanged,
    /// The two mean speeds are not far enough apart (or not finite).
    SpeedsTooClose,
    /// A result is not finite.
    NotFinite,
}

impl RefineError {
    pub fn name(self) -> &'static str {
        match self {
            RefineError::Empty => "Empty",
            RefineError::BankChanged => "BankChanged",
            RefineError::SpeedsTooClose => "SpeedsTooClose",
            RefineError::NotFinite => "NotFinite",
        }
    }
}

/// A refinement's result: the mean coefficients and the mean |ω̂| (mechanical).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refined {
    pub coefficients: Coefficients,
    pub speed_rad_s: f32,
}

impl Default for CoefficientMean {
    fn default() -> Self {
        Self {
            first: Coefficients::EMPTY,
            sum: [Cplx::ZERO; mras::MAX_PATHS],
            speed_sum_rad_s: 0.0,
            n: 0,
        }
    }
}

impl CoefficientMean {
    /// Add one snapshot; a snapshot of another bank starts the mean again.
    pub fn add(&mut self, c: &Coefficients, omega_rad_s: f32) {
        if c.is_empty() {
            return;
        }
        if self.n == 0 || self.first.kinds() != c.kinds() {
            *self = Self {
                first: *c,
                ..Self::default()
            };
        }
        for (s, ((_, v), (_, v0))) in self.sum.iter_mut().zip(c.iter().zip(self.first.iter())) {
            *s += v - v0;
        }
        self.speed_sum_rad_s += libm::fabsf(omega_rad_s);
        self.n += 1;
    }

    pub fn samples(&self) -> u32 {
        self.n
    }

    pub fn mean(&self) -> Result<Refined, RefineError> {
        if self.n == 0 {
            return Err(RefineError::Empty);
        }
        let inv_n = 1.0 / self.n as f32;
        let mut out = self.first;
        for ((kind, v0), s) in self.first.iter().zip(&self.sum) {
            out.set(kind, v0 + s.scale(inv_n));
        }
        Ok(Refined {
            coefficients: out,
            speed_rad_s: self.speed_sum_rad_s * inv_n,
        })
    }
}

/// The sensor's coefficients from refinements at two speeds, the motion ripple's part
/// (`M/ω²`) removed: `e = a2 + (a2 - a1)·ω1²/(ω2² - ω1²)`. The speeds must differ by
/// at least [`crate::commissioning::MIN_SECOND_SPEED_RATIO`] (either order).
pub fn separate(first: &Refined, second: &Refined) -> Result<Coefficients, RefineError> {
    let (a1, a2) = (&first.coefficients, &second.coefficients);
    if a1.is_empty() || a2.is_empty() {
        return Err(RefineError::Empty);
    }
    if Bank::new(a1.kinds()) != Bank::new(a2.kinds()) {
        return Err(RefineError::BankChanged);
    }
    let (w1, w2) = (first.speed_rad_s, second.speed_rad_s);
    let (lo, hi) = (w1.min(w2), w1.max(w2));
    if !(lo > 0.0 && hi.is_finite() && hi >= crate::commissioning::MIN_SECOND_SPEED_RATIO * lo) {
        return Err(RefineError::SpeedsTooClose);
    }
    // The ratio in f32 from the speeds' ratio, not from the squares' difference.
    let r2 = (w2 / w1) * (w2 / w1);
    let k = 1.0 / (r2 - 1.0);
    let mut e = *a2;
    for ((kind, v1), (_, v2)) in a1.iter().zip(a2.iter()) {
        let v = v2 + (v2 - v1).scale(k);
        if !v.is_finite() {
            return Err(RefineError::NotFinite);
        }
        e.set(kind, v);
    }
    Ok(e)
}

//! A torque ripple fixed to the shaft angle (cogging, a load that varies with angle),
//! learned in Run and fed to the observer with the commanded torque.
//!
//! Why: the observer's feedforward knows the commanded torque only, so θ̂ lags the motion
//! a torque ripple makes by H·δθ (2.7-3.6 mrad at 1 rev/s in the ripple scenarios), and
//! the drive controls with θ̂. Once the sensor's own error is corrected (commissioned
//! with the motion separated out, docs/theory.md §9), what ε keeps at a harmonic of the
//! sensor angle is that lag alone, and it tells the missing acceleration: an
//! acceleration ripple Δa (mechanical) at temporal frequency w reaches the observer's
//! error as ε = N·Δa·H(jw)/(jw)² (the observer's closed loop with Ĵ cancelled). Each
//! sensor period the learner takes the mean of ε·e^{-jkθ̂s} per harmonic k, undoes that
//! transfer, and moves its model by a share of what is missing (a learning step with the
//! exact inverse: the error falls by 1 − gain a period).
//!
//! Only harmonics of the sensor angle: with N > 1 a once-per-revolution ripple is not
//! one of them. The model is the acceleration, so Ĵ does not enter; the torque handed to
//! the observer is Ĵ times it.

use mras::observer::ObserverGains;
use mras::Cplx;

/// Harmonics k of the sensor angle the model holds (k = 1..=4).
pub const RIPPLE_HARMONICS: usize = 4;
/// Share of the missing acceleration learned per sensor period.
pub const RIPPLE_GAIN: f32 = 0.5;
/// A harmonic is learned only where the observer shows it, |H(jw)| ≥ this (the MRAS's
/// default `gates.min_h`): below, 1/H grows as 1/w³ and ε's noise would be taken for a
/// large, slow torque.
pub const RIPPLE_MIN_H: f32 = 0.005;

/// One locked sample for the learning: ε (sensor electrical), ω̂ (mechanical) and the
/// sensor angle advanced since the previous sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LearnSample {
    pub eps_e_rad: f32,
    pub omega_rad_s: f32,
    pub advance_e_rad: f32,
}

/// e^{jkθ̂s} for k = 1..=[`RIPPLE_HARMONICS`] from `u` = e^{jθ̂s}.
#[inline(always)]
fn powers(u: Cplx) -> [Cplx; RIPPLE_HARMONICS] {
    let mut p = [Cplx::ONE; RIPPLE_HARMONICS];
    let mut power = Cplx::ONE;
    for v in p.iter_mut() {
        power = power * u;
        *v = power;
    }
    p
}

/// The learned acceleration ripple and the sums of the sensor period under way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RippleLearner {
    /// Harmonics in use (0: off).
    harmonics: usize,
    /// The observer's (for 1/H) and N.
    gains: ObserverGains,
    sensor_periods: f32,
    /// Share of the missing acceleration added per sensor period (0..=1].
    gain: f32,
    /// a_k: the acceleration is Σ Im(a_k·e^{jkθ̂s}) (rad/s², mechanical).
    accel: [Cplx; RIPPLE_HARMONICS],
    /// Σ ε·e^{-jkθ̂s}, Σ ω̂, samples and sensor angle travelled in the period under way.
    sums: [Cplx; RIPPLE_HARMONICS],
    omega_sum_rad_s: f32,
    n: u32,
    travelled_rad: f32,
}

impl RippleLearner {
    /// `harmonics` (clamped to [`RIPPLE_HARMONICS`]; 0 disables), `gain` per period, for
    /// the observer with `gains` and N = `sensor_periods`.
    pub fn new(harmonics: u8, gain: f32, gains: ObserverGains, sensor_periods: u16) -> Self {
        Self {
            harmonics: (harmonics as usize).min(RIPPLE_HARMONICS),
            gains,
            sensor_periods: sensor_periods.max(1) as f32,
            gain,
            accel: [Cplx::ZERO; RIPPLE_HARMONICS],
            sums: [Cplx::ZERO; RIPPLE_HARMONICS],
            omega_sum_rad_s: 0.0,
            n: 0,
            travelled_rad: 0.0,
        }
    }

    /// The model's acceleration at the sensor angle whose e^{jθ̂s} is `u` (rad/s²).
    pub fn accel_rad_s2(&self, u: Cplx) -> f32 {
        self.accel_at(&powers(u))
    }

    /// One locked sample to learn from: `u` = e^{jθ̂s}, ε (sensor electrical), ω̂
    /// (mechanical), the sensor angle advanced since the previous one. A whole sensor
    /// period completes a learning step.
    pub fn learn(&mut self, u: Cplx, sample: LearnSample) {
        self.learn_at(&powers(u), sample);
    }

    /// A period of the control loop: learn from `sample`, if any, then the model's
    /// acceleration at `u`, the powers of `u` computed once for both.
    #[inline(always)]
    pub fn step(&mut self, u: Cplx, sample: Option<LearnSample>) -> f32 {
        let p = powers(u);
        if let Some(s) = sample {
            self.learn_at(&p, s);
        }
        self.accel_at(&p)
    }

    #[inline(always)]
    fn accel_at(&self, p: &[Cplx; RIPPLE_HARMONICS]) -> f32 {
        let mut a = 0.0;
        for (c, p) in self.accel.iter().zip(p).take(self.harmonics) {
            a += c.re * p.im + c.im * p.re;
        }
        a
    }

    #[inline(always)]
    fn learn_at(&mut self, p: &[Cplx; RIPPLE_HARMONICS], x: LearnSample) {
        if self.harmonics == 0 {
            return;
        }
        let eps = x.eps_e_rad;
        for (s, p) in self.sums.iter_mut().zip(p).take(self.harmonics) {
            *s += Cplx::new(p.re * eps, -p.im * eps);
        }
        self.omega_sum_rad_s += x.omega_rad_s;
        self.n += 1;
        self.travelled_rad += libm::fabsf(x.advance_e_rad);
        if self.travelled_rad >= core::f32::consts::TAU {
            self.travelled_rad -= core::f32::consts::TAU;
            self.complete_period();
        }
    }

    /// Out of a whole period (a pause, a fault): the partial sums are dropped.
    pub fn interrupt(&mut self) {
        self.sums = [Cplx::ZERO; RIPPLE_HARMONICS];
        self.omega_sum_rad_s = 0.0;
        self.n = 0;
        self.travelled_rad = 0.0;
    }

    /// The period's means give ε_k; the missing acceleration is
    /// Δa_k = −w²·(ε_k/N)/H(jw) at w = k·N·ω̂.
    #[cold]
    #[inline(never)]
    fn complete_period(&mut self) {
        let inv_n = 1.0 / self.n.max(1) as f32;
        let n_s = self.sensor_periods;
        let omega = self.omega_sum_rad_s * inv_n;
        let used = self.accel.iter_mut().zip(&self.sums).take(self.harmonics);
        for (k, (a, s)) in used.enumerate() {
            let w = (k + 1) as f32 * n_s * omega;
            // ε = Im(E·e^{jkθ}) has the mean of ε·e^{-jkθ} = E/(2j).
            let inv_h = self.gains.inverse_error_transfer(w);
            // False for a non-finite 1/H (at w = 0) too.
            let shown = inv_h.abs() * RIPPLE_MIN_H <= 1.0;
            if !shown {
                continue;
            }
            let e_k = s.scale(2.0 * inv_n).mul_j();
            let missing = (e_k * inv_h).scale(-w * w / n_s);
            if missing.is_finite() {
                *a += missing.scale(self.gain);
            }
        }
        self.interrupt();
    }

    pub fn model(&self) -> &[Cplx] {
        self.accel.get(..self.harmonics).unwrap_or(&[])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f32::consts::TAU;

    const T_S: f32 = 50e-6;

    fn gains() -> ObserverGains {
        ObserverGains::from_eigenvalues([10.0, 1.0, 0.1], 1e-3)
    }

    /// One sensor period at constant speed, ε as the observer's closed loop makes it of
    /// the acceleration the model lacks: ε = N·Σ Im(H(jw)/(jw)²·(a_true − a)·e^{jkθ}).
    fn period(l: &mut RippleLearner, truth: &[Cplx], omega: f32, n: u16) {
        let g = gains();
        let advance = omega * n as f32 * T_S;
        let samples = (TAU / advance.abs()).ceil() as usize + 1;
        let mut missing = [Cplx::ZERO; RIPPLE_HARMONICS];
        for ((m, t), a) in missing.iter_mut().zip(truth).zip(l.model()) {
            *m = *t - *a;
        }
        for i in 0..samples {
            let th = advance * i as f32;
            let u = Cplx::new(libm::cosf(th), libm::sinf(th));
            let mut eps = 0.0;
            for (k, d) in missing.iter().enumerate() {
                let w = (k + 1) as f32 * n as f32 * omega;
                let e = (g.error_transfer(w) * *d).scale(-(n as f32) / (w * w));
                let kth = (k + 1) as f32 * th;
                eps += e.re * libm::sinf(kth) + e.im * libm::cosf(kth);
            }
            l.learn(
                u,
                LearnSample {
                    eps_e_rad: eps,
                    omega_rad_s: omega,
                    advance_e_rad: advance,
                },
            );
        }
    }

    /// Each sensor period moves the model by the gain's share of what it lacks, in
    /// either direction of rotation and at N = 1 and 2; the model's acceleration is
    /// Σ Im(a_k·e^{jkθ}).
    #[test]
    fn a_period_learns_the_gains_share_of_the_missing_acceleration() {
        let truth = [
            Cplx::new(1.6, -0.4),
            Cplx::new(-0.5, 3.2),
            Cplx::new(0.2, 0.1),
            Cplx::ZERO,
        ];
        for (omega, n) in [(TAU, 1), (-TAU, 1), (5.0 * TAU, 2)] {
            let mut l = RippleLearner::new(4, RIPPLE_GAIN, gains(), n);
            period(&mut l, &truth, omega, n);
            for (a, t) in l.model().iter().zip(&truth) {
                let want = t.scale(RIPPLE_GAIN);
                assert!(
                    (*a - want).abs() < 0.02 * (1.0 + t.abs()),
                    "{omega}: {a:?} vs {want:?}"
                );
            }
            for _ in 0..20 {
                period(&mut l, &truth, omega, n);
            }
            for (a, t) in l.model().iter().zip(&truth) {
                assert!((*a - *t).abs() < 0.01, "{omega}: {a:?} vs {t:?}");
            }
            let u = Cplx::new(libm::cosf(0.7), libm::sinf(0.7));
            let want: f32 = truth
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    let kth = (k + 1) as f32 * 0.7;
                    t.re * libm::sinf(kth) + t.im * libm::cosf(kth)
                })
                .sum();
            assert!((l.accel_rad_s2(u) - want).abs() < 0.02, "{omega}");
        }
    }

    /// Where the observer does not show a harmonic (|H| below the floor) nothing is
    /// learned of it; an interrupted period is dropped; 0 harmonics is off.
    #[test]
    fn what_the_observer_does_not_show_is_not_learned() {
        let truth = [Cplx::new(1.0, 0.0); 4];
        // 0.05 rev/s: |H| at k = 1 is ~1e-4 with these eigenvalues.
        let mut l = RippleLearner::new(4, RIPPLE_GAIN, gains(), 1);
        period(&mut l, &truth, 0.05 * TAU, 1);
        assert_eq!(l.model()[0], Cplx::ZERO);
        let mut l = RippleLearner::new(4, RIPPLE_GAIN, gains(), 1);
        let sample = |eps_e_rad, advance_e_rad| LearnSample {
            eps_e_rad,
            omega_rad_s: TAU,
            advance_e_rad,
        };
        l.learn(Cplx::ONE, sample(1e-3, 3.0));
        l.interrupt();
        l.learn(Cplx::ONE, sample(0.0, 3.5));
        assert!(l.model().iter().all(|a| *a == Cplx::ZERO));
        let mut off = RippleLearner::new(0, RIPPLE_GAIN, gains(), 1);
        period(&mut off, &truth, TAU, 1);
        assert!(off.model().is_empty());
        assert_eq!(off.accel_rad_s2(Cplx::ONE), 0.0);
    }
}

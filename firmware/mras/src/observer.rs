//! Luenberger vector-tracking motion observer with torque feedforward (paper Fig. 5).
//!
//! The controller `b_o s + K_so + K_iso/s` acts on the mechanical angle error; its
//! output adds to the feedforward torque T* and drives the model `1/(Ĵ s²)`. The
//! closed loop is `Ĵs³ + b_o s² + K_so s + K_iso`, and a sensor angle error δ reaches
//! the cross-product error through `H(s) = Ĵs³ / (Ĵs³ + b_o s² + K_so s + K_iso)`.

use crate::complex::Cplx;
use core::f32::consts::TAU;

/// Observer gains derived from the eigenvalues.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObserverGains {
    /// λ1..λ3 (rad/s).
    pub lambda_rad_s: [f32; 3],
    pub inertia_kg_m2: f32,
    /// b_o = Ĵ(λ1+λ2+λ3) (N·m·s/rad).
    pub b_o: f32,
    /// K_so = Ĵ(λ1λ2+λ1λ3+λ2λ3) (N·m/rad).
    pub k_so: f32,
    /// K_iso = Ĵ λ1λ2λ3 (N·m/(rad·s)).
    pub k_iso: f32,
    /// 1/Ĵ, kept so that the control path does not divide.
    pub inv_inertia: f32,
    /// Elementary symmetric sums of λ (Σλ, Σλλ, Πλ): the coefficients of 1/H.
    pub sigma: [f32; 3],
}

impl ObserverGains {
    /// Match `Ĵs³ + b_o s² + K_so s + K_iso = Ĵ(s+λ1)(s+λ2)(s+λ3)`.
    pub fn from_eigenvalues(eigenvalues_hz: [f32; 3], inertia_kg_m2: f32) -> Self {
        let [l1, l2, l3] = eigenvalues_hz.map(|f| TAU * f);
        Self {
            lambda_rad_s: [l1, l2, l3],
            inertia_kg_m2,
            b_o: inertia_kg_m2 * (l1 + l2 + l3),
            k_so: inertia_kg_m2 * (l1 * l2 + l1 * l3 + l2 * l3),
            k_iso: inertia_kg_m2 * l1 * l2 * l3,
            inv_inertia: 1.0 / inertia_kg_m2,
            sigma: [l1 + l2 + l3, l1 * l2 + l1 * l3 + l2 * l3, l1 * l2 * l3],
        }
    }

    /// `H(jw) = Π_i jw/(λi + jw)`: how a sensor angle error at temporal frequency `w`
    /// (rad/s, signed) appears in the observer error. Factored form: well-conditioned
    /// in f32 for any `w`.
    pub fn error_transfer(&self, w_rad_s: f32) -> Cplx {
        let w2 = w_rad_s * w_rad_s;
        let mut h = Cplx::ONE;
        for l in self.lambda_rad_s {
            // jw/(λ + jw) = (w² + jλw)/(λ² + w²)
            let d = 1.0 / (l * l + w2);
            h = h * Cplx::new(w2 * d, l * w_rad_s * d);
        }
        h
    }

    /// `1/H(jw) = 1 + σ1/(jw) + σ2/(jw)² + σ3/(jw)³` with one division: what the
    /// adaptation needs (it divides the correlation by H). Its real and imaginary parts
    /// are `1 − σ2/w²` and `−(σ1 − σ3/w²)/w`; |1/H| ≥ 1, so their rounding errors
    /// (~1e-7 absolute) stay relative too. Not finite at `w = 0`.
    #[inline]
    pub fn inverse_error_transfer(&self, w_rad_s: f32) -> Cplx {
        Self::inverse_error_transfer_of(self.sigma, w_rad_s)
    }

    /// [`Self::inverse_error_transfer`] from the λ sums alone.
    #[inline]
    pub(crate) fn inverse_error_transfer_of(sigma: [f32; 3], w_rad_s: f32) -> Cplx {
        let [s1, s2, s3] = sigma;
        let u = 1.0 / w_rad_s;
        let u2 = u * u;
        Cplx::new(1.0 - s2 * u2, -u * (s1 - s3 * u2))
    }
}

/// The observer's state; the mechanical angle is kept as a wrapped sensor-electrical
/// angle plus a signed count of sensor periods, so hours of rotation cost no precision.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ObserverState {
    /// θ̂s, sensor electrical angle in [0, 2π).
    pub theta_e_rad: f32,
    /// Whole sensor periods travelled (θ̂rm = (periods·2π + θ̂s)/N).
    pub periods: i32,
    /// Integrated velocity state (rad/s, mechanical).
    pub omega_int_rad_s: f32,
    /// ω̂ output including the b_o path (rad/s, mechanical).
    pub omega_rad_s: f32,
    /// K_iso ∫ε: the low-frequency disturbance torque estimate (N·m).
    pub disturbance_nm: f32,
    /// Observer acceleration (T* + controller)/Ĵ (rad/s²).
    pub accel_rad_s2: f32,
}

impl ObserverState {
    /// Advance one period with the mechanical angle error `e_rad` (θ - θ̂) and the
    /// torque feedforward; returns the next state (the caller commits it if finite).
    #[must_use]
    #[inline(always)]
    pub fn advanced(&self, d: &DiscreteGains, e_rad: f32, torque_ff_nm: f32) -> Self {
        let disturbance_nm = self.disturbance_nm + d.k_iso_t_s * e_rad;
        let accel_rad_s2 = (torque_ff_nm + d.k_so * e_rad + disturbance_nm) * d.inv_inertia;
        let omega_int_rad_s = self.omega_int_rad_s + accel_rad_s2 * d.t_s;
        let omega_rad_s = omega_int_rad_s + d.b_o_over_j * e_rad;
        let theta = self.theta_e_rad + omega_rad_s * d.n_t_s;
        let (theta_e_rad, periods) = if (0.0..TAU).contains(&theta) {
            (theta, self.periods)
        } else {
            wrap(theta, self.periods)
        };
        Self {
            theta_e_rad,
            periods,
            omega_int_rad_s,
            omega_rad_s,
            disturbance_nm,
            accel_rad_s2,
        }
    }

    /// Whether the state is finite. Every other state variable flows into ω̂ within
    /// the same update (d → α → ω_int → ω̂), so a non-finite value anywhere shows in
    /// ω̂ or in the disturbance; θ̂s is wrapped into [0, 2π) by construction.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.omega_rad_s.is_finite() && self.disturbance_nm.is_finite()
    }
}

/// The observer gains folded with the sample period and N, for the control path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscreteGains {
    pub k_iso_t_s: f32,
    pub k_so: f32,
    pub inv_inertia: f32,
    pub b_o_over_j: f32,
    pub t_s: f32,
    /// N·Ts: sensor-electrical angle per sample per rad/s.
    pub n_t_s: f32,
}

impl DiscreteGains {
    pub fn new(g: &ObserverGains, t_s: f32, sensor_periods: u16) -> Self {
        Self {
            k_iso_t_s: g.k_iso * t_s,
            k_so: g.k_so,
            inv_inertia: g.inv_inertia,
            b_o_over_j: g.b_o * g.inv_inertia,
            t_s,
            n_t_s: sensor_periods as f32 * t_s,
        }
    }
}

/// `theta` wrapped into [0, 2π) and the period count carried, for the uncommon sample
/// that crosses the wrap. Bounded (no loop): an absurd speed must not hang the control
/// path; a non-finite angle lands at 0 and the caller's finiteness check rejects it.
/// No calls and one compare before the fix-ups: the turns are floor(θ/2π), rounded
/// without a branch (a chain of range checks made the wrap's period one of the
/// control interrupt's longest).
#[inline(always)]
fn wrap(theta: f32, periods: i32) -> (f32, i32) {
    // Exact for |θ/2π| < 2^22; a turn too few at a whole turn, which the fix-up adds.
    let turns = crate::trig::round_f32_fast(theta * (1.0 / TAU) - 0.5);
    let mut theta_e_rad = theta - turns * TAU;
    // `as` saturates beyond ±2^31 turns (an absurd angle, clamped below).
    let mut periods = periods.wrapping_add(turns as i32);
    // Rounding can leave the result a hair below 0 (a turn too few: one added back may
    // round up to TAU itself), or at or a hair above TAU.
    if theta_e_rad < 0.0 {
        theta_e_rad += TAU;
        periods = periods.wrapping_sub(1);
    }
    if theta_e_rad >= TAU {
        theta_e_rad -= TAU;
        periods = periods.wrapping_add(1);
    }
    if !(0.0..TAU).contains(&theta_e_rad) {
        theta_e_rad = 0.0;
    }
    (theta_e_rad, periods)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gains_match_characteristic_polynomial() {
        let g = ObserverGains::from_eigenvalues([100.0, 10.0, 1.0], 2.0e-4);
        let l = [TAU * 100.0, TAU * 10.0, TAU];
        // Evaluate both polynomials at s = -λi: the product form vanishes there.
        for s in l.map(|x| -x) {
            let p = g.inertia_kg_m2 * s * s * s + g.b_o * s * s + g.k_so * s + g.k_iso;
            let scale = g.inertia_kg_m2 * s.abs().powi(3);
            assert!(p.abs() / scale < 1e-5, "residual {p}");
        }
    }

    #[test]
    fn error_transfer_limits_and_symmetry() {
        let g = ObserverGains::from_eigenvalues([100.0, 10.0, 1.0], 1.0);
        // Far above the bandwidth the sensor error passes unchanged.
        let hi = g.error_transfer(1.0e6);
        assert!((hi.re - 1.0).abs() < 1e-3 && hi.im.abs() < 1e-3);
        // Far below it: H ≈ (jw)³/(λ1λ2λ3), phase 270° for w > 0, 90° for w < 0.
        let w = 0.01;
        let lo = g.error_transfer(w);
        let expect = -w * w * w / (TAU * 100.0 * TAU * 10.0 * TAU);
        assert!((lo.im / expect - 1.0).abs() < 1e-2, "{lo:?} vs {expect}");
        assert_eq!(g.error_transfer(-w), lo.conj());
        // At one eigenvalue alone (others far away) the phase is near 45°·(count above).
        let mid = g.error_transfer(TAU * 31.6);
        let phase = libm::atan2f(mid.im, mid.re).to_degrees();
        assert!(phase > 45.0 && phase < 135.0, "phase {phase}");
    }

    #[test]
    fn inverse_error_transfer_is_the_reciprocal() {
        let g = ObserverGains::from_eigenvalues([100.0, 10.0, 1.0], 2.0e-4);
        for w in [-5000.0f32, -60.0, -2.0, 0.5, 3.0, 62.8, 200.0, 1.0e4] {
            let h = g.error_transfer(w);
            let r = g.inverse_error_transfer(w);
            let one = h * r;
            assert!(
                (one.re - 1.0).abs() < 1e-5 && one.im.abs() < 1e-5,
                "w {w}: H·(1/H) = {one:?}"
            );
        }
    }

    #[test]
    fn absurd_speed_neither_hangs_nor_leaves_the_interval() {
        let g = ObserverGains::from_eigenvalues([100.0, 10.0, 1.0], 1.0);
        for w in [1.0e30, -1.0e30, f32::MAX] {
            let s = ObserverState {
                omega_int_rad_s: w,
                ..Default::default()
            }
            .advanced(&DiscreteGains::new(&g, 1e-4, 2), 0.0, 0.0);
            assert!(s.theta_e_rad >= 0.0 && s.theta_e_rad < TAU);
        }
        let light = ObserverGains::from_eigenvalues([100.0, 10.0, 1.0], 1.0e-4);
        let s =
            ObserverState::default().advanced(&DiscreteGains::new(&light, 1e-4, 2), 0.0, f32::MAX);
        assert!(!s.is_finite());
    }

    #[test]
    fn wrap_keeps_the_angle_and_counts_its_turns() {
        for i in -40_000..40_000 {
            let theta = i as f32 * 7.3e-3;
            if (0.0..TAU).contains(&theta) {
                continue;
            }
            let (w, periods) = wrap(theta, 5);
            assert!((0.0..TAU).contains(&w), "{theta} -> {w}");
            let back = w as f64 + (periods - 5) as f64 * core::f64::consts::TAU;
            // f32 rounding of turns·2π: half an ulp of θ and of the product.
            let allowed = 1.2e-7 * theta.abs() as f64 + 1e-6;
            assert!(
                (back - theta as f64).abs() < allowed,
                "{theta} -> {w}, {periods}"
            );
        }
        // A hair below 0 is a hair below 2π of the turn before, or 0 of this one where
        // 2π minus the hair rounds to 2π: never 0 of the turn before.
        for hair in [-1e-9f32, -1e-8, -1e-7, -4e-7, -1e-6] {
            let (w, periods) = wrap(hair, 5);
            let back = w as f64 + (periods - 5) as f64 * core::f64::consts::TAU;
            assert!(
                (back - hair as f64).abs() < 1e-6,
                "{hair} -> {w}, {periods}"
            );
        }
        // Whole turns land at 0 (to the rounding of k·2π) with the turn counted.
        for k in [-3i32, -1, 1, 2, 7] {
            let (w, periods) = wrap(k as f32 * TAU, 0);
            assert!(w < 1e-5 && periods == k, "{k}: {w}, {periods}");
        }
        assert_eq!(wrap(f32::NAN, 3).0, 0.0);
    }

    #[test]
    fn free_run_integrates_velocity_and_wraps() {
        let g = ObserverGains::from_eigenvalues([100.0, 10.0, 1.0], 1.0);
        let mut s = ObserverState {
            omega_int_rad_s: 100.0,
            omega_rad_s: 100.0,
            ..Default::default()
        };
        for _ in 0..1000 {
            s = s.advanced(&DiscreteGains::new(&g, 1e-4, 2), 0.0, 0.0);
        }
        // 100 rad/s · 0.1 s · N = 20 rad electrical.
        let travelled = s.periods as f32 * TAU + s.theta_e_rad;
        assert!((travelled - 20.0).abs() < 1e-3, "{travelled}");
        assert!(s.theta_e_rad >= 0.0 && s.theta_e_rad < TAU);
    }
}

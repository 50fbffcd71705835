//! The MRAS decoupler (paper Fig. 6): a bank of harmonic paths, each correlating the
//! model reference error (MRE, the observer's cross-product error ε) with the rotating
//! unit vector of its error harmonic and adapting one complex coefficient.
//!
//! Notation (docs/theory.md §2): a net sensor error whose angle error is
//! `δ(θs) = Im(G·e^{j m θs})` has error phasor `G`. The observer passes it to ε as
//! `H(j m N ω̂)·G`, so the mean of `ε·e^{-j m θ̂s}` is `H·G/(2j)`.

use crate::complex::Cplx;
use crate::config::{AdaptationLaw, Config, PathKind, MAX_PATHS};
use crate::observer::ObserverGains;
use crate::trig::{max_f32, min_f32};
use core::f32::consts::TAU;

/// |H| floor used for the residual measure when the law itself has none (paper-literal):
/// the same as our default, so that both laws' residuals read alike.
const METRIC_H_FLOOR: f32 = 0.05;
/// The error phasor estimate is low-passed over this much sensor-electrical angle before
/// integration: its ripple (the other paths' harmonics, amplified by 1/|H|) would
/// otherwise drive a limit cycle between paths at low speed (docs/theory.md §3).
pub(crate) const G_WINDOW_RAD: f32 = core::f32::consts::PI;
/// H is re-evaluated only when the smoothed speed has moved by more than this fraction
/// (phase error below ~2 mrad), which saves most of the path's arithmetic.
const H_REUSE_REL: f32 = 1.0e-3;
/// The residual measure averages over this much sensor-electrical angle (two periods).
const RESIDUAL_WINDOW_RAD: f32 = 2.0 * TAU;

/// One path's adaptive state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PathState {
    /// Integral (persistent) coefficient in the path's paper form (Xo+jYo, C+jD, or d_h).
    pub coef: Cplx,
    /// Proportional contribution, recomputed every adapting step, not persisted.
    pub coef_p: Cplx,
    /// Angle-averaged estimate of the remaining error phasor G (rad, sensor electrical).
    pub residual: Cplx,
    pub coef_at_rev_start: Cplx,
    /// G estimate low-passed over angle before it is integrated (see [`G_WINDOW_RAD`]).
    pub g_filtered: Cplx,
    /// H compensation cached at `comp_omega_rad_s` (see [`H_REUSE_REL`]): the factor
    /// `2·conj(H)/(|H|·max(|H|, floor))` and |H|.
    pub comp: Cplx,
    pub h_abs: f32,
    pub comp_omega_rad_s: f32,
    /// |Δcoef| over the last completed revolution of adaptation, relative to |Z|.
    pub change_last_rev: f32,
}

impl Default for PathState {
    fn default() -> Self {
        Self {
            coef: Cplx::ZERO,
            coef_p: Cplx::ZERO,
            residual: Cplx::ZERO,
            coef_at_rev_start: Cplx::ZERO,
            g_filtered: Cplx::ZERO,
            comp: Cplx::ZERO,
            h_abs: 0.0,
            comp_omega_rad_s: f32::NAN,
            change_last_rev: 0.0,
        }
    }
}

/// The path's contribution to the decoupling vector, given `pw[i] = e^{j i θ̂s}`.
#[inline]
pub(crate) fn injection(kind: PathKind, coef: Cplx, pw: &[Cplx]) -> Cplx {
    match kind {
        PathKind::Offset => coef,
        // C·cos θ̂s + D·sin θ̂s on X only (eq. 9).
        PathKind::AmplitudeQuadrature => Cplx::new(coef.re * pw[1].re + coef.im * pw[1].im, 0.0),
        PathKind::Harmonic(h) => coef * Cplx::pow_from(pw, h as i32),
    }
}

/// Coefficient change that moves the error phasor by `-scale·G/|Z|` (first order).
///
/// A residual component `c_k` (relative to the fundamental) gives `G = c_k` for
/// `k = 1+m` and `G = -conj(c_k)` for `k = 1-m`; the X-only C/D form injects
/// `(C+jD)/2` at `k = -1`.
#[inline]
pub(crate) fn coef_delta(kind: PathKind, g: Cplx, scale: f32) -> Cplx {
    match kind {
        PathKind::Offset => g.conj().scale(scale),
        PathKind::AmplitudeQuadrature => g.conj().scale(2.0 * scale),
        PathKind::Harmonic(h) if h > 1 => g.scale(-scale),
        PathKind::Harmonic(_) => g.conj().scale(scale),
    }
}

/// What the bank needs from one control period.
pub(crate) struct StepContext<'a> {
    /// ε, sensor electrical radians (normalised by |Z|).
    pub eps_e_rad: f32,
    /// `pw[i] = e^{j i θ̂s}` at the prior estimate.
    pub pw: &'a [Cplx],
    /// ω̂ as output by the observer (the paper-literal law uses its sign).
    pub omega_rad_s: f32,
    /// ω̂ smoothed over angle: sets H and the angle travelled (ours).
    pub omega_smooth_rad_s: f32,
    /// Smoothed amplitude of the decoupled vector.
    pub amplitude: f32,
    /// Global gates passed (speed, torque, acceleration, no loss of lock).
    pub gates_open: bool,
    /// Manual freeze: measure the residual but do not adapt.
    pub frozen: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PathBank {
    pub kinds: [PathKind; MAX_PATHS],
    pub state: [PathState; MAX_PATHS],
    pub len: usize,
    /// Sensor-electrical angle adapted over since the last revolution boundary.
    pub angle_this_rev_rad: f32,
    pub revs_adapted: u32,
}

impl PathBank {
    pub fn new(cfg: &Config) -> Self {
        Self {
            kinds: cfg.paths,
            state: [PathState::default(); MAX_PATHS],
            len: cfg.paths().len(),
            angle_this_rev_rad: 0.0,
            revs_adapted: 0,
        }
    }

    /// The decoupling vector added to the measured vector before the cross product.
    #[inline]
    pub fn decoupling_vector(&self, pw: &[Cplx]) -> Cplx {
        let mut d = Cplx::ZERO;
        for (kind, s) in self.kinds[..self.len].iter().zip(&self.state[..self.len]) {
            d += injection(*kind, s.coef + s.coef_p, pw);
        }
        d
    }

    /// Correlate, compensate, adapt. Returns whether any path adapted.
    pub fn step(&mut self, cfg: &Config, gains: &ObserverGains, cx: &StepContext) -> bool {
        let n = cfg.sensor_periods as f32;
        let d_theta_e = n * libm::fabsf(cx.omega_smooth_rad_s) * cfg.sample_period_s;
        let limit = cfg.health.coefficient_limit * cx.amplitude;
        let residual_alpha = min_f32(d_theta_e * (1.0 / RESIDUAL_WINDOW_RAD), 1.0);
        let g_alpha = min_f32(d_theta_e * (1.0 / G_WINDOW_RAD), 1.0);
        let h_floor = match cfg.law {
            AdaptationLaw::Compensated { h_floor, .. } => h_floor,
            AdaptationLaw::PaperLiteral { .. } => METRIC_H_FLOOR,
        };
        let mut adapted = false;
        for (kind, s) in self.kinds[..self.len]
            .iter()
            .copied()
            .zip(&mut self.state[..self.len])
        {
            let m = kind.error_harmonic() as usize;
            // Coherent power of the MRE: ε·e^{-j m θ̂s}, mean H·G/(2j).
            let cp = cx.pw[m].conj().scale(cx.eps_e_rad);
            let w = cx.omega_smooth_rad_s;
            // A fresh state holds NaN, whose difference never passes `stale` as false.
            let drift = libm::fabsf(w - s.comp_omega_rad_s);
            let stale = drift.is_nan() || drift > H_REUSE_REL * libm::fabsf(w);
            if stale {
                let h = gains.error_transfer(m as f32 * n * w);
                s.h_abs = h.abs();
                s.comp = if s.h_abs > 0.0 {
                    h.conj().scale(2.0 / (s.h_abs * max_f32(s.h_abs, h_floor)))
                } else {
                    Cplx::ZERO
                };
                s.comp_omega_rad_s = w;
            }
            let visible = cx.gates_open && s.h_abs >= cfg.gates.min_h && s.h_abs > 0.0;
            // G estimate: 2j·cp·conj(H)/(|H|·max(|H|, floor)).
            let g_est = if visible {
                cp.mul_j() * s.comp
            } else {
                Cplx::ZERO
            };
            if visible {
                s.g_filtered = s.g_filtered + (g_est - s.g_filtered).scale(g_alpha);
                s.residual = s.residual + (g_est - s.residual).scale(residual_alpha);
            }
            if !cx.gates_open || cx.frozen {
                s.coef_p = Cplx::ZERO;
                continue;
            }
            match cfg.law {
                AdaptationLaw::Compensated {
                    gain_per_rad,
                    proportional,
                    ..
                } => {
                    if !visible {
                        s.coef_p = Cplx::ZERO;
                        continue;
                    }
                    // Integrated over angle: gain per radian (docs/theory.md §3).
                    s.coef +=
                        coef_delta(kind, s.g_filtered, gain_per_rad * cx.amplitude * d_theta_e);
                    s.coef_p = if proportional == 0.0 {
                        Cplx::ZERO
                    } else {
                        coef_delta(kind, s.g_filtered, proportional * cx.amplitude)
                    };
                }
                AdaptationLaw::PaperLiteral { k1_per_s, k2 } => {
                    // CPMRE = ε_m · sign(ω̂) · e^{-j m θ̂s}, PI in time (Fig. 6).
                    let c = cp.scale(libm::copysignf(1.0, cx.omega_rad_s) / n);
                    s.coef += coef_delta(kind, c, k1_per_s * cx.amplitude * cfg.sample_period_s);
                    s.coef_p = coef_delta(kind, c, k2 * cx.amplitude);
                }
            }
            let a2 = s.coef.norm_sqr();
            if a2 > limit * limit {
                s.coef = s.coef.scale(limit / crate::trig::sqrt_f32(a2));
            }
            adapted = true;
        }
        if adapted {
            self.angle_this_rev_rad += d_theta_e;
            if self.angle_this_rev_rad >= TAU * n {
                self.angle_this_rev_rad -= TAU * n;
                self.revs_adapted = self.revs_adapted.saturating_add(1);
                let inv_a = 1.0 / cx.amplitude;
                for s in &mut self.state[..self.len] {
                    s.change_last_rev = (s.coef - s.coef_at_rev_start).abs() * inv_a;
                    s.coef_at_rev_start = s.coef;
                }
            }
        }
        adapted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The angle error of `e^{jθ} + c_k e^{jkθ}` at θ, to first order, is Im(G e^{jmθ}):
    /// check the sign convention of `coef_delta` by finite differences on the real angle.
    #[test]
    fn coef_delta_reduces_the_error_phasor() {
        let pw_at = |th: f32| -> [Cplx; 8] {
            let u = Cplx::new(libm::cosf(th), libm::sinf(th));
            let mut pw = [Cplx::ONE; 8];
            for i in 1..8 {
                pw[i] = pw[i - 1] * u;
            }
            pw
        };
        for kind in [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(-2),
        ] {
            let m = kind.error_harmonic() as i32;
            // Start from a coefficient, measure G by projecting the angle error.
            let g_of = |coef: Cplx| -> Cplx {
                let mut acc = Cplx::ZERO;
                let n = 720;
                for i in 0..n {
                    let th = TAU * i as f32 / n as f32;
                    let pw = pw_at(th);
                    let z = pw[1] + injection(kind, coef, &pw);
                    let err = libm::atan2f(
                        z.im * pw[1].re - z.re * pw[1].im,
                        z.re * pw[1].re + z.im * pw[1].im,
                    );
                    acc += Cplx::pow_from(&pw, -m).scale(err);
                }
                // δ = Im(G e^{jmθ}) ⇒ mean(δ e^{-jmθ}) = G/(2j) ⇒ G = 2j·mean.
                acc.scale(2.0 / n as f32).mul_j()
            };
            let c0 = Cplx::new(0.02, -0.01);
            let g0 = g_of(c0);
            let c1 = c0 + coef_delta(kind, g0, 0.5);
            let g1 = g_of(c1);
            let ratio = g1.abs() / g0.abs();
            assert!((ratio - 0.5).abs() < 0.02, "{kind:?}: |G| ratio {ratio}");
        }
    }
}

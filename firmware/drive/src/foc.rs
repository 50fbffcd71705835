//! Field-oriented current control: Clarke/Park transforms, the d/q current loop (PI
//! with decoupling and back-EMF feed-forward, anti-windup) and space-vector PWM duties
//! (min-max zero-sequence injection).

use mras::{max_f32, min_f32};

const SQRT3: f32 = 1.732_050_8;
const INV_SQRT3: f32 = 0.577_350_26;

/// Phase currents a, b (c = -a - b) → αβ (amplitude-invariant Clarke).
#[inline]
pub fn clarke(ia: f32, ib: f32) -> (f32, f32) {
    (ia, (ia + 2.0 * ib) * INV_SQRT3)
}

/// αβ → dq at the electrical angle given as (sin, cos).
#[inline]
pub fn park(alpha: f32, beta: f32, (s, c): (f32, f32)) -> (f32, f32) {
    (c * alpha + s * beta, -s * alpha + c * beta)
}

/// dq → αβ.
#[inline]
pub fn inverse_park(d: f32, q: f32, (s, c): (f32, f32)) -> (f32, f32) {
    (c * d - s * q, s * d + c * q)
}

/// Duty cycles (0..=1) of phases a, b, c for an αβ voltage on a DC link, centre-aligned
/// PWM. The vector is first limited to the linear range |v| <= Vdc/√3; the return's
/// second element says whether it was.
pub fn svpwm(v_alpha: f32, v_beta: f32, vdc_v: f32) -> ([f32; 3], bool) {
    svpwm_on(v_alpha, v_beta, DcLink::new(vdc_v))
}

/// A DC link's voltage with its reciprocal, worked out once: [`svpwm`]'s division ran
/// in every control period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DcLink {
    pub vdc_v: f32,
    inv_vdc: f32,
}

impl DcLink {
    pub fn new(vdc_v: f32) -> Self {
        Self {
            vdc_v,
            inv_vdc: 1.0 / vdc_v,
        }
    }
}

/// [`svpwm`] on a [`DcLink`], bit for bit.
pub fn svpwm_on(v_alpha: f32, v_beta: f32, dc: DcLink) -> ([f32; 3], bool) {
    let v_max = dc.vdc_v * INV_SQRT3;
    let mag2 = v_alpha * v_alpha + v_beta * v_beta;
    let (va, vb, limited) = if mag2 > v_max * v_max {
        let k = v_max * mras::inv_sqrt_f32(mag2);
        (v_alpha * k, v_beta * k, true)
    } else {
        (v_alpha, v_beta, false)
    };
    let a = va;
    let b = -0.5 * va + 0.5 * SQRT3 * vb;
    let c = -0.5 * va - 0.5 * SQRT3 * vb;
    // Min-max injection centres the three phase voltages in the DC link.
    // Inline compare-and-select (`f32::max`/`min` are `fmaxf`/`fminf` calls on the MCU).
    let offset = -0.5 * (max_f32(max_f32(a, b), c) + min_f32(min_f32(a, b), c));
    let inv = dc.inv_vdc;
    let duty = [a, b, c].map(|v| mras::clamp_01_f32((v + offset) * inv + 0.5));
    (duty, limited)
}

/// A PI regulator; the caller stops its integrator while the output is limited.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pi {
    pub kp: f32,
    /// Integral gain (1/s).
    pub ki: f32,
    pub integral: f32,
}

impl Pi {
    /// Current loop with its zero on the electrical pole: kp = L·ωc, ki = R·ωc.
    pub fn current_loop(r_ohm: f32, l_h: f32, bandwidth_hz: f32) -> Self {
        let wc = core::f32::consts::TAU * bandwidth_hz;
        Self {
            kp: l_h * wc,
            ki: r_ohm * wc,
            integral: 0.0,
        }
    }

    /// One step; `saturated` (from the previous output) stops the integrator.
    pub fn step(&mut self, error: f32, t_s: f32, saturated: bool) -> f32 {
        if !saturated {
            self.integral += self.ki * error * t_s;
        }
        self.kp * error + self.integral
    }

    pub fn reset(&mut self) {
        self.integral = 0.0;
    }
}

/// The motor as the current loop knows it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLoopParams {
    pub r_ohm: f32,
    pub l_h: f32,
    /// Permanent-magnet flux linkage ψ (V·s).
    pub flux_wb: f32,
    pub vdc_v: f32,
    /// The voltage limit as a fraction of the linear SVPWM range Vdc/√3 (0 < m <= 1):
    /// below 1 where the shunts need a longer low-side window than full modulation
    /// leaves (a fast PWM rate).
    pub max_modulation: f32,
    pub bandwidth_hz: f32,
}

/// The share of ωc·T by which the errors' slow mean follows them each period (its time
/// constant ten of the loop's).
const STEADY_SHARE: f32 = 0.1;

/// The d/q current loop in the rotor frame.
///
/// `v = PI(i* - i) + feed-forward`, the feed-forward being the cross-coupling and the
/// back-EMF the PI would otherwise have to integrate: `vd_ff = -ωe·L·iq`,
/// `vq_ff = ωe·(L·id + ψ)`. The voltage vector is limited to the linear SVPWM range
/// `Vdc/√3`; in a limited period neither integrator moves (anti-windup), so the loop
/// leaves the limit as soon as the error reverses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLoop {
    p: CurrentLoopParams,
    d: Pi,
    q: Pi,
    v_max: f32,
    /// ωc (rad/s): the loop's design bandwidth.
    wc_rad_s: f32,
    /// The last period's errors (A), whose voltage acts through the present period.
    last_error_a: (f32, f32),
    /// The currents predicted for the middle of the next period (A), [`Self::ahead_a`].
    ahead_a: (f32, f32),
    /// The errors' slow mean (A): what the integrators hold against a disturbance.
    steady_error_a: (f32, f32),
}

impl CurrentLoop {
    pub fn new(p: CurrentLoopParams) -> Self {
        let pi = Pi::current_loop(p.r_ohm, p.l_h, p.bandwidth_hz);
        Self {
            p,
            d: pi,
            q: pi,
            v_max: p.max_modulation * p.vdc_v * INV_SQRT3,
            wc_rad_s: core::f32::consts::TAU * p.bandwidth_hz,
            last_error_a: (0.0, 0.0),
            ahead_a: (0.0, 0.0),
            steady_error_a: (0.0, 0.0),
        }
    }

    pub fn reset(&mut self) {
        self.d.reset();
        self.q.reset();
        self.last_error_a = (0.0, 0.0);
        self.steady_error_a = (0.0, 0.0);
    }

    /// The d and q currents (A) the last [`Self::step`] predicts for the middle of the
    /// period its voltage acts through (the next one): the sampled current, plus what
    /// the last period's voltage adds by the next sample and half of what this one adds
    /// after it. With its zero on the electrical pole the loop gives `L·di/dt = kp·e`,
    /// so a period's voltage moves the current by `ωc·T·e`; an error the integrators
    /// hold steady against a disturbance (a ramp, a back-EMF the feed-forward misses)
    /// moves none, so the errors' slow mean is taken out.
    pub fn ahead_a(&self) -> (f32, f32) {
        self.ahead_a
    }

    /// Another ψ for the back-EMF feed-forward at electrical speed `we_rad_s`: the q
    /// integrator gives back what the feed-forward adds, so the voltage does not step.
    pub fn set_flux(&mut self, flux_wb: f32, we_rad_s: f32) {
        self.q.integral -= we_rad_s * (flux_wb - self.p.flux_wb);
        self.p.flux_wb = flux_wb;
    }

    /// `(vd, vq, limited)` for the references and measured currents (A) at electrical
    /// speed `we_rad_s`.
    pub fn step(
        &mut self,
        (id_ref, iq_ref): (f32, f32),
        (id, iq): (f32, f32),
        we_rad_s: f32,
        t_s: f32,
    ) -> (f32, f32, bool) {
        let (ed, eq) = (id_ref - id, iq_ref - iq);
        let k = self.wc_rad_s * t_s;
        let (ld, lq) = self.last_error_a;
        let (sd, sq) = self.steady_error_a;
        self.ahead_a = (
            id + k * (ld + 0.5 * ed - 1.5 * sd),
            iq + k * (lq + 0.5 * eq - 1.5 * sq),
        );
        self.last_error_a = (ed, eq);
        let a = STEADY_SHARE * k;
        self.steady_error_a = (sd + a * (ed - sd), sq + a * (eq - sq));
        let (d0, q0) = (self.d.integral, self.q.integral);
        let l = self.p.l_h;
        let vd = self.d.step(ed, t_s, false) - we_rad_s * l * iq;
        let vq = self.q.step(eq, t_s, false) + we_rad_s * (l * id + self.p.flux_wb);
        let mag2 = vd * vd + vq * vq;
        if mag2 > self.v_max * self.v_max {
            self.d.integral = d0;
            self.q.integral = q0;
            let k = self.v_max * mras::inv_sqrt_f32(mag2);
            (vd * k, vq * k, true)
        } else {
            (vd, vq, false)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn park_and_inverse_round_trip_and_clarke_is_amplitude_invariant() {
        let sc = libm::sincosf(0.7);
        let (d, q) = park(0.3, -0.8, sc);
        let (a, b) = inverse_park(d, q, sc);
        assert!(close(a, 0.3, 1e-6) && close(b, -0.8, 1e-6));
        // Balanced currents of amplitude 2 at angle 0.4 → |αβ| = 2.
        let th = 0.4f32;
        let ia = 2.0 * libm::cosf(th);
        let ib = 2.0 * libm::cosf(th - 2.094_395_2);
        let (al, be) = clarke(ia, ib);
        assert!(close(al, 2.0 * libm::cosf(th), 1e-5) && close(be, 2.0 * libm::sinf(th), 1e-5));
    }

    #[test]
    fn svpwm_reproduces_the_vector_and_limits_it() {
        let vdc = 48.0;
        for k in 0..36 {
            let th = k as f32 * 0.1745;
            let (va, vb) = (20.0 * libm::cosf(th), 20.0 * libm::sinf(th));
            let (d, limited) = svpwm(va, vb, vdc);
            assert!(!limited);
            // Line-to-line voltages from the duties reproduce the vector.
            let (ua, ub, uc) = (d[0] * vdc, d[1] * vdc, d[2] * vdc);
            let (al, be) = clarke(ua - (ua + ub + uc) / 3.0, ub - (ua + ub + uc) / 3.0);
            assert!(close(al, va, 1e-3) && close(be, vb, 1e-3), "{k}: {al} {be}");
            assert!(d.iter().all(|x| (0.0..=1.0).contains(x)));
        }
        let (d, limited) = svpwm(100.0, 0.0, vdc);
        assert!(limited && d.iter().all(|x| (0.0..=1.0).contains(x)));
    }

    /// An R-L load with back-EMF under the loop: the current settles at the reference
    /// with the feed-forward; at the voltage limit the integrators hold, so the current
    /// follows a lowered reference at once instead of unwinding first.
    #[test]
    fn current_loop_settles_and_does_not_wind_up() {
        let p = CurrentLoopParams {
            r_ohm: 0.3,
            l_h: 0.5e-3,
            flux_wb: 0.02,
            vdc_v: 24.0,
            max_modulation: 1.0,
            bandwidth_hz: 1000.0,
        };
        let mut c = CurrentLoop::new(p);
        let dt = 50e-6;
        let we = 200.0;
        // Steady rotor-frame model: L di/dt = v - R i ∓ cross terms - back-EMF.
        let run = |c: &mut CurrentLoop, iq_ref: f32, n: usize, i: &mut (f32, f32)| {
            let mut limited_any = false;
            for _ in 0..n {
                let (vd, vq, lim) = c.step((0.0, iq_ref), *i, we, dt);
                limited_any |= lim;
                let did = (vd - p.r_ohm * i.0 + we * p.l_h * i.1) / p.l_h;
                let diq = (vq - p.r_ohm * i.1 - we * (p.l_h * i.0 + p.flux_wb)) / p.l_h;
                i.0 += did * dt;
                i.1 += diq * dt;
            }
            limited_any
        };
        let mut i = (0.0, 0.0);
        assert!(!run(&mut c, 2.0, 400, &mut i));
        assert!((i.1 - 2.0).abs() < 0.02 && i.0.abs() < 0.02, "{i:?}");
        // 100 A cannot be reached with 24 V: limited, integrators frozen.
        assert!(run(&mut c, 100.0, 2000, &mut i));
        let frozen = (c.d.integral, c.q.integral);
        run(&mut c, 100.0, 100, &mut i);
        assert_eq!(frozen, (c.d.integral, c.q.integral));
        // Back to 2 A within 10 ms, with no integrator to unwind.
        run(&mut c, 2.0, 200, &mut i);
        assert!((i.1 - 2.0).abs() < 0.1, "{i:?}");
    }

    /// The current predicted for the middle of the period a step's voltage acts
    /// through (one period of delay, as the PWM's) against the R-L winding's own mean
    /// over that period: within 5 % of the step through the step, a third of the
    /// sampled current's error. A back-EMF the feed-forward misses, growing as in an
    /// acceleration (50 V/s), leaves the integrators a steady error that moves no
    /// current: the prediction is the current once the errors' mean has it.
    #[test]
    fn the_current_ahead_is_the_windings_over_the_next_period() {
        let (r, l, dt, sub) = (0.3f32, 0.5e-3f32, 50e-6f32, 50);
        let p = CurrentLoopParams {
            r_ohm: r,
            l_h: l,
            flux_wb: 0.0,
            vdc_v: 48.0,
            max_modulation: 1.0,
            bandwidth_hz: 1000.0,
        };
        for (step_a, missed_emf_v_s) in [(2.0f32, 0.0f32), (0.0, 50.0)] {
            let mut c = CurrentLoop::new(p);
            let (mut i, mut v_applied) = (0.0f32, 0.0f32);
            let mut ahead = [0.0f32; 2000];
            let mut sampled = [0.0f32; 2000];
            let mut mean = [0.0f32; 2000];
            for k in 0..2000 {
                let (vd, _, _) = c.step((step_a, 0.0), (i, 0.0), 0.0, dt);
                ahead[k] = c.ahead_a().0;
                sampled[k] = i;
                // This period runs on the last one's voltage.
                let mut sum = 0.0;
                for _ in 0..sub {
                    let emf_v = missed_emf_v_s * k as f32 * dt;
                    i += (v_applied - emf_v - r * i) / l * (dt / sub as f32);
                    sum += i;
                }
                mean[k] = sum / sub as f32;
                v_applied = vd;
            }
            // ahead[k] is for period k + 1's mean.
            let worst = |x: &[f32]| {
                (0..1999)
                    .map(|k| (x[k] - mean[k + 1]).abs())
                    .skip(if step_a > 0.0 { 0 } else { 1000 })
                    .fold(0.0f32, f32::max)
            };
            let (predicted, from_sample) = (worst(&ahead), worst(&sampled));
            if step_a > 0.0 {
                assert!(predicted < 0.05 * step_a, "{predicted} A");
                assert!(
                    predicted < from_sample / 3.0,
                    "{predicted} A, sampled {from_sample} A"
                );
            } else {
                assert!(predicted < 1e-3, "back-EMF missed: {predicted} A");
            }
        }
    }

    #[test]
    fn pi_integrates_and_stops_when_saturated() {
        let mut pi = Pi::current_loop(0.3, 0.5e-3, 1000.0);
        let u1 = pi.step(1.0, 50e-6, false);
        assert!(pi.integral > 0.0 && u1 > pi.kp);
        let i = pi.integral;
        pi.step(1.0, 50e-6, true);
        assert_eq!(pi.integral, i);
        pi.reset();
        assert_eq!(pi.integral, 0.0);
    }
}

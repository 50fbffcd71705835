//! The motor's mechanical constants, identified at speed: the inertia J of rotor and load
//! and its friction ([`InertiaFit`]), and the permanent-magnet flux linkage ψ
//! ([`FluxMeter`]). The commissioning ([`crate::commissioning`]) starts SpinUp with a
//! torque probe from rest ([`Probe`]: J/kt for the speed loop that follows), then fits J
//! roughly over SpinUp's ramp on the uncorrected sensor and measures ψ roughly from its
//! back-EMF, for the loops of the states that follow, and again in its `Motion` state on
//! the corrected sensor, after a coast that measures ψ.
//!
//! **Inertia.** From the fit's first sample (t = 0), the motion
//! `J·dω/dt = kt·iq − B·ω − Tc` integrated twice reads
//!
//! `J·(Δθ(t) − ω0·t) + B·∫Δθ dt + Tc·t²/2 = kt·∫∫iq dt`
//!
//! with Δθ the angle travelled, ω0 the speed at t = 0 and Tc a constant friction torque
//! (Coulomb's, the speed keeping its sign, or a constant load). It holds at every instant
//! whatever the speed loop did, so least squares give J/kt, B/kt, Tc/kt and ω0; without
//! Tc a bearing's Coulomb friction would be taken for inertia wherever the speed
//! changes. One speed region separates B from Tc only weakly: their sum at the speed is
//! what the fit determines well. The angle is the sensor vector's own (θ̂ + ε/N: the
//! observer lags an acceleration its feed-forward, made for another J, does not know),
//! and it is a regressor, not the speed: the uncorrected sensor's angle is off by tens of
//! mrad against a travel of tens of radians, while ω̂ ripples by tens of per cent and
//! would bias a fit on it toward zero (errors in variables). Each signal passes the same
//! two first-order low-passes ([`FIT_FILTER_S`]): the relation is linear and
//! time-invariant, so it holds between the filtered signals too, and the sensor's error,
//! periodic in the angle at N or more times the rotation frequency, is left out. J/kt is
//! all the motion loops and the observer's torque feed-forward need (they act in
//! acceleration per amp); J itself follows from ψ (`kt = 1.5·p·ψ`). A fit is taken only
//! if its ω0 is the speed the rotor had ([`MotionFit::starts_at`]): on the uncorrected
//! sensor a light rotor's torque wobbles with the loop's frame, and the fit then explains
//! its data with a start that did not happen.
//!
//! **Flux linkage.** With the q current held at zero and the d current at +I, then at
//! −I, the rotor coasts (next to no torque) and the current loop applies, in its frame,
//! `v = R·i + jωe·L·i + e + v_inv`: the back-EMF e, of magnitude ωe·ψ (split between d
//! and q by however far the frame is off the rotor's), the inverter's error v_inv along
//! the current (on d), and no L·di/dt once the currents have settled. The control period
//! integrates `(v − R·i − jωe·L·i)/p` over the coast (`Snapshot::flux_angle_wb_rad`);
//! summed over both halves, what is odd in id cancels (the inverter's error, R's and L's
//! errors), and `ψ = |Σ|/Δθ` over the angle travelled, exact to 1e-4 on the corrected
//! sensor. At zero current the inverter's error would not vanish: in a winding whose PWM
//! ripple is small it turns over within a few mA of zero, where the current sensing's own
//! errors put the current. Motion's inertia fit starts after the coast: its friction can
//! slow a light rotor by most of its speed, faster than the observer's feed-forward
//! knows, and the loop's frame lags the rotor's meanwhile. A load that would stop the
//! rotor within the coast (a fan on a light rotor: J/B of about 10 ms against the
//! coast's 40 ms) cuts it once the speed has halved, before θ̂ loses the rotor and the d
//! current turns it backwards; ψ then comes from the same integral at held speed over
//! Motion's dip, where the q current's R·i and the inverter's error do not cancel (a
//! rough ψ from SpinUp is measured the same way).

use crate::align::wrap_pi;

/// The least-squares fit, as it stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionFit {
    /// J/kt: the q current one rad/s² of acceleration takes (A·s²/rad).
    pub amps_per_accel_a_s2: f32,
    /// B/kt: the q current one rad/s of speed takes against viscous friction (A·s/rad).
    pub amps_per_speed_a_s: f32,
    /// Tc/kt: the q current a constant friction torque takes (A; Coulomb friction at one
    /// sign of speed, a constant load).
    pub amps_constant_a: f32,
    /// The speed at the start (rad/s).
    pub omega0_rad_s: f32,
}

impl MotionFit {
    /// Whether the fit's starting speed is within [`START_SPEED_TOLERANCE`] of the speed
    /// the rotor had (rad/s, a share of `scale_rad_s`): a fit that moved the start is
    /// explaining the data with what is not in the model (a light rotor whose torque
    /// wobbles with the uncorrected sensor's frame).
    pub fn starts_at(&self, omega_rad_s: f32, scale_rad_s: f32) -> bool {
        libm::fabsf(self.omega0_rad_s - omega_rad_s)
            <= START_SPEED_TOLERANCE * libm::fabsf(scale_rad_s)
    }
}

/// Plausible accelerations per amp (rad/s²/A): beyond these the fit is broken (the rotor
/// did not spin up, or the speed loop never moved it), not the motor. The drive's
/// ratings span about 80-10 000.
pub const ACCEL_PER_AMP_RANGE: (f32, f32) = (1.0, 1.0e6);
/// Plausible flux linkages (Wb).
pub const FLUX_RANGE_WB: (f32, f32) = (1.0e-4, 1.0);
/// The least travel a fit or a flux measurement needs (rad, mechanical).
const MIN_TRAVEL_RAD: f32 = 1.0;
/// The equilibrated normal matrix's least pivot: below it the regressors are too near
/// collinear (a rotor turning at one speed all along, from which no inertia follows).
const MIN_PIVOT: f32 = 1e-6;
/// The fit's unknowns (see [`InertiaFit`]).
const UNKNOWNS: usize = 4;
/// How far a fit's starting speed may be from the rotor's ([`MotionFit::starts_at`]).
pub const START_SPEED_TOLERANCE: f32 = 0.1;
/// Time constant of each of the fit's two low-passes (s): the sensor's error at 20 rev/s
/// and N = 2 (40 Hz and above) is 40x smaller behind them.
pub const FIT_FILTER_S: f32 = 0.02;

/// The torque probe's q current runs until the rotor has travelled this far (rad,
/// mechanical): far enough that the uncorrected sensor's error is a small share of it.
pub const PROBE_TRAVEL_RAD: f32 = 0.5;
/// ... or for this long (s): a rotor at the ratings' least acceleration per amp (80
/// rad/s²/A) travels 0.5 rad in 0.16 s at a quarter of the alignment's current.
pub const PROBE_TIMEOUT_S: f32 = 0.25;
/// Below this travel the probe gives nothing (the loops keep what they have).
const PROBE_MIN_TRAVEL_RAD: f32 = 0.2;

/// SpinUp's torque probe: a constant q current from rest until the rotor has travelled
/// [`PROBE_TRAVEL_RAD`] or [`PROBE_TIMEOUT_S`] has passed. Its load is the rotor's own
/// inertia (a fan's torque grows with the speed, still small), so the travel
/// `d = ω0·t + a·t²/2` at a quarter of the travel and at its end gives the acceleration
/// per amp whatever speed the rotor had at the first sample (the current was on a
/// period before it), and J/kt = i/a, within the share the uncorrected sensor's error
/// has of the travel. The speed loop closes after it on that J/kt: on the nominal one a
/// light rotor's loop runs several times faster than designed and swings between a
/// quarter and one and a half times the commissioning speed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Probe {
    travel: Option<Travel>,
    travel_rad: f32,
    t_s: f32,
    /// (t, d) where the travel first reached a quarter of [`PROBE_TRAVEL_RAD`].
    quarter: Option<(f32, f32)>,
    done: bool,
    /// J/kt (A·s²/rad), on the step the probe ended with one.
    ended: Option<f32>,
}

impl Probe {
    pub fn probing(&self) -> bool {
        !self.done
    }

    /// How long it has run (s).
    pub fn duration_s(&self) -> f32 {
        self.t_s
    }

    /// J/kt on the step the probe ended with one ([`Probe::next_step`] clears it).
    pub fn ended(&self) -> Option<f32> {
        self.ended
    }

    /// A new step: what ended is reported once.
    pub fn next_step(&mut self) {
        self.ended = None;
    }

    /// One sample: `dt_s` since the previous one, the mechanical angle (wrapped) and the
    /// q current applied (A).
    pub fn add(&mut self, dt_s: f32, theta_rad: f32, current_a: f32) {
        match &mut self.travel {
            None => self.travel = Some(Travel::new(theta_rad)),
            Some(t) => {
                self.t_s += dt_s;
                self.travel_rad = t.add(theta_rad);
            }
        }
        let d = libm::fabsf(self.travel_rad);
        if self.quarter.is_none() && d >= 0.25 * PROBE_TRAVEL_RAD {
            self.quarter = Some((self.t_s, d));
        }
        if !(d < PROBE_TRAVEL_RAD && self.t_s < PROBE_TIMEOUT_S) {
            self.done = true;
            // d/t = ω0 + a·t/2 at both points (from the start alone if the quarter
            // came at the end).
            let (t1, d1) = match self.quarter {
                Some((t1, d1)) if t1 < self.t_s => (t1, d1),
                _ => (0.0, 0.0),
            };
            let v1 = if t1 > 0.0 { d1 / t1 } else { 0.0 };
            let accel = 2.0 * (d / self.t_s - v1) / (self.t_s - t1);
            let per_amp = accel / current_a;
            self.ended = (d >= PROBE_MIN_TRAVEL_RAD
                && per_amp >= ACCEL_PER_AMP_RANGE.0
                && per_amp <= ACCEL_PER_AMP_RANGE.1)
                .then(|| 1.0 / per_amp);
        }
    }
}

/// A continuous angle from wrapped samples (each step turns less than π).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Travel {
    last_rad: f32,
    travel_rad: f32,
}

impl Travel {
    pub fn new(theta_rad: f32) -> Self {
        Self {
            last_rad: theta_rad,
            travel_rad: 0.0,
        }
    }

    /// The angle travelled since [`Travel::new`], with this sample.
    pub fn add(&mut self, theta_rad: f32) -> f32 {
        self.travel_rad += wrap_pi(theta_rad - self.last_rad);
        self.last_rad = theta_rad;
        self.travel_rad
    }
}

/// Least squares of `x·[J/kt, J·(ω0 − ω_ref)/kt, B/kt, (B·ω_ref + Tc)/kt] = ∫∫iq` with
/// `x = [Δθ − ω_ref·t, −t, ∫Δθ dt − ω_ref·t²/2, t²/2]` (the motion's equation about a
/// reference speed, [`InertiaFit::about`]), each signal low-passed ([`FIT_FILTER_S`]),
/// over samples at the supervisor's rate, the sums compensated (Kahan).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct InertiaFit {
    /// The speed the regressors are taken about (rad/s, [`InertiaFit::about`]).
    omega_ref_rad_s: f32,
    started: bool,
    t_s: f32,
    travel: Travel,
    last_travel_rad: f32,
    /// ∫Δθ dt (trapezoid).
    travel_integral: f32,
    /// ∫iq dt at t = 0 (the control period's running integral), and since then.
    iq_integral_0: f32,
    last_iq_integral: f32,
    /// ∫∫iq (trapezoid on the control period's exact ∫iq).
    iq_double: f32,
    /// The low-passes' states: x then y, first stage then second.
    filter: [[f32; 2]; UNKNOWNS + 1],
    /// Σx·xᵀ and Σx·y.
    xx: [[Sum; UNKNOWNS]; UNKNOWNS],
    xy: [Sum; UNKNOWNS],
}

impl InertiaFit {
    /// A fit whose angle regressors are taken about the travel at `omega_ref_rad_s`, the
    /// speed the rotor starts at: `Δθ` and `∫Δθ dt` alone are then nearly the same
    /// columns as `t` and `t²/2`, and J's information is their small difference, which
    /// the f32 normal equations would lose (their condition is the square of the
    /// columns').
    pub fn about(omega_ref_rad_s: f32) -> Self {
        Self {
            omega_ref_rad_s,
            ..Self::default()
        }
    }

    /// One sample: `dt_s` since the previous one, the mechanical angle (wrapped, motor
    /// frame) and the control period's running ∫iq dt (A·s).
    pub fn add(&mut self, dt_s: f32, theta_rad: f32, iq_integral_a_s: f32) {
        if !self.started {
            *self = Self {
                omega_ref_rad_s: self.omega_ref_rad_s,
                started: true,
                travel: Travel::new(theta_rad),
                iq_integral_0: iq_integral_a_s,
                ..Self::default()
            };
        } else {
            self.t_s += dt_s;
            let travel = self.travel.add(theta_rad);
            let iq = iq_integral_a_s - self.iq_integral_0;
            self.travel_integral += 0.5 * (travel + self.last_travel_rad) * dt_s;
            self.iq_double += 0.5 * (iq + self.last_iq_integral) * dt_s;
            self.last_travel_rad = travel;
            self.last_iq_integral = iq;
        }
        let k = mras::min_f32(dt_s / FIT_FILTER_S, 1.0);
        let w = self.omega_ref_rad_s;
        let half_t2 = 0.5 * self.t_s * self.t_s;
        let raw = [
            self.last_travel_rad - w * self.t_s,
            -self.t_s,
            self.travel_integral - w * half_t2,
            half_t2,
            self.iq_double,
        ];
        for (f, v) in self.filter.iter_mut().zip(raw) {
            f[0] += k * (v - f[0]);
            f[1] += k * (f[0] - f[1]);
        }
        let [.., [_, y]] = self.filter;
        let mut x = [0.0; UNKNOWNS];
        for (xi, f) in x.iter_mut().zip(self.filter.iter()) {
            *xi = f[1];
        }
        // The upper triangle; `solve` mirrors it.
        for (i, (row, &xi)) in self.xx.iter_mut().zip(x.iter()).enumerate() {
            for (m, &xj) in row.iter_mut().zip(x.iter()).skip(i) {
                m.add(xi * xj);
            }
        }
        for (s, xi) in self.xy.iter_mut().zip(x) {
            s.add(xi * y);
        }
    }

    /// The angle travelled so far (rad).
    pub fn travel_rad(&self) -> f32 {
        self.last_travel_rad
    }

    /// The fit, if the data determine it and it is plausible.
    pub fn solve(&self) -> Option<MotionFit> {
        if self.last_travel_rad < MIN_TRAVEL_RAD {
            return None;
        }
        // Equilibrated (unit diagonal): the columns differ in scale by orders of
        // magnitude, not in direction. Then Gaussian elimination; the matrix is symmetric
        // positive definite, so no pivoting, and a small pivot means collinear columns.
        let mut scale = [0.0; UNKNOWNS];
        for (i, s) in scale.iter_mut().enumerate() {
            let d = self
                .xx
                .get(i)
                .and_then(|r| r.get(i))
                .map_or(0.0, |s| s.value);
            if d.is_nan() || d <= 0.0 {
                return None;
            }
            *s = 1.0 / libm::sqrtf(d);
        }
        // The lower triangle mirrors the upper one `add` sums.
        let xx = &self.xx;
        let mut a: [[f32; UNKNOWNS]; UNKNOWNS] =
            core::array::from_fn(|i| core::array::from_fn(|j| xx[i.min(j)][i.max(j)].value));
        let mut b = self.xy.map(|s| s.value);
        for (i, (row, bi)) in a.iter_mut().zip(b.iter_mut()).enumerate() {
            let si = scale.get(i).copied().unwrap_or(0.0);
            for (m, sj) in row.iter_mut().zip(scale.iter()) {
                *m *= si * sj;
            }
            *bi *= si;
        }
        let mut k = eliminate(a, b)?;
        for (ki, s) in k.iter_mut().zip(scale) {
            *ki *= s;
        }
        // About ω_ref: J/kt, J/kt·(ω0 − ω_ref), B/kt and (B·ω_ref + Tc)/kt.
        let [per_accel, accel_omega0, per_speed, constant] = k;
        let accel_per_amp = 1.0 / per_accel;
        if !(accel_per_amp >= ACCEL_PER_AMP_RANGE.0 && accel_per_amp <= ACCEL_PER_AMP_RANGE.1) {
            return None;
        }
        let w = self.omega_ref_rad_s;
        Some(MotionFit {
            amps_per_accel_a_s2: per_accel,
            amps_per_speed_a_s: per_speed,
            amps_constant_a: constant - per_speed * w,
            omega0_rad_s: w + accel_omega0 / per_accel,
        })
    }
}

/// A compensated (Kahan) sum. The fit's sums gather hundreds of terms whose J-bearing
/// part is a small share of each: summed plainly in f32, the rounding of the running sums
/// alone moved a light rotor's J by up to 20 %.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Sum {
    value: f32,
    /// What the last additions lost to rounding, to be put back in the next.
    lost: f32,
}

impl Sum {
    #[inline(never)]
    fn add(&mut self, v: f32) {
        let y = v - self.lost;
        let t = self.value + y;
        self.lost = (t - self.value) - y;
        self.value = t;
    }
}

/// Solve `a·k = b` for a symmetric positive definite `a` with a unit diagonal, by Gaussian
/// elimination without pivoting; None if a pivot falls below [`MIN_PIVOT`].
// The textbook's indices read clearer here than iterators over rows and columns.
#[allow(clippy::needless_range_loop)]
fn eliminate(
    mut a: [[f32; UNKNOWNS]; UNKNOWNS],
    mut b: [f32; UNKNOWNS],
) -> Option<[f32; UNKNOWNS]> {
    for p in 0..UNKNOWNS {
        let pivot = a[p][p];
        if pivot.is_nan() || pivot <= MIN_PIVOT {
            return None;
        }
        for r in p + 1..UNKNOWNS {
            let f = a[r][p] / pivot;
            for c in p..UNKNOWNS {
                a[r][c] -= f * a[p][c];
            }
            b[r] -= f * b[p];
        }
    }
    let mut k = [0.0; UNKNOWNS];
    for p in (0..UNKNOWNS).rev() {
        let mut v = b[p];
        for c in p + 1..UNKNOWNS {
            v -= a[p][c] * k[c];
        }
        k[p] = v / a[p][p];
    }
    Some(k)
}

/// The back-EMF's integral over a window: its d and q parts (Wb·rad) and the angle
/// travelled (rad).
type Window = ([f32; 2], f32);

/// ψ from the coast: the control period's running back-EMF integrals
/// (`Snapshot::flux_angle_wb_rad`) and the angle, over windows (one per sign of id), each
/// from its first sample to its last.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FluxMeter {
    mark: Option<(Travel, [f32; 2])>,
    /// The closed windows' sums, and the open one's so far.
    closed: Window,
    open: Window,
}

impl FluxMeter {
    /// One sample of a window (the first is its mark).
    pub fn add(&mut self, theta_rad: f32, flux_angle_wb_rad: [f32; 2]) {
        match &mut self.mark {
            None => self.mark = Some((Travel::new(theta_rad), flux_angle_wb_rad)),
            Some((travel, at)) => {
                let [d, q] = flux_angle_wb_rad;
                self.open = ([d - at[0], q - at[1]], travel.add(theta_rad));
            }
        }
    }

    /// End the open window: the next sample starts another.
    pub fn close(&mut self) {
        let ([d, q], t) = self.open;
        self.closed = (
            [self.closed.0[0] + d, self.closed.0[1] + q],
            self.closed.1 + t,
        );
        self.open = ([0.0; 2], 0.0);
        self.mark = None;
    }

    /// ψ (Wb) over the windows so far, if the rotor travelled enough and the result is
    /// plausible.
    pub fn flux_wb(&self) -> Option<f32> {
        let d = self.closed.0[0] + self.open.0[0];
        let q = self.closed.0[1] + self.open.0[1];
        let travel = self.closed.1 + self.open.1;
        if travel.is_nan() || travel < MIN_TRAVEL_RAD {
            return None;
        }
        let psi = libm::sqrtf(d * d + q * q) / travel;
        (psi >= FLUX_RANGE_WB.0 && psi <= FLUX_RANGE_WB.1).then_some(psi)
    }
}

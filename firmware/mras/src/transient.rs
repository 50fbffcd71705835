//! Torque transients kept out of the adaptation.
//!
//! A torque the feedforward does not know (a load step) makes the observer lag the rotor
//! until its disturbance estimate has caught up: ε carries a bump of ΔT/K_so (tens of
//! mrad) that rises within a few 1/λ1 and decays over 1/λ3. It is not periodic in angle,
//! but over part of a revolution it correlates with the low error harmonics (offset,
//! amplitude), and those paths take it for sensor error: kicks of tens of mrad after
//! every step, un-learnt only over the next revolutions (docs/theory.md §3, *Torque
//! transients*).
//!
//! Two defences, both in the adaptation (the control interrupt is untouched), and both
//! only after such a transient: until then the adaptation is exactly what it was.
//! - Once the bank has converged, a jump of ε's band between λ2 and λ1 far above its
//!   recent envelope closes the adaptation's gate for 1.5/λ3, the disturbance estimate's
//!   settling, counted from the band's last jump.
//! - For 5/λ3 after the jump the paths correlate ε through a second-order high-pass two
//!   octaves below the lowest error harmonic (at λ2 at most), their compensation
//!   including it, so that what is left of the lag when the gate reopens does not leak.

use crate::complex::Cplx;
use crate::config::Config;
use crate::trig::min_f32;
use core::f32::consts::TAU;

/// A jump is this many times the envelope's variance (4σ) ...
const TRIP_VARIANCE_RATIO: f32 = 16.0;
/// ... and above this floor (sensor-electrical rad): ε's band carries noise of a few
/// 0.1 mrad after convergence; a load step puts tens of mrad in it.
const TRIP_FLOOR_RAD: f32 = 2.0e-3;
/// The envelope (rad²) after a (re)start: no memory of the ripple yet.
const ENVELOPE_START_RAD2: f32 = 1.0;
/// Time the gate stays closed after the band's last jump, in time constants of the
/// slowest eigenvalue: the lag has decayed to e^-1.5 (a fifth); what is left, the
/// high-pass takes. Shorter lets the tail kick the paths (2.1x the oracle in the load-step
/// phase at 1.0); longer delays tracking a drift that follows a load change.
const HOLD_TIME_CONSTANTS: f32 = 1.5;
/// The envelope follows a fall within this many 1/λ2; it follows a rise only over the
/// hold time, so that a transient cannot raise its own threshold while a lasting change
/// of the ripple (another speed) is accepted within about the hold time.
const ENVELOPE_FALL_TIME_CONSTANTS: f32 = 3.0;
/// After a jump the correlation runs through the high-pass for this many time constants
/// of the slowest eigenvalue (the lag has decayed to e^-5, under 1 %), then through
/// none again, as before the jump.
const HIGH_PASS_TIME_CONSTANTS: f32 = 5.0;
/// The high-pass corner sits this far below the lowest error harmonic's frequency N·ω̂:
/// it passes that harmonic at 0.94 (second order).
const HIGH_PASS_BELOW_LOWEST: f32 = 0.25;

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct TransientGate {
    /// ε low-passed at λ1 and at λ2: their difference is the band watched for jumps
    /// (sensor-electrical rad).
    fast_rad: f32,
    slow_rad: f32,
    /// Mean square of the band (rad²), rising slowly and falling fast.
    envelope_rad2: f32,
    /// Samples until the gate reopens.
    hold_left: u32,
    /// Samples the correlation still runs through the high-pass after a jump.
    high_pass_left: u32,
    high_pass_samples: u32,
    /// Trips only once the bank has converged since the last (re)start: before, the band
    /// carries the sensor error itself, whose level follows the speed through H.
    armed: bool,
    /// The two low-pass stages the high-pass subtracts (rad).
    hp_rad: [f32; 2],
    /// The high-pass corner (rad/s) and its per-sample gain.
    corner_rad_s: f32,
    a_hp: f32,
    max_corner_rad_s: f32,
    a_fast: f32,
    a_slow: f32,
    a_rise: f32,
    a_fall: f32,
    hold_samples: u32,
    sample_period_s: f32,
}

impl TransientGate {
    /// `enabled` false: always open and no high-pass (the paper's law, literally).
    pub fn new(cfg: &Config, enabled: bool) -> Self {
        let [a, b, c] = cfg.observer.eigenvalues_hz.map(|f| TAU * f);
        let slowest = a.min(b).min(c);
        let fastest = a.max(b).max(c);
        let mid = a.min(b).max(a.max(b).min(c));
        let t = cfg.sample_period_s;
        let hold_s = HOLD_TIME_CONSTANTS / slowest;
        let alpha = |tau_s: f32| (t / tau_s).min(1.0);
        Self {
            fast_rad: 0.0,
            slow_rad: 0.0,
            envelope_rad2: ENVELOPE_START_RAD2,
            hold_left: 0,
            high_pass_left: 0,
            high_pass_samples: if enabled {
                (HIGH_PASS_TIME_CONSTANTS / slowest / t) as u32
            } else {
                0
            },
            armed: false,
            hp_rad: [0.0; 2],
            corner_rad_s: 0.0,
            a_hp: 0.0,
            max_corner_rad_s: mid,
            a_fast: alpha(1.0 / fastest),
            a_slow: alpha(1.0 / mid),
            a_rise: alpha(hold_s),
            a_fall: alpha(ENVELOPE_FALL_TIME_CONSTANTS / mid),
            hold_samples: if enabled { (hold_s / t) as u32 } else { 0 },
            sample_period_s: t,
        }
    }

    /// After a (re)start of the observer: open, disarmed, no memory of the old ε.
    pub fn reset(&mut self) {
        self.fast_rad = 0.0;
        self.slow_rad = 0.0;
        self.envelope_rad2 = ENVELOPE_START_RAD2;
        self.hold_left = 0;
        self.high_pass_left = 0;
        self.armed = false;
        self.hp_rad = [0.0; 2];
    }

    /// The bank has converged: from now on a jump of the band closes the gate.
    pub fn arm(&mut self) {
        self.armed = true;
    }

    /// A new bank has yet to converge: no trips until it has.
    pub fn disarm(&mut self) {
        self.armed = false;
    }

    pub fn is_armed(&self) -> bool {
        self.armed
    }

    /// Place the high-pass below the lowest error harmonic, at `w_rad_s` = N·|ω̂|.
    #[inline(always)]
    pub fn set_lowest_harmonic(&mut self, w_rad_s: f32) {
        self.corner_rad_s = min_f32(HIGH_PASS_BELOW_LOWEST * w_rad_s, self.max_corner_rad_s);
        self.a_hp = min_f32(self.corner_rad_s * self.sample_period_s, 1.0);
    }

    /// One sample's ε: whether the adaptation may use it (no jump of the band within
    /// the hold time). Also advances the high-pass.
    #[inline(always)]
    pub fn step(&mut self, eps_e_rad: f32) -> bool {
        self.fast_rad += (eps_e_rad - self.fast_rad) * self.a_fast;
        self.slow_rad += (eps_e_rad - self.slow_rad) * self.a_slow;
        let band = self.fast_rad - self.slow_rad;
        let band2 = band * band;
        if self.armed
            && band2 > TRIP_VARIANCE_RATIO * self.envelope_rad2 + TRIP_FLOOR_RAD * TRIP_FLOOR_RAD
        {
            self.hold_left = self.hold_samples;
            self.high_pass_left = self.high_pass_samples;
        }
        let a = if band2 > self.envelope_rad2 {
            self.a_rise
        } else {
            self.a_fall
        };
        self.envelope_rad2 += (band2 - self.envelope_rad2) * a;
        let [s1, s2] = &mut self.hp_rad;
        *s1 += (eps_e_rad - *s1) * self.a_hp;
        *s2 += (eps_e_rad - *s1 - *s2) * self.a_hp;
        let calm = self.hold_left == 0;
        self.hold_left = self.hold_left.saturating_sub(1);
        self.high_pass_left = self.high_pass_left.saturating_sub(1);
        calm
    }

    /// ε, through the high-pass while a lag may remain (after [`Self::step`] with the
    /// same ε).
    #[inline(always)]
    pub fn high_passed(&self, eps_e_rad: f32) -> f32 {
        if self.high_pass_left != 0 {
            eps_e_rad - self.hp_rad[0] - self.hp_rad[1]
        } else {
            eps_e_rad
        }
    }

    /// `1/HP(jω)` at the error frequency `w_rad_s` (either sign): `(1 - j·ωc/ω)²`; the
    /// path compensation multiplies `1/H` by it.
    #[inline(always)]
    pub fn inverse_high_pass(&self, w_rad_s: f32) -> Cplx {
        if self.high_pass_left == 0 {
            return Cplx::ONE;
        }
        let h = Cplx::new(1.0, -self.corner_rad_s / w_rad_s);
        h * h
    }
}

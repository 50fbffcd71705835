//! The motor's electrical constants identified at power-up: the current sensing's sign,
//! the stator resistance (with the inverter's dead-time voltage error and device drops
//! cancelled) and the d and q inductances, before any loop relies on them.
//!
//! It works in a fixed frame: electrical angle 0 (α) before any alignment is known, so
//! that the rotor aligns there as it would in the alignment, or the rotor's d axis when
//! a calibration is in force, where its current makes no torque (the control period
//! chooses, `commissioning::Setpoint::Identify`). "α" and "β" below are that frame's
//! axes. Per period: the measured current in, the voltage for the next period out
//! ([`Identifier::step`]), in five stages:
//!
//! 1. **Probe**, open loop: voltage pulses on α of [`PROBE_ON_PERIODS`], each twice the
//!    last, until one drives the current to half the identification level. Its steepest
//!    rise and its final current bound L and R from above (the dead-time voltage and the
//!    resistive drop only lower both); they place a conservative PI for stage 2. The
//!    measured current must point along the applied voltage: a reversed or crossed
//!    current sense is refused here ([`IdentError::CurrentSign`]), before any loop
//!    could run it as positive feedback.
//! 2. **Levels**: that PI holds the α current at half the level, then at the level, and a
//!    second one holds β at zero. The levels rise above the identification current where
//!    the probe's rise says the PWM ripple takes a phase current through zero (small L):
//!    there the inverter's error is not yet its full value. The inverter's error (dead
//!    time, device drops) has the same sign and size at both, so `R = ΔV/ΔI` leaves it
//!    out and the intercept measures it. A rotor resting off α swings onto it, lightly
//!    damped, for seconds: its back-EMF along α, `d(ψ·cos θe)/dt`, integrates to zero
//!    between two instants at the same rotor angle, so each level's means are taken
//!    between two instants the sensor reads alike, and the β loop keeps the swing's β
//!    back-EMF from driving a current that would change the phases' inverter error
//!    between the levels.
//! 3. **Ripple d**: ±ΔV added on α, alternating every period, while the loops hold the
//!    level on the mean of the last two samples (in which the zig-zag cancels). The
//!    current zig-zags by `D` peak to peak around the level without changing sign, so
//!    the inverter's error stays constant and drops out. For a first-order R-L with the voltage constant over each period (exact, for
//!    any L/R against the period): `x = R·D/(2ΔV) = (1-a)/(1+a)`, `a = exp(-R·T/L)`.
//!    A short trial burst sizes ΔV for a ripple of [`RIPPLE_TARGET`] of the level.
//! 4. **Ripple q**: the same on β, α still at the level: the rotor is held by the d
//!    current and sees a torque alternating every period, with no mean.
//! 5. **Release**: both currents held at zero until they have decayed, so that the loop
//!    that follows starts from rest (shorted windings would let a swinging rotor drive
//!    amperes).
//!
//! Everything is bounded: the current (an over-current is refused at once), the voltage
//! (the loop's limit) and each stage's time.

use crate::foc::Pi;

/// Periods of one probe pulse: long enough for a measurable rise on the largest L, short
/// enough that a pulse stays below the current limit on the smallest (each pulse is at
/// most twice one that stayed below half the level).
pub const PROBE_ON_PERIODS: u32 = 40;
/// Periods the mean current and voltage are taken over while a level settles, and the
/// consecutive settled windows a level on a still rotor needs.
const WINDOW_PERIODS: u32 = 100;
const SETTLED_WINDOWS: u32 = 3;
/// A level's window may start at any of these marks, this many periods apart.
const MARKS: usize = 8;
const MARK_PERIODS: u32 = 100;
/// The shortest window from a mark (s), and from a mark the sensor never left (a swing
/// that died out: only noise to average).
const MIN_WINDOW_S: f32 = 0.05;
const STILL_WINDOW_S: f32 = 0.015;
/// The sensor reads alike: its vector within this of the mark's (scaled units, summed
/// over X and Y: four counts of the 12-bit front end, twice the noise of a board's
/// inputs), or within 0.6 of this period's step (a fast swing passes the mark between
/// two samples).
const SAME_READING: f32 = 3e-3;
/// A mark the vector never left by more than this saw a still rotor (a swing travels
/// tens of times as far).
const STILL_READING: f32 = 1.5e-2;
/// A window that has not closed this long after the first mark starts again (a rotor
/// still creeping toward α).
const RESTART_S: f32 = 0.3;
/// Each stage's time limit (s): the probe's decay and a level's settling scale with L/R,
/// up to 40 ms on the slowest motor in the ratings; this leaves about 7x.
const STAGE_TIMEOUT_S: f32 = 1.0;
/// Peak-to-peak ripple aimed at, as a share of the level: well clear of zero current on
/// either axis (on β, a phase current changes sign only beyond `level/√3`).
pub const RIPPLE_TARGET: f32 = 0.3;
/// Ripple periods measured, after `RIPPLE_SKIP` periods of transient.
const RIPPLE_TRIAL_PERIODS: u32 = 64;
const RIPPLE_PERIODS: u32 = 400;
const RIPPLE_SKIP: u32 = 8;
/// Bandwidth of the stage-2 PI (Hz), designed on the probe's upper bounds: an L bound up
/// to a few times too high raises it that much, an R bound too high lowers its damping,
/// to no less than 0.5 as long as the probe's rise time is within 1/(2π·f).
const LEVEL_BANDWIDTH_HZ: f32 = 100.0;
/// Plausible results: beyond these the measurement is broken, not the motor.
const R_RANGE_OHM: (f32, f32) = (1e-3, 100.0);
const L_RANGE_H: (f32, f32) = (1e-6, 0.1);

/// What the identification needs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IdentConfig {
    /// The identification level (A, peak phase current), at least: the probe's pulses
    /// end at half of it; the two levels are it and half of it, or higher where the
    /// PWM ripple needs (at most 0.8 `i_limit_a`, and within the voltage).
    pub current_a: f32,
    /// The largest voltage magnitude it may apply (V): the current loop's limit.
    pub v_max_v: f32,
    /// A measured current beyond this (A) ends it at once.
    pub i_limit_a: f32,
    /// The control period (s).
    pub period_s: f32,
}

/// The identified constants.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Identified {
    pub r_ohm: f32,
    pub ld_h: f32,
    pub lq_h: f32,
    /// The inverter's voltage error along α at the levels (dead time and device drops
    /// together, V): what `R·I` leaves of the voltage.
    pub v_inverter_v: f32,
}

/// Why the identification stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IdentError {
    /// The measured current does not point along the applied voltage: a current
    /// amplifier's sign, a phase's wiring or its channel is wrong.
    CurrentSign,
    /// The largest voltage did not drive half the identification level: R too high for
    /// it, or a phase open.
    CurrentNotReached,
    /// A measured current beyond the limit.
    OverCurrent,
    /// A stage did not settle (or decay) in its time.
    Unsettled,
    /// A result outside what any motor in the drive's ratings could give.
    OutOfRange,
    /// The spin-up's acceleration per amp could not be fitted, or is implausible
    /// ([`crate::spin::InertiaFit`]).
    InertiaOutOfRange,
    /// The coast's flux linkage is implausible, or the rotor did not travel
    /// ([`crate::spin::FluxMeter`]).
    FluxOutOfRange,
}

impl IdentError {
    pub const fn name(&self) -> &'static str {
        match self {
            IdentError::CurrentSign => "CurrentSign",
            IdentError::CurrentNotReached => "CurrentNotReached",
            IdentError::OverCurrent => "IdentOverCurrent",
            IdentError::Unsettled => "IdentUnsettled",
            IdentError::OutOfRange => "IdentOutOfRange",
            IdentError::InertiaOutOfRange => "InertiaOutOfRange",
            IdentError::FluxOutOfRange => "FluxOutOfRange",
        }
    }
}

/// Where the identification is.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum IdentStatus {
    #[default]
    Pending,
    Done(Identified),
    Failed(IdentError),
}

/// Where a level's window may start: the sensor's vector and the sums so far.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Mark {
    xy: (f32, f32),
    n: u32,
    sum_i: f32,
    sum_v: f32,
    /// The vector never left it by more than [`STILL_READING`].
    still: bool,
}

/// A level's means between two instants the sensor reads alike: from one of the first
/// [`MARKS`] marks, [`MARK_PERIODS`] apart, to the first period at least
/// [`MIN_WINDOW_S`] (or [`STILL_WINDOW_S`] for a still rotor) later whose vector is the
/// mark's again ([`SAME_READING`]); the earliest mark that closes wins. A swing's later
/// marks lie inside it, so a rotor released at a swing's extreme still closes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Window {
    n: u32,
    sum_i: f32,
    sum_v: f32,
    last_xy: (f32, f32),
    marks: [Mark; MARKS],
    count: usize,
}

/// |a − b| summed over X and Y.
fn apart(a: (f32, f32), b: (f32, f32)) -> f32 {
    libm::fabsf(a.0 - b.0) + libm::fabsf(a.1 - b.1)
}

impl Window {
    /// Open (again) at sensor vector `xy`, in place: the marks past `count` are never
    /// read, so they stay as they are (a new window built and copied in costs the
    /// control period about 200 cycles).
    fn restart(&mut self, xy: (f32, f32)) {
        (self.n, self.sum_i, self.sum_v, self.count) = (0, 0.0, 0.0, 0);
        self.last_xy = xy;
    }

    /// One period's α current and voltage at sensor vector `xy`; the window's means
    /// (current, voltage) once it closes. `least` holds the shortest windows in periods
    /// ([`WindowPeriods`]).
    fn add(&mut self, i: f32, v: f32, xy: (f32, f32), least: WindowPeriods) -> Option<(f32, f32)> {
        if self.n % MARK_PERIODS == 0 {
            if let Some(m) = self.marks.get_mut(self.count) {
                *m = Mark {
                    xy,
                    n: self.n,
                    sum_i: self.sum_i,
                    sum_v: self.sum_v,
                    still: true,
                };
                self.count += 1;
            }
        }
        self.n += 1;
        self.sum_i += i;
        self.sum_v += v;
        let same = mras::max_f32(SAME_READING, 0.6 * apart(xy, self.last_xy));
        self.last_xy = xy;
        for m in self.marks.iter_mut().take(self.count) {
            let periods = self.n - m.n;
            // A mark the vector left that is not yet old enough cannot close: no
            // distance to work out (eight marks' were most of a level's period).
            if !m.still && periods < least.moving {
                continue;
            }
            let d = apart(xy, m.xy);
            m.still &= d <= STILL_READING;
            let least = if m.still { least.still } else { least.moving };
            if periods >= least && d <= same {
                let k = 1.0 / periods as f32;
                return Some(((self.sum_i - m.sum_i) * k, (self.sum_v - m.sum_v) * k));
            }
        }
        None
    }
}

/// A window's shortest spans in periods: the fewest `p` with `p·T` at least
/// [`MIN_WINDOW_S`] (a moving rotor) and [`STILL_WINDOW_S`] (a still one), as f32
/// reads them; worked out once per attempt, not compared in seconds every period.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct WindowPeriods {
    moving: u32,
    still: u32,
}

impl WindowPeriods {
    fn new(period_s: f32) -> Self {
        // The first p of a few around s/T whose p·T reaches s (bounded: no loop on a
        // period the configuration let through as 0 or NaN).
        let fewest = |s: f32| {
            let guess = (s / period_s) as u32;
            (guess.saturating_sub(1)..guess.saturating_add(3))
                .find(|&p| p as f32 * period_s >= s)
                .unwrap_or(guess)
        };
        Self {
            moving: fewest(MIN_WINDOW_S),
            still: fewest(STILL_WINDOW_S),
        }
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Stage {
    /// A pulse of `volts` (`on`), then the current's decay.
    Probe {
        volts: f32,
        on: bool,
    },
    Level {
        index: u8,
    },
    /// `trial`: sizing ΔV; then measuring.
    Ripple {
        q: bool,
        trial: bool,
    },
    /// Both currents held at zero until they have decayed: the next state's loop starts
    /// from rest (its step response is then its design's).
    Release,
    #[default]
    Finished,
}

/// The identification's state: one per attempt.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Identifier {
    cfg: IdentConfig,
    stage: Stage,
    status: IdentStatus,
    /// Periods in the stage (or the pulse), and the stage's time.
    k: u32,
    stage_s: f32,
    // Probe.
    last_i: f32,
    max_rise_a: f32,
    l_bound_h: f32,
    r_bound_ohm: f32,
    /// The second level (A); the first is half of it.
    level_target_a: f32,
    // Levels: the α and β loops, the voltage they commanded last, the settling check's
    // sum and, once settled, the window.
    pi: [Pi; 2],
    v_ab: (f32, f32),
    sum_i: f32,
    sum_v: f32,
    last_mean_v: f32,
    /// The settling window's sum of sensor vectors, and the last window's mean.
    sum_xy: (f32, f32),
    last_xy: (f32, f32),
    settled: u32,
    /// The level's window, read only while open: opened and restarted in place.
    window: Window,
    window_open: bool,
    window_s: f32,
    window_periods: WindowPeriods,
    level_v: [f32; 2],
    level_a: [f32; 2],
    r_ohm: f32,
    // Ripple.
    last_ab: (f32, f32),
    dv_v: f32,
    ripple_sum: f32,
    ld_h: f32,
    /// Everything found, reported once the current has decayed.
    found: Identified,
}

impl Identifier {
    pub fn new(cfg: IdentConfig) -> Self {
        let mut id = Self::default();
        id.restart(cfg);
        id
    }

    /// [`Identifier::new`] in place, for another attempt: every field but the window's
    /// storage, which is read only once opened. Built aside and copied in, a new
    /// identifier cost the control period a copy of its 300 bytes.
    pub fn restart(&mut self, cfg: IdentConfig) {
        // Every field named: one added is a compile error here until it is restarted.
        let Self {
            cfg: c,
            stage,
            status,
            k,
            stage_s,
            last_i,
            max_rise_a,
            l_bound_h,
            r_bound_ohm,
            level_target_a,
            pi,
            v_ab,
            sum_i,
            sum_v,
            last_mean_v,
            sum_xy,
            last_xy,
            settled,
            window: _,
            window_open,
            window_s,
            window_periods,
            level_v,
            level_a,
            r_ohm,
            last_ab,
            dv_v,
            ripple_sum,
            ld_h,
            found,
        } = self;
        *c = cfg;
        // A hundredth of a volt at first: below any dead-time voltage, so the first
        // pulses measure nothing and the doubling finds the level from below.
        *stage = Stage::Probe {
            volts: 0.01,
            on: true,
        };
        *status = IdentStatus::Pending;
        *k = 0;
        (*stage_s, *last_i, *max_rise_a, *l_bound_h) = (0.0, 0.0, 0.0, 0.0);
        (*r_bound_ohm, *level_target_a) = (0.0, 0.0);
        *pi = [Pi::default(); 2];
        *v_ab = (0.0, 0.0);
        (*sum_i, *sum_v, *last_mean_v) = (0.0, 0.0, f32::NAN);
        (*sum_xy, *last_xy) = ((0.0, 0.0), (0.0, 0.0));
        *settled = 0;
        (*window_open, *window_s) = (false, 0.0);
        *window_periods = WindowPeriods::new(cfg.period_s);
        (*level_v, *level_a, *r_ohm) = ([0.0; 2], [0.0; 2], 0.0);
        (*last_ab, *dv_v, *ripple_sum, *ld_h) = ((0.0, 0.0), 0.0, 0.0, 0.0);
        *found = Identified::default();
    }

    pub fn status(&self) -> IdentStatus {
        self.status
    }

    fn fail(&mut self, e: IdentError) -> (f32, f32) {
        self.status = IdentStatus::Failed(e);
        self.stage = Stage::Finished;
        (0.0, 0.0)
    }

    fn enter(&mut self, s: Stage) {
        self.stage = s;
        self.k = 0;
        self.stage_s = 0.0;
    }

    /// One period: the measured αβ current of this period's sample (A) and the sensor's
    /// vector (scaled units, as the core takes it) → the αβ voltage for the next period
    /// (V). After the end, (0, 0).
    pub fn step(&mut self, (i_alpha, i_beta): (f32, f32), xy: (f32, f32)) -> (f32, f32) {
        let c = self.cfg;
        if self.stage == Stage::Finished {
            return (0.0, 0.0);
        }
        if !(i_alpha.is_finite() && i_beta.is_finite()) {
            return self.fail(IdentError::OutOfRange);
        }
        if libm::fabsf(i_alpha) > c.i_limit_a || libm::fabsf(i_beta) > c.i_limit_a {
            return self.fail(IdentError::OverCurrent);
        }
        self.stage_s += c.period_s;
        if self.stage_s > STAGE_TIMEOUT_S {
            return self.fail(IdentError::Unsettled);
        }
        self.k += 1;
        match self.stage {
            Stage::Probe { volts, on } => self.probe(volts, on, i_alpha, i_beta),
            Stage::Level { index } => self.level(index, (i_alpha, i_beta), xy),
            Stage::Ripple { q, trial } => self.ripple(q, trial, (i_alpha, i_beta)),
            Stage::Release => {
                let rest = 0.02 * self.level_target_a;
                if self.k >= 3 && libm::fabsf(i_alpha) < rest && libm::fabsf(i_beta) < rest {
                    self.status = IdentStatus::Done(self.found);
                    self.stage = Stage::Finished;
                    return (0.0, 0.0);
                }
                self.hold((0.0, 0.0), (i_alpha, i_beta))
            }
            Stage::Finished => (0.0, 0.0),
        }
    }

    fn probe(&mut self, volts: f32, on: bool, i_alpha: f32, i_beta: f32) -> (f32, f32) {
        let c = self.cfg;
        // Commanded in periods 1..=ON, applied one period later each, seen in the
        // samples 3..=ON+2 (a period's sample shows the voltage of the period before).
        const ON: u32 = PROBE_ON_PERIODS;
        let k = self.k;
        let rise = i_alpha - self.last_i;
        self.last_i = i_alpha;
        if !on {
            // Off until the pulse has passed and the current decayed.
            if k >= 3 && libm::fabsf(i_alpha) < 0.02 * c.current_a {
                if self.l_bound_h > 0.0 {
                    self.start_levels();
                    return (0.0, 0.0);
                }
                let volts = 2.0 * volts;
                if volts > c.v_max_v {
                    return self.fail(IdentError::CurrentNotReached);
                }
                self.max_rise_a = 0.0;
                self.enter_keeping_time(Stage::Probe { volts, on: true });
            }
            return (0.0, 0.0);
        }
        if k >= 3 {
            self.max_rise_a = mras::max_f32(self.max_rise_a, rise);
        }
        let magnitude = libm::sqrtf(i_alpha * i_alpha + i_beta * i_beta);
        let reached = magnitude >= 0.5 * c.current_a;
        if reached || k >= ON + 2 {
            if magnitude >= 0.25 * c.current_a && i_alpha < 0.8 * magnitude {
                return self.fail(IdentError::CurrentSign);
            }
            if reached && self.max_rise_a > 0.0 {
                // Both bounds from above: the inverter's error and R·i only lower the
                // rise and the current.
                self.l_bound_h = volts * c.period_s / self.max_rise_a;
                self.r_bound_ohm = volts / i_alpha;
                // The levels clear the band the PWM ripple makes a phase current cross
                // zero in (its inverter error is not yet the full one there): the
                // smaller phases carry half the level, and the ripple is of the order
                // of a period's rise at this voltage.
                // Within the current limit and, by the R bound, the voltage.
                let low = mras::max_f32(0.5 * c.current_a, 4.0 * self.max_rise_a);
                let high = mras::min_f32(0.8 * c.i_limit_a, 0.7 * c.v_max_v / self.r_bound_ohm);
                self.level_target_a = mras::min_f32(2.0 * low, high);
            }
            self.enter_keeping_time(Stage::Probe { volts, on: false });
            return (0.0, 0.0);
        }
        (if k <= ON { volts } else { 0.0 }, 0.0)
    }

    /// A new pulse or its decay: the stage's time goes on.
    fn enter_keeping_time(&mut self, s: Stage) {
        self.stage = s;
        self.k = 0;
    }

    fn start_levels(&mut self) {
        let wc = core::f32::consts::TAU * LEVEL_BANDWIDTH_HZ;
        let pi = Pi {
            kp: self.l_bound_h * wc,
            ki: self.r_bound_ohm * wc,
            integral: 0.0,
        };
        self.pi = [pi; 2];
        self.v_ab = (0.0, 0.0);
        self.start_level(0);
    }

    fn start_level(&mut self, index: u8) {
        (self.sum_i, self.sum_v, self.last_mean_v) = (0.0, 0.0, f32::NAN);
        self.sum_xy = (0.0, 0.0);
        self.settled = 0;
        self.window_open = false;
        self.enter(Stage::Level { index });
    }

    /// Both loops toward `target` (αβ, A) on the measured current `i`, each within the
    /// voltage limit (anti-windup: an integrator holds what the limit allows); the voltage
    /// for the next period.
    fn hold(&mut self, target: (f32, f32), i: (f32, f32)) -> (f32, f32) {
        let (lim, t) = (self.cfg.v_max_v, self.cfg.period_s);
        let mut v = [0.0; 2];
        for ((pi, out), e) in self
            .pi
            .iter_mut()
            .zip(v.iter_mut())
            .zip([target.0 - i.0, target.1 - i.1])
        {
            let unlimited = pi.step(e, t, false);
            *out = mras::min_f32(mras::max_f32(unlimited, -lim), lim);
            if *out != unlimited {
                pi.integral = *out - pi.kp * e;
            }
        }
        self.v_ab = (v[0], v[1]);
        self.v_ab
    }

    fn level(&mut self, index: u8, i: (f32, f32), xy: (f32, f32)) -> (f32, f32) {
        let c = self.cfg;
        let target = if index == 0 { 0.5 } else { 1.0 } * self.level_target_a;
        // The voltage of the period this sample closed.
        let v_alpha = self.v_ab.0;
        let measured = if !self.window_open {
            // A still rotor: the α current's mean within 1 % of the level, the
            // voltage's steady and the sensor's reading the same over SETTLED_WINDOWS
            // windows, the last window's means.
            // A moving one: the current within 5 %, then a window between two
            // instants the sensor reads alike (its back-EMF keeps the voltage from
            // settling; the window's ends at one reading take it out).
            self.sum_i += i.0;
            self.sum_v += v_alpha;
            self.sum_xy = (self.sum_xy.0 + xy.0, self.sum_xy.1 + xy.1);
            let mut measured = None;
            if self.k % WINDOW_PERIODS == 0 {
                let n = WINDOW_PERIODS as f32;
                let (mean_i, mean_v) = (self.sum_i / n, self.sum_v / n);
                // The window's mean reading: the sensor's noise a tenth of a sample's.
                let mean_xy = (self.sum_xy.0 / n, self.sum_xy.1 / n);
                (self.sum_i, self.sum_v, self.sum_xy) = (0.0, 0.0, (0.0, 0.0));
                let off = libm::fabsf(mean_i - target);
                let steady =
                    libm::fabsf(mean_v - self.last_mean_v) <= 2e-3 * libm::fabsf(mean_v) + 1e-3;
                // (Not on the level's first window: nothing to compare with.)
                let moved = apart(mean_xy, self.last_xy);
                let moving = self.last_mean_v.is_finite() && moved > STILL_READING;
                self.last_mean_v = mean_v;
                self.last_xy = mean_xy;
                self.settled = if off <= 0.01 * target && steady && moved <= SAME_READING {
                    self.settled + 1
                } else {
                    0
                };
                if self.settled >= SETTLED_WINDOWS {
                    measured = Some((mean_i, mean_v));
                } else if off <= 0.05 * target && moving {
                    self.window.restart(xy);
                    (self.window_open, self.window_s) = (true, 0.0);
                }
            }
            measured
        } else {
            let w = &mut self.window;
            let m = w.add(i.0, v_alpha, xy, self.window_periods);
            self.window_s += c.period_s;
            if m.is_none() && self.window_s > RESTART_S {
                w.restart(xy);
                self.window_s = 0.0;
            }
            m
        };
        if let Some((mean_i, mean_v)) = measured {
            // Constant indices: no bounds check in the control interrupt.
            if index == 0 {
                self.level_v[0] = mean_v;
                self.level_a[0] = mean_i;
                self.start_level(1);
            } else {
                self.level_v[1] = mean_v;
                self.level_a[1] = mean_i;
                return self.finish_levels(i);
            }
        }
        self.hold((target, 0.0), i)
    }

    fn finish_levels(&mut self, i: (f32, f32)) -> (f32, f32) {
        let di = self.level_a[1] - self.level_a[0];
        let r = (self.level_v[1] - self.level_v[0]) / di;
        if !(r.is_finite() && r > R_RANGE_OHM.0 && r < R_RANGE_OHM.1) {
            return self.fail(IdentError::OutOfRange);
        }
        self.r_ohm = r;
        // A trial ΔV from the L bound: at most the aimed ripple (the bound is high).
        self.dv_v = RIPPLE_TARGET * self.level_target_a * self.l_bound_h / self.cfg.period_s;
        self.dv_v = mras::min_f32(self.dv_v, self.ripple_room()) / 4.0;
        self.ripple_sum = 0.0;
        self.last_ab = i;
        self.enter(Stage::Ripple {
            q: false,
            trial: true,
        });
        self.hold((self.level_target_a, 0.0), i)
    }

    /// The largest ΔV that keeps the voltage within the limit on either axis.
    fn ripple_room(&self) -> f32 {
        let base = mras::max_f32(libm::fabsf(self.v_ab.0), libm::fabsf(self.v_ab.1));
        mras::max_f32(self.cfg.v_max_v - base, 0.0)
    }

    fn ripple(&mut self, q: bool, trial: bool, i: (f32, f32)) -> (f32, f32) {
        let n = if trial {
            RIPPLE_TRIAL_PERIODS
        } else {
            RIPPLE_PERIODS
        };
        let (i_axis, last) = if q {
            (i.1, self.last_ab.1)
        } else {
            (i.0, self.last_ab.0)
        };
        // Alternating differences: the zig-zag adds up, a slow drift cancels.
        if self.k > RIPPLE_SKIP + 1 {
            let sign = if self.k & 1 == 0 { 1.0 } else { -1.0 };
            self.ripple_sum += sign * (i_axis - last);
        }
        // The loops hold the level on the mean of the last two samples, where the
        // zig-zag cancels.
        let mean = (0.5 * (i.0 + self.last_ab.0), 0.5 * (i.1 + self.last_ab.1));
        self.last_ab = i;
        let base = self.hold((self.level_target_a, 0.0), mean);
        if self.k > RIPPLE_SKIP + 1 + n {
            let d = libm::fabsf(self.ripple_sum) / n as f32;
            self.ripple_sum = 0.0;
            if trial {
                // Size ΔV for the aimed ripple (at most 8x the trial, within the limit).
                let want = RIPPLE_TARGET * self.level_target_a;
                let scale = if d > 0.0 { want / d } else { 8.0 };
                self.dv_v =
                    mras::min_f32(self.dv_v * mras::min_f32(scale, 8.0), self.ripple_room());
                self.enter(Stage::Ripple { q, trial: false });
            } else {
                let Some(l) = self.inductance(d) else {
                    return self.fail(IdentError::OutOfRange);
                };
                if q {
                    self.found = Identified {
                        r_ohm: self.r_ohm,
                        ld_h: self.ld_h,
                        lq_h: l,
                        v_inverter_v: self.level_v[1] - self.r_ohm * self.level_a[1],
                    };
                    self.enter(Stage::Release);
                    return self.hold((0.0, 0.0), i);
                }
                self.ld_h = l;
                self.dv_v /= 4.0;
                self.enter(Stage::Ripple {
                    q: true,
                    trial: true,
                });
            }
            return base;
        }
        let dv = if self.k & 1 == 0 {
            self.dv_v
        } else {
            -self.dv_v
        };
        if q {
            (base.0, base.1 + dv)
        } else {
            (base.0 + dv, base.1)
        }
    }

    /// L from the peak-to-peak ripple `d` of ±ΔV: `x = R·d/(2ΔV) = (1-a)/(1+a)`,
    /// `a = exp(-R·T/L)`.
    fn inductance(&self, d: f32) -> Option<f32> {
        let x = self.r_ohm * d / (2.0 * self.dv_v);
        if !(x > 0.0 && x < 1.0) {
            return None;
        }
        let a = (1.0 - x) / (1.0 + x);
        let l = -self.r_ohm * self.cfg.period_s / libm::logf(a);
        (l.is_finite() && l > L_RANGE_H.0 && l < L_RANGE_H.1).then_some(l)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The window's spans in periods read as its seconds did: the first p whose p·T
    /// reaches the span, for every rate a drive runs at.
    #[test]
    fn window_spans_in_periods_are_the_first_to_reach_the_seconds() {
        let first = |s: f32, t: f32| (0..u32::MAX).find(|&p| p as f32 * t >= s).unwrap();
        for hz in [
            8_000.0f32, 10_000.0, 16_000.0, 20_000.0, 24_000.0, 30_000.0, 40_000.0,
        ] {
            for t in [
                1.0 / hz,
                1.0 / hz * (1.0 + f32::EPSILON),
                1.0 / hz * (1.0 - f32::EPSILON),
            ] {
                let w = WindowPeriods::new(t);
                assert_eq!(w.moving, first(MIN_WINDOW_S, t), "{hz} Hz");
                assert_eq!(w.still, first(STILL_WINDOW_S, t), "{hz} Hz");
            }
        }
    }
}

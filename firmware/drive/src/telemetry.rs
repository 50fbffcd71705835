//! What the control period, the supervisor and the host exchange: the one schema.
//!
//! - [`Command`]: supervisor → control period, read every period (small, `Copy`).
//! - [`Telemetry`]: control period → supervisor, a snapshot taken at the supervisor's
//!   divider ticks only.
//! - [`Record`] and [`Event`]: supervisor → RTT stream (and hil-sim's stream file). The
//!   defmt format strings live in this module ([`log_line`], feature `defmt`), next to
//!   the field names the host decodes them by ([`RECORD_KEYS`], [`Event::fields`],
//!   [`SEQ_KEY`]), so that the firmware and the host cannot drift apart.
//!
//! Every line of ours starts with `seq`, its number since boot: init writes the banner
//! (`drive-fw: ...`, not ours), then the `mras-paths` line with [`INIT_SEQ`] (0); the
//! supervisor numbers its lines from 1 on in the order it writes them ([`Line`]). The
//! host counts a gap in `seq` as frames RTT dropped (defmt-rtt drops a frame that does
//! not fit whole), whatever line was lost; a new boot is the banner, or `seq` not
//! increasing where the banner was lost. (u32 lines at the supervisor's rate never
//! wrap in practice: 1.4 years at 100 lines a second.)

use crate::commissioning::{Adaptation, Cause, Setpoint, State};
use calib_record::Alignment;
use mras::{Coefficients, MAX_PATHS};

/// A fault the control period latched: the bridge is off from the faulted period on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The core refused a sample or lost lock.
    Sensor(mras::Fault),
    /// An ADC count above the converter's range: a misconfigured ADC, not the sensor.
    AdcOutOfRange,
    /// The break input (over-current comparator) fired; hardware already cleared MOE.
    OverCurrent,
}

/// Supervisor → control period, in force from the next period on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Command {
    pub setpoint: Setpoint,
    pub adaptation: Adaptation,
    /// The rotor's electrical zero as the sensor sees it (commissioned or loaded).
    pub alignment: Alignment,
    /// Measure the current sensors' zero while the bridge is off.
    pub calibrate_currents: bool,
    /// Measure the mean shift of the corrected angle against the raw one
    /// ([`Snapshot::corrected_offset_e_rad`]).
    pub measure_shift: bool,
    /// A value other than the last one seen releases a latched fault.
    pub release: u8,
    /// Learn the torque ripple fixed to the shaft angle from this period's lock
    /// ([`crate::ripple`]); what was learned is fed to the observer whether or not.
    pub learn_ripple: bool,
    /// Ride through sensor faults: the bridge is off only for periods without a locked
    /// estimate (`commissioning::Outputs::reacquire`).
    pub reacquire: bool,
    /// The motor's mechanical constants as identified or loaded; the control period puts
    /// a change in force (the motion loops, the torque constant and the observer's
    /// feed-forward).
    pub motion: MotionConstants,
}

/// The motor's mechanical constants in force ([`crate::spin`]); 0 in a field: not known,
/// the configuration's nominal one stays.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MotionConstants {
    /// Another value than the control period's last is a change to put in force (one
    /// byte to compare every period, not the constants).
    pub generation: u8,
    /// J/kt: the q current one rad/s² of acceleration takes (A·s²/rad).
    pub amps_per_accel_a_s2: f32,
    /// The permanent magnet's flux linkage ψ (Wb).
    pub flux_wb: f32,
    /// 1/ψ and kt/J, worked out by [`Self::changed`] (0 where their constant is not
    /// positive): the control period puts the constants in force without a division.
    pub per_flux_per_wb: f32,
    pub accel_per_amp_rad_a_s2: f32,
}

impl MotionConstants {
    pub const NOMINAL: Self = Self {
        generation: 0,
        amps_per_accel_a_s2: 0.0,
        flux_wb: 0.0,
        per_flux_per_wb: 0.0,
        accel_per_amp_rad_a_s2: 0.0,
    };

    /// `self` with `change` applied, the reciprocals worked out again, and a new
    /// generation.
    #[must_use]
    pub fn changed(self, change: impl FnOnce(&mut Self)) -> Self {
        let mut m = self;
        change(&mut m);
        let per = |v: f32| if v > 0.0 { 1.0 / v } else { 0.0 };
        m.per_flux_per_wb = per(m.flux_wb);
        m.accel_per_amp_rad_a_s2 = per(m.amps_per_accel_a_s2);
        m.generation = self.generation.wrapping_add(1);
        m
    }
}

impl Command {
    /// Bridge off, nothing adapts: the command before the supervisor's first step.
    pub const OFF: Self = Self {
        setpoint: Setpoint::Off,
        adaptation: Adaptation::Frozen,
        alignment: Alignment::IDENTITY,
        calibrate_currents: false,
        measure_shift: false,
        release: 0,
        learn_ripple: false,
        reacquire: false,
        motion: MotionConstants::NOMINAL,
    };
}

/// Coefficients handed to the control period (loaded from flash), acknowledged in
/// [`Telemetry::install`] with the same generation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Install {
    pub generation: u8,
    pub coefficients: Coefficients,
}

/// The control period's answer to an [`Install`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InstallAck {
    pub generation: u8,
    /// The core accepted them (paths match, values finite and in range).
    pub accepted: bool,
}

/// Result of the open-loop alignment sweep (see `crate::align`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepResult {
    /// Sensor periods travelled over one commanded sensor period (1 when the pole-pair
    /// count in force and the sensor periods are right; 0 when the rotor did not follow).
    pub ratio: f32,
    /// The motor's pole pairs as the travel gives them (`p_in_force / ratio`; finite,
    /// huge when the rotor did not follow), and the nearest count N divides.
    pub pole_pairs: f32,
    pub whole_pole_pairs: u16,
    /// The sensor's periods N the sweep ran with.
    pub sensor_periods: u16,
    /// The offset and direction for the count in force (which it names).
    pub alignment: Alignment,
}

/// min / mean / max of a per-period count (the firmware's DWT cycles of the control
/// interrupt), since the previous snapshot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleStats {
    pub min: u32,
    pub max: u32,
    pub sum: u64,
    pub count: u32,
}

impl CycleStats {
    pub const EMPTY: Self = Self {
        min: u32::MAX,
        max: 0,
        sum: 0,
        count: 0,
    };

    pub fn add(&mut self, c: u32) {
        self.min = self.min.min(c);
        self.max = self.max.max(c);
        self.sum += c as u64;
        self.count += 1;
    }

    pub fn merge(&mut self, o: &Self) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.sum += o.sum;
        self.count += o.count;
    }

    pub fn mean(&self) -> u32 {
        if self.count == 0 {
            0
        } else {
            (self.sum / self.count as u64) as u32
        }
    }

    /// The minimum, 0 when nothing was counted.
    pub fn min_or_zero(&self) -> u32 {
        if self.count == 0 {
            0
        } else {
            self.min
        }
    }
}

/// Control period → supervisor: what the control period knows at a divider tick. The
/// adaptation's figures are not in it: [`Snapshot::merged`] adds them outside the control
/// interrupt, so the snapshot it copies (and the copy taken under the lock it shares with
/// the supervisor) holds no coefficient set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Snapshot {
    /// Control periods since start.
    pub ticks: u32,
    /// The latched fault holding the bridge off, until the supervisor releases it.
    pub fault: Option<Fault>,
    /// The last [`Command::release`] the control period applied: a snapshot with an
    /// older one was taken before the supervisor's release reached it.
    pub release: u8,
    /// The core's latched fault set (`mras::Faults::bits`).
    pub core_faults: u8,
    /// Some period since the previous snapshot had no locked estimate: its sample was
    /// refused, or the core was (re-)acquiring its lock.
    pub unlocked: bool,
    /// θ̂ at this period's sample, mechanical, in the motor's frame (the sensor's
    /// direction of the alignment in force applied), in [0, 2π).
    pub theta_rad: f32,
    /// The observer's angle error ε at this sample, mechanical, in the motor's frame:
    /// `theta_rad + epsilon_rad` is the sensor vector's own angle (the decoupled
    /// vector's, so the raw sensor's while the coefficients are zero), with the sensor's
    /// error but none of the observer's lag ([`Snapshot::sensor_theta_rad`]).
    pub epsilon_rad: f32,
    /// ω̂ in the motor's frame (the sensor's direction applied), mechanical.
    pub omega_rad_s: f32,
    pub amplitude: f32,
    /// The alignment sweep's result, once it finished: worked out from `sweep_fit` by
    /// [`Snapshot::merged`], outside the control interrupt and its mask.
    pub sweep: Option<SweepResult>,
    /// The finished sweep's sums, as the control period holds them.
    pub sweep_fit: Option<crate::align::SweepFit>,
    /// The motor's identification (Pending until one ran).
    pub ident: crate::ident::IdentStatus,
    /// The mean shift of the corrected angle against the raw one as measured so far,
    /// with the alignment it moves ([`Snapshot::corrected_offset_e_rad`]).
    pub shift: Option<crate::align::ShiftReading>,
    /// The running integrals the motion's identification takes differences of
    /// ([`crate::spin`]): `∫iq dt` over the periods at the speed setpoint (A·s), and the back-EMF's d and q parts, `∫(vd − R·id + ωe·L·iq)/p dt` and
    /// `∫(vq − R·iq − ωe·L·id)/p dt`, over the periods coasting (Wb·rad).
    pub iq_integral_a_s: f32,
    pub flux_angle_wb_rad: [f32; 2],
    /// The current sensors' zero has been measured (or was never asked for).
    pub currents_ready: bool,
    /// Measured current zero is implausible (counts far from nominal).
    pub currents_implausible: bool,
    /// The control interrupt's cycles (firmware only; empty on the host).
    pub cycles: CycleStats,
    /// Samples the adaptation task never got since start (its queue was full: the task
    /// starved). Zero on a healthy drive; the coefficients then lag, nothing else.
    pub handoffs_dropped: u32,
    /// The adaptation's updates applied after the period they were due in, since start
    /// (the task missed its deadline, [`mras::UPDATE_LATENCY_PERIODS`]). Zero on a
    /// healthy drive.
    pub updates_late: u32,
}

impl Snapshot {
    /// The offset in force moved by the measured mean shift of the corrected angle
    /// against the raw one: the alignment for the corrected angle (once measured over
    /// enough samples). Worked out here, where it is read, not in the control interrupt.
    pub fn corrected_offset_e_rad(&self) -> Option<f32> {
        self.shift.and_then(|s| s.corrected_offset_e_rad())
    }

    /// Nothing measured yet: what the slot holds before the first snapshot.
    pub const EMPTY: Self = Self {
        ticks: 0,
        fault: None,
        release: 0,
        core_faults: 0,
        unlocked: false,
        theta_rad: 0.0,
        epsilon_rad: 0.0,
        omega_rad_s: 0.0,
        amplitude: 0.0,
        sweep: None,
        sweep_fit: None,
        ident: crate::ident::IdentStatus::Pending,
        shift: None,
        iq_integral_a_s: 0.0,
        flux_angle_wb_rad: [0.0; 2],
        currents_ready: false,
        currents_implausible: false,
        cycles: CycleStats::EMPTY,
        handoffs_dropped: 0,
        updates_late: 0,
    };

    /// The sensor vector's own angle (mechanical, motor frame, not wrapped: within ε of
    /// `theta_rad`).
    pub fn sensor_theta_rad(&self) -> f32 {
        self.theta_rad + self.epsilon_rad
    }
}

/// The supervisor's view at a divider tick: the control period's [`Snapshot`] with the
/// adaptation's figures ([`Snapshot::merged`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Telemetry {
    pub snapshot: Snapshot,
    pub converged: bool,
    pub revs: u32,
    /// Largest per-path residual (`mras::Convergence::residual_rad`).
    pub residual_max_rad: f32,
    pub coefficients: Coefficients,
    pub install: Option<InstallAck>,
    /// `crate::adaptation::AdaptReport::updates_dropped`.
    pub updates_dropped: u32,
}

/// Where the control period leaves its snapshots for the supervisor (an RTIC shared
/// resource in the firmware).
///
/// A supervisor's period that wakes the supervisor only marks its snapshot owed
/// ([`TelemetrySlot::owe`]); the supervisor writes it from the control period's state
/// ([`TelemetrySlot::take_into`]). Until the next control period starts, that state is
/// the period's own: the adaptation task between them does not touch it. A control
/// period that finds the snapshot still owed (the supervisor preempted past it) writes
/// it first, before anything changes that state ([`TelemetrySlot::settle_with`]); a
/// second one written before the supervisor read the first replaces it, keeping its
/// cycle statistics. Either way the snapshot is its period's, as if written there, but
/// the control interrupt no longer copies it on every supervisor's period (about 190
/// cycles off the longest of them). A tick whose supervisor is still busy (a flash
/// erase) owes nothing: what its snapshot would have restarted (the cycle statistics,
/// the loss of lock) runs on into the next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TelemetrySlot {
    unread: bool,
    owed: bool,
    snapshot: Snapshot,
}

impl Default for TelemetrySlot {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl TelemetrySlot {
    pub const EMPTY: Self = Self {
        unread: false,
        owed: false,
        snapshot: Snapshot::EMPTY,
    };

    /// A snapshot written by `write`, which sets every field.
    #[inline(always)]
    pub fn publish_with(&mut self, write: impl FnOnce(&mut Snapshot)) {
        let unread = self.unread.then_some(self.snapshot.cycles);
        write(&mut self.snapshot);
        if let Some(old) = unread {
            self.snapshot.cycles.merge(&old);
        }
        self.unread = true;
    }

    /// A supervisor's period has ended: its snapshot is owed, to be written from the
    /// control period's state before the next control period changes it.
    #[inline(always)]
    pub fn owe(&mut self) {
        self.owed = true;
    }

    /// At the start of a control period, before anything else: the snapshot still owed
    /// is written now (`write` reads the state the last period left).
    #[inline(always)]
    pub fn settle_with(&mut self, write: impl FnOnce(&mut Snapshot)) {
        if self.owed {
            self.owed = false;
            self.publish_with(write);
        }
    }

    /// The supervisor's read, into `out` (`false`: nothing unread, `out` untouched):
    /// the owed snapshot written by `write` from the control period's state (which must
    /// not have moved since the period that owed it), or else the unread one. The owed
    /// one goes straight into `out`, not through the slot: the firmware reads it with
    /// the control interrupt masked, and a second copy doubled that.
    #[inline(always)]
    pub fn take_into(&mut self, out: &mut Snapshot, write: impl FnOnce(&mut Snapshot)) -> bool {
        if core::mem::take(&mut self.owed) {
            write(out);
            if core::mem::take(&mut self.unread) {
                out.cycles.merge(&self.snapshot.cycles);
            }
            true
        } else if core::mem::take(&mut self.unread) {
            *out = self.snapshot;
            true
        } else {
            false
        }
    }
}

/// One line of the coefficient stream (every [`crate::supervisor::RECORD_DIVIDER`]-th
/// supervisor step), from the snapshot of the control period numbered
/// `t_ms · control rate / 1000` (its `Snapshot::ticks`).
///
/// Time: `t_ms` counts the control periods run, exact at the supervisor's divider ticks.
/// The first period's sample is at `t_ms` = 0 on that clock, so this record's sample, the
/// instant of `theta_rad` and `omega_rad_s`, is one control period before `t_ms`
/// (`t_ms/1000 - 1/f_pwm` seconds after the first sample; a period the firmware missed
/// does not count).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    pub t_ms: u32,
    pub state: State,
    /// The core's latched fault bits.
    pub faults: u8,
    /// θ̂ at the sample, mechanical, in [0, 2π), in the motor's frame: that of
    /// `omega_rad_s`, the sensor's angle with the direction of the alignment in force
    /// applied (forward until the sweep measured it), its zero the sensor's (the
    /// alignment's offset is electrical, not applied). A reference encoder reads it as
    /// `θ + c` mod 2π/N for a constant c of the mounting, N the sensor's periods.
    pub theta_rad: f32,
    /// ω̂ at the sample, mechanical, in the motor's frame (rad/s).
    pub omega_rad_s: f32,
    pub amplitude: f32,
    pub converged: bool,
    pub revs: u32,
    pub residual_max_rad: f32,
    pub cycles_max: u32,
    pub cycles_mean: u32,
    pub cycles_min: u32,
    /// Losses since boot (every one zero on a healthy drive): samples the adaptation
    /// task never got ([`Snapshot::handoffs_dropped`]), its updates the queue could not
    /// take when made (`AdaptReport::updates_dropped`) or applied after their period
    /// ([`Snapshot::updates_late`]), and events a supervisor step could not hold
    /// (`Supervisor::events_dropped`).
    pub handoffs_dropped: u32,
    pub updates_dropped: u32,
    pub updates_late: u32,
    pub events_dropped: u32,
    /// Re and im of each path, in configuration order; unused paths are 0.
    pub coef: [f32; 2 * MAX_PATHS],
}

impl Record {
    /// The coefficients' values as the stream carries them.
    pub fn coef_of(c: &Coefficients) -> [f32; 2 * MAX_PATHS] {
        let mut out = [0.0; 2 * MAX_PATHS];
        for (pair, (_, v)) in out.chunks_exact_mut(2).zip(c.iter()) {
            pair[0] = v.re;
            pair[1] = v.im;
        }
        out
    }
}

/// Field names of a `mras` record line after [`SEQ_KEY`], in stream order; the host
/// decodes by them. `coef` carries `2 * MAX_PATHS` values.
pub const RECORD_KEYS: [&str; 17] = [
    "t_ms",
    "state",
    "faults",
    "theta_rad",
    "omega_rad_s",
    "amplitude",
    "converged",
    "revs",
    "residual_max_rad",
    "cycles_max",
    "cycles_mean",
    "cycles_min",
    "handoffs_dropped",
    "updates_dropped",
    "updates_late",
    "events_dropped",
    "coef",
];

/// The first field of every line of ours: its number since boot (see the module's doc).
pub const SEQ_KEY: &str = "seq";
/// The `seq` of init's `mras-paths` line; the supervisor's lines follow from 1.
pub const INIT_SEQ: u32 = 0;

/// A line the supervisor task writes, in stream order (`crate::supervisor::Output::lines`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Line {
    /// A new `mras-paths` line: the core's bank changed.
    Paths(mras::Bank),
    Event(Event),
    Record(Record),
}

/// Something that happened, streamed when it happens.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// Entered a state (other than Safe).
    State { t_ms: u32, state: State },
    /// Entered the safe state from `state`, because of `cause`.
    Fault {
        t_ms: u32,
        cause: Cause,
        state: State,
    },
    /// The stored calibration was loaded and accepted by the core.
    Loaded { t_ms: u32, sequence: u32 },
    /// No usable stored calibration (the reason's name): commissioning.
    NotLoaded { t_ms: u32, reason: &'static str },
    /// A calibration was written.
    Stored { t_ms: u32 },
    /// A store failed (the previous record is intact); the reason's name.
    StoreFailed { t_ms: u32, reason: &'static str },
    /// The alignment sweep's measurement: the sensor's travel over one commanded
    /// sensor period (`ratio`), and the pole pairs put in force with the offset (another
    /// count than before is swept again).
    Aligned {
        t_ms: u32,
        offset_e_rad: f32,
        reversed: bool,
        ratio: f32,
        pole_pairs: u16,
    },
    /// The offset moved onto the corrected angle, after adaptation.
    OffsetCorrected { t_ms: u32, offset_e_rad: f32 },
    /// The refined coefficients went to the control period: the refinements' mean |ω̂|
    /// (the second 0 with one speed), and the largest |coefficient| the separation took
    /// out of the first speed's mean as the rotor's motion (relative to |Z|, about the
    /// angle error in rad; 0 with one speed).
    Refined {
        t_ms: u32,
        speed_rad_s: f32,
        second_speed_rad_s: f32,
        motion_max: f32,
    },
    /// The motor's constants, identified ([`crate::ident::Identified`]); the current loop
    /// is designed on them from then on.
    Identified {
        t_ms: u32,
        r_ohm: f32,
        ld_h: f32,
        lq_h: f32,
        v_inverter_v: f32,
    },
    /// The motor's mechanical constants in force from now on: identified in this
    /// commissioning (at Verify's end, [`crate::spin`]) or loaded with the calibration.
    Motion {
        t_ms: u32,
        flux_wb: f32,
        inertia_kg_m2: f32,
        /// Friction: its viscous and its constant part, as fitted (their sum at the
        /// commissioning speed is what one speed region determines well).
        viscous_nm_s_rad: f32,
        coulomb_nm: f32,
    },
}

/// A value of a streamed field, as its defmt parameter carries it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FieldValue {
    U32(u32),
    U16(u16),
    U8(u8),
    F32(f32),
    Bool(bool),
    Str(&'static str),
}

impl Record {
    /// The record's fields in stream order, named by [`RECORD_KEYS`] (`coef` once per
    /// value): the order of [`log_line`]'s parameters after `seq`.
    pub fn fields(&self) -> impl Iterator<Item = (&'static str, FieldValue)> + '_ {
        use FieldValue::*;
        let head = [
            U32(self.t_ms),
            Str(self.state.name()),
            U8(self.faults),
            F32(self.theta_rad),
            F32(self.omega_rad_s),
            F32(self.amplitude),
            Bool(self.converged),
            U32(self.revs),
            F32(self.residual_max_rad),
            U32(self.cycles_max),
            U32(self.cycles_mean),
            U32(self.cycles_min),
            U32(self.handoffs_dropped),
            U32(self.updates_dropped),
            U32(self.updates_late),
            U32(self.events_dropped),
        ];
        RECORD_KEYS
            .iter()
            .copied()
            .zip(head)
            .chain(self.coef.iter().map(|c| ("coef", F32(*c))))
    }
}

/// Most fields an event line has.
pub const MAX_EVENT_FIELDS: usize = 5;

impl Event {
    /// Whether this is a fault (the safe state's entry): never dropped from a step's
    /// events (`crate::supervisor::Events`).
    pub fn is_fault(&self) -> bool {
        matches!(self, Event::Fault { .. })
    }

    /// The line's marker (its first word), as [`log_line`] prints it.
    pub fn kind(&self) -> &'static str {
        match self {
            Event::State { .. } => "mras-state",
            Event::Fault { .. } => "mras-fault",
            Event::Loaded { .. } => "mras-loaded",
            Event::NotLoaded { .. } => "mras-not-loaded",
            Event::Stored { .. } => "mras-stored",
            Event::StoreFailed { .. } => "mras-store-failed",
            Event::Aligned { .. } => "mras-aligned",
            Event::OffsetCorrected { .. } => "mras-offset-corrected",
            Event::Refined { .. } => "mras-refined",
            Event::Identified { .. } => "mras-identified",
            Event::Motion { .. } => "mras-motion",
        }
    }

    /// The fields in the order of [`log_line`]'s parameters after `seq`.
    pub fn fields(&self) -> heapless::Vec<(&'static str, FieldValue), MAX_EVENT_FIELDS> {
        use FieldValue::*;
        let mut v = heapless::Vec::new();
        let fields: &[(&'static str, FieldValue)] = match *self {
            Event::State { t_ms, state } => &[("state", Str(state.name())), ("t_ms", U32(t_ms))],
            Event::Fault { t_ms, cause, state } => &[
                ("cause", Str(cause_name(cause))),
                ("state", Str(state.name())),
                ("t_ms", U32(t_ms)),
            ],
            Event::Loaded { t_ms, sequence } => &[("sequence", U32(sequence)), ("t_ms", U32(t_ms))],
            Event::NotLoaded { t_ms, reason } | Event::StoreFailed { t_ms, reason } => {
                &[("reason", Str(reason)), ("t_ms", U32(t_ms))]
            }
            Event::Stored { t_ms } => &[("t_ms", U32(t_ms))],
            Event::Aligned {
                t_ms,
                offset_e_rad,
                reversed,
                ratio,
                pole_pairs,
            } => &[
                ("offset_e_rad", F32(offset_e_rad)),
                ("reversed", Bool(reversed)),
                ("ratio", F32(ratio)),
                ("pole_pairs", U16(pole_pairs)),
                ("t_ms", U32(t_ms)),
            ],
            Event::OffsetCorrected { t_ms, offset_e_rad } => {
                &[("offset_e_rad", F32(offset_e_rad)), ("t_ms", U32(t_ms))]
            }
            Event::Refined {
                t_ms,
                speed_rad_s,
                second_speed_rad_s,
                motion_max,
            } => &[
                ("speed_rad_s", F32(speed_rad_s)),
                ("second_speed_rad_s", F32(second_speed_rad_s)),
                ("motion_max", F32(motion_max)),
                ("t_ms", U32(t_ms)),
            ],
            Event::Identified {
                t_ms,
                r_ohm,
                ld_h,
                lq_h,
                v_inverter_v,
            } => &[
                ("r_ohm", F32(r_ohm)),
                ("ld_h", F32(ld_h)),
                ("lq_h", F32(lq_h)),
                ("v_inverter_v", F32(v_inverter_v)),
                ("t_ms", U32(t_ms)),
            ],
            Event::Motion {
                t_ms,
                flux_wb,
                inertia_kg_m2,
                viscous_nm_s_rad,
                coulomb_nm,
            } => &[
                ("flux_wb", F32(flux_wb)),
                ("inertia_kg_m2", F32(inertia_kg_m2)),
                ("viscous_nm_s_rad", F32(viscous_nm_s_rad)),
                ("coulomb_nm", F32(coulomb_nm)),
                ("t_ms", U32(t_ms)),
            ],
        };
        for f in fields {
            // At most MAX_EVENT_FIELDS by construction.
            let _ = v.push(*f);
        }
        v
    }
}

/// Names of the causes as streamed (`mras-fault cause=...`).
pub fn cause_name(c: Cause) -> &'static str {
    match c {
        Cause::Sensor(f) => fault_name(Fault::Sensor(f)),
        Cause::AdcOutOfRange => "AdcOutOfRange",
        Cause::OverCurrent => "OverCurrent",
        Cause::CurrentSensor => "CurrentSensor",
        Cause::Identify(e) => e.name(),
        Cause::BadInput => "BadInput",
        Cause::Timeout(_) => "Timeout",
        Cause::NoRotation => "NoRotation",
        Cause::PolePairs => "PolePairs",
        Cause::VerifyFailed => "VerifyFailed",
        Cause::LoadRefused => "LoadRefused",
        Cause::RefineFailed => "RefineFailed",
        Cause::StoreFailed => "StoreFailed",
        Cause::Watchdog => "Watchdog",
        Cause::HardFault => "HardFault",
        Cause::Panic => "Panic",
    }
}

/// Names of the control period's faults.
pub fn fault_name(f: Fault) -> &'static str {
    match f {
        Fault::Sensor(mras::Fault::NonFiniteInput) => "NonFiniteInput",
        Fault::Sensor(mras::Fault::SensorLost) => "SensorLost",
        Fault::Sensor(mras::Fault::SensorSaturated) => "SensorSaturated",
        Fault::Sensor(mras::Fault::LossOfLock) => "LossOfLock",
        Fault::Sensor(mras::Fault::NumericalOverflow) => "NumericalOverflow",
        Fault::AdcOutOfRange => "AdcOutOfRange",
        Fault::OverCurrent => "OverCurrent",
    }
}

/// A line of the supervisor task, numbered `seq`. The stream's format strings, here only.
#[cfg(feature = "defmt")]
pub fn log_line(seq: u32, l: &Line) {
    match l {
        Line::Paths(b) => log_paths(seq, &bank_names(b.as_slice())),
        Line::Event(e) => log_event(seq, e),
        Line::Record(r) => log_record(seq, r),
    }
}

#[cfg(feature = "defmt")]
fn log_record(seq: u32, r: &Record) {
    const _: () = assert!(2 * MAX_PATHS == 32, "one placeholder per coef value");
    let c = &r.coef;
    defmt::info!(
        "mras seq={=u32} t_ms={=u32} state={=str} faults={=u8} theta_rad={=f32} omega_rad_s={=f32} amplitude={=f32} converged={=bool} revs={=u32} residual_max_rad={=f32} cycles_max={=u32} cycles_mean={=u32} cycles_min={=u32} handoffs_dropped={=u32} updates_dropped={=u32} updates_late={=u32} events_dropped={=u32} coef={=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32},{=f32}",
        seq,
        r.t_ms,
        r.state.name(),
        r.faults,
        r.theta_rad,
        r.omega_rad_s,
        r.amplitude,
        r.converged,
        r.revs,
        r.residual_max_rad,
        r.cycles_max,
        r.cycles_mean,
        r.cycles_min,
        r.handoffs_dropped,
        r.updates_dropped,
        r.updates_late,
        r.events_dropped,
        c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7],
        c[8], c[9], c[10], c[11], c[12], c[13], c[14], c[15],
        c[16], c[17], c[18], c[19], c[20], c[21], c[22], c[23],
        c[24], c[25], c[26], c[27], c[28], c[29], c[30], c[31]
    );
}

#[cfg(feature = "defmt")]
fn log_event(seq: u32, e: &Event) {
    match *e {
        Event::State { t_ms, state } => defmt::info!(
            "mras-state seq={=u32} state={=str} t_ms={=u32}",
            seq,
            state.name(),
            t_ms
        ),
        Event::Fault { t_ms, cause, state } => defmt::error!(
            "mras-fault seq={=u32} cause={=str} state={=str} t_ms={=u32}",
            seq,
            cause_name(cause),
            state.name(),
            t_ms
        ),
        Event::Loaded { t_ms, sequence } => defmt::info!(
            "mras-loaded seq={=u32} sequence={=u32} t_ms={=u32}",
            seq,
            sequence,
            t_ms
        ),
        Event::NotLoaded { t_ms, reason } => defmt::info!(
            "mras-not-loaded seq={=u32} reason={=str} t_ms={=u32}",
            seq,
            reason,
            t_ms
        ),
        Event::Stored { t_ms } => defmt::info!("mras-stored seq={=u32} t_ms={=u32}", seq, t_ms),
        Event::StoreFailed { t_ms, reason } => defmt::error!(
            "mras-store-failed seq={=u32} reason={=str} t_ms={=u32}",
            seq,
            reason,
            t_ms
        ),
        Event::Aligned {
            t_ms,
            offset_e_rad,
            reversed,
            ratio,
            pole_pairs,
        } => defmt::info!(
            "mras-aligned seq={=u32} offset_e_rad={=f32} reversed={=bool} ratio={=f32} pole_pairs={=u16} t_ms={=u32}",
            seq,
            offset_e_rad,
            reversed,
            ratio,
            pole_pairs,
            t_ms
        ),
        Event::OffsetCorrected { t_ms, offset_e_rad } => defmt::info!(
            "mras-offset-corrected seq={=u32} offset_e_rad={=f32} t_ms={=u32}",
            seq,
            offset_e_rad,
            t_ms
        ),
        Event::Refined {
            t_ms,
            speed_rad_s,
            second_speed_rad_s,
            motion_max,
        } => defmt::info!(
            "mras-refined seq={=u32} speed_rad_s={=f32} second_speed_rad_s={=f32} motion_max={=f32} t_ms={=u32}",
            seq,
            speed_rad_s,
            second_speed_rad_s,
            motion_max,
            t_ms
        ),
        Event::Identified {
            t_ms,
            r_ohm,
            ld_h,
            lq_h,
            v_inverter_v,
        } => defmt::info!(
            "mras-identified seq={=u32} r_ohm={=f32} ld_h={=f32} lq_h={=f32} v_inverter_v={=f32} t_ms={=u32}",
            seq,
            r_ohm,
            ld_h,
            lq_h,
            v_inverter_v,
            t_ms
        ),
        Event::Motion {
            t_ms,
            flux_wb,
            inertia_kg_m2,
            viscous_nm_s_rad,
            coulomb_nm,
        } => defmt::info!(
            "mras-motion seq={=u32} flux_wb={=f32} inertia_kg_m2={=f32} viscous_nm_s_rad={=f32} coulomb_nm={=f32} t_ms={=u32}",
            seq,
            flux_wb,
            inertia_kg_m2,
            viscous_nm_s_rad,
            coulomb_nm,
            t_ms
        ),
    }
}

/// The path names line, at boot ([`INIT_SEQ`]) and whenever the bank changes: names the
/// `coef` columns of the records that follow.
#[cfg(feature = "defmt")]
pub fn log_paths(seq: u32, names: &str) {
    defmt::info!("mras-paths seq={=u32} paths={=str}", seq, names);
}

/// A path's name in the stream and in CSV columns: `offset`, `amplitude_quadrature`,
/// `h<h>` (e.g. `h4`, `h-2`).
pub fn write_path_name(kind: mras::PathKind, w: &mut impl core::fmt::Write) -> core::fmt::Result {
    match kind {
        mras::PathKind::Offset => w.write_str("offset"),
        mras::PathKind::AmplitudeQuadrature => w.write_str("amplitude_quadrature"),
        mras::PathKind::Harmonic(h) => write!(w, "h{h}"),
    }
}

/// The comma-separated path names of a configuration (the `mras-paths` line).
pub fn path_names(cfg: &mras::Config) -> heapless::String<128> {
    bank_names(cfg.paths())
}

/// The comma-separated names of a bank's paths.
pub fn bank_names(paths: &[mras::PathKind]) -> heapless::String<128> {
    let mut s = heapless::String::new();
    for (i, k) in paths.iter().enumerate() {
        // A bank's names fit: `offset`, `amplitude_quadrature` and 14 of at most 4
        // characters (`h-15`) with their commas are 97: the writes cannot fail.
        if i > 0 {
            let _ = s.push(',');
        }
        let _ = write_path_name(*k, &mut s);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stand-in for the control period's state: its tick and the cycles since the
    /// last snapshot, restarted by each snapshot written, as `write_snapshot` does.
    struct Period {
        ticks: u32,
        cycles: CycleStats,
    }

    impl Period {
        fn run(&mut self, c: u32) {
            self.ticks += 1;
            self.cycles.add(c);
        }

        fn write(&mut self, s: &mut Snapshot) {
            *s = Snapshot {
                ticks: self.ticks,
                cycles: self.cycles,
                ..Snapshot::EMPTY
            };
            self.cycles = CycleStats::EMPTY;
        }
    }

    #[test]
    fn the_supervisor_gets_the_owing_periods_snapshot_whoever_writes_it() {
        let mut p = Period {
            ticks: 0,
            cycles: CycleStats::EMPTY,
        };
        let mut slot = TelemetrySlot::EMPTY;
        let mut out = Snapshot::EMPTY;
        // Nothing owed, nothing unread.
        assert!(!slot.take_into(&mut out, |s| p.write(s)));
        // Read by the supervisor before the next period: written from the state.
        p.run(100);
        slot.owe();
        assert!(slot.take_into(&mut out, |s| p.write(s)));
        assert_eq!((out.ticks, out.cycles.count), (1, 1));
        assert!(!slot.take_into(&mut out, |s| p.write(s)));
        // The supervisor preempted past the next period: that period writes it first,
        // and the supervisor reads the owing period's.
        p.run(200);
        slot.owe();
        slot.settle_with(|s| p.write(s));
        p.run(300);
        slot.settle_with(|s| p.write(s));
        assert!(slot.take_into(&mut out, |s| p.write(s)));
        assert_eq!((out.ticks, out.cycles.count, out.cycles.max), (2, 1, 200));
        // Two owed before a read: the second replaces the first, keeping its cycles.
        slot.owe();
        slot.settle_with(|s| p.write(s));
        p.run(400);
        slot.owe();
        slot.settle_with(|s| p.write(s));
        assert!(slot.take_into(&mut out, |s| p.write(s)));
        assert_eq!(
            (out.ticks, out.cycles.count, out.cycles.min, out.cycles.max),
            (4, 2, 300, 400)
        );
    }
}

//! The supervisor: the commissioning state machine, the calibration in flash, and what
//! the stream reports. The firmware's supervisor task and hil-sim both call
//! [`Supervisor::step`] with a [`Telemetry`] snapshot and the flash; they apply the
//! returned [`Command`] and [`Install`] to the control period and stream the record and
//! events.
//!
//! A load is reported only once the control period has accepted the coefficients (its
//! [`crate::telemetry::InstallAck`]); a store writes the coefficients of the snapshot
//! together with the alignment in force. Flash operations block the caller for their
//! duration (a page erase is tens of milliseconds): the control period keeps running
//! meanwhile, at a higher priority, on the command in force.
//!
//! A step's events are bounded ([`Events`]): one that does not fit is dropped and
//! counted ([`Supervisor::events_dropped`], streamed in every record), except a fault,
//! which is never dropped. The stream's lines are numbered ([`Output::lines`]).

use crate::commissioning::{
    Cause, Commissioning, Inputs, LoadStatus, Params, RefineStatus, Request, State, StoreStatus,
};
use crate::control::MotorConfig;
use crate::ident::IdentStatus;
use crate::refine::{separate, CoefficientMean, RefineError, Refined};
use crate::telemetry::{
    Command, Event, Install, Line, MotionConstants, Record, Telemetry, INIT_SEQ,
};
use calib_record::{Alignment, Calibration, FlashSlots, MotorConstants, StoreError};
use heapless::Vec;
use mras::{Bank, Coefficients};

/// What an [`Install`] in flight is for.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Awaiting {
    /// A record loaded from flash (its sequence number, for the event, and its motor).
    Load {
        generation: u8,
        sequence: u32,
        motor: MotorConstants,
    },
    /// The refined coefficients.
    Refined { generation: u8 },
}

/// A record every this many supervisor steps: every 11 ms at a 1 kHz supervisor (about
/// 91 Hz). A prime number of milliseconds, so that at a round speed (10 rev/s, say)
/// successive records fall on many rotor angles instead of the same ten: a host that
/// scores the streamed θ̂ against a reference encoder sees the whole revolution.
pub const RECORD_DIVIDER: u32 = 11;

/// Events one step holds besides a boot fault: twice the most a step of the
/// commissioning produces (an event of the state's request or of a store, and the state
/// change).
pub const MAX_EVENTS: usize = 4;

/// A step's events, bounded. The fault of a boot ([`Supervisor::boot_fault`]) has its
/// own slot; the others hold up to `E`. A step's own fault (at most one: it enters the
/// safe state once) that finds them full takes the place of the newest event that is
/// not a fault; any other event that does not fit is dropped. Each dropped event is
/// counted ([`Events::dropped`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Events<const E: usize = MAX_EVENTS> {
    boot: Option<Event>,
    list: Vec<Event, E>,
    dropped: u32,
}

impl<const E: usize> Default for Events<E> {
    fn default() -> Self {
        Self {
            boot: None,
            list: Vec::new(),
            dropped: 0,
        }
    }
}

impl<const E: usize> Events<E> {
    /// Add `e` by the rule above.
    pub fn push(&mut self, e: Event) {
        let Err(e) = self.list.push(e) else {
            return;
        };
        self.dropped = self.dropped.saturating_add(1);
        if e.is_fault() {
            // The list holds no other fault of this step: E >= 1 non-faults, the newest
            // last (replaced in place: a removal would pull in a memmove).
            if let Some(slot) = self.list.iter_mut().rev().find(|x| !x.is_fault()) {
                *slot = e;
            }
        }
    }

    /// In stream order: the boot fault, then the step's.
    pub fn iter(&self) -> impl Iterator<Item = &Event> + '_ {
        self.into_iter()
    }

    pub fn len(&self) -> usize {
        self.boot.is_some() as usize + self.list.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Events this step could not hold.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }
}

impl<'a, const E: usize> IntoIterator for &'a Events<E> {
    type Item = &'a Event;
    type IntoIter = core::iter::Chain<core::option::Iter<'a, Event>, core::slice::Iter<'a, Event>>;
    fn into_iter(self) -> Self::IntoIter {
        self.boot.iter().chain(self.list.iter())
    }
}

/// A flash error's name for the stream.
pub trait NamedError {
    fn name(&self) -> &'static str;
}

/// What one step produces.
#[derive(Clone, Debug, PartialEq)]
pub struct Output<const E: usize = MAX_EVENTS> {
    pub command: Command,
    /// Coefficients for the control period to install (once per load).
    pub install: Option<Install>,
    /// A stream record, every [`RECORD_DIVIDER`] steps.
    pub record: Option<Record>,
    pub events: Events<E>,
    /// The core's bank changed (a bank from the data grew, or a record's was installed):
    /// stream a new `mras-paths` line before the record, as init streams the first.
    pub paths: Option<Bank>,
    /// The `seq` of this step's first line.
    pub first_seq: u32,
}

impl<const E: usize> Output<E> {
    /// The lines to stream, in order, each with its `seq`: the new bank's names, the
    /// events, the record.
    pub fn lines(&self) -> impl Iterator<Item = (u32, Line)> + '_ {
        let paths = self.paths.map(Line::Paths);
        let events = self.events.iter().map(|e| Line::Event(*e));
        let lines = paths
            .into_iter()
            .chain(events)
            .chain(self.record.map(Line::Record));
        let first = self.first_seq;
        lines
            .enumerate()
            .map(move |(k, l)| (first.wrapping_add(k as u32), l))
    }

    fn line_count(&self) -> u32 {
        self.lines().count() as u32
    }
}

/// The supervisor; `E`: the events one step holds besides a boot fault ([`Events`]).
#[derive(Clone, Debug)]
pub struct Supervisor<const E: usize = MAX_EVENTS> {
    sm: Commissioning,
    dt_s: f32,
    control_rate_hz: u32,
    cfg_hash: u32,
    /// The configured pole pairs (in force until an alignment carries a count), and the
    /// sensor's periods N, which must divide a count put in force.
    configured_pole_pairs: u16,
    sensor_periods: u16,
    alignment: Alignment,
    /// The motor's constants as identified or loaded (the configured ones until then),
    /// and what the control period is told of them.
    motor: MotorConstants,
    motion: MotionConstants,
    load: LoadStatus,
    store: StoreStatus,
    refine: RefineStatus,
    /// The coefficients' mean over each refinement (at the commissioning speed, and at
    /// the second speed), and why the refined coefficients could not be formed.
    means: [CoefficientMean; 2],
    refine_error: Option<RefineError>,
    generation: u8,
    /// The install the control period has yet to answer.
    awaiting: Option<Awaiting>,
    release: u8,
    store_requested: bool,
    /// The state last streamed.
    last_state: State,
    /// Restarted since the last step: its state (the sequence's first) is streamed.
    restarted: bool,
    steps: u32,
    /// The boot fault, for the next step's events.
    boot_event: Option<Event>,
    /// The bank of the coefficients last seen (None before the first report).
    bank: Option<Bank>,
    events_dropped: u32,
    /// The `seq` of the next line.
    next_seq: u32,
}

impl Supervisor {
    /// `cfg_hash`: the control period's `calibration_hash` (the core's configuration,
    /// the motor and the sensor's scaling); `control_rate_hz` and `divider`: the control
    /// rate and the control periods per supervisor step; `motor`: the control period's
    /// configured motor (its pole pairs, and the constants a calibration stores where the
    /// motor is not identified); `sensor_periods`: the core's N.
    pub fn new(
        params: Params,
        cfg_hash: u32,
        control_rate_hz: u32,
        divider: u32,
        motor: &MotorConfig,
        sensor_periods: u16,
    ) -> Self {
        Self::with_event_room(
            params,
            cfg_hash,
            control_rate_hz,
            divider,
            motor,
            sensor_periods,
        )
    }
}

impl<const E: usize> Supervisor<E> {
    /// [`Supervisor::new`] whose steps hold `E` events besides a boot fault.
    pub fn with_event_room(
        params: Params,
        cfg_hash: u32,
        control_rate_hz: u32,
        divider: u32,
        motor: &MotorConfig,
        sensor_periods: u16,
    ) -> Self {
        const { assert!(E >= 1, "a step's fault needs an event to take the place of") };
        let divider = divider.max(1);
        Self {
            sm: Commissioning::new(params),
            dt_s: divider as f32 / control_rate_hz.max(1) as f32,
            control_rate_hz: control_rate_hz.max(1),
            cfg_hash,
            configured_pole_pairs: motor.pole_pairs,
            sensor_periods,
            alignment: Alignment::IDENTITY,
            motor: MotorConstants {
                r_ohm: motor.r_ohm,
                ld_h: motor.l_h,
                lq_h: motor.l_h,
                v_inverter_v: 0.0,
                flux_wb: motor.flux_wb,
                inertia_kg_m2: motor.inertia_kg_m2,
                viscous_nm_s_rad: 0.0,
                coulomb_nm: 0.0,
            },
            motion: MotionConstants::NOMINAL,
            load: LoadStatus::Pending,
            store: StoreStatus::Pending,
            refine: RefineStatus::Pending,
            means: [CoefficientMean::default(); 2],
            refine_error: None,
            generation: 0,
            awaiting: None,
            release: 0,
            store_requested: false,
            last_state: State::CheckSensor,
            restarted: false,
            steps: 0,
            boot_event: None,
            bank: None,
            events_dropped: 0,
            next_seq: INIT_SEQ + 1,
        }
    }

    pub fn state(&self) -> State {
        self.sm.state()
    }

    pub fn cause(&self) -> Option<Cause> {
        self.sm.cause()
    }

    /// Whether Run uses a calibration loaded from flash.
    pub fn calibration_loaded(&self) -> bool {
        self.sm.calibration_loaded()
    }

    /// Why the refined coefficients could not be formed (the drive is then in the safe
    /// state with [`Cause::RefineFailed`]); `None` if they were, or the core refused them.
    pub fn refine_error(&self) -> Option<RefineError> {
        self.refine_error
    }

    /// The refinements' means so far (at the commissioning speed, at the second speed).
    pub fn refinements(&self) -> [Option<Refined>; 2] {
        self.means.map(|m| m.mean().ok())
    }

    /// The alignment in force.
    pub fn alignment(&self) -> Alignment {
        self.alignment
    }

    /// The motor's constants as identified or loaded (the configured ones until then; 0
    /// for what the configuration does not hold).
    pub fn motor(&self) -> MotorConstants {
        self.motor
    }

    /// The reason the previous run ended (watchdog, HardFault, panic), found at boot:
    /// start in the safe state and report it in the next step's events (one reason: a
    /// second call before that step replaces the first).
    pub fn boot_fault(&mut self, cause: Cause) {
        self.sm.force_safe(cause);
        self.last_state = State::Safe;
        self.boot_event = Some(Event::Fault {
            t_ms: 0,
            cause,
            state: State::CheckSensor,
        });
    }

    /// Events the steps could not hold since start ([`Events`]); never a fault.
    pub fn events_dropped(&self) -> u32 {
        self.events_dropped
    }

    /// The operator asks to store the calibration in force (in Run): drift tracked
    /// since commissioning is kept across power cycles.
    pub fn request_store(&mut self) {
        self.store_requested = true;
    }

    /// Start over from the sensor check; releases the control period's latch.
    pub fn restart(&mut self) {
        self.sm.restart();
        self.restarted = true;
        self.release = self.release.wrapping_add(1);
        self.load = LoadStatus::Pending;
        self.store = StoreStatus::Pending;
        self.refine = RefineStatus::Pending;
        self.means = [CoefficientMean::default(); 2];
        self.refine_error = None;
        self.awaiting = None;
        self.alignment = Alignment::IDENTITY;
    }

    fn t_ms(&self, tm: &Telemetry) -> u32 {
        (tm.snapshot.ticks as u64 * 1000 / self.control_rate_hz as u64) as u32
    }

    /// One step on the latest snapshot.
    pub fn step<F>(&mut self, tm: &Telemetry, flash: &mut F) -> Output<E>
    where
        F: FlashSlots,
        F::Error: NamedError,
    {
        let t_ms = self.t_ms(tm);
        let mut events = Events::<E> {
            boot: self.boot_event.take(),
            ..Events::default()
        };
        if core::mem::take(&mut self.restarted) {
            // Streamed now, so that a fault in this very step is a change from it.
            let state = self.sm.state();
            events.push(Event::State { t_ms, state });
            self.last_state = state;
        }
        let mut install = None;

        // The control period's answer to an install.
        match (self.awaiting, tm.install) {
            (
                Some(Awaiting::Load {
                    generation,
                    sequence,
                    motor,
                }),
                Some(ack),
            ) if ack.generation == generation => {
                self.awaiting = None;
                self.load = if ack.accepted {
                    events.push(Event::Loaded { t_ms, sequence });
                    self.motor = motor;
                    let per_accel = motor.inertia_kg_m2 / self.torque_constant();
                    self.motion = self.motion.changed(|m| {
                        (m.amps_per_accel_a_s2, m.flux_wb) = (per_accel, motor.flux_wb)
                    });
                    events.push(self.motion_event(t_ms));
                    LoadStatus::Loaded
                } else {
                    LoadStatus::Refused
                };
            }
            (Some(Awaiting::Refined { generation }), Some(ack)) if ack.generation == generation => {
                self.awaiting = None;
                self.refine = if ack.accepted {
                    RefineStatus::Installed
                } else {
                    RefineStatus::Failed
                };
            }
            _ => {}
        }
        if self.sm.refine_averaging() {
            if let Some(m) = self.means.get_mut(self.sm.refine_index() as usize) {
                m.add(&tm.coefficients, tm.snapshot.omega_rad_s);
            }
        }

        match self.sm.outputs().request {
            Request::LoadCalibration
                if self.load == LoadStatus::Pending && self.awaiting.is_none() =>
            {
                match calib_record::load(flash, self.cfg_hash) {
                    // A count N does not divide cannot come from this configuration's
                    // sweep (N is in the record's hash): commission again.
                    Ok(l)
                        if !crate::align::pole_pairs_serve(
                            l.record.calibration.alignment.pole_pairs,
                            self.sensor_periods,
                        ) =>
                    {
                        self.load = LoadStatus::Unavailable;
                        events.push(Event::NotLoaded {
                            t_ms,
                            reason: "PolePairs",
                        });
                    }
                    Ok(l) => {
                        self.generation = self.generation.wrapping_add(1);
                        self.alignment = l.record.calibration.alignment;
                        self.awaiting = Some(Awaiting::Load {
                            generation: self.generation,
                            sequence: l.record.sequence,
                            motor: l.record.calibration.motor,
                        });
                        install = Some(Install {
                            generation: self.generation,
                            coefficients: l.record.calibration.coefficients,
                        });
                    }
                    Err(e) => {
                        self.load = LoadStatus::Unavailable;
                        // A failed read names the flash's own error (a double ECC
                        // error of a torn write, say), as a failed store does.
                        let reason = match e.reason() {
                            calib_record::Rejected::Flash(f) => f.name(),
                            r => r.name(),
                        };
                        events.push(Event::NotLoaded { t_ms, reason });
                    }
                }
            }
            Request::InstallRefined
                if self.refine == RefineStatus::Pending && self.awaiting.is_none() =>
            {
                match self.refined_coefficients() {
                    Ok(coefficients) => {
                        events.push(self.refined_event(t_ms, &coefficients));
                        self.generation = self.generation.wrapping_add(1);
                        self.awaiting = Some(Awaiting::Refined {
                            generation: self.generation,
                        });
                        install = Some(Install {
                            generation: self.generation,
                            coefficients,
                        });
                    }
                    Err(e) => {
                        self.refine_error = Some(e);
                        self.refine = RefineStatus::Failed;
                    }
                }
            }
            Request::StoreCalibration if self.store == StoreStatus::Pending => {
                self.store = match self.write(tm, flash, t_ms, &mut events) {
                    true => StoreStatus::Done,
                    false => StoreStatus::Failed,
                };
            }
            _ => {}
        }
        if self.store_requested && self.sm.state() == State::Run {
            // A failed store in Run keeps the previous record and the motor running.
            self.write(tm, flash, t_ms, &mut events);
        }
        self.store_requested = false;

        let before = self.sm.state();
        self.sm.step(&Inputs {
            dt_s: self.dt_s,
            // A fault from before a restart's release is the one already handled.
            fault: tm
                .snapshot
                .fault
                .filter(|_| tm.snapshot.release == self.release),
            currents_ready: tm.snapshot.currents_ready,
            currents_implausible: tm.snapshot.currents_implausible,
            theta_rad: tm.snapshot.sensor_theta_rad(),
            omega_rad_s: tm.snapshot.omega_rad_s,
            iq_integral_a_s: tm.snapshot.iq_integral_a_s,
            flux_angle_wb_rad: tm.snapshot.flux_angle_wb_rad,
            converged: tm.converged,
            residual_max_rad: tm.residual_max_rad,
            load: self.load,
            store: self.store,
            refine: self.refine,
            sweep: tm.snapshot.sweep,
            ident: tm.snapshot.ident,
            locked: !tm.snapshot.unlocked,
        });
        let state = self.sm.state();
        if before == State::Verify && matches!(state, State::Motion | State::Store) {
            if let Some(offset_e_rad) = tm.snapshot.corrected_offset_e_rad() {
                self.alignment.offset_e_rad = offset_e_rad;
                events.push(Event::OffsetCorrected { t_ms, offset_e_rad });
            }
        }
        if let (State::Identify, State::Align | State::Run, IdentStatus::Done(x)) =
            (before, state, tm.snapshot.ident)
        {
            let m = &mut self.motor;
            (m.r_ohm, m.ld_h, m.lq_h) = (x.r_ohm, x.ld_h, x.lq_h);
            // As the control period puts it back: a negative one (noise on an ideal
            // inverter) is none.
            m.v_inverter_v = mras::max_f32(x.v_inverter_v, 0.0);
            events.push(Event::Identified {
                t_ms,
                r_ohm: x.r_ohm,
                ld_h: x.ld_h,
                lq_h: x.lq_h,
                v_inverter_v: x.v_inverter_v,
            });
        }
        if let Some(amps_per_accel) = self.sm.probe_ended() {
            // The speed loop closes on the probe's J/kt where it is below the one in
            // force, never above: on the uncorrected sensor ω̂ swings by tens of rad/s at
            // speed, and a heavy rotor's loop at its design gain turns that into the
            // current limit (the nominal's lower gain carries it to speed).
            let in_force = if self.motion.amps_per_accel_a_s2 > 0.0 {
                self.motion.amps_per_accel_a_s2
            } else {
                self.motor.inertia_kg_m2 / self.torque_constant()
            };
            if amps_per_accel < in_force {
                self.motion = self
                    .motion
                    .changed(|m| m.amps_per_accel_a_s2 = amps_per_accel);
            }
        }
        if let (State::SpinUp, State::Adapt) = (before, state) {
            // A rough J/kt and ψ now: the motion loops and the observer in acceleration
            // per amp, the current loop's back-EMF feed-forward.
            let fit = self.sm.spin_up_fit();
            let psi = self.sm.spin_up_flux_wb();
            if fit.is_some() || psi.is_some() {
                self.motion = self.motion.changed(|m| {
                    if let Some(f) = fit {
                        m.amps_per_accel_a_s2 = f.amps_per_accel_a_s2;
                    }
                    if let Some(psi) = psi {
                        m.flux_wb = psi;
                    }
                });
            }
        }
        if let (State::Motion, State::Store, Some(psi), Some(f)) =
            (before, state, self.sm.flux_wb(), self.sm.motion_fit())
        {
            self.motion = self
                .motion
                .changed(|m| (m.amps_per_accel_a_s2, m.flux_wb) = (f.amps_per_accel_a_s2, psi));
            self.motor.flux_wb = psi;
            let kt = self.torque_constant();
            self.motor.inertia_kg_m2 = f.amps_per_accel_a_s2 * kt;
            // As fitted: at one speed region viscous and constant friction are separated
            // only weakly, either may come out negative while their sum is right.
            self.motor.viscous_nm_s_rad = f.amps_per_speed_a_s * kt;
            self.motor.coulomb_nm = f.amps_constant_a * kt;
            events.push(self.motion_event(t_ms));
        }
        // Accepted, or another pole-pair count to put in force and sweep again (the
        // offset is the second sweep's business).
        if before == State::Sweep && matches!(state, State::SpinUp | State::Align) {
            if let Some(r) = tm.snapshot.sweep {
                self.alignment = r.alignment;
                if state == State::Align {
                    self.alignment.pole_pairs = r.whole_pole_pairs;
                }
                events.push(Event::Aligned {
                    t_ms,
                    offset_e_rad: r.alignment.offset_e_rad,
                    reversed: r.alignment.reversed,
                    ratio: r.ratio,
                    pole_pairs: self.alignment.pole_pairs,
                });
            }
        }
        if state != self.last_state {
            events.push(match self.sm.cause() {
                Some(cause) if state == State::Safe => Event::Fault {
                    t_ms,
                    cause,
                    state: self.last_state,
                },
                _ => Event::State { t_ms, state },
            });
            self.last_state = state;
        }

        let o = self.sm.outputs();
        let command = Command {
            setpoint: o.setpoint,
            adaptation: o.adaptation,
            alignment: self.alignment,
            calibrate_currents: o.calibrate_currents,
            measure_shift: o.measure_shift,
            release: self.release,
            learn_ripple: o.learn_ripple,
            reacquire: o.reacquire,
            motion: self.motion,
        };
        self.events_dropped = self.events_dropped.saturating_add(events.dropped());
        let record = (self.steps % RECORD_DIVIDER == 0).then(|| Record {
            t_ms,
            state,
            faults: tm.snapshot.core_faults,
            theta_rad: tm.snapshot.theta_rad,
            omega_rad_s: tm.snapshot.omega_rad_s,
            amplitude: tm.snapshot.amplitude,
            converged: tm.converged,
            revs: tm.revs,
            residual_max_rad: tm.residual_max_rad,
            cycles_max: tm.snapshot.cycles.max,
            cycles_mean: tm.snapshot.cycles.mean(),
            cycles_min: tm.snapshot.cycles.min_or_zero(),
            handoffs_dropped: tm.snapshot.handoffs_dropped,
            updates_dropped: tm.updates_dropped,
            updates_late: tm.snapshot.updates_late,
            events_dropped: self.events_dropped,
            coef: Record::coef_of(&tm.coefficients),
        });
        self.steps = self.steps.wrapping_add(1);
        let out = Output {
            command,
            install,
            record,
            events,
            paths: self.bank_change(&tm.coefficients),
            first_seq: self.next_seq,
        };
        self.next_seq = self.next_seq.wrapping_add(out.line_count());
        out
    }

    /// The pole pairs in force: the alignment's, or the configured ones before one.
    pub fn pole_pairs(&self) -> u16 {
        self.alignment.pole_pairs_or(self.configured_pole_pairs)
    }

    /// The torque constant `1.5·p·ψ` of the flux linkage in force (N·m/A).
    fn torque_constant(&self) -> f32 {
        1.5 * self.pole_pairs() as f32 * self.motor.flux_wb
    }

    /// The motion constants in force, for the stream.
    fn motion_event(&self, t_ms: u32) -> Event {
        Event::Motion {
            t_ms,
            flux_wb: self.motor.flux_wb,
            inertia_kg_m2: self.motor.inertia_kg_m2,
            viscous_nm_s_rad: self.motor.viscous_nm_s_rad,
            coulomb_nm: self.motor.coulomb_nm,
        }
    }

    /// The mean of the one refinement, or the two speeds' separation.
    fn refined_coefficients(&self) -> Result<Coefficients, RefineError> {
        let [first, second] = self.means.map(|m| m.mean());
        match second {
            Ok(second) => separate(&first?, &second),
            Err(RefineError::Empty) => first.map(|r| r.coefficients),
            Err(e) => Err(e),
        }
    }

    /// What the refinement installs, for the stream.
    fn refined_event(&self, t_ms: u32, installed: &Coefficients) -> Event {
        let [first, second] = self.means.map(|m| m.mean().ok());
        let speed = |r: &Option<Refined>| r.map_or(0.0, |r| r.speed_rad_s);
        let motion_max = match (first, second) {
            (Some(a1), Some(_)) => a1
                .coefficients
                .iter()
                .zip(installed.iter())
                .map(|((_, v1), (_, e))| (v1 - e).abs())
                .fold(0.0, mras::max_f32),
            _ => 0.0,
        };
        Event::Refined {
            t_ms,
            speed_rad_s: speed(&first),
            second_speed_rad_s: speed(&second),
            motion_max,
        }
    }

    /// The bank, if it differs from the last one seen (the first is init's to stream).
    fn bank_change(&mut self, c: &Coefficients) -> Option<Bank> {
        if c.is_empty() {
            return None;
        }
        let bank = Bank::new(c.kinds());
        match self.bank.replace(bank) {
            Some(last) if last != bank => Some(bank),
            _ => None,
        }
    }

    /// Write the snapshot's coefficients with the alignment in force; true on success.
    fn write<F>(&self, tm: &Telemetry, flash: &mut F, t_ms: u32, events: &mut Events<E>) -> bool
    where
        F: FlashSlots,
        F::Error: NamedError,
    {
        let cal = Calibration {
            coefficients: tm.coefficients,
            // A stored alignment names its count.
            alignment: Alignment {
                pole_pairs: self.pole_pairs(),
                ..self.alignment
            },
            motor: self.motor,
        };
        let event = match calib_record::store(flash, &cal, self.cfg_hash) {
            Ok(_) => Event::Stored { t_ms },
            Err(StoreError::Flash(e)) => Event::StoreFailed {
                t_ms,
                reason: e.name(),
            },
            Err(e) => Event::StoreFailed {
                t_ms,
                reason: e.name(),
            },
        };
        let ok = matches!(event, Event::Stored { .. });
        events.push(event);
        ok
    }
}

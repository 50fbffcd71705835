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

use crate::commissioning::{
    Cause, Commissioning, Inputs, LoadStatus, Params, RefineStatus, Request, State, StoreStatus,
};
use crate::refine::{separate, CoefficientMean, RefineError, Refined};
use crate::telemetry::{Command, Event, Install, Record, Telemetry};
use calib_record::{Alignment, Calibration, FlashSlots, StoreError};
use heapless::Vec;
use mras::{Bank, Coefficients};

/// What an [`Install`] in flight is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Awaiting {
    /// A record loaded from flash (its sequence number, for the event).
    Load { generation: u8, sequence: u32 },
    /// The refined coefficients.
    Refined { generation: u8 },
}

/// A record every this many supervisor steps (100 Hz at a 1 kHz supervisor).
pub const RECORD_DIVIDER: u32 = 10;

/// Most events one step can produce.
pub const MAX_EVENTS: usize = 4;

/// A flash error's name for the stream.
pub trait NamedError {
    fn name(&self) -> &'static str;
}

/// What one step produces.
#[derive(Clone, Debug, PartialEq)]
pub struct Output {
    pub command: Command,
    /// Coefficients for the control period to install (once per load).
    pub install: Option<Install>,
    /// A stream record, every [`RECORD_DIVIDER`] steps.
    pub record: Option<Record>,
    pub events: Vec<Event, MAX_EVENTS>,
    /// The core's bank changed (a bank from the data grew, or a record's was installed):
    /// stream a new `mras-paths` line before the record, as init streams the first.
    pub paths: Option<Bank>,
}

#[derive(Clone, Debug)]
pub struct Supervisor {
    sm: Commissioning,
    dt_s: f32,
    control_rate_hz: u32,
    cfg_hash: u32,
    alignment: Alignment,
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
    last_state: State,
    steps: u32,
    pending_events: Vec<Event, MAX_EVENTS>,
    /// The bank of the coefficients last seen (None before the first report).
    bank: Option<Bank>,
}

impl Supervisor {
    /// `cfg_hash`: the control period's `calibration_hash` (the core's configuration,
    /// the motor and the sensor's scaling); `control_rate_hz` and `divider`: the control
    /// rate and the control periods per supervisor step.
    pub fn new(params: Params, cfg_hash: u32, control_rate_hz: u32, divider: u32) -> Self {
        let divider = divider.max(1);
        Self {
            sm: Commissioning::new(params),
            dt_s: divider as f32 / control_rate_hz.max(1) as f32,
            control_rate_hz: control_rate_hz.max(1),
            cfg_hash,
            alignment: Alignment::IDENTITY,
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
            steps: 0,
            pending_events: Vec::new(),
            bank: None,
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

    /// The reason the previous run ended (watchdog, HardFault, panic), found at boot:
    /// start in the safe state and report it.
    pub fn boot_fault(&mut self, cause: Cause) {
        self.sm.force_safe(cause);
        self.last_state = State::Safe;
        let _ = self.pending_events.push(Event::Fault {
            t_ms: 0,
            cause,
            state: State::CheckSensor,
        });
    }

    /// The operator asks to store the calibration in force (in Run): drift tracked
    /// since commissioning is kept across power cycles.
    pub fn request_store(&mut self) {
        self.store_requested = true;
    }

    /// Start over from the sensor check; releases the control period's latch.
    pub fn restart(&mut self) {
        self.sm.restart();
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
    pub fn step<F>(&mut self, tm: &Telemetry, flash: &mut F) -> Output
    where
        F: FlashSlots,
        F::Error: NamedError,
    {
        let t_ms = self.t_ms(tm);
        let mut events = core::mem::take(&mut self.pending_events);
        let mut install = None;

        // The control period's answer to an install.
        match (self.awaiting, tm.install) {
            (
                Some(Awaiting::Load {
                    generation,
                    sequence,
                }),
                Some(ack),
            ) if ack.generation == generation => {
                self.awaiting = None;
                self.load = if ack.accepted {
                    let _ = events.push(Event::Loaded { t_ms, sequence });
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
                    Ok(l) => {
                        self.generation = self.generation.wrapping_add(1);
                        self.alignment = l.record.calibration.alignment;
                        self.awaiting = Some(Awaiting::Load {
                            generation: self.generation,
                            sequence: l.record.sequence,
                        });
                        install = Some(Install {
                            generation: self.generation,
                            coefficients: l.record.calibration.coefficients,
                        });
                    }
                    Err(e) => {
                        self.load = LoadStatus::Unavailable;
                        let _ = events.push(Event::NotLoaded {
                            t_ms,
                            reason: e.name(),
                        });
                    }
                }
            }
            Request::InstallRefined
                if self.refine == RefineStatus::Pending && self.awaiting.is_none() =>
            {
                match self.refined_coefficients() {
                    Ok(coefficients) => {
                        let _ = events.push(self.refined_event(t_ms, &coefficients));
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
            omega_rad_s: tm.snapshot.omega_rad_s,
            converged: tm.converged,
            residual_max_rad: tm.residual_max_rad,
            load: self.load,
            store: self.store,
            refine: self.refine,
            sweep: tm.snapshot.sweep,
            locked: !tm.snapshot.unlocked,
        });
        let state = self.sm.state();
        if before == State::Verify && state == State::Store {
            if let Some(offset_e_rad) = tm.snapshot.corrected_offset_e_rad {
                self.alignment.offset_e_rad = offset_e_rad;
                let _ = events.push(Event::OffsetCorrected { t_ms, offset_e_rad });
            }
        }
        if before == State::Sweep && state == State::SpinUp {
            if let Some(r) = tm.snapshot.sweep {
                self.alignment = r.alignment;
                let _ = events.push(Event::Aligned {
                    t_ms,
                    offset_e_rad: r.alignment.offset_e_rad,
                    reversed: r.alignment.reversed,
                    ratio: r.ratio,
                });
            }
        }
        if state != self.last_state {
            let _ = events.push(match self.sm.cause() {
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
        };
        let record = (self.steps % RECORD_DIVIDER == 0).then(|| Record {
            t_ms,
            state,
            faults: tm.snapshot.core_faults,
            omega_rad_s: tm.snapshot.omega_rad_s,
            amplitude: tm.snapshot.amplitude,
            converged: tm.converged,
            revs: tm.revs,
            residual_max_rad: tm.residual_max_rad,
            cycles_max: tm.snapshot.cycles.max,
            cycles_mean: tm.snapshot.cycles.mean(),
            cycles_min: tm.snapshot.cycles.min_or_zero(),
            coef: Record::coef_of(&tm.coefficients),
        });
        self.steps = self.steps.wrapping_add(1);
        Output {
            command,
            install,
            record,
            events,
            paths: self.bank_change(&tm.coefficients),
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
    fn write<F>(
        &self,
        tm: &Telemetry,
        flash: &mut F,
        t_ms: u32,
        events: &mut Vec<Event, MAX_EVENTS>,
    ) -> bool
    where
        F: FlashSlots,
        F::Error: NamedError,
    {
        let cal = Calibration {
            coefficients: tm.coefficients,
            alignment: self.alignment,
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
        let _ = events.push(event);
        ok
    }
}

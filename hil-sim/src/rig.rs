//! The firmware's wiring on the host: the [`Plant`] in place of the board, and the
//! firmware's own control period (`drive::control`), adaptation task
//! (`drive::adaptation`, over `drive::handoff`'s bounded queues) and supervisor
//! (`drive::supervisor`) called exactly as its RTIC tasks call them: per PWM period read
//! the ADC, [`ControlPeriod::apply_due`], [`ControlPeriod::step`], apply the output,
//! [`ControlPeriod::hand_over`]; then the adaptation task on the queued samples (with
//! the install mailbox); at the divider ticks publish a snapshot and run the supervisor,
//! whose command applies from the next period. The queues have the firmware's depths
//! and drop rules; [`Rig::set_adaptation_every`] runs the task late, and
//! [`Rig::with_queue_depths`] gives it other depths, to see what the firmware would drop.
//!
//! The supervisor's flash is [`SimFlash`]: the calibration pages with the chip's erase
//! and programming times. While a flash operation runs the supervisor is blocked (its
//! command and events come out when it finishes, its ticks in between are lost, as the
//! firmware's control interrupt skips the tick of a supervisor still running) and the
//! control period keeps running, as it
//! does with the pages in the other flash bank; [`SimFlash::stall_cpu`] models pages in
//! the bank the code runs from, where the erase stalls everything.

use crate::plant::{Plant, Truth};
use anyhow::anyhow;
use calib_record::{FlashSlots, RamFlash, RamFlashError, Slot};
use drive::adaptation::{AdaptReport, AdaptationTask};
use drive::control::{ControlPeriod, DriveConfig, MotorConfig, Output};
use drive::handoff::{BankQueue, Queue, SpareQueue, HANDOFF_DEPTH, UPDATE_DEPTH};
use drive::motion::{Angle, LoopMode, MotionRef};
use drive::supervisor::{NamedError, Supervisor};
use drive::telemetry::{Command, Fault, Install, Line, Snapshot, TelemetrySlot};
use mras::{AdaptSample, Estimate, F32Trig, InjectionUpdate, Trig};
use std::f64::consts::TAU;

/// The motion profile the application asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reference {
    /// From rest, accelerate at `accel_rad_s2` to `speed_rev_s` and hold.
    Ramp { speed_rev_s: f64, accel_rad_s2: f64 },
    /// ω* = A·sin(2π f t) (the paper's Fig. 8 profile).
    Sine { amplitude_rad_s: f64, freq_hz: f64 },
}

impl Reference {
    fn trajectory(&self) -> mras_sim::Trajectory {
        match *self {
            Reference::Ramp {
                speed_rev_s,
                accel_rad_s2,
            } => mras_sim::Trajectory::Ramp {
                omega_rad_s: speed_rev_s * TAU,
                accel_rad_s2,
            },
            Reference::Sine {
                amplitude_rad_s,
                freq_hz,
            } => mras_sim::Trajectory::Sine {
                amplitude_rad_s,
                freq_hz,
            },
        }
    }

    /// (θ*, ω*, α*) at t.
    pub fn state(&self, t_s: f64) -> (f64, f64, f64) {
        self.trajectory().state(t_s)
    }

    /// A state `(θ*, ω*, α*)` as the control period takes it (whole turns kept apart in
    /// f64).
    pub fn motion_ref((th, w, a): (f64, f64, f64)) -> MotionRef {
        let turns = crate::exact::floor(th / TAU);
        MotionRef {
            theta: Angle {
                turns: turns as i32,
                rad: (th - turns * TAU) as f32,
            },
            omega_rad_s: w as f32,
            accel_rad_s2: a as f32,
        }
    }
}

/// The scenario's control settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlParams {
    pub mode: LoopMode,
    /// Motion loop bandwidth (Hz): the application's loop and the commissioning speed
    /// loop.
    pub bandwidth_hz: f64,
    /// Current loop bandwidth (Hz).
    pub current_bandwidth_hz: f64,
    pub reference: Reference,
}

/// The supervisor's period: 1 kHz, as on the MCU (20 control periods at 20 kHz).
pub const SUPERVISOR_PERIOD_S: f64 = 1e-3;

/// The drive's configuration for a plant: what the firmware's board module holds.
pub fn drive_config(
    plant: &Plant,
    control: &ControlParams,
    inertia_estimate_kg_m2: f64,
    sample_period_s: f64,
) -> anyhow::Result<DriveConfig> {
    let m = &plant.motor;
    let (count_size, bits) = plant.sensor_adc();
    let sensor =
        drive::adc::ChannelScaling::from_count_size(count_size, bits).ok_or_else(|| {
            anyhow!("sensor ADC count size {count_size} at {bits} bits is not representable")
        })?;
    let c = &plant.current_adc;
    let pole_pairs = u16::try_from(m.pole_pairs)
        .map_err(|_| anyhow!("`motor.pole_pairs` = {}: too many", m.pole_pairs))?;
    let divider = (SUPERVISOR_PERIOD_S / sample_period_s).round().max(1.0) as u32;
    Ok(DriveConfig {
        control_period_s: sample_period_s as f32,
        motor: MotorConfig {
            pole_pairs,
            r_ohm: m.r_ohm as f32,
            l_h: m.l_h as f32,
            flux_wb: m.flux_wb as f32,
            inertia_kg_m2: inertia_estimate_kg_m2 as f32,
            vdc_v: m.vdc_v as f32,
            i_max_a: m.i_max_a as f32,
        },
        sensor_x: sensor,
        sensor_y: sensor,
        current: drive::control::CurrentSensing {
            amps_per_count: c.amps_per_count as f32,
            zero_counts: c.zero_counts,
            max_counts: c.max_counts,
            zero_tolerance_counts: 200,
        },
        current_bandwidth_hz: control.current_bandwidth_hz as f32,
        speed_bandwidth_hz: control.bandwidth_hz as f32,
        application_loop: control.mode,
        application_bandwidth_hz: control.bandwidth_hz as f32,
        max_modulation: 1.0,
        supervisor_divider: divider,
    })
}

/// Page erase and double-word programming times: DS12288's maxima as recalled (22 ms
/// typical, 40 ms maximum per page; 82/91 µs per double word), not a datasheet reading.
pub const ERASE_S: f64 = 40e-3;
pub const PROGRAM_DOUBLE_WORD_S: f64 = 91e-6;

/// The calibration pages with the time their operations take.
#[derive(Clone, Debug, Default)]
pub struct SimFlash {
    pub ram: RamFlash,
    busy_s: f64,
    /// The pages share the bank the code runs from: an erase or program stalls the CPU,
    /// control period included (the firmware keeps them in the other bank).
    pub stall_cpu: bool,
    /// Make the next program operation fail (a flash error during a store).
    pub fail_next_program: bool,
}

/// A [`SimFlash`] operation's error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimFlashError {
    Ram(RamFlashError),
    /// Injected: the programming error flag (PROGERR) after the operation.
    Injected,
}

impl NamedError for SimFlashError {
    fn name(&self) -> &'static str {
        match self {
            SimFlashError::Ram(RamFlashError::OutOfBounds) => "OutOfBounds",
            SimFlashError::Ram(RamFlashError::Misaligned) => "Misaligned",
            SimFlashError::Ram(RamFlashError::NotErased) => "ProgErr",
            SimFlashError::Ram(RamFlashError::PowerLost) => "PowerLost",
            SimFlashError::Injected => "ProgErr",
        }
    }
}

impl SimFlash {
    pub fn new(ram: RamFlash) -> Self {
        Self {
            ram,
            ..Self::default()
        }
    }

    /// Time the operations since the last call took.
    fn take_busy_s(&mut self) -> f64 {
        std::mem::take(&mut self.busy_s)
    }
}

impl FlashSlots for SimFlash {
    type Error = SimFlashError;

    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), SimFlashError> {
        self.ram.read(slot, buf).map_err(SimFlashError::Ram)
    }

    fn erase(&mut self, slot: Slot) -> Result<(), SimFlashError> {
        self.busy_s += ERASE_S;
        self.ram.erase(slot).map_err(SimFlashError::Ram)
    }

    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), SimFlashError> {
        self.busy_s += PROGRAM_DOUBLE_WORD_S * (data.len() / 8) as f64;
        if std::mem::take(&mut self.fail_next_program) {
            return Err(SimFlashError::Injected);
        }
        self.ram
            .program(slot, offset, data)
            .map_err(SimFlashError::Ram)
    }
}

/// A line the supervisor streamed, with the simulated time it came out and its `seq`
/// (`drive::supervisor::Output::lines`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Streamed {
    pub t_s: f64,
    pub seq: u32,
    pub line: Line,
}

/// The supervisor task on the host.
struct SupervisorTask {
    sup: Supervisor,
    flash: SimFlash,
    /// Until this time the supervisor is inside a flash operation.
    busy_until_s: f64,
    /// Its output, published when the operation ends.
    deferred: Option<drive::supervisor::Output>,
    /// The CPU is stalled (flash in the code bank) until this time.
    stalled_until_s: f64,
}

/// One period of the rig.
#[derive(Clone, Copy, Debug)]
pub struct Step {
    pub truth: Truth,
    /// The fault this period raised, if any.
    pub fault: Option<Fault>,
    /// The estimate after this period's sample (the last good one on a fault).
    pub estimate: Estimate,
    /// The scaled sensor vector fed to the core.
    pub input: (f32, f32),
    pub output: Output,
    /// Torque commanded for the period under way (motor frame) and produced (mean).
    pub torque_cmd_nm: f64,
    pub torque_nm: f64,
    /// The reference position in force, θ* (motor frame, continuous, not homed).
    pub theta_ref_rad: f64,
    /// θ* - θ̂ as the application's position loop sees it (homed; 0 before it runs).
    pub tracking_error_rad: f64,
}

/// Plant + control period (+ supervisor): the firmware on a simulated board, with the
/// hand-over queues `H` samples and `U` updates deep (the firmware's by default).
pub struct Rig<T: Trig = F32Trig, const H: usize = HANDOFF_DEPTH, const U: usize = UPDATE_DEPTH> {
    pub plant: Plant,
    pub period: ControlPeriod<T>,
    /// The firmware's adaptation task, the queues between it and the control period,
    /// and the report it last published for the supervisor.
    adaptation: AdaptationTask,
    handoff: Queue<AdaptSample, H>,
    updates: Queue<InjectionUpdate, U>,
    banks: BankQueue,
    spares: SpareQueue,
    report: AdaptReport,
    /// The task is pended (a sample was handed over since it last ran).
    adapt_pended: bool,
    /// It runs once every this many control periods (1: right after each, as the
    /// firmware's scheduler runs it at the next priority down).
    adapt_every: u32,
    periods: u64,
    /// The command in force. Without a supervisor the experiment sets it.
    pub command: Command,
    reference: Option<Reference>,
    mailbox: Option<Install>,
    telemetry: TelemetrySlot,
    task: Option<SupervisorTask>,
    streamed: Vec<Streamed>,
    /// Control periods that did not run (CPU stalled by a flash operation).
    pub missed_periods: u64,
    last_output: Output,
}

impl<T: Trig> Rig<T> {
    /// A rig driven by the experiment: it sets [`Rig::command`] itself.
    pub fn new(plant: Plant, period: ControlPeriod<T>, reference: Option<Reference>) -> Self {
        Self {
            plant,
            adaptation: AdaptationTask::new(period.tracker().config())
                .expect("the control period validated this configuration"),
            handoff: Queue::new(),
            updates: Queue::new(),
            banks: Queue::new(),
            spares: Queue::new(),
            report: AdaptReport::EMPTY,
            adapt_pended: false,
            adapt_every: 1,
            periods: 0,
            period,
            command: Command::OFF,
            reference,
            mailbox: None,
            telemetry: TelemetrySlot::EMPTY,
            task: None,
            streamed: Vec::new(),
            missed_periods: 0,
            last_output: Output {
                duties: [0.5; 3],
                enable: false,
                supervisor_due: false,
            },
        }
    }
}

impl<T: Trig, const H: usize, const U: usize> Rig<T, H, U> {
    /// The same rig with hand-over queues `H2` samples and `U2` updates deep (before its
    /// first period: the queues start empty).
    pub fn with_queue_depths<const H2: usize, const U2: usize>(self) -> Rig<T, H2, U2> {
        Rig {
            plant: self.plant,
            period: self.period,
            adaptation: self.adaptation,
            handoff: Queue::new(),
            updates: Queue::new(),
            banks: Queue::new(),
            spares: Queue::new(),
            report: self.report,
            adapt_pended: false,
            adapt_every: self.adapt_every,
            periods: self.periods,
            command: self.command,
            reference: self.reference,
            mailbox: self.mailbox,
            telemetry: self.telemetry,
            task: self.task,
            streamed: self.streamed,
            missed_periods: self.missed_periods,
            last_output: self.last_output,
        }
    }

    /// Run the adaptation task only once every `periods` control periods (at least 1),
    /// on everything queued by then: a task held off by work at its priority or above.
    pub fn set_adaptation_every(&mut self, periods: u32) {
        self.adapt_every = periods.max(1);
    }

    /// The MRAS adaptation: coefficients and convergence.
    pub fn adaptation(&self) -> &AdaptationTask {
        &self.adaptation
    }

    /// The firmware's supervisor commands the rig, with its calibration pages.
    pub fn with_supervisor(mut self, sup: Supervisor, flash: SimFlash) -> Self {
        self.task = Some(SupervisorTask {
            sup,
            flash,
            busy_until_s: f64::NEG_INFINITY,
            deferred: None,
            stalled_until_s: f64::NEG_INFINITY,
        });
        self
    }

    pub fn supervisor(&self) -> Option<&Supervisor> {
        self.task.as_ref().map(|t| &t.sup)
    }

    pub fn supervisor_mut(&mut self) -> Option<&mut Supervisor> {
        self.task.as_mut().map(|t| &mut t.sup)
    }

    pub fn flash(&self) -> Option<&SimFlash> {
        self.task.as_ref().map(|t| &t.flash)
    }

    pub fn flash_mut(&mut self) -> Option<&mut SimFlash> {
        self.task.as_mut().map(|t| &mut t.flash)
    }

    /// Take the flash out (the next power-up's).
    pub fn into_flash(self) -> Option<SimFlash> {
        self.task.map(|t| t.flash)
    }

    /// Everything streamed so far, with its time.
    pub fn streamed(&self) -> &[Streamed] {
        &self.streamed
    }

    /// One control period.
    pub fn step(&mut self) -> Step {
        let t = self.plant.time_s();
        let stalled = self.task.as_ref().is_some_and(|k| t < k.stalled_until_s);
        self.finish_flash_operation(t);
        let theta_ref_rad = match &self.reference {
            Some(r) => {
                let state = r.state(t);
                self.period.set_reference(Reference::motion_ref(state));
                state.0
            }
            None => 0.0,
        };
        let (sample, truth) = self.plant.sample();
        let out = if stalled {
            // The ADC interrupt cannot run: the timer keeps the last duties and MOE.
            self.missed_periods += 1;
            Output {
                supervisor_due: false,
                ..self.last_output
            }
        } else {
            // As the control interrupt: a snapshot the supervisor did not take since
            // the period that owed it is written first.
            let period = &mut self.period;
            self.telemetry.settle_with(|s| period.write_snapshot(s));
            self.period
                .apply_due(&mut self.updates, &mut self.banks, &mut self.spares);
            let out = self.period.step(&sample, &self.command);
            self.adapt_pended |= self.period.hand_over(&mut self.handoff);
            // As the firmware's control interrupt: a supervisor still busy skips the tick.
            if out.supervisor_due && self.task.as_ref().is_some_and(|k| t >= k.busy_until_s) {
                self.telemetry.owe();
            }
            self.periods += 1;
            if self.adapt_pended && self.periods.is_multiple_of(u64::from(self.adapt_every)) {
                self.adapt_pended = false;
                let report = &mut self.report;
                self.adaptation.run(
                    &mut self.handoff,
                    &mut self.updates,
                    &mut self.banks,
                    &mut self.spares,
                    self.mailbox.take(),
                    |r| *report = *r,
                );
            }
            out
        };
        // The supervisor runs below the adaptation task: on the report of this period's
        // sample.
        if out.supervisor_due {
            self.run_supervisor(t);
        }
        self.plant.advance(&out);
        self.last_output = out;
        let estimate = self.period.tracker().last_estimate();
        let dir = if self.command.alignment.reversed {
            -1.0
        } else {
            1.0
        };
        let tracking_error_rad = self.period.application_home().map_or(0.0, |h| {
            theta_ref_rad + h.turns as f64 * TAU + h.rad as f64
                - dir * estimate.theta_unwrapped_rad()
        });
        Step {
            truth,
            fault: if stalled {
                None
            } else {
                self.period.last_fault()
            },
            estimate,
            input: self.period.last_input(),
            output: out,
            torque_cmd_nm: self.period.torque_command_nm() as f64,
            torque_nm: self.plant.torque_nm(),
            theta_ref_rad,
            tracking_error_rad,
        }
    }

    fn run_supervisor(&mut self, t: f64) {
        let Some(task) = self.task.as_mut() else {
            return;
        };
        if t < task.busy_until_s {
            return;
        }
        let period = &mut self.period;
        let mut snapshot = Snapshot::EMPTY;
        if !self
            .telemetry
            .take_into(&mut snapshot, |s| period.write_snapshot(s))
        {
            return;
        }
        let tm = snapshot.merged(&self.report);
        let out = task.sup.step(&tm, &mut task.flash);
        let busy = task.flash.take_busy_s();
        if busy > 0.0 {
            task.busy_until_s = t + busy;
            if task.flash.stall_cpu {
                task.stalled_until_s = t + busy;
            }
            task.deferred = Some(out);
        } else {
            self.publish(t, out);
        }
    }

    fn finish_flash_operation(&mut self, t: f64) {
        let Some(task) = self.task.as_mut() else {
            return;
        };
        if t >= task.busy_until_s {
            if let Some(out) = task.deferred.take() {
                self.publish(t, out);
            }
        }
    }

    fn publish(&mut self, t: f64, out: drive::supervisor::Output) {
        // As the firmware's supervisor: its motion constants in force with the command.
        self.period.put_motion(&out.command.motion);
        self.command = out.command;
        if out.install.is_some() {
            self.mailbox = out.install;
        }
        let lines = out
            .lines()
            .map(|(seq, line)| Streamed { t_s: t, seq, line });
        self.streamed.extend(lines);
    }
}

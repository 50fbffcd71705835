//! The power-up self-commissioning sequence, as a hardware-independent state machine.
//!
//! Check sensor health (and measure the current sensors' zero) → load the stored
//! calibration if valid → identify the motor's resistance and inductances and check the
//! current sensing's sign ([`crate::ident`]; the current loop is designed on them from
//! then on): on the rotor's d axis when a calibration was loaded (nothing moves; then
//! run, with slow tracking if enabled), otherwise at electrical angle 0 → align the
//! rotor → sweep the field open loop over one sensor period and back (the sensor's
//! electrical offset and direction against the phase sequence, and the motor's pole
//! pairs: another count than the one in force is put in force and swept again, after a
//! second alignment) → spin up on the uncorrected sensor to the commissioning speed over a
//! ramp (a rough fit of the inertia, [`crate::spin`]) → adapt until converged or timeout
//! → optionally refine: adapt on and average the coefficients, and do the same at a
//! second, higher speed, from which the rotor's motion ripple is separated from the
//! sensor error ([`crate::refine`]) → verify with the coefficients frozen → measure the
//! motor's flux linkage over a coast and its inertia and friction over a dip of the speed
//! ([`State::Motion`]) → store → run. Any fault at any step ends in [`State::Safe`] (PWM
//! outputs off) with its [`Cause`], until an explicit [`Commissioning::restart`].
//!
//! [`crate::supervisor::Supervisor`] steps it with the control period's telemetry; the
//! firmware and hil-sim both run that supervisor.

use crate::ident::{IdentError, IdentStatus};
use crate::spin::{FluxMeter, InertiaFit, MotionFit, Probe};
use crate::telemetry::{Fault, SweepResult};

/// Where the sequence is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum State {
    CheckSensor,
    LoadCalibration,
    /// The motor's R, Ld, Lq and the current sensing's sign ([`crate::ident`]).
    Identify,
    Align,
    Sweep,
    SpinUp,
    Adapt,
    /// Adapting on at speed while the coefficients are averaged (`Params::refine_s`).
    Refine,
    /// At `Params::second_speed_ratio` times the commissioning speed, adapting until
    /// converged again (then refined there too).
    SecondSpeed,
    Verify,
    /// The motor's mechanical constants at speed, on the corrected sensor
    /// ([`crate::spin`]): a coast (the flux linkage), then a dip of the speed setpoint
    /// and its recovery at the first commissioning speed (the inertia and friction).
    Motion,
    Store,
    Run,
    Safe,
}

impl State {
    pub const ALL: [State; 14] = [
        State::CheckSensor,
        State::LoadCalibration,
        State::Identify,
        State::Align,
        State::Sweep,
        State::SpinUp,
        State::Adapt,
        State::Refine,
        State::SecondSpeed,
        State::Verify,
        State::Motion,
        State::Store,
        State::Run,
        State::Safe,
    ];

    /// The state of a streamed name.
    pub fn from_name(name: &str) -> Option<State> {
        State::ALL.into_iter().find(|s| s.name() == name)
    }

    pub fn name(self) -> &'static str {
        match self {
            State::CheckSensor => "CheckSensor",
            State::LoadCalibration => "LoadCalibration",
            State::Identify => "Identify",
            State::Align => "Align",
            State::Sweep => "Sweep",
            State::SpinUp => "SpinUp",
            State::Adapt => "Adapt",
            State::Refine => "Refine",
            State::SecondSpeed => "SecondSpeed",
            State::Verify => "Verify",
            State::Motion => "Motion",
            State::Store => "Store",
            State::Run => "Run",
            State::Safe => "Safe",
        }
    }
}

/// Why the drive went to the safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cause {
    /// The core refused a sample or lost lock.
    Sensor(mras::Fault),
    /// An ADC count beyond the converter's range (misconfigured ADC).
    AdcOutOfRange,
    /// Over-current (break input), reported by the hardware layer.
    OverCurrent,
    /// The current sensors' zero, measured with the bridge off, is implausible.
    CurrentSensor,
    /// The motor's identification stopped ([`crate::ident::IdentError`] names why).
    Identify(IdentError),
    /// Non-finite or negative time step: a bug in the caller, refused safely.
    BadInput,
    /// The state did not finish in time (spin-up speed not reached, no convergence).
    Timeout(State),
    /// The rotor did not follow the alignment sweep (phase open, shaft locked, too
    /// little current).
    NoRotation,
    /// The sweeps found no pole-pair count the sensor's periods divide that the
    /// sensor's travel confirms (N ∤ p, or the sensor's period count is wrong); without
    /// the motor's identification: the travel does not confirm the configured count.
    PolePairs,
    /// With the coefficients frozen, the residual error did not stay below the limit.
    VerifyFailed,
    /// The core refused the stored coefficients although the record was intact.
    LoadRefused,
    /// The refined coefficients (their mean, or the two speeds' separation) could not be
    /// formed or the core refused them.
    RefineFailed,
    /// Writing the calibration to flash failed (the previous record is intact).
    StoreFailed,
    /// The independent watchdog reset the MCU (found in the reset flags at boot).
    Watchdog,
    /// A HardFault ended the previous run (found in the fault record at boot).
    HardFault,
    /// A panic ended the previous run (found in the fault record at boot).
    Panic,
}

impl From<Fault> for Cause {
    fn from(f: Fault) -> Self {
        match f {
            Fault::Sensor(s) => Cause::Sensor(s),
            Fault::AdcOutOfRange => Cause::AdcOutOfRange,
            Fault::OverCurrent => Cause::OverCurrent,
        }
    }
}

/// Timing and limits of the sequence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// The sensor must be healthy this long before anything moves.
    pub check_s: f32,
    /// Identify the motor (R, L and the current sensing's sign in `Identify`; ψ, J and the
    /// friction in the spin-up and `Motion`). Off: the configuration's constants stay
    /// (what the firmware did before it identified its motor), and the calibration
    /// stores them.
    pub identify_motor: bool,
    /// The identification's current (A, at least: [`crate::ident::IdentConfig`]).
    pub identify_current_a: f32,
    /// d-axis current and duration of the alignment (and current of the sweep).
    pub align_current_a: f32,
    pub align_s: f32,
    /// Duration of each direction of the alignment sweep (one sensor period forward,
    /// then back): long enough that a heavy rotor on a weak magnet follows the field
    /// within the pole-pair tolerance (at 0.4 s one at 87 rad/s²/A and 2 A travelled
    /// 19 % too far).
    pub sweep_s: f32,
    /// How far the pole-pair count the sweep's travel gives may be from the count in
    /// force, in units of N (below 0.5, so that a count N does not divide, half-way
    /// between two it does, is refused): a rotor ringing on the field's stiffness
    /// travels up to a fifth too far or too short at 2 pole pairs, a few % at 8.
    pub pole_pair_tolerance: f32,
    /// The largest pole-pair count taken for a motor: a rotor that travels less did not
    /// follow the field.
    pub max_pole_pairs: u16,
    /// Commissioning speed (mechanical) and how close and how long ω̂ must be to it.
    pub speed_rad_s: f32,
    pub speed_tolerance: f32,
    pub speed_settle_s: f32,
    /// Time constant of the low-pass on ω̂ for that check: on the uncorrected sensor ω̂
    /// ripples with the sensor error's derivative (tens of % at speed).
    pub speed_filter_s: f32,
    pub spin_up_timeout_s: f32,
    /// The spin-up's speed setpoint ramps up to the commissioning speed over this long:
    /// every rotor accelerates for a while, however light, and the inertia's fit sees the
    /// acceleration it needs ([`crate::spin`]).
    pub spin_up_ramp_s: f32,
    pub adapt_timeout_s: f32,
    /// Verification: coefficients frozen this long, the residual's mean over it below the
    /// limit (rad, sensor electrical, as `Convergence::residual_rad`).
    pub verify_s: f32,
    pub verify_residual_rad: f32,
    /// In [`State::Motion`], the q current held at zero this long, the d current at
    /// `coast_current_a` for the first half and at its negative for the second, while the
    /// control period integrates the back-EMF: the flux linkage ([`crate::spin`]).
    pub coast_s: f32,
    pub coast_current_a: f32,
    /// After `converged`, keep adapting this long at speed and install the mean of the
    /// coefficients over its second half (0: verify the coefficients of the moment
    /// `converged` came).
    /// `converged` only says every path is within `convergence.residual_rad`; the mean
    /// over a refinement settles to the noise of the estimate.
    pub refine_s: f32,
    /// 0: one commissioning speed. Otherwise (at least [`MIN_SECOND_SPEED_RATIO`]), after
    /// refining, converge and refine again at this many times the commissioning speed,
    /// and install the coefficients with the rotor's motion ripple separated out: a
    /// sensor error is the same at both speeds, the ripple a torque ripple makes falls as
    /// 1/ω² ([`crate::refine::separate`]). Needs `refine_s` > 0.
    pub second_speed_ratio: f32,
    /// After a loaded calibration or a commissioning: keep adapting slowly in Run.
    pub slow_tracking: bool,
    /// ...while |ω̂| (low-passed) is at least this share of `speed_rad_s`. A sensor
    /// error is fixed in angle; the position ripple a torque ripple (cogging, load)
    /// makes falls as 1/(J·ω²), and at one speed the MRAS cannot tell the two apart: it
    /// would learn the ripple as sensor error and the corrected angle would follow a
    /// motion the shaft did not make. At half the commissioning speed or more, that
    /// ripple is at most 4x what it was while commissioning adapted and verified.
    pub tracking_min_speed_ratio: f32,
    /// In Run, how long the core may go without a locked estimate (a sensor dropout, a
    /// loss of lock being re-acquired) before the drive goes to the safe state: the
    /// bridge is off meanwhile and the core re-acquires by itself, typically within a
    /// few ms of the sensor's return.
    pub reacquire_timeout_s: f32,
    /// In Run, while the coefficients are held (below the tracking speed) and the speed
    /// is steady: learn the torque ripple fixed to the shaft angle from the observer's
    /// lag ([`crate::ripple`]) and feed it to the observer, so that θ̂ follows the
    /// motion it makes. Needs the sensor error separated from the motion (two
    /// commissioning speeds, or a record made so): what the learner sees at a harmonic
    /// is taken for motion.
    pub learn_torque_ripple: bool,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            check_s: 0.05,
            identify_motor: true,
            identify_current_a: 2.0,
            align_current_a: 2.0,
            align_s: 0.3,
            sweep_s: 0.6,
            pole_pair_tolerance: 0.35,
            max_pole_pairs: 16,
            speed_rad_s: 20.0 * core::f32::consts::TAU,
            speed_tolerance: 0.1,
            speed_settle_s: 0.2,
            speed_filter_s: 0.05,
            spin_up_timeout_s: 2.0,
            spin_up_ramp_s: 0.2,
            adapt_timeout_s: 5.0,
            verify_s: 0.2,
            verify_residual_rad: 3.0e-3,
            coast_s: 0.04,
            coast_current_a: 1.0,
            refine_s: 0.0,
            second_speed_ratio: 0.0,
            slow_tracking: true,
            tracking_min_speed_ratio: 0.5,
            reacquire_timeout_s: 0.05,
            learn_torque_ripple: false,
        }
    }
}

/// The alignment sweeps at most this often: the first's travel covers another share of
/// a sensor period than one when the count in force is not the motor's, and the
/// sensor's error over that share can put its count one off (the next covers about
/// one period).
pub const MAX_SWEEPS: u8 = 3;

/// The identification's own stages are bounded (1 s each); this bounds the whole.
pub const IDENTIFY_TIMEOUT_S: f32 = 5.0;

/// A coast that slows the rotor below this share of its speed ends at once: it would
/// stop within the coast (see `Commissioning::measure_motion`).
pub const COAST_CUT: f32 = 0.5;

/// SpinUp's torque probe's q current, as a share of the alignment's.
pub const PROBE_SHARE: f32 = 0.25;

/// The speed setpoint's dip in [`State::Motion`], as a share of the commissioning
/// speed: down and back up, each over half of `Params::spin_up_ramp_s`. It gives the
/// inertia's fit, which starts after the coast, an acceleration whatever the friction
/// did.
pub const MOTION_DIP: f32 = 0.3;

/// Each half of the coast begins with this long left out of the flux measurement: the
/// currents' step.
pub const COAST_SETTLE_S: f32 = 0.005;

/// A residual this many times `Params::verify_residual_rad` fails Verify at once.
pub const VERIFY_GROSS: f32 = 3.0;

/// The smallest second speed, relative to the first: the separation divides by
/// 1 - 1/ratio², which amplifies the estimates' noise by 2.1x at 1.5 and 1.3x at 2.
pub const MIN_SECOND_SPEED_RATIO: f32 = 1.5;

impl Params {
    /// Check the refinement settings (the rest are the firmware's and a scenario's own
    /// constants); the error names the field.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
        if !(self.coast_s.is_finite() && self.coast_s > 4.0 * COAST_SETTLE_S) {
            return Err(("coast_s", "must be a finite number of seconds above 0.02"));
        }
        if !(self.spin_up_ramp_s.is_finite()
            && self.spin_up_ramp_s >= 0.0
            && self.spin_up_ramp_s < self.spin_up_timeout_s)
        {
            return Err((
                "spin_up_ramp_s",
                "must be a finite number of seconds, 0 or more, below spin_up_timeout_s",
            ));
        }
        if !(self.pole_pair_tolerance > 0.0 && self.pole_pair_tolerance < 0.5) {
            return Err((
                "pole_pair_tolerance",
                "must be above 0 and below 0.5 (of N pole pairs)",
            ));
        }
        if self.max_pole_pairs == 0 {
            return Err(("max_pole_pairs", "must be at least 1"));
        }
        if !(self.coast_current_a.is_finite() && self.coast_current_a > 0.0) {
            return Err(("coast_current_a", "must be a finite current above 0"));
        }
        if !(self.refine_s.is_finite() && self.refine_s >= 0.0) {
            return Err(("refine_s", "must be a finite number of seconds, 0 or more"));
        }
        let r = self.second_speed_ratio;
        if !(r == 0.0 || (r.is_finite() && r >= MIN_SECOND_SPEED_RATIO)) {
            return Err(("second_speed_ratio", "must be 0 (off) or at least 1.5"));
        }
        if r != 0.0 && self.refine_s == 0.0 {
            return Err((
                "second_speed_ratio",
                "needs refine_s > 0: the separation uses the two speeds' mean coefficients",
            ));
        }
        Ok(())
    }
}

/// What the hardware layer reports about a requested calibration load.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadStatus {
    Pending,
    /// A valid record was loaded into the core.
    Loaded,
    /// No valid record (erased, corrupt, other configuration): commission.
    Unavailable,
    /// An intact record the core refused: a bug or a configuration mismatch the hash
    /// did not catch; safe state rather than overwriting it.
    Refused,
}

/// What the supervisor reports about the refined coefficients' install.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RefineStatus {
    Pending,
    /// The core accepted them; they are in force.
    Installed,
    /// They could not be formed, or the core refused them.
    Failed,
}

/// What the hardware layer reports about a requested calibration store.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreStatus {
    Pending,
    Done,
    Failed,
}

/// One step's measurements.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inputs {
    /// Time since the previous step (s).
    pub dt_s: f32,
    /// A fault the control period latched since the previous step, if any.
    pub fault: Option<Fault>,
    /// The current sensors' zero is measured, and whether it is implausible.
    pub currents_ready: bool,
    pub currents_implausible: bool,
    /// The sensor vector's angle (`Snapshot::sensor_theta_rad`, within a turn of
    /// [0, 2π)) and ω̂, in the motor's frame (mechanical).
    pub theta_rad: f32,
    pub omega_rad_s: f32,
    /// The control period's running integrals for the motion's identification
    /// (`Snapshot::iq_integral_a_s`, `Snapshot::flux_angle_wb_rad`).
    pub iq_integral_a_s: f32,
    pub flux_angle_wb_rad: [f32; 2],
    pub converged: bool,
    /// Largest per-path residual (`Convergence::residual_rad`).
    pub residual_max_rad: f32,
    pub load: LoadStatus,
    pub store: StoreStatus,
    pub refine: RefineStatus,
    /// The alignment sweep's result, once it finished.
    pub sweep: Option<SweepResult>,
    /// The identification's progress (the control period's).
    pub ident: IdentStatus,
    /// The control period ran on a locked estimate in every period since the previous
    /// step (no refused sample, no re-acquisition under way).
    pub locked: bool,
}

impl Default for Inputs {
    fn default() -> Self {
        Self {
            dt_s: 0.0,
            fault: None,
            currents_ready: true,
            currents_implausible: false,
            theta_rad: 0.0,
            omega_rad_s: 0.0,
            iq_integral_a_s: 0.0,
            flux_angle_wb_rad: [0.0; 2],
            converged: false,
            residual_max_rad: f32::INFINITY,
            load: LoadStatus::Pending,
            store: StoreStatus::Pending,
            refine: RefineStatus::Pending,
            sweep: None,
            ident: IdentStatus::Pending,
            locked: true,
        }
    }
}

/// What the motion and current loops should do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Setpoint {
    /// PWM outputs off (MOE cleared).
    Off,
    /// The motor's identification, at `current_a` at least ([`crate::ident`]), in the
    /// frame of the rotor's d axis when `on_rotor` (a calibration is in force: no
    /// torque, nothing moves), else at electrical angle 0 (the rotor aligns to it).
    Identify { current_a: f32, on_rotor: bool },
    /// d-axis current at electrical angle 0, open loop: pulls the rotor to a known angle.
    Align { current_a: f32 },
    /// d-axis current on a field turned open loop over one sensor period and back, in
    /// `duration_s` each way: measures the alignment (`crate::align`).
    Sweep { current_a: f32, duration_s: f32 },
    /// Closed-loop speed on the (uncorrected or corrected) estimate.
    Speed { omega_rad_s: f32 },
    /// The q current held at zero and the d current at `id_a` in the estimate's frame:
    /// the rotor coasts while the control period integrates the back-EMF
    /// ([`crate::spin`]).
    Coast { id_a: f32 },
    /// The q current held at `iq_a` and the d current at zero in the estimate's frame,
    /// open loop in speed: SpinUp's torque probe ([`crate::spin::Probe`]).
    Torque { iq_a: f32 },
    /// The application's own motion control.
    Application,
}

/// What the MRAS should do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Adaptation {
    Frozen,
    /// Full-rate commissioning.
    Commissioning,
    /// Tracking of drift in Run, with the commissioning gain (the gates keep it to
    /// steady, high-speed motion).
    Tracking,
}

/// A request to the hardware layer, repeated every step until answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request {
    None,
    LoadCalibration,
    StoreCalibration,
    /// Install the refined coefficients (the mean of the refinements, or their
    /// separation) and report [`RefineStatus`].
    InstallRefined,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outputs {
    pub setpoint: Setpoint,
    pub adaptation: Adaptation,
    pub request: Request,
    /// Measure the current sensors' zero (bridge off, sensor check).
    pub calibrate_currents: bool,
    /// Measure how far the corrected angle sits from the raw one on average (at speed,
    /// coefficients frozen), to move the alignment onto the corrected angle.
    pub measure_shift: bool,
    /// Ride through sensor faults (Run): the control period switches the bridge off for
    /// a period whose sample was refused or whose estimate is not locked, instead of
    /// latching the safe state; the core re-acquires by itself.
    pub reacquire: bool,
    /// Learn the torque ripple ([`Params::learn_torque_ripple`]).
    pub learn_ripple: bool,
}

impl Outputs {
    pub fn pwm_enabled(&self) -> bool {
        self.setpoint != Setpoint::Off
    }
}

/// The sequence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Commissioning {
    params: Params,
    state: State,
    cause: Option<Cause>,
    /// Time in the current state, and time the current condition has held.
    in_state_s: f32,
    held_s: f32,
    /// Whether the coefficients in use came from flash (for reporting).
    loaded: bool,
    /// Low-passed ω̂ (see `Params::speed_filter_s`).
    speed_lp_rad_s: f32,
    /// Refinements completed (0, 1 or 2): which speed the current one is at.
    refined: u8,
    /// The refined coefficients are in force (Verify after a refinement).
    refined_installed: bool,
    /// In Run (judged on locked steps only): ω̂ is within `speed_tolerance` of its
    /// low-pass, and how long it has been; `settled` once that lasted `speed_settle_s`
    /// since Run was entered.
    steady: bool,
    steady_s: f32,
    settled: bool,
    /// The motion's identification: the spin-up's fit (J/kt, B/kt) on the uncorrected
    /// sensor, then in [`State::Motion`] the coast's ψ and the fit over the dip and the
    /// recovery on the corrected one ([`crate::spin`]).
    fit: InertiaFit,
    /// SpinUp's torque probe from rest, then the back-EMF over the rest of SpinUp: a
    /// rough J/kt and ψ for the loops before the rotor is at speed.
    probe: Probe,
    spin_flux: FluxMeter,
    spin_up_fit: Option<MotionFit>,
    motion_fit: Option<MotionFit>,
    flux: FluxMeter,
    flux_half: u8,
    flux_wb: Option<f32>,
    /// ω̂ where Motion's fit starts (the coast's end), once it has.
    fit_from_rad_s: Option<f32>,
    /// ω̂ at the coast's start, and whether the coast was cut ([`COAST_CUT`]): ψ then
    /// comes from the back-EMF at held speed over the dip.
    coast_from_rad_s: Option<f32>,
    coast_cut: bool,
    /// Sweeps done (each with the count the one before found in force), and the count
    /// in force in the one before the last (0 before a second).
    sweeps: u8,
    swept_before: u16,
    /// Verify's residuals: their sum and count.
    residual_sum: f32,
    residual_n: u32,
}

impl Commissioning {
    pub fn new(params: Params) -> Self {
        Self {
            params,
            state: State::CheckSensor,
            cause: None,
            in_state_s: 0.0,
            held_s: 0.0,
            loaded: false,
            speed_lp_rad_s: 0.0,
            refined: 0,
            refined_installed: false,
            steady: false,
            steady_s: 0.0,
            settled: false,
            fit: InertiaFit::default(),
            probe: Probe::default(),
            spin_flux: FluxMeter::default(),
            spin_up_fit: None,
            motion_fit: None,
            flux: FluxMeter::default(),
            flux_half: 0,
            flux_wb: None,
            fit_from_rad_s: None,
            coast_from_rad_s: None,
            coast_cut: false,
            sweeps: 0,
            swept_before: 0,
            residual_sum: 0.0,
            residual_n: 0,
        }
    }

    /// The spin-up's fit, once SpinUp ended with one that starts from rest
    /// ([`MotionFit::starts_at`]): a rough J/kt for the loops of the states that follow
    /// (on the uncorrected sensor the loop's frame wobbles against the rotor's, and on a
    /// light rotor the torque with it).
    pub fn spin_up_fit(&self) -> Option<MotionFit> {
        self.spin_up_fit
    }

    /// The torque probe's J/kt (A·s²/rad) on the step SpinUp's probe ended with one
    /// (None on every other step): the loops' first estimate of the rotor's
    /// acceleration per amp.
    pub fn probe_ended(&self) -> Option<f32> {
        self.probe.ended()
    }

    /// ψ (Wb) from the back-EMF over SpinUp after its probe, once SpinUp ended: rough
    /// (the q current's R·i and the inverter's error are in it), for the current loop's
    /// feed-forward and the torque constant until `Motion`'s coast measures it.
    pub fn spin_up_flux_wb(&self) -> Option<f32> {
        self.spin_flux.flux_wb()
    }

    /// SpinUp's time since its probe ended (s).
    fn spin_s(&self) -> f32 {
        self.in_state_s - self.probe.duration_s()
    }

    /// The probe's q current (A): a quarter of the alignment's.
    fn probe_current_a(&self) -> f32 {
        PROBE_SHARE * self.params.align_current_a
    }

    /// The fit over [`State::Motion`]'s dip and recovery after the coast, on the
    /// corrected sensor, once Motion ended.
    pub fn motion_fit(&self) -> Option<MotionFit> {
        self.motion_fit
    }

    /// The flux linkage the coast measured (Wb), once the coast ended.
    pub fn flux_wb(&self) -> Option<f32> {
        self.flux_wb
    }

    /// In [`State::Motion`]'s coast: its first half (0, +id) or its second (1, −id).
    fn coast_half(&self) -> Option<u8> {
        let p = &self.params;
        (self.state == State::Motion && self.in_state_s < p.coast_s && !self.coast_cut)
            .then_some((self.in_state_s >= 0.5 * p.coast_s) as u8)
    }

    /// While in [`State::Refine`]: 0 at the commissioning speed, 1 at the second.
    pub fn refine_index(&self) -> u8 {
        self.refined
    }

    /// In the second half of a refinement, the half the coefficients are averaged over:
    /// the first lets them settle from `converged`, which only bounds their residual.
    pub fn refine_averaging(&self) -> bool {
        self.state == State::Refine && self.in_state_s >= 0.5 * self.params.refine_s
    }

    /// The speed setpoint of the commissioning states (mechanical, rad/s).
    fn commissioning_speed_rad_s(&self) -> f32 {
        let p = &self.params;
        if self.refined >= 1 && p.second_speed_ratio > 0.0 {
            p.second_speed_ratio * p.speed_rad_s
        } else {
            p.speed_rad_s
        }
    }

    pub fn state(&self) -> State {
        self.state
    }

    /// Why the drive is in the safe state (None otherwise).
    pub fn cause(&self) -> Option<Cause> {
        self.cause
    }

    /// Whether Run uses a calibration loaded from flash (false: commissioned now).
    pub fn calibration_loaded(&self) -> bool {
        self.loaded
    }

    /// Start over from the sensor check (after the operator cleared the cause).
    pub fn restart(&mut self) {
        *self = Self::new(self.params);
    }

    /// Enter the safe state at once (watchdog reset, HardFault record found at boot).
    pub fn force_safe(&mut self, cause: Cause) {
        self.go(State::Safe);
        self.cause = Some(cause);
    }

    fn go(&mut self, s: State) {
        if matches!(s, State::SpinUp | State::Motion) {
            self.fit = InertiaFit::default();
            self.probe = Probe::default();
            self.spin_flux = FluxMeter::default();
            self.flux = FluxMeter::default();
            (self.flux_half, self.flux_wb) = (0, None);
            (self.fit_from_rad_s, self.coast_from_rad_s) = (None, None);
            self.coast_cut = false;
        }
        (self.residual_sum, self.residual_n) = (0.0, 0);
        self.state = s;
        self.in_state_s = 0.0;
        self.held_s = 0.0;
        self.steady = false;
        self.steady_s = 0.0;
        self.settled = false;
    }

    /// One step.
    pub fn step(&mut self, i: &Inputs) -> Outputs {
        self.probe.next_step();
        if self.state != State::Safe {
            if !(i.dt_s.is_finite() && i.dt_s >= 0.0) {
                self.force_safe(Cause::BadInput);
            } else if let Some(f) = i.fault {
                self.force_safe(f.into());
            } else {
                self.in_state_s += i.dt_s;
                let a = if self.params.speed_filter_s > 0.0 {
                    (i.dt_s / self.params.speed_filter_s).min(1.0)
                } else {
                    1.0
                };
                self.speed_lp_rad_s += (i.omega_rad_s - self.speed_lp_rad_s) * a;
                self.advance(i);
            }
        }
        self.outputs()
    }

    fn advance(&mut self, i: &Inputs) {
        let p = self.params;
        match self.state {
            State::CheckSensor => {
                if i.currents_implausible {
                    self.force_safe(Cause::CurrentSensor);
                } else if self.in_state_s >= p.check_s && i.currents_ready {
                    self.go(State::LoadCalibration);
                } else if self.in_state_s >= 10.0 * p.check_s {
                    self.force_safe(Cause::Timeout(State::CheckSensor));
                }
            }
            State::LoadCalibration => match (i.load, p.identify_motor) {
                (LoadStatus::Pending, _) => {}
                (LoadStatus::Loaded, identify) => {
                    self.loaded = true;
                    self.go(if identify {
                        State::Identify
                    } else {
                        State::Run
                    });
                }
                (LoadStatus::Unavailable, true) => self.go(State::Identify),
                (LoadStatus::Unavailable, false) => self.go(State::Align),
                (LoadStatus::Refused, _) => self.force_safe(Cause::LoadRefused),
            },
            State::Identify => match i.ident {
                IdentStatus::Done(_) if self.loaded => self.go(State::Run),
                IdentStatus::Done(_) => self.go(State::Align),
                IdentStatus::Failed(e) => self.force_safe(Cause::Identify(e)),
                // Its stages have their own limits; this one only catches a stall.
                IdentStatus::Pending if self.in_state_s >= IDENTIFY_TIMEOUT_S => {
                    self.force_safe(Cause::Timeout(State::Identify))
                }
                IdentStatus::Pending => {}
            },
            State::Align => {
                if self.in_state_s >= p.align_s {
                    self.go(State::Sweep);
                }
            }
            State::Sweep => match i.sweep {
                Some(r) => self.judge_sweep(&r),
                // Both directions plus their dwell, with margin.
                None if self.in_state_s >= 3.0 * p.sweep_s + 1.0 => {
                    self.force_safe(Cause::Timeout(State::Sweep))
                }
                None => {}
            },
            State::SpinUp => {
                self.fit.add(i.dt_s, i.theta_rad, i.iq_integral_a_s);
                if p.identify_motor && self.probe.probing() {
                    self.probe.add(i.dt_s, i.theta_rad, self.probe_current_a());
                    return;
                }
                if p.identify_motor {
                    self.spin_flux.add(i.theta_rad, i.flux_angle_wb_rad);
                }
                self.hold_speed(i.dt_s);
                if self.held_s >= p.speed_settle_s {
                    // A rough J/kt if the fit is consistent (the loops stay on theirs
                    // otherwise).
                    let w = self.commissioning_speed_rad_s();
                    self.spin_up_fit = self
                        .fit
                        .solve()
                        .filter(|f| p.identify_motor && f.starts_at(0.0, w));
                    self.go(State::Adapt);
                } else if self.spin_s() >= p.spin_up_timeout_s {
                    self.force_safe(Cause::Timeout(State::SpinUp));
                }
            }
            State::Adapt => {
                if i.converged {
                    self.converged_at_speed();
                } else if self.in_state_s >= p.adapt_timeout_s {
                    self.force_safe(Cause::Timeout(State::Adapt));
                }
            }
            State::Refine => {
                if self.in_state_s >= p.refine_s {
                    self.refined += 1;
                    if self.refined == 1 && p.second_speed_ratio > 0.0 {
                        self.go(State::SecondSpeed);
                    } else {
                        self.go(State::Verify);
                    }
                }
            }
            State::SecondSpeed => {
                // Adapting all along; refined once the speed has settled and the
                // coefficients have converged at it.
                self.hold_speed(i.dt_s);
                if self.held_s >= p.speed_settle_s && i.converged {
                    self.go(State::Refine);
                } else if self.in_state_s >= p.spin_up_timeout_s + p.adapt_timeout_s {
                    self.force_safe(Cause::Timeout(State::SecondSpeed));
                }
            }
            State::Verify if self.refined > 0 && !self.refined_installed => {
                // The verification starts once the refined coefficients are in force.
                self.in_state_s = 0.0;
                match i.refine {
                    RefineStatus::Pending => {}
                    RefineStatus::Installed => self.refined_installed = true,
                    RefineStatus::Failed => self.force_safe(Cause::RefineFailed),
                }
            }
            State::Verify => {
                // Verified with the coefficients frozen and the drive still at speed, on
                // the residual's mean over verify_s: a residual over two sensor periods is
                // noisy (a high R near the bus voltage peaks near the limit with its mean
                // at half of it); a gross one, or NaN, fails at once.
                let r = i.residual_max_rad;
                self.residual_sum += r;
                self.residual_n += 1;
                if r.is_nan() || r >= VERIFY_GROSS * p.verify_residual_rad {
                    self.force_safe(Cause::VerifyFailed);
                } else if self.in_state_s >= p.verify_s {
                    if self.residual_sum / self.residual_n as f32 >= p.verify_residual_rad {
                        self.force_safe(Cause::VerifyFailed);
                    } else if p.identify_motor {
                        self.go(State::Motion);
                    } else {
                        self.go(State::Store);
                    }
                }
            }
            State::Motion => self.measure_motion(i),
            State::Store => match i.store {
                StoreStatus::Pending => {}
                StoreStatus::Done => self.go(State::Run),
                StoreStatus::Failed => self.force_safe(Cause::StoreFailed),
            },
            State::Run => {
                if i.locked {
                    // Judged on locked steps only: a dropout being ridden through holds
                    // the estimate, and the adaptation resumes with the lock.
                    let dev = libm::fabsf(i.omega_rad_s - self.speed_lp_rad_s);
                    self.steady = dev <= p.speed_tolerance * libm::fabsf(self.speed_lp_rad_s);
                    self.steady_s = if self.steady {
                        self.steady_s + i.dt_s
                    } else {
                        0.0
                    };
                    self.settled |= self.steady_s >= p.speed_settle_s;
                    self.held_s = 0.0;
                } else {
                    self.held_s += i.dt_s;
                    if self.held_s >= p.reacquire_timeout_s {
                        // The sensor stays wrong: only a restart may try again.
                        self.force_safe(Cause::Sensor(mras::Fault::LossOfLock));
                    }
                }
            }
            State::Safe => {}
        }
    }

    /// A sweep's result: on if it travelled one sensor period of the count in force
    /// (within `pole_pair_tolerance`); otherwise, identifying the motor, aligned and
    /// swept again with the nearest count N divides in force (the supervisor puts it
    /// there), at most [`MAX_SWEEPS`] sweeps in all and never back to the count swept
    /// before (a count N does not divide lies half-way between two it does).
    fn judge_sweep(&mut self, r: &SweepResult) {
        let p = self.params;
        let n = r.sensor_periods.max(1) as f32;
        let tolerance = p.pole_pair_tolerance * n;
        let in_force = r.alignment.pole_pairs;
        self.sweeps = self.sweeps.saturating_add(1);
        // NaN included (the sweep gives none, but this is the last word on it).
        let followed = r.pole_pairs <= p.max_pole_pairs as f32 + tolerance;
        if !followed {
            self.force_safe(Cause::NoRotation)
        } else if libm::fabsf(r.pole_pairs - in_force as f32) <= tolerance {
            self.go(State::SpinUp)
        } else if p.identify_motor
            && self.sweeps < MAX_SWEEPS
            && r.whole_pole_pairs != in_force
            && r.whole_pole_pairs != self.swept_before
        {
            self.swept_before = in_force;
            self.go(State::Align)
        } else {
            self.force_safe(Cause::PolePairs)
        }
    }

    /// [`State::Motion`]: the coast (ψ), then the dip and the speed recovered, over which
    /// J/kt and B/kt are fitted.
    fn measure_motion(&mut self, i: &Inputs) {
        let p = self.params;
        if let Some(half) = self.coast_half() {
            let from = *self.coast_from_rad_s.get_or_insert(i.omega_rad_s);
            if libm::fabsf(i.omega_rad_s) >= COAST_CUT * libm::fabsf(from) {
                if half != self.flux_half {
                    self.flux.close();
                    self.flux_half = half;
                }
                let since = self.in_state_s - half as f32 * 0.5 * p.coast_s;
                if since >= COAST_SETTLE_S {
                    self.flux.add(i.theta_rad, i.flux_angle_wb_rad);
                }
                return;
            }
            // The rotor would stop within the coast (a fan on a light rotor): once it
            // stands θ̂ loses it, and the coast's d current turns it. ψ from the
            // back-EMF at held speed instead, over the dip.
            self.coast_cut = true;
            self.flux = FluxMeter::default();
            return;
        }
        let from = match self.fit_from_rad_s {
            Some(w) => w,
            None => {
                if !self.coast_cut {
                    match self.flux.flux_wb() {
                        Some(psi) => self.flux_wb = Some(psi),
                        None => {
                            return self.force_safe(Cause::Identify(IdentError::FluxOutOfRange))
                        }
                    }
                }
                // The fit starts here, at the speed the coast left (its friction can
                // slow a light rotor by most of it, faster than the observer's
                // feed-forward knows).
                self.fit = InertiaFit::about(i.omega_rad_s);
                *self.fit_from_rad_s.insert(i.omega_rad_s)
            }
        };
        if self.coast_cut {
            self.flux.add(i.theta_rad, i.flux_angle_wb_rad);
        }
        self.fit.add(i.dt_s, i.theta_rad, i.iq_integral_a_s);
        self.hold_speed(i.dt_s);
        let dipped = self.in_state_s >= p.coast_s + p.spin_up_ramp_s;
        if dipped && self.held_s >= p.speed_settle_s {
            if self.coast_cut {
                match self.flux.flux_wb() {
                    Some(psi) => self.flux_wb = Some(psi),
                    None => return self.force_safe(Cause::Identify(IdentError::FluxOutOfRange)),
                }
            }
            let (w0, w) = (from, p.speed_rad_s);
            match self.fit.solve().filter(|f| f.starts_at(w0, w)) {
                Some(f) => {
                    self.motion_fit = Some(f);
                    self.go(State::Store);
                }
                None => self.force_safe(Cause::Identify(IdentError::InertiaOutOfRange)),
            }
        } else if self.in_state_s >= p.coast_s + p.spin_up_timeout_s {
            self.force_safe(Cause::Timeout(State::Motion));
        }
    }

    /// Count the time the low-passed ω̂ has been within tolerance of the setpoint.
    fn hold_speed(&mut self, dt_s: f32) {
        let target = if self.state == State::Motion {
            self.params.speed_rad_s
        } else {
            self.commissioning_speed_rad_s()
        };
        let err = libm::fabsf(self.speed_lp_rad_s - target);
        if err <= self.params.speed_tolerance * libm::fabsf(target) {
            self.held_s += dt_s;
        } else {
            self.held_s = 0.0;
        }
    }

    /// `converged` at the commissioning speed: refine, or verify at once.
    fn converged_at_speed(&mut self) {
        if self.params.refine_s > 0.0 {
            self.go(State::Refine);
        } else {
            self.go(State::Verify);
        }
    }

    /// What the loops and the MRAS should do in the current state.
    pub fn outputs(&self) -> Outputs {
        let p = &self.params;
        let speed = Setpoint::Speed {
            omega_rad_s: self.commissioning_speed_rad_s(),
        };
        let since = if self.state == State::SpinUp {
            self.spin_s()
        } else {
            self.in_state_s
        };
        let ramp = if since < p.spin_up_ramp_s {
            since / p.spin_up_ramp_s
        } else {
            1.0
        };
        let ramped = Setpoint::Speed {
            omega_rad_s: ramp * self.commissioning_speed_rad_s(),
        };
        let mut learn_ripple = false;
        let (setpoint, adaptation, request) = match self.state {
            State::CheckSensor => (Setpoint::Off, Adaptation::Frozen, Request::None),
            State::LoadCalibration => (Setpoint::Off, Adaptation::Frozen, Request::LoadCalibration),
            State::Identify => (
                Setpoint::Identify {
                    current_a: p.identify_current_a,
                    on_rotor: self.loaded,
                },
                Adaptation::Frozen,
                Request::None,
            ),
            State::Align => (
                Setpoint::Align {
                    current_a: p.align_current_a,
                },
                Adaptation::Frozen,
                Request::None,
            ),
            State::Sweep => (
                Setpoint::Sweep {
                    current_a: p.align_current_a,
                    duration_s: p.sweep_s,
                },
                Adaptation::Frozen,
                Request::None,
            ),
            State::SpinUp if p.identify_motor && self.probe.probing() => (
                Setpoint::Torque {
                    iq_a: self.probe_current_a(),
                },
                Adaptation::Frozen,
                Request::None,
            ),
            State::SpinUp => (ramped, Adaptation::Frozen, Request::None),
            State::Adapt | State::Refine | State::SecondSpeed => {
                (speed, Adaptation::Commissioning, Request::None)
            }
            State::Verify if self.refined > 0 && !self.refined_installed => {
                (speed, Adaptation::Frozen, Request::InstallRefined)
            }
            State::Verify => (speed, Adaptation::Frozen, Request::None),
            State::Motion => match self.coast_half() {
                Some(half) => {
                    let sign = if half == 0 { 1.0 } else { -1.0 };
                    let coast = Setpoint::Coast {
                        id_a: sign * p.coast_current_a,
                    };
                    (coast, Adaptation::Frozen, Request::None)
                }
                None => {
                    // Down over the first half ramp, back up over the second.
                    // At the full speed until then after a coast that was cut.
                    let t =
                        mras::max_f32(self.in_state_s - p.coast_s, 0.0) / (0.5 * p.spin_up_ramp_s);
                    let dip = if t < 1.0 {
                        t
                    } else if t < 2.0 {
                        2.0 - t
                    } else {
                        0.0
                    };
                    // At the first commissioning speed, whatever speed Verify was at: the
                    // second may leave the loop too little voltage to follow the dip.
                    let w = (1.0 - MOTION_DIP * dip) * p.speed_rad_s;
                    let dipping = Setpoint::Speed { omega_rad_s: w };
                    (dipping, Adaptation::Frozen, Request::None)
                }
            },
            // The calibration pages are in the flash bank the code does not run from
            // (read-while-write): the control period keeps running through the erase.
            // At the speed Motion ended at.
            State::Store => (
                Setpoint::Speed {
                    omega_rad_s: p.speed_rad_s,
                },
                Adaptation::Frozen,
                Request::StoreCalibration,
            ),
            State::Run => {
                let fast = libm::fabsf(self.speed_lp_rad_s)
                    >= p.tracking_min_speed_ratio * libm::fabsf(p.speed_rad_s);
                // Not through a hard speed change: it moves ε by more than the transient
                // gate lets pass unseen. The application's first setpoint can brake the
                // rotor within 0.1 s of Run's entry, so tracking starts only once the
                // speed has been steady for `speed_settle_s`; later, ω̂ leaves its 50 ms
                // low-pass by the tolerance within a few ms of such a change (not in a
                // steady ramp), and tracking pauses while it is out.
                let adaptation = if p.slow_tracking && fast && self.settled && self.steady {
                    Adaptation::Tracking
                } else {
                    Adaptation::Frozen
                };
                learn_ripple = p.learn_torque_ripple
                    && adaptation == Adaptation::Frozen
                    && self.settled
                    && self.steady;
                (Setpoint::Application, adaptation, Request::None)
            }
            State::Safe => (Setpoint::Off, Adaptation::Frozen, Request::None),
        };
        Outputs {
            setpoint,
            adaptation,
            request,
            calibrate_currents: self.state == State::CheckSensor,
            measure_shift: self.state == State::Verify
                && (self.refined == 0 || self.refined_installed),
            reacquire: self.state == State::Run,
            learn_ripple,
        }
    }
}

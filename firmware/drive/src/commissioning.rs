//! The power-up self-commissioning sequence, as a hardware-independent state machine.
//!
//! Check sensor health (and measure the current sensors' zero) → load the stored
//! calibration if valid → identify the motor's resistance and inductances and check the
//! current sensing's sign ([`crate::ident`]; the current loop is designed on them from
//! then on): on the rotor's d axis when a calibration was loaded (nothing moves; then
//! run, with slow tracking if enabled), otherwise at electrical angle 0 → align the
//! rotor → sweep the field open loop over one sensor period and back (the sensor's
//! electrical offset and direction against the phase sequence, and a check of the
//! pole-pair count) → spin up on the uncorrected sensor to the commissioning speed →
//! adapt until converged or timeout → optionally refine: adapt on and average the
//! coefficients, and do the same at a second, higher speed, from which the rotor's motion
//! ripple is separated from the sensor error ([`crate::refine`]) → verify with the
//! coefficients frozen → store → run. Any fault at any step ends in [`State::Safe`] (PWM outputs off) with its
//! [`Cause`], until an explicit [`Commissioning::restart`].
//!
//! [`crate::supervisor::Supervisor`] steps it with the control period's telemetry; the
//! firmware and hil-sim both run that supervisor.

use crate::ident::{IdentError, IdentStatus};
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
    Store,
    Run,
    Safe,
}

impl State {
    pub const ALL: [State; 13] = [
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
    /// The sensor turned by a different angle than one sensor period over the sweep:
    /// the pole-pair count (or the sensor's period count) is wrong.
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
    /// The identification's current (A, at least: [`crate::ident::IdentConfig`]).
    pub identify_current_a: f32,
    /// d-axis current and duration of the alignment (and current of the sweep).
    pub align_current_a: f32,
    pub align_s: f32,
    /// Duration of each direction of the alignment sweep (one sensor period forward,
    /// then back), and how far the sensor's travel may be from one period (relative).
    pub sweep_s: f32,
    pub sweep_tolerance: f32,
    /// Commissioning speed (mechanical) and how close and how long ω̂ must be to it.
    pub speed_rad_s: f32,
    pub speed_tolerance: f32,
    pub speed_settle_s: f32,
    /// Time constant of the low-pass on ω̂ for that check: on the uncorrected sensor ω̂
    /// ripples with the sensor error's derivative (tens of % at speed).
    pub speed_filter_s: f32,
    pub spin_up_timeout_s: f32,
    pub adapt_timeout_s: f32,
    /// Verification: coefficients frozen this long, residual below the limit (rad, sensor
    /// electrical, as `Convergence::residual_rad`).
    pub verify_s: f32,
    pub verify_residual_rad: f32,
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
            identify_current_a: 2.0,
            align_current_a: 2.0,
            align_s: 0.3,
            sweep_s: 0.4,
            sweep_tolerance: 0.1,
            speed_rad_s: 20.0 * core::f32::consts::TAU,
            speed_tolerance: 0.1,
            speed_settle_s: 0.2,
            speed_filter_s: 0.05,
            spin_up_timeout_s: 2.0,
            adapt_timeout_s: 5.0,
            verify_s: 0.2,
            verify_residual_rad: 3.0e-3,
            refine_s: 0.0,
            second_speed_ratio: 0.0,
            slow_tracking: true,
            tracking_min_speed_ratio: 0.5,
            reacquire_timeout_s: 0.05,
            learn_torque_ripple: false,
        }
    }
}

/// The identification's own stages are bounded (1 s each); this bounds the whole.
pub const IDENTIFY_TIMEOUT_S: f32 = 5.0;

/// The smallest second speed, relative to the first: the separation divides by
/// 1 - 1/ratio², which amplifies the estimates' noise by 2.1x at 1.5 and 1.3x at 2.
pub const MIN_SECOND_SPEED_RATIO: f32 = 1.5;

impl Params {
    /// Check the refinement settings (the rest are the firmware's and a scenario's own
    /// constants); the error names the field.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
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
    /// ω̂ in the motor's frame (mechanical).
    pub omega_rad_s: f32,
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
            omega_rad_s: 0.0,
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
        }
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
        self.state = s;
        self.in_state_s = 0.0;
        self.held_s = 0.0;
        self.steady = false;
        self.steady_s = 0.0;
        self.settled = false;
    }

    /// One step.
    pub fn step(&mut self, i: &Inputs) -> Outputs {
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
            State::LoadCalibration => match i.load {
                LoadStatus::Pending => {}
                LoadStatus::Loaded => {
                    self.loaded = true;
                    self.go(State::Identify);
                }
                LoadStatus::Unavailable => self.go(State::Identify),
                LoadStatus::Refused => self.force_safe(Cause::LoadRefused),
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
                Some(r) if r.ratio < 0.5 => self.force_safe(Cause::NoRotation),
                Some(r) if libm::fabsf(r.ratio - 1.0) > p.sweep_tolerance => {
                    self.force_safe(Cause::PolePairs)
                }
                Some(_) => self.go(State::SpinUp),
                // Both directions plus their dwell, with margin.
                None if self.in_state_s >= 3.0 * p.sweep_s + 1.0 => {
                    self.force_safe(Cause::Timeout(State::Sweep))
                }
                None => {}
            },
            State::SpinUp => {
                self.hold_speed(i.dt_s);
                if self.held_s >= p.speed_settle_s {
                    self.go(State::Adapt);
                } else if self.in_state_s >= p.spin_up_timeout_s {
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
                // Verified with the coefficients frozen and the drive still at speed.
                if i.residual_max_rad.is_nan() || i.residual_max_rad >= p.verify_residual_rad {
                    self.force_safe(Cause::VerifyFailed);
                } else if self.in_state_s >= p.verify_s {
                    self.go(State::Store);
                }
            }
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

    /// Count the time the low-passed ω̂ has been within tolerance of the setpoint.
    fn hold_speed(&mut self, dt_s: f32) {
        let target = self.commissioning_speed_rad_s();
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
            State::SpinUp => (speed, Adaptation::Frozen, Request::None),
            State::Adapt | State::Refine | State::SecondSpeed => {
                (speed, Adaptation::Commissioning, Request::None)
            }
            State::Verify if self.refined > 0 && !self.refined_installed => {
                (speed, Adaptation::Frozen, Request::InstallRefined)
            }
            State::Verify => (speed, Adaptation::Frozen, Request::None),
            // The calibration pages are in the flash bank the code does not run from
            // (read-while-write): the control period keeps running through the erase.
            State::Store => (speed, Adaptation::Frozen, Request::StoreCalibration),
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

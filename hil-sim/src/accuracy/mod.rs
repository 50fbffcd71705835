//! The accuracy benchmark (`hil-sim bench-accuracy`, results in docs/results.md): the
//! online MRAS against the calibrations drive engineers use today, on the same
//! simulated sensors, drive and sample stream.
//!
//! One run per random sensor ([`draw_sensor`]): the SPMSM drive, closed in speed on OUR
//! tracker's estimate as in the product, goes through the phases of a [`Plan`]:
//! commissioning at +20 rev/s from rest (our MRAS adapts; the offline methods record
//! their calibration spin), then evaluation phases at other speeds, in the other
//! direction, under load steps and under sensor drift, with cogging throughout. Every
//! method turns each (x, y) sample into a sensor-electrical angle:
//!
//! * raw `atan2`, min/max, ellipse and LUT: `baselines`, fitted once on the calibration
//!   spin's raw samples (the LUT on `constant_speed_reference`: no encoder on a bench);
//! * the MRAS trackers: `arg(Zd)`, the decoupled vector of `Estimate::decoupled`. That is
//!   the corrected sensor reading, comparable sample by sample with the offline
//!   corrections; the observer's θ̂ would also low-pass the noise and add lag, which is
//!   the observer's merit or fault, not the calibration's;
//! * the oracle: the exact inverse of the simulated sensor ([`oracle_angle_rad`]).
//!
//! Each method's error against the true sensor angle N·θrm is binned over the
//! sensor-electrical angle ([`BINS`] bins, 4° electrical): a calibration error is a
//! function of θs, and the bin means average the noise away, so what is left is the
//! method's spatial error plus a noise residue that the oracle measures.

mod charts;
mod oracle;
pub mod page;
mod plan;
mod population;
pub mod report;
pub mod stats;
pub(crate) mod tables;

use crate::baselines::{constant_speed_reference, Corrector, Ellipse, Lut, MinMax, Raw};
use crate::plant::{Cogging, LoadStep, MotorParams, Plant};
use crate::rig::{self, ControlParams, Rig};
use crate::sensor::SensorSim;
use crate::Law;
use anyhow::{anyhow, bail, Context, Result};
use drive::commissioning::{Adaptation, Setpoint};
use drive::control::ControlPeriod;
use drive::motion::LoopMode;
use drive::telemetry::Command;
use mras::{Config, Estimate, Fault, Front, PathKind, Tracker};
use mras_sim::{wrap_pi, SpatialError};
use std::f64::consts::TAU;

pub use oracle::oracle_angle_rad;
use plan::steps;
pub use plan::{Phase, PhaseKind, Plan, SPECTRUM_PHASE};
pub use population::{
    draw_sensor, draw_sensor_in, Distribution, Harmonics, SensorCase, DISTRIBUTION, DISTRIBUTION_N1,
};

/// Control period (20 kHz, the core's default).
pub const SAMPLE_PERIOD_S: f64 = 50e-6;
/// Sensor periods per revolution N (KMZ41-like, the core's default).
pub const SENSOR_PERIODS: u16 = 2;
/// Bins of the spatial error over one sensor-electrical period (4° electrical, 2°
/// mechanical: 13 bins per period of the highest error harmonic, m = 7, that the
/// population produces; fewer bins would blur it, more would raise the noise residue).
pub const BINS: usize = 90;
/// Error harmonics m of the sensor angle θs reported in the spectrum of the first
/// evaluated phase: the benchmark's sensors put their errors at m <= 7. (A scenario's
/// spectrum counts harmonics of the mechanical angle instead:
/// [`crate::scenario::SPECTRUM_HARMONICS_OF_THETA_RM`].)
pub const SPECTRUM_HARMONICS_OF_THETA_S: usize = 8;

/// A method compared, in table order (declared in the order of [`Method::ALL`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    Raw,
    MinMax,
    Ellipse,
    Lut128,
    Lut256,
    Lut360,
    Paper,
    /// Ours in the core's default configuration: a path for every error harmonic the
    /// distribution produces (m = 1..7).
    Ours,
    /// Ours with the paper's four paths only (offset, C/D, h = 4, h = 5: m = 1..4), to
    /// show what the larger bank buys.
    OursPaperBank,
    /// Ours choosing its bank from the data (`mras::Config::paths_from_data`): offset and
    /// C/D first, then the harmonics the survey finds.
    OursFromData,
    Oracle,
}

impl Method {
    pub const COUNT: usize = 11;
    pub const ALL: [Method; Method::COUNT] = [
        Method::Raw,
        Method::MinMax,
        Method::Ellipse,
        Method::Lut128,
        Method::Lut256,
        Method::Lut360,
        Method::Paper,
        Method::Ours,
        Method::OursPaperBank,
        Method::OursFromData,
        Method::Oracle,
    ];
    /// The tracker-based methods, in the order of [`SensorResult::mras`].
    pub const MRAS: [Method; 4] = [
        Method::Ours,
        Method::Paper,
        Method::OursPaperBank,
        Method::OursFromData,
    ];

    /// Position in [`Method::ALL`] (the declaration order).
    pub fn index(self) -> usize {
        self as usize
    }

    pub fn label(self) -> &'static str {
        match self {
            Method::Raw => "raw atan2",
            Method::MinMax => "min/max (VESC)",
            Method::Ellipse => "ellipse (Heydemann)",
            Method::Lut128 => "LUT 128 bins",
            Method::Lut256 => "LUT 256 bins",
            Method::Lut360 => "LUT 360 bins",
            Method::Paper => "MRAS, paper-literal",
            Method::Ours => "MRAS, ours (default)",
            Method::OursPaperBank => "MRAS, ours, the paper's 4 paths",
            Method::OursFromData => "MRAS, ours, bank from the data",
            Method::Oracle => "oracle (noise floor)",
        }
    }

    /// Column name in the per-sensor CSV.
    pub fn key(self) -> &'static str {
        match self {
            Method::Raw => "raw",
            Method::MinMax => "minmax",
            Method::Ellipse => "ellipse",
            Method::Lut128 => "lut128",
            Method::Lut256 => "lut256",
            Method::Lut360 => "lut360",
            Method::Paper => "paper",
            Method::Ours => "ours",
            Method::OursPaperBank => "ours4",
            Method::OursFromData => "ours_data",
            Method::Oracle => "oracle",
        }
    }

    /// Variants beyond the seven methods every table compares (raw, min-max, ellipse,
    /// 256-bin LUT, paper, ours, oracle): other LUT sizes and the paper's smaller path
    /// bank, which show how sensitive a result is to those choices.
    pub fn is_extra(self) -> bool {
        matches!(
            self,
            Method::Lut128 | Method::Lut360 | Method::OursPaperBank | Method::OursFromData
        )
    }

    fn lut_bins(self) -> Option<usize> {
        match self {
            Method::Lut128 => Some(128),
            Method::Lut256 => Some(256),
            Method::Lut360 => Some(360),
            _ => None,
        }
    }
}

/// Residual spatial error of one method in one phase (rad, mechanical); NaN when the
/// method has no result (its calibration could not be fitted).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Residual {
    pub pk_pk_rad: f64,
    pub rms_rad: f64,
}

impl Residual {
    pub const NONE: Residual = Residual {
        pk_pk_rad: f64::NAN,
        rms_rad: f64::NAN,
    };
}

/// What one tracker did over the run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackerOutcome {
    /// Mechanical revolutions travelled from the start of adaptation to the first sample
    /// with `Tracker::convergence().converged`; None: never.
    pub converged_revs: Option<f64>,
    /// Whether `converged` held by the end of the commissioning phase.
    pub converged_in_commissioning: bool,
    /// The first fault and the phase it happened in.
    pub first_fault: Option<(usize, Fault)>,
    pub lost_lock: bool,
    pub faulted_samples: u32,
}

/// Everything measured for one sensor.
#[derive(Clone, Debug)]
pub struct SensorResult {
    pub index: usize,
    pub noise_std: f64,
    pub skew_s: f64,
    /// Per evaluated phase, per method (in [`Method::ALL`] order).
    pub residuals: Vec<[Residual; Method::COUNT]>,
    /// Amplitude of error harmonics m = 1..=[`SPECTRUM_HARMONICS_OF_THETA_S`] of θs (rad,
    /// mechanical) in the first evaluated phase, per method: where a residual comes from.
    pub spectrum_rad: [[f64; SPECTRUM_HARMONICS_OF_THETA_S]; Method::COUNT],
    /// Per tracker, in [`Method::MRAS`] order.
    pub mras: [TrackerOutcome; 4],
    /// What [`Method::OursFromData`]'s survey chose (None: it never completed).
    pub survey: Option<mras::survey::SurveyOutcome>,
    /// Offline methods whose fit failed, with the reason.
    pub fit_failures: Vec<(Method, String)>,
}

impl SensorResult {
    pub fn residual(&self, phase: usize, m: Method) -> Residual {
        self.residuals[phase][m.index()]
    }

    /// The largest residual over the evaluated phases (pk-pk and RMS each their own max).
    pub fn worst(&self, m: Method) -> Residual {
        self.residuals.iter().fold(
            Residual {
                pk_pk_rad: 0.0,
                rms_rad: 0.0,
            },
            |w, r| {
                let r = r[m.index()];
                // NaN propagates: a method without a result has no worst case either.
                Residual {
                    pk_pk_rad: if r.pk_pk_rad.is_nan() {
                        f64::NAN
                    } else {
                        w.pk_pk_rad.max(r.pk_pk_rad)
                    },
                    rms_rad: if r.rms_rad.is_nan() {
                        f64::NAN
                    } else {
                        w.rms_rad.max(r.rms_rad)
                    },
                }
            },
        )
    }

    pub fn tracker(&self, m: Method) -> Option<&TrackerOutcome> {
        Method::MRAS
            .iter()
            .position(|x| *x == m)
            .map(|i| &self.mras[i])
    }
}

/// The core configuration of a tracker method for a sensor with `sensor_periods`, with
/// the drive's inertia as Ĵ.
pub fn tracker_config(m: Method, j_kg_m2: f64, sensor_periods: u16) -> Result<Config> {
    let mut cfg = match m {
        Method::Paper => Law::Paper.config(),
        Method::Ours | Method::OursPaperBank | Method::OursFromData => Law::Ours.config(),
        other => bail!("{} is not a tracker", other.label()),
    };
    cfg.sample_period_s = SAMPLE_PERIOD_S as f32;
    cfg.sensor_periods = sensor_periods;
    if m == Method::OursFromData {
        cfg.set_paths(&mras::survey::FIRST_STAGE)?;
        cfg.paths_from_data = true;
    }
    cfg.observer.inertia_kg_m2 = j_kg_m2 as f32;
    if m == Method::OursPaperBank {
        cfg.set_paths(&[
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(5),
        ])?;
    }
    cfg.validate()?;
    Ok(cfg)
}

/// Spatial error of one method over one window, binned over θs; errors are unwrapped
/// around the window's first one so that a constant near ±π cannot split.
#[derive(Clone, Debug)]
struct Accumulator {
    error: SpatialError<BINS>,
    pivot: Option<f64>,
    /// Sensor periods per revolution: sensor-electrical to mechanical radians.
    n: f64,
}

impl Accumulator {
    fn new(sensor_periods: u16) -> Self {
        Self {
            error: SpatialError::new(),
            pivot: None,
            n: sensor_periods as f64,
        }
    }

    fn add(&mut self, theta_s_rad: f64, angle_rad: f64) {
        if !angle_rad.is_finite() {
            return;
        }
        let e = wrap_pi(angle_rad - theta_s_rad);
        let p = *self.pivot.get_or_insert(e);
        self.error.add(theta_s_rad, p + wrap_pi(e - p));
    }

    /// Harmonics m = 1.. of θs (mechanical radians); NaN unless every bin saw samples.
    fn spectrum(&self) -> [f64; SPECTRUM_HARMONICS_OF_THETA_S] {
        let full = self.error.filled_bins() == BINS;
        std::array::from_fn(|i| {
            if full {
                self.error.harmonic_amplitude_rad(i as u32 + 1) / self.n
            } else {
                f64::NAN
            }
        })
    }

    /// Mechanical radians; NaN unless every bin saw samples.
    fn residual(&self) -> Residual {
        if self.error.filled_bins() < BINS {
            return Residual::NONE;
        }
        let n = self.n;
        Residual {
            pk_pk_rad: self.error.pk_pk_rad() / n,
            rms_rad: self.error.rms_rad() / n,
        }
    }
}

/// The corrected angle `arg(Zd)` of a tracker's sample; None for a refused sample
/// (a loss of lock still computes Zd: the tracker has its estimate).
fn decoupled_angle(result: &Result<Estimate, Fault>, last: &Estimate) -> Option<f64> {
    let zd = match result {
        Ok(e) => e.decoupled,
        Err(Fault::LossOfLock) => last.decoupled,
        Err(_) => return None,
    };
    Some((zd.im as f64).atan2(zd.re as f64))
}

/// The result of the rig's own tracker in a period, as a passenger's step returns it.
fn rig_result(s: &rig::Step) -> Result<Estimate, Fault> {
    match s.fault {
        None => Ok(s.estimate),
        Some(drive::telemetry::Fault::Sensor(f)) => Err(f),
        // ADC range or over-current: no usable sample.
        Some(_) => Err(Fault::SensorSaturated),
    }
}

/// The sensor from `start_s` on: the same sensor, its drift starting at `start_s` (the
/// simulated sensor drifts from t = 0, so the model is shifted back by the drift up to
/// `start_s`; a fresh noise stream, still seeded).
fn drifting_sensor(case: &SensorCase, start_s: f64) -> Result<SensorSim> {
    let mut p = case.params.clone();
    let d = case.drift;
    p.model.ax -= d.ax_per_s * start_s;
    p.model.ay -= d.ay_per_s * start_s;
    let g = 1.0 + d.gain_per_s * start_s;
    p.model.bx1 /= g;
    p.model.by1 /= g;
    p.drift = d;
    Ok(SensorSim::new(p, case.noise_seed.wrapping_add(1))?)
}

/// Speed setpoint `t` after the start of a ramp from `from` to `to` (rad/s).
fn ramp(from: f64, to: f64, accel: f64, t: f64) -> f64 {
    let step = accel * t;
    if to > from {
        (from + step).min(to)
    } else {
        (from - step).max(to)
    }
}

/// Offline methods ready to correct samples.
type Fitted = Vec<(Method, Box<dyn Corrector>)>;

/// The offline methods fitted on the calibration spin, and those that failed to fit.
fn fit_offline(record: &[(f32, f32)]) -> (Fitted, Vec<(Method, String)>) {
    fn boxed<C: Corrector + 'static>(
        r: Result<C, crate::baselines::FitError>,
    ) -> Result<Box<dyn Corrector>> {
        Ok(Box::new(r?))
    }
    let reference = constant_speed_reference(record);
    let mut fits = vec![
        (Method::MinMax, boxed(MinMax::fit(record))),
        (Method::Ellipse, boxed(Ellipse::fit(record))),
    ];
    for m in [Method::Lut128, Method::Lut256, Method::Lut360] {
        let bins = m.lut_bins().unwrap_or(256);
        let lut = match &reference {
            Ok(r) => boxed(Lut::fit(record, r, bins)),
            Err(e) => Err(anyhow!("constant-speed reference: {e}")),
        };
        fits.push((m, lut));
    }
    let mut fitted: Fitted = vec![(Method::Raw, Box::new(Raw))];
    let mut failed = Vec::new();
    for (m, r) in fits {
        match r {
            Ok(c) => fitted.push((m, c)),
            Err(e) => failed.push((m, format!("{e:#}"))),
        }
    }
    (fitted, failed)
}

/// Per-tracker bookkeeping during the run.
struct TrackerRun {
    method: Method,
    outcome: TrackerOutcome,
}

impl TrackerRun {
    fn record(&mut self, phase: usize, r: &Result<Estimate, Fault>) {
        if let Err(f) = r {
            let o = &mut self.outcome;
            o.faulted_samples += 1;
            o.first_fault.get_or_insert((phase, *f));
            o.lost_lock |= *f == Fault::LossOfLock;
        }
    }
}

/// Simulate one sensor through the plan and measure every method.
pub fn run_sensor(case: &SensorCase, plan: &Plan) -> Result<SensorResult> {
    plan.validate()?;
    let starts = plan.phase_starts_s();
    let mut motor = MotorParams::default();
    let rated = motor.rated_torque_nm;
    motor.cogging = plan
        .cogging
        .iter()
        .enumerate()
        .map(|(i, &(harmonic, pu))| Cogging {
            harmonic,
            amplitude_nm: pu * rated,
            phase_rad: i as f64,
        })
        .collect();
    for (p, start) in plan.phases.iter().zip(&starts) {
        for &(t, pu) in &p.load_steps {
            motor.load_steps.push(LoadStep {
                t_s: start + t,
                torque_nm: pu * rated,
            });
        }
    }
    let j = motor.j_kg_m2;
    let control = ControlParams {
        mode: LoopMode::Velocity,
        bandwidth_hz: plan.speed_loop_hz,
        current_bandwidth_hz: 1000.0,
        // Unused: the run commands the speed loop phase by phase.
        reference: rig::Reference::Ramp {
            speed_rev_s: 0.0,
            accel_rad_s2: 1.0,
        },
    };
    let sensor = SensorSim::new(case.params.clone(), case.noise_seed)?;
    let plant = Plant::new(motor, sensor, SAMPLE_PERIOD_S, 0.0)?;
    let dcfg = rig::drive_config(&plant, &control, j, SAMPLE_PERIOD_S)?;
    let sensor_periods = case.population.sensor_periods;
    // The drive runs the firmware's code path with its tracker; the other trackers ride
    // along on the same samples.
    let (driving, riders) = if case.population.bank_from_data {
        let riders = [Method::Ours, Method::Paper, Method::OursPaperBank];
        (Method::OursFromData, riders)
    } else {
        let riders = [Method::Paper, Method::OursPaperBank, Method::OursFromData];
        (Method::Ours, riders)
    };
    let config = |m| tracker_config(m, j, sensor_periods);
    let period = ControlPeriod::new(dcfg, Front::new(config(driving)?)?)?;
    let mut drive = Rig::new(plant, period, None);
    let mut passengers: Vec<Tracker> = riders
        .iter()
        .map(|&m| Ok(Tracker::new(config(m)?)?))
        .collect::<Result<_>>()?;
    let mut runs: Vec<TrackerRun> = [driving]
        .iter()
        .chain(&riders)
        .map(|&method| TrackerRun {
            method,
            outcome: TrackerOutcome::default(),
        })
        .collect();

    let n = sensor_periods as f64;
    let mut offline: Fitted = Vec::new();
    let mut fit_failures = Vec::new();
    let mut residuals = Vec::new();
    let mut spectrum_rad = [[f64::NAN; SPECTRUM_HARMONICS_OF_THETA_S]; Method::COUNT];
    let mut record: Vec<(f32, f32, f64)> = Vec::new();
    // Rotor angle at the previous adapting sample, and the angle travelled since
    // adaptation started.
    let mut theta_adapt: Option<f64> = None;
    let mut travelled_rad = 0.0;
    let mut speed_rad_s = 0.0;
    let mut torque_in_force = 0.0f32;

    for (pi, phase) in plan.phases.iter().enumerate() {
        let commissioning = pi == 0;
        if phase.kind == PhaseKind::Drift {
            drive.plant.sensor = drifting_sensor(case, drive.plant.time_s())?;
        }
        let target = phase.speed_rev_s * TAU;
        let mut acc: Vec<Accumulator> = (0..Method::COUNT)
            .map(|_| Accumulator::new(sensor_periods))
            .collect();
        let skew_s = drive.plant.sensor.params.skew_s;
        let mut model = drive.plant.sensor.model_at(drive.plant.time_s());
        for k in 0..steps(phase.duration_s) {
            let t_rel = k as f64 * SAMPLE_PERIOD_S;
            let after_settle = t_rel >= phase.settle_s;
            let frozen = commissioning && !after_settle;
            drive.command = Command {
                setpoint: Setpoint::Speed {
                    omega_rad_s: ramp(speed_rad_s, target, phase.accel_rad_s2, t_rel) as f32,
                },
                adaptation: if frozen {
                    Adaptation::Frozen
                } else {
                    Adaptation::Commissioning
                },
                ..Command::OFF
            };
            for p in &mut passengers {
                p.set_frozen(frozen);
            }

            let s = drive.step();
            let (x, y) = s.input;
            let mut results = vec![rig_result(&s)];
            results.extend(passengers.iter_mut().map(|p| p.step(x, y, torque_in_force)));
            torque_in_force = s.torque_cmd_nm as f32;
            let theta_rad = s.truth.theta_rad;
            for (r, res) in runs.iter_mut().zip(&results) {
                r.record(pi, res);
            }

            if !frozen {
                // Revolutions travelled, not net: a reversal must not count backwards.
                let last = theta_adapt.replace(theta_rad).unwrap_or(theta_rad);
                travelled_rad += (theta_rad - last).abs();
                let drive_convergence = drive.adaptation().adapter().convergence();
                let convergence = [drive_convergence]
                    .into_iter()
                    .chain(passengers.iter().map(|p| p.convergence()));
                for (r, c) in runs.iter_mut().zip(convergence) {
                    if r.outcome.converged_revs.is_none() && c.converged {
                        r.outcome.converged_revs = Some(travelled_rad / TAU);
                        r.outcome.converged_in_commissioning = commissioning;
                    }
                }
            }
            if commissioning {
                if after_settle {
                    record.push((x, y, theta_rad));
                }
                continue;
            }
            if !after_settle {
                continue;
            }

            let theta_s = n * theta_rad;
            for (m, c) in &offline {
                acc[m.index()].add(theta_s, c.angle_rad(x, y));
            }
            let lasts = [drive.period.tracker().last_estimate()]
                .into_iter()
                .chain(passengers.iter().map(|p| p.last_estimate()));
            for ((r, res), last) in runs.iter().zip(&results).zip(lasts) {
                if let Some(a) = decoupled_angle(res, &last) {
                    acc[r.method.index()].add(theta_s, a);
                }
            }
            if phase.kind == PhaseKind::Drift {
                model = drive.plant.sensor.model_at(s.truth.t_s);
            }
            let skew_e_rad = n * s.truth.omega_rad_s * skew_s;
            acc[Method::Oracle.index()]
                .add(theta_s, oracle_angle_rad(&model, skew_e_rad, x, y, theta_s));
        }
        speed_rad_s = target;

        if commissioning {
            // The calibration spin: the last whole revolutions of the record.
            let end = record.last().map_or(0.0, |r| r.2);
            let span = plan.calibration_revs as f64 * TAU;
            let first = record
                .iter()
                .position(|r| (end - r.2).abs() <= span)
                .unwrap_or(0);
            let samples: Vec<(f32, f32)> = record[first..].iter().map(|r| (r.0, r.1)).collect();
            (offline, fit_failures) = fit_offline(&samples);
            record = Vec::new();
        } else {
            if residuals.len() == SPECTRUM_PHASE {
                spectrum_rad = std::array::from_fn(|i| acc[i].spectrum());
            }
            residuals.push(std::array::from_fn(|i| acc[i].residual()));
        }
    }

    Ok(SensorResult {
        index: case.index,
        noise_std: case.params.noise_std,
        skew_s: case.params.skew_s,
        residuals,
        spectrum_rad,
        survey: if driving == Method::OursFromData {
            drive.adaptation().adapter().survey().cloned()
        } else {
            let i = riders.iter().position(|&m| m == Method::OursFromData);
            i.and_then(|i| passengers[i].adapter().survey().cloned())
        },
        // In [`Method::MRAS`] order.
        mras: Method::MRAS.map(|m| {
            runs.iter()
                .find(|r| r.method == m)
                .map_or_else(TrackerOutcome::default, |r| r.outcome)
        }),
        fit_failures,
    })
}

/// Run sensors `0..sensors` of `population` with `seed` through `plan`, in parallel
/// (rayon); `progress` prints a line to stderr about every 10 % of the sensors.
pub fn run_suite(
    population: &'static Distribution,
    seed: u64,
    sensors: usize,
    plan: &Plan,
    progress: bool,
) -> Result<Vec<SensorResult>> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    plan.validate()?;
    let done = AtomicUsize::new(0);
    let started = std::time::Instant::now();
    let step = sensors.div_ceil(10).max(1);
    (0..sensors)
        .into_par_iter()
        .map(|i| {
            let r = run_sensor(&draw_sensor_in(population, seed, i), plan)
                .with_context(|| format!("{}: sensor {i}", population.name));
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            if progress && (n.is_multiple_of(step) || n == sensors) {
                eprintln!(
                    "  {n:>5} of {sensors} sensors ({:3.0} %), {:.1} s",
                    100.0 * n as f64 / sensors as f64,
                    started.elapsed().as_secs_f64()
                );
            }
            r
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_index_is_its_position() {
        for (i, m) in Method::ALL.iter().enumerate() {
            assert_eq!(m.index(), i, "{}", m.label());
        }
    }

    #[test]
    fn the_default_bank_is_the_full_one_and_the_variant_the_papers_four() {
        let j = MotorParams::default().j_kg_m2;
        let ours = tracker_config(Method::Ours, j, 2).unwrap();
        let paper = tracker_config(Method::Paper, j, 2).unwrap();
        let four = tracker_config(Method::OursPaperBank, j, 2).unwrap();
        assert_eq!(ours.paths(), Config::default().paths());
        assert_eq!(ours.paths().len(), 7);
        assert_eq!(paper.paths(), ours.paths());
        assert_ne!(paper.law, ours.law);
        assert_eq!(
            four.paths(),
            [
                PathKind::Offset,
                PathKind::AmplitudeQuadrature,
                PathKind::Harmonic(4),
                PathKind::Harmonic(5),
            ]
        );
        assert_eq!(four.law, ours.law);
        let data = tracker_config(Method::OursFromData, j, 1).unwrap();
        assert_eq!(data.paths(), mras::survey::FIRST_STAGE);
        assert!(data.paths_from_data && data.sensor_periods == 1);
        assert!(tracker_config(Method::Lut256, j, 2).is_err());
    }

    #[test]
    fn ramp_reaches_its_target_either_way() {
        assert_eq!(ramp(0.0, 10.0, 100.0, 0.05), 5.0);
        assert_eq!(ramp(0.0, 10.0, 100.0, 1.0), 10.0);
        assert_eq!(ramp(10.0, -10.0, 100.0, 0.1), 0.0);
        assert_eq!(ramp(10.0, -10.0, 100.0, 1.0), -10.0);
    }

    #[test]
    fn drift_starts_where_the_sensor_was() {
        let case = draw_sensor(3, 0);
        let start_s = 2.5;
        let s = drifting_sensor(&case, start_s).unwrap();
        let (at, later) = (s.model_at(start_s), s.model_at(start_s + 1.0));
        let m = case.params.model;
        assert!((at.ax - m.ax).abs() < 1e-12 && (at.bx1 - m.bx1).abs() < 1e-12);
        assert!((later.ax - at.ax - case.drift.ax_per_s).abs() < 1e-12);
        assert!((later.ay - at.ay - case.drift.ay_per_s).abs() < 1e-12);
    }

    #[test]
    fn plans_that_cannot_run_are_refused() {
        let mut p = Plan::full();
        assert!(p.validate().is_ok());
        p.calibration_revs = 100;
        assert!(p
            .validate()
            .unwrap_err()
            .to_string()
            .contains("calibration revolutions"));
        let mut p = Plan::full();
        p.phases.truncate(1);
        assert!(p.validate().is_err());
        let mut p = Plan::full();
        p.phases[2].settle_s = p.phases[2].duration_s;
        assert!(p.validate().unwrap_err().to_string().contains("settle_s"));
    }
}

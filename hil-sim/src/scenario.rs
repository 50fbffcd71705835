//! Scenarios: one TOML file per case (`hil-sim/scenarios/`), run by name. A paper
//! scenario runs twice, the paper-literal law and ours, on the same drive and sensor.

use crate::exact::wrap_pi;
use crate::input_error::{InputError, InvalidParam};
use crate::plant::{Cogging, LoadStep, MotorParams, Plant};
use crate::rig::{self, ControlParams, Reference, Rig, Step};
use crate::sensor::{Drift, Mount, SensorParams, SensorSim};
use anyhow::{anyhow, bail, Result};
use drive::commissioning::{Adaptation, Setpoint};
use drive::control::ControlPeriod;
use drive::motion::LoopMode;
use drive::telemetry::Command;
use mras::{AdaptationLaw, Coefficients, Tracker};
use mras_sim::{Adc, SensorHarmonic, SensorModel, SpatialError};
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;
use std::path::PathBuf;

/// The shipped scenarios (`hil-sim/scenarios/*.toml`), compiled in: a scenario is found
/// by name wherever the command runs, not under a source path fixed at build time.
const SHIPPED: [(&str, &str); 8] = [
    (
        "commissioning",
        include_str!("../scenarios/commissioning.toml"),
    ),
    ("paper-fig10", include_str!("../scenarios/paper-fig10.toml")),
    ("paper-fig11", include_str!("../scenarios/paper-fig11.toml")),
    ("paper-fig8", include_str!("../scenarios/paper-fig8.toml")),
    ("paper-fig9", include_str!("../scenarios/paper-fig9.toml")),
    ("ripple-1rev", include_str!("../scenarios/ripple-1rev.toml")),
    ("ripple-5rev", include_str!("../scenarios/ripple-5rev.toml")),
    ("table1", include_str!("../scenarios/table1.toml")),
];

/// The text of shipped scenario `name`.
pub fn shipped(name: &str) -> Option<&'static str> {
    SHIPPED.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// Names of the shipped scenarios, sorted.
pub fn list() -> Vec<String> {
    let mut names: Vec<String> = SHIPPED.iter().map(|(n, _)| n.to_string()).collect();
    names.sort();
    names
}

// ---- the file format ----

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    pub name: String,
    pub description: String,
    /// Simulated time of the full run and of the reduced CI variant.
    pub duration_s: f64,
    pub ci_duration_s: Option<f64>,
    #[serde(default = "default_rate")]
    pub sample_rate_hz: f64,
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Adaptation is frozen before this time (the paper's Fig. 9: 1 s).
    #[serde(default)]
    pub mras_enable_s: f64,
    /// Ĵ used by the observer and the motion controller, relative to J (Fig. 11: 0.66).
    #[serde(default = "one")]
    pub inertia_estimate_ratio: f64,
    #[serde(default)]
    pub sensor: SensorToml,
    #[serde(default)]
    pub motor: MotorToml,
    pub control: ControlToml,
    /// The core's configuration (`mras::Config`'s own TOML form, every key optional).
    #[serde(default)]
    pub core: mras::Config,
    /// The paper-literal gains for this scenario; when present the scenario also runs
    /// the paper's law side by side with ours.
    pub paper: Option<PaperToml>,
    /// Table I: each error alone (no adaptation), spectrum of the raw error.
    #[serde(default)]
    pub cases: Vec<CaseToml>,
    /// Present: run the firmware's power-up state machine (two power-ups).
    pub commissioning: Option<CommissioningToml>,
    /// Present: each power-up also reports its Run's spatial harmonics against the true
    /// rotor and the oracle, and the rotor's motion ripple ([`crate::truth_spectrum`]).
    pub truth_spectrum: Option<crate::truth_spectrum::TruthSpectrumToml>,
}

/// `drive::commissioning::Params` in the scenario file (defaults from there).
#[derive(Clone, Copy, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CommissioningToml {
    pub speed_rev_s: Option<f64>,
    pub align_current_a: Option<f64>,
    pub adapt_timeout_s: Option<f64>,
    pub verify_residual_rad: Option<f64>,
    pub slow_tracking: Option<bool>,
    pub tracking_min_speed_ratio: Option<f64>,
    pub refine_s: Option<f64>,
    pub second_speed_ratio: Option<f64>,
    pub learn_torque_ripple: Option<bool>,
    /// Identify the motor at power-up (default on; off: the controller keeps the
    /// firmware's nominal constants, as it did before it identified its motor).
    pub identify_motor: Option<bool>,
    /// The inertia the controller is configured with before it identifies the plant's
    /// (kg·m², board.rs's `INERTIA_KG_M2`): the firmware's nominal unless given. A board
    /// whose observer is tuned slow (the default eigenvalues, 100/10/1 Hz) needs it within
    /// a few times of the load's for the spin-up to keep its lock.
    pub inertia_kg_m2: Option<f64>,
}

impl CommissioningToml {
    /// The parameters, checked (the error names the `commissioning.` field).
    pub fn params(&self) -> Result<drive::commissioning::Params> {
        let d = drive::commissioning::Params::default();
        let p = drive::commissioning::Params {
            speed_rad_s: self.speed_rev_s.map_or(d.speed_rad_s, |v| (v * TAU) as f32),
            align_current_a: self.align_current_a.map_or(d.align_current_a, |v| v as f32),
            adapt_timeout_s: self.adapt_timeout_s.map_or(d.adapt_timeout_s, |v| v as f32),
            verify_residual_rad: self
                .verify_residual_rad
                .map_or(d.verify_residual_rad, |v| v as f32),
            slow_tracking: self.slow_tracking.unwrap_or(d.slow_tracking),
            tracking_min_speed_ratio: self
                .tracking_min_speed_ratio
                .map_or(d.tracking_min_speed_ratio, |v| v as f32),
            refine_s: self.refine_s.map_or(d.refine_s, |v| v as f32),
            second_speed_ratio: self
                .second_speed_ratio
                .map_or(d.second_speed_ratio, |v| v as f32),
            learn_torque_ripple: self.learn_torque_ripple.unwrap_or(d.learn_torque_ripple),
            identify_motor: self.identify_motor.unwrap_or(d.identify_motor),
            ..d
        };
        p.validate()
            .map_err(|(field, problem)| anyhow::anyhow!("`commissioning.{field}` {problem}"))?;
        Ok(p)
    }
}

fn default_rate() -> f64 {
    20_000.0
}
fn default_seed() -> u64 {
    1
}
fn one() -> f64 {
    1.0
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaperToml {
    pub k1_per_s: f32,
    pub k2: f32,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaseToml {
    pub name: String,
    /// Table I: the spatial harmonic of θrm the error must show.
    pub expect_harmonic: u32,
    pub sensor: SensorToml,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorToml {
    pub sensor_periods: u16,
    pub ax: f64,
    pub ay: f64,
    pub bx1: f64,
    pub by1: f64,
    pub phi_x1_deg: f64,
    pub harmonics: Vec<HarmonicToml>,
    pub noise_std: f64,
    /// 0: no quantisation.
    pub adc_bits: u8,
    pub adc_full_scale: f64,
    pub skew_s: f64,
    pub drift: DriftToml,
    pub eccentricity_rad: f64,
    pub eccentricity_phase_deg: f64,
    /// Mounting: the magnet's zero against the rotor's (mechanical degrees), and
    /// whether the sensor turns against the motor's phase sequence.
    pub mount_offset_deg: f64,
    pub mount_reversed: bool,
}

impl Default for SensorToml {
    fn default() -> Self {
        Self {
            sensor_periods: 2,
            ax: 0.0,
            ay: 0.0,
            bx1: 1.0,
            by1: 1.0,
            phi_x1_deg: 0.0,
            harmonics: Vec::new(),
            noise_std: 3.0e-4,
            adc_bits: 12,
            adc_full_scale: 1.5,
            skew_s: 0.0,
            drift: DriftToml::default(),
            eccentricity_rad: 0.0,
            eccentricity_phase_deg: 0.0,
            mount_offset_deg: 0.0,
            mount_reversed: false,
        }
    }
}

/// A harmonic `h`: either equal on X and Y (`b`, `phi_deg`) or per channel.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HarmonicToml {
    pub h: i32,
    pub b: Option<f64>,
    pub phi_deg: Option<f64>,
    pub bx: f64,
    pub phi_x_deg: f64,
    pub by: f64,
    pub phi_y_deg: f64,
}

#[derive(Clone, Copy, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriftToml {
    pub ax_per_s: f64,
    pub ay_per_s: f64,
    pub gain_per_s: f64,
}

impl SensorToml {
    pub fn to_params(&self) -> Result<SensorParams> {
        let mut m = SensorModel::ideal(self.sensor_periods);
        m.ax = self.ax;
        m.ay = self.ay;
        m.bx1 = self.bx1;
        m.by1 = self.by1;
        m.phi_x1_rad = self.phi_x1_deg.to_radians();
        for h in &self.harmonics {
            let hm = match (h.b, h.phi_deg) {
                (Some(b), phi) => SensorHarmonic::equal(h.h, b, phi.unwrap_or(0.0).to_radians()),
                (None, _) => SensorHarmonic {
                    h: h.h,
                    bx: h.bx,
                    phi_x_rad: h.phi_x_deg.to_radians(),
                    by: h.by,
                    phi_y_rad: h.phi_y_deg.to_radians(),
                },
            };
            if !m.push_harmonic(hm) {
                bail!(
                    "`sensor.harmonics`: at most {} harmonics",
                    mras_sim::MAX_SENSOR_HARMONICS
                );
            }
        }
        let p = SensorParams {
            model: m,
            noise_std: self.noise_std,
            adc: (self.adc_bits > 0).then_some(Adc {
                bits: self.adc_bits,
                full_scale: self.adc_full_scale,
            }),
            skew_s: self.skew_s,
            drift: Drift {
                ax_per_s: self.drift.ax_per_s,
                ay_per_s: self.drift.ay_per_s,
                gain_per_s: self.drift.gain_per_s,
            },
            eccentricity_rad: self.eccentricity_rad,
            eccentricity_phase_rad: self.eccentricity_phase_deg.to_radians(),
            mount: Mount {
                offset_rad: self.mount_offset_deg.to_radians(),
                reversed: self.mount_reversed,
            },
        };
        p.validate()?;
        Ok(p)
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotorToml {
    pub pole_pairs: u32,
    pub r_ohm: f64,
    pub l_h: f64,
    pub flux_wb: f64,
    pub j_kg_m2: f64,
    pub vdc_v: f64,
    pub i_max_a: f64,
    pub rated_torque_nm: f64,
    /// Coulomb friction as a fraction of rated torque (Fig. 11: 0.5 p.u.).
    pub coulomb_pu: f64,
    pub viscous_nm_s_rad: f64,
    pub cogging: Vec<CoggingToml>,
    pub load_steps: Vec<LoadStepToml>,
    /// Per phase a, b, c; two values are phases a and b (the paper's two sensors),
    /// phase c's then 0.
    #[serde(deserialize_with = "per_phase")]
    pub current_offset_a: [f64; 3],
    #[serde(deserialize_with = "per_phase")]
    pub current_gain_error: [f64; 3],
    /// The inverter's dead time (s) and device drop (V); 0: ideal.
    pub dead_time_s: f64,
    pub device_drop_v: f64,
}

/// Two or three values, one per phase (a missing phase c reads 0).
fn per_phase<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    match v.as_slice() {
        [a, b] => Ok([*a, *b, 0.0]),
        [a, b, c] => Ok([*a, *b, *c]),
        _ => Err(serde::de::Error::invalid_length(
            v.len(),
            &"2 or 3 values (phases a, b[, c])",
        )),
    }
}

impl Default for MotorToml {
    fn default() -> Self {
        let d = MotorParams::default();
        Self {
            pole_pairs: d.pole_pairs,
            r_ohm: d.r_ohm,
            l_h: d.l_h,
            flux_wb: d.flux_wb,
            j_kg_m2: d.j_kg_m2,
            vdc_v: d.vdc_v,
            i_max_a: d.i_max_a,
            rated_torque_nm: d.rated_torque_nm,
            coulomb_pu: 0.0,
            viscous_nm_s_rad: d.viscous_nm_s_rad,
            cogging: Vec::new(),
            load_steps: Vec::new(),
            current_offset_a: [0.0; 3],
            current_gain_error: [0.0; 3],
            dead_time_s: d.dead_time_s,
            device_drop_v: d.device_drop_v,
        }
    }
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoggingToml {
    pub harmonic: u32,
    pub amplitude_nm: f64,
    #[serde(default)]
    pub phase_deg: f64,
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadStepToml {
    pub t_s: f64,
    pub torque_nm: f64,
}

impl MotorToml {
    pub fn to_params(&self) -> Result<MotorParams, InvalidParam> {
        let mut m = MotorParams {
            pole_pairs: self.pole_pairs,
            r_ohm: self.r_ohm,
            l_h: self.l_h,
            flux_wb: self.flux_wb,
            j_kg_m2: self.j_kg_m2,
            vdc_v: self.vdc_v,
            i_max_a: self.i_max_a,
            rated_torque_nm: self.rated_torque_nm,
            coulomb_nm: 0.0,
            viscous_nm_s_rad: self.viscous_nm_s_rad,
            cogging: self
                .cogging
                .iter()
                .map(|c| Cogging {
                    harmonic: c.harmonic,
                    amplitude_nm: c.amplitude_nm,
                    phase_rad: c.phase_deg.to_radians(),
                })
                .collect(),
            load_steps: self
                .load_steps
                .iter()
                .map(|s| LoadStep {
                    t_s: s.t_s,
                    torque_nm: s.torque_nm,
                })
                .collect(),
            current_offset_a: self.current_offset_a,
            current_gain_error: self.current_gain_error,
            dead_time_s: self.dead_time_s,
            device_drop_v: self.device_drop_v,
        };
        m.coulomb_nm = self.coulomb_pu * m.rated_torque_nm;
        m.validate()?;
        Ok(m)
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlToml {
    /// "position" or "velocity".
    pub mode: String,
    pub bandwidth_hz: f64,
    #[serde(default = "default_current_bw")]
    pub current_bandwidth_hz: f64,
    pub reference: ReferenceToml,
}

fn default_current_bw() -> f64 {
    1000.0
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ReferenceToml {
    Ramp {
        speed_rev_s: f64,
        #[serde(default = "default_accel")]
        accel_rad_s2: f64,
    },
    Sine {
        amplitude_rad_s: f64,
        freq_hz: f64,
    },
}

fn default_accel() -> f64 {
    200.0
}

impl ControlToml {
    pub fn to_params(&self) -> Result<ControlParams> {
        let mode = match self.mode.as_str() {
            "position" => LoopMode::Position,
            "velocity" => LoopMode::Velocity,
            other => bail!("`control.mode` = \"{other}\": must be \"position\" or \"velocity\""),
        };
        let reference = match self.reference {
            ReferenceToml::Ramp {
                speed_rev_s,
                accel_rad_s2,
            } => {
                if accel_rad_s2.is_nan() || accel_rad_s2 <= 0.0 {
                    bail!("`control.reference.accel_rad_s2` must be > 0");
                }
                Reference::Ramp {
                    speed_rev_s,
                    accel_rad_s2,
                }
            }
            ReferenceToml::Sine {
                amplitude_rad_s,
                freq_hz,
            } => Reference::Sine {
                amplitude_rad_s,
                freq_hz,
            },
        };
        Ok(ControlParams {
            mode,
            bandwidth_hz: self.bandwidth_hz,
            current_bandwidth_hz: self.current_bandwidth_hz,
            reference,
        })
    }
}

/// A scenario that cannot be loaded: the file is missing, does not parse (the line is
/// named) or breaks a rule of the simulation (the parameter is named).
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("cannot read scenario {}: {error} (available: {available})", .path.display())]
    Read {
        path: PathBuf,
        error: std::io::Error,
        /// The shipped scenarios, comma-separated: what the user probably meant.
        available: String,
    },
    #[error("no scenario named `{name}` (available: {available}; or a path to a .toml file)")]
    Unknown {
        name: String,
        /// The shipped scenarios, comma-separated.
        available: String,
    },
    #[error(transparent)]
    Parse(#[from] InputError),
    #[error("{origin}: {error:#}")]
    Invalid {
        origin: String,
        error: anyhow::Error,
    },
}

/// A parsed, validated scenario.
#[derive(Clone, Debug)]
pub struct Scenario {
    pub file: ScenarioFile,
    pub origin: String,
}

impl Scenario {
    /// Load shipped scenario `name` ([`list`]), or a path to a `.toml` file.
    pub fn load(name_or_path: &str) -> Result<Self, ScenarioError> {
        if !name_or_path.ends_with(".toml") {
            let text = shipped(name_or_path).ok_or_else(|| ScenarioError::Unknown {
                name: name_or_path.into(),
                available: list().join(", "),
            })?;
            return Self::parse(text, &format!("hil-sim/scenarios/{name_or_path}.toml"));
        }
        let path = PathBuf::from(name_or_path);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(error) => {
                return Err(ScenarioError::Read {
                    path,
                    error,
                    available: list().join(", "),
                })
            }
        };
        Self::parse(&text, &path.display().to_string())
    }

    pub fn parse(text: &str, origin: &str) -> Result<Self, ScenarioError> {
        let file: ScenarioFile = toml::from_str(text).map_err(|e| InputError {
            line: e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() as u64 + 1),
            ..InputError::new(origin, e.message())
        })?;
        let sc = Self {
            file,
            origin: origin.to_string(),
        };
        sc.validate().map_err(|error| ScenarioError::Invalid {
            origin: origin.to_string(),
            error,
        })?;
        Ok(sc)
    }

    fn validate(&self) -> Result<()> {
        let f = &self.file;
        if !(f.duration_s > 0.0 && f.duration_s <= 600.0) {
            bail!("`duration_s` = {}: must be in (0, 600]", f.duration_s);
        }
        if !(f.sample_rate_hz >= 1000.0 && f.sample_rate_hz <= 200_000.0) {
            bail!(
                "`sample_rate_hz` = {}: must be in [1 kHz, 200 kHz]",
                f.sample_rate_hz
            );
        }
        if !(f.inertia_estimate_ratio > 0.05 && f.inertia_estimate_ratio < 20.0) {
            bail!("`inertia_estimate_ratio` must be in (0.05, 20)");
        }
        f.sensor.to_params()?;
        f.motor.to_params()?;
        f.control.to_params()?;
        let cfg = self.core_config(None)?;
        self.rig(cfg, f.seed)?;
        for c in &f.cases {
            c.sensor.to_params()?;
        }
        if let Some(t) = f.truth_spectrum {
            t.window_s(self)?;
        }
        Ok(())
    }

    pub fn sample_period_s(&self) -> f64 {
        1.0 / self.file.sample_rate_hz
    }

    /// The core configuration: the `[core]` table, with Ĵ from the motor and the
    /// scenario's inertia ratio, and the law replaced by the paper's when asked.
    pub fn core_config(&self, paper: Option<PaperToml>) -> Result<mras::Config> {
        let f = &self.file;
        let mut cfg = mras::Config {
            sample_period_s: self.sample_period_s() as f32,
            ..f.core
        };
        // The table as written is checked too, before the scenario overrides parts of it.
        cfg.validate()?;
        cfg.sensor_periods = f.sensor.sensor_periods;
        cfg.observer.inertia_kg_m2 = (f.motor.j_kg_m2 * f.inertia_estimate_ratio) as f32;
        if let Some(p) = paper {
            cfg.law = AdaptationLaw::PaperLiteral {
                k1_per_s: p.k1_per_s,
                k2: p.k2,
            };
        }
        cfg.validate()?;
        Ok(cfg)
    }
}

// ---- running ----

impl Scenario {
    /// The scenario's plant with the firmware's control period on it (no supervisor:
    /// the caller commands it), the core configured by `cfg`, sensor noise seeded by
    /// `seed`.
    pub fn rig(&self, cfg: mras::Config, seed: u64) -> Result<Rig> {
        self.rig_with(cfg, seed, |_| {})
    }

    /// [`Scenario::rig`] with the controller's configuration adjusted (e.g. told a pole
    /// count the motor does not have).
    pub fn rig_with(
        &self,
        cfg: mras::Config,
        seed: u64,
        adjust: impl FnOnce(&mut drive::control::DriveConfig),
    ) -> Result<Rig> {
        let f = &self.file;
        let t_s = self.sample_period_s();
        let motor = f.motor.to_params()?;
        let j_hat = motor.j_kg_m2 * f.inertia_estimate_ratio;
        let sensor = SensorSim::new(f.sensor.to_params()?, seed)?;
        let plant = Plant::new(motor, sensor, t_s, 0.0)?;
        let control = f.control.to_params()?;
        let mut dcfg = rig::drive_config(&plant, &control, j_hat, t_s)?;
        adjust(&mut dcfg);
        let tracker = mras::Front::new(cfg)?;
        let period = ControlPeriod::new(dcfg, tracker)?;
        Ok(Rig::new(plant, period, Some(control.reference)))
    }
}

/// How a sensor's reading relates to the rotor: its periods and mounting, for measuring
/// the error of the raw sensor and of the estimate against the true rotor angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    pub sensor_periods: f64,
    pub mount: Mount,
}

impl Probe {
    pub fn of(p: &SensorParams) -> Self {
        Self {
            sensor_periods: p.model.sensor_periods as f64,
            mount: p.mount,
        }
    }

    /// The magnet's angle for a rotor angle (mechanical).
    pub(crate) fn magnet_rad(&self, theta_rad: f64) -> f64 {
        if self.mount.reversed {
            self.mount.offset_rad - theta_rad
        } else {
            self.mount.offset_rad + theta_rad
        }
    }

    /// (raw sensor error, estimate error), mechanical rad, each within ±π/N: what one
    /// sensor period cannot tell apart is removed.
    pub fn errors_rad(&self, s: &Step) -> (f64, f64) {
        let n = self.sensor_periods;
        let truth = self.magnet_rad(s.truth.theta_rad);
        let raw = self.raw_error_rad(s.truth.theta_rad, s.truth.x, s.truth.y);
        let est = wrap_pi(n * (s.estimate.theta_unwrapped_rad() - truth)) / n;
        (raw, est)
    }

    /// The raw sensor's angle error (mechanical rad, within ±π/N) of its true vector
    /// `(x, y)` at rotor angle `theta_rad`.
    pub fn raw_error_rad(&self, theta_rad: f64, x: f32, y: f32) -> f64 {
        let n = self.sensor_periods;
        wrap_pi((y as f64).atan2(x as f64) - n * self.magnet_rad(theta_rad)) / n
    }
}

/// Which law a run uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Variant {
    Paper,
    Ours,
}

impl Variant {
    pub fn label(self) -> &'static str {
        match self {
            Variant::Paper => "paper",
            Variant::Ours => "ours",
        }
    }
}

/// One recorded (decimated) row of a run.
#[derive(Clone, Debug)]
pub struct Row {
    pub t_s: f64,
    pub theta_rad: f64,
    pub theta_hat_rad: f64,
    pub omega_rad_s: f64,
    pub omega_hat_rad_s: f64,
    pub tracking_error_rad: f64,
    pub torque_cmd_nm: f64,
    pub x: f32,
    pub y: f32,
    pub zd_x: f32,
    pub zd_y: f32,
    pub coefficients: Coefficients,
}

/// Spatial error (binned by true angle) of the raw sensor and of θ̂ over a window.
#[derive(Clone, Debug, Serialize)]
pub struct WindowStats {
    pub from_s: f64,
    pub to_s: f64,
    pub raw_pk_pk_mrad: f64,
    pub raw_rms_mrad: f64,
    pub estimate_pk_pk_mrad: f64,
    pub estimate_rms_mrad: f64,
    /// Position loop command tracking error θ* - θ̂, pk-pk.
    pub tracking_pk_pk_mrad: f64,
    /// Spatial harmonics 1..=16 of θrm (mrad), raw and estimate.
    #[serde(skip)]
    pub raw_spectrum_mrad: Vec<f64>,
    #[serde(skip)]
    pub estimate_spectrum_mrad: Vec<f64>,
    #[serde(skip)]
    pub estimate_by_angle: Vec<(f64, f64)>,
    #[serde(skip)]
    pub raw_by_angle: Vec<(f64, f64)>,
}

/// Spatial harmonics k of the mechanical angle θrm in a run's error spectrum (summary,
/// Table I): up to m = 8 of θs for the paper's N = 2 sensor. (The accuracy benchmark
/// counts harmonics of θs instead: [`crate::accuracy::SPECTRUM_HARMONICS_OF_THETA_S`].)
pub const SPECTRUM_HARMONICS_OF_THETA_RM: u32 = 16;

/// Spatial and tracking error over a time window of a run.
#[derive(Clone, Debug)]
pub(crate) struct Window {
    from_s: f64,
    to_s: f64,
    raw: SpatialError<360>,
    est: SpatialError<360>,
    track_min: f64,
    track_max: f64,
}

impl Window {
    pub(crate) fn new(from_s: f64, to_s: f64) -> Self {
        Self {
            from_s,
            to_s,
            raw: SpatialError::new(),
            est: SpatialError::new(),
            track_min: f64::INFINITY,
            track_max: f64::NEG_INFINITY,
        }
    }

    pub(crate) fn add(&mut self, s: &Step, probe: &Probe) {
        let t = s.truth.t_s;
        if t < self.from_s || t >= self.to_s {
            return;
        }
        let (raw, est) = probe.errors_rad(s);
        self.raw.add(s.truth.theta_rad, raw);
        self.est.add(s.truth.theta_rad, est);
        let e = s.tracking_error_rad;
        self.track_min = self.track_min.min(e);
        self.track_max = self.track_max.max(e);
    }

    pub(crate) fn stats(&self) -> WindowStats {
        let spec = |e: &SpatialError<360>| {
            (1..=SPECTRUM_HARMONICS_OF_THETA_RM)
                .map(|k| e.harmonic_amplitude_rad(k) * 1e3)
                .collect()
        };
        WindowStats {
            from_s: self.from_s,
            to_s: self.to_s,
            raw_pk_pk_mrad: self.raw.pk_pk_rad() * 1e3,
            raw_rms_mrad: self.raw.rms_rad() * 1e3,
            estimate_pk_pk_mrad: self.est.pk_pk_rad() * 1e3,
            estimate_rms_mrad: self.est.rms_rad() * 1e3,
            tracking_pk_pk_mrad: (self.track_max - self.track_min).max(0.0) * 1e3,
            raw_spectrum_mrad: spec(&self.raw),
            estimate_spectrum_mrad: spec(&self.est),
            estimate_by_angle: self.est.bin_means().collect(),
            raw_by_angle: self.raw.bin_means().collect(),
        }
    }
}

/// What one run measured.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    pub scenario: String,
    pub variant: Variant,
    pub duration_s: f64,
    pub mras_enable_s: f64,
    /// Before adaptation (absent when it runs from the start).
    pub before: Option<WindowStats>,
    /// The last 20 % of the run.
    pub after: WindowStats,
    /// Time and revolutions from enabling the MRAS to its `converged` flag.
    pub converged_after_s: Option<f64>,
    pub converged_after_revs: Option<f64>,
    pub faults: u32,
    pub coefficients: Vec<NamedCoefficient>,
}

/// (path name, real part, imaginary part) of a coefficient.
pub type NamedCoefficient = (String, f32, f32);

/// A run's summary and its decimated record.
pub struct RunOutcome {
    pub summary: RunSummary,
    pub rows: Vec<Row>,
}

/// Rows kept for CSV and plots.
const MAX_ROWS: u64 = 20_000;

/// A path's column name in CSV and summaries (one owner: replay's published interface).
pub use crate::replay::path_column_name as path_name;

/// Run one variant for `duration_s`; `progress` prints to stderr every 10 %.
pub fn run(sc: &Scenario, variant: Variant, duration_s: f64, progress: bool) -> Result<RunOutcome> {
    let f = &sc.file;
    let paper =
        match variant {
            Variant::Paper => Some(f.paper.ok_or_else(|| {
                anyhow!("{}: no [paper] table, so no paper-literal run", sc.origin)
            })?),
            Variant::Ours => None,
        };
    let cfg = sc.core_config(paper)?;
    let mut rig = sc.rig(cfg, f.seed)?;
    let t_s = sc.sample_period_s();
    let probe = Probe::of(&rig.plant.sensor.params);

    let steps = (duration_s / t_s).round() as u64;
    let decim = (steps / MAX_ROWS).max(1);
    let enable_s = f.mras_enable_s.min(duration_s);
    let before_from = (enable_s - 1.0).max(enable_s / 2.0);
    let mut before = (enable_s > 0.2).then(|| Window::new(before_from, enable_s));
    let mut after = Window::new(0.8 * duration_s, duration_s + t_s);
    let mut rows = Vec::with_capacity((steps / decim + 1) as usize);
    let (mut faults, mut converged_at, mut theta_at_enable) = (0u32, None, None);
    // The application from the start; adaptation from `mras_enable_s` on.
    rig.command = Command {
        setpoint: Setpoint::Application,
        ..Command::OFF
    };
    for k in 0..steps {
        let t = k as f64 * t_s;
        rig.command.adaptation = if t >= enable_s {
            Adaptation::Commissioning
        } else {
            Adaptation::Frozen
        };
        let s = rig.step();
        faults += s.fault.is_some() as u32;
        if let Some(w) = before.as_mut() {
            w.add(&s, &probe);
        }
        after.add(&s, &probe);
        if t >= enable_s {
            let th0 = *theta_at_enable.get_or_insert(s.truth.theta_rad);
            if converged_at.is_none()
                && k % 64 == 0
                && rig.adaptation().adapter().convergence().converged
            {
                converged_at = Some((t - enable_s, (s.truth.theta_rad - th0).abs() / TAU));
            }
        }
        if k % decim == 0 {
            rows.push(Row {
                t_s: t,
                theta_rad: s.truth.theta_rad,
                theta_hat_rad: s.estimate.theta_unwrapped_rad(),
                omega_rad_s: s.truth.omega_rad_s,
                omega_hat_rad_s: s.estimate.omega_rad_s as f64,
                tracking_error_rad: s.tracking_error_rad,
                torque_cmd_nm: s.torque_cmd_nm,
                x: s.input.0,
                y: s.input.1,
                zd_x: s.estimate.decoupled.re,
                zd_y: s.estimate.decoupled.im,
                coefficients: rig.adaptation().adapter().coefficients(),
            });
        }
        if progress && steps >= 200_000 && k % (steps / 10) == 0 && k > 0 {
            eprintln!(
                "  [{} {}] {:3.0} % ({:.1} of {:.1} s simulated)",
                f.name,
                variant.label(),
                100.0 * k as f64 / steps as f64,
                t,
                duration_s
            );
        }
    }
    let coefficients = rig
        .adaptation()
        .adapter()
        .coefficients()
        .iter()
        .map(|(k, v)| (path_name(k), v.re, v.im))
        .collect();
    Ok(RunOutcome {
        summary: RunSummary {
            scenario: f.name.clone(),
            variant,
            duration_s,
            mras_enable_s: enable_s,
            before: before.map(|w| w.stats()),
            after: after.stats(),
            converged_after_s: converged_at.map(|c| c.0),
            converged_after_revs: converged_at.map(|c| c.1),
            faults,
            coefficients,
        },
        rows,
    })
}

/// The exact decoupling coefficients of the scenario's sensor for its path bank: the
/// fixed point the MRAS converges to without noise, drive or drift (docs/theory.md §1,
/// §4), found by a noiseless kinematic commissioning at 20 rev/s, 40 revolutions.
/// `None` when the sensor drifts or has errors the paths cannot represent exactly
/// (eccentricity), or when that run does not settle.
pub fn reference_coefficients(sc: &Scenario) -> Result<Option<Vec<NamedCoefficient>>> {
    let f = &sc.file;
    let p = f.sensor.to_params()?;
    if p.eccentricity_rad != 0.0 || p.drift != Drift::default() {
        return Ok(None);
    }
    let mut cfg = sc.core_config(None)?;
    cfg.sample_period_s = 50e-6;
    cfg.observer.eigenvalues_hz = [100.0, 10.0, 1.0];
    let mut t = Tracker::new(cfg)?;
    let run = mras_sim::CommissioningRun {
        sensor: p.model,
        speed_rev_s: 20.0,
        sample_period_s: 50e-6,
        inertia_kg_m2: 1e-4,
        adc: None,
    };
    let mut last_change = f32::INFINITY;
    run.run(
        &mut t,
        40,
        || (0.0, 0.0),
        |t, _| {
            let c = t.convergence();
            last_change = c.change_per_rev[..c.len as usize]
                .iter()
                .fold(0.0, |a, b| a.max(*b));
        },
    );
    if !t.faults().is_empty() || last_change > 1e-4 {
        return Ok(None);
    }
    Ok(Some(
        t.coefficients()
            .iter()
            .map(|(k, v)| (path_name(k), v.re, v.im))
            .collect(),
    ))
}

/// (case, Table I harmonic, measured dominant harmonic, spectrum in mrad for 1..=16).
pub type Table1Row = (String, u32, u32, Vec<f64>);

/// Table I: each case's raw spatial error spectrum.
pub fn run_table1(sc: &Scenario, duration_s: f64) -> Result<Vec<Table1Row>> {
    let mut out = Vec::new();
    for case in &sc.file.cases {
        let mut file = sc.file.clone();
        file.sensor = case.sensor.clone();
        file.cases.clear();
        file.mras_enable_s = duration_s; // frozen throughout
        let one = Scenario {
            file,
            origin: format!("{} case {}", sc.origin, case.name),
        };
        let r = run(&one, Variant::Ours, duration_s, false)?;
        let spec = r.summary.after.raw_spectrum_mrad.clone();
        let dominant = spec
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(i, _)| i as u32 + 1);
        out.push((case.name.clone(), case.expect_harmonic, dominant, spec));
    }
    Ok(out)
}

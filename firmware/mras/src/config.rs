//! Configuration of the core, with validation that names the offending field.
//!
//! Every number here has a unit in its name; defaults are the ones measured in
//! `docs/theory.md`.

use core::f32::consts::PI;

#[cfg(feature = "serde")]
mod de;

/// Most harmonic paths one core can run: offset, C/D and fourteen more, a path for each
/// error harmonic m = 1..16 of an N = 1 sensor (`survey::SURVEY_HARMONICS`).
pub const MAX_PATHS: usize = 16;
/// Largest gain per electrical radian of any path: the measured stable range's top
/// (docs/theory.md §5).
pub const MAX_GAIN_PER_RAD: f32 = 0.2;
/// Largest |h| (sensor harmonic number) a path may inject.
pub const MAX_HARMONIC: i8 = 15;

/// Which decoupling term a harmonic path injects (paper Fig. 6).
///
/// Every path cancels one *error harmonic* `m` of the sensor electrical angle θs
/// (angle error ∝ e^{j m θs}); the kinds differ in which sequence `k ∈ {1-m, 1+m}` of
/// the measured vector they inject the correction at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathKind {
    /// Offset vector Xo + jYo (`k = 0`, `m = 1`); also removes h = 2 (eq. 6-7).
    Offset,
    /// Amplitude/quadrature in the paper's X-only form C·cos θ̂s + D·sin θ̂s added to X
    /// (`k = -1`, `m = 2`); also removes h = 3 (eq. 9-15).
    AmplitudeQuadrature,
    /// Sensor harmonic `h` (h > 3 or h < 0) injected as d·e^{j h θ̂s} (`m = |h - 1|`, eq. 16-20).
    Harmonic(i8),
}

impl PathKind {
    /// Error harmonic `m` of θs that this path nulls.
    pub fn error_harmonic(self) -> u8 {
        match self {
            PathKind::Offset => 1,
            PathKind::AmplitudeQuadrature => 2,
            PathKind::Harmonic(h) => (h as i16 - 1).unsigned_abs() as u8,
        }
    }

    /// Sequence `k` of the measured vector the path injects at (its e^{j k θ̂s}).
    pub fn sequence(self) -> i8 {
        match self {
            PathKind::Offset => 0,
            PathKind::AmplitudeQuadrature => -1,
            PathKind::Harmonic(h) => h,
        }
    }

    /// Spatial harmonic of the mechanical angle error this path removes (Table I: `m·N`).
    pub fn mechanical_error_harmonic(self, sensor_periods: u16) -> u32 {
        self.error_harmonic() as u32 * sensor_periods as u32
    }

    pub(crate) fn validate(self) -> Result<(), ConfigError> {
        match self {
            PathKind::Harmonic(h)
                if (0..=3).contains(&h) || h.unsigned_abs() > MAX_HARMONIC as u8 =>
            {
                Err(ConfigError::new(
                    "paths.harmonic",
                    "h must be > 3 or < 0 (h = 2, 3 are covered by offset and C/D) and |h| <= 15",
                ))
            }
            _ => Ok(()),
        }
    }
}

/// A path bank as the core runs it: kinds in path order (a path's index is its place
/// here).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bank {
    kinds: [PathKind; MAX_PATHS],
    len: u8,
}

impl Bank {
    /// The first [`MAX_PATHS`] of `paths`.
    pub fn new(paths: &[PathKind]) -> Self {
        let mut kinds = [PathKind::Offset; MAX_PATHS];
        let len = paths.len().min(MAX_PATHS);
        for (k, p) in kinds.iter_mut().zip(paths) {
            *k = *p;
        }
        Self {
            kinds,
            len: len as u8,
        }
    }

    pub fn as_slice(&self) -> &[PathKind] {
        self.kinds.get(..self.len as usize).unwrap_or(&self.kinds)
    }
}

/// The Luenberger motion observer (paper Fig. 5).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct ObserverConfig {
    /// Closed-loop eigenvalues λ1..λ3 of `Ĵs³ + b_o s² + K_so s + K_iso`, in Hz
    /// (paper: 100/10/1 Hz in simulation, 200/20/2 Hz on the bench).
    pub eigenvalues_hz: [f32; 3],
    /// Estimated inertia Ĵ, which scales the torque feedforward (§V.A).
    pub inertia_kg_m2: f32,
}

impl Default for ObserverConfig {
    fn default() -> Self {
        Self {
            eigenvalues_hz: [100.0, 10.0, 1.0],
            inertia_kg_m2: 1.0e-4,
        }
    }
}

/// How a path turns its correlation into a coefficient change.
#[derive(Clone, Copy, Debug, PartialEq)]
// A flat table with `kind` rather than serde's tagged enum, so a file can set one gain
// and keep the law's other defaults.
#[cfg_attr(feature = "serde", derive(serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(try_from = "de::LawFile"))]
pub enum AdaptationLaw {
    /// Ours: the correlation is compensated by the observer's error transfer function
    /// H(j m N ω̂) (phase, and magnitude with a floor) and integrated over the sensor
    /// electrical angle, so gains are per radian and convergence is counted in revolutions.
    Compensated {
        /// Integral gain per electrical radian of travel (1/rad).
        gain_per_rad: f32,
        /// The offset path's gain per *mechanical* radian (1/rad), used where it exceeds
        /// `gain_per_rad` per electrical radian, and at most [`MAX_GAIN_PER_RAD`]. Offsets
        /// are what drifts (temperature), and a drift happens in time: per electrical
        /// radian alone, an N = 1 sensor would track it half as fast as an N = 2 one at
        /// the same shaft speed. 0 gives the offset `gain_per_rad` like every path.
        offset_gain_per_mech_rad: f32,
        /// Optional proportional term (dimensionless); 0 disables it.
        proportional: f32,
        /// Floor of |H| in the magnitude compensation `1/max(|H|, floor)`.
        h_floor: f32,
    },
    /// The paper, literally: correlation · sign(ω̂), no compensation, PI in time with
    /// K1 (1/s, integral) and K2 (proportional).
    PaperLiteral { k1_per_s: f32, k2: f32 },
}

impl AdaptationLaw {
    /// Our default: 10x error reduction in about two revolutions (docs/theory.md).
    pub const DEFAULT_COMPENSATED: Self = Self::Compensated {
        gain_per_rad: 0.15,
        offset_gain_per_mech_rad: 0.3,
        proportional: 0.0,
        h_floor: 0.05,
    };
    /// The paper's Fig. 8 simulation gains.
    pub const PAPER_FIG8: Self = Self::PaperLiteral {
        k1_per_s: 50.0,
        k2: 0.1,
    };
}

/// Conditions under which adaptation may run (§V.B-C: high speed, low load, steady).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct Gates {
    /// Minimum |ω̂| (rad/s, mechanical).
    pub min_speed_rad_s: f32,
    /// Per path: minimum |H(j m N ω̂)|; below it the error is invisible in ε (ours only).
    pub min_h: f32,
    /// Maximum |ω̂ - ω̂ smoothed| relative to |ω̂ smoothed|: adapt only while the speed
    /// is steady enough for H to be evaluated at the right frequency (and not across a
    /// reversal).
    pub max_speed_deviation: f32,
    /// Maximum |disturbance torque estimate| (N·m); `INFINITY` disables.
    pub max_disturbance_nm: f32,
    /// Maximum commanded acceleration |T*|/Ĵ (rad/s²); `INFINITY` disables. The
    /// command, not the observer's acceleration, which carries the sensor error's ripple.
    pub max_accel_rad_s2: f32,
    /// Maximum fall of the error harmonics' frequencies per sensor-electrical radian,
    /// |dω/dt|/(N·ω²) while |ω̂| slows, taken from the observer's net torque
    /// (T* + T̂d)/Ĵ smoothed like ω̂. Ours only, and only once the bank has converged
    /// (before, the sensor error's own ripple is in that torque). The compensation by H
    /// assumes a steady frequency; through a deceleration or a reversal it
    /// over-compensates and the paths take the observer's transient for sensor error
    /// (docs/theory.md §3, *Speed changes*). `INFINITY` disables.
    pub max_sweep_per_rad: f32,
}

impl Default for Gates {
    fn default() -> Self {
        Self {
            min_speed_rad_s: 1.0,
            min_h: 0.005,
            max_speed_deviation: 0.5,
            max_disturbance_nm: f32::INFINITY,
            max_accel_rad_s2: f32::INFINITY,
            max_sweep_per_rad: 0.02,
        }
    }
}

/// Sensor and observer health limits.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct HealthConfig {
    /// |Z| (scaled, nominal 1) below this: sensor disconnected.
    pub amplitude_min: f32,
    /// |Z| above this: sensor or front end saturated.
    pub amplitude_max: f32,
    /// Angle between the decoupled vector and the reference above which lock is lost (rad,
    /// sensor electrical). An observer that slips a period passes through 90°.
    pub lock_threshold_rad: f32,
    /// Largest |coefficient| relative to the tracked amplitude; adaptation clamps there.
    pub coefficient_limit: f32,
}

impl Default for HealthConfig {
    fn default() -> Self {
        Self {
            amplitude_min: 0.25,
            amplitude_max: 2.0,
            lock_threshold_rad: 1.0,
            coefficient_limit: 0.6,
        }
    }
}

/// The `converged` judgement (see [`crate::Convergence`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct ConvergenceConfig {
    /// Every path's residual error phasor below this (rad, sensor electrical).
    pub residual_rad: f32,
    /// Every path's coefficient change over the last revolution below this (relative to |Z|).
    pub change_per_rev: f32,
    /// At least this many mechanical revolutions of adaptation.
    pub min_revs: u16,
}

impl Default for ConvergenceConfig {
    fn default() -> Self {
        Self {
            residual_rad: 2.0e-3,
            change_per_rev: 2.0e-3,
            min_revs: 2,
        }
    }
}

/// Everything the core needs; validate with [`Config::validate`] (done by `Tracker::new`).
#[derive(Clone, Copy, Debug, PartialEq)]
// The file form lists the paths and leaves out the control period (see `de::ConfigFile`).
#[cfg_attr(feature = "serde", derive(serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(from = "de::ConfigFile"))]
pub struct Config {
    /// Control period T (s).
    pub sample_period_s: f32,
    /// Sensor periods per mechanical revolution N (2 for the KMZ41, pole pairs of a
    /// resolver, lines of a sin/cos encoder).
    pub sensor_periods: u16,
    pub observer: ObserverConfig,
    /// The harmonic path bank; `path_count` entries of `paths` are used.
    pub paths: [PathKind; MAX_PATHS],
    pub path_count: u8,
    /// Complete the bank from the sensor's own error spectrum (`crate::survey`): `paths`
    /// adapt first, until they converge; then, with adaptation paused, the spectrum of
    /// what remains is measured over [`crate::survey::SURVEY_PERIODS`] sensor periods,
    /// and the rest of the bank (up to [`MAX_PATHS`]) goes to the largest harmonics above
    /// the noise floor. A fixed bank (false) adapts `paths` only.
    pub paths_from_data: bool,
    pub law: AdaptationLaw,
    pub gates: Gates,
    pub health: HealthConfig,
    pub convergence: ConvergenceConfig,
}

impl Default for Config {
    /// 20 kHz, N = 2, paper observer 100/10/1 Hz, and a path for every error harmonic
    /// m = 1..7: offset, C/D, h = 4..8. That nulls, to first order, every sensor harmonic
    /// |h| ≤ 6 of either sequence (unequal X and Y terms), the population of the accuracy
    /// benchmark (docs/results.md); the paper's sensor needs only the first four.
    fn default() -> Self {
        let mut c = Self {
            sample_period_s: 50.0e-6,
            sensor_periods: 2,
            observer: ObserverConfig::default(),
            paths: [PathKind::Offset; MAX_PATHS],
            path_count: 0,
            paths_from_data: false,
            law: AdaptationLaw::DEFAULT_COMPENSATED,
            gates: Gates::default(),
            health: HealthConfig::default(),
            convergence: ConvergenceConfig::default(),
        };
        c.set_paths(&[
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(5),
            PathKind::Harmonic(6),
            PathKind::Harmonic(7),
            PathKind::Harmonic(8),
        ])
        .expect("seven paths fit");
        c
    }
}

/// A configuration field that is out of range, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConfigError {
    pub field: &'static str,
    pub problem: &'static str,
}

impl ConfigError {
    pub const fn new(field: &'static str, problem: &'static str) -> Self {
        Self { field, problem }
    }
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "invalid configuration `{}`: {}",
            self.field, self.problem
        )
    }
}

/// So hosts can pass it up with `?` as any error; `core::error::Error` needs no `std`.
impl core::error::Error for ConfigError {}

fn positive_finite(v: f32, field: &'static str) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(ConfigError::new(field, "must be finite and > 0"))
    }
}

fn non_negative_finite(v: f32, field: &'static str) -> Result<(), ConfigError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(ConfigError::new(field, "must be finite and >= 0"))
    }
}

/// A limit that may be `INFINITY` (disabled) but not NaN or <= 0.
fn positive_limit(v: f32, field: &'static str) -> Result<(), ConfigError> {
    if v > 0.0 {
        Ok(())
    } else {
        Err(ConfigError::new(field, "must be > 0 (INFINITY disables)"))
    }
}

impl Config {
    /// Replace the path bank. Fails if more than [`MAX_PATHS`] are given.
    pub fn set_paths(&mut self, paths: &[PathKind]) -> Result<(), ConfigError> {
        if paths.len() > MAX_PATHS {
            return Err(ConfigError::new("paths", "at most 16 paths"));
        }
        self.paths[..paths.len()].copy_from_slice(paths);
        self.path_count = paths.len() as u8;
        Ok(())
    }

    /// The active paths.
    pub fn paths(&self) -> &[PathKind] {
        self.paths
            .get(..self.path_count as usize)
            .unwrap_or(&self.paths)
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        positive_finite(self.sample_period_s, "sample_period_s")?;
        if self.sensor_periods == 0 {
            return Err(ConfigError::new("sensor_periods", "must be >= 1"));
        }

        let ev = self.observer.eigenvalues_hz;
        for v in ev {
            positive_finite(v, "observer.eigenvalues_hz")?;
        }
        // Forward-Euler integration stays close to the continuous design only while
        // every λ·T is small; 0.2 keeps the pole error under ~2 %.
        let fastest = ev[0].max(ev[1]).max(ev[2]);
        if 2.0 * PI * fastest * self.sample_period_s > 0.2 {
            return Err(ConfigError::new(
                "observer.eigenvalues_hz",
                "fastest eigenvalue too close to the sample rate (need 2π·λ·T <= 0.2)",
            ));
        }
        positive_finite(self.observer.inertia_kg_m2, "observer.inertia_kg_m2")?;

        if self.path_count as usize > MAX_PATHS {
            return Err(ConfigError::new("path_count", "at most 16 paths"));
        }
        let paths = self.paths();
        for (n, p) in paths.iter().enumerate() {
            p.validate()?;
            if paths
                .iter()
                .take(n)
                .any(|q| q.error_harmonic() == p.error_harmonic())
            {
                return Err(ConfigError::new(
                    "paths",
                    "two paths null the same error harmonic m = |k-1| (e.g. h = 4 and h = -2); keep one",
                ));
            }
        }
        if self.paths_from_data && paths.len() >= MAX_PATHS {
            return Err(ConfigError::new(
                "paths_from_data",
                "needs room in the bank: give at most 7 `paths` (the first stage)",
            ));
        }

        match self.law {
            AdaptationLaw::Compensated {
                gain_per_rad,
                offset_gain_per_mech_rad,
                proportional,
                h_floor,
            } => {
                // Measured stable range 0.05..0.2 at 2-100 rev/s with the default seven
                // paths; 0.3 oscillates at 5 rev/s (docs/theory.md §5).
                if !(gain_per_rad.is_finite()
                    && gain_per_rad > 0.0
                    && gain_per_rad <= MAX_GAIN_PER_RAD)
                {
                    return Err(ConfigError::new(
                        "law.gain_per_rad",
                        "must be in (0, 0.2] per electrical radian (the measured stable range)",
                    ));
                }
                // Clipped to the stable range per electrical radian where it is used.
                non_negative_finite(offset_gain_per_mech_rad, "law.offset_gain_per_mech_rad")?;
                if !(proportional.is_finite() && (0.0..=0.5).contains(&proportional)) {
                    return Err(ConfigError::new("law.proportional", "must be in [0, 0.5]"));
                }
                if !(h_floor.is_finite() && h_floor > 0.0 && h_floor <= 1.0) {
                    return Err(ConfigError::new("law.h_floor", "must be in (0, 1]"));
                }
            }
            AdaptationLaw::PaperLiteral { k1_per_s, k2 } => {
                positive_finite(k1_per_s, "law.k1_per_s")?;
                non_negative_finite(k2, "law.k2")?;
            }
        }

        let g = &self.gates;
        non_negative_finite(g.min_speed_rad_s, "gates.min_speed_rad_s")?;
        if !(g.min_h.is_finite() && (0.0..1.0).contains(&g.min_h)) {
            return Err(ConfigError::new("gates.min_h", "must be in [0, 1)"));
        }
        positive_limit(g.max_speed_deviation, "gates.max_speed_deviation")?;
        positive_limit(g.max_disturbance_nm, "gates.max_disturbance_nm")?;
        positive_limit(g.max_accel_rad_s2, "gates.max_accel_rad_s2")?;
        positive_limit(g.max_sweep_per_rad, "gates.max_sweep_per_rad")?;

        let h = &self.health;
        positive_finite(h.amplitude_min, "health.amplitude_min")?;
        if !(h.amplitude_max.is_finite() && h.amplitude_max > h.amplitude_min) {
            return Err(ConfigError::new(
                "health.amplitude_max",
                "must be finite and > amplitude_min",
            ));
        }
        if !(h.lock_threshold_rad > 0.0 && h.lock_threshold_rad < PI) {
            return Err(ConfigError::new(
                "health.lock_threshold_rad",
                "must be in (0, π)",
            ));
        }
        if !(h.coefficient_limit > 0.0 && h.coefficient_limit < 1.0) {
            return Err(ConfigError::new(
                "health.coefficient_limit",
                "must be in (0, 1)",
            ));
        }

        let c = &self.convergence;
        positive_finite(c.residual_rad, "convergence.residual_rad")?;
        positive_finite(c.change_per_rev, "convergence.change_per_rev")?;
        Ok(())
    }
}

//! The core's configuration as a TOML table (used by `replay --config` and by the
//! scenario files' `[core]` table).
//!
//! The schema mirrors `mras::Config` field for field, with the same names and units, so
//! that the core's validation errors (`law.gain_per_rad`, `gates.min_h`, ...) name the
//! TOML key to fix. Every field is optional; what is left out keeps the value of
//! `mras::Config::default()` (the measured defaults of docs/theory.md). The control
//! period is not part of the file: it comes from the recording or the scenario.
//!
//! ```toml
//! sensor_periods = 2
//! paths = ["offset", "amplitude-quadrature", "h4", "h5"]
//! [input]
//! offset_x = 2048.0
//! gain_x = 0.001
//! [law]
//! kind = "compensated"
//! gain_per_rad = 0.15
//! ```
//!
//! A complete example is `hil-sim/tests/data/core_config_full.toml`.

use crate::input_error::InputError;
use mras::{AdaptationLaw, Config, ConfigError, PathKind};
use serde::Deserialize;

/// TOML form of `mras::Config`; every field optional, defaults from `mras::Config::default()`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CoreConfigToml {
    /// Sensor periods per mechanical revolution N.
    pub sensor_periods: Option<u16>,
    /// Raw ADC units to the nominal unit vector.
    #[serde(default)]
    pub input: InputToml,
    #[serde(default)]
    pub observer: ObserverToml,
    /// The path bank, in order: `"offset"`, `"amplitude-quadrature"`, `"hN"` (N > 3 or < 0).
    pub paths: Option<Vec<PathName>>,
    #[serde(default)]
    pub law: LawToml,
    #[serde(default)]
    pub gates: GatesToml,
    #[serde(default)]
    pub health: HealthToml,
    #[serde(default)]
    pub convergence: ConvergenceToml,
}

/// `[input]`: `x = (x_raw - offset_x) · gain_x`; `raw_limit` = railed ADC (`inf` disables).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InputToml {
    pub offset_x: Option<f32>,
    pub offset_y: Option<f32>,
    pub gain_x: Option<f32>,
    pub gain_y: Option<f32>,
    pub raw_limit: Option<f32>,
}

/// `[observer]`: eigenvalues λ1..λ3 (Hz) and the inertia Ĵ that scales the feedforward.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ObserverToml {
    pub eigenvalues_hz: Option<[f32; 3]>,
    pub inertia_kg_m2: Option<f32>,
}

/// Which adaptation law `[law]` selects.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum LawKind {
    /// Ours (`gain_per_rad`, `proportional`, `h_floor`).
    #[default]
    Compensated,
    /// The paper's (`k1_per_s`, `k2`).
    PaperLiteral,
}

/// `[law]`: flat rather than a tagged enum so that every key keeps its own line in errors;
/// a key of the other law is refused by [`CoreConfigToml::to_config`].
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LawToml {
    pub kind: Option<LawKind>,
    pub gain_per_rad: Option<f32>,
    pub proportional: Option<f32>,
    pub h_floor: Option<f32>,
    pub k1_per_s: Option<f32>,
    pub k2: Option<f32>,
}

/// `[gates]`: when adaptation may run (`inf` disables a limit).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GatesToml {
    pub min_speed_rad_s: Option<f32>,
    pub min_h: Option<f32>,
    pub max_speed_deviation: Option<f32>,
    pub max_disturbance_nm: Option<f32>,
    pub max_accel_rad_s2: Option<f32>,
}

/// `[health]`: sensor and observer limits.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HealthToml {
    pub amplitude_min: Option<f32>,
    pub amplitude_max: Option<f32>,
    pub lock_threshold_rad: Option<f32>,
    pub coefficient_limit: Option<f32>,
}

/// `[convergence]`: the `converged` judgement.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ConvergenceToml {
    pub residual_rad: Option<f32>,
    pub change_per_rev: Option<f32>,
    pub min_revs: Option<u16>,
}

/// One entry of `paths`, parsed from its string form (see [`path_toml_name`]).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(try_from = "String")]
pub struct PathName(pub PathKind);

/// What the TOML's path list expects, appended to every [`PathNameError`].
const PATH_EXPECTED: &str =
    "expected \"offset\", \"amplitude-quadrature\" or \"hN\" (N > 3 or N < 0, |N| <= 15)";

/// A `paths` entry that names no path of the core.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PathNameError {
    #[error("unknown path \"{0}\": {PATH_EXPECTED}")]
    Unknown(String),
    #[error(
        "path \"{0}\": h = 0..3 is not a harmonic path (h = 2 is removed by \
         \"offset\", h = 3 by \"amplitude-quadrature\"); {PATH_EXPECTED}"
    )]
    NotHarmonic(String),
    #[error("path \"{0}\": |h| above 15; {PATH_EXPECTED}")]
    TooHigh(String),
}

impl TryFrom<String> for PathName {
    type Error = PathNameError;

    fn try_from(s: String) -> Result<Self, PathNameError> {
        let kind = match s.as_str() {
            "offset" => PathKind::Offset,
            // The CSV columns and the firmware's stream spell it with an underscore; a
            // name copied from there is the same path.
            "amplitude-quadrature" | "amplitude_quadrature" => PathKind::AmplitudeQuadrature,
            _ => {
                let Some(h) = s.strip_prefix('h').and_then(|n| n.parse::<i8>().ok()) else {
                    return Err(PathNameError::Unknown(s));
                };
                // Checked here as well as by the core so the error carries the line.
                if (0..=3).contains(&h) {
                    return Err(PathNameError::NotHarmonic(s));
                }
                if h.unsigned_abs() > mras::config::MAX_HARMONIC as u8 {
                    return Err(PathNameError::TooHigh(s));
                }
                PathKind::Harmonic(h)
            }
        };
        Ok(PathName(kind))
    }
}

/// A path's name in the TOML `paths` list: `offset`, `amplitude-quadrature`, `h4`, `h-2`.
pub fn path_toml_name(kind: PathKind) -> String {
    match kind {
        PathKind::Offset => "offset".into(),
        PathKind::AmplitudeQuadrature => "amplitude-quadrature".into(),
        PathKind::Harmonic(h) => format!("h{h}"),
    }
}

/// A configuration field that is out of range, named as in the TOML (`law.gain_per_rad`).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("invalid configuration `{field}`: {problem}")]
pub struct FieldError {
    pub field: String,
    pub problem: String,
}

impl From<ConfigError> for FieldError {
    fn from(e: ConfigError) -> Self {
        Self {
            field: e.field.into(),
            problem: e.problem.into(),
        }
    }
}

/// A core configuration file that does not parse or does not validate: the file, the
/// line when one can be named, and what is wrong there.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConfigFileError {
    /// The TOML does not parse into the schema (syntax, type, unknown key, bad path).
    #[error(transparent)]
    Parse(#[from] InputError),
    /// The values parse but the core refuses them.
    #[error("{origin}{}: {error}", .line.map(|l| format!(":{l}")).unwrap_or_default())]
    Invalid {
        origin: String,
        line: Option<usize>,
        error: FieldError,
    },
}

fn set<T: Copy>(dst: &mut T, v: Option<T>) {
    if let Some(v) = v {
        *dst = v;
    }
}

impl CoreConfigToml {
    /// Parse from TOML text; errors name `origin` (the file), the line and the field.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ConfigFileError> {
        toml::from_str(text).map_err(|e| {
            let line = e.span().map(|span| line_at(text, span.start));
            ConfigFileError::Parse(InputError {
                file: origin.to_string(),
                line: line.map(|l| l as u64),
                // Unknown-field messages already say which key; the prefix adds its table.
                field: line.and_then(|l| key_on_line(text, l)),
                problem: e.message().to_string(),
            })
        })
    }

    /// True when `[input]` sets any offset or gain: the file fixes the scaling, so replay
    /// must not estimate it (`raw_limit` alone does not count).
    pub fn input_given(&self) -> bool {
        let i = &self.input;
        i.offset_x.is_some() || i.offset_y.is_some() || i.gain_x.is_some() || i.gain_y.is_some()
    }

    /// Build and validate the core configuration for a given control period.
    pub fn to_config(&self, sample_period_s: f32) -> Result<mras::Config, FieldError> {
        self.build(sample_period_s)
    }

    /// As [`Self::to_config`], with errors located in the TOML `text` read from `origin`
    /// (`cfg.toml:7: invalid configuration `law.gain_per_rad`: ...`).
    pub fn to_config_located(
        &self,
        sample_period_s: f32,
        origin: &str,
        text: &str,
    ) -> Result<mras::Config, ConfigFileError> {
        self.build(sample_period_s)
            .map_err(|error| ConfigFileError::Invalid {
                origin: origin.to_string(),
                line: line_of_field(text, &error.field),
                error,
            })
    }

    /// Build and validate; the error names the field as the TOML spells it.
    pub fn build(&self, sample_period_s: f32) -> Result<Config, FieldError> {
        let mut c = Config {
            sample_period_s,
            ..Config::default()
        };
        set(&mut c.sensor_periods, self.sensor_periods);

        let i = &self.input;
        set(&mut c.input.offset_x, i.offset_x);
        set(&mut c.input.offset_y, i.offset_y);
        set(&mut c.input.gain_x, i.gain_x);
        set(&mut c.input.gain_y, i.gain_y);
        set(&mut c.input.raw_limit, i.raw_limit);

        set(&mut c.observer.eigenvalues_hz, self.observer.eigenvalues_hz);
        set(&mut c.observer.inertia_kg_m2, self.observer.inertia_kg_m2);

        if let Some(paths) = &self.paths {
            let kinds: Vec<PathKind> = paths.iter().map(|p| p.0).collect();
            c.set_paths(&kinds)?;
        }

        c.law = self.law.to_law()?;

        let g = &self.gates;
        set(&mut c.gates.min_speed_rad_s, g.min_speed_rad_s);
        set(&mut c.gates.min_h, g.min_h);
        set(&mut c.gates.max_speed_deviation, g.max_speed_deviation);
        set(&mut c.gates.max_disturbance_nm, g.max_disturbance_nm);
        set(&mut c.gates.max_accel_rad_s2, g.max_accel_rad_s2);

        let h = &self.health;
        set(&mut c.health.amplitude_min, h.amplitude_min);
        set(&mut c.health.amplitude_max, h.amplitude_max);
        set(&mut c.health.lock_threshold_rad, h.lock_threshold_rad);
        set(&mut c.health.coefficient_limit, h.coefficient_limit);

        let v = &self.convergence;
        set(&mut c.convergence.residual_rad, v.residual_rad);
        set(&mut c.convergence.change_per_rev, v.change_per_rev);
        set(&mut c.convergence.min_revs, v.min_revs);

        c.validate()?;
        Ok(c)
    }
}

impl LawToml {
    fn to_law(&self) -> Result<AdaptationLaw, FieldError> {
        let other = |field: &str, kind: &str| FieldError {
            field: format!("law.{field}"),
            problem: format!("belongs to kind = \"{kind}\", not to this law"),
        };
        match self.kind.unwrap_or_default() {
            LawKind::Compensated => {
                if self.k1_per_s.is_some() {
                    return Err(other("k1_per_s", "paper-literal"));
                }
                if self.k2.is_some() {
                    return Err(other("k2", "paper-literal"));
                }
                let AdaptationLaw::Compensated {
                    mut gain_per_rad,
                    mut proportional,
                    mut h_floor,
                } = AdaptationLaw::DEFAULT_COMPENSATED
                else {
                    unreachable!("DEFAULT_COMPENSATED is the compensated law")
                };
                set(&mut gain_per_rad, self.gain_per_rad);
                set(&mut proportional, self.proportional);
                set(&mut h_floor, self.h_floor);
                Ok(AdaptationLaw::Compensated {
                    gain_per_rad,
                    proportional,
                    h_floor,
                })
            }
            LawKind::PaperLiteral => {
                for (v, f) in [
                    (self.gain_per_rad, "gain_per_rad"),
                    (self.proportional, "proportional"),
                    (self.h_floor, "h_floor"),
                ] {
                    if v.is_some() {
                        return Err(other(f, "compensated"));
                    }
                }
                let AdaptationLaw::PaperLiteral {
                    mut k1_per_s,
                    mut k2,
                } = AdaptationLaw::PAPER_FIG8
                else {
                    unreachable!("PAPER_FIG8 is the paper-literal law")
                };
                set(&mut k1_per_s, self.k1_per_s);
                set(&mut k2, self.k2);
                Ok(AdaptationLaw::PaperLiteral { k1_per_s, k2 })
            }
        }
    }
}

/// 1-based line of a byte offset.
fn line_at(text: &str, byte: usize) -> usize {
    let end = byte.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|b| **b == b'\n')
        .count()
        + 1
}

/// The dotted key (`law.gain_per_rad`) defined on each line, in order: a line-based
/// reading of the usual layout (`[table]` headers, `key = value` lines), used only to
/// name fields and lines in messages.
fn keys_by_line(text: &str) -> impl Iterator<Item = (usize, Option<String>)> + '_ {
    let mut table = String::new();
    text.lines().enumerate().map(move |(n, raw)| {
        let l = raw.trim();
        if let Some(h) = l.strip_prefix('[') {
            let name = h.split(']').next().unwrap_or("").trim();
            table = name.trim_matches('[').trim().to_string();
            return (n + 1, None);
        }
        if l.is_empty() || l.starts_with('#') {
            return (n + 1, None);
        }
        let key = l.split('=').next().unwrap_or("").trim().trim_matches('"');
        if key.is_empty() || !l.contains('=') {
            return (n + 1, None);
        }
        let full = if table.is_empty() {
            key.to_string()
        } else {
            format!("{table}.{key}")
        };
        (n + 1, Some(full))
    })
}

fn key_on_line(text: &str, line: usize) -> Option<String> {
    keys_by_line(text)
        .find(|(n, _)| *n == line)
        .and_then(|(_, k)| k)
}

/// The line that sets `field` (`law.gain_per_rad`), or its closest parent key
/// (`paths` for the core's `paths.harmonic`); `None` when the file leaves it at its default.
pub fn line_of_field(text: &str, field: &str) -> Option<usize> {
    let mut parent: Option<(usize, usize)> = None;
    for (n, key) in keys_by_line(text) {
        let Some(key) = key else { continue };
        if key == field {
            return Some(n);
        }
        let is_parent = field
            .strip_prefix(key.as_str())
            .is_some_and(|rest| rest.starts_with('.'));
        if is_parent && parent.is_none_or(|(len, _)| key.len() > len) {
            parent = Some((key.len(), n));
        }
    }
    parent.map(|(_, n)| n)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FULL: &str = include_str!("../tests/data/core_config_full.toml");

    #[test]
    fn full_file_parses_and_every_field_arrives() {
        let t = CoreConfigToml::from_toml_str(FULL, "full.toml").unwrap();
        assert!(t.input_given());
        let c = t.to_config(100.0e-6).unwrap();
        assert_eq!(c.sample_period_s, 100.0e-6);
        assert_eq!(c.sensor_periods, 4);
        assert_eq!(c.input.offset_x, 2048.0);
        assert_eq!(c.input.gain_y, 1.0 / 1000.0);
        assert_eq!(c.input.raw_limit, 4095.0);
        assert_eq!(c.observer.eigenvalues_hz, [200.0, 20.0, 2.0]);
        assert_eq!(c.observer.inertia_kg_m2, 2.0e-4);
        assert_eq!(
            c.paths(),
            &[
                PathKind::Offset,
                PathKind::AmplitudeQuadrature,
                PathKind::Harmonic(4),
                PathKind::Harmonic(5),
                PathKind::Harmonic(-4),
            ]
        );
        assert_eq!(
            c.law,
            AdaptationLaw::Compensated {
                gain_per_rad: 0.1,
                proportional: 0.05,
                h_floor: 0.1
            }
        );
        assert_eq!(c.gates.max_disturbance_nm, f32::INFINITY);
        assert_eq!(c.gates.max_accel_rad_s2, 5000.0);
        assert_eq!(c.health.coefficient_limit, 0.5);
        assert_eq!(c.convergence.min_revs, 3);
    }

    #[test]
    fn empty_file_is_the_core_default() {
        let t = CoreConfigToml::from_toml_str("", "empty.toml").unwrap();
        assert!(!t.input_given());
        assert_eq!(t.to_config(50.0e-6).unwrap(), Config::default());
    }

    #[test]
    fn paper_literal_law_and_integer_values() {
        let t = CoreConfigToml::from_toml_str(
            "[law]\nkind = \"paper-literal\"\nk1_per_s = 20\n",
            "p.toml",
        )
        .unwrap();
        assert_eq!(
            t.to_config(50.0e-6).unwrap().law,
            AdaptationLaw::PaperLiteral {
                k1_per_s: 20.0,
                k2: 0.1
            }
        );
    }

    #[test]
    fn unknown_field_names_it_its_table_and_line() {
        let text = "sensor_periods = 2\n\n[gates]\nmin_speed_rad_s = 1.0\nmin_speeed = 2.0\n";
        let e = CoreConfigToml::from_toml_str(text, "cfg.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("cfg.toml:5: "), "{e}");
        assert!(e.contains("`gates.min_speeed`"), "{e}");
        assert!(e.contains("unknown field"), "{e}");
    }

    #[test]
    fn wrong_type_names_the_field() {
        let text = "[law]\ngain_per_rad = \"fast\"\n";
        let e = CoreConfigToml::from_toml_str(text, "cfg.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("cfg.toml:2: field `law.gain_per_rad`"), "{e}");
    }

    #[test]
    fn path_names_as_the_csv_columns_spell_them_are_accepted() {
        let t = CoreConfigToml::from_toml_str(
            "paths = [\"offset\", \"amplitude_quadrature\", \"h4\"]\n",
            "p.toml",
        )
        .unwrap();
        let want = ["offset", "amplitude-quadrature", "h4"]
            .map(|s| PathName::try_from(s.to_string()).unwrap());
        assert_eq!(t.paths.as_deref(), Some(&want[..]));
    }

    #[test]
    fn bad_path_string_is_refused_with_its_line() {
        for (bad, why) in [
            ("\"h3\"", "not a harmonic path"),
            ("\"hx\"", "unknown path"),
        ] {
            let text = format!("sensor_periods = 2\npaths = [\"offset\", {bad}]\n");
            let e = CoreConfigToml::from_toml_str(&text, "cfg.toml")
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("cfg.toml:2: field `paths`"), "{e}");
            assert!(e.contains(why), "{e}");
        }
    }

    #[test]
    fn out_of_range_value_names_the_core_field_and_line() {
        let text = "[observer]\ninertia_kg_m2 = 1e-4\n\n[law]\ngain_per_rad = 0.5\n";
        let t = CoreConfigToml::from_toml_str(text, "cfg.toml").unwrap();
        let e = t.to_config(50.0e-6).unwrap_err().to_string();
        assert!(e.contains("`law.gain_per_rad`"), "{e}");
        let e = t
            .to_config_located(50.0e-6, "cfg.toml", text)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("cfg.toml:5: invalid configuration `law.gain_per_rad`"),
            "{e}"
        );
    }

    #[test]
    fn paths_sharing_an_error_harmonic_point_at_paths() {
        let text = "# m = 3 twice\npaths = [\"h4\", \"h-2\"]\n";
        let t = CoreConfigToml::from_toml_str(text, "cfg.toml").unwrap();
        let e = t
            .to_config_located(50.0e-6, "cfg.toml", text)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("cfg.toml:2: invalid configuration `paths`"),
            "{e}"
        );
    }

    #[test]
    fn key_of_the_other_law_is_refused() {
        let text = "[law]\nkind = \"compensated\"\nk2 = 0.1\n";
        let t = CoreConfigToml::from_toml_str(text, "cfg.toml").unwrap();
        let e = t
            .to_config_located(50.0e-6, "cfg.toml", text)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("cfg.toml:3: invalid configuration `law.k2`"),
            "{e}"
        );
    }

    #[test]
    fn eigenvalue_too_fast_for_the_period_is_refused() {
        let t = CoreConfigToml::default();
        let e = t.to_config(1.0e-3).unwrap_err().to_string();
        assert!(e.contains("`observer.eigenvalues_hz`"), "{e}");
    }
}

//! The configuration's file form (feature `serde`), as hil-sim reads it from TOML: the
//! same names, units and tables as the structs, every key optional (what is left out
//! keeps [`Config::default()`]), the paths as a list of names and the law as a flat
//! `[law]` table with a `kind`. The control period is not in the file: the recording or
//! the scenario sets it. Ranges are [`Config::validate`]'s job, not the parser's.

use super::{AdaptationLaw, Config, ConfigError, MAX_PATHS};
use super::{ConvergenceConfig, Gates, HealthConfig, ObserverConfig, PathKind};
use core::fmt;
use serde::de::{Deserializer, Error, SeqAccess, Visitor};

const PATH_EXPECTED: &str =
    "\"offset\", \"amplitude-quadrature\" or \"hN\" (N > 3 or N < 0, |N| <= 15)";

/// A path by name: `offset`, `amplitude-quadrature` (or `amplitude_quadrature`, as the
/// CSV columns and the firmware's stream spell it), `h4`, `h-2`.
impl<'de> serde::Deserialize<'de> for PathKind {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Name;
        impl Visitor<'_> for Name {
            type Value = PathKind;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(PATH_EXPECTED)
            }
            fn visit_str<E: Error>(self, s: &str) -> Result<PathKind, E> {
                let kind = match s {
                    "offset" => PathKind::Offset,
                    "amplitude-quadrature" | "amplitude_quadrature" => {
                        PathKind::AmplitudeQuadrature
                    }
                    _ => match s.strip_prefix('h').and_then(|n| n.parse().ok()) {
                        Some(h) => PathKind::Harmonic(h),
                        None => {
                            let why =
                                format_args!("unknown path \"{s}\": expected {PATH_EXPECTED}");
                            return Err(E::custom(why));
                        }
                    },
                };
                // Checked here as well as by `validate` so the error points at the name.
                kind.validate()
                    .map_err(|e| E::custom(format_args!("path \"{s}\": {}", e.problem)))?;
                Ok(kind)
            }
        }
        d.deserialize_str(Name)
    }
}

/// `paths`: at most [`MAX_PATHS`] names, stored as [`Config`] stores them.
struct PathBank([PathKind; MAX_PATHS], u8);

impl<'de> serde::Deserialize<'de> for PathBank {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct List;
        impl<'de> Visitor<'de> for List {
            type Value = PathBank;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                write!(
                    f,
                    "a list of at most {MAX_PATHS} paths, each {PATH_EXPECTED}"
                )
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<PathBank, A::Error> {
                let mut bank = PathBank([PathKind::Offset; MAX_PATHS], 0);
                while let Some(kind) = seq.next_element()? {
                    let Some(slot) = bank.0.get_mut(bank.1 as usize) else {
                        return Err(Error::custom(ConfigError::new("paths", "at most 16 paths")));
                    };
                    *slot = kind;
                    bank.1 += 1;
                }
                Ok(bank)
            }
        }
        d.deserialize_seq(List)
    }
}

/// [`Config`] as the file has it; `None` keeps the default.
#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ConfigFile {
    sensor_periods: Option<u16>,
    observer: Option<ObserverConfig>,
    paths: Option<PathBank>,
    paths_from_data: Option<bool>,
    law: Option<AdaptationLaw>,
    gates: Option<Gates>,
    health: Option<HealthConfig>,
    convergence: Option<ConvergenceConfig>,
}

impl From<ConfigFile> for Config {
    fn from(f: ConfigFile) -> Self {
        let d = Config::default();
        let PathBank(paths, path_count) = f.paths.unwrap_or(PathBank(d.paths, d.path_count));
        Self {
            sensor_periods: f.sensor_periods.unwrap_or(d.sensor_periods),
            observer: f.observer.unwrap_or(d.observer),
            paths,
            path_count,
            paths_from_data: f.paths_from_data.unwrap_or(d.paths_from_data),
            law: f.law.unwrap_or(d.law),
            gates: f.gates.unwrap_or(d.gates),
            health: f.health.unwrap_or(d.health),
            convergence: f.convergence.unwrap_or(d.convergence),
            ..d
        }
    }
}

#[derive(Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
enum LawKind {
    #[default]
    Compensated,
    PaperLiteral,
}

/// `[law]`: `kind` and the gains of either law; unset gains keep the law's defaults
/// ([`AdaptationLaw::DEFAULT_COMPENSATED`], [`AdaptationLaw::PAPER_FIG8`]).
#[derive(Default, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub(super) struct LawFile {
    kind: LawKind,
    gain_per_rad: Option<f32>,
    offset_gain_per_mech_rad: Option<f32>,
    proportional: Option<f32>,
    h_floor: Option<f32>,
    k1_per_s: Option<f32>,
    k2: Option<f32>,
}

impl TryFrom<LawFile> for AdaptationLaw {
    type Error = ConfigError;

    /// Refuses a gain of the other law, which would otherwise be silently ignored.
    fn try_from(l: LawFile) -> Result<Self, ConfigError> {
        let refuse = |keys: &[(Option<f32>, &'static str)], problem| match keys
            .iter()
            .find(|(v, _)| v.is_some())
        {
            Some((_, field)) => Err(ConfigError::new(field, problem)),
            None => Ok(()),
        };
        let mut law = match l.kind {
            LawKind::Compensated => Self::DEFAULT_COMPENSATED,
            LawKind::PaperLiteral => Self::PAPER_FIG8,
        };
        match &mut law {
            Self::Compensated {
                gain_per_rad,
                offset_gain_per_mech_rad,
                proportional,
                h_floor,
            } => {
                refuse(
                    &[(l.k1_per_s, "law.k1_per_s"), (l.k2, "law.k2")],
                    "belongs to kind = \"paper-literal\", not to this law",
                )?;
                *gain_per_rad = l.gain_per_rad.unwrap_or(*gain_per_rad);
                *offset_gain_per_mech_rad = l
                    .offset_gain_per_mech_rad
                    .unwrap_or(*offset_gain_per_mech_rad);
                *proportional = l.proportional.unwrap_or(*proportional);
                *h_floor = l.h_floor.unwrap_or(*h_floor);
            }
            Self::PaperLiteral { k1_per_s, k2 } => {
                refuse(
                    &[
                        (l.gain_per_rad, "law.gain_per_rad"),
                        (l.offset_gain_per_mech_rad, "law.offset_gain_per_mech_rad"),
                        (l.proportional, "law.proportional"),
                        (l.h_floor, "law.h_floor"),
                    ],
                    "belongs to kind = \"compensated\", not to this law",
                )?;
                *k1_per_s = l.k1_per_s.unwrap_or(*k1_per_s);
                *k2 = l.k2.unwrap_or(*k2);
            }
        }
        Ok(law)
    }
}

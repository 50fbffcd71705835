//! The core's configuration as a TOML table (used by `replay --config` and by the
//! scenario files' `[core]` table).
//!
//! The file is `mras::Config`'s own `Deserialize` (feature `serde`): the names, tables
//! and units of its structs, so the core's validation errors (`law.gain_per_rad`,
//! `gates.min_h`, ...) name the TOML key to fix. Every key is optional; what is left out
//! keeps `mras::Config::default()`. The control period is not in the file: it comes from
//! the recording or the scenario. A complete example is
//! `hil-sim/tests/data/core_config_full.toml`.
//!
//! One table is not the core's: `[input]`, replay's front end (the firmware's is its ADC
//! scaling, `drive::adc`).
//!
//! Here: what serde cannot say, the line and the dotted key of an error, from the spans
//! of the parse into a spanned table.

use crate::front_end::FrontEnd;
use crate::input_error::InputError;
use mras::{Config, ConfigError, PathKind};
use serde::Deserialize;
use std::ops::Range;
use toml::de::{DeTable, DeValue};

/// A parsed core configuration file, with what it needs to point errors at lines.
#[derive(Clone, Debug)]
pub struct CoreConfigFile {
    /// As the file sets it; the control period is still the default's.
    pub config: Config,
    /// `[input]` as the file sets it.
    pub input: FrontEnd,
    origin: String,
    text: String,
    /// Every key, dotted (`law.gain_per_rad`), with the spans of its name and its value;
    /// a table's keys follow it.
    keys: Vec<(String, Range<usize>, Range<usize>)>,
}

impl CoreConfigFile {
    /// Parse TOML `text` read from `origin` (the file as the user named it).
    pub fn parse(text: &str, origin: &str) -> Result<Self, InputError> {
        let mut keys = Vec::new();
        // Best effort when the text does not parse: the keys before the error still count.
        collect_keys(DeTable::parse_recoverable(text).0.get_ref(), "", &mut keys);
        let mut file = Self {
            config: Config::default(),
            input: FrontEnd::default(),
            origin: origin.into(),
            text: text.into(),
            keys,
        };
        let mut root = DeTable::parse(text).map_err(|e| file.toml_error(&e))?;
        // `[input]` apart, the rest is the core's; the spans stay those of `text`.
        if let Some(input) = root.get_mut().remove("input") {
            let span = input.span();
            let DeValue::Table(table) = input.into_inner() else {
                return Err(file.locate(ConfigError::new("input", "must be a table")));
            };
            let table = toml::de::Deserializer::from(toml::Spanned::new(span, table));
            file.input = FrontEnd::deserialize(table).map_err(|e| file.toml_error(&e))?;
        }
        let core = toml::de::Deserializer::from(root);
        file.config = Config::deserialize(core).map_err(|e| file.toml_error(&e))?;
        Ok(file)
    }

    /// Whether the file sets the dotted `key` (`sensor_periods`, `input.gain_x`).
    pub fn sets(&self, key: &str) -> bool {
        self.keys.iter().any(|(k, ..)| k == key)
    }

    /// True when `[input]` sets any offset or gain: the file fixes the scaling, so replay
    /// must not estimate it (`raw_limit` alone does not count).
    pub fn input_given(&self) -> bool {
        ["offset_x", "offset_y", "gain_x", "gain_y"]
            .iter()
            .any(|k| self.sets(&format!("input.{k}")))
    }

    /// The configuration for the control period `sample_period_s`, validated.
    pub fn to_config(&self, sample_period_s: f32) -> Result<Config, InputError> {
        let c = Config {
            sample_period_s,
            ..self.config
        };
        c.validate().map_err(|e| self.locate(e))?;
        Ok(c)
    }

    /// The core's refusal, at the line of its field:
    /// `cfg.toml:5: invalid configuration `law.gain_per_rad`: ...`.
    pub fn locate(&self, e: ConfigError) -> InputError {
        InputError {
            line: self.line_of(e.field),
            ..InputError::new(&self.origin, e.to_string())
        }
    }

    /// The line of `key`, else of its closest parent in the file (`paths` for
    /// `paths.harmonic`, `[law]` for a law key the file leaves at its default).
    fn line_of(&self, key: &str) -> Option<u64> {
        let set = self.keys.iter();
        let set = set.filter(|(k, ..)| key == k || key.starts_with(&format!("{k}.")));
        let (_, name, _) = set.max_by_key(|(k, ..)| k.len())?;
        Some(self.line_at(name.start))
    }

    fn toml_error(&self, e: &toml::de::Error) -> InputError {
        let problem = e.message();
        // serde carries only a message. The core's refusals while parsing (a key of the
        // other law, too many paths) are `ConfigError`'s text naming the key: point at
        // that key rather than at its table.
        let named = problem.strip_prefix("invalid configuration `");
        if let Some(key) = named.and_then(|rest| rest.split('`').next()) {
            return InputError {
                line: self.line_of(key),
                ..InputError::new(&self.origin, problem)
            };
        }
        let pos = e.span().map(|s| s.start);
        // The innermost key whose name or value holds the error. Unknown-field messages
        // already say which key; the dotted name adds its table.
        let keys = self.keys.iter().rev();
        let mut key = keys.filter(|(_, name, value)| {
            pos.is_some_and(|p| name.contains(&p) || value.contains(&p))
        });
        InputError {
            line: pos.map(|p| self.line_at(p)),
            field: key.next().map(|(k, ..)| k.clone()),
            ..InputError::new(&self.origin, problem)
        }
    }

    /// 1-based line of a byte offset.
    fn line_at(&self, byte: usize) -> u64 {
        self.text[..byte.min(self.text.len())].matches('\n').count() as u64 + 1
    }
}

fn collect_keys(
    table: &DeTable,
    prefix: &str,
    out: &mut Vec<(String, Range<usize>, Range<usize>)>,
) {
    for (k, v) in table {
        let key = format!("{prefix}{}", k.get_ref());
        out.push((key.clone(), k.span(), v.span()));
        if let DeValue::Table(t) = v.get_ref() {
            collect_keys(t, &format!("{key}."), out);
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use mras::AdaptationLaw;

    const FULL: &str = include_str!("../tests/data/core_config_full.toml");

    fn parse(text: &str) -> CoreConfigFile {
        CoreConfigFile::parse(text, "cfg.toml").unwrap()
    }

    fn parse_error(text: &str) -> String {
        CoreConfigFile::parse(text, "cfg.toml")
            .unwrap_err()
            .to_string()
    }

    fn config_error(text: &str) -> String {
        parse(text).to_config(50.0e-6).unwrap_err().to_string()
    }

    #[test]
    fn full_file_parses_and_every_field_arrives() {
        let t = parse(FULL);
        assert!(t.input_given() && t.sets("sensor_periods"));
        let c = t.to_config(100.0e-6).unwrap();
        assert_eq!(c.sample_period_s, 100.0e-6);
        assert_eq!(c.sensor_periods, 4);
        assert_eq!(t.input.offset_x, 2048.0);
        assert_eq!(t.input.gain_y, 1.0 / 1000.0);
        assert_eq!(t.input.raw_limit, 4095.0);
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
        let t = parse("");
        assert!(!t.input_given() && !t.sets("sensor_periods"));
        assert_eq!(t.to_config(50.0e-6).unwrap(), Config::default());
        assert_eq!(t.input, FrontEnd::default());
    }

    #[test]
    fn a_partial_table_keeps_the_other_defaults() {
        let t = parse("[gates]\nmin_h = 0.01\n[input]\nraw_limit = 4095\n");
        let (c, d) = (t.config, Config::default());
        assert_eq!(c.gates.min_h, 0.01);
        assert_eq!(c.gates.min_speed_rad_s, d.gates.min_speed_rad_s);
        assert_eq!(t.input.raw_limit, 4095.0);
        assert_eq!(t.input.gain_x, FrontEnd::default().gain_x);
        assert!(!parse("[input]\nraw_limit = 4095\n").input_given());
    }

    #[test]
    fn input_table_errors_name_their_line() {
        let e = parse_error("sensor_periods = 2\n[input]\ngain_x = 0.5\nofset_x = 1\n");
        assert!(
            e.starts_with("cfg.toml:4: ") && e.contains("`input.ofset_x`"),
            "{e}"
        );
        let e = parse_error("sensor_periods = 2\ninput = 3\n");
        assert!(
            e.starts_with("cfg.toml:2: ") && e.contains("must be a table"),
            "{e}"
        );
    }

    #[test]
    fn paper_literal_law_and_integer_values() {
        let t = parse("[law]\nkind = \"paper-literal\"\nk1_per_s = 20\n");
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
        let e =
            parse_error("sensor_periods = 2\n\n[gates]\nmin_speed_rad_s = 1.0\nmin_speeed = 2.0\n");
        assert!(e.starts_with("cfg.toml:5: "), "{e}");
        assert!(e.contains("`gates.min_speeed`"), "{e}");
        assert!(e.contains("unknown field"), "{e}");
    }

    #[test]
    fn wrong_type_names_the_field() {
        let e = parse_error("[law]\ngain_per_rad = \"fast\"\n");
        assert!(e.starts_with("cfg.toml:2: field `law.gain_per_rad`"), "{e}");
    }

    #[test]
    fn path_names_as_the_csv_columns_spell_them_are_accepted() {
        let t = parse("paths = [\"offset\", \"amplitude_quadrature\", \"h4\"]\n");
        let want = [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
        ];
        assert_eq!(t.config.paths(), &want);
    }

    #[test]
    fn bad_path_string_is_refused_with_its_line() {
        for (bad, why) in [
            ("\"h3\"", "h must be > 3 or < 0"),
            ("\"h16\"", "|h| <= 15"),
            ("\"hx\"", "unknown path"),
        ] {
            let e = parse_error(&format!(
                "sensor_periods = 2\npaths = [\"offset\", {bad}]\n"
            ));
            assert!(e.starts_with("cfg.toml:2: field `paths`"), "{e}");
            assert!(e.contains(why), "{e}");
        }
    }

    #[test]
    fn too_many_paths_point_at_paths() {
        let e = parse_error("sensor_periods = 2\npaths = [\"offset\", \"h4\", \"h5\", \"h6\", \"h7\", \"h8\", \"h9\", \"h10\", \"h11\"]\n");
        assert!(
            e.starts_with("cfg.toml:2: invalid configuration `paths`: at most 8 paths"),
            "{e}"
        );
    }

    #[test]
    fn out_of_range_value_names_the_core_field_and_line() {
        let e = config_error("[observer]\ninertia_kg_m2 = 1e-4\n\n[law]\ngain_per_rad = 0.5\n");
        assert!(
            e.starts_with("cfg.toml:5: invalid configuration `law.gain_per_rad`"),
            "{e}"
        );
        // Dotted keys and inline tables are the same keys.
        for text in ["law.gain_per_rad = 0.5\n", "law = { gain_per_rad = 0.5 }\n"] {
            let e = config_error(text);
            assert!(
                e.starts_with("cfg.toml:1: invalid configuration `law.gain_per_rad`"),
                "{e}"
            );
        }
    }

    #[test]
    fn paths_sharing_an_error_harmonic_point_at_paths() {
        let e = config_error("# m = 3 twice\npaths = [\"h4\", \"h-2\"]\n");
        assert!(
            e.starts_with("cfg.toml:2: invalid configuration `paths`"),
            "{e}"
        );
    }

    #[test]
    fn key_of_the_other_law_is_refused() {
        for (text, line, key) in [
            ("[law]\nkind = \"compensated\"\nk2 = 0.1\n", 3, "law.k2"),
            ("[law]\nk1_per_s = 20.0\n", 2, "law.k1_per_s"),
            (
                "[law]\nh_floor = 0.1\nkind = \"paper-literal\"\n",
                2,
                "law.h_floor",
            ),
        ] {
            let e = parse_error(text);
            let want = format!("cfg.toml:{line}: invalid configuration `{key}`: belongs to");
            assert!(e.starts_with(&want), "{e}");
        }
    }

    #[test]
    fn eigenvalue_too_fast_for_the_period_is_refused() {
        let e = parse("").to_config(1.0e-3).unwrap_err().to_string();
        assert!(e.contains("`observer.eigenvalues_hz`"), "{e}");
    }
}

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
use mras::{Config, ConfigError};
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

//! The core's configuration as a TOML table (used by `replay --config` and by the
//! scenario files' `[core]` table). STUB: being written.

use serde::Deserialize;

/// TOML form of `mras::Config`; every field optional, defaults from `mras::Config::default()`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CoreConfigToml {}

impl CoreConfigToml {
    /// Parse from TOML text; errors name the file's line and the field.
    pub fn from_toml_str(_text: &str, _origin: &str) -> Result<Self, String> {
        Err("not implemented yet".into())
    }

    /// Build and validate the core configuration for a given control period.
    pub fn to_config(&self, sample_period_s: f32) -> Result<mras::Config, String> {
        let cfg = mras::Config {
            sample_period_s,
            ..mras::Config::default()
        };
        cfg.validate().map_err(|e| e.to_string())?;
        Ok(cfg)
    }
}

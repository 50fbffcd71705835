//! Replay's front end (`[input]` of `--config`): a recording's raw units to the core's.
//! The firmware's front end is its ADC scaling, `drive::adc`; the core takes scaled
//! samples from either.

use mras::{ConfigError, Fault};
use serde::Deserialize;

/// `[input]`: a recording's raw units to the core's, `x = (x_raw - offset_x) · gain_x`,
/// and the level at which a raw channel is railed.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FrontEnd {
    pub offset_x: f32,
    pub offset_y: f32,
    pub gain_x: f32,
    pub gain_y: f32,
    /// |raw| at or above this is a railed (saturated) channel; `inf` disables.
    pub raw_limit: f32,
    /// Quadrature correction: `y += skew · x` after scaling. Not a config key: replay sets
    /// it from an ellipse fit of the recording (a shaft moving at m = 1, 2, see
    /// `replay`); 0 leaves the scaling exactly as the keys give it.
    #[serde(skip)]
    pub skew: f32,
}

impl Default for FrontEnd {
    fn default() -> Self {
        Self {
            offset_x: 0.0,
            offset_y: 0.0,
            gain_x: 1.0,
            gain_y: 1.0,
            raw_limit: f32::INFINITY,
            skew: 0.0,
        }
    }
}

impl FrontEnd {
    /// The sample in the core's units, or the fault a railed channel is. Non-finite
    /// values pass through for the core to refuse by name.
    pub fn scale(&self, x_raw: f32, y_raw: f32) -> Result<(f32, f32), Fault> {
        if x_raw.abs() >= self.raw_limit || y_raw.abs() >= self.raw_limit {
            return Err(Fault::SensorSaturated);
        }
        let x = (x_raw - self.offset_x) * self.gain_x;
        let y = (y_raw - self.offset_y) * self.gain_y;
        // (Only when set: without it the samples are bit for bit the keys' scaling.)
        if self.skew != 0.0 {
            return Ok((x, y + self.skew * x));
        }
        Ok((x, y))
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        for (v, field) in [
            (self.offset_x, "input.offset_x"),
            (self.offset_y, "input.offset_y"),
            (self.skew, "input (ellipse fit's quadrature)"),
        ] {
            if !v.is_finite() {
                return Err(ConfigError::new(field, "must be finite"));
            }
        }
        for (v, field) in [(self.gain_x, "input.gain_x"), (self.gain_y, "input.gain_y")] {
            if !(v.is_finite() && v != 0.0) {
                return Err(ConfigError::new(field, "must be finite and non-zero"));
            }
        }
        if self.raw_limit.is_nan() || self.raw_limit <= 0.0 {
            return Err(ConfigError::new(
                "input.raw_limit",
                "must be > 0 (inf disables)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scales_refuses_railed_channels_and_passes_non_finite_on() {
        let f = FrontEnd {
            offset_x: 2048.0,
            offset_y: 2000.0,
            gain_x: 1.0 / 1600.0,
            gain_y: -1.0 / 1500.0,
            raw_limit: 4095.0,
            skew: 0.0,
        };
        assert_eq!(f.scale(3648.0, 500.0), Ok((1.0, 1.0)));
        assert_eq!(f.scale(4095.0, 2000.0), Err(Fault::SensorSaturated));
        assert_eq!(f.scale(2048.0, -4095.0), Err(Fault::SensorSaturated));
        let (x, y) = f.scale(f32::NAN, 2000.0).unwrap();
        assert!(x.is_nan() && y == 0.0);
        assert_eq!(FrontEnd::default().scale(3.5, -1e30), Ok((3.5, -1e30)));
    }

    #[test]
    fn validation_names_the_field() {
        let d = FrontEnd::default();
        for (bad, field) in [
            (
                FrontEnd {
                    offset_y: f32::NAN,
                    ..d
                },
                "input.offset_y",
            ),
            (FrontEnd { gain_x: 0.0, ..d }, "input.gain_x"),
            (
                FrontEnd {
                    gain_y: f32::INFINITY,
                    ..d
                },
                "input.gain_y",
            ),
            (
                FrontEnd {
                    raw_limit: 0.0,
                    ..d
                },
                "input.raw_limit",
            ),
            (
                FrontEnd {
                    raw_limit: f32::NAN,
                    ..d
                },
                "input.raw_limit",
            ),
        ] {
            assert_eq!(bad.validate().unwrap_err().field, field);
        }
        assert!(d.validate().is_ok());
    }
}

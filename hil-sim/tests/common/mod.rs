//! What the replay tests share: the converter their recordings are quantised with, the
//! configuration that makes replay read them as they are, and running the binary.

use mras_sim::Adc;
use std::path::Path;
use std::process::{Command, Output};

/// The control period of the recordings.
pub const SAMPLE_PERIOD_S: f64 = 50.0e-6;
pub const ADC: Adc = Adc {
    bits: 12,
    full_scale: 1.5,
};
/// Identity input scaling, so that the live tracker and replay agree on every field
/// (without [input] replay would estimate the scaling from the data).
pub const IDENTITY_CONFIG: &str = "\
sensor_periods = 2
[input]
offset_x = 0.0
offset_y = 0.0
gain_x = 1.0
gain_y = 1.0
";

pub fn hil_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(args)
        .output()
        .expect("hil-sim runs")
}

pub fn path_str(p: &Path) -> &str {
    p.to_str().expect("temp paths are UTF-8")
}

pub fn report(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("report written"))
        .expect("report is JSON")
}

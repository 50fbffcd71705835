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

/// One replay run's files in a temporary directory: IN.csv (and CFG.toml) written,
/// OUT.csv and REPORT.json named.
pub struct Files {
    /// Keeps the directory (removed when dropped).
    _dir: tempfile::TempDir,
    pub input: std::path::PathBuf,
    pub output: std::path::PathBuf,
    pub config: Option<std::path::PathBuf>,
    pub report: std::path::PathBuf,
}

impl Files {
    pub fn new(input_text: &str, config_text: Option<&str>) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("IN.csv");
        std::fs::write(&input, input_text).unwrap();
        let config = config_text.map(|c| {
            let p = dir.path().join("CFG.toml");
            std::fs::write(&p, c).unwrap();
            p
        });
        Self {
            input,
            output: dir.path().join("OUT.csv"),
            config,
            report: dir.path().join("REPORT.json"),
            _dir: dir,
        }
    }

    /// `replay` over these files, then `extra`.
    pub fn args<'a>(&'a self, extra: &[&'a str]) -> Vec<&'a str> {
        let mut args = vec!["replay", "--input", path_str(&self.input)];
        args.extend(["--output", path_str(&self.output)]);
        args.extend(["--report", path_str(&self.report)]);
        if let Some(c) = &self.config {
            args.extend(["--config", path_str(c)]);
        }
        args.extend(extra);
        args
    }

    /// Run replay over these files with `extra`; it must succeed. Its stdout.
    pub fn run(&self, extra: &[&str]) -> String {
        let out = hil_sim(&self.args(extra));
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    }
}

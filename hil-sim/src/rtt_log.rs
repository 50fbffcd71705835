//! `hil-sim rtt-log`: a captured RTT stream of the firmware to CSV and plots.
//! STUB: being written.

use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Captured `probe-rs run` output or saved log.
    #[arg(long)]
    pub input: PathBuf,
    /// CSV to write.
    #[arg(long)]
    pub output: PathBuf,
    /// Directory for PNG/SVG plots (none if absent).
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

pub fn run(_a: &Args) -> Result<(), String> {
    Err("rtt-log: not implemented yet".into())
}

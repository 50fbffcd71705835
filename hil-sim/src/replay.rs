//! `hil-sim replay`: the core over recorded data. STUB: being written.

use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    #[arg(long)]
    pub input: PathBuf,
    #[arg(long)]
    pub output: PathBuf,
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[arg(long, default_value_t = 2)]
    pub sensor_periods: u16,
    #[arg(long)]
    pub report: Option<PathBuf>,
}

pub fn run(_a: &Args) -> Result<(), String> {
    Err("replay: not implemented yet".into())
}

//! `hil-sim`: the firmware's control period and supervisor, step for step, against a
//! simulated SPMSM drive; the core alone against kinematic rotors and recorded data.

use clap::{Parser, Subcommand};
use hil_sim::{
    accuracy, cli as cmd, commission, figures, probe_bench, replay, rtt_log, study, vector,
};
use std::process::ExitCode;

#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Kinematic self-commissioning (rigid rotor, perfect feedforward) of the extreme
    /// sensor at constant speed: the core alone, no drive model.
    Commission(commission::Args),
    /// Revolutions to a 10x error reduction, ours vs the paper-literal law, per speed
    /// (the table in docs/theory.md).
    CompareLaws(study::CompareArgs),
    /// Revolutions to 10x over adaptation gain and speed: the stable gain range.
    GainSweep(study::SweepArgs),
    /// Run the core over recorded sensor data (CSV) and write its estimates.
    Replay(replay::Args),
    /// Run a scenario by name: the firmware's control period (and, for `commissioning`,
    /// its supervisor) on the simulated SPMSM drive; paper scenarios run the paper's law
    /// and ours side by side and write CSV, JSON and plots.
    Scenario(cmd::ScenarioArgs),
    /// Simulated seconds per wall second of the full drive model.
    Bench(cmd::BenchArgs),
    /// The firmware's RTT stream (raw defmt bytes) decoded against its ELF into CSV, an
    /// event table and plots.
    RttLog(rtt_log::Args),
    /// A drive on a debug probe (probe-rs): flash the firmware, record its RTT stream raw
    /// and decoded live (`attach`), or run the commissioning power-up and the reboot with
    /// the stored calibration (`power-up`). Attaching halts the core briefly.
    Probe(probe_bench::Args),
    /// Accuracy benchmark: the MRAS against offline calibrations on random simulated
    /// sensors (writes docs/results.md, its plots and a per-sensor CSV).
    BenchAccuracy(accuracy::report::Args),
    /// Write an input vector for the emulated Cortex-M4F and the host's trace over it.
    QemuVector(vector::Args),
    /// Run the docs' figure generators and write their sections (docs/figures/*.md;
    /// `cargo xtask docs` splices them into the pages).
    Figures(figures::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        // The README's main job: the firmware's control period and supervisor
        // commissioning the simulated drive (two power-ups: erased flash, then stored
        // calibration).
        None => cmd::scenario(&cmd::ScenarioArgs::named("commissioning")),
        Some(Command::Commission(a)) => commission::run(&a),
        Some(Command::CompareLaws(a)) => study::compare_laws(&a),
        Some(Command::GainSweep(a)) => study::gain_sweep(&a),
        Some(Command::Replay(a)) => replay::run(&a),
        Some(Command::Scenario(a)) => cmd::scenario(&a),
        Some(Command::Bench(a)) => cmd::bench(&a),
        Some(Command::RttLog(a)) => rtt_log::run(&a),
        Some(Command::Probe(a)) => probe_bench::run(&a),
        Some(Command::BenchAccuracy(a)) => accuracy::report::run(&a),
        Some(Command::QemuVector(a)) => vector::run(&a),
        Some(Command::Figures(a)) => figures::run(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // The whole chain: the file or flag, then what went wrong with it.
            eprintln!("hil-sim: {e:#}");
            ExitCode::FAILURE
        }
    }
}

//! `drive-emu`: the release firmware ELF on the emulated board.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use drive_emu::scenarios;
use std::path::PathBuf;

#[derive(Parser)]
#[command(about = "Runs the release drive-fw ELF on an emulated STM32G474 driving hil-sim's simulated motor")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Power-up with an erased calibration area (commissioning → Run), then again with
    /// the stored one (load → Run): states, errors, the interrupt budget, the stream as
    /// CSV and plots.
    PowerUp {
        /// Firmware ELF (default: this checkout's release build).
        #[arg(long)]
        elf: Option<PathBuf>,
        /// Where the capture, CSV and plots go.
        #[arg(long, default_value = "target/emu")]
        out: PathBuf,
    },
    /// Run scenarios (all when none named) and print their measurements.
    Scenarios {
        #[arg(long)]
        elf: Option<PathBuf>,
        /// Write the markdown report (docs/performance.md's section) here.
        #[arg(long)]
        report: Option<PathBuf>,
        names: Vec<String>,
    },
}

fn read_elf(elf: Option<PathBuf>) -> Result<(PathBuf, Vec<u8>)> {
    let path = elf.unwrap_or_else(hil_sim::stream::release_elf);
    let bytes = std::fs::read(&path).with_context(|| {
        format!(
            "{}: cannot read the firmware ELF (build it: `cargo xtask build-cross`, or pass --elf)",
            path.display()
        )
    })?;
    Ok((path, bytes))
}

fn main() -> Result<()> {
    match Cli::parse().cmd {
        Cmd::PowerUp { elf, out } => power_up(elf, out),
        Cmd::Scenarios { elf, report, names } => {
            let (path, bytes) = read_elf(elf)?;
            let names: Vec<String> = if names.is_empty() {
                scenarios::ALL.iter().map(|s| s.to_string()).collect()
            } else {
                names
            };
            let mut outcomes = Vec::new();
            for n in &names {
                eprintln!("drive-emu: scenario {n} ...");
                let o = scenarios::run(n, &bytes)?;
                eprintln!(
                    "  {} boot(s), {} missed periods, ISR {:.0}/{} instructions mean/max, {:.1} s wall",
                    o.boots, o.missed_periods, o.isr_instrs_mean, o.isr_instrs_max, o.wall_s
                );
                outcomes.push(o);
            }
            let note = format!("Firmware: `{}` ({} bytes).", path.display(), bytes.len());
            let text = scenarios::report(&outcomes, &note);
            match report {
                Some(p) => {
                    std::fs::write(&p, &text).with_context(|| p.display().to_string())?;
                    eprintln!("drive-emu: report written to {}", p.display());
                }
                None => println!("{text}"),
            }
            Ok(())
        }
    }
}

fn power_up(elf: Option<PathBuf>, out: PathBuf) -> Result<()> {
    let (path, bytes) = read_elf(elf)?;
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    println!("drive-emu: {} on the emulated STM32G474, the `commissioning` scenario's motor and sensor", path.display());
    let run = scenarios::power_up_run(&bytes)?;
    for l in run.outcome.state_lines() {
        println!("  {l}");
    }
    for e in run.outcome.events.iter().filter(|e| e.kind != "mras-state") {
        println!("  boot {}: {} {}", e.boot + 1, e.kind, e.text);
    }
    println!(
        "  sensor error before (raw, against the simulated rotor): {:.1} mrad pk-pk mechanical",
        run.raw_error_pkpk_rad * 1e3
    );
    println!(
        "  MRAS residual in Adapt at first → in Run: {:.2} → {:.3} mrad (the firmware's own measure, streamed)",
        run.residual_first_rad * 1e3,
        run.residual_run_rad * 1e3
    );
    let o = &run.outcome;
    println!(
        "  control interrupt: {:.0} mean / {} max executed instructions of the {} per period; \
         longest interrupt-masked stretch {} instructions; {} missed periods in {} control periods",
        o.isr_instrs_mean, o.isr_instrs_max, 8500, o.masked_max_instrs, o.missed_periods, o.control_periods
    );
    if o.violations.is_empty() {
        println!("  hardware rules: none broken");
    }
    for v in &o.violations {
        println!("  rule broken: {v}");
    }
    for (i, capture) in run.captures.iter().enumerate() {
        let raw = out.join(format!("power-up-{}.defmt", i + 1));
        std::fs::write(&raw, capture).with_context(|| raw.display().to_string())?;
        let args = hil_sim::rtt_log::Args {
            input: raw.clone(),
            elf: Some(path.clone()),
            output: out.join(format!("power-up-{}.csv", i + 1)),
            plots: Some(out.join(format!("plots-{}", i + 1))),
        };
        hil_sim::rtt_log::run(&args).map_err(anyhow::Error::msg)?;
    }
    println!(
        "  the RTT captures (raw defmt), their CSV, events and plots (rtt-log): {}/",
        out.display()
    );
    println!("  emulated {:.2} s in {:.1} s wall", o.emulated_s, o.wall_s);
    Ok(())
}

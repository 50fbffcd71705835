//! `drive-emu`: the release firmware ELF on the emulated board.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use drive_emu::scenarios::{self, pieces};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    about = "Runs the release drive-fw ELF on an emulated STM32G474 driving hil-sim's simulated motor"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// The bench workflow through probe-rs on an erased emulated STM32G474: probe-rs's
    /// own flash algorithm flashes the ELF, its RTT client records the commissioning
    /// power-up, the same ELF is flashed again (the calibration pages survive) and the
    /// reboot that loads the calibration is recorded; `hil-sim probe power-up` is the
    /// same workflow with a real probe.
    Bench {
        /// Firmware ELF (default: this checkout's release build).
        #[arg(long)]
        elf: Option<PathBuf>,
        /// Where the captures, CSV, events and plots go.
        #[arg(long, default_value = "target/bench")]
        out: PathBuf,
        /// Firmware seconds to record once in Run.
        #[arg(long, default_value_t = 1.0)]
        hold_s: f64,
    },
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
        /// Write the table (docs/figures/emu-report.md) here.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Write each scenario's details (docs/figures/emu-scenarios.md) here.
        #[arg(long)]
        details: Option<PathBuf>,
        /// The `fast-run` build (Run near the voltage limit): the details then end with
        /// its Run at the plant beside the release ELF's.
        #[arg(long)]
        fast_elf: Option<PathBuf>,
        /// Take each scenario a run of the emulator's tests left here (`DRIVE_EMU_PIECES`
        /// when they ran) on the same ELFs, instead of running it again.
        #[arg(long)]
        reuse: Option<PathBuf>,
        names: Vec<String>,
    },
    /// Per firmware build: the commissioning power-up to Run, then the control
    /// interrupt's instructions and estimated cycles by stage over a window of Run.
    /// The gate of every build: fails on a HardFault, a broken rule, a missed period,
    /// an interrupt or masked stretch over budget, or the adaptation task past its
    /// deadline (budget.rs; known failures listed there with their figures).
    Perf {
        /// `LABEL=ELF`, once per build (e.g. `20 kHz=target/perf/drive-fw-20k`).
        #[arg(long = "build", required_unless_present = "n1_builds")]
        builds: Vec<String>,
        /// `LABEL=ELF` of a build with `sensor-n1`: run on the board with an N = 1 sensor.
        #[arg(long = "n1-build")]
        n1_builds: Vec<String>,
        /// Length of the measurement window in Run (emulated seconds).
        #[arg(long, default_value_t = 0.5)]
        window_s: f64,
        /// Write the tables here (docs/figures/perf.md).
        #[arg(long)]
        report: Option<PathBuf>,
    },
    /// The torque-ripple learner on the ELF: each build (`LABEL=ELF`, built with
    /// `sensor-n1` and a low Run speed, `slow-run` or `run-5rev`, with or without
    /// `learn-ripple`) commissioned on `ripple-1rev`'s rig and N = 1 sensor, then its
    /// Run scored at the plant (ripple_elf.rs): θ̂ against the rotor by harmonic, the
    /// rotor's motion.
    Ripple {
        /// `LABEL=ELF`, once per build.
        #[arg(long = "build", required = true)]
        builds: Vec<String>,
        /// Emulated seconds of Run before the scored window.
        #[arg(long, default_value_t = drive_emu::ripple_elf::PLAN.settle_s)]
        settle_s: f64,
        /// Emulated seconds scored (the whole revolutions in them).
        #[arg(long, default_value_t = drive_emu::ripple_elf::PLAN.window_s)]
        window_s: f64,
        /// Write the table here (docs/figures/ripple-elf.md).
        #[arg(long)]
        report: Option<PathBuf>,
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
        Cmd::Bench { elf, out, hold_s } => {
            let (path, _) = read_elf(elf)?;
            println!(
                "drive-emu bench: {} through probe-rs's virtual probe into an erased emulated \
                 {}, the `commissioning` scenario's motor and sensor",
                path.display(),
                drive_emu::bench::CHIP
            );
            let opts = hil_sim::probe_bench::PowerUpOptions {
                hold_s,
                ..Default::default()
            };
            let run = drive_emu::bench::power_up(&path, &out, &opts)?;
            print!("{}", hil_sim::probe_bench::power_up_summary(&run.report));
            print!("{}", drive_emu::bench::describe(&run));
            println!(
                "  captures (raw defmt), CSV, events and plots: {}/; what the drive did in \
                 Run measured at the plant: `cargo run --release -p drive-emu -- power-up`",
                out.display()
            );
            Ok(())
        }
        Cmd::PowerUp { elf, out } => power_up(elf, out),
        Cmd::Ripple {
            builds,
            settle_s,
            window_s,
            report,
        } => {
            use drive_emu::ripple_elf::{self, Plan};
            let plan = Plan { settle_s, window_s };
            let mut runs = Vec::new();
            for b in &builds {
                let (label, path) = b
                    .rsplit_once('=')
                    .with_context(|| format!("`--build {b}`: expected LABEL=ELF"))?;
                let (path, bytes) = read_elf(Some(PathBuf::from(path)))?;
                eprintln!("drive-emu: ripple {label} ({}) ...", path.display());
                let r = ripple_elf::run(label, &bytes, plan).with_context(|| label.to_string())?;
                eprintln!(
                    "  θ̂ at m = 1, 2: {:.4} / {:.4} mrad; motion 1x / 2x {:.3} / {:.3} mrad pk-pk; {:.1} emulated s in {:.1} s wall",
                    r.estimate_rad[0] * 1e3,
                    r.estimate_rad[1] * 1e3,
                    r.motion.h1_pk_pk_rad * 1e3,
                    r.motion.h2_pk_pk_rad * 1e3,
                    r.outcome.emulated_s,
                    r.outcome.wall_s
                );
                runs.push(r);
            }
            publish(report, &ripple_elf::report(&runs, plan)?)
        }
        Cmd::Perf {
            builds,
            n1_builds,
            window_s,
            report,
        } => perf(&builds, &n1_builds, window_s, report),
        Cmd::Scenarios {
            elf,
            report,
            details,
            fast_elf,
            reuse,
            names,
        } => {
            let (path, bytes) = read_elf(elf)?;
            let names: Vec<String> = if names.is_empty() {
                scenarios::ALL.iter().map(|s| s.to_string()).collect()
            } else {
                names
            };
            let (mut rows, mut sections) = (Vec::new(), String::new());
            for n in &names {
                if let Some(dir) = &reuse {
                    if let Some(p) = pieces::load(dir, n, &[&bytes], &["row", "details"]) {
                        eprintln!(
                            "drive-emu: scenario {n}: as the emulator's tests measured it on this ELF ({})",
                            dir.display()
                        );
                        rows.push(p[0].clone());
                        sections.push_str(&p[1]);
                        continue;
                    }
                }
                eprintln!("drive-emu: scenario {n} ...");
                let o = scenarios::run(n, &bytes)?;
                eprintln!(
                    "  {} boot(s), {} missed periods, ISR {:.0}/{} instructions, {:.0}/{} est. cycles mean/max, {:.1} s wall",
                    o.boots,
                    o.missed_periods,
                    o.isr_instrs_mean,
                    o.isr_instrs_max,
                    o.isr_cycles_mean,
                    o.isr_cycles_max,
                    o.wall_s
                );
                rows.push(scenarios::report_row(&o));
                sections.push_str(&scenarios::report_detail(&o));
            }
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            let note = format!("Firmware: the release `{name}` ELF of this checkout.");
            let table = scenarios::report_table_of(&rows);
            let mut text = format!("{sections}{note}\n");
            if report.is_none() && details.is_none() {
                println!("{table}\n{text}");
                return Ok(());
            }
            if let Some(fast) = fast_elf {
                let (_, fast_bytes) = read_elf(Some(fast))?;
                let elfs: [&[u8]; 2] = [&bytes, &fast_bytes];
                let reused = reuse.as_deref().and_then(|dir| {
                    pieces::load(dir, scenarios::AT_PLANT_PIECE, &elfs, &["modulation"])
                });
                match reused {
                    Some(p) => {
                        eprintln!("drive-emu: Run at the plant, the release and the fast-run builds: as the emulator's tests measured them");
                        text.push_str(&p[0]);
                    }
                    None => {
                        eprintln!(
                            "drive-emu: Run at the plant, the release and the fast-run builds ..."
                        );
                        let low = scenarios::run_at_plant(&bytes)?;
                        let high = scenarios::run_at_plant(&fast_bytes)?;
                        text.push_str(&scenarios::modulation_report(&low, &high));
                    }
                }
            }
            publish(report, &table)?;
            publish(details, &text)
        }
    }
}

/// `text` written to `report` (the figure file `cargo xtask docs` splices into the
/// pages), or on stdout without one.
fn publish(report: Option<PathBuf>, text: &str) -> Result<()> {
    let Some(p) = report else {
        println!("{text}");
        return Ok(());
    };
    std::fs::write(&p, text).with_context(|| p.display().to_string())?;
    eprintln!("drive-emu: report written to {}", p.display());
    Ok(())
}

fn perf(
    builds: &[String],
    n1_builds: &[String],
    window_s: f64,
    report: Option<PathBuf>,
) -> Result<()> {
    use drive_emu::budget;
    use drive_emu::perf_report::{self, Built};
    use scenarios::SensorBoard;
    let mut failed = Vec::new();
    let mut measured = Vec::new();
    let all = builds
        .iter()
        .map(|b| (b, SensorBoard::Kmz41))
        .chain(n1_builds.iter().map(|b| (b, SensorBoard::N1)));
    let mut elfs = Vec::new();
    for (b, sensor) in all {
        let (label, path) = b
            .rsplit_once('=')
            .with_context(|| format!("`--build {b}`: expected LABEL=ELF"))?;
        let (path, bytes) = read_elf(Some(PathBuf::from(path)))?;
        elfs.push((label, path, bytes, sensor));
    }
    // Each build on its own emulator, all at once: a run is one thread, and the machine
    // has more than one core. The results are taken in the order given.
    let runs: Vec<Result<scenarios::Perf>> = std::thread::scope(|s| {
        let handles: Vec<_> = elfs
            .iter()
            .map(|(label, path, bytes, sensor)| {
                eprintln!("drive-emu: perf {label} ({}) ...", path.display());
                s.spawn(move || scenarios::perf_run(bytes, window_s, *sensor))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(anyhow::anyhow!("the emulator's thread panicked")))
            })
            .collect()
    });
    for ((label, _, bytes, _), p) in elfs.iter().zip(runs) {
        let label = *label;
        let p = p.with_context(|| label.to_string())?;
        // Where the firmware was at each missed period: the inlined chain's functions.
        let mut missed_at = Vec::new();
        for (ms, _, pc) in p.missed.iter().take(5) {
            if let Ok(c) = m4_cycles::chains_of_elf(bytes, &[*pc]) {
                let names: Vec<String> = c
                    .get(pc)
                    .into_iter()
                    .flatten()
                    .map(|f| format!("`{}`", f.function))
                    .collect();
                missed_at.push(format!(
                    "the code running at the missed period at {ms:.2} ms ({pc:#010x}, innermost first): {}",
                    names.join(" ← ")
                ));
            }
        }
        let mut table = scenarios::perf_table(&p, label);
        for l in &missed_at {
            table.push_str(&format!("- {l}\n"));
        }
        eprintln!("{table}\n  {:.1} s wall", p.wall_s);
        for v in budget::evaluate(&p.budget_measures())
            .iter()
            .filter(|v| v.fails())
        {
            failed.push(format!("{label}: {}", v.describe()));
        }
        measured.push((label.to_string(), p, missed_at));
    }
    let built: Vec<Built> = measured
        .iter()
        .map(|(label, perf, missed_at)| Built {
            label,
            perf,
            missed_at: missed_at.clone(),
        })
        .collect();
    let text = perf_report::report(&built);
    publish(report, &text)?;
    if !failed.is_empty() {
        anyhow::bail!("over budget:\n  {}", failed.join("\n  "));
    }
    Ok(())
}

fn power_up(elf: Option<PathBuf>, out: PathBuf) -> Result<()> {
    let (path, bytes) = read_elf(elf)?;
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    println!(
        "drive-emu: {} on the emulated STM32G474, the `commissioning` scenario's motor and sensor",
        path.display()
    );
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
        "  MRAS residual in Adapt at first → in Run: {:.2} → {:.3} mrad (the firmware's own measure, streamed: not an angle error)",
        run.residual_first_rad * 1e3,
        run.residual_run_rad * 1e3
    );
    let o = &run.outcome;
    println!(
        "  control interrupt: {:.0} mean / {} max executed instructions, {:.0} / {} estimated \
         cycles of the {} per period; longest interrupt-masked stretch {} instructions; {} missed \
         periods in {} control periods; adaptation task: at most {} control interrupts from a \
         sample to its return ({} late)",
        o.isr_instrs_mean,
        o.isr_instrs_max,
        o.isr_cycles_mean,
        o.isr_cycles_max,
        o.period_cycles,
        o.masked_max_instrs,
        o.missed_periods,
        o.control_periods,
        o.task_interrupts_max,
        o.task_deadline_misses
    );
    for (b, c) in run.run_current.iter().enumerate() {
        if let Some(c) = c {
            println!(
                "  boot {}, Run, the current against the rotor's q axis (plant): {}",
                b + 1,
                scenarios::describe_current(c)
            );
        }
    }
    for (b, e) in run.estimate.iter().enumerate() {
        println!(
            "  boot {}, Run, the streamed θ̂ against the rotor (plant): {}",
            b + 1,
            scenarios::describe_estimate(e)
        );
    }
    println!(
        "  lost (the stream's counters and seq gaps): {}",
        o.losses.describe()
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
        hil_sim::rtt_log::run(&args)?;
    }
    println!(
        "  the RTT captures (raw defmt), their CSV, events and plots (rtt-log): {}/",
        out.display()
    );
    println!("  emulated {:.2} s in {:.1} s wall", o.emulated_s, o.wall_s);
    Ok(())
}

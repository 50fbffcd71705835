//! The `scenario` and `bench` commands.

use crate::report;
use crate::scenario::{self, RunOutcome, Scenario, Variant};
use anyhow::{anyhow, bail, Context, Result};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Clone, Debug)]
pub struct ScenarioArgs {
    /// Scenario name (see --list) or path to a scenario .toml.
    pub name: Option<String>,
    /// List the shipped scenarios.
    #[arg(long)]
    pub list: bool,
    /// Run the reduced-length CI variant.
    #[arg(long)]
    pub ci: bool,
    /// Output directory (default: target/hil-sim/<scenario> of the checkout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Skip the PNG/SVG plots.
    #[arg(long)]
    pub no_plots: bool,
    /// The firmware ELF whose stream format the `commissioning` scenario writes its RTT
    /// streams in (default: this checkout's release build, if built).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Run a scenario with a truth spectrum at N sensor-noise seeds (1, 3, .., 2N - 1)
    /// instead of its own, and report the spread of arg Zd over the oracle: the oracle
    /// of one run is one draw of the noise, so one run's ratio is too.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub seeds: Option<u64>,
}

impl ScenarioArgs {
    /// Full-length run of `name` with plots into the default directory.
    pub fn named(name: &str) -> Self {
        Self {
            name: Some(name.into()),
            list: false,
            ci: false,
            out: None,
            no_plots: false,
            elf: None,
            seeds: None,
        }
    }
}

fn out_dir(a: &ScenarioArgs, name: &str) -> PathBuf {
    a.out
        .clone()
        .unwrap_or_else(|| crate::checkout::target_dir().join("hil-sim").join(name))
}

/// The power-ups' RTT streams in the firmware's own format (its ELF's defmt table), for
/// `hil-sim rtt-log` and any defmt tool.
fn write_streams(
    a: &ScenarioArgs,
    sc: &Scenario,
    dir: &std::path::Path,
    boots: &[&crate::power_up::Boot],
) -> Result<()> {
    let elf_path = a.elf.clone().unwrap_or_else(crate::stream::release_elf);
    let Ok(elf) = std::fs::read(&elf_path) else {
        println!(
            "  no firmware ELF at {}: RTT streams not written (`cargo xtask build-cross`, or --elf)",
            elf_path.display()
        );
        return Ok(());
    };
    let formats =
        crate::stream::Formats::from_elf(&elf).with_context(|| elf_path.display().to_string())?;
    let names = drive::telemetry::path_names(&sc.core_config(None)?);
    for (k, b) in boots.iter().enumerate() {
        let bytes = crate::stream::encode_streamed(&formats, &names, &b.streamed)
            .with_context(|| elf_path.display().to_string())?;
        let path = dir.join(format!("rtt-{}.defmt", k + 1));
        std::fs::write(&path, bytes).with_context(|| path.display().to_string())?;
        println!(
            "  RTT stream of power-up {} in the firmware's format: {} (hil-sim rtt-log --input ...)",
            k + 1,
            path.display()
        );
    }
    Ok(())
}

pub fn scenario(a: &ScenarioArgs) -> Result<()> {
    if a.list || a.name.is_none() {
        for name in scenario::list() {
            let desc = Scenario::load(&name).map_or_else(|e| e.to_string(), |s| s.file.description);
            println!("{name:<16} {desc}");
        }
        return Ok(());
    }
    let sc = Scenario::load(a.name.as_deref().unwrap_or_default())?;
    let f = &sc.file;
    let duration = if a.ci {
        f.ci_duration_s.unwrap_or(f.duration_s)
    } else {
        f.duration_s
    };
    let dir = out_dir(a, &f.name);
    if !f.cases.is_empty() {
        return table1(&sc, duration);
    }
    if let Some(seeds) = a.seeds {
        return over_seeds(&sc, duration, seeds, &dir);
    }
    if f.commissioning.is_some() {
        let (first, second) = crate::power_up::run(&sc, duration)?;
        let boots = [
            ("1 (flash erased)", &first),
            ("2 (calibration in flash)", &second),
        ];
        let text = crate::power_up::report(&sc, &boots);
        print!("{text}");
        std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
        let mut outputs = vec![dir.join("summary.txt")];
        std::fs::write(&outputs[0], &text).with_context(|| dir.display().to_string())?;
        if f.truth_spectrum.is_some() {
            let json = crate::power_up::summary_json(&sc, duration, &boots)?;
            let path = dir.join("summary.json");
            std::fs::write(&path, json).with_context(|| path.display().to_string())?;
            outputs.push(path);
        }
        let outputs: Vec<String> = outputs.iter().map(|p| p.display().to_string()).collect();
        println!("  output: {}", outputs.join(", "));
        write_streams(a, &sc, &dir, &[&first, &second])?;
        return Ok(());
    }
    let mut variants = vec![];
    if f.paper.is_some() {
        variants.push(Variant::Paper);
    }
    variants.push(Variant::Ours);
    let started = Instant::now();
    let outcomes: Vec<RunOutcome> = std::thread::scope(|s| {
        let handles: Vec<_> = variants
            .iter()
            .map(|v| {
                let sc = &sc;
                s.spawn(move || scenario::run(sc, *v, duration, true))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .map_err(|_| anyhow!("a simulation thread panicked"))?
            })
            .collect::<Result<_, _>>()
    })?;
    let summaries: Vec<_> = outcomes.iter().map(|o| &o.summary).collect();
    let reference = scenario::reference_coefficients(&sc)?;
    let text = report::summary_text(&sc, &summaries, reference.as_deref());
    print!("{text}");
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    std::fs::write(dir.join("summary.txt"), &text).with_context(|| dir.display().to_string())?;
    for o in &outcomes {
        report::write_run(&dir.join(o.summary.variant.label()), o, !a.no_plots)?;
    }
    println!(
        "  output: {} (timeseries.csv, summary.json{} per run) in {:.1} s wall",
        dir.display(),
        if a.no_plots {
            ""
        } else {
            ", PNG and SVG plots"
        },
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// arg Zd over the oracle of both power-ups at `seeds` noise seeds: per seed, then
/// median and worst over every power-up (docs/hil-sim.md).
fn over_seeds(sc: &Scenario, duration: f64, seeds: u64, dir: &std::path::Path) -> Result<()> {
    use std::fmt::Write as _;
    let started = Instant::now();
    eprintln!(
        "scenario {}: {seeds} noise seeds, {duration} s each, {} threads",
        sc.file.name,
        rayon::current_num_threads()
    );
    let s = crate::power_up::SeedSpread::run(sc, duration, seeds)?;
    let mut text = format!(
        "scenario {}: arg Zd over the oracle (root sums of squares) at {seeds} noise seeds, \
         power-up 1 (flash erased) / 2 (calibration in flash)\n  seed   m = 1, 2      m = 1, 2 to the floor   m = 3..16 with a path (power-up 2 at seed + 1)\n",
        sc.file.name
    );
    for (seed, [a, b]) in &s.runs {
        let _ = writeln!(
            text,
            "  {seed:>4}   {:.2} / {:.2}   {:.2} / {:.2}             {:.2} / {:.2}",
            a.m1_m2, b.m1_m2, a.m1_m2_floor, b.m1_m2_floor, a.m3_up, b.m3_up
        );
    }
    for (what, d) in [
        ("m = 1, 2", s.m1_m2()),
        ("m = 1, 2 to the floor", s.m1_m2_floor()),
        ("m = 3..16", s.m3_up()),
    ] {
        let _ = writeln!(
            text,
            "  {what}: median {:.2}x, 95th percentile {:.2}x, worst {:.2}x over {} power-ups",
            d.median, d.p95, d.worst, d.count
        );
    }
    print!("{text}");
    std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    let path = dir.join("seeds.txt");
    std::fs::write(&path, &text).with_context(|| path.display().to_string())?;
    println!(
        "  output: {} in {:.1} s wall",
        path.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn table1(sc: &Scenario, duration: f64) -> Result<()> {
    println!("scenario {}: {}", sc.file.name, sc.file.description);
    println!(
        "  {:<22} {:>9} {:>9}   largest spatial harmonics of the raw error (mrad)",
        "error", "Table I", "measured"
    );
    for (name, expect, got, spec) in scenario::run_table1(sc, duration)? {
        let mut top: Vec<(usize, f64)> = spec.iter().copied().enumerate().collect();
        top.sort_by(|a, b| b.1.total_cmp(&a.1));
        let shown: Vec<String> = top
            .iter()
            .take(3)
            .map(|(i, v)| format!("{}: {v:.2}", i + 1))
            .collect();
        println!(
            "  {name:<22} {expect:>9} {got:>9}   {}{}",
            shown.join(", "),
            if expect == got { "" } else { "   MISMATCH" }
        );
    }
    Ok(())
}

#[derive(clap::Args, Clone, Debug)]
pub struct BenchArgs {
    /// Scenario whose drive model is timed.
    #[arg(long, default_value = "paper-fig9")]
    pub scenario: String,
    /// Simulated seconds per run.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Runs; best and median are reported.
    #[arg(long, default_value_t = 5)]
    pub repeats: u32,
}

/// Simulated seconds per wall second of the full drive model plus the core, one thread,
/// everything a scenario run does but writing files (recording, error windows included).
/// Best and median of `repeats` runs: shared machines vary their speed from run to run.
pub fn bench(a: &BenchArgs) -> Result<()> {
    if !(a.seconds > 0.0 && a.seconds <= 600.0) || a.repeats == 0 {
        bail!("--seconds must be in (0, 600] and --repeats >= 1");
    }
    let sc = Scenario::load(&a.scenario)?;
    let mut walls = Vec::new();
    for _ in 0..a.repeats {
        let started = Instant::now();
        scenario::run(&sc, Variant::Ours, a.seconds, false)?;
        walls.push(started.elapsed().as_secs_f64());
    }
    walls.sort_by(f64::total_cmp);
    let (best, median) = (walls[0], walls[walls.len() / 2]);
    let steps = a.seconds * sc.file.sample_rate_hz;
    println!(
        "bench {}: {:.1} s simulated at {:.0} kHz, one thread, {} runs",
        sc.file.name,
        a.seconds,
        sc.file.sample_rate_hz / 1e3,
        a.repeats
    );
    for (what, wall) in [("best", best), ("median", median)] {
        println!(
            "  {what:<6}: {wall:.3} s wall, {:.0}x real time, {:.0} ns per control period",
            a.seconds / wall,
            wall / steps * 1e9
        );
    }
    Ok(())
}

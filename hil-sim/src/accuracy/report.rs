//! The `bench-accuracy` command: run the suite, write the results page (docs/results.md),
//! its plots and the per-sensor CSV.

use super::page::{markdown, page_values, render, values, SUMMARY_TEMPLATE};
use super::stats::{summarise, Summary};
use super::tables::main_table;
use super::{
    charts, run_suite, Distribution, Method, Plan, SensorResult, DISTRIBUTION, DISTRIBUTION_N1,
    SAMPLE_PERIOD_S, SPECTRUM_HARMONICS_OF_THETA_S, SPECTRUM_PHASE,
};
use crate::pending::Pending;
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Sensors of the published run and of the reduced (CI-sized) one.
pub const FULL_SENSORS: usize = 500;
pub const REDUCED_SENSORS: usize = 24;
const MAX_SENSORS: usize = 100_000;

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Number of random sensors [default: 500, or 24 with --reduced].
    #[arg(long)]
    pub sensors: Option<usize>,
    /// Seed of the sensor population (sensor i is the same for any --sensors > i).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Results page to write [default: docs/results.md, or
    /// target/bench-accuracy-reduced/results.md with --reduced].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Directory for the plots and the per-sensor CSV [default: `results/` next to the
    /// page].
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// The reduced variant CI runs (24 sensors; written under target/, not docs/).
    #[arg(long)]
    pub reduced: bool,
    /// Directory for the figure files (`accuracy.json`, `accuracy-reduced.json`,
    /// `accuracy-summary.md`) [default: `figures/` next to the page, i.e. docs/figures].
    #[arg(long)]
    pub figures: Option<PathBuf>,
}

/// One population's run: its plan, every sensor's result and their summary.
pub struct Suite {
    pub population: &'static Distribution,
    pub plan: Plan,
    pub results: Vec<SensorResult>,
    pub summary: Summary,
}

impl Suite {
    /// Run sensors `0..sensors` of `population` with `seed` through its plan (N = 1:
    /// [`Plan::full_n1`]).
    pub fn run(
        population: &'static Distribution,
        seed: u64,
        sensors: usize,
        progress: bool,
    ) -> Result<Self> {
        let plan = match population.sensor_periods {
            1 => Plan::full_n1(),
            _ => Plan::full(),
        };
        let results = run_suite(population, seed, sensors, &plan, progress)?;
        let summary = summarise(&results, &plan);
        Ok(Self {
            population,
            plan,
            results,
            summary,
        })
    }
}

/// How a run was made, for the page's header. Wall-clock time and threads are printed,
/// not published: they change from run to run.
#[derive(Clone, Debug)]
pub struct RunInfo {
    pub seed: u64,
    pub sensors: usize,
    pub reduced: bool,
}

impl RunInfo {
    pub(crate) fn command(&self) -> String {
        let mut c = format!(
            "hil-sim bench-accuracy --sensors {} --seed {}",
            self.sensors, self.seed
        );
        if self.reduced {
            c += " --reduced";
        }
        c
    }

    /// The run's figures the results page names (`run.*`).
    pub(crate) fn figures(&self, s: &Summary, plan: &Plan) -> Vec<(&'static str, String)> {
        let mut note = String::new();
        if self.reduced {
            note += " **Reduced variant** (CI size): the published page has 500 sensors.";
        }
        if let Some(n) = s.fit_failures.iter().max().filter(|n| **n > 0) {
            note +=
                &format!(" Offline fits failed on up to {n} sensors per method (no value there).");
        }
        vec![
            ("run.command", self.command()),
            ("run.sensors", self.sensors.to_string()),
            ("run.seed", self.seed.to_string()),
            ("run.duration_s", format!("{:.2}", plan.duration_s())),
            ("run.rate_khz", format!("{:.0}", 1e-3 / SAMPLE_PERIOD_S)),
            ("run.note", note),
        ]
    }
}

pub fn run(a: &Args) -> Result<()> {
    let sensors = a.sensors.unwrap_or(if a.reduced {
        REDUCED_SENSORS
    } else {
        FULL_SENSORS
    });
    if !(1..=MAX_SENSORS).contains(&sensors) {
        bail!("--sensors {sensors}: must be in 1..={MAX_SENSORS}");
    }
    let page = a.out.clone().unwrap_or_else(|| {
        let root = crate::checkout::root();
        if a.reduced {
            root.join("target/bench-accuracy-reduced/results.md")
        } else {
            root.join("docs/results.md")
        }
    });
    if page.file_name().is_none() || page.is_dir() {
        bail!("--out {}: must name a file", page.display());
    }
    let page_dir = page
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let plots = a.plots.clone().unwrap_or_else(|| page_dir.join("results"));
    for dir in [&page_dir, &plots] {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create directory {}", dir.display()))?;
    }

    let figures = a
        .figures
        .clone()
        .unwrap_or_else(|| page_dir.join("figures"));
    let threads = rayon::current_num_threads();
    let started = Instant::now();
    let mut suites = Vec::new();
    for population in [&DISTRIBUTION, &DISTRIBUTION_N1] {
        eprintln!(
            "bench-accuracy: {}: {sensors} sensors, seed {}, {threads} threads",
            population.name, a.seed,
        );
        suites.push(Suite::run(population, a.seed, sensors, true)?);
    }
    let info = RunInfo {
        seed: a.seed,
        sensors,
        reduced: a.reduced,
    };
    let suites: Vec<&Suite> = suites.iter().collect();
    write_outputs(&suites, &info, &page, &plots, &figures)?;
    for s in &suites {
        println!("{}:", s.population.name);
        print!("{}", main_table(&s.summary, &s.plan));
    }
    println!(
        "\n{} sensors of each population in {:.1} s wall on {threads} threads; wrote {}, {} and {}",
        sensors,
        started.elapsed().as_secs_f64(),
        page.display(),
        plots.display(),
        figures.display()
    );
    Ok(())
}

impl Suite {
    /// The suite of its first `n` sensors: what a run of `n` sensors gives (sensor i is
    /// the same in any run), without running them again.
    fn first(&self, n: usize) -> Self {
        let results = self.results[..n.min(self.results.len())].to_vec();
        Self {
            population: self.population,
            summary: summarise(&results, &self.plan),
            plan: self.plan.clone(),
            results,
        }
    }
}

/// The reduced variant's figures: the run's own when it is no larger, else those of its
/// first [`REDUCED_SENSORS`] sensors, as `--reduced` would give them.
fn reduced_values(suites: &[&Suite], info: &RunInfo) -> BTreeMap<String, String> {
    if info.reduced || info.sensors <= REDUCED_SENSORS {
        return values(suites, info);
    }
    let first: Vec<Suite> = suites.iter().map(|s| s.first(REDUCED_SENSORS)).collect();
    let info = RunInfo {
        sensors: REDUCED_SENSORS,
        reduced: true,
        ..info.clone()
    };
    values(&first.iter().collect::<Vec<_>>(), &info)
}

fn json(values: &BTreeMap<String, String>) -> Result<String> {
    Ok(serde_json::to_string_pretty(values)? + "\n")
}

/// The page, its plots, the CSVs and the figure files; the page, CSVs and figure files
/// appear whole or not at all. The first suite is the page's main population (its plots),
/// the others follow it (N = 1). A reduced run writes only `accuracy-reduced.json` of the
/// figure files (CI compares it with the committed one).
pub fn write_outputs(
    suites: &[&Suite],
    info: &RunInfo,
    page: &Path,
    plots: &Path,
    figures: &Path,
) -> Result<()> {
    let Some(main) = suites.first() else {
        bail!("no suite to write");
    };
    // The page first: a template that cannot be filled writes nothing.
    let page_dir = page.parent().unwrap_or(Path::new(""));
    let rel = plots.strip_prefix(page_dir).unwrap_or(plots);
    let (full, reduced) = (values(suites, info), reduced_values(suites, info));
    let text = markdown(&page_values(&full, &reduced), &rel.to_string_lossy())?;
    let summary = render(SUMMARY_TEMPLATE, &full)?;
    for dir in [plots, figures] {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create directory {}", dir.display()))?;
    }
    write_plots(&main.results, &main.summary, &main.plan, plots)?;
    for (i, s) in suites.iter().enumerate() {
        let name = match i {
            0 => "per_sensor.csv".to_string(),
            _ => format!("per_sensor_n{}.csv", s.population.sensor_periods),
        };
        write_file(&plots.join(name), &per_sensor_csv(&s.results, &s.plan))?;
    }
    write_file(&figures.join("accuracy-reduced.json"), &json(&reduced)?)?;
    if !info.reduced {
        write_file(&figures.join("accuracy.json"), &json(&full)?)?;
        write_file(&figures.join("accuracy-summary.md"), &summary)?;
    }
    write_file(page, &text)
}

fn write_file(path: &Path, text: &str) -> Result<()> {
    let (pending, mut f) = Pending::create(path)?;
    f.write_all(text.as_bytes())
        .with_context(|| format!("{}: cannot write", path.display()))?;
    drop(f);
    pending.commit()
}

/// The methods drawn in the plots: the seven every table compares, and the 4-path
/// variant (our law on the paper's four paths: against `paper` it isolates the law,
/// against `ours` the path bank).
fn plotted() -> Vec<Method> {
    Method::ALL
        .into_iter()
        .filter(|m| !m.is_extra() || *m == Method::OursPaperBank)
        .collect()
}

fn write_plots(results: &[SensorResult], summary: &Summary, plan: &Plan, dir: &Path) -> Result<()> {
    let methods = plotted();
    let cdf: Vec<(&str, Vec<f64>)> = methods
        .iter()
        .map(|&m| {
            (
                m.label(),
                results.iter().map(|r| r.worst(m).pk_pk_rad * 1e3).collect(),
            )
        })
        .collect();
    charts::cdf_chart(
        &dir.join("cdf_worst_phase.png"),
        "Residual spatial error over sensors, worst evaluated phase",
        "pk-pk residual (mrad, mechanical, log scale)",
        &cdf,
    )?;
    let categories: Vec<&str> = plan.evaluation().iter().map(|p| p.name).collect();
    let bars: Vec<(&str, Vec<f64>)> = methods
        .iter()
        .map(|&m| {
            (
                m.label(),
                summary
                    .phases
                    .iter()
                    .map(|c| c.get(m).pk_pk.median * 1e3)
                    .collect(),
            )
        })
        .collect();
    charts::grouped_bars(
        &dir.join("phases_median.png"),
        "Median residual pk-pk per phase",
        "pk-pk residual (mrad, mechanical)",
        &categories,
        &bars,
    )?;
    let harmonics: Vec<String> = (1..=SPECTRUM_HARMONICS_OF_THETA_S)
        .map(|m| format!("m = {m}"))
        .collect();
    let harmonics: Vec<&str> = harmonics.iter().map(String::as_str).collect();
    let groups: Vec<(&str, Vec<f64>)> = [
        Method::Raw,
        Method::Lut256,
        Method::Paper,
        Method::Ours,
        Method::OursPaperBank,
        Method::Oracle,
    ]
    .iter()
    .map(|&m| {
        (
            m.label(),
            summary.spectrum_median_rad[m.index()]
                .iter()
                .map(|v| v * 1e3)
                .collect(),
        )
    })
    .collect();
    charts::grouped_bars(
        &dir.join("residual_harmonics.png"),
        &format!(
            "Median residual by error harmonic m of θs, {}",
            plan.evaluation()[SPECTRUM_PHASE].name
        ),
        "amplitude (mrad, mechanical)",
        &harmonics,
        &groups,
    )
}

/// One row per sensor: its noise and skew, pk-pk and RMS of every method in every
/// evaluated phase (mrad, mechanical), and each tracker's convergence and faults.
pub fn per_sensor_csv(results: &[SensorResult], plan: &Plan) -> String {
    let mut s = String::from("sensor,noise_std,skew_us");
    for p in plan.evaluation() {
        for m in Method::ALL {
            let _ = write!(
                s,
                ",{k}_{m}_pkpk_mrad,{k}_{m}_rms_mrad",
                k = p.key,
                m = m.key()
            );
        }
    }
    for m in Method::MRAS {
        let _ = write!(
            s,
            ",{m}_converged_revs,{m}_lost_lock,{m}_first_fault",
            m = m.key()
        );
    }
    s.push_str(",ours_data_bank,ours_data_unobserved\n");
    // Four significant digits, plain decimals (keeps the file small).
    let num = |v: f64| {
        if !v.is_finite() {
            String::new()
        } else if v == 0.0 || !(1e-4..1e5).contains(&v.abs()) {
            format!("{v:.3e}")
        } else {
            let decimals = (3 - v.abs().log10().floor() as i32).max(0) as usize;
            format!("{v:.decimals$}")
        }
    };
    for r in results {
        let _ = write!(s, "{},{:.3e},{:.3}", r.index, r.noise_std, r.skew_s * 1e6);
        for phase in &r.residuals {
            for x in phase {
                let _ = write!(s, ",{},{}", num(x.pk_pk_rad * 1e3), num(x.rms_rad * 1e3));
            }
        }
        for t in &r.mras {
            let fault = t.first_fault.map_or(String::new(), |(p, f)| {
                format!("{f:?} in {}", plan.phases[p].key)
            });
            let _ = write!(
                s,
                ",{},{},{fault}",
                t.converged_revs
                    .map_or(String::new(), |v| format!("{v:.2}")),
                t.lost_lock as u8
            );
        }
        let (bank, unobserved) = r.survey.as_ref().map_or_else(Default::default, |o| {
            // The stream's names, space-separated: the CSV's own separator is the comma.
            let names = drive::telemetry::bank_names(o.bank.as_slice()).replace(',', " ");
            let left = o.unobserved.iter().map(|m| m.to_string());
            (names, left.collect::<Vec<_>>().join(" "))
        });
        let _ = writeln!(s, ",{bank},{unobserved}");
    }
    s
}

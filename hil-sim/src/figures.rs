//! `hil-sim figures`: the simulator's figures in the docs. Each generator runs what it
//! measures and writes markdown sections (`<out>/<id>.md`, by default the checkout's
//! `docs/figures/`); `cargo xtask docs` splices each into the pages that show it, and
//! `cargo xtask docs --check` compares. Every figure here is computed by the run:
//! a section states no number a run did not produce, and no comparison it did not
//! compute.
//!
//! The CI-length sections (`scenarios-ci`, `ripple-ci`, `commissioning`'s CI column)
//! hold the figures `hil-sim/tests/scenarios.rs` asserts bounds against, measured the
//! same way.

use crate::accuracy::tables::sig3;
use crate::commission::{noise, ADC, INERTIA_KG_M2, SAMPLE_PERIOD_S};
use crate::power_up::{self, Boot, SeedSpread};
use crate::scenario::{self, NamedCoefficient, RunSummary, Scenario, Variant, WindowStats};
use crate::study::{self, cell};
use crate::truth_spectrum::TruthSpectrum;
use crate::Law;
use anyhow::{anyhow, bail, Context, Result};
use drive::telemetry::Event;
use mras::{Config, Tracker};
use mras_sim::{wrap_pi, CommissioningRun, Kinematic, SensorModel, SpatialError, Trajectory};
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Generators to run (default: all; `--list` names them and their sections).
    pub names: Vec<String>,
    /// Directory the sections are written to [default: docs/figures of the checkout].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// List the generators, the sections each writes, and whether CI reruns it.
    #[arg(long)]
    pub list: bool,
}

type Sections = Vec<(&'static str, String)>;

/// A generator: its name, the sections it writes, whether `cargo xtask ci` reruns it
/// (seconds) or only the full regeneration does (minutes), and its run.
pub struct Generator {
    pub name: &'static str,
    pub sections: &'static [&'static str],
    pub in_ci: bool,
    run: fn() -> Result<Sections>,
}

pub const GENERATORS: [Generator; 8] = [
    Generator {
        name: "scenarios",
        sections: &["scenarios", "scenarios-ci", "scenarios-summary"],
        in_ci: true,
        run: scenarios,
    },
    Generator {
        name: "commissioning",
        sections: &["commissioning"],
        in_ci: true,
        run: commissioning,
    },
    Generator {
        name: "identification",
        sections: &["identification", "identification-without"],
        in_ci: true,
        run: identification,
    },
    Generator {
        name: "laws",
        sections: &["compare-laws", "gain-sweep", "laws-summary"],
        in_ci: true,
        run: laws,
    },
    Generator {
        name: "core",
        sections: &["core-accuracy"],
        in_ci: true,
        run: core_accuracy,
    },
    Generator {
        name: "ripple-ci",
        sections: &["ripple-ci"],
        in_ci: true,
        run: ripple_ci,
    },
    Generator {
        name: "ripple",
        sections: &["ripple"],
        in_ci: false,
        run: ripple_full,
    },
    Generator {
        name: "identification-seeds",
        sections: &["identification-seeds"],
        in_ci: false,
        run: identification_seeds,
    },
];

pub fn run(a: &Args) -> Result<()> {
    if a.list {
        for g in &GENERATORS {
            println!(
                "{:<22} {:<8} {}",
                g.name,
                if g.in_ci { "in CI" } else { "full" },
                g.sections.join(", ")
            );
        }
        return Ok(());
    }
    let chosen: Vec<&Generator> = if a.names.is_empty() {
        GENERATORS.iter().collect()
    } else {
        a.names
            .iter()
            .map(|n| {
                GENERATORS.iter().find(|g| g.name == n).ok_or_else(|| {
                    let names: Vec<&str> = GENERATORS.iter().map(|g| g.name).collect();
                    anyhow!("no generator `{n}` (available: {})", names.join(", "))
                })
            })
            .collect::<Result<_>>()?
    };
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| crate::checkout::root().join(docgen::FIGURES_DIR));
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    for g in chosen {
        let started = std::time::Instant::now();
        let sections = (g.run)().with_context(|| format!("generator {}", g.name))?;
        let ids: Vec<&str> = sections.iter().map(|s| s.0).collect();
        if ids != g.sections {
            bail!("generator {} wrote {ids:?}, not {:?}", g.name, g.sections);
        }
        for (id, text) in sections {
            let path = out.join(format!("{id}.md"));
            std::fs::write(&path, docgen::normalised(&text))
                .with_context(|| path.display().to_string())?;
            eprintln!("hil-sim figures: {}", path.display());
        }
        eprintln!(
            "hil-sim figures: {} in {:.1} s wall",
            g.name,
            started.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

// ---- formatting ----

/// A ratio as "N.Nx" (three significant digits).
fn x(r: f64) -> String {
    format!("{}x", sig3(r))
}

/// A magnitude that may be small: three significant digits, in exponent form below
/// 0.0001.
fn small(v: f64) -> String {
    match v.abs() {
        a if a == 0.0 || !a.is_finite() || a >= 1.0 => sig3(v),
        a if a < 1e-4 => format!("{v:.2e}"),
        a => {
            let decimals = (2.0 - a.log10().floor()) as usize;
            format!("{v:.decimals$}")
        }
    }
}

fn before_after(a: f64, b: f64) -> String {
    format!("{} → {} mrad pk-pk ({})", small(a), small(b), x(a / b))
}

fn converged(r: &RunSummary) -> String {
    match (r.converged_after_s, r.converged_after_revs) {
        (Some(s), Some(n)) => format!("converged after {s:.2} s / {n:.1} rev"),
        _ => "not converged".into(),
    }
}

fn spatial(w: &WindowStats) -> String {
    before_after(w.raw_pk_pk_mrad, w.estimate_pk_pk_mrad)
}

/// The largest |a - b| over the coefficients two runs share.
fn largest_difference(a: &[NamedCoefficient], b: &[NamedCoefficient]) -> f64 {
    a.iter()
        .zip(b)
        .map(|((_, ar, ai), (_, br, bi))| f64::from((ar - br).hypot(ai - bi)))
        .fold(0.0, f64::max)
}

fn magnitudes(c: &[NamedCoefficient]) -> Vec<f64> {
    c.iter()
        .map(|(_, re, im)| f64::from(re.hypot(*im)))
        .collect()
}

// ---- the paper scenarios ----

/// Both laws (the paper's where the file has one) of a scenario, in parallel.
struct PaperRuns {
    paper: Option<RunSummary>,
    ours: RunSummary,
}

fn paper_runs(name: &str, ci: bool) -> Result<PaperRuns> {
    let sc = Scenario::load(name)?;
    let d = match ci {
        true => sc.file.ci_duration_s.unwrap_or(sc.file.duration_s),
        false => sc.file.duration_s,
    };
    let has_paper = sc.file.paper.is_some();
    let (paper, ours) = std::thread::scope(|s| {
        let paper = has_paper.then(|| s.spawn(|| scenario::run(&sc, Variant::Paper, d, false)));
        let ours = scenario::run(&sc, Variant::Ours, d, false);
        let paper = paper.map(|h| {
            h.join()
                .map_err(|_| anyhow!("a simulation thread panicked"))
        });
        (paper, ours)
    });
    let paper = match paper {
        Some(p) => Some(p??.summary),
        None => None,
    };
    Ok(PaperRuns {
        paper,
        ours: ours?.summary,
    })
}

fn tracking(r: &RunSummary) -> Result<String> {
    let b = r.before.as_ref().context("no window before the MRAS")?;
    Ok(format!(
        "tracking error {}",
        before_after(b.tracking_pk_pk_mrad, r.after.tracking_pk_pk_mrad)
    ))
}

fn tracking_ratio(r: &RunSummary) -> Result<f64> {
    let b = r.before.as_ref().context("no window before the MRAS")?;
    Ok(b.tracking_pk_pk_mrad / r.after.tracking_pk_pk_mrad)
}

fn estimate(r: &RunSummary) -> Result<String> {
    let b = r.before.as_ref().context("no window before the MRAS")?;
    Ok(format!(
        "θ̂'s spatial error {}",
        before_after(b.estimate_pk_pk_mrad, r.after.estimate_pk_pk_mrad)
    ))
}

fn table1_matches(ci: bool) -> Result<(usize, usize)> {
    let sc = Scenario::load("table1")?;
    let d = match ci {
        true => sc.file.ci_duration_s.unwrap_or(sc.file.duration_s),
        false => sc.file.duration_s,
    };
    let rows = scenario::run_table1(&sc, d)?;
    let matched = rows.iter().filter(|(_, want, got, _)| want == got).count();
    Ok((matched, rows.len()))
}

fn paper_of(r: &PaperRuns) -> Result<&RunSummary> {
    r.paper.as_ref().context("no paper-literal run")
}

fn scenarios() -> Result<Sections> {
    let names = ["paper-fig8", "paper-fig9", "paper-fig10", "paper-fig11"];
    let full: Vec<PaperRuns> = names
        .iter()
        .map(|n| paper_runs(n, false))
        .collect::<Result<_>>()?;
    let ci: Vec<PaperRuns> = names
        .iter()
        .map(|n| paper_runs(n, true))
        .collect::<Result<_>>()?;
    let [f8, f9, f10, f11] = &full[..] else {
        unreachable!()
    };
    let desc = |n: &str| -> Result<String> { Ok(Scenario::load(n)?.file.description) };

    // Full length.
    let mut s = String::from("| scenario | what | paper law | ours |\n|---|---|---|---|\n");
    let (p8, o8) = (paper_of(f8)?, &f8.ours);
    let _ = writeln!(
        s,
        "| `paper-fig8` | {} | θ̂'s spatial error {}; {} | {}; {} |",
        desc("paper-fig8")?,
        spatial(&p8.after),
        converged(p8),
        spatial(&o8.after),
        converged(o8)
    );
    for (name, r) in [("paper-fig9", f9), ("paper-fig10", f10)] {
        let p = paper_of(r)?;
        let _ = writeln!(
            s,
            "| `{name}` | {} | {} | {}; {}; {} |",
            desc(name)?,
            tracking(p)?,
            tracking(&r.ours)?,
            estimate(&r.ours)?,
            converged(&r.ours)
        );
    }
    let (p11, o11) = (paper_of(f11)?, &f11.ours);
    let _ = writeln!(
        s,
        "| `paper-fig11` | {} | every coefficient within {} of Fig. 8's | within {} |",
        desc("paper-fig11")?,
        small(largest_difference(&p11.coefficients, &p8.coefficients)),
        small(largest_difference(&o11.coefficients, &o8.coefficients))
    );
    let (matched, cases) = table1_matches(false)?;
    let _ = writeln!(
        s,
        "| `table1` | {} | — | {matched} of {cases} cases show Table I's harmonic |",
        desc("table1")?
    );

    // CI length: what the tests assert bounds on.
    let [c8, c9, c10, c11] = &ci[..] else {
        unreachable!()
    };
    let mut t = String::from("| at CI length (`--ci`) | paper law | ours |\n|---|---|---|\n");
    let coef_delta = |a: &PaperRuns, b: &PaperRuns| -> Result<[String; 2]> {
        Ok([
            small(largest_difference(
                &paper_of(a)?.coefficients,
                &paper_of(b)?.coefficients,
            )),
            small(largest_difference(
                &a.ours.coefficients,
                &b.ours.coefficients,
            )),
        ])
    };
    let [dp, d_ours] = coef_delta(c8, c11)?;
    let _ = writeln!(
        t,
        "| `paper-fig8` against `paper-fig11`: the largest difference of a coefficient (scaled units) | {dp} | {d_ours} |"
    );
    let split = |r: &RunSummary| {
        let m = magnitudes(&r.coefficients);
        let loaded = m[..4].iter().copied().fold(f64::INFINITY, f64::min);
        let idle = m[4..].iter().copied().fold(0.0, f64::max);
        format!("{} / {}", small(loaded), small(idle))
    };
    let _ = writeln!(
        t,
        "| `paper-fig8`: the smallest \\|coefficient\\| of offset, C/D, h4, h5 / the largest of h6..h8 (no error there) | {} | {} |",
        split(paper_of(c8)?),
        split(&c8.ours)
    );
    for (name, r) in [("paper-fig9", c9), ("paper-fig10", c10)] {
        let _ = writeln!(
            t,
            "| `{name}`: tracking error before → after the MRAS | {} | {} |",
            tracking(paper_of(r)?)?,
            tracking(&r.ours)?
        );
    }
    let truth = scenario::reference_coefficients(&Scenario::load("paper-fig9")?)?
        .context("paper-fig9 has an exact fixed point")?;
    let _ = writeln!(
        t,
        "| `paper-fig9`: the largest distance of a coefficient from the sensor's exact fixed point | {} | {} |",
        small(largest_difference(&paper_of(c9)?.coefficients, &truth)),
        small(largest_difference(&c9.ours.coefficients, &truth))
    );
    let _ = writeln!(
        t,
        "| `paper-fig10`: the raw sensor's spatial error (mrad pk-pk) | — | {} |",
        sig3(c10.ours.after.raw_pk_pk_mrad)
    );
    let (matched, cases) = table1_matches(true)?;
    let _ = writeln!(
        t,
        "| `table1`: cases that show Table I's harmonic | — | {matched} of {cases} |"
    );

    // The README's lines.
    let p10 = paper_of(f10)?;
    let mut r = String::new();
    let _ = writeln!(
        r,
        "- **Fig. 10 case** (`paper-fig10`: residual offsets and h = 2, 4, 5 after a min/max \
         calibration, 5 rev/s, 5 Hz position loop): {} with our law, {} with the paper's law \
         on the same simulated drive; {}.",
        tracking(&f10.ours)?,
        x(tracking_ratio(p10)?),
        estimate(&f10.ours)?
    );
    let _ = writeln!(
        r,
        "- **Fig. 8 case** (`paper-fig8`: the extreme sensor, 10 % offsets, 20 % imbalance, 6° \
         quadrature, h = 2..5, 12-bit converter and noise, on a 1 Hz 100 rad/s sine): θ̂'s \
         spatial error {}, {}; the paper's law {}, {}.",
        spatial(&o8.after),
        converged(o8),
        spatial(&p8.after),
        converged(p8)
    );
    Ok(vec![
        ("scenarios", s),
        ("scenarios-ci", t),
        ("scenarios-summary", r),
    ])
}

// ---- the commissioning scenario ----

fn aligned(b: &Boot) -> String {
    b.streamed
        .iter()
        .find_map(|s| match &s.line {
            drive::telemetry::Line::Event(Event::Aligned {
                offset_e_rad,
                reversed,
                ratio,
                ..
            }) => Some(format!(
                "electrical offset {offset_e_rad:+.3} rad, {}, {ratio:.3} sensor periods per swept period",
                if *reversed { "reversed" } else { "forward" }
            )),
            _ => None,
        })
        .unwrap_or_else(|| "— (loaded)".into())
}

fn commissioning() -> Result<Sections> {
    let sc = Scenario::load("commissioning")?;
    let full = power_up::run(&sc, sc.file.duration_s)?;
    let ci = power_up::run(&sc, sc.file.ci_duration_s.context("no ci_duration_s")?)?;
    let boots = [&full.0, &full.1, &ci.0, &ci.1];
    let mut s = format!(
        "| | power-up 1 (flash erased) | power-up 2 (calibration in flash) | at CI length ({} s): 1 | 2 |\n|---|---|---|---|---|\n",
        sc.file.ci_duration_s.unwrap_or_default()
    );
    let row = |s: &mut String, what: &str, f: &dyn Fn(&Boot) -> String| {
        let cells: Vec<String> = boots.iter().map(|b| f(b)).collect();
        let _ = writeln!(s, "| {what} | {} |", cells.join(" | "));
    };
    // The reloaded coefficients against those power-up 1 stored (slow tracking in Run
    // moves them a little).
    let reloaded: Vec<String> = [(&full.0, &full.1), (&ci.0, &ci.1)]
        .iter()
        .flat_map(|(a, b)| {
            [
                "—".to_string(),
                small(largest_difference(&a.coefficients, &b.coefficients)),
            ]
        })
        .collect();
    row(&mut s, "states (entered at, s)", &|b| {
        b.transitions
            .iter()
            .map(|(t, st)| format!("{} {t:.3}", st.name()))
            .collect::<Vec<_>>()
            .join(" → ")
    });
    row(&mut s, "Sweep: alignment", &aligned);
    row(
        &mut s,
        "Adapt: until `converged`",
        &|b| match (b.adapt_s, b.adapt_revs) {
            (Some(t), Some(r)) => format!("{t:.2} s / {r:.1} rev"),
            _ => "—".into(),
        },
    );
    row(
        &mut s,
        "Run: spatial error over the last 20 %, raw → θ̂",
        &|b| b.run.as_ref().map_or("—".into(), spatial),
    );
    row(
        &mut s,
        "Run: electrical angle of the current against the rotor's (mean, mrad electrical)",
        &|b| {
            b.run_angle_error_e_rad
                .map_or("—".into(), |e| format!("{:+.1}", e * 1e3))
        },
    );
    row(
        &mut s,
        "Run: torque per amp, of the torque constant",
        &|b| {
            b.run_torque_per_amp
                .map_or("—".into(), |k| format!("{k:.4}"))
        },
    );
    row(&mut s, "faulted / missed control periods", &|b| {
        format!("{} / {}", b.faulted_samples, b.missed_periods)
    });
    let _ = writeln!(
        s,
        "| coefficients at the end: largest difference from power-up 1's (scaled units) | {} |",
        reloaded.join(" | ")
    );
    Ok(vec![("commissioning", s)])
}

// ---- the kinematic studies ----

/// The random motors of [`crate::identification`], each commissioned from the
/// firmware's nominal motor: what was found against the plant, the current loop's step,
/// the time Identify took, when Run came and the spatial error in Run.
fn identification() -> Result<Sections> {
    use crate::identification::{
        commission, commission_as, nominal, population_of, Errors, MOTORS, RUN_SETTLE_S, SEED,
    };
    use drive::commissioning::State;
    use rayon::prelude::*;
    let sc = Scenario::load("commissioning")?;
    let design_hz = sc.file.control.current_bandwidth_hz;
    let mut runs: Vec<_> = population_of(&sc, MOTORS, SEED)?
        .into_par_iter()
        .map(|d| commission(&sc, d))
        .collect::<Result<_>>()?;
    runs.sort_by(|a, b| a.draw.l_h.total_cmp(&b.draw.l_h));
    let nominal_run = commission(&sc, nominal())?;
    let pct = |e: Option<f64>| e.map_or("—".to_string(), |e| format!("{:+.2} %", 100.0 * e));
    let mut s = String::from(
        "| p | R (Ω) | L (µH) | ψ (mWb) | J (kg·m²) | dead time (ns) | device drop (V) | end state | p found | R found | Ld found | Lq found | ψ found | J found | current loop (Hz) | Identify (s) | Run at (s) | Run: θ̂ spatial error (mrad pk-pk) |\n|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let mut worst = Errors::default();
    let (mut bw_lo, mut bw_hi) = (f64::INFINITY, 0f64);
    let (mut in_run, mut counts_found) = (0, 0);
    let speed_rad_s = crate::identification::Targets::of(&sc)?.speed_rad_s;
    let (mut worst_speed, mut worst_angle_mrad) = (0f64, 0f64);
    for o in &runs {
        if let Some(x) = o.speed_from_store_error(speed_rad_s) {
            worst_speed = worst_speed.max(x);
        }
        if let Some(x) = o.angle_span_from_store_mrad() {
            worst_angle_mrad = worst_angle_mrad.max(x);
        }
        let (d, b) = (o.draw, &o.boot);
        in_run += (b.final_state == State::Run) as usize;
        let found = o.pole_pairs_found();
        counts_found += (found == Some(d.pole_pairs as u16)) as usize;
        let e = o.errors();
        if let Some(e) = e {
            worst = worst.worst(e);
        }
        let bw = o.loop_bandwidth_hz();
        if let Some(f) = bw {
            (bw_lo, bw_hi) = (bw_lo.min(f), bw_hi.max(f));
        }
        let identify_s = b
            .entered(State::Align)
            .zip(b.entered(State::Identify))
            .map_or("—".to_string(), |(a, i)| format!("{:.3}", a - i));
        let run_s = b
            .entered(State::Run)
            .map_or("—".to_string(), |t| format!("{t:.2}"));
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.1} | {:.1} | {:.2e} | {:.0} | {:.2} | {} | {} | {} | {} | {} | {} | {} | {} | {identify_s} | {run_s} | {} |",
            d.pole_pairs,
            d.r_ohm,
            1e6 * d.l_h,
            1e3 * d.flux_wb,
            d.j_kg_m2,
            1e9 * d.dead_time_s,
            d.device_drop_v,
            b.final_state.name(),
            found.map_or("—".to_string(), |p| p.to_string()),
            pct(e.map(|e| e.r)),
            pct(e.map(|e| e.ld)),
            pct(e.map(|e| e.lq)),
            pct(e.and_then(|e| e.flux)),
            pct(e.and_then(|e| e.inertia)),
            bw.map_or("—".to_string(), |f| format!("{f:.0}")),
            b.run.as_ref().map_or("—".to_string(), |r| format!(
                "{:.4}",
                r.estimate_pk_pk_mrad
            )),
        );
    }
    let _ = writeln!(
        s,
        "\n{in_run} of {} motors to Run, the pole pairs found on {counts_found} (the firmware's nominal motor has {}). Worst error: R {:.2} %, Ld {:.2} %, Lq {:.2} %, ψ {}, J {}. The current loop, designed for {design_hz:.0} Hz, steps at {bw_lo:.0}-{bw_hi:.0} Hz (the firmware's nominal motor: {}). Run's spatial error is taken from {RUN_SETTLE_S} s after its entry to the end. From Store's entry on (the identified ψ and J put in force, then the application's loop taking over at speed) the rotor's speed stays within {:.2} % of the commissioning speed and θ̂'s error within a {worst_angle_mrad:.2} mrad span.",
        runs.len(),
        nominal().pole_pairs,
        100.0 * worst.r,
        100.0 * worst.ld,
        100.0 * worst.lq,
        pct(worst.flux).trim_start_matches('+'),
        pct(worst.inertia).trim_start_matches('+'),
        nominal_run
            .loop_bandwidth_hz()
            .map_or("—".to_string(), |f| format!("{f:.0} Hz")),
        100.0 * worst_speed
    );
    // The reason for it: the firmware before it identified its motor, on the smallest L
    // and on the largest J of the population.
    let smallest_l = runs.first().map(|o| o.draw);
    let largest_j = runs
        .iter()
        .map(|o| o.draw)
        .max_by(|a, b| a.j_kg_m2.total_cmp(&b.j_kg_m2));
    let mut without = String::from(
        "| motor | p | R (Ω) | L (µH) | ψ (mWb) | J (kg·m²) | 1.5·p·ψ/J (rad/s²/A) | with identification | without (the nominal constants) |\n|---|---:|---:|---:|---:|---:|---:|---|---|\n",
    );
    // Outside the population's acceleration per amp, on the nominal R and L: a heavy load
    // on a weak magnet, and a light one on a strong magnet.
    let outside = |flux_wb: f64, j_kg_m2: f64| {
        Some(crate::identification::Draw {
            flux_wb,
            j_kg_m2,
            ..nominal()
        })
    };
    for (what, d) in [
        ("smallest L", smallest_l),
        ("largest J", largest_j),
        ("below the range", outside(20e-3, 1e-2)),
        ("above the range", outside(25e-3, 1e-5)),
    ] {
        let Some(d) = d else { continue };
        let ended = |o: &crate::identification::Outcome| {
            let b = &o.boot;
            match (b.final_state, b.cause) {
                (State::Run, _) => format!(
                    "Run at {:.2} s; θ̂ {} mrad pk-pk in Run",
                    b.entered(State::Run).unwrap_or(f64::NAN),
                    b.run.as_ref().map_or("—".to_string(), |r| format!(
                        "{:.4}",
                        r.estimate_pk_pk_mrad
                    ))
                ),
                (state, cause) => {
                    let t = b.transitions.last().map_or(f64::NAN, |(t, _)| *t);
                    let from = b
                        .transitions
                        .iter()
                        .rev()
                        .nth(1)
                        .map_or("?", |(_, s)| s.name());
                    format!(
                        "{} at {t:.3} s in {from} ({})",
                        state.name(),
                        cause.map_or("—", drive::telemetry::cause_name)
                    )
                }
            }
        };
        let with = match runs
            .iter()
            .find(|o| o.draw.l_h == d.l_h && o.draw.j_kg_m2 == d.j_kg_m2)
        {
            Some(o) => ended(o),
            None => ended(&commission(&sc, d)?),
        };
        let old = commission_as(&sc, d, false)?;
        let _ = writeln!(
            without,
            "| {what} | {} | {with} | {} |",
            motor_cells(&d),
            ended(&old)
        );
    }
    Ok(vec![
        ("identification", s),
        ("identification-without", without),
    ])
}

/// A motor's table cells: p, R (Ω), L (µH), ψ (mWb), J (kg·m²), 1.5·p·ψ/J (rad/s²/A).
fn motor_cells(d: &crate::identification::Draw) -> String {
    format!(
        "{} | {:.3} | {:.1} | {:.1} | {:.2e} | {:.0}",
        d.pole_pairs,
        d.r_ohm,
        1e6 * d.l_h,
        1e3 * d.flux_wb,
        d.j_kg_m2,
        1.5 * d.pole_pairs as f64 * d.flux_wb / d.j_kg_m2
    )
}

/// The population of [`identification`] drawn with other seeds: how many motors meet
/// every bound of `identification::bounds`, and what the others miss.
fn identification_seeds() -> Result<Sections> {
    use crate::identification::{commission, population_of, Errors, Targets, MOTORS, SEED};
    use rayon::prelude::*;
    let sc = Scenario::load("commissioning")?;
    let targets = Targets::of(&sc)?;
    let seeds = SEED..SEED + 6;
    let mut summary = String::from(
        "| seed | motors to Run | meeting every bound | worst ψ | worst J | worst current loop (of its design) |\n|---:|---:|---:|---:|---:|---:|\n",
    );
    let mut missed = String::from(
        "| seed | p | R (Ω) | L (µH) | ψ (mWb) | J (kg·m²) | 1.5·p·ψ/J (rad/s²/A) | misses |\n|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    let (mut all, mut all_met) = (0, 0);
    for seed in seeds.clone() {
        eprintln!("identification-seeds: seed {seed}");
        let mut runs: Vec<_> = population_of(&sc, MOTORS, seed)?
            .into_par_iter()
            .map(|d| commission(&sc, d))
            .collect::<Result<_>>()?;
        runs.sort_by(|a, b| a.draw.l_h.total_cmp(&b.draw.l_h));
        let (mut in_run, mut met) = (0, 0);
        let (mut worst, mut current_loop) = (Errors::default(), 0f64);
        for o in &runs {
            let d = o.draw;
            in_run += (o.boot.final_state == drive::commissioning::State::Run) as usize;
            if let Some(e) = o.errors() {
                worst = worst.worst(e);
            }
            if let Some(x) = o.current_loop_error(targets.current_bandwidth_hz) {
                current_loop = current_loop.max(x.abs());
            }
            let m = o.shortfalls(&targets);
            if m.is_empty() {
                met += 1;
                continue;
            }
            let _ = writeln!(
                missed,
                "| {seed} | {} | {} |",
                motor_cells(&d),
                m.join("; ")
            );
        }
        (all, all_met) = (all + runs.len(), all_met + met);
        let _ = writeln!(
            summary,
            "| {seed}{} | {in_run} of {} | {met} | {:.2} % | {:.2} % | {:.1} % |",
            if seed == SEED { " (the test's)" } else { "" },
            runs.len(),
            100.0 * worst.flux.unwrap_or(0.0),
            100.0 * worst.inertia.unwrap_or(0.0),
            100.0 * current_loop
        );
    }
    let _ = write!(
        summary,
        "\n{all_met} of {all} motors over seeds {}-{} meet every bound.",
        seeds.start,
        seeds.end - 1
    );
    if all_met < all {
        let _ = writeln!(summary, " Those that do not:\n\n{missed}");
    } else {
        summary.push('\n');
    }
    Ok(vec![("identification-seeds", summary)])
}

fn laws() -> Result<Sections> {
    const REVS: u32 = 30;
    let grid = study::compare_laws_grid(REVS)?;
    let compare = study::laws_table(&grid, REVS);
    let sweep = study::gain_sweep_table(REVS)?;
    // Over 5-100 rev/s (the paper's band and above), either direction, and at 2 rev/s.
    let span = |law: usize, keep: &dyn Fn(f64) -> bool| {
        let cells: Vec<Option<usize>> = grid
            .iter()
            .filter(|(v, _)| keep(*v))
            .flat_map(|(_, r)| [r[2 * law], r[2 * law + 1]])
            .collect();
        let reached: Vec<usize> = cells.iter().flatten().copied().collect();
        let (lo, hi) = (reached.iter().min(), reached.iter().max());
        let missed = cells.iter().any(Option::is_none);
        match (lo, hi, missed) {
            (None, _, _) | (_, None, _) => cell(None, REVS),
            (Some(lo), Some(hi), false) if lo == hi => lo.to_string(),
            (Some(lo), Some(hi), false) => format!("{lo}-{hi}"),
            (Some(lo), _, true) => format!("{lo} to {}", cell(None, REVS)),
        }
    };
    let band = |v: f64| v >= 5.0;
    let slow = |v: f64| v < 5.0;
    let summary = format!(
        "- Revolutions to a 10x reduction of the extreme sensor's error (core alone, \
         noiseless): {} with our law at 5-100 rev/s either way, {} with the paper's; at \
         2 rev/s {} against {}.\n",
        span(0, &band),
        span(1, &band),
        span(0, &slow),
        span(1, &slow)
    );
    Ok(vec![
        ("compare-laws", compare),
        ("gain-sweep", sweep),
        ("laws-summary", summary),
    ])
}

/// The core alone on the extreme sensor with the 12-bit converter and noise, as
/// `firmware/mras/tests/combined.rs` measures it: ten revolutions of commissioning at
/// constant speed, then revolutions 11-20 binned (360 bins), adaptation running.
/// Returns (raw, corrected) pk-pk in rad.
fn core_spatial_errors(speed_rev_s: f64, seed: u64) -> Result<(f64, f64)> {
    let r = CommissioningRun {
        sensor: SensorModel::extreme(),
        speed_rev_s,
        sample_period_s: SAMPLE_PERIOD_S,
        inertia_kg_m2: INERTIA_KG_M2,
        adc: Some(ADC),
    };
    let mut t = Tracker::new(Config::default())?;
    let faults = r.run(&mut t, 10, noise(seed, NOISE_STD)?, |_, _| {});
    if faults != 0 || !t.faults().is_empty() {
        bail!("{speed_rev_s} rev/s: faults while commissioning");
    }
    let steps_per_rev = r.steps_per_rev();
    let (kin, k0) = (r.kinematic(), r.step_after(10));
    let mut est = SpatialError::<360>::new();
    let mut raw = SpatialError::<360>::new();
    let n = SensorModel::extreme().sensor_periods as f64;
    kin.run(
        &mut t,
        k0,
        10 * steps_per_rev,
        noise(seed + 1, NOISE_STD)?,
        |_, rec| {
            est.add(rec.theta_rad, rec.error_rad);
            raw.add(
                rec.theta_rad,
                wrap_pi((rec.y as f64).atan2(rec.x as f64) - n * rec.theta_rad) / n,
            );
        },
    );
    Ok((raw.pk_pk_rad(), est.pk_pk_rad()))
}

const NOISE_STD: f64 = 3.0e-4;

/// The paper's Fig. 8 motion, core alone: the pk-pk spatial error of the first and the
/// last second of 10 s, as `combined.rs` measures it (rad).
fn core_sine(law: Law) -> Result<(f64, f64)> {
    let kin = Kinematic {
        sensor: SensorModel::extreme(),
        trajectory: Trajectory::Sine {
            amplitude_rad_s: 100.0,
            freq_hz: 1.0,
        },
        sample_period_s: SAMPLE_PERIOD_S,
        inertia_kg_m2: INERTIA_KG_M2,
        adc: Some(ADC),
    };
    let mut t = Tracker::new(law.config())?;
    let steps = (10.0 / SAMPLE_PERIOD_S) as u64;
    let mut first = SpatialError::<360>::new();
    let mut last = SpatialError::<360>::new();
    kin.run(&mut t, 0, steps, noise(7, NOISE_STD)?, |_, rec| {
        if rec.t_s < 1.0 {
            first.add(rec.theta_rad, rec.error_rad);
        } else if rec.t_s >= 9.0 {
            last.add(rec.theta_rad, rec.error_rad);
        }
    });
    Ok((first.pk_pk_rad(), last.pk_pk_rad()))
}

fn core_accuracy() -> Result<Sections> {
    let mut s = String::from(
        "| speed | raw pk-pk | corrected pk-pk | reduction |\n|---:|---:|---:|---:|\n",
    );
    // The noise seeds `combined.rs` gives each speed.
    for (i, v) in [5.0, -5.0, 50.0, -50.0].into_iter().enumerate() {
        let (raw, corrected) = core_spatial_errors(v, 10 + i as u64)?;
        let _ = writeln!(
            s,
            "| {v:+} rev/s | {} mrad | {} mrad | {} |",
            small(raw * 1e3),
            small(corrected * 1e3),
            x(raw / corrected)
        );
    }
    s += "\nThe paper's Fig. 8 trajectory (1 Hz, 100 rad/s sine, 10 s), pk-pk:\n\n| law | first second | last second | reduction |\n|---|---:|---:|---:|\n";
    for (name, law) in [("ours", Law::Ours), ("paper", Law::Paper)] {
        let (first, last) = core_sine(law)?;
        let _ = writeln!(
            s,
            "| {name} | {} mrad | {} mrad | {} |",
            small(first * 1e3),
            small(last * 1e3),
            x(first / last)
        );
    }
    Ok(vec![("core-accuracy", s)])
}

// ---- the ripple scenarios ----

const RIPPLE: [&str; 2] = ["ripple-1rev", "ripple-5rev"];

fn spectra(sc: &Scenario, duration_s: f64) -> Result<[TruthSpectrum; 2]> {
    let (a, b) = power_up::run(sc, duration_s)?;
    let t = |b: Boot, k: usize| {
        if b.final_state != drive::commissioning::State::Run || b.faulted_samples != 0 {
            bail!(
                "{} power-up {k}: {:?} with {} faulted periods",
                sc.file.name,
                b.cause,
                b.faulted_samples
            );
        }
        b.truth_spectrum
            .with_context(|| format!("{} power-up {k}: window not all in Run", sc.file.name))
    };
    Ok([t(a, 1)?, t(b, 2)?])
}

fn m12_max(t: &TruthSpectrum, f: fn(&crate::truth_spectrum::HarmonicRow) -> f64) -> f64 {
    t.harmonics
        .iter()
        .filter(|r| r.m <= 2)
        .map(f)
        .fold(0.0, f64::max)
}

fn m3_max(t: &TruthSpectrum) -> f64 {
    t.harmonics
        .iter()
        .filter(|r| r.m >= 3)
        .map(|r| r.decoupled_mrad)
        .fold(0.0, f64::max)
}

fn learning(sc: &Scenario) -> Scenario {
    let mut sc = sc.clone();
    if let Some(c) = sc.file.commissioning.as_mut() {
        c.learn_torque_ripple = Some(true);
    }
    sc
}

/// Per file and power-up at `duration_s`: the motion, arg Zd and θ̂ against the rotor,
/// with the files' settings and with `learn_torque_ripple` on.
fn ripple_table(ci: bool) -> Result<String> {
    let mut s = String::from(
        "| power-up | rotor motion pk-pk at 1x / 2x (mrad) | arg Zd at m = 1, 2: largest (mrad); over the noise floor | arg Zd at m = 3..16: largest (mrad); over the oracle | θ̂ at m = 1, 2, largest (mrad) | with `learn_torque_ripple`: θ̂ at m = 1, 2 (mrad); motion at 1x; arg Zd at m = 1, 2 over the oracle |\n|---|---|---|---|---|---|\n",
    );
    for name in RIPPLE {
        let sc = Scenario::load(name)?;
        let d = match ci {
            true => sc.file.ci_duration_s.context("no ci_duration_s")?,
            false => sc.file.duration_s,
        };
        let plain = spectra(&sc, d)?;
        let learned = spectra(&learning(&sc), d)?;
        for (k, (t, l)) in plain.iter().zip(&learned).enumerate() {
            let m3 = t.decoupled_over_oracle_m3_up_in_bank.map_or("—".into(), x);
            let _ = writeln!(
                s,
                "| `{name}` {} | {} / {} | {}; {} | {}; {m3} | {} | {}; {}; {} |",
                k + 1,
                sig3(t.motion_1x_pk_pk_mrad),
                sig3(t.motion_2x_pk_pk_mrad),
                small(m12_max(t, |r| r.decoupled_mrad)),
                x(t.decoupled_over_floor_m1_m2()),
                small(m3_max(t)),
                small(m12_max(t, |r| r.estimate_mrad)),
                small(m12_max(l, |r| r.estimate_mrad)),
                sig3(l.motion_1x_pk_pk_mrad),
                x(l.decoupled_over_oracle_m1_m2)
            );
        }
    }
    Ok(s)
}

/// The spread of arg Zd over the oracle at `seeds` noise seeds, both files.
fn seeds_table(ci: bool, seeds: u64) -> Result<String> {
    let mut s = format!(
        "Over {seeds} noise seeds ({} power-ups a file), median (95th percentile, worst):\n\n| | m = 1, 2 over the oracle | m = 1, 2 over the noise floor | m = 3..16 over the oracle |\n|---|---|---|---|\n",
        2 * seeds
    );
    for name in RIPPLE {
        let sc = Scenario::load(name)?;
        let d = match ci {
            true => sc.file.ci_duration_s.context("no ci_duration_s")?,
            false => sc.file.duration_s,
        };
        let spread = SeedSpread::run(&sc, d, seeds)?;
        let cell = |d: crate::accuracy::stats::Dist| {
            format!("**{}** ({}, {})", x(d.median), x(d.p95), x(d.worst))
        };
        let _ = writeln!(
            s,
            "| `{name}` | {} | {} | {} |",
            cell(spread.m1_m2()),
            cell(spread.m1_m2_floor()),
            cell(spread.m3_up())
        );
    }
    Ok(s)
}

/// Seeds of the CI-length spread (`ripple_scenarios_reach_the_oracle_over_noise_seeds`)
/// and of the full-length one.
pub const CI_SEEDS: u64 = 9;
pub const FULL_SEEDS: u64 = 25;

fn ripple_ci() -> Result<Sections> {
    let mut s = ripple_table(true)?;
    s.push('\n');
    s += &seeds_table(true, CI_SEEDS)?;
    // The control: one commissioning speed keeps the motion at that speed.
    let mut one = Scenario::load("ripple-5rev")?;
    if let Some(c) = one.file.commissioning.as_mut() {
        c.second_speed_ratio = Some(0.0);
    }
    let d = one.file.ci_duration_s.context("no ci_duration_s")?;
    let (first, _) = power_up::run(&one, d)?;
    let t = first
        .truth_spectrum
        .context("ripple-5rev at one speed: window not all in Run")?;
    let m1 = t.row(1).context("no m = 1")?;
    let _ = write!(
        s,
        "\n`ripple-5rev` commissioned at one speed (`second_speed_ratio = 0`), power-up 1: arg Zd at m = 1 {} mrad, the rotor's motion there {} mrad.\n",
        small(m1.decoupled_mrad),
        small(m1.motion_mrad)
    );
    Ok(vec![("ripple-ci", s)])
}

fn ripple_full() -> Result<Sections> {
    let mut s = ripple_table(false)?;
    s.push('\n');
    s += &seeds_table(false, FULL_SEEDS)?;
    Ok(vec![("ripple", s)])
}

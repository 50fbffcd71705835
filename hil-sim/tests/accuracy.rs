//! The reduced accuracy benchmark (CI): the first 24 sensors of the published
//! population, the same plan, asserting the orderings docs/results.md reports.

use hil_sim::accuracy::report::{self, RunInfo, REDUCED_SENSORS};
use hil_sim::accuracy::stats::{summarise, Condition, Summary};
use hil_sim::accuracy::{
    draw_sensor, run_sensor, run_suite, Method, PhaseKind, Plan, DISTRIBUTION, SENSOR_PERIODS,
    SPECTRUM_PHASE,
};
use std::sync::OnceLock;

const SEED: u64 = 1;

/// The suite, run once for all tests of this file.
fn suite() -> &'static (Plan, Vec<hil_sim::accuracy::SensorResult>, Summary) {
    static SUITE: OnceLock<(Plan, Vec<hil_sim::accuracy::SensorResult>, Summary)> = OnceLock::new();
    SUITE.get_or_init(|| {
        let plan = Plan::full();
        let results = run_suite(SEED, REDUCED_SENSORS, &plan, false).expect("suite runs");
        let summary = summarise(&results, &plan);
        (plan, results, summary)
    })
}

fn med(c: &Condition, m: Method) -> f64 {
    c.get(m).pk_pk.median
}

fn phase<'a>(s: &'a Summary, plan: &Plan, kind: PhaseKind) -> &'a Condition {
    let i = plan
        .evaluation()
        .iter()
        .position(|p| p.kind == kind)
        .expect("phase in plan");
    &s.phases[i]
}

#[test]
fn offline_methods_order_as_published() {
    let (_, _, s) = suite();
    for c in &s.phases {
        let raw = med(c, Method::Raw);
        for m in Method::ALL.into_iter().filter(|m| *m != Method::Raw) {
            assert!(med(c, m) < raw, "{}: {} not below raw", c.name, m.label());
        }
        // Harmonics dominate this population: min/max and the ellipse help a little,
        // the ellipse a bit more; a LUT removes harmonics too.
        assert!(med(c, Method::MinMax) < 0.8 * raw, "{}", c.name);
        assert!(
            med(c, Method::Ellipse) < med(c, Method::MinMax),
            "{}",
            c.name
        );
        assert!(
            med(c, Method::Lut256) < med(c, Method::Ellipse) / 10.0,
            "{}",
            c.name
        );
        // The oracle is the floor of per-sample corrections; arg(Zd) places its
        // correction with the observer's noise-free angle and can dip a little below.
        for m in Method::ALL {
            let margin = if Method::MRAS.contains(&m) { 1.5 } else { 1.0 };
            assert!(
                med(c, Method::Oracle) <= margin * med(c, m),
                "{}: oracle {} above {} {}",
                c.name,
                med(c, Method::Oracle),
                m.label(),
                med(c, m)
            );
        }
    }
}

#[test]
fn default_mras_removes_what_its_paths_see_and_converges_fast() {
    let (plan, _, s) = suite();
    for c in &s.phases {
        // Its 4 paths beat min/max and the ellipse everywhere...
        for m in [Method::MinMax, Method::Ellipse] {
            assert!(
                med(c, Method::Ours) < med(c, m) / 2.0,
                "{}: ours {} vs {} {}",
                c.name,
                med(c, Method::Ours),
                m.label(),
                med(c, m)
            );
        }
    }
    // ...and what is left sits at the error harmonics m = 5..7 they do not cover.
    let spec = &s.spectrum_median_rad[Method::Ours.index()];
    let rss = |r: std::ops::RangeInclusive<usize>| {
        r.map(|m| spec[m - 1] * spec[m - 1]).sum::<f64>().sqrt()
    };
    assert!(rss(1..=4) < 0.05 * rss(5..=7), "{spec:?}");
    let oracle = &s.spectrum_median_rad[Method::Oracle.index()];
    for m in 0..4 {
        assert!(spec[m] < 5.0 * oracle[m], "m = {}: {spec:?}", m + 1);
    }
    // The 7-path bank removes them: same core, same gains.
    let all = &s.spectrum_median_rad[Method::OursAllPaths.index()];
    for m in 4..7 {
        assert!(all[m] < spec[m] / 20.0, "m = {}: {all:?}", m + 1);
    }

    let ours = s
        .trackers
        .iter()
        .find(|t| t.method == Method::Ours)
        .unwrap();
    let paper = s
        .trackers
        .iter()
        .find(|t| t.method == Method::Paper)
        .unwrap();
    assert_eq!(ours.lost_lock, 0);
    assert_eq!(ours.any_fault, 0);
    assert!(
        ours.converged_revs.median <= 5.0,
        "{:?}",
        ours.converged_revs
    );
    assert!(
        ours.converged_revs.median < paper.converged_revs.median / 2.0,
        "ours {:?} paper {:?}",
        ours.converged_revs,
        paper.converged_revs
    );
    // Same paths, same floor as the paper-literal law (within 20 %).
    let w = &s.worst_phase;
    let r = med(w, Method::Ours) / med(w, Method::Paper);
    assert!((0.8..1.2).contains(&r), "{r}");
    assert!(plan.evaluation().len() == s.phases.len());
}

#[test]
fn mras_with_every_path_reaches_the_noise_floor_and_tracks_drift() {
    let (plan, _, s) = suite();
    let offline = [
        Method::MinMax,
        Method::Ellipse,
        Method::Lut128,
        Method::Lut256,
        Method::Lut360,
    ];
    for (c, p) in s.phases.iter().zip(plan.evaluation()) {
        if p.kind == PhaseKind::LoadSteps {
            continue;
        }
        let ours = med(c, Method::OursAllPaths);
        assert!(
            ours <= 2.0 * med(c, Method::Oracle),
            "{}: {ours} vs oracle {}",
            c.name,
            med(c, Method::Oracle)
        );
        for m in offline.into_iter().chain([Method::Paper, Method::Ours]) {
            assert!(ours < med(c, m), "{}: {ours} vs {}", c.name, m.label());
        }
    }
    // Load steps: the correction rides on the observer's lagging angle.
    let load = phase(s, plan, PhaseKind::LoadSteps);
    let steady = &s.phases[SPECTRUM_PHASE];
    assert!(
        med(load, Method::OursAllPaths) > 1.5 * med(steady, Method::OursAllPaths),
        "load {} steady {}",
        med(load, Method::OursAllPaths),
        med(steady, Method::OursAllPaths)
    );
    // Drift: offline calibrations go stale, the MRAS follows.
    let drift = phase(s, plan, PhaseKind::Drift);
    for m in [Method::Lut128, Method::Lut256, Method::Lut360] {
        assert!(med(drift, m) > 2.0 * med(steady, m), "{}", m.label());
        assert!(med(drift, Method::OursAllPaths) < med(drift, m) / 3.0);
    }
    assert!(med(drift, Method::OursAllPaths) < 1.5 * med(steady, Method::OursAllPaths));
    assert!(med(drift, Method::Ours) < 1.2 * med(steady, Method::Ours));

    let t = s
        .trackers
        .iter()
        .find(|t| t.method == Method::OursAllPaths)
        .unwrap();
    assert_eq!((t.lost_lock, t.any_fault, t.never_converged), (0, 0, 0));
    assert_eq!(t.not_converged_in_commissioning, 0);
    assert!(t.converged_revs.worst <= 6.0, "{:?}", t.converged_revs);
}

#[test]
fn sensors_are_deterministic_and_within_the_documented_distribution() {
    let d = &DISTRIBUTION;
    for i in 0..200 {
        let c = draw_sensor(SEED, i);
        let m = &c.params.model;
        assert_eq!(m.sensor_periods, SENSOR_PERIODS);
        assert!(m.ax.abs() <= d.offset_max && m.ay.abs() <= d.offset_max);
        assert!((2.0 * (m.bx1 - m.by1) / (m.bx1 + m.by1)).abs() <= d.imbalance_max);
        assert!(m.phi_x1_rad.abs() <= d.quadrature_max_deg.to_radians());
        assert_eq!(m.harmonic_count, d.harmonic_orders.len());
        for (h, want) in m.harmonics.iter().zip(d.harmonic_orders) {
            assert_eq!(h.h, want);
            assert!((0.0..=d.harmonic_max).contains(&h.bx));
            assert!((0.0..=d.harmonic_max).contains(&h.by));
        }
        assert!((d.noise_min..=d.noise_max).contains(&c.params.noise_std));
        assert!((0.0..=d.skew_max_s).contains(&c.params.skew_s));
        assert_eq!(c.params.adc, Some(d.adc));
        for r in [c.drift.ax_per_s, c.drift.ay_per_s, c.drift.gain_per_s] {
            assert!(r.abs() <= d.drift_max_per_s);
        }
        // Independent of how many are drawn, and of other seeds.
        assert_eq!(draw_sensor(SEED, i).params, c.params);
        assert_ne!(draw_sensor(SEED + 1, i).params, c.params);
    }
    // The same sensor gives the same run, bit for bit.
    let (plan, results, _) = suite();
    let again = run_sensor(&draw_sensor(SEED, 5), plan).unwrap();
    assert_eq!(again.residuals, results[5].residuals);
    assert_eq!(again.mras, results[5].mras);
}

#[test]
fn results_page_csv_and_plots_are_written() {
    let (plan, results, s) = suite();
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("results.md");
    let plots = dir.path().join("results");
    let info = RunInfo {
        seed: SEED,
        sensors: results.len(),
        reduced: true,
        wall_s: 1.0,
        threads: 2,
    };
    report::write_outputs(results, s, plan, &info, &page, &plots).unwrap();
    let text = std::fs::read_to_string(&page).unwrap();
    for want in [
        "**Generated** by `cargo xtask bench-accuracy`",
        "--sensors 24 --seed 1 --reduced",
        "## Main table",
        "## Targets for our MRAS",
        "## Sensor distribution",
        "| MRAS, ours (default) |",
        "| oracle (noise floor) |",
        "](results/cdf_worst_phase.png)",
    ] {
        assert!(text.contains(want), "no `{want}` in the page");
    }
    let csv = std::fs::read_to_string(plots.join("per_sensor.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), results.len() + 1);
    let columns = lines[0].split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == columns));
    assert!(lines[0].contains("drift_ours_pkpk_mrad"));
    for png in [
        "cdf_worst_phase.png",
        "phases_median.png",
        "residual_harmonics.png",
    ] {
        let bytes = std::fs::read(plots.join(png)).unwrap();
        assert_eq!(&bytes[..4], b"\x89PNG", "{png}");
    }
}

#[test]
fn bad_arguments_fail_with_a_message() {
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_hil-sim"))
            .arg("bench-accuracy")
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (ok, err) = run(&["--sensors", "0"]);
    assert!(!ok && err.contains("--sensors 0: must be in 1..="), "{err}");
    let (ok, err) = run(&["--sensors", "many"]);
    assert!(!ok && err.contains("--sensors"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let (ok, err) = run(&["--sensors", "1", "--out", dir.path().to_str().unwrap()]);
    assert!(!ok && err.contains("must name a file"), "{err}");
}

//! The reduced accuracy benchmark (CI): the first 24 sensors of the published
//! population, the same plan, asserting the orderings docs/results.md reports. Its
//! figures are published there (*The reduced variant CI runs*, from
//! docs/figures/accuracy-reduced.json, which `cargo xtask docs --check` regenerates);
//! each bound below is within 2x of the figure it bounds, quoted where it is derived.

use hil_sim::accuracy::report::{self, RunInfo, Suite, REDUCED_SENSORS};
use hil_sim::accuracy::stats::{Condition, Summary, TrackerStats};
use hil_sim::accuracy::{
    draw_sensor, draw_sensor_in, run_sensor, Harmonics, Method, PhaseKind, Plan, SensorResult,
    DISTRIBUTION, DISTRIBUTION_N1, SENSOR_PERIODS, SPECTRUM_HARMONICS_OF_THETA_S, SPECTRUM_PHASE,
};
use std::sync::OnceLock;

const SEED: u64 = 1;

/// The main (N = 2) suite, run once for all tests of this file.
fn main_suite() -> &'static Suite {
    static SUITE: OnceLock<Suite> = OnceLock::new();
    SUITE.get_or_init(|| Suite::run(&DISTRIBUTION, SEED, REDUCED_SENSORS, false).unwrap())
}

/// The N = 1 suite (banks from the data), run once.
fn n1_suite() -> &'static Suite {
    static SUITE: OnceLock<Suite> = OnceLock::new();
    SUITE.get_or_init(|| Suite::run(&DISTRIBUTION_N1, SEED, REDUCED_SENSORS, false).unwrap())
}

fn suite() -> (&'static Plan, &'static Vec<SensorResult>, &'static Summary) {
    let s = main_suite();
    (&s.plan, &s.results, &s.summary)
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

fn tracker(s: &Summary, m: Method) -> &TrackerStats {
    s.trackers
        .iter()
        .find(|t| t.method == m)
        .expect("a tracker")
}

fn spectrum(s: &Summary, m: Method) -> &[f64; SPECTRUM_HARMONICS_OF_THETA_S] {
    &s.spectrum_median_rad[m.index()]
}

/// Root-sum-square of the median harmonic amplitudes m in `r` (1-based).
fn rss(spec: &[f64; SPECTRUM_HARMONICS_OF_THETA_S], r: std::ops::RangeInclusive<usize>) -> f64 {
    r.map(|m| spec[m - 1] * spec[m - 1]).sum::<f64>().sqrt()
}

#[test]
fn default_mras_reaches_the_noise_floor_and_tracks_drift() {
    let (plan, _, s) = suite();
    let offline = [
        Method::MinMax,
        Method::Ellipse,
        Method::Lut128,
        Method::Lut256,
        Method::Lut360,
    ];
    for c in &s.phases {
        // The median target (1.5x the oracle) holds in every phase, the load steps
        // included: the adaptation pauses through the observer's torque transients
        // (docs/theory.md §3), so only the placement still sees the lag.
        let ours = med(c, Method::Ours);
        assert!(
            ours <= 1.5 * med(c, Method::Oracle),
            "{}: {ours} vs oracle {}",
            c.name,
            med(c, Method::Oracle)
        );
        for m in offline.into_iter().chain([Method::OursPaperBank]) {
            assert!(ours < med(c, m), "{}: {ours} vs {}", c.name, m.label());
        }
    }
    assert!(s.worst_phase.ratio_to_oracle(Method::Ours) <= 1.5);
    let steady = &s.phases[SPECTRUM_PHASE];
    // Drift: offline calibrations go stale (published: a LUT's median 3.9-5.5x its
    // +20 rev/s one), the MRAS follows (a LUT's drift median 9.0-9.3x ours).
    let drift = phase(s, plan, PhaseKind::Drift);
    for m in [Method::Lut128, Method::Lut256, Method::Lut360] {
        assert!(med(drift, m) > 2.0 * med(steady, m), "{}", m.label());
        assert!(
            med(drift, Method::Ours) < med(drift, m) / 4.5,
            "{}",
            m.label()
        );
    }
    assert!(med(drift, Method::Ours) < 1.5 * med(steady, Method::Ours));
    // The 95th percentile target, just: the oracle itself is not far above 100x.
    let w = &s.worst_phase;
    assert!(
        w.p95_reduction(Method::Ours) >= 100.0,
        "{}",
        w.p95_reduction(Method::Ours)
    );

    let t = tracker(s, Method::Ours);
    assert_eq!((t.lost_lock, t.any_fault, t.never_converged), (0, 0, 0));
    assert_eq!(t.not_converged_in_commissioning, 0);
    assert!(t.converged_revs.worst <= 5.0, "{:?}", t.converged_revs);
}

#[test]
fn the_papers_four_paths_leave_m5_to_7_that_the_default_removes() {
    let (_, _, s) = suite();
    let four = Method::OursPaperBank;
    for c in &s.phases {
        // Four paths beat min/max and the ellipse everywhere...
        for m in [Method::MinMax, Method::Ellipse] {
            assert!(
                med(c, four) < med(c, m) / 2.0,
                "{}: 4 paths {} vs {} {}",
                c.name,
                med(c, four),
                m.label(),
                med(c, m)
            );
        }
    }
    // ...and what they leave sits at the error harmonics m = 5..7 they do not cover.
    // Published: m = 1..4 at 0.0055 of m = 5..7 (root sums of squares); at m = 1..4
    // up to 3.3x the oracle; ours at m = 5..7 at least 228x below the four paths', at
    // m = 1..7 up to 1.7x the oracle; the four paths' worst phase 66x ours.
    let spec = spectrum(s, four);
    let oracle = spectrum(s, Method::Oracle);
    assert!(rss(spec, 1..=4) < 0.011 * rss(spec, 5..=7), "{spec:?}");
    for m in 0..4 {
        assert!(spec[m] < 5.0 * oracle[m], "m = {}: {spec:?}", m + 1);
    }
    // The default bank removes them: same core, same gains, down to the oracle's level.
    let ours = spectrum(s, Method::Ours);
    for m in 0..7 {
        assert!(ours[m] < 3.0 * oracle[m], "m = {}: {ours:?}", m + 1);
    }
    for m in 4..7 {
        assert!(ours[m] < spec[m] / 115.0, "m = {}: {ours:?}", m + 1);
    }
    let w = &s.worst_phase;
    assert!(med(w, four) > 33.0 * med(w, Method::Ours));
    let t = tracker(s, four);
    assert_eq!((t.lost_lock, t.any_fault), (0, 0));
}

#[test]
fn paper_literal_law_on_the_same_bank_is_slower_but_reaches_the_floor() {
    let (plan, _, s) = suite();
    // Published: medians of 3.86 and 18.16 revolutions to `converged`; at +20 rev/s
    // the paper's law 8.6x ours; under drift 4.2x ours.
    let (ours, paper) = (tracker(s, Method::Ours), tracker(s, Method::Paper));
    assert_eq!((paper.lost_lock, paper.any_fault), (0, 0));
    assert!(
        ours.converged_revs.median <= 5.0
            && ours.converged_revs.median < paper.converged_revs.median / 2.4,
        "ours {:?} paper {:?}",
        ours.converged_revs,
        paper.converged_revs
    );
    // Right after commissioning the paper's law is still converging...
    let first = &s.phases[SPECTRUM_PHASE];
    assert!(
        med(first, Method::Paper) > 4.3 * med(first, Method::Ours),
        "paper {} ours {}",
        med(first, Method::Paper),
        med(first, Method::Ours)
    );
    // ...and it gets to the same floor in the later constant-speed phases: the same
    // fixed point, the same 7 paths.
    for (i, p) in plan.evaluation().iter().enumerate() {
        if p.kind == PhaseKind::Steady && i != SPECTRUM_PHASE {
            let c = &s.phases[i];
            assert!(
                c.ratio_to_oracle(Method::Paper) <= 1.5,
                "{}: {}",
                c.name,
                c.ratio_to_oracle(Method::Paper)
            );
        }
    }
    // It follows the drift less closely than ours.
    let drift = phase(s, plan, PhaseKind::Drift);
    assert!(med(drift, Method::Ours) < med(drift, Method::Paper) / 2.2);
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
        let Harmonics::AllOf { orders, max } = d.harmonics else {
            panic!("the main population has every order");
        };
        assert_eq!(m.harmonic_count, orders.len());
        for (h, want) in m.harmonics.iter().zip(orders) {
            assert_eq!(h.h, want);
            assert!((0.0..=max).contains(&h.bx));
            assert!((0.0..=max).contains(&h.by));
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
    let figures = dir.path().join("figures");
    let info = RunInfo {
        seed: SEED,
        sensors: results.len(),
        reduced: true,
    };
    let _ = (plan, s);
    report::write_outputs(&[main_suite(), n1_suite()], &info, &page, &plots, &figures).unwrap();
    let text = std::fs::read_to_string(&page).unwrap();
    for want in [
        "**Generated** by `cargo xtask bench-accuracy`",
        "--sensors 24 --seed 1 --reduced",
        "## Main table",
        "## Targets for our MRAS",
        "## Sensor distribution",
        "| MRAS, ours (default) |",
        "| *MRAS, ours, the paper's 4 paths* |",
        "| target | default configuration (7 paths) |",
        "| oracle (noise floor) |",
        "](results/cdf_worst_phase.png)",
        "## N = 1 sensors: a bank chosen from the data",
        "| sensor periods per revolution N | 1 |",
        "| *MRAS, ours, bank from the data* |",
    ] {
        assert!(text.contains(want), "no `{want}` in the page");
    }
    let csv = std::fs::read_to_string(plots.join("per_sensor.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), results.len() + 1);
    let columns = lines[0].split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == columns));
    for key in [
        "drift_ours_pkpk_mrad",
        "drift_ours4_pkpk_mrad",
        "ours4_converged_revs",
    ] {
        assert!(lines[0].contains(key), "no {key} column");
    }
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

#[test]
fn n1_sensors_are_within_their_documented_distribution() {
    let d = &DISTRIBUTION_N1;
    let Harmonics::Rotating {
        count,
        max_m,
        amplitude: (lo, hi),
    } = d.harmonics
    else {
        panic!("the N = 1 population has rotating harmonics");
    };
    let mut seen = [false; 17];
    for i in 0..200 {
        let c = draw_sensor_in(d, SEED, i);
        let m = &c.params.model;
        assert_eq!(m.sensor_periods, 1);
        assert!((count.0..=count.1).contains(&m.harmonic_count));
        let mut orders = Vec::new();
        for h in &m.harmonics[..m.harmonic_count] {
            // Rotating: equal on X and Y, one error harmonic m = |h - 1| each.
            assert_eq!((h.bx, h.phi_x_rad), (h.by, h.phi_y_rad));
            assert!((lo..=hi).contains(&h.bx));
            let err = (h.h - 1).unsigned_abs() as u8;
            assert!((3..=max_m).contains(&err), "h = {}", h.h);
            assert!(!orders.contains(&err), "two harmonics at m = {err}");
            orders.push(err);
            seen[err as usize] = true;
        }
    }
    assert!(seen[3..=16].iter().all(|s| *s), "every m = 3..16 is drawn");
}

/// N = 1 sensors, harmonics up to m = 16: the drive's bank from the data reaches 1.5x
/// the oracle in every phase, where the fixed default bank (m = 1..7) cannot.
#[test]
fn a_bank_from_the_data_reaches_the_noise_floor_on_n1_sensors() {
    let s = n1_suite();
    for (c, p) in s.summary.phases.iter().zip(s.plan.evaluation()) {
        let (data, oracle) = (med(c, Method::OursFromData), med(c, Method::Oracle));
        // The target, 1.5x the oracle, and 2x under drift (published: up to 1.26x).
        let bound = if p.kind == PhaseKind::Drift { 2.0 } else { 1.5 };
        assert!(
            data <= bound * oracle,
            "{}: {data} vs oracle {oracle}",
            c.name
        );
        // Published: the default bank 40-58x the bank from the data, the paper's law
        // 39-57x, the 256-bin LUT 2.9-8.9x.
        for (m, factor) in [
            (Method::Ours, 21.0),
            (Method::Paper, 20.0),
            (Method::Lut256, 2.0),
        ] {
            assert!(
                data < med(c, m) / factor,
                "{}: {data} vs {} {}",
                c.name,
                m.label(),
                med(c, m)
            );
        }
    }
    for r in &s.results {
        let o = r.survey.as_ref().expect("every survey completes");
        assert!(o.bank.as_slice().starts_with(&mras::survey::FIRST_STAGE));
        let t = r.tracker(Method::OursFromData).unwrap();
        assert!(!t.lost_lock, "sensor {}", r.index);
        assert!(
            t.converged_in_commissioning,
            "sensor {}: converged after {:?} revolutions",
            r.index, t.converged_revs
        );
    }
}

//! The paper scenarios, reduced-length (`ci_duration_s`), with their figures asserted
//! within 2x of what the docs publish for the same runs: docs/figures/scenarios-ci.md,
//! commissioning.md and ripple-ci.md (`cargo xtask docs scenarios commissioning
//! ripple-ci`), quoted below where a bound is derived from them. A lower bound is at
//! most half the published figure, an upper bound at most twice.

use hil_sim::input_error::InputError;
use hil_sim::scenario::{self, RunOutcome, Scenario, ScenarioError, Variant};
use hil_sim::truth_spectrum::TruthSpectrum;

fn run(name: &str, variant: Variant) -> RunOutcome {
    let sc = Scenario::load(name).unwrap();
    let d = sc.file.ci_duration_s.unwrap_or(sc.file.duration_s);
    let out = scenario::run(&sc, variant, d, false).unwrap();
    assert_eq!(out.summary.faults, 0, "{name} {variant:?}: faults");
    out
}

fn coefficients(o: &RunOutcome) -> Vec<scenario::NamedCoefficient> {
    o.summary.coefficients.clone()
}

/// Fig. 8 and Fig. 11 (friction load, Ĵ = 0.66 J) converge to the same coefficients,
/// with either law: the MRAS is insensitive to Ĵ and to non-spatial disturbances (§V.A-B).
#[test]
fn fig8_and_fig11_coefficients_agree() {
    // Published: the largest difference 0.00556 with either law; the smallest of the
    // first four coefficients 0.0200 (either law), the largest of h6..h8 0.000106
    // (paper) and 1.85e-5 (ours).
    const TOL: f32 = 0.01;
    for (v, idle_max) in [(Variant::Ours, 3.7e-5), (Variant::Paper, 2.1e-4)] {
        let a = coefficients(&run("paper-fig8", v));
        let b = coefficients(&run("paper-fig11", v));
        for (i, ((name, re8, im8), (_, re11, im11))) in a.iter().zip(&b).enumerate() {
            let d = (re8 - re11).hypot(im8 - im11);
            println!(
                "{v:?} {name}: fig8 {re8:+.4}{im8:+.4}j fig11 {re11:+.4}{im11:+.4}j |Δ| {d:.5}"
            );
            assert!(d < TOL, "{v:?} {name}: |Δ| = {d}");
            // The extreme sensor (h = 2..5) loads the first four paths of the default
            // bank; it has no error at m = 5..7, so h6..h8 stay near zero.
            let m = re8.hypot(*im8);
            if i < 4 {
                assert!(m > 0.01, "{v:?} {name} did not adapt: {m}");
            } else {
                assert!(m < idle_max, "{v:?} {name} adapted to nothing: {m}");
            }
        }
    }
}

/// Fig. 9 and Fig. 10: the position loop's tracking error falls once the MRAS runs, at
/// least half the published 359x and 96.7x (the paper measured 4.5x on its bench for
/// Fig. 10).
#[test]
fn fig9_and_fig10_tracking_error_falls_as_published() {
    for (name, min_ratio) in [("paper-fig9", 180.0), ("paper-fig10", 48.0)] {
        let o = run(name, Variant::Ours);
        let before = o.summary.before.as_ref().unwrap().tracking_pk_pk_mrad;
        let after = o.summary.after.tracking_pk_pk_mrad;
        println!(
            "{name}: tracking error {before:.2} → {after:.3} mrad pk-pk ({:.1}x)",
            before / after
        );
        assert!(
            before / after >= min_ratio,
            "{name}: {before} → {after}, bound {min_ratio}x"
        );
        assert!(
            o.summary.converged_after_s.is_some(),
            "{name}: never converged"
        );
    }
}

/// Fig. 10's sensor is built to show the paper's ~34 mrad pk-pk before correction
/// (published: 34.7).
#[test]
fn fig10_sensor_matches_the_paper_before_correction() {
    let o = run("paper-fig10", Variant::Ours);
    let raw = o.summary.after.raw_pk_pk_mrad;
    assert!((30.0..40.0).contains(&raw), "{raw}");
}

#[test]
fn table1_harmonics_match() {
    let sc = Scenario::load("table1").unwrap();
    let rows = scenario::run_table1(&sc, sc.file.ci_duration_s.unwrap()).unwrap();
    assert_eq!(rows.len(), 8);
    for (name, expect, got, spec) in rows {
        assert_eq!(expect, got, "{name}: spectrum {spec:?}");
    }
}

/// Every file of hil-sim/scenarios/ is compiled in (`SHIPPED`), and each parses.
#[test]
fn every_shipped_scenario_parses() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut files: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| {
            let p = e.unwrap().path();
            (p.extension()? == "toml").then(|| p.file_stem()?.to_str().map(String::from))?
        })
        .collect();
    files.sort();
    let names = scenario::list();
    assert_eq!(
        names, files,
        "hil-sim/scenarios/ against SHIPPED in scenario.rs"
    );
    for n in names {
        let sc = Scenario::load(&n).unwrap();
        assert_eq!(sc.file.name, n, "the file's name = its file name");
    }
}

#[test]
fn malformed_scenarios_name_line_and_field() {
    let text = "name = \"x\"\ndescription = \"y\"\nduration_s = 1.0\nbogus = 3\n";
    let e = Scenario::parse(text, "x.toml").unwrap_err();
    assert!(
        matches!(&e, ScenarioError::Parse(InputError { line: Some(4), .. })),
        "{e:?}"
    );
    let e = e.to_string();
    assert!(e.contains("x.toml:4") && e.contains("bogus"), "{e}");
    let text = "name = \"x\"\ndescription = \"y\"\nduration_s = -1.0\n[control]\nmode = \"position\"\nbandwidth_hz = 5.0\nreference = { kind = \"ramp\", speed_rev_s = 5.0 }\n";
    let e = Scenario::parse(text, "x.toml").unwrap_err().to_string();
    assert!(e.contains("duration_s"), "{e}");
    let text = "name = \"x\"\ndescription = \"y\"\nduration_s = 1.0\n[control]\nmode = \"torque\"\nbandwidth_hz = 5.0\nreference = { kind = \"ramp\", speed_rev_s = 5.0 }\n";
    let e = Scenario::parse(text, "x.toml").unwrap_err().to_string();
    assert!(e.contains("control.mode"), "{e}");
    let e = Scenario::load("no-such-scenario").unwrap_err().to_string();
    assert!(e.contains("available: ") && e.contains("paper-fig9"), "{e}");
}

/// The summary's "truth" column is the closed form where one exists: Fig. 9's sensor
/// (offsets, Y at 66 %) has Xo = -Ax, Yo = -Ay (eq. 6-7), C = By1 - Bx1, D = 0
/// (eq. 10-11); and our law lands on it on the simulated drive.
#[test]
fn fig9_truth_is_the_closed_form_and_ours_reaches_it() {
    let sc = Scenario::load("paper-fig9").unwrap();
    let truth = scenario::reference_coefficients(&sc).unwrap().unwrap();
    let s = &sc.file.sensor;
    let (xo, yo) = mras::closed_form::offset_and_h2(s.ax, s.ay, 0.0, 0.0);
    let (c, d) = mras::closed_form::amplitude_quadrature(s.bx1, s.by1, 0.0);
    let want = [("offset", xo, yo), ("amplitude_quadrature", c, d)];
    for (name, re, im) in want {
        let (_, tr, ti) = truth.iter().find(|(n, _, _)| n == name).unwrap();
        assert!(
            (*tr as f64 - re).abs() < 1e-4 && (*ti as f64 - im).abs() < 1e-4,
            "{name}"
        );
    }
    // Published: 4.35e-5 at the largest.
    let ours = coefficients(&run("paper-fig9", Variant::Ours));
    for ((name, re, im), (_, tr, ti)) in ours.iter().zip(&truth) {
        let d = (re - tr).hypot(im - ti);
        assert!(
            d < 8.7e-5,
            "{name}: ours {re}{im:+}j vs truth {tr}{ti:+}j: {d}"
        );
    }
}

/// The file-format example in docs/hil-sim.md is a valid scenario.
#[test]
fn documented_example_parses() {
    let doc = include_str!("../../docs/hil-sim.md");
    let start = doc.find("```toml\n").expect("toml block") + 8;
    let end = start + doc[start..].find("```").unwrap();
    let sc = Scenario::parse(&doc[start..end], "docs/hil-sim.md").unwrap();
    assert_eq!(sc.file.motor.cogging.len(), 1);
    assert_eq!(sc.file.sensor.harmonics.len(), 2);
    assert!(sc.file.paper.is_some());
}

/// The firmware's control period and supervisor end to end on the simulated drive:
/// erased flash → every commissioning state in order → Run, stored; second power-up
/// loads and runs with the stored alignment.
#[test]
fn commissioning_scenario_commissions_stores_and_reloads() {
    use drive::commissioning::State::*;
    let sc = Scenario::load("commissioning").unwrap();
    let (first, second) = hil_sim::power_up::run(&sc, sc.file.ci_duration_s.unwrap()).unwrap();
    let states: Vec<_> = first.transitions.iter().map(|(_, s)| *s).collect();
    assert_eq!(
        states,
        [
            CheckSensor,
            LoadCalibration,
            Identify,
            Align,
            Sweep,
            SpinUp,
            Adapt,
            Verify,
            Motion,
            Store,
            Run
        ]
    );
    assert_eq!(first.cause, None);
    assert!(!first.loaded_from_flash);
    assert_eq!(first.faulted_samples, 0);
    assert_eq!((first.missed_periods, second.missed_periods), (0, 0));
    // The scenario mounts its sensor reversed at 73°: the drive found it.
    assert!(first.alignment.reversed);
    assert_eq!(second.alignment, first.alignment);
    // Published at CI length (docs/figures/commissioning.md): the electrical angle about
    // 1 mrad off the rotor's, torque per amp 0.9995 (the board's 820 ns of dead time,
    // its identified error fed forward: 0.9998 without the feed-forward, 0.9999 on an
    // ideal inverter), the spatial error about 3 000x below raw, Adapt 4.2
    // revolutions, the reloaded coefficients about 1e-4 from the stored ones.
    for b in [&first, &second] {
        let e = b.run_angle_error_e_rad.unwrap();
        assert!(e.abs() < 2.0e-3, "electrical angle {e} rad off");
        let k = b.run_torque_per_amp.unwrap();
        assert!(k > 0.999, "torque per amp {k}");
        // Nothing dropped, late or lost, and the stream has the records to say so.
        assert!(b.records().count() > 100);
        assert!(b.losses().is_none(), "{:?}", b.losses());
    }
    let run = first.run.as_ref().unwrap();
    assert!(
        run.raw_pk_pk_mrad / run.estimate_pk_pk_mrad > 1690.0,
        "{run:?}"
    );
    assert!(first.adapt_revs.unwrap() < 8.4, "{:?}", first.adapt_revs);

    let states: Vec<_> = second.transitions.iter().map(|(_, s)| *s).collect();
    assert_eq!(states, [CheckSensor, LoadCalibration, Identify, Run]);
    assert!(second.loaded_from_flash);
    // Both power-ups identified the plant's R and L (the controller started from the
    // firmware's nominal ones) through the board's 820 ns of dead time.
    let m = &sc.file.motor;
    for b in [&first, &second] {
        let x = b.identified().expect("identified");
        assert!((x.r_ohm as f64 / m.r_ohm - 1.0).abs() < 0.05, "{x:?}");
        assert!((x.ld_h as f64 / m.l_h - 1.0).abs() < 0.10, "{x:?}");
        assert!((x.lq_h as f64 / m.l_h - 1.0).abs() < 0.10, "{x:?}");
    }
    // The first identified the plant's flux linkage and inertia at speed (from the
    // nominal ones), the second loaded them with the calibration.
    let (found, loaded) = (first.motion().expect("identified"), second.motion());
    assert!(
        (found.flux_wb as f64 / m.flux_wb - 1.0).abs() < 0.03,
        "{found:?}"
    );
    assert!(
        (found.inertia_kg_m2 as f64 / m.j_kg_m2 - 1.0).abs() < 0.10,
        "{found:?}"
    );
    assert_eq!(loaded, Some(found), "the record's motor");
    let run = second.run.as_ref().unwrap();
    assert!(
        run.raw_pk_pk_mrad / run.estimate_pk_pk_mrad > 1660.0,
        "{run:?}"
    );
    // The reloaded coefficients are the stored ones (slow tracking moves them little).
    for ((n, a, b), (_, c, d)) in first.coefficients.iter().zip(&second.coefficients) {
        let moved = (a - c).hypot(b - d);
        assert!(moved < 2.2e-4, "{n}: {moved}");
    }
}

/// A disconnected sensor at power-up: the safe state with its cause, PWM never enabled.
#[test]
fn commissioning_with_a_dead_sensor_ends_safe() {
    let text = scenario::shipped("commissioning")
        .unwrap()
        .replace("bx1 = 1.2", "bx1 = 0.05\nby1 = 0.05")
        .replace("ax = 0.10", "ax = 0.0")
        .replace("ay = -0.08", "ay = 0.0")
        .replace("harmonics = [", "harmonics_unused = [");
    let text = text
        .lines()
        .filter(|l| {
            !l.contains("harmonics_unused")
                && !l.trim_start().starts_with("{ h =")
                && l.trim() != "]"
        })
        .collect::<Vec<_>>()
        .join("\n");
    let sc = Scenario::parse(&text, "dead-sensor.toml").unwrap();
    let (first, _) = hil_sim::power_up::run(&sc, 0.5).unwrap();
    assert_eq!(first.final_state, drive::commissioning::State::Safe);
    assert_eq!(
        first.cause,
        Some(drive::commissioning::Cause::Sensor(mras::Fault::SensorLost))
    );
    assert!(first.entered(drive::commissioning::State::Align).is_none());
}

/// Both power-ups of a ripple scenario at CI length, each in Run without a fault: the
/// truth spectrum of each (printed), named for the messages.
fn ripple_power_ups(sc: &Scenario, name: &str) -> Vec<(String, TruthSpectrum)> {
    let (first, second) = hil_sim::power_up::run(sc, sc.file.ci_duration_s.unwrap()).unwrap();
    [first, second]
        .into_iter()
        .enumerate()
        .map(|(k, b)| {
            let what = format!("{name} power-up {}", k + 1);
            assert_eq!(
                b.final_state,
                drive::commissioning::State::Run,
                "{what}: {:?}",
                b.cause
            );
            assert_eq!(b.faulted_samples, 0, "{what}");
            // The bank from the data grows through the update queue: nothing dropped.
            assert!(b.losses().is_none(), "{what}: {:?}", b.losses());
            let t = b.truth_spectrum.expect("window all in Run");
            print!("{what}:\n{}", t.text("  "));
            (what, t)
        })
        .collect()
}

/// The ripple scenarios (N = 1 sensor, torque ripple at once and twice per revolution)
/// at CI length: both power-ups reach Run and measure their spectra against the true
/// rotor. Commissioned at 20 and 40 rev/s, the rotor's motion separated from the sensor
/// error across the two speeds, and run at 1 or 5 rev/s, below half that speed, where
/// Run does not track: the corrected angle (arg Zd) is the sensor corrected to within
/// a few times the oracle at m = 1, 2, where the motion ripple is, and it does not learn
/// the rotor's motion. (θ̂ still follows the motion with the observer's lag: the files
/// leave `learn_torque_ripple` off, `a_learned_torque_ripple_puts_theta_hat_on_the_rotor`.)
/// What docs/figures/ripple-ci.md publishes for a ripple file, the largest over its
/// two power-ups: the motion pk-pk at 1x and 2x (mrad; the smallest), arg Zd at m = 1, 2
/// (mrad, and over the noise floor), at m = 3..16 (mrad, and over the oracle), and with
/// `learn_torque_ripple`, θ̂ at m = 1, 2 (mrad) and arg Zd at m = 1, 2 over the oracle.
struct RipplePublished {
    motion_mrad: [f64; 2],
    m12_mrad: f64,
    m12_floor: f64,
    m3_mrad: f64,
    m3_oracle: f64,
    learned_theta_mrad: f64,
    learned_m12_oracle: f64,
}

fn published(name: &str) -> RipplePublished {
    match name {
        "ripple-1rev" => RipplePublished {
            motion_mrad: [8.74, 12.9],
            m12_mrad: 0.00294,
            m12_floor: 0.999,
            m3_mrad: 0.00511,
            m3_oracle: 1.19,
            learned_theta_mrad: 0.00734,
            learned_m12_oracle: 1.46,
        },
        "ripple-5rev" => RipplePublished {
            motion_mrad: [8.84, 9.65],
            m12_mrad: 0.00666,
            m12_floor: 1.53,
            m3_mrad: 0.0104,
            m3_oracle: 1.38,
            learned_theta_mrad: 0.00711,
            learned_m12_oracle: 1.58,
        },
        _ => panic!("no published figures for {name}"),
    }
}

fn ripple_scenario_reports_motion_and_spectra(name: &str) -> [f64; 2] {
    let sc = Scenario::load(name).unwrap();
    let p = published(name);
    let mut m1_mrad = [0.0; 2];
    for (k, (what, t)) in ripple_power_ups(&sc, name).into_iter().enumerate() {
        // The rig moves as the scenario says, within 2x of the published motion.
        for (h, pk_pk) in [(1, t.motion_1x_pk_pk_mrad), (2, t.motion_2x_pk_pk_mrad)] {
            let want = p.motion_mrad[h - 1];
            assert!(
                (0.5 * want..=2.0 * want).contains(&pk_pk),
                "{what}: motion at {h}x {pk_pk} mrad pk-pk, published {want}"
            );
        }
        assert_eq!(t.harmonics.len(), 16, "{what}");
        for r in &t.harmonics {
            let figures = [
                r.raw_mrad,
                r.estimate_mrad,
                r.decoupled_mrad,
                r.oracle_mrad,
                r.motion_mrad,
                r.estimate_over_oracle,
            ];
            assert!(figures.iter().all(|v| v.is_finite()), "{what}: {r:?}");
            // The oracle is the noise floor: well under the sensor's own error.
            assert!(r.oracle_mrad < 0.05 * r.raw_mrad, "{what}: {r:?}");
        }
        // The sensor error at m = 1, 2 is corrected to the noise floor (one speed leaves
        // the motion at the commissioning speed, `the_second_speed_separates_the_motion`),
        // and the motion is not learned. The floor is the oracle's level over all 16
        // harmonics: its own m = 1, 2 are two noise draws, whose ratio scatters between
        // seeds (`ripple_scenarios_reach_the_oracle_over_noise_seeds`); this run is seed
        // 1, as published.
        let m12 = t.decoupled_over_floor_m1_m2();
        assert!(
            m12 < 2.0 * p.m12_floor,
            "{what}: arg Zd at m = 1, 2 {m12}x the noise floor, published {}",
            p.m12_floor
        );
        for m in [1, 2] {
            let r = t.row(m).unwrap();
            assert!(r.decoupled_mrad < 2.0 * p.m12_mrad, "{what}: {r:?}");
            assert!(r.decoupled_mrad < 0.01 * r.motion_mrad, "{what}: {r:?}");
        }
        m1_mrad[k] = t.row(1).unwrap().decoupled_mrad;
        // The bank has a path for every harmonic, and the sensor error is removed at
        // each.
        assert_eq!(t.decoupled_over_oracle_m3_up_not_in_bank, None, "{what}");
        let m3 = t.decoupled_over_oracle_m3_up_in_bank.unwrap();
        assert!(
            m3 < 2.0 * p.m3_oracle,
            "{what}: arg Zd at m = 3..16 {m3}x the oracle, published {}",
            p.m3_oracle
        );
        for r in t.harmonics.iter().filter(|r| r.m >= 3) {
            assert!(
                r.in_path_bank && r.decoupled_mrad < 2.0 * p.m3_mrad,
                "{what}: {r:?}"
            );
        }
    }
    m1_mrad
}

#[test]
fn ripple_1rev_motion_is_not_learned_as_sensor_error() {
    ripple_scenario_reports_motion_and_spectra("ripple-1rev");
}

#[test]
fn ripple_5rev_motion_is_not_learned_as_sensor_error() {
    ripple_scenario_reports_motion_and_spectra("ripple-5rev");
}

/// The control: ripple-5rev commissioned at 20 rev/s alone (refined all the same) keeps
/// the rotor's motion there in its correction (published: 2.52 mrad at m = 1); the
/// second speed is what removes it.
#[test]
fn the_second_speed_separates_the_motion() {
    let two = ripple_scenario_reports_motion_and_spectra("ripple-5rev");
    let mut sc = Scenario::load("ripple-5rev").unwrap();
    let c = sc.file.commissioning.as_mut().unwrap();
    c.second_speed_ratio = Some(0.0);
    let (first, _) = hil_sim::power_up::run(&sc, sc.file.ci_duration_s.unwrap()).unwrap();
    let t = first.truth_spectrum.expect("window all in Run");
    let one = t.row(1).unwrap();
    print!("one speed:\n{}", t.text("  "));
    assert!(
        one.decoupled_mrad > 1.26 && one.decoupled_mrad > 50.0 * two[0],
        "m = 1: {} mrad at one speed, {:?} at two",
        one.decoupled_mrad,
        two
    );
}

/// Learning the torque ripple in Run (`learn_torque_ripple`): the observer is fed the
/// ripple the rotor's motion comes from, and θ̂ follows the rotor at m = 1, 2 instead of
/// lagging it by millimradians; the speed loop, now seeing the ripple, rejects more of
/// it (published: 3.09-3.11 mrad pk-pk at 1x, against 8.74-8.85 without). The sensor
/// correction is not touched.
#[test]
fn a_learned_torque_ripple_puts_theta_hat_on_the_rotor() {
    for name in ["ripple-1rev", "ripple-5rev"] {
        let p = published(name);
        let mut sc = Scenario::load(name).unwrap();
        sc.file.commissioning.as_mut().unwrap().learn_torque_ripple = Some(true);
        for (what, t) in ripple_power_ups(&sc, name) {
            for m in [1, 2] {
                let r = t.row(m).unwrap();
                assert!(
                    r.estimate_mrad < 2.0 * p.learned_theta_mrad,
                    "{what}: θ̂ {r:?}"
                );
            }
            assert!(
                t.motion_1x_pk_pk_mrad < 5.0,
                "{what}: {}",
                t.motion_1x_pk_pk_mrad
            );
            let m12 = t.decoupled_over_oracle_m1_m2;
            assert!(
                m12 < 2.0 * p.learned_m12_oracle,
                "{what}: arg Zd at m = 1, 2 {m12}x the oracle"
            );
        }
    }
}

/// One run's arg Zd over the oracle is a draw of the noise (the oracle's harmonics are
/// noise, a few µrad): the figure is the median over power-ups at several noise seeds.
/// At CI length, 9 seeds, published: arg Zd at m = 1, 2 over the noise floor a median
/// of 1.20-1.21x, at m = 3..16 over the oracle 1.21-1.35x; the bound is the target,
/// 1.5x.
#[test]
fn ripple_scenarios_reach_the_oracle_over_noise_seeds() {
    for name in ["ripple-1rev", "ripple-5rev"] {
        let sc = Scenario::load(name).unwrap();
        let s = hil_sim::power_up::SeedSpread::run(&sc, sc.file.ci_duration_s.unwrap(), 9).unwrap();
        let (floor, m3) = (s.m1_m2_floor(), s.m3_up());
        assert_eq!((floor.count, m3.count), (18, 18), "{name}");
        assert!(floor.median <= 1.5, "{name}: m = 1, 2 {floor:?}");
        assert!(m3.median <= 1.5, "{name}: m = 3..16 {m3:?}");
    }
}

/// A shipped scenario is found by name from any directory (compiled in), and its
/// outputs go under the checkout the command runs in, found from the current
/// directory: never under the source tree the binary was built from.
#[test]
fn outputs_go_under_the_checkout_the_command_runs_in() {
    let dir = tempfile::tempdir().unwrap();
    let ws = dir.path();
    std::fs::write(ws.join("Cargo.toml"), "[workspace]\nmembers = []\n").unwrap();
    let below = ws.join("some").join("dir");
    std::fs::create_dir_all(&below).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["scenario", "paper-fig10", "--ci", "--no-plots"])
        .current_dir(&below)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let run = ws.join("target/hil-sim/paper-fig10");
    for f in ["summary.txt", "ours/summary.json", "paper/timeseries.csv"] {
        assert!(run.join(f).is_file(), "no {f} under {}", run.display());
    }
    assert!(!below.join("target").exists());
}

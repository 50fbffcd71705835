//! The README's main command works and says what a drive engineer needs; bad
//! arguments get a clear message and a non-zero exit.

use std::process::Command;

fn hil_sim(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(args)
        .output()
        .expect("hil-sim runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The first number after `label` on the line that contains it.
fn number_after(text: &str, label: &str) -> f64 {
    let line = text
        .lines()
        .find(|l| l.contains(label))
        .unwrap_or_else(|| panic!("no `{label}` in\n{text}"));
    let rest = &line[line.find(label).unwrap() + label.len()..];
    rest.split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
        .find(|s| !s.is_empty())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no number after `{label}` in `{line}`"))
}

#[test]
fn default_run_is_the_power_up_commissioning() {
    let (ok, out, err) = hil_sim(&[]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("scenario commissioning"), "{out}");
    assert!(out.contains("calibration commissioned and stored"), "{out}");
    assert!(out.contains("calibration loaded from flash"), "{out}");
    assert!(out.contains("output: "), "{out}");
}

#[test]
fn fig9_scenario_writes_its_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("fig9");
    let (ok, out, err) = hil_sim(&[
        "scenario",
        "paper-fig9",
        "--ci",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("scenario paper-fig9"), "{out}");
    assert!(
        out.contains(&format!("output: {}", out_dir.display())),
        "{out}"
    );
    for run in ["paper", "ours"] {
        for f in [
            "timeseries.csv",
            "summary.json",
            "sensor_image.png",
            "spectrum.svg",
        ] {
            assert!(out_dir.join(run).join(f).is_file(), "{run}/{f} missing");
        }
    }
}

#[test]
fn kinematic_commission_self_commissions_the_extreme_sensor() {
    let (ok, out, err) = hil_sim(&["commission"]);
    assert!(ok, "{out}\n{err}");
    let raw = number_after(&out, "spatial error, raw sensor :");
    let corrected = number_after(&out, "spatial error, corrected  :");
    assert!(raw > 150.0, "raw {raw} mrad");
    assert!(
        raw / corrected > 100.0,
        "raw {raw} vs corrected {corrected} mrad"
    );
    assert_eq!(number_after(&out, "faults:"), 0.0);
    assert!(out.contains("converged flag: rev"), "{out}");
}

#[test]
fn reverse_paper_law_runs_and_reports_slower_convergence() {
    let (ok, out, err) = hil_sim(&[
        "commission",
        "--speed-rev-s",
        "-20",
        "--law",
        "paper",
        "--revs",
        "12",
    ]);
    assert!(ok, "{out}\n{err}");
    let ten_x = number_after(&out, "10x reduction:");
    assert!(
        ten_x >= 8.0,
        "paper law reached 10x after {ten_x} revolutions\n{out}"
    );
}

#[test]
fn bad_arguments_are_refused_with_a_reason() {
    let (ok, _, err) = hil_sim(&["commission", "--speed-rev-s", "0"]);
    assert!(!ok);
    assert!(err.contains("--speed-rev-s 0 out of range"), "{err}");
    let (ok, _, err) = hil_sim(&["commission", "--noise-std", "-1"]);
    assert!(!ok);
    assert!(err.contains("--noise-std"), "{err}");
    let (ok, _, err) = hil_sim(&["commission", "--revs", "x"]);
    assert!(!ok);
    assert!(err.contains("--revs"), "{err}");
}

#[test]
fn bench_reports_real_time_factor() {
    let (ok, out, err) = hil_sim(&["bench", "--seconds", "0.2", "--repeats", "1"]);
    assert!(ok, "{out}\n{err}");
    assert!(number_after(&out, "best  :") > 0.0, "{out}");
    assert!(out.contains("x real time"), "{out}");
}

//! `hil-sim replay`: the published recorded-data interface. The replayed estimate is the
//! live one bit for bit, the report scores it, and bad input stops with file, line and
//! field named and without touching the output.

mod common;

use common::{hil_sim, report, Files, ADC, IDENTITY_CONFIG, SAMPLE_PERIOD_S};
use hil_sim::core_config::CoreConfigFile;
use mras::{Config, Tracker};
use mras_sim::{Kinematic, SensorHarmonic, SensorModel, Trajectory};
use std::fmt::Write as _;

const INERTIA_KG_M2: f64 = 1.0e-4;

/// One simulated control period: what the core was fed and what it answered.
struct Row {
    t_s: f64,
    x: f32,
    y: f32,
    torque_nm: f32,
    theta_rad: f64,
    theta_hat_rad: f64,
}

/// The extreme sensor through a 12-bit ADC on a ramp to 20 rev/s with the torque
/// feedforward, with a live tracker on `cfg`.
fn simulate(cfg: Config, duration_s: f64) -> Vec<Row> {
    let kin = Kinematic {
        sensor: SensorModel::extreme(),
        trajectory: Trajectory::Ramp {
            omega_rad_s: 20.0 * std::f64::consts::TAU,
            accel_rad_s2: 2000.0,
        },
        sample_period_s: SAMPLE_PERIOD_S,
        inertia_kg_m2: INERTIA_KG_M2,
        adc: Some(ADC),
    };
    let mut tracker = Tracker::new(cfg).expect("valid config");
    let mut rows = Vec::new();
    let steps = (duration_s / SAMPLE_PERIOD_S) as u64;
    kin.run(
        &mut tracker,
        0,
        steps,
        || (0.0, 0.0),
        |t, r| {
            let est = r.result.unwrap_or_else(|_| t.last_estimate());
            rows.push(Row {
                t_s: r.t_s,
                x: r.x,
                y: r.y,
                torque_nm: r.torque_nm,
                theta_rad: r.theta_rad,
                theta_hat_rad: est.theta_unwrapped_rad(),
            });
        },
    );
    rows
}

#[test]
fn replay_reproduces_the_live_estimate_bit_exactly() {
    let cfg = CoreConfigFile::parse(IDENTITY_CONFIG, "identity")
        .unwrap()
        .to_config(SAMPLE_PERIOD_S as f32)
        .unwrap();
    let rows = simulate(cfg, 0.6);

    // Columns in a shuffled order with an ignored extra column. f32 and f64 `Display`
    // print the shortest string that parses back to the same value, so replay sees
    // exactly the samples the live tracker saw.
    let mut text = String::from("theta_rad,t_s,note,y,x,torque_nm\n");
    for r in &rows {
        writeln!(
            text,
            "{},{},sim,{},{},{}",
            r.theta_rad, r.t_s, r.y, r.x, r.torque_nm
        )
        .unwrap();
    }
    // The live tracker ran the core's fixed bank: so does replay (`--bank default`;
    // without it the bank would come from the data).
    let files = Files::new(&text, Some(IDENTITY_CONFIG));
    let stdout = files.run(&["--bank", "default"]);
    assert!(stdout.contains("corrected"), "{stdout}");

    let rep = report(&files.report);
    // t_s = k·T exactly; replay's (t_last - t_first)/(n - 1) in f64 is within an ulp or
    // two of T, which rounds to the same f32: the same control period as the live core.
    assert_eq!(
        rep["sample_period_s"].as_f64().unwrap() as f32,
        cfg.sample_period_s
    );
    assert_eq!(rep["rows"], rows.len());
    assert_eq!(rep["input_scaling"]["source"], "config");
    // A 20 rev/s recording at 20 kHz keeps the default observer the live tracker ran,
    // which the bit-exact comparison below confirms.
    assert_eq!(rep["observer"]["source"], "default");
    assert_eq!(rep["faults_total"], 0);

    let mut rdr = csv::Reader::from_path(&files.output).unwrap();
    let header: Vec<String> = rdr.headers().unwrap().iter().map(String::from).collect();
    assert_eq!(
        header,
        [
            "t_s",
            "theta_hat_rad",
            "omega_hat_rad_s",
            "offset_re",
            "offset_im",
            "amplitude_quadrature_re",
            "amplitude_quadrature_im",
            "h4_re",
            "h4_im",
            "h5_re",
            "h5_im",
            "h6_re",
            "h6_im",
            "h7_re",
            "h7_im",
            "h8_re",
            "h8_im"
        ]
    );
    let mut n = 0;
    for (k, rec) in rdr.records().enumerate() {
        let rec = rec.unwrap();
        let t: f64 = rec[0].parse().unwrap();
        let theta_hat: f64 = rec[1].parse().unwrap();
        assert_eq!(t, rows[k].t_s, "row {k}");
        // Same core code on the same f32 inputs and period: no tolerance needed (Rust
        // does not reassociate or contract float arithmetic, and libm is pure Rust).
        assert_eq!(
            theta_hat.to_bits(),
            rows[k].theta_hat_rad.to_bits(),
            "row {k}: replay {theta_hat} vs live {}",
            rows[k].theta_hat_rad
        );
        n += 1;
    }
    assert_eq!(n, rows.len());

    let e = &rep["spatial_error"];
    let raw = e["raw"]["pk_pk_mrad"].as_f64().unwrap();
    let corrected = e["corrected"]["pk_pk_mrad"].as_f64().unwrap();
    assert!(raw > 150.0, "raw {raw} mrad");
    assert!(
        raw / corrected > 200.0,
        "raw {raw} vs corrected {corrected} mrad"
    );
    assert!(e["method"].as_str().unwrap().contains("second half"));
    assert_eq!(e["filled_bins"], 360);
}

#[test]
fn default_config_commissions_a_recording_in_adc_counts() {
    let rows = simulate(Config::default(), 0.8);
    let lsb = 2.0 * ADC.full_scale / 4096.0;
    let counts = |v: f32| (v as f64 / lsb).round() + 2048.0;
    let mut text = String::from("t_s,x,y,torque_nm,theta_rad\n");
    for r in &rows {
        writeln!(
            text,
            "{},{},{},{},{}",
            r.t_s,
            counts(r.x),
            counts(r.y),
            r.torque_nm,
            r.theta_rad
        )
        .unwrap();
    }
    // The fixed bank, asked for (without it the bank comes from the data: below).
    let files = Files::new(&text, None);
    let stdout = files.run(&["--bank", "default"]);
    let rep = report(&files.report);
    assert_eq!(rep["input_scaling"]["source"], "estimated from min/max");
    assert_eq!(rep["sensor_periods"], 2);
    assert_eq!(rep["sensor_periods_source"]["source"], "from theta_rad");
    let obs = &rep["observer"];
    assert_eq!(obs["source"], "default", "{stdout}");
    assert_eq!(obs["eigenvalues_hz"], serde_json::json!([100.0, 10.0, 1.0]));
    assert_eq!(obs["sample_rate_hz"].as_f64().unwrap().round(), 20_000.0);
    // Median over time: the ramp to 20 rev/s takes 63 ms of the 0.8 s.
    let speed_rev_s = obs["speed_rev_s"].as_f64().unwrap();
    assert!((speed_rev_s - 20.0).abs() < 0.01, "{speed_rev_s} rev/s");
    assert!(
        stdout.contains("observer eigenvalues [100.0, 10.0, 1.0] Hz (default)"),
        "{stdout}"
    );
    let coefs = rep["final_coefficients"].as_array().unwrap();
    // The default bank: the extreme sensor's h = 2..5 load the first four paths; it has
    // no error at m = 5..7, so h6..h8 stay near zero.
    assert_eq!(coefs.len(), 7);
    for (i, c) in coefs.iter().enumerate() {
        let mag = c["re"].as_f64().unwrap().hypot(c["im"].as_f64().unwrap());
        if i < 4 {
            assert!(mag > 1e-3, "{c}");
        } else {
            assert!(mag < 1e-3, "{c}");
        }
    }
    let e = &rep["spatial_error"];
    let reduction = e["reduction"].as_f64().unwrap();
    // Measured: converged, 5 184x (one common estimated gain keeps the sensor's equal
    // x/y harmonics equal; see `estimate_scaling`).
    assert_eq!(rep["convergence"]["converged"], true, "{stdout}");
    assert!(reduction >= 1000.0, "{stdout}");

    // No flags: the bank from the data. The recording ends before the survey's second
    // round: its first round's bank (offset, C/D, h4, h5) gave 3 525x alone; with the
    // fixed bank's paths joined (the same seven) 5 184x, as the fixed bank.
    let files = Files::new(&text, None);
    let stdout = files.run(&[]);
    let rep = report(&files.report);
    assert_eq!(rep["bank"]["source"], "data", "{stdout}");
    assert!(rep["motion"]["warning"].is_null(), "{stdout}");
    let from_data = rep["spatial_error"]["reduction"].as_f64().unwrap();
    eprintln!("{stdout}");
    eprintln!("reduction: default bank {reduction:.0}x, from the data {from_data:.0}x");
    assert!(from_data >= 1000.0, "{stdout}");
}

#[test]
fn without_reference_angle_the_report_says_why() {
    let mut text = String::from("t_s,x,y\n");
    for k in 0..2000 {
        let th = 2.0e-3 * k as f64; // rad electrical: 20 rad/s at 10 kHz, ideal sensor
        writeln!(text, "{},{},{}", k as f64 * 1e-4, th.cos(), th.sin()).unwrap();
    }
    let files = Files::new(&text, None);
    let stdout = files.run(&[]);
    assert!(stdout.contains("no theta_rad column"), "{stdout}");
    let rep = report(&files.report);
    assert!(rep["spatial_error"].is_null());
    assert!(rep["spatial_error_note"]
        .as_str()
        .unwrap()
        .contains("theta_rad"));
    let n = csv::Reader::from_path(&files.output)
        .unwrap()
        .records()
        .count();
    assert_eq!(n, 2000);
}

/// A clean recording: one revolution of an ideal sensor at 20 kHz.
fn good_csv(rows: usize) -> String {
    let mut s = String::from("t_s,x,y\n");
    for k in 0..rows {
        let th = std::f64::consts::TAU * k as f64 / rows as f64;
        writeln!(
            s,
            "{},{},{}",
            k as f64 * SAMPLE_PERIOD_S,
            th.cos(),
            th.sin()
        )
        .unwrap();
    }
    s
}

/// `text` with its 1-based line `line` replaced.
fn with_line(text: &str, line: usize, new: &str) -> String {
    let mut lines: Vec<&str> = text.lines().collect();
    lines[line - 1] = new;
    lines.join("\n") + "\n"
}

/// Run replay on `input_text` (and `config_text`) twice, without and with a pre-existing
/// OUT.csv: it must fail with every `expected` fragment in its message, create nothing
/// and leave the existing output untouched.
fn assert_refused(input_text: &str, config_text: Option<&str>, expected: &[&str]) {
    assert_refused_with(input_text, config_text, &[], expected);
}

/// [`assert_refused`] with `flags` added to the command.
fn assert_refused_with(
    input_text: &str,
    config_text: Option<&str>,
    flags: &[&str],
    expected: &[&str],
) {
    for pre_existing in [false, true] {
        let files = Files::new(input_text, config_text);
        let (dir, output) = (files.input.parent().unwrap(), &files.output);
        let args = files.args(flags);
        if pre_existing {
            std::fs::write(output, "precious\n").unwrap();
        }
        let out = hil_sim(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "accepted; stderr: {stderr}");
        for e in expected {
            assert!(stderr.contains(e), "`{e}` not in: {stderr}");
        }
        let mut left: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut want = vec!["IN.csv".to_string()];
        if config_text.is_some() {
            want.insert(0, "CFG.toml".into());
        }
        if pre_existing {
            want.push("OUT.csv".into());
            assert_eq!(std::fs::read_to_string(output).unwrap(), "precious\n");
        }
        assert_eq!(left, want, "files left behind; stderr: {stderr}");
    }
}

#[test]
fn missing_column_is_named() {
    assert_refused(
        "t_s,x\n0,1\n0.00005,1\n",
        None,
        &["IN.csv:1:", "column `y`"],
    );
}

#[test]
fn non_numeric_field_is_named_with_its_line() {
    let text = with_line(&good_csv(400), 4, "0.00015,abc,0.1");
    assert_refused(&text, None, &["IN.csv:4: field `x`: not a number: \"abc\""]);
}

#[test]
fn non_increasing_time_is_named_with_its_line() {
    let text = with_line(&good_csv(400), 5, "0.0001,0.99,0.1");
    assert_refused(&text, None, &["IN.csv:5: field `t_s`: not increasing"]);
}

#[test]
fn irregular_period_is_refused() {
    let text = with_line(&good_csv(400), 5, "0.000162,0.99,0.1");
    assert_refused(
        &text,
        None,
        &["IN.csv:5: field `t_s`", "fixed control period"],
    );
}

#[test]
fn nan_field_is_named_with_its_line() {
    let text = with_line(&good_csv(400), 3, "0.00005,0.99,NaN");
    assert_refused(&text, None, &["IN.csv:3: field `y`: not finite"]);
}

#[test]
fn empty_file_is_refused() {
    assert_refused("", None, &["IN.csv:1: empty file"]);
}

#[test]
fn unknown_config_field_is_named_with_its_line() {
    assert_refused(
        &good_csv(400),
        Some("sensor_periods = 2\n[gates]\nmin_spead_rad_s = 1.0\n"),
        &["CFG.toml:3:", "`gates.min_spead_rad_s`", "unknown field"],
    );
}

/// `revs` revolutions of the extreme sensor on an N = 1 encoder at a constant
/// `speed_rev_s` from the first row (mid-flight, at an arbitrary angle), sampled at
/// `rate_hz` by the 12-bit converter and written in its counts, as a bench records them.
fn encoder_recording(rate_hz: f64, speed_rev_s: f64, revs: f64) -> String {
    let mut sensor = SensorModel::extreme();
    sensor.sensor_periods = 1;
    sensor_recording(&sensor, rate_hz, speed_rev_s, revs)
}

/// `sensor` through the 12-bit converter at constant speed, in counts.
fn sensor_recording(sensor: &SensorModel, rate_hz: f64, speed_rev_s: f64, revs: f64) -> String {
    let lsb = 2.0 * ADC.full_scale / 4096.0;
    let counts = |v: f64| (ADC.quantise(v) / lsb).round() + 2048.0;
    let rows = (revs / speed_rev_s.abs() * rate_hz).round() as usize;
    let mut text = String::from("t_s,x,y,theta_rad\n");
    for k in 0..rows {
        let t = k as f64 / rate_hz;
        let th = 0.7 + std::f64::consts::TAU * speed_rev_s * t;
        let (x, y) = sensor.vector(th);
        writeln!(text, "{t},{},{},{th}", counts(x), counts(y)).unwrap();
    }
    text
}

/// Replay `text` with N = 1 and, when given, `config`; the report and stdout.
fn replay_encoder(text: &str, config: Option<&str>) -> (serde_json::Value, String) {
    replay_encoder_with(text, config, &[])
}

fn replay_encoder_with(
    text: &str,
    config: Option<&str>,
    flags: &[&str],
) -> (serde_json::Value, String) {
    let files = Files::new(text, config);
    let stdout = files.run(&[&["--sensor-periods", "1"], flags].concat());
    (report(&files.report), stdout)
}

fn eigenvalues_hz(rep: &serde_json::Value) -> Vec<f64> {
    rep["observer"]["eigenvalues_hz"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

fn reduction(rep: &serde_json::Value) -> f64 {
    rep["spatial_error"]["reduction"].as_f64().unwrap()
}

#[test]
fn a_1_khz_recording_without_config_gets_eigenvalues_chosen_from_it() {
    let (rep, stdout) = replay_encoder(&encoder_recording(1000.0, 1.0, 40.0), None);
    eprintln!("{stdout}");
    let obs = &rep["observer"];
    assert_eq!(obs["source"], "chosen from the recording", "{stdout}");
    assert!(stdout.contains("chosen from the recording"), "{stdout}");
    let speed_rev_s = obs["speed_rev_s"].as_f64().unwrap();
    assert!((speed_rev_s - 1.0).abs() < 0.01, "{speed_rev_s} rev/s");
    let f_e_hz = obs["lowest_error_harmonic_hz"].as_f64().unwrap();
    assert!(
        (f_e_hz - speed_rev_s).abs() < 1e-9,
        "m = 1, N = 1: {f_e_hz}"
    );
    // The default scaled to put its middle eigenvalue on the lowest error harmonic (the
    // sample rate alone would allow 15.9 Hz for the fastest), the 10:1 spacing kept.
    assert_eq!(eigenvalues_hz(&rep), [10.0, 1.0, 0.1], "{stdout}");
    let ev = eigenvalues_hz(&rep);
    let period_s = rep["sample_period_s"].as_f64().unwrap();
    assert!(std::f64::consts::TAU * ev[0] * period_s <= 0.1, "{ev:?}");

    assert_eq!(rep["faults_total"], 0, "{stdout}");
    assert_eq!(rep["convergence"]["converged"], true, "{stdout}");
    let e = &rep["spatial_error"];
    assert!(e["raw"]["pk_pk_mrad"].as_f64().unwrap() > 300.0, "{e}");
    // Measured: 328 → 0.24 mrad pk-pk, 1 374x, the bank from the data (the survey's
    // offset, C/D, h4, h5 alone: 1 179x; with the fixed bank's h6..h8 joined, the fixed
    // bank's seven, as the fixed bank). The default eigenvalues are refused at 1 kHz.
    assert!(reduction(&rep) > 500.0, "{stdout}");
}

#[test]
fn a_slow_shaft_at_10_khz_gets_a_slower_observer_than_the_default() {
    // 2 rev/s on N = 1: the error harmonics from 2 Hz up. The default is valid at 10 kHz
    // but its middle eigenvalue (10 Hz) is above them: |H(2 Hz)| = 0.0035, below the
    // gate min_h, so with it the MRAS would not see the lowest one at all.
    let text = encoder_recording(10_000.0, 2.0, 20.0);
    let (chosen, stdout) = replay_encoder(&text, None);
    eprintln!("{stdout}");
    assert_eq!(chosen["observer"]["source"], "chosen from the recording");
    let ev = eigenvalues_hz(&chosen);
    assert!(ev[1] <= 2.0 && ev[1] >= 1.8, "{ev:?}");
    let (default, stdout_d) = replay_encoder(
        &text,
        Some("[observer]\neigenvalues_hz = [100.0, 10.0, 1.0]\n"),
    );
    eprintln!("{stdout_d}");
    assert_eq!(default["observer"]["source"], "config");
    // Measured: 2 317x with the chosen set, 4x with the default (its offset path never
    // adapts: |H| below min_h; the survey does not complete with it either, and the
    // fixed bank runs, said so in the summary).
    assert!(reduction(&chosen) > 1000.0, "{stdout}");
    assert!(reduction(&default) < 10.0, "{stdout_d}");
    // And it says so: the offset path never saw its error, so nothing converged.
    let conv = &default["convergence"];
    assert_eq!(conv["converged"], false, "{stdout_d}");
    let unseen = conv["unseen_paths"].as_array().unwrap();
    assert!(unseen.iter().any(|p| p == "offset"), "{conv}");
    assert_eq!(chosen["convergence"]["unseen_paths"], serde_json::json!([]));
}

#[test]
fn eigenvalues_a_config_sets_are_used_as_given() {
    let text = encoder_recording(1000.0, 1.0, 10.0);
    let (rep, stdout) = replay_encoder(
        &text,
        Some("[observer]\neigenvalues_hz = [20.0, 2.0, 0.2]\n"),
    );
    assert_eq!(rep["observer"]["source"], "config", "{stdout}");
    assert_eq!(eigenvalues_hz(&rep), [20.0, 2.0, 0.2]);
    // A set the file gives is not second-guessed: too fast for 1 kHz, it is refused as
    // before, naming the key.
    let text = encoder_recording(1000.0, 1.0, 2.0);
    assert_refused(
        &text,
        Some("[observer]\neigenvalues_hz = [100.0, 10.0, 1.0]\n"),
        &[
            "CFG.toml:2:",
            "`observer.eigenvalues_hz`",
            "too close to the sample rate",
        ],
    );
}

#[test]
fn a_shaft_too_slow_to_adapt_at_1_khz_is_refused() {
    // 0.1 rev/s = 0.63 rad/s, below the core's adaptation gate (1 rad/s): no observer
    // makes the MRAS adapt, and the default is too fast for 1 kHz.
    assert_refused(
        &encoder_recording(1000.0, 0.1, 1.0),
        None,
        &[
            "IN.csv: the default observer eigenvalues",
            "too slow for the MRAS to adapt with any observer (gates.min_speed_rad_s = 1 rad/s)",
            "set [observer] eigenvalues_hz in a --config file",
        ],
    );
}

/// An N = 1 sensor with error harmonics beyond the default bank's m = 1..7: the extreme
/// sensor plus h = 10 and 13 (m = 9 and 12) at 1 % and 0.6 %.
fn sensor_beyond_the_default_bank() -> SensorModel {
    let mut sensor = SensorModel::extreme();
    sensor.sensor_periods = 1;
    sensor
        .with_harmonic(SensorHarmonic::equal(10, 0.010, 0.4))
        .with_harmonic(SensorHarmonic::equal(13, 0.006, -1.1))
}

#[test]
fn paths_from_the_data_cover_harmonics_the_default_bank_lacks() {
    // Long enough for the survey's rounds: the large m = 3, 4 first, then m = 12.
    let text = sensor_recording(&sensor_beyond_the_default_bank(), 20_000.0, 10.0, 60.0);
    // (`--paths-from-data` is what no flag does, `--bank data`; still accepted.)
    let (fixed, _) = replay_encoder_with(&text, None, &["--bank", "default"]);
    let (chosen, stdout) = replay_encoder_with(&text, None, &["--paths-from-data"]);
    eprintln!("{stdout}");
    assert!(fixed.get("survey").is_none());
    let survey = &chosen["survey"];
    let paths: Vec<&str> = survey["paths"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap())
        .collect();
    // The survey's bank, and the fixed bank's paths it left out (h6..h8 here) joined.
    let ran = chosen["paths"].as_array().unwrap();
    assert!(paths.iter().all(|p| ran.iter().any(|r| r == p)), "{ran:?}");
    assert!(ran.iter().any(|r| r == "h8"), "{ran:?}");
    assert!(
        paths.contains(&"h10") && paths.contains(&"h13"),
        "{paths:?}"
    );
    let error_mrad: Vec<f64> = survey["error_mrad"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // Equal x/y harmonics of amplitude b: an angle error of about b rad at m = h - 1
    // (to first order: the extreme sensor's large h = 2..5 modulate it by several %).
    for (m, want) in [(9, 10.0), (12, 6.0)] {
        let got = error_mrad[m - 1];
        assert!((got - want).abs() < 0.15 * want, "m = {m}: {got} mrad");
    }
    assert!(stdout.contains("paths chosen from the data"), "{stdout}");
    assert_eq!(survey["complete"], true, "{stdout}");
    assert!(survey["rounds"].as_u64().unwrap() >= 2, "{stdout}");
    let (r_fixed, r_chosen) = (reduction(&fixed), reduction(&chosen));
    eprintln!("reduction: default bank {r_fixed:.1}x, bank from the data {r_chosen:.1}x");
    assert!(r_chosen > 5.0 * r_fixed, "{r_chosen} against {r_fixed}");
}

#[test]
fn paths_from_the_data_and_paths_in_the_config_are_refused_together() {
    let text = sensor_recording(&sensor_beyond_the_default_bank(), 20_000.0, 10.0, 2.0);
    assert_refused_with(
        &text,
        Some("paths = [\"offset\"]\n"),
        &["--paths-from-data"],
        &["--paths-from-data and `paths`"],
    );
}

/// Amplitude (rad) of the shaft's own once- and twice-per-revolution motion in
/// [`rig_recording`]: 5 mrad each, 10 mrad pk-pk at each harmonic, the size of a rig's
/// speed ripple (ripple-1rev's rotor moves 8-13 mrad pk-pk at 1x and 2x).
const RIG_MOTION_RAD: [f64; 2] = [5.0e-3, 5.0e-3];

/// An on-axis Hall-array encoder (N = 1, analog sin/cos) as a user's bench records it:
/// offsets, amplitude imbalance and quadrature (m = 1, 2) and harmonics m = 3..12 falling
/// from 3 mrad (ripple-1rev's sensor, h = 14, 15 left out), through a 12-bit converter
/// with σ = 3·10⁻⁴ of noise, at 1 kHz and 1 rev/s, and a shaft whose angle (the
/// reference `theta_rad` follows it) carries [`RIG_MOTION_RAD`] at m = 1, 2.
fn rig_recording(revs: f64) -> String {
    rig_recording_with(revs, 1.0, 3.0e-4)
}

fn rig_recording_with(revs: f64, motion_scale: f64, sigma: f64) -> String {
    use rand::SeedableRng;
    use rand_distr::Distribution;
    let deg = std::f64::consts::PI / 180.0;
    let mut sensor = SensorModel::ideal(1);
    (sensor.ax, sensor.ay, sensor.bx1, sensor.phi_x1_rad) = (0.004, -0.003, 1.008, 0.15 * deg);
    for (h, b, phi_deg) in [
        (-2, 0.0030, 40.0),
        (5, 0.0025, -70.0),
        (6, 0.0020, 110.0),
        (-5, 0.0016, 15.0),
        (8, 0.0013, -150.0),
        (9, 0.0011, 60.0),
        (10, 0.0009, -20.0),
        (11, 0.0008, 170.0),
        (12, 0.0006, -100.0),
        (13, 0.0005, 80.0),
    ] {
        sensor.push_harmonic(SensorHarmonic::equal(h, b, phi_deg * deg));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let noise = rand_distr::Normal::new(0.0, sigma).unwrap();
    let (rate_hz, speed_rev_s) = (1000.0, 1.0);
    let lsb = 2.0 * ADC.full_scale / 4096.0;
    let counts = |v: f64| (ADC.quantise(v) / lsb).round() + 2048.0;
    let rows = (revs / speed_rev_s * rate_hz).round() as usize;
    let mut text = String::from("t_s,x,y,theta_rad\n");
    for k in 0..rows {
        let t = k as f64 / rate_hz;
        let smooth = 0.7 + std::f64::consts::TAU * speed_rev_s * t;
        let th = smooth
            + motion_scale * RIG_MOTION_RAD[0] * (smooth + 0.3).sin()
            + motion_scale * RIG_MOTION_RAD[1] * (2.0 * smooth - 1.1).sin();
        let (x, y) = sensor.vector(th);
        let (x, y) = (x + noise.sample(&mut rng), y + noise.sample(&mut rng));
        writeln!(text, "{t},{},{},{th}", counts(x), counts(y)).unwrap();
    }
    text
}

fn band_rms(rep: &serde_json::Value, which: &str, ms: std::ops::RangeInclusive<usize>) -> f64 {
    let h = rep["spatial_error"][which]["harmonics_mrad"]
        .as_array()
        .unwrap();
    ms.map(|m| 0.5 * h[m - 1].as_f64().unwrap().powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Replay `text` with no flags but the files; its report and stdout.
fn replay_plain(text: &str) -> (serde_json::Value, String) {
    let files = Files::new(text, None);
    let stdout = files.run(&[]);
    (report(&files.report), stdout)
}

#[test]
fn a_rig_recording_with_motion_at_once_and_twice_per_revolution_replays_without_flags() {
    // Measured (40 revolutions, second half scored), RMS raw → corrected:
    // * no flags: N = 1 from theta_rad; m = 1, 2 flagged as motion, left out of the bank
    //   and corrected by the ellipse fit: m = 1, 2 4.48 → 0.42 mrad (what is left is the
    //   observer's lag on the motion), m = 3..12 3.64 → 0.024 mrad (152x);
    // * the bank from the data with m = 1, 2 fitted to the motion (`paths` offset, C/D,
    //   h4..h13): m = 1, 2 4.48 → 5.00 mrad (the motion, worse than raw), m = 3..12
    //   0.032 mrad (115x);
    // * `--bank default`: m = 1, 2 flagged as above, 0.42 mrad; m = 3..12 1.30 mrad (h4..h8
    //   reach m = 3..7 only); the fixed bank with offset and C/D (`paths`): m = 1, 2 5.00
    //   mrad, m = 3..12 1.09 mrad (3.3x).
    // Without the motion, the same sensor: m = 3..12 0.003 mrad, m = 1, 2 0.002 mrad.
    let text = rig_recording(40.0);
    let (rep, stdout) = replay_plain(&text);
    eprintln!("{stdout}");
    assert_eq!(rep["sensor_periods"], 1, "{stdout}");
    assert_eq!(rep["sensor_periods_source"]["source"], "from theta_rad");
    assert_eq!(rep["bank"]["source"], "data", "{stdout}");
    let [raw12, cor12, raw3, cor3] = motion_and_sensor_bands(&rep);
    eprintln!("m = 1, 2: {raw12:.3} -> {cor12:.3} mrad; m = 3..12: {raw3:.3} -> {cor3:.4} mrad");
    assert!(raw3 / cor3 >= 30.0, "m = 3..12: {raw3} -> {cor3} mrad");
    assert!(cor12 <= raw12, "m = 1, 2: {raw12} -> {cor12} mrad");
    // The warning, in the report and the summary, naming both harmonics.
    let motion = &rep["motion"];
    let warning = motion["warning"].as_str().expect("motion warning");
    assert!(
        warning.contains("m = 1") && warning.contains("m = 2"),
        "{warning}"
    );
    assert!(stdout.contains("WARNING: the shaft moves"), "{stdout}");
    for h in motion["harmonics"].as_array().unwrap() {
        assert_eq!(h["flagged"], true, "{h}");
        let mrad = h["motion_mrad"].as_f64().unwrap();
        assert!((mrad - 5.0).abs() < 0.1, "{h}");
    }
    let paths = rep["paths"].as_array().unwrap();
    assert!(
        !paths
            .iter()
            .any(|p| p == "offset" || p == "amplitude-quadrature"),
        "{paths:?}"
    );
    assert_eq!(rep["input_scaling"]["source"], "ellipse fit");

    // The fixed bank on request: m = 1, 2 still left out (fitted to the motion
    // otherwise), the higher harmonics only as far as h4..h8 reach.
    let files = Files::new(&text, None);
    let stdout = files.run(&["--bank", "default"]);
    let fixed = report(&files.report);
    assert_eq!(fixed["bank"]["source"], "default", "{stdout}");
    assert!(fixed.get("survey").is_none());
    assert!(
        band_rms(&fixed, "corrected", 3..=12) > 5.0 * cor3,
        "{stdout}"
    );
}

/// RMS (mrad) of the raw and the corrected angle at m = 1, 2 (where the rig's motion
/// is) and at m = 3..12 (the sensor's error).
fn motion_and_sensor_bands(rep: &serde_json::Value) -> [f64; 4] {
    [
        band_rms(rep, "raw", 1..=2),
        band_rms(rep, "corrected", 1..=2),
        band_rms(rep, "raw", 3..=12),
        band_rms(rep, "corrected", 3..=12),
    ]
}

#[test]
fn without_motion_the_rig_sensor_keeps_its_m_1_2_paths() {
    // The same sensor on a shaft turning evenly: nothing flagged, the bank from the data
    // with offset and C/D. Measured: m = 1, 2 4.52 → 0.002 mrad, m = 3..12 3.64 → 0.003.
    let (rep, stdout) = replay_plain(&rig_recording_with(40.0, 0.0, 3.0e-4));
    assert!(rep["motion"]["warning"].is_null(), "{stdout}");
    assert_eq!(rep["motion"]["harmonics"][0]["flagged"], false);
    let paths = rep["paths"].as_array().unwrap();
    assert!(paths.iter().any(|p| p == "offset"), "{paths:?}");
    assert_eq!(rep["input_scaling"]["source"], "estimated from min/max");
    let [raw12, cor12, raw3, cor3] = motion_and_sensor_bands(&rep);
    assert!(raw12 / cor12 > 100.0, "{stdout}");
    assert!(raw3 / cor3 > 300.0, "{stdout}");
}

#[test]
fn sensor_periods_are_read_from_the_reference_or_refused() {
    // N = 2 (the extreme sensor) on a reference in degrees: 2π/360 the travel, refused
    // with the figures named.
    let mut sensor = SensorModel::extreme();
    sensor.sensor_periods = 3;
    let text = sensor_recording(&sensor, 20_000.0, 10.0, 4.0);
    let (rep, stdout) = replay_plain(&text);
    assert_eq!(rep["sensor_periods"], 3, "{stdout}");
    assert!(stdout.contains("N = 3 (from theta_rad)"), "{stdout}");
    // The flag overrides.
    let files = Files::new(&text, None);
    let _ = files.run(&["--sensor-periods", "2", "--bank", "default"]);
    let rep = report(&files.report);
    assert_eq!(rep["sensor_periods_source"]["source"], "--sensor-periods");
    // A reference in degrees: refused, naming the column.
    let mut deg = String::from("t_s,x,y,theta_rad\n");
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let th: f64 = f[3].parse().unwrap();
        writeln!(deg, "{},{},{},{}", f[0], f[1], f[2], th.to_degrees()).unwrap();
    }
    assert_refused(
        &deg,
        None,
        &["IN.csv", "column `theta_rad`", "--sensor-periods"],
    );
}

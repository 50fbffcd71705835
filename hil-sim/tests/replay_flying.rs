//! `hil-sim replay` of recordings that begin with the rotor at speed, and of one whose
//! sensor drops out for 5 ms: the core locks from the first samples, never reports a
//! loss of lock it did not have, and adapts (again) by itself.

mod common;

use common::{report, Files, ADC, IDENTITY_CONFIG, SAMPLE_PERIOD_S};
use mras_sim::{wrap_pi, SensorModel};
use serde_json::Value;
use std::f64::consts::TAU;
use std::fmt::Write as _;

/// `revs` revolutions of the extreme sensor at a constant speed from the first row (the
/// recording starts mid-flight, at an arbitrary angle), with a 12-bit converter. Rows in
/// `dropout` read both channels at mid-scale (a disconnected sensor).
fn recording(speed_rev_s: f64, revs: f64, dropout: Option<std::ops::Range<usize>>) -> String {
    let sensor = SensorModel::extreme();
    let w = speed_rev_s * TAU;
    let rows = (revs / speed_rev_s.abs() / SAMPLE_PERIOD_S).round() as usize;
    let mut text = String::from("t_s,x,y,theta_rad\n");
    for k in 0..rows {
        let t = k as f64 * SAMPLE_PERIOD_S;
        let th = 1.234 + w * t;
        let (x, y) = match &dropout {
            Some(d) if d.contains(&k) => (0.0, 0.0),
            _ => {
                let (x, y) = sensor.vector(th);
                (ADC.quantise(x) as f32, ADC.quantise(y) as f32)
            }
        };
        writeln!(text, "{t},{x},{y},{th}").unwrap();
    }
    text
}

/// Replay `text` with the identity scaling; the report and the estimates (θ̂ per row).
fn replay(text: &str) -> (Value, Vec<f64>) {
    let files = Files::new(text, Some(IDENTITY_CONFIG));
    files.run(&[]);
    let rep = report(&files.report);
    let mut rdr = csv::Reader::from_path(&files.output).unwrap();
    let theta_hat = rdr
        .records()
        .map(|r| r.unwrap()[1].parse::<f64>().unwrap())
        .collect();
    (rep, theta_hat)
}

/// The estimate's spatial error pk-pk (mechanical rad) over revolution `rev` (0-based)
/// of a recording at `speed_rev_s`, modulo a sensor period, its mean removed.
fn revolution_pk_pk(text: &str, theta_hat: &[f64], speed_rev_s: f64, rev: usize) -> f64 {
    let per_rev = (1.0 / speed_rev_s.abs() / SAMPLE_PERIOD_S).round() as usize;
    let theta: Vec<f64> = text
        .lines()
        .skip(1 + rev * per_rev)
        .take(per_rev)
        .map(|l| l.rsplit(',').next().unwrap().parse().unwrap())
        .collect();
    const BINS: usize = 64;
    let (mut sum, mut n) = ([0.0f64; BINS], [0u32; BINS]);
    for (k, th) in theta.iter().enumerate() {
        let e = wrap_pi(2.0 * (theta_hat[rev * per_rev + k] - th)) / 2.0;
        let b = ((th / TAU).rem_euclid(1.0) * BINS as f64) as usize % BINS;
        sum[b] += e;
        n[b] += 1;
    }
    let means: Vec<f64> = (0..BINS)
        .filter(|&b| n[b] > 0)
        .map(|b| sum[b] / n[b] as f64)
        .collect();
    let max = means.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let min = means.iter().cloned().fold(f64::INFINITY, f64::min);
    max - min
}

/// Recordings at ±100 and ±70 rev/s from their first row: no loss of lock, the error
/// 100x below raw within 20 revolutions (the report's second half is revolutions
/// 10-20), and most of the revolutions adapted.
#[test]
fn replay_of_a_recording_that_starts_at_speed_adapts() {
    for speed_rev_s in [100.0, -100.0, 70.0, -70.0] {
        let text = recording(speed_rev_s, 20.0, None);
        let (rep, theta_hat) = replay(&text);
        assert_eq!(rep["faults_total"], 0, "{speed_rev_s}: {}", rep["faults"]);
        assert!(rep["first_loss_of_lock_line"].is_null());
        let e = &rep["spatial_error"];
        let reduction = e["reduction"].as_f64().unwrap();
        assert!(
            reduction > 100.0,
            "{speed_rev_s} rev/s: {reduction:.0}x ({} → {} mrad)",
            e["raw"]["pk_pk_mrad"],
            e["corrected"]["pk_pk_mrad"]
        );
        let revs = rep["convergence"]["revs_adapted"].as_u64().unwrap();
        assert!(
            revs >= 18,
            "{speed_rev_s} rev/s: {revs} revolutions adapted"
        );
        let raw = e["raw"]["pk_pk_rad"].as_f64().unwrap();
        let first_100x = (0..20)
            .find(|&r| raw / revolution_pk_pk(&text, &theta_hat, speed_rev_s, r) >= 100.0)
            .map(|r| r + 1);
        eprintln!(
            "{speed_rev_s:+} rev/s: {reduction:.0}x over revolutions 10-20; first revolution at \
             100x: {first_100x:?}"
        );
        assert!(first_100x.is_some_and(|r| r <= 10), "{first_100x:?}");
    }
}

/// 5 ms without a sensor at 100 rev/s, in revolution 3 (before the adaptation has
/// converged): replay re-acquires, adapts on (revolutions adapted ~ all but the
/// dropout's), and reaches the same accuracy as without the dropout.
#[test]
fn replay_reacquires_after_a_dropout_at_speed() {
    let speed_rev_s = 100.0;
    let start = (2.5 / speed_rev_s / SAMPLE_PERIOD_S) as usize;
    let dropout = start..start + (5.0e-3 / SAMPLE_PERIOD_S) as usize;
    let text = recording(speed_rev_s, 20.0, Some(dropout.clone()));
    let (rep, theta_hat) = replay(&text);
    assert_eq!(rep["faults"]["sensor_lost"], dropout.len());
    let revs = rep["convergence"]["revs_adapted"].as_u64().unwrap();
    assert!(revs >= 17, "{revs} revolutions adapted");
    let e = &rep["spatial_error"];
    let reduction = e["reduction"].as_f64().unwrap();
    assert!(reduction > 100.0, "{reduction:.0}x");
    // Within the revolution after the one with the dropout, the error is back below
    // raw / 30 (the observer's restart transient), and 100x below by revolution 10.
    let raw = e["raw"]["pk_pk_rad"].as_f64().unwrap();
    let per_rev: Vec<f64> = (0..20)
        .map(|r| raw / revolution_pk_pk(&text, &theta_hat, speed_rev_s, r))
        .collect();
    eprintln!("reduction per revolution: {per_rev:.0?}");
    assert!(per_rev[4] > 30.0, "{per_rev:?}");
    assert!(per_rev[9..].iter().all(|r| *r > 100.0), "{per_rev:?}");
}

//! Adaptation gates: speed, |H|, disturbance torque, acceleration, manual freeze.

mod common;
use common::*;
use mras::{Config, Cplx, PathKind, Tracker};
use std::f64::consts::TAU;

fn moved(t: &Tracker, kind: PathKind) -> bool {
    t.coefficients().get(kind).unwrap() != Cplx::ZERO
}

#[test]
fn frozen_tracker_measures_but_does_not_adapt() {
    let mut t = Tracker::new(Config::default()).unwrap();
    t.set_frozen(true);
    run(extreme_sensor(), 20.0).run(&mut t, 5, no_noise(), |_, _| {});
    assert_eq!(
        t.coefficients(),
        mras::Coefficients::zeros(Config::default().paths())
    );
    let c = t.convergence();
    assert!(c.residual_rad[0] > 0.01, "residual still measured: {c:?}");
    assert_eq!(c.revs_adapted, 0);
    assert!(!c.converged);
}

#[test]
fn minimum_speed_gate() {
    let mut cfg = Config::default();
    cfg.gates.min_speed_rad_s = 200.0; // above 20 rev/s = 126 rad/s
    let (t, _, _) = commission(cfg, &run(extreme_sensor(), 20.0), 3, no_noise());
    assert!(!moved(&t, PathKind::Offset));
    cfg.gates.min_speed_rad_s = 100.0;
    let (t, _, _) = commission(cfg, &run(extreme_sensor(), 20.0), 3, no_noise());
    assert!(moved(&t, PathKind::Offset));
}

#[test]
fn minimum_h_gate_is_per_path() {
    // At 5 rev/s with EVs 100/10/1 Hz: |H| ≈ 0.07, 0.18, 0.28, 0.36 for m = 1..4.
    let mut cfg = Config::default();
    cfg.gates.min_h = 0.32;
    let (t, _, _) = commission(cfg, &run(extreme_sensor(), 5.0), 3, no_noise());
    for kind in [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(4),
    ] {
        assert!(!moved(&t, kind), "{kind:?} adapted below its |H| gate");
    }
    assert!(moved(&t, PathKind::Harmonic(5)));
    // The gated paths never saw their error: their zero residual says nothing, and the
    // bank is not converged however long it runs.
    let (t, _, _) = commission(cfg, &run(extreme_sensor(), 5.0), 12, no_noise());
    let c = t.convergence();
    assert_eq!(c.unseen_paths, 0b0111, "{c:?}");
    assert!(!c.converged, "{c:?}");
    // Without the gate every path sees its error, and the bank converges.
    let (t, _, _) = commission(
        Config::default(),
        &run(extreme_sensor(), 5.0),
        12,
        no_noise(),
    );
    let c = t.convergence();
    assert_eq!(c.unseen_paths, 0, "{c:?}");
    assert!(c.converged, "{c:?}");
}

/// Constant speed with a torque feedforward that is off by `bias_nm`: the observer's
/// disturbance estimate settles at -bias.
fn run_with_torque_bias(cfg: Config, bias_nm: f32) -> Tracker {
    let mut t = Tracker::new(cfg).unwrap();
    let sensor = extreme_sensor();
    let w = 20.0 * std::f64::consts::TAU;
    for k in 0..40_000u32 {
        let th = w * k as f64 * T_S;
        let (x, y) = sensor.vector(th);
        // Start at speed: the first sample acquires the angle, ω̂ follows within ~0.2 s.
        let _ = t.step(x as f32, y as f32, bias_nm);
    }
    t
}

#[test]
fn disturbance_torque_gate() {
    let mut cfg = Config::default();
    cfg.gates.max_disturbance_nm = 0.005;
    let t = run_with_torque_bias(cfg, 0.02);
    assert!((t.last_estimate().disturbance_nm + 0.02).abs() < 1e-3);
    assert!(!t.last_estimate().adapting);
    let t = run_with_torque_bias(Config::default(), 0.02);
    assert!(t.last_estimate().adapting);
}

#[test]
fn acceleration_gate_on_the_sine_trajectory() {
    let mut cfg = Config::default();
    cfg.gates.max_accel_rad_s2 = 100.0; // the trajectory peaks at 628 rad/s²
    let kin = paper_sine(None);
    let mut t = Tracker::new(cfg).unwrap();
    let (mut adapting, mut during_accel) = (0u32, 0u32);
    kin.run(&mut t, 0, 40_000, no_noise(), |_, rec| {
        let accel = 100.0 * std::f64::consts::TAU * (std::f64::consts::TAU * rec.t_s).cos();
        let est = rec.result.unwrap();
        adapting += est.adapting as u32;
        during_accel += (est.adapting && accel.abs() > 100.0 + 1e-3) as u32;
    });
    assert!(adapting > 1000, "never adapted");
    assert_eq!(during_accel, 0);
}

/// Largest change of any coefficient between two snapshots (relative to |Z| = 1).
fn largest_change(a: &mras::Coefficients, b: &mras::Coefficients) -> f32 {
    a.iter()
        .zip(b.iter())
        .map(|((_, x), (_, y))| (x - y).abs())
        .fold(0.0, f32::max)
}

/// After convergence, a torque the feedforward does not know (a step of its bias, as an
/// unmodelled load step) makes the observer lag by ΔT/K_so ≈ 23 mrad mechanical until
/// its disturbance estimate catches up. The adaptation pauses through it, the
/// coefficients stay where commissioning put them, and it resumes once the lag settled.
#[test]
fn a_torque_step_after_convergence_pauses_the_adaptation() {
    let sensor = extreme_sensor();
    let w = 20.0 * std::f64::consts::TAU;
    let mut t = Tracker::new(Config::default()).unwrap();
    let mut k = 0u32;
    let mut step = |t: &mut Tracker, bias_nm: f32| {
        let (x, y) = sensor.vector(w * k as f64 * T_S);
        k += 1;
        t.step(x as f32, y as f32, bias_nm).unwrap()
    };
    // 2 s at 20 rev/s: converged.
    for _ in 0..40_000 {
        step(&mut t, 0.0);
    }
    assert!(t.convergence().converged, "{:?}", t.convergence());
    let before = t.coefficients();
    let (mut paused, mut largest) = (0u32, 0.0f32);
    // 0.1 N·m against K_so = Ĵ·Σλiλj ≈ 4.4 N·m/rad; 0.3 s.
    for i in 0..6_000 {
        paused += !step(&mut t, 0.1).adapting as u32;
        if i % 100 == 0 {
            largest = largest.max(largest_change(&before, &t.coefficients()));
        }
    }
    assert!(paused > 5_000, "paused {paused} of 6000 samples");
    assert!(largest < 1.0e-3, "coefficients moved by {largest}");
    // The disturbance estimate has caught up: adapting again, from where it was.
    let mut adapting_at_end = false;
    for _ in 0..10_000 {
        adapting_at_end = step(&mut t, 0.1).adapting;
    }
    assert!(adapting_at_end);
    assert!(largest_change(&before, &t.coefficients()) < 1.0e-3);
}

/// Samples the tracker adapted on, converged at `from_rev_s` (2 s) and then ramping at
/// `accel_rad_s2` to `to_rev_s` with a perfect torque feedforward: over the ramp after its
/// first `onset_s`, and over the 0.2 s after the ramp's end.
fn adapting_through_a_ramp(
    cfg: Config,
    (from_rev_s, to_rev_s, accel_rad_s2): (f64, f64, f64),
    onset_s: f64,
) -> (u32, u32, u32) {
    let sensor = extreme_sensor();
    let mut t = Tracker::new(cfg).unwrap();
    let (w0, w1) = (from_rev_s * TAU, to_rev_s * TAU);
    let ramp_s = (w1 - w0) / accel_rad_s2;
    let (mut theta, mut w) = (0.0f64, w0);
    let (mut in_ramp, mut ramp_samples, mut after) = (0u32, 0u32, 0u32);
    for k in 0..(2.6 / T_S) as u32 {
        let t_rel = k as f64 * T_S - 2.0;
        let a = if (0.0..ramp_s).contains(&t_rel) {
            accel_rad_s2
        } else {
            0.0
        };
        let (x, y) = sensor.vector(theta);
        let est = t.step(x as f32, y as f32, (J_KG_M2 * a) as f32).unwrap();
        if t_rel < 0.0 {
            assert!(
                t_rel < -0.1 || t.convergence().converged,
                "{:?}",
                t.convergence()
            );
        } else if t_rel >= onset_s && t_rel < ramp_s {
            in_ramp += est.adapting as u32;
            ramp_samples += 1;
        } else if t_rel >= ramp_s + 0.2 {
            after += est.adapting as u32;
        }
        theta += w * T_S + 0.5 * a * T_S * T_S;
        w += a * T_S;
    }
    (in_ramp, ramp_samples, after)
}

#[test]
fn a_deceleration_after_convergence_closes_the_sweep_gate() {
    // 20 → 5 rev/s at 2000 rad/s²: the sweep |dω/dt|/(N·ω²) is 0.03 at 20 rev/s and
    // 0.5 at 5 rev/s. Without the sweep gate the other gates let most of it through ...
    let slowing = (20.0, 5.0, -2000.0);
    let mut cfg = Config::default();
    cfg.gates.max_sweep_per_rad = f32::INFINITY;
    let (open, samples, _) = adapting_through_a_ramp(cfg, slowing, 0.0);
    assert!(open > samples / 2, "{open} of {samples}");
    // ... with it (the default) the adaptation stops within 11 ms (a quarter of a sensor
    // period: the net torque is smoothed over one), and resumes at the new steady speed.
    let (open, samples, after) = adapting_through_a_ramp(Config::default(), slowing, 0.011);
    assert_eq!(open, 0, "{open} of {samples} samples adapted in the ramp");
    assert!(after > 0, "never adapted again at the new speed");
    // Speeding up at the same rate does not close it.
    let (open, samples, _) = adapting_through_a_ramp(Config::default(), (10.0, 20.0, 2000.0), 0.0);
    assert!(open > samples / 2, "{open} of {samples}");
}

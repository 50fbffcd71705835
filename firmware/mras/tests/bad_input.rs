//! Bad input: every kind raises its own fault, holds the state, never panics, and
//! never lets a NaN into the state.

mod common;
use common::*;
use mras::{Config, Fault, InputScaling, Tracker};

/// A tracker that has commissioned for a few revolutions (non-trivial state).
fn running_tracker(cfg: Config) -> Tracker {
    let (t, _, _) = commission(cfg, &run(extreme_sensor(), 20.0), 3, no_noise());
    t
}

fn snapshot(t: &Tracker) -> impl PartialEq + std::fmt::Debug {
    (
        t.observer_state(),
        t.coefficients(),
        t.last_estimate(),
        t.convergence(),
    )
}

#[test]
fn each_bad_sample_raises_its_fault_and_holds_state() {
    let cfg = Config {
        input: InputScaling {
            raw_limit: 1.9,
            ..InputScaling::default()
        },
        ..Config::default()
    };
    let cases: [(&str, f32, f32, f32, Fault); 9] = [
        ("NaN x", f32::NAN, 0.5, 0.0, Fault::NonFiniteInput),
        ("NaN y", 0.5, f32::NAN, 0.0, Fault::NonFiniteInput),
        ("+inf x", f32::INFINITY, 0.0, 0.0, Fault::NonFiniteInput),
        ("-inf y", 0.0, f32::NEG_INFINITY, 0.0, Fault::NonFiniteInput),
        ("NaN torque", 1.0, 0.0, f32::NAN, Fault::NonFiniteInput),
        ("zero vector", 0.0, 0.0, 0.0, Fault::SensorLost),
        ("tiny vector", 0.1, -0.1, 0.0, Fault::SensorLost),
        ("saturated vector", 1.8, 1.8, 0.0, Fault::SensorSaturated),
        ("railed ADC", 1.9, 0.0, 0.0, Fault::SensorSaturated),
    ];
    for (what, x, y, tq, fault) in cases {
        let mut t = running_tracker(cfg);
        let before = snapshot(&t);
        assert_eq!(t.step(x, y, tq), Err(fault), "{what}");
        assert_eq!(snapshot(&t), before, "{what}: state changed");
        assert!(t.faults().contains(fault), "{what}: not latched");
        assert_eq!(t.faults().iter().count(), 1, "{what}: {:?}", t.faults());
        // A burst of the same bad sample changes nothing either.
        for _ in 0..1000 {
            assert_eq!(t.step(x, y, tq), Err(fault));
        }
        assert_eq!(snapshot(&t), before, "{what}: state changed over a burst");
        // The next good sample is accepted and the state stays finite.
        let th = t.last_estimate().theta_e_rad;
        let est = t
            .step(th.cos(), th.sin(), 0.0)
            .expect("good sample accepted");
        assert!(est.theta_rad.is_finite() && est.omega_rad_s.is_finite());
        t.clear_faults();
        assert!(t.faults().is_empty());
    }
}

#[test]
fn absurd_torque_is_refused_not_propagated() {
    let mut t = running_tracker(Config::default());
    let before = snapshot(&t);
    let th = t.last_estimate().theta_e_rad;
    assert_eq!(
        t.step(th.cos(), th.sin(), f32::MAX),
        Err(Fault::NumericalOverflow)
    );
    assert_eq!(snapshot(&t), before);
}

#[test]
fn loss_of_lock_is_detected_and_freezes_adaptation() {
    let mut t = running_tracker(Config::default());
    let coefs = t.coefficients();
    // The vector jumps half a sensor period: the observer cannot be locked to it.
    let th = t.last_estimate().theta_e_rad + std::f32::consts::PI;
    assert_eq!(t.step(th.cos(), th.sin(), 0.0), Err(Fault::LossOfLock));
    assert!(t.faults().contains(Fault::LossOfLock));
    // Until cleared, nothing adapts, whatever the observer does meanwhile.
    let est0 = t.last_estimate();
    let mut th_e = th;
    for _ in 0..2000 {
        th_e += 2.0 * est0.omega_rad_s * 50e-6;
        let _ = t.step(th_e.cos(), th_e.sin(), 0.0);
    }
    assert_eq!(t.coefficients(), coefs);
    assert!(!t.last_estimate().adapting);
    for v in [t.last_estimate().theta_rad, t.last_estimate().omega_rad_s] {
        assert!(v.is_finite());
    }
}

#[test]
fn disconnected_sensor_at_power_up_never_acquires_garbage() {
    let mut t = Tracker::new(Config::default()).unwrap();
    for _ in 0..100 {
        assert_eq!(t.step(0.0, 0.0, 0.0), Err(Fault::SensorLost));
    }
    assert_eq!(t.last_estimate(), mras::Estimate::default());
    let est = t.step(0.0, 1.0, 0.0).unwrap();
    assert!((est.theta_e_rad - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
}

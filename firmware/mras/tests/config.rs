//! Out-of-range configuration is refused with the field named; snapshots round-trip.

use mras::{
    AdaptationLaw, CoefficientsError, Config, ConfigError, Cplx, PathKind, Tracker, MAX_PATHS,
};

fn field_of(cfg: Config) -> &'static str {
    match Tracker::new(cfg) {
        Err(ConfigError { field, .. }) => field,
        Ok(_) => panic!("accepted {cfg:?}"),
    }
}

#[test]
fn defaults_are_valid() {
    Config::default().validate().unwrap();
    let cfg = Config {
        law: AdaptationLaw::PAPER_FIG8,
        ..Config::default()
    };
    cfg.validate().unwrap();
}

#[test]
fn each_bad_field_is_named() {
    let d = Config::default;
    let mut c = d();
    c.sample_period_s = 0.0;
    assert_eq!(field_of(c), "sample_period_s");
    c = d();
    c.sample_period_s = f32::NAN;
    assert_eq!(field_of(c), "sample_period_s");
    c = d();
    c.sensor_periods = 0;
    assert_eq!(field_of(c), "sensor_periods");
    c = d();
    c.observer.eigenvalues_hz = [100.0, -10.0, 1.0];
    assert_eq!(field_of(c), "observer.eigenvalues_hz");
    c = d();
    c.observer.eigenvalues_hz = [2000.0, 10.0, 1.0];
    assert_eq!(field_of(c), "observer.eigenvalues_hz");
    c = d();
    c.observer.inertia_kg_m2 = f32::INFINITY;
    assert_eq!(field_of(c), "observer.inertia_kg_m2");
    c = d();
    c.set_paths(&[PathKind::Harmonic(3)]).unwrap();
    assert_eq!(field_of(c), "paths.harmonic");
    c = d();
    c.set_paths(&[PathKind::Harmonic(4), PathKind::Harmonic(-2)])
        .unwrap();
    assert_eq!(field_of(c), "paths");
    c = d();
    assert!(c.set_paths(&[PathKind::Offset; MAX_PATHS + 1]).is_err());
    c = d();
    c.law = AdaptationLaw::Compensated {
        gain_per_rad: 0.5,
        offset_gain_per_mech_rad: 0.0,
        proportional: 0.0,
        h_floor: 0.05,
    };
    assert_eq!(field_of(c), "law.gain_per_rad");
    c = d();
    c.law = AdaptationLaw::Compensated {
        gain_per_rad: 0.15,
        offset_gain_per_mech_rad: -0.1,
        proportional: 0.0,
        h_floor: 0.05,
    };
    assert_eq!(field_of(c), "law.offset_gain_per_mech_rad");
    c = d();
    c.law = AdaptationLaw::PaperLiteral {
        k1_per_s: -1.0,
        k2: 0.1,
    };
    assert_eq!(field_of(c), "law.k1_per_s");
    c = d();
    c.gates.min_h = 1.5;
    assert_eq!(field_of(c), "gates.min_h");
    c = d();
    c.health.amplitude_max = 0.1;
    assert_eq!(field_of(c), "health.amplitude_max");
    c = d();
    c.health.lock_threshold_rad = 4.0;
    assert_eq!(field_of(c), "health.lock_threshold_rad");
    c = d();
    c.convergence.residual_rad = 0.0;
    assert_eq!(field_of(c), "convergence.residual_rad");
    let msg = format!("{}", Tracker::new(c).unwrap_err());
    assert!(msg.contains("convergence.residual_rad"), "{msg}");
}

#[test]
fn coefficient_snapshot_round_trips_and_is_validated() {
    let mut t = Tracker::new(Config::default()).unwrap();
    let mut c = t.coefficients();
    assert_eq!(c.len(), 7);
    assert!(c.set(PathKind::Harmonic(5), Cplx::new(0.01, -0.02)));
    assert!(!c.set(PathKind::Harmonic(9), Cplx::ZERO));
    t.set_coefficients(&c).unwrap();
    assert_eq!(t.coefficients(), c);

    let mut bad = c;
    bad.set(PathKind::Offset, Cplx::new(f32::NAN, 0.0));
    assert_eq!(t.set_coefficients(&bad), Err(CoefficientsError::OutOfRange));
    bad = c;
    bad.set(PathKind::Offset, Cplx::new(5.0, 0.0));
    assert_eq!(t.set_coefficients(&bad), Err(CoefficientsError::OutOfRange));
    let other = mras::Coefficients::zeros(&[PathKind::Offset]);
    assert_eq!(
        t.set_coefficients(&other),
        Err(CoefficientsError::PathMismatch)
    );
    // Refusals leave the loaded values alone.
    assert_eq!(t.coefficients(), c);
}

//! An offset that drifts in time: the offset path's gain per mechanical radian.

mod common;
use common::*;
use mras::closed_form::offset_and_h2;
use mras::{AdaptationLaw, Config, Cplx, PathKind, Tracker};
use mras_sim::SensorModel;
use std::f64::consts::TAU;

const SPEED_REV_S: f64 = 20.0;
/// dAx/dt (of the nominal amplitude), the accuracy benchmark's largest.
const DRIFT_PER_S: f64 = 0.01;
const SETTLE_S: f64 = 1.5;
const DRIFT_S: f64 = 1.0;

fn config(sensor_periods: u16, offset_gain_per_mech_rad: f32) -> Config {
    let mut cfg = Config {
        sensor_periods,
        ..Config::default()
    };
    if let AdaptationLaw::Compensated {
        offset_gain_per_mech_rad: g,
        ..
    } = &mut cfg.law
    {
        *g = offset_gain_per_mech_rad;
    }
    cfg
}

/// Spin a sensor with offsets at constant speed until the bank has settled, then let Ax
/// drift. Returns the offset coefficient's distance from eq. (6)-(7) for the drifted
/// sensor at the end, and every offset coefficient on the way.
fn drifting(cfg: Config) -> (f64, Vec<Cplx>) {
    let mut sensor = SensorModel::ideal(cfg.sensor_periods);
    (sensor.ax, sensor.ay) = (0.06, -0.04);
    let mut t = Tracker::new(cfg).unwrap();
    let w = SPEED_REV_S * TAU;
    let mut trail = Vec::new();
    let steps = ((SETTLE_S + DRIFT_S) / T_S) as u32;
    for k in 0..steps {
        let t_s = k as f64 * T_S;
        sensor.ax = 0.06 + DRIFT_PER_S * (t_s - SETTLE_S).max(0.0);
        let (x, y) = sensor.vector(w * t_s);
        t.step(x as f32, y as f32, 0.0).unwrap();
        if k % 200 == 0 {
            trail.push(t.coefficients().get(PathKind::Offset).unwrap());
        }
    }
    assert!(t.convergence().converged, "{:?}", t.convergence());
    let (xo, yo) = offset_and_h2(sensor.ax, sensor.ay, 0.0, 0.0);
    let c = t.coefficients().get(PathKind::Offset).unwrap();
    let lag = ((c.re as f64 - xo).powi(2) + (c.im as f64 - yo).powi(2)).sqrt();
    (lag, trail)
}

/// A first-order loop integrating over angle lags a ramp by (rate per radian) / gain.
fn predicted_lag(sensor_periods: u16, gain_per_rad: f64) -> f64 {
    DRIFT_PER_S / (sensor_periods as f64 * SPEED_REV_S * TAU) / gain_per_rad
}

#[test]
fn at_n_1_the_offset_tracks_a_drift_at_the_offset_gain() {
    // Per electrical radian alone (0.15): the lag of a type-1 loop.
    let (alone, _) = drifting(config(1, 0.0));
    let expected = predicted_lag(1, 0.15);
    assert!(
        (alone / expected - 1.0).abs() < 0.15,
        "lag {alone:.3e}, expected {expected:.3e}"
    );
    // The default, 0.3 per mechanical radian, is 0.2 per electrical radian at N = 1.
    let (default, _) = drifting(Config {
        sensor_periods: 1,
        ..Config::default()
    });
    let expected = predicted_lag(1, 0.2);
    assert!(
        (default / expected - 1.0).abs() < 0.15,
        "lag {default:.3e}, expected {expected:.3e}"
    );
}

#[test]
fn at_n_2_the_default_offset_gain_is_the_common_one() {
    // 0.3 per mechanical radian is 0.15 per electrical radian at N = 2: the same loop,
    // sample for sample.
    let (lag, trail) = drifting(config(2, 0.3));
    let (lag_common, trail_common) = drifting(config(2, 0.0));
    assert_eq!(trail, trail_common);
    assert_eq!(lag, lag_common);
    let expected = predicted_lag(2, 0.15);
    assert!(
        (lag / expected - 1.0).abs() < 0.15,
        "lag {lag:.3e}, expected {expected:.3e}"
    );
}

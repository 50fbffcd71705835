//! Single-error sensors: the coefficients converge to the paper's closed forms
//! (eq. 6-7, 10-11, 13-15, 19-20) in both directions of rotation.

mod common;
use common::*;
use mras::closed_form;
use mras::{Config, Cplx, PaperForm, PathKind};
use mras_sim::{SensorHarmonic, SensorModel};

/// Closed forms are exact fixed points for a single error (docs/theory.md §4);
/// what remains is f32 round-off and the adaptation's residual ripple.
const TOL: f32 = 2.0e-4;
const SPEEDS_REV_S: [f64; 2] = [10.0, -10.0];
const REVS: u32 = 20;

fn assert_close(what: &str, speed: f64, got: Cplx, want: (f64, f64)) {
    let err = ((got.re as f64 - want.0).powi(2) + (got.im as f64 - want.1).powi(2)).sqrt();
    assert!(
        err < TOL as f64,
        "{what} at {speed} rev/s: got ({:.6}, {:.6}), closed form ({:.6}, {:.6}), |err| {err:.2e}",
        got.re,
        got.im,
        want.0,
        want.1
    );
}

/// Run every speed; check `path` against `want` and every other path against zero.
fn check(cfg: Config, sensor: SensorModel, path: PathKind, want: (f64, f64)) {
    for speed in SPEEDS_REV_S {
        let (t, per_rev, raw) = commission(cfg, &run(sensor, speed), REVS, no_noise());
        let c = t.coefficients();
        for (kind, v) in c.iter() {
            if kind == path {
                assert_close(&format!("{kind:?}"), speed, v, want);
            } else {
                assert_close(&format!("{kind:?} (should stay 0)"), speed, v, (0.0, 0.0));
            }
        }
        let last = *per_rev.last().unwrap();
        assert!(
            last < raw / 100.0,
            "{path:?} {speed}: error {last} vs raw {raw}"
        );
        assert!(
            t.convergence().converged,
            "{path:?} {speed}: {:?}",
            t.convergence()
        );
    }
}

#[test]
fn offset_only() {
    let mut s = SensorModel::ideal(2);
    s.ax = 0.05;
    s.ay = -0.03;
    let want = closed_form::offset_and_h2(0.05, -0.03, 0.0, 0.0);
    check(Config::default(), s, PathKind::Offset, want);
}

#[test]
fn amplitude_only() {
    let mut s = SensorModel::ideal(2);
    s.bx1 = 1.1;
    let want = closed_form::amplitude_quadrature(1.1, 1.0, 0.0);
    check(Config::default(), s, PathKind::AmplitudeQuadrature, want);
}

#[test]
fn quadrature_only() {
    let mut s = SensorModel::ideal(2);
    s.phi_x1_rad = 5f64.to_radians();
    let want = closed_form::amplitude_quadrature(1.0, 1.0, 5f64.to_radians());
    check(Config::default(), s, PathKind::AmplitudeQuadrature, want);
}

#[test]
fn second_harmonic_goes_to_the_offset_path() {
    let s = SensorModel::ideal(2).with_harmonic(SensorHarmonic::equal(2, 0.04, 0.6));
    let want = closed_form::offset_and_h2(0.0, 0.0, 0.04, 0.6);
    check(Config::default(), s, PathKind::Offset, want);
}

#[test]
fn third_harmonic_goes_to_the_cd_path() {
    let s = SensorModel::ideal(2).with_harmonic(SensorHarmonic::equal(3, 0.04, 0.5));
    let (c, d, _psi) = closed_form::third_harmonic(0.04, 0.5);
    check(Config::default(), s, PathKind::AmplitudeQuadrature, (c, d));
}

/// E and F per eq. (19)-(20), checked through the paper-form accessor.
fn check_ef(cfg: Config, h: i8, b: f64, phi: f64) {
    let s = SensorModel::ideal(2).with_harmonic(SensorHarmonic::equal(h as i32, b, phi));
    let (e, f) = closed_form::harmonic_ef(b, phi);
    // Our stored value d_h = -(E - jF).
    check(cfg, s, PathKind::Harmonic(h), (-e, f));
    for speed in SPEEDS_REV_S {
        let (t, _, _) = commission(cfg, &run(s, speed), REVS, no_noise());
        match t.coefficients().paper_form(PathKind::Harmonic(h)) {
            Some(PaperForm::Harmonic { e: ge, f: gf, .. }) => {
                assert!((ge as f64 - e).abs() < TOL as f64 && (gf as f64 - f).abs() < TOL as f64);
            }
            other => panic!("no harmonic path: {other:?}"),
        }
    }
}

#[test]
fn fourth_harmonic() {
    check_ef(Config::default(), 4, 0.03, 0.7);
}

#[test]
fn negative_second_harmonic() {
    let mut cfg = Config::default();
    cfg.set_paths(&[
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(-2),
        PathKind::Harmonic(5),
    ])
    .unwrap();
    check_ef(cfg, -2, 0.03, 0.7);
}

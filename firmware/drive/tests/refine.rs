//! The refinement's mean and the two speeds' separation of motion from sensor error.

use drive::refine::{separate, CoefficientMean, RefineError, Refined};
use mras::{Coefficients, Cplx, PathKind};

const BANK: [PathKind; 3] = [
    PathKind::Offset,
    PathKind::AmplitudeQuadrature,
    PathKind::Harmonic(4),
];

fn coefs(values: [Cplx; 3]) -> Coefficients {
    let mut c = Coefficients::zeros(&BANK);
    for (k, v) in BANK.iter().zip(values) {
        c.set(*k, v);
    }
    c
}

/// A sensor's coefficients `e` as the MRAS learns them at speed ω with a motion ripple
/// `M`: `e + M/ω²`.
fn learnt(e: [Cplx; 3], m: [Cplx; 3], omega_rad_s: f32) -> Refined {
    let mut v = e;
    for (v, m) in v.iter_mut().zip(m) {
        *v += m.scale(1.0 / (omega_rad_s * omega_rad_s));
    }
    Refined {
        coefficients: coefs(v),
        speed_rad_s: omega_rad_s,
    }
}

const E: [Cplx; 3] = [
    Cplx {
        re: -4.0e-3,
        im: 3.0e-3,
    },
    Cplx {
        re: -8.1e-3,
        im: 2.6e-3,
    },
    Cplx {
        re: 2.3e-3,
        im: -1.9e-3,
    },
];
/// 0.1 mrad at 125.7 rad/s (20 rev/s) on the offset and C/D paths, none on h4.
const M: [Cplx; 3] = [
    Cplx { re: 1.2, im: -1.0 },
    Cplx { re: -0.9, im: 1.3 },
    Cplx::ZERO,
];

fn max_error(c: &Coefficients, e: [Cplx; 3]) -> f32 {
    c.iter()
        .zip(e)
        .map(|((_, v), e)| (v - e).abs())
        .fold(0.0, f32::max)
}

#[test]
fn two_speeds_give_the_sensor_error_without_the_motion() {
    let w1 = 125.7;
    for ratio in [1.5, 2.0, 3.0] {
        let (a1, a2) = (learnt(E, M, w1), learnt(E, M, ratio * w1));
        let one_speed = max_error(&a1.coefficients, E);
        assert!(one_speed > 1e-4, "the motion is in a1: {one_speed}");
        let e = separate(&a1, &a2).unwrap();
        let err = max_error(&e, E);
        assert!(
            err < 2e-8,
            "ratio {ratio}: {err} against {one_speed} at one speed"
        );
        // Either order.
        let e = separate(&a2, &a1).unwrap();
        assert!(max_error(&e, E) < 2e-8);
        assert_eq!(e.kinds(), &BANK);
    }
}

#[test]
fn speeds_too_close_or_banks_that_differ_are_refused() {
    let w1 = 125.7;
    let a1 = learnt(E, M, w1);
    assert_eq!(
        separate(&a1, &learnt(E, M, 1.2 * w1)),
        Err(RefineError::SpeedsTooClose)
    );
    assert_eq!(
        separate(&a1, &learnt(E, M, f32::NAN)),
        Err(RefineError::SpeedsTooClose)
    );
    assert_eq!(
        separate(&learnt(E, M, 0.0), &a1),
        Err(RefineError::SpeedsTooClose)
    );
    let mut other = learnt(E, M, 2.0 * w1);
    other.coefficients = Coefficients::zeros(&BANK[..2]);
    assert_eq!(separate(&a1, &other), Err(RefineError::BankChanged));
    let empty = Refined {
        coefficients: Coefficients::EMPTY,
        speed_rad_s: 2.0 * w1,
    };
    assert_eq!(separate(&a1, &empty), Err(RefineError::Empty));
}

#[test]
fn the_mean_is_of_the_snapshots_and_restarts_on_another_bank() {
    let mut m = CoefficientMean::default();
    assert_eq!(m.mean(), Err(RefineError::Empty));
    m.add(&Coefficients::EMPTY, 100.0);
    assert_eq!(
        m.samples(),
        0,
        "an empty snapshot (no report yet) is skipped"
    );
    // Jitter of ±20 µ around E, at ±1 rad/s around -100 rad/s (|ω̂| is averaged).
    for i in 0..1000 {
        let s = if i % 2 == 0 { 1.0 } else { -1.0 };
        let v = E.map(|e| e + Cplx::new(2e-5 * s, -2e-5 * s));
        m.add(&coefs(v), -100.0 + s);
    }
    let r = m.mean().unwrap();
    assert!(max_error(&r.coefficients, E) < 1e-8);
    assert!((r.speed_rad_s - 100.0).abs() < 1e-4);
    // Another bank: the mean starts again from it.
    m.add(&Coefficients::zeros(&BANK[..2]), 50.0);
    assert_eq!(m.samples(), 1);
    assert_eq!(m.mean().unwrap().coefficients.kinds(), &BANK[..2]);
}

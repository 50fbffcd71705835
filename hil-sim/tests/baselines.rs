//! The offline calibration baselines against sensors with known errors.

use hil_sim::baselines::{
    constant_speed_reference, Corrector, Ellipse, FitError, Lut, MinMax, Raw,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

/// Wrap into (-π, π].
fn wrap(a: f64) -> f64 {
    let r = a.rem_euclid(TAU);
    if r > PI {
        r - TAU
    } else {
        r
    }
}

/// `x = ax·cos θ + ox + h3·cos 3θ`, `y = ay·sin(θ + φ) + oy + h3·sin 3θ`.
#[derive(Clone, Copy, Debug)]
struct Sensor {
    ax: f64,
    ay: f64,
    ox: f64,
    oy: f64,
    phi_rad: f64,
    h3: f64,
}

impl Sensor {
    const IDEAL: Sensor = Sensor {
        ax: 1.0,
        ay: 1.0,
        ox: 0.0,
        oy: 0.0,
        phi_rad: 0.0,
        h3: 0.0,
    };

    fn sample(&self, theta_rad: f64) -> (f32, f32) {
        let x = self.ax * theta_rad.cos() + self.ox + self.h3 * (3.0 * theta_rad).cos();
        let y = self.ay * (theta_rad + self.phi_rad).sin()
            + self.oy
            + self.h3 * (3.0 * theta_rad).sin();
        (x as f32, y as f32)
    }

    /// `n` samples at θ = start + step·i.
    fn spin(&self, start_rad: f64, step_rad: f64, n: usize) -> (Vec<(f32, f32)>, Vec<f64>) {
        let theta: Vec<f64> = (0..n).map(|i| start_rad + step_rad * i as f64).collect();
        (theta.iter().map(|&t| self.sample(t)).collect(), theta)
    }
}

/// Angle errors `wrap(corrected - θ)` on a fine grid over one revolution that is not
/// aligned with any fit's samples or LUT bins.
fn errors(c: &dyn Corrector, s: &Sensor) -> Vec<f64> {
    (0..10_007)
        .map(|i| {
            let theta = -PI + TAU * (i as f64 + 0.377) / 10_007.0;
            let (x, y) = s.sample(theta);
            let a = c.angle_rad(x, y);
            assert!(a > -PI && a <= PI, "{} gave {a} outside (-π, π]", c.name());
            wrap(a - theta)
        })
        .collect()
}

fn max_abs(e: &[f64]) -> f64 {
    e.iter().fold(0.0, |m, v| m.max(v.abs()))
}

fn pk_pk(e: &[f64]) -> f64 {
    let max = e.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let min = e.iter().cloned().fold(f64::INFINITY, f64::min);
    max - min
}

/// Peak error about the mean (a constant is a mounting offset, not a sensor error).
fn peak_about_mean(e: &[f64]) -> f64 {
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    e.iter().fold(0.0, |m, v| m.max((v - mean).abs()))
}

/// One revolution, 4096 samples (grid hits 0, π/2, π, 3π/2 exactly).
fn one_rev(s: &Sensor) -> Vec<(f32, f32)> {
    s.spin(0.0, TAU / 4096.0, 4096).0
}

const THIRD_HARMONIC: Sensor = Sensor {
    h3: 0.02,
    ..Sensor::IDEAL
};

#[test]
fn raw_on_a_perfect_circle_returns_theta() {
    let e = errors(&Raw, &Sensor::IDEAL);
    assert!(max_abs(&e) < 1e-6, "{}", max_abs(&e));
    // atan2(-0, -1) is -π; the contract is (-π, π].
    assert_eq!(Raw.angle_rad(-1.0, -0.0), PI);
}

#[test]
fn minmax_recovers_offsets_and_amplitudes() {
    let s = Sensor {
        ax: 1.1,
        ay: 0.85,
        ox: 0.07,
        oy: -0.04,
        ..Sensor::IDEAL
    };
    let m = MinMax::fit(&one_rev(&s)).unwrap();
    let (ox, oy) = m.offsets();
    let (ax, ay) = m.amplitudes();
    for (got, want) in [(ox, s.ox), (oy, s.oy), (ax, s.ax), (ay, s.ay)] {
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }
    let e = errors(&m, &s);
    assert!(max_abs(&e) < 1e-5, "{}", max_abs(&e));
    // The raw sensor is far off, so the test means something.
    assert!(max_abs(&errors(&Raw, &s)) > 0.05);
}

#[test]
fn minmax_leaves_half_the_quadrature_error_and_ellipse_removes_it() {
    let s = Sensor {
        ax: 1.1,
        ay: 0.9,
        ox: 0.03,
        oy: -0.02,
        phi_rad: 0.05,
        h3: 0.0,
    };
    let samples = one_rev(&s);
    let m = MinMax::fit(&samples).unwrap();
    // Error ≈ φ/2 + (φ/2)·cos 2θ: peak φ/2 about its mean.
    let peak = peak_about_mean(&errors(&m, &s));
    assert!((0.02..0.03).contains(&peak), "min-max peak {peak}");
    let el = Ellipse::fit(&samples).unwrap();
    let e = errors(&el, &s);
    assert!(max_abs(&e) < 1e-5, "ellipse {}", max_abs(&e));
}

#[test]
fn ellipse_recovers_random_sensors() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x4b4d_5a41);
    let mut sensors: Vec<Sensor> = (0..20)
        .map(|_| {
            let ax = rng.random_range(0.3..3.0);
            Sensor {
                ax,
                ay: ax * rng.random_range(0.6..1.4),
                ox: ax * rng.random_range(-0.3..0.3),
                oy: ax * rng.random_range(-0.3..0.3),
                phi_rad: rng.random_range(-0.3..0.3),
                h3: 0.0,
            }
        })
        .collect();
    // Make sure both signs of φ and a large, negative one are in.
    sensors.push(Sensor {
        ax: 2.5,
        ay: 1.7,
        ox: -0.4,
        oy: 0.6,
        phi_rad: -0.6,
        h3: 0.0,
    });
    assert!(sensors.iter().any(|s| s.phi_rad < -0.05));
    assert!(sensors.iter().any(|s| s.phi_rad > 0.05));
    for s in &sensors {
        // An arbitrary start and a non-integer number of samples per revolution.
        let start = rng.random_range(-PI..PI);
        let (samples, _) = s.spin(start, TAU / 997.3, 2000);
        let el = Ellipse::fit(&samples).unwrap();
        let p = el.params();
        // f32 samples: the fit lands within a few 1e-9 of the truth.
        let tol = 1e-7;
        assert!((p.offset_x - s.ox).abs() < tol * s.ax, "{p:?} vs {s:?}");
        assert!((p.offset_y - s.oy).abs() < tol * s.ax, "{p:?} vs {s:?}");
        assert!(
            (p.amplitude_ratio - s.ay / s.ax).abs() < tol,
            "{p:?} vs {s:?}"
        );
        assert!((p.quadrature_rad - s.phi_rad).abs() < tol, "{p:?} vs {s:?}");
        let e = errors(&el, s);
        assert!(max_abs(&e) < 1e-6, "{} for {s:?}", max_abs(&e));
    }
}

#[test]
fn ellipse_is_exact_on_mras_sensor_model_up_to_its_phase_convention() {
    // `mras_sim::SensorModel` puts φ on X: x = bx1·cos(θ + φx1), y = by1·sin θ.
    let mut m = mras_sim::SensorModel::ideal(1);
    (m.ax, m.ay, m.bx1, m.by1, m.phi_x1_rad) = (0.1, -0.08, 1.2, 1.0, 0.1);
    let samples: Vec<(f32, f32)> = (0..2048)
        .map(|i| {
            let (x, y) = m.vector(TAU * i as f64 / 2048.0);
            (x as f32, y as f32)
        })
        .collect();
    let el = Ellipse::fit(&samples).unwrap();
    let p = el.params();
    assert!((p.offset_x - 0.1).abs() < 1e-6 && (p.offset_y + 0.08).abs() < 1e-6);
    assert!((p.amplitude_ratio - 1.0 / 1.2).abs() < 1e-6, "{p:?}");
    assert!((p.quadrature_rad + 0.1).abs() < 1e-6, "{p:?}");
    for i in 0..1000 {
        let theta = TAU * (i as f64 + 0.5) / 1000.0;
        let (x, y) = m.vector(theta);
        let e = wrap(el.angle_rad(x as f32, y as f32) - (theta + 0.1));
        assert!(e.abs() < 1e-6, "{e} at {theta}");
    }
}

#[test]
fn ellipse_leaves_a_third_harmonic_that_a_lut_removes() {
    let s = THIRD_HARMONIC;
    let el = Ellipse::fit(&one_rev(&s)).unwrap();
    let el_pp = pk_pk(&errors(&el, &s));
    assert!(el_pp > 0.03, "ellipse pk-pk {el_pp}");
    // The 3rd harmonic makes the locus a rounded 2-fold shape (1.02 on x, 0.98 on y):
    // the ellipse fit takes it for amplitude imbalance and doubles the error.
    let raw_pp = pk_pk(&errors(&Raw, &s));
    assert!(el_pp > 1.5 * raw_pp, "ellipse {el_pp} vs raw {raw_pp}");

    // Three revolutions at a step incommensurate with the bins.
    let (samples, reference) = s.spin(0.3, TAU / 9001.7, 27_000);
    let lut_error = |bins| {
        let lut = Lut::fit(&samples, &reference, bins).unwrap();
        assert_eq!(lut.bins(), bins);
        let e = errors(&lut, &s);
        (pk_pk(&e), max_abs(&e))
    };
    let (pp256, _) = lut_error(256);
    assert!(pp256 < 1e-3, "256 bins pk-pk {pp256}");
    let (_, max128) = lut_error(128);
    let (_, max360) = lut_error(360);
    assert!(max128 > max360, "128 bins {max128} vs 360 bins {max360}");
}

#[test]
fn lut_works_backwards_and_with_corrections_at_plus_minus_pi() {
    let s = Sensor {
        ax: 1.05,
        ay: 0.95,
        ox: 0.04,
        oy: -0.03,
        phi_rad: 0.04,
        h3: 0.02,
    };
    // Reverse spin over 5 revolutions: the reference crosses ±π (wrapped) 5 times.
    let (samples, reference) = s.spin(2.0, -TAU / 7001.3, 35_000);
    let lut = Lut::fit(&samples, &reference, 512).unwrap();
    let e = errors(&lut, &s);
    assert!(max_abs(&e) < 1e-3, "reverse {}", max_abs(&e));

    // The magnet mounted half a turn off: raw ≈ θ + π, so every correction is near
    // ±π and a bin's corrections straddle it (a plain mean would give ≈ 0 there).
    let flipped = Sensor {
        ax: -s.ax,
        ay: -s.ay,
        h3: -s.h3,
        ..s
    };
    let (samples, reference) = flipped.spin(-1.0, TAU / 6007.9, 60_000);
    let lut = Lut::fit(&samples, &reference, 256).unwrap();
    let e = errors(&lut, &flipped);
    assert!(max_abs(&e) < 1e-3, "flipped {}", max_abs(&e));
    assert!(max_abs(&errors(&Raw, &flipped)) > 3.0);
}

#[test]
fn constant_speed_reference_recovers_a_perfect_spin() {
    let (theta0, omega) = (1.234_567, TAU * 5.3 / 100_000.0);
    let (samples, truth) = Sensor::IDEAL.spin(theta0, omega, 100_000);
    let r = constant_speed_reference(&samples).unwrap();
    assert_eq!(r.len(), samples.len());
    let n = r.len();
    let omega_fit = (r[n - 1] - r[0]) / (n - 1) as f64;
    assert!((r[0] - theta0).abs() < 1e-9, "θ0 {}", r[0] - theta0);
    assert!((omega_fit - omega).abs() < 1e-9 * omega, "ω {omega_fit}");
    let worst = r
        .iter()
        .zip(&truth)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(worst < 1e-9, "{worst}");

    // Backwards, starting near -π.
    let (samples, _) = Sensor::IDEAL.spin(-3.1, -omega, 100_000);
    let r = constant_speed_reference(&samples).unwrap();
    assert!((r[0] + 3.1).abs() < 1e-9, "θ0 {}", r[0]);
    assert!(((r[1] - r[0]) + omega).abs() < 1e-9 * omega);
}

#[test]
fn constant_speed_reference_slope_on_a_distorted_sensor() {
    let s = Sensor {
        ax: 1.1,
        ay: 0.95,
        ox: 0.02,
        oy: -0.015,
        phi_rad: 0.03,
        h3: 0.02,
    };
    // 10 whole revolutions.
    let n = 50_000;
    let omega = TAU * 10.0 / n as f64;
    let (samples, _) = s.spin(0.7, omega, n);
    let r = constant_speed_reference(&samples).unwrap();
    let omega_fit = (r[n - 1] - r[0]) / (n - 1) as f64;
    let rel = (omega_fit - omega).abs() / omega;
    assert!(rel < 1e-4, "relative slope error {rel}");
}

#[test]
fn lut_on_a_constant_speed_reference_removes_most_of_the_error() {
    let s = Sensor {
        ax: 1.1,
        ay: 0.95,
        ox: 0.05,
        oy: -0.04,
        phi_rad: 0.05,
        h3: 0.02,
    };
    let n = 100_000;
    let (samples, _) = s.spin(0.7, TAU * 10.0 / n as f64, n);
    let reference = constant_speed_reference(&samples).unwrap();
    let lut = Lut::fit(&samples, &reference, 256).unwrap();
    // Up to a constant (the reference's θ0 is the raw sensor's, not the rotor's).
    let lut_pp = pk_pk(&errors(&lut, &s));
    let raw_pp = pk_pk(&errors(&Raw, &s));
    assert!(
        lut_pp < 2e-3 && lut_pp < raw_pp / 20.0,
        "{lut_pp} vs raw {raw_pp}"
    );
}

#[test]
fn non_finite_input_gives_nan_without_panic() {
    let s = Sensor {
        ox: 0.1,
        ..THIRD_HARMONIC
    };
    let (samples, reference) = s.spin(0.0, TAU / 1000.3, 3000);
    let correctors: Vec<Box<dyn Corrector>> = vec![
        Box::new(Raw),
        Box::new(MinMax::fit(&samples).unwrap()),
        Box::new(Ellipse::fit(&samples).unwrap()),
        Box::new(Lut::fit(&samples, &reference, 128).unwrap()),
    ];
    for c in &correctors {
        for (x, y) in [
            (f32::NAN, 0.5),
            (0.5, f32::INFINITY),
            (f32::NEG_INFINITY, f32::NAN),
        ] {
            let _ = c.angle_rad(x, y);
        }
        assert!(c.angle_rad(f32::NAN, 1.0).is_nan(), "{}", c.name());
        // Extreme but finite values stay in range.
        let a = c.angle_rad(f32::MAX, -f32::MAX);
        assert!(a.is_nan() || (a > -PI && a <= PI), "{} gave {a}", c.name());
    }
}

#[test]
fn fit_errors() {
    let s = Sensor {
        ox: 0.1,
        ..THIRD_HARMONIC
    };
    let (mut samples, mut reference) = s.spin(0.0, TAU / 1000.3, 3000);

    // Too few samples.
    assert_eq!(
        MinMax::fit(&samples[..15]),
        Err(FitError::TooFewSamples {
            needed: 16,
            got: 15
        })
    );
    assert_eq!(
        Ellipse::fit(&samples[..4]),
        Err(FitError::TooFewSamples { needed: 5, got: 4 })
    );
    assert_eq!(
        Lut::fit(&samples[..200], &reference[..200], 256),
        Err(FitError::TooFewSamples {
            needed: 256,
            got: 200
        })
    );
    assert!(matches!(
        constant_speed_reference(&samples[..3]),
        Err(FitError::TooFewSamples { .. })
    ));

    // Bad bin counts.
    for bins in [0, 127, 4097, 10_000] {
        assert_eq!(
            Lut::fit(&samples, &reference, bins),
            Err(FitError::BadBins(bins))
        );
    }

    // Length mismatch.
    assert!(matches!(
        Lut::fit(&samples, &reference[1..], 256),
        Err(FitError::Degenerate(_))
    ));

    // A bin never visited: half a revolution only.
    let (half, half_ref) = s.spin(0.0, PI / 3000.0, 3000);
    match Lut::fit(&half, &half_ref, 256) {
        Err(FitError::IncompleteCoverage { empty_bins }) => {
            assert!((120..=136).contains(&empty_bins), "{empty_bins}")
        }
        other => panic!("{other:?}"),
    }

    // All-equal samples.
    let same = vec![(0.3f32, -0.2f32); 200];
    let same_ref = vec![0.0; 200];
    assert!(matches!(MinMax::fit(&same), Err(FitError::Degenerate(_))));
    assert!(matches!(Ellipse::fit(&same), Err(FitError::Degenerate(_))));
    assert!(matches!(
        constant_speed_reference(&same),
        Err(FitError::Degenerate(_))
    ));
    assert!(matches!(
        Lut::fit(&same, &same_ref, 128),
        Err(FitError::IncompleteCoverage { empty_bins: 127 })
    ));

    // Not an ellipse: collinear points, and points on a hyperbola x² - y² = 1.
    let line: Vec<(f32, f32)> = (0..50).map(|i| (i as f32, 2.0 * i as f32 + 1.0)).collect();
    assert!(matches!(Ellipse::fit(&line), Err(FitError::Degenerate(_))));
    let hyperbola: Vec<(f32, f32)> = (0..50)
        .map(|i| {
            let t = (i as f64 - 25.0) / 10.0;
            let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
            ((sign * t.cosh()) as f32, t.sinh() as f32)
        })
        .collect();
    assert!(matches!(
        Ellipse::fit(&hyperbola),
        Err(FitError::Degenerate(_))
    ));

    // A NaN sample names its index, in the error and in its message.
    samples[7].1 = f32::NAN;
    let want = Err(FitError::NonFinite { index: 7 });
    assert_eq!(MinMax::fit(&samples).map(|_| ()), want);
    assert_eq!(Ellipse::fit(&samples).map(|_| ()), want);
    assert_eq!(Lut::fit(&samples, &reference, 256).map(|_| ()), want);
    assert_eq!(constant_speed_reference(&samples).map(|_| ()), want);
    let msg = MinMax::fit(&samples).unwrap_err().to_string();
    assert!(msg.contains("sample 7") && msg.contains("NaN"), "{msg}");
    samples[7].1 = 0.0;
    reference[11] = f64::INFINITY;
    assert_eq!(
        Lut::fit(&samples, &reference, 256).map(|_| ()),
        Err(FitError::NonFinite { index: 11 })
    );

    // Every error has a message.
    for e in [
        FitError::Degenerate("why"),
        FitError::BadBins(3),
        FitError::IncompleteCoverage { empty_bins: 2 },
    ] {
        let m = e.to_string();
        assert!(!m.is_empty());
        let _: &dyn std::error::Error = &e;
    }
}

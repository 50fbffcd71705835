//! The error survey: with adaptation frozen, the spectrum of ε against θ̂s (the
//! observer's transfer undone) is the sensor's angle-error spectrum, and a bank given to
//! the harmonics it finds removes what the fixed default bank leaves.

use mras::survey::{allocate, path_for, ErrorSurvey, FIRST_STAGE, SURVEY_HARMONICS};
use mras::{Coefficients, Config, Cplx, PathKind, Tracker};
use mras_sim::wrap_pi;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::f64::consts::TAU;

const T_S: f64 = 50.0e-6;
const SPEED_REV_S: f64 = 5.0;

/// An N = 1 sensor whose angle error is exactly Σ e_m cos(m θ + φ_m): (m, e_m rad).
struct AngleError(Vec<(u8, f64, f64)>);

impl AngleError {
    fn rad(&self, theta_rad: f64) -> f64 {
        let terms = self.0.iter();
        terms
            .map(|&(m, e, phi)| e * (m as f64 * theta_rad + phi).cos())
            .sum()
    }

    fn vector(&self, theta_rad: f64) -> (f32, f32) {
        let a = theta_rad + self.rad(theta_rad);
        (a.cos() as f32, a.sin() as f32)
    }
}

/// Spread over the orders a fixed bank covers (m ≤ 7) and those it does not.
fn sensor() -> AngleError {
    AngleError(vec![
        (1, 4.0e-3, 0.3),
        (3, 2.0e-3, -1.0),
        (6, 0.8e-3, 2.0),
        (9, 1.5e-3, 0.7),
        (12, 1.0e-3, -2.5),
        (16, 0.6e-3, 1.2),
    ])
}

fn config(paths: Option<&[PathKind]>) -> Config {
    let mut c = Config {
        sensor_periods: 1,
        ..Config::default()
    };
    if let Some(p) = paths {
        c.set_paths(p).unwrap();
    }
    c
}

/// Drive `t` at constant speed from angle 0 for `revs`, with white angle noise of
/// `noise_rad` RMS; `each(estimate, θ)` per accepted sample.
fn spin(t: &mut Tracker, revs: f64, noise_rad: f64, mut each: impl FnMut(&mras::Estimate, f64)) {
    let s = sensor();
    let omega = TAU * SPEED_REV_S;
    let n = (revs / (SPEED_REV_S * T_S)).round() as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let normal = Normal::new(0.0, noise_rad.max(1e-300)).unwrap();
    for k in 0..n {
        let th = omega * k as f64 * T_S;
        let (x, y) = s.vector(
            th + if noise_rad > 0.0 {
                normal.sample(&mut rng)
            } else {
                0.0
            },
        );
        if let Ok(e) = t.step(x, y, 0.0) {
            each(&e, th);
        }
    }
}

fn survey(noise_rad: f64) -> (Tracker, ErrorSurvey) {
    let mut t = Tracker::new(config(None)).unwrap();
    t.set_frozen(true);
    let mut survey = ErrorSurvey::default();
    // One second settles the observer (its slowest pole, 1 Hz, to e^-6); then four
    // whole sensor periods.
    let mut k = 0;
    spin(&mut t, 10.0, noise_rad, |e, _| {
        k += 1;
        if k as f64 * T_S > 1.0 && survey.periods() < 4.0 {
            let (sin, cos) = mras::sin_cos_f32(e.theta_e_rad);
            survey.add(Cplx::new(cos, sin), e.epsilon_rad, e.omega_rad_s);
        }
    });
    (t, survey)
}

#[test]
fn the_survey_measures_the_sensors_angle_error_spectrum() {
    let (t, survey) = survey(0.0);
    assert!(
        (survey.periods() - 4.0).abs() < 1e-3,
        "{}",
        survey.periods()
    );
    let spec = survey.spectrum(t.gains()).expect("four periods at speed");
    let truth = sensor();
    for m in 1..=SURVEY_HARMONICS as u8 {
        let want = truth.0.iter().find(|h| h.0 == m).map_or(0.0, |h| h.1);
        let got = spec.amplitude_rad[m as usize - 1] as f64;
        eprintln!(
            "m = {m:2}: {:7.1} µrad (true {:7.1}), floor {:.2} µrad",
            got * 1e6,
            want * 1e6,
            spec.floor_rad * 1e6
        );
        // Beside a large harmonic, a small one: θ̂s, the DFT's angle, carries the part of
        // the error the observer follows (mostly m = 1), which modulates its neighbours.
        assert!(
            (got - want).abs() < 0.03 * want + 30e-6,
            "m = {m}: {:.1} µrad measured, {:.1} µrad true",
            got * 1e6,
            want * 1e6
        );
    }
}

#[test]
fn the_noise_floor_separates_the_harmonics_from_the_noise() {
    let (t, survey) = survey(2.0e-3);
    let spec = survey.spectrum(t.gains()).unwrap();
    let truth = sensor();
    for m in 1..=SURVEY_HARMONICS as u8 {
        let (a, floor) = (spec.amplitude_rad[m as usize - 1], spec.floor_rad);
        let present = truth.0.iter().any(|h| h.0 == m);
        eprintln!(
            "m = {m:2}: {:7.1} µrad, floor {:5.1} µrad",
            a * 1e6,
            floor * 1e6
        );
        assert!(
            floor > 0.0 && (a > floor) == present,
            "m = {m}: {a} against {floor}"
        );
    }
    let chosen = allocate(&spec, 8, 0.0);
    let want: Vec<PathKind> = [1, 3, 6, 9, 12, 16].map(|m| path_for(m).unwrap()).into();
    assert_eq!(chosen.paths.as_slice(), want.as_slice());
}

#[test]
fn the_bank_goes_to_the_largest_harmonics_and_names_what_it_left() {
    let (t, survey) = survey(0.0);
    let spec = survey.spectrum(t.gains()).unwrap();
    let all = allocate(&spec, 8, 50e-6);
    let want: Vec<PathKind> = [1, 3, 6, 9, 12, 16].map(|m| path_for(m).unwrap()).into();
    assert_eq!(all.paths.as_slice(), want.as_slice());
    assert!(all.unobserved.is_empty());
    // A bank of three: m = 1, 3 and 9 (4, 2 and 1.5 mrad); 12, 6 and 16 left.
    let three = allocate(&spec, 3, 50e-6);
    let want: Vec<PathKind> = [1, 3, 9].map(|m| path_for(m).unwrap()).into();
    assert_eq!(three.paths.as_slice(), want.as_slice());
    assert_eq!(three.unobserved.as_slice(), &[6, 12, 16]);
    // Every chosen bank is one the core accepts.
    config(Some(&all.paths)).validate().unwrap();
}

#[test]
fn every_harmonic_has_a_path_the_core_accepts() {
    for m in 1..=SURVEY_HARMONICS as u8 {
        let k = path_for(m).unwrap();
        assert_eq!(k.error_harmonic(), m);
        config(Some(&[k])).validate().unwrap();
    }
    assert_eq!(path_for(0), None);
    assert_eq!(path_for(17), None);
}

/// Error of θ̂ against the true angle over the last revolution of `revs`, pk-pk (rad).
fn residual_pk_pk_rad(paths: &[PathKind], revs: f64) -> f64 {
    let mut t = Tracker::new(config(Some(paths))).unwrap();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let last_from = ((revs - 1.0) / (SPEED_REV_S * T_S)) as u64;
    let mut k = 0;
    // θ̂ carries the constant lag of the observer; pk-pk removes it.
    spin(&mut t, revs, 0.0, |e, th| {
        k += 1;
        if k > last_from {
            let d = wrap_pi(e.theta_unwrapped_rad() - th);
            (lo, hi) = (lo.min(d), hi.max(d));
        }
    });
    hi - lo
}

#[test]
fn a_bank_from_the_data_removes_what_the_default_bank_leaves() {
    let (t, survey) = survey(0.0);
    let chosen = allocate(&survey.spectrum(t.gains()).unwrap(), 8, 50e-6);
    let default = *Config::default().paths().last().unwrap();
    assert_eq!(
        default,
        PathKind::Harmonic(8),
        "the default bank ends at m = 7"
    );
    let raw = {
        let s = sensor();
        let e: Vec<f64> = (0..3600).map(|i| s.rad(TAU * i as f64 / 3600.0)).collect();
        e.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - e.iter().cloned().fold(f64::INFINITY, f64::min)
    };
    let fixed = residual_pk_pk_rad(Config::default().paths(), 20.0);
    let from_data = residual_pk_pk_rad(&chosen.paths, 20.0);
    eprintln!(
        "raw {:.2} mrad pk-pk; default bank {:.3} mrad; bank from the data {:.3} mrad",
        raw * 1e3,
        fixed * 1e3,
        from_data * 1e3
    );
    // The default bank cannot touch m = 9, 12, 16 (3.1 mrad of amplitude).
    assert!(fixed > 0.3 * raw, "{fixed} of {raw}");
    assert!(from_data < raw / 30.0, "{from_data} of {raw}");
}

/// The core choosing its bank by itself (`paths_from_data`): offset and C/D adapt, the
/// survey finds m = 3, 6, 9, 12, 16, the bank grows in place (the front follows through
/// the update queue) and the whole error goes.
/// A core choosing its bank from the data, `revs` revolutions of sensor `s` at constant
/// speed: the core, the revolution at which the bank was complete, and the residual
/// pk-pk (rad) over the last revolution.
fn choose_bank(s: &AngleError, revs: f64) -> (Tracker, Option<f64>, f64) {
    let mut cfg = config(Some(&FIRST_STAGE));
    cfg.paths_from_data = true;
    let mut t = Tracker::new(cfg).unwrap();
    let omega = TAU * SPEED_REV_S;
    let n = (revs / (SPEED_REV_S * T_S)).round() as u64;
    let last_from = ((revs - 1.0) / (SPEED_REV_S * T_S)) as u64;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut chosen_at_rev = None;
    for k in 0..n {
        let th = omega * k as f64 * T_S;
        let (x, y) = s.vector(th);
        let e = t.step(x, y, 0.0).unwrap();
        let surveying = t.adapter().surveying();
        assert!(
            !(surveying && t.convergence().converged),
            "converged before the bank was complete"
        );
        if !surveying && chosen_at_rev.is_none() {
            chosen_at_rev = Some(th / TAU);
        }
        if k > last_from {
            let d = wrap_pi(e.theta_unwrapped_rad() - th);
            (lo, hi) = (lo.min(d), hi.max(d));
        }
    }
    (t, chosen_at_rev, hi - lo)
}

#[test]
fn a_core_with_paths_from_data_chooses_its_bank_and_nulls_the_error() {
    let (t, chosen_at_rev, pk_pk_rad) = choose_bank(&sensor(), 30.0);
    let o = t.adapter().survey().expect("the survey completed");
    let want: Vec<PathKind> = [1, 2, 3, 6, 9, 12, 16].map(|m| path_for(m).unwrap()).into();
    assert_eq!(o.bank.as_slice(), want.as_slice());
    assert_eq!(
        t.config().paths(),
        FIRST_STAGE,
        "the front's configuration is as given"
    );
    assert_eq!(t.adapter().config().paths(), want.as_slice());
    assert!(o.unobserved.is_empty());
    assert!(t.convergence().converged);
    eprintln!(
        "bank chosen at revolution {:.1}; residual {:.3} mrad pk-pk",
        chosen_at_rev.unwrap(),
        pk_pk_rad * 1e3
    );
    assert!(pk_pk_rad < 0.2e-3, "{} mrad", pk_pk_rad * 1e3);
}

/// More than 8 paths: a bank grows to one for each of 12 harmonics, and its last round's
/// survey still ends (it ends on a sample without a path's update, which a bank of more
/// than 8 paths once never had) and the bank converges.
#[test]
fn a_bank_of_more_than_eight_paths_completes_and_converges() {
    let harmonics = [1, 3, 4, 5, 6, 7, 8, 9, 11, 13, 14, 16];
    let s = AngleError(
        harmonics
            .iter()
            .enumerate()
            .map(|(i, &m)| (m, 1.5e-3 - 0.05e-3 * i as f64, 0.7 * i as f64))
            .collect(),
    );
    let (t, chosen_at_rev, pk_pk_rad) = choose_bank(&s, 60.0);
    let o = t.adapter().survey().expect("the survey completed");
    eprintln!(
        "{} rounds, bank {:?} complete at revolution {chosen_at_rev:?}; residual {:.3} mrad pk-pk",
        o.rounds,
        o.bank.as_slice(),
        pk_pk_rad * 1e3
    );
    assert!(!t.adapter().surveying(), "the bank is complete");
    let want: Vec<PathKind> = harmonics.map(|m| path_for(m).unwrap()).into();
    let mut got: Vec<PathKind> = o.bank.as_slice().into();
    got.sort_by_key(|k| k.error_harmonic());
    let mut want_sorted = want.clone();
    want_sorted.push(PathKind::AmplitudeQuadrature);
    want_sorted.sort_by_key(|k| k.error_harmonic());
    assert_eq!(got, want_sorted);
    assert!(o.unobserved.is_empty());
    assert!(t.convergence().converged);
    assert!(pk_pk_rad < 0.2e-3, "{} mrad", pk_pk_rad * 1e3);
}

/// A record's bank from the data is taken (it starts with the first stage); another
/// bank is refused, and so is any bank other than the configured one with a fixed bank.
#[test]
fn coefficients_of_a_bank_from_the_data_are_installed_with_their_bank() {
    let mut cfg = config(Some(&FIRST_STAGE));
    cfg.paths_from_data = true;
    let bank = [1, 2, 3, 9, 16].map(|m| path_for(m).unwrap());
    let mut c = Coefficients::zeros(&bank);
    c.set(path_for(9).unwrap(), Cplx::new(1e-3, -2e-3));
    let mut t = Tracker::new(cfg).unwrap();
    t.set_coefficients(&c).unwrap();
    assert_eq!(t.adapter().config().paths(), bank);
    assert!(!t.adapter().surveying());
    assert_eq!(t.coefficients(), c);
    let wrong_start = Coefficients::zeros(&[PathKind::Offset, PathKind::Harmonic(4)]);
    assert_eq!(
        Tracker::new(cfg).unwrap().set_coefficients(&wrong_start),
        Err(mras::CoefficientsError::PathMismatch)
    );
    let fixed = config(Some(&FIRST_STAGE));
    assert_eq!(
        Tracker::new(fixed).unwrap().set_coefficients(&c),
        Err(mras::CoefficientsError::PathMismatch)
    );
}

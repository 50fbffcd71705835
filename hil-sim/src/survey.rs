//! `replay --paths-from-data`: the survey pass (the core with adaptation frozen over the
//! start of the recording) and the bank it gives to the harmonics that carry error
//! (`mras::survey`, docs/theory.md section 8).

use crate::front_end::FrontEnd;
use anyhow::{bail, Result};
use mras::survey::{allocate, ErrorSurvey};
use mras::{Config, PathKind, Tracker, MAX_PATHS};
use serde::Serialize;
use std::f64::consts::TAU;

/// Whole sensor periods the survey covers.
pub const SURVEY_PERIODS: f32 = 4.0;
/// Harmonics under this share of the largest get no path: what the observer follows of
/// the largest phase-modulates its neighbours, by about 1 % of it (docs/theory.md).
const MIN_SHARE: f32 = 0.01;
/// Time constants of the slowest observer pole between the lock and the survey.
const SETTLE_TIME_CONSTANTS: f64 = 5.0;

/// The recording, column by column, as replay holds it (`torque_nm` may be empty).
pub struct Samples<'a> {
    pub t_s: &'a [f64],
    pub x: &'a [f32],
    pub y: &'a [f32],
    pub torque_nm: &'a [f32],
}

#[derive(Clone, Debug, Serialize)]
pub struct SurveyReport {
    /// Where the survey began (t_s, after the offset and C/D paths converged) and the
    /// sensor periods it covered.
    pub from_t_s: f64,
    pub periods: f32,
    /// The angle error per harmonic m = 1..16 of θs left after the offset and C/D paths,
    /// mechanical (electrical / N).
    pub error_mrad: Vec<f64>,
    /// The noise floor and the share-of-the-largest floor a harmonic must clear.
    pub floor_mrad: f64,
    pub min_mrad: f64,
    /// The bank, in order of m, as `paths` in a --config file names them.
    pub paths: Vec<String>,
    /// Harmonics m above both floors that the bank (at most 8 paths) has no room for.
    pub unobserved: Vec<u8>,
    #[serde(skip)]
    pub kinds: Vec<PathKind>,
}

/// Every sensor has an offset and an amplitude/quadrature error, and at the size they
/// come in they put error into every harmonic of the angle (products of the two): the
/// bank always holds their paths, adapted first, and the survey measures what remains.
const ALWAYS: [PathKind; 2] = [PathKind::Offset, PathKind::AmplitudeQuadrature];
/// Mechanical revolutions the first stage may adapt before the survey starts anyway.
const FIRST_STAGE_MAX_REVS: u32 = 20;

/// Survey `s` through `front` with `cfg`'s observer: offset and C/D adapted until they
/// converge, then frozen while the rest of the error spectrum is measured.
pub fn survey(cfg: &Config, front: &FrontEnd, s: &Samples) -> Result<SurveyReport> {
    let mut first = *cfg;
    first.set_paths(&ALWAYS)?;
    let mut tracker = Tracker::new(first)?;
    let slowest_hz = cfg
        .observer
        .eigenvalues_hz
        .iter()
        .fold(f32::INFINITY, |a, &b| a.min(b));
    let settle_s = SETTLE_TIME_CONSTANTS / (TAU * slowest_hz as f64);
    let n = cfg.sensor_periods as f32;
    let mut survey = ErrorSurvey::default();
    let (mut locked_since_s, mut from_t_s) = (None, None);
    for (k, &t_s) in s.t_s.iter().enumerate() {
        let torque_nm = s.torque_nm.get(k).copied().unwrap_or(0.0);
        let estimate = match front.scale(s.x[k], s.y[k]) {
            Ok((x, y)) => tracker.step(x, y, torque_nm),
            Err(f) => Err(tracker.refuse(f)),
        };
        // A refused sample or a lost lock restarts the survey: whole periods of one
        // settled lock only.
        let (Ok(e), true) = (estimate, tracker.is_locked()) else {
            (locked_since_s, from_t_s) = (None, None);
            survey = ErrorSurvey::default();
            continue;
        };
        if t_s - *locked_since_s.get_or_insert(t_s) < settle_s {
            continue;
        }
        let c = tracker.convergence();
        if !tracker.is_frozen() {
            if c.converged || c.revs_adapted >= FIRST_STAGE_MAX_REVS {
                tracker.set_frozen(true);
            }
            continue;
        }
        let from_t_s = *from_t_s.get_or_insert(t_s);
        survey.add(e.theta_e_rad, e.epsilon_rad, n * e.omega_rad_s);
        if survey.periods() >= SURVEY_PERIODS {
            return Ok(report(&survey, &tracker, from_t_s, cfg.sensor_periods));
        }
    }
    bail!(
        "the survey for --paths-from-data needs {SURVEY_PERIODS} whole sensor periods of a \
         settled lock ({settle_s:.2} s after the observer locks, at a speed the core tracks); \
         the recording gives {:.2}: give `paths` in a --config file instead",
        survey.periods()
    )
}

fn report(survey: &ErrorSurvey, tracker: &Tracker, from_t_s: f64, n: u16) -> SurveyReport {
    // `report` is reached only once the survey holds whole periods at speed.
    let spec = survey
        .spectrum(tracker.gains())
        .unwrap_or(mras::survey::ErrorSpectrum {
            amplitude_rad: [0.0; mras::survey::SURVEY_HARMONICS],
            floor_rad: f32::INFINITY,
            periods: 0.0,
        });
    let largest = spec.amplitude_rad.iter().fold(0.0f32, |a, &b| a.max(b));
    let min_rad = MIN_SHARE * largest;
    // m = 1, 2 are the first stage's; the rest of the bank goes to m ≥ 3.
    let mut rest = spec;
    rest.amplitude_rad[..ALWAYS.len()].fill(0.0);
    let bank = allocate(&rest, MAX_PATHS - ALWAYS.len(), min_rad);
    let mech_mrad = |rad: f32| rad as f64 * 1e3 / n as f64;
    let kinds: Vec<PathKind> = ALWAYS.iter().chain(&bank.paths).copied().collect();
    SurveyReport {
        from_t_s,
        periods: spec.periods,
        error_mrad: spec.amplitude_rad.iter().map(|&a| mech_mrad(a)).collect(),
        floor_mrad: mech_mrad(spec.floor_rad),
        min_mrad: mech_mrad(min_rad),
        paths: kinds
            .iter()
            .map(|&k| crate::replay::path_toml_name(k))
            .collect(),
        unobserved: bank.unobserved.to_vec(),
        kinds,
    }
}

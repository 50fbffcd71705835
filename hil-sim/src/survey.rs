//! `replay`'s bank from the data (its default, `--bank data`): a first pass over the
//! recording with the core choosing its bank from the data (`mras::Config::paths_from_data`, `mras::survey`,
//! docs/theory.md section 8), the same code the firmware's commissioning runs; replay
//! then runs the whole recording with that bank.

use crate::front_end::FrontEnd;
use anyhow::{bail, Result};
use mras::survey::{SurveyOutcome, FIRST_STAGE, SURVEY_PERIODS};
use mras::{Config, PathKind, Tracker};
use serde::Serialize;

/// The recording, column by column, as replay holds it (`torque_nm` may be empty).
pub struct Samples<'a> {
    pub t_s: &'a [f64],
    pub x: &'a [f32],
    pub y: &'a [f32],
    pub torque_nm: &'a [f32],
}

#[derive(Clone, Debug, Serialize)]
pub struct SurveyReport {
    /// Where the survey ended (t_s: the offset and C/D paths had converged before it)
    /// and the sensor periods it covered.
    pub until_t_s: f64,
    pub periods: f32,
    /// The angle error per harmonic m = 1..16 of θs left after the offset and C/D paths,
    /// mechanical (electrical / N).
    pub error_mrad: Vec<f64>,
    /// The noise floor and the share-of-the-largest floor a harmonic must clear.
    pub floor_mrad: f64,
    pub min_mrad: f64,
    /// The bank, in order of m, as `paths` in a --config file names them.
    pub paths: Vec<String>,
    /// Harmonics m above both floors that the bank (at most 16 paths) has no room for.
    pub unobserved: Vec<u8>,
    /// Survey rounds, and whether the last one completed the bank (false: the recording
    /// ended while the grown bank was still adapting; the bank is the last round's).
    pub rounds: u8,
    pub complete: bool,
    #[serde(skip)]
    pub kinds: Vec<PathKind>,
}

/// Run `s` through `front` and the core with `cfg`'s observer choosing its bank from the
/// data, until the bank is complete.
pub fn survey(cfg: &Config, front: &FrontEnd, s: &Samples) -> Result<SurveyReport> {
    let mut first = *cfg;
    first.set_paths(&FIRST_STAGE)?;
    first.paths_from_data = true;
    let mut tracker = Tracker::new(first)?;
    for (k, &t_s) in s.t_s.iter().enumerate() {
        let torque_nm = s.torque_nm.get(k).copied().unwrap_or(0.0);
        // Faults are the core's to handle: a refused sample or a lost lock restarts
        // the survey (whole periods of one lock only).
        let _ = match front.scale(s.x[k], s.y[k]) {
            Ok((x, y)) => tracker.step(x, y, torque_nm),
            Err(f) => Err(tracker.refuse(f)),
        };
        if let (false, Some(o)) = (tracker.adapter().surveying(), tracker.adapter().survey()) {
            return Ok(report(o, t_s, cfg.sensor_periods));
        }
    }
    // The recording ended between rounds: the bank as the last round left it.
    if let Some(o) = tracker.adapter().survey() {
        let end_s = s.t_s.last().copied().unwrap_or(0.0);
        let mut r = report(o, end_s, cfg.sensor_periods);
        r.complete = false;
        return Ok(r);
    }
    bail!(
        "the bank from the data: the first survey did not complete. It needs the offset and C/D \
         paths to converge (at most {} revolutions at a speed the core adapts at), then \
         {SURVEY_PERIODS} whole sensor periods of one lock: give `paths` in a --config file \
         or --bank default instead",
        mras::survey::FIRST_STAGE_MAX_REVS
    )
}

fn report(o: &SurveyOutcome, until_t_s: f64, n: u16) -> SurveyReport {
    let mech_mrad = |rad: f32| rad as f64 * 1e3 / n as f64;
    let kinds = o.bank.as_slice().to_vec();
    SurveyReport {
        until_t_s,
        periods: o.spectrum.periods,
        error_mrad: o
            .spectrum
            .amplitude_rad
            .iter()
            .map(|&a| mech_mrad(a))
            .collect(),
        floor_mrad: mech_mrad(o.spectrum.floor_rad),
        min_mrad: mech_mrad(o.min_rad),
        paths: kinds
            .iter()
            .map(|&k| crate::replay::path_toml_name(k))
            .collect(),
        unobserved: o.unobserved.to_vec(),
        rounds: o.rounds,
        complete: true,
        kinds,
    }
}

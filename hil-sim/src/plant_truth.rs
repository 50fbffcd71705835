//! Measures taken at the plant, never from what the drive reports: the electrical angle
//! of the current the bridge really drives against the rotor's q axis, the torque per
//! amp, and a streamed angle estimate scored against the rotor at the records' periods.
//! hil-sim's rig and the emulator (which runs the release firmware) feed the same
//! functions, so a figure means the same thing in both.

use crate::exact::wrap_pi;
use crate::plant::{MotorParams, Truth};
use crate::scenario::Probe;
use mras_sim::SpatialError;
use nalgebra::{DMatrix, DVector};
use std::f64::consts::TAU;

/// The plant at one control period's sampling instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeriodTruth {
    pub truth: Truth,
    /// The true phase currents (αβ, A) at the instant.
    pub i_ab: [f64; 2],
    /// The mean electrical torque of the period that ended at the instant (N·m).
    pub torque_nm: f64,
    /// The duties the bridge applied in that period (None: bridge off).
    pub duties: Option<[f32; 3]>,
}

/// The current vector the bridge drives against the true rotor's q axis, over the
/// periods added: the mean angle error (sin/cos sums, as hil-sim's power-up averages
/// the control's angle error), its spatial pk-pk over the rotor angle (bin means, so
/// a correction that moves the angle with the rotor shows even when its mean is zero),
/// and the torque per amp.
#[derive(Clone, Debug)]
pub struct CurrentVector {
    pole_pairs: f64,
    torque_constant_nm_a: f64,
    err_sin: f64,
    err_cos: f64,
    torque_sum_nm: f64,
    amps_sum: f64,
    periods: u64,
    by_angle: SpatialError<360>,
}

/// What [`CurrentVector`] measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentVectorStats {
    pub periods: u64,
    /// Mean electrical angle of the current from the q axis it pushes along (the +q
    /// axis for positive torque, -q for negative): 0 when the drive's electrical angle
    /// is right.
    pub angle_error_e_rad: f64,
    /// The same error averaged by rotor angle (360 bins), pk-pk.
    pub angle_error_e_pk_pk_rad: f64,
    /// |mean torque| / mean |i| / Kt: 1 when all of the current is on the q axis.
    pub torque_per_amp: f64,
    pub mean_current_a: f64,
}

impl CurrentVector {
    pub fn new(motor: &MotorParams) -> Self {
        Self {
            pole_pairs: motor.pole_pairs as f64,
            torque_constant_nm_a: motor.torque_constant_nm_a(),
            err_sin: 0.0,
            err_cos: 0.0,
            torque_sum_nm: 0.0,
            amps_sum: 0.0,
            periods: 0,
            by_angle: SpatialError::new(),
        }
    }

    /// One period: the rotor's mechanical angle, the phase currents and the torque.
    /// A period with no current (bridge off) has no angle and is left out.
    pub fn add(&mut self, theta_rad: f64, i_ab: [f64; 2], torque_nm: f64) {
        let amps = i_ab[0].hypot(i_ab[1]);
        let usable = amps > 0.0 && theta_rad.is_finite() && torque_nm.is_finite();
        if !usable {
            return;
        }
        let (s, c) = (self.pole_pairs * theta_rad).sin_cos();
        let id = i_ab[0] * c + i_ab[1] * s;
        let iq = -i_ab[0] * s + i_ab[1] * c;
        // From the q axis the current pushes along, positive towards -d (lagging).
        let dir = if iq < 0.0 { -1.0 } else { 1.0 };
        let e = (-id * dir).atan2(iq * dir);
        self.err_sin += e.sin();
        self.err_cos += e.cos();
        self.by_angle.add(theta_rad, e);
        self.torque_sum_nm += torque_nm;
        self.amps_sum += amps;
        self.periods += 1;
    }

    pub fn add_period(&mut self, p: &PeriodTruth) {
        self.add(p.truth.theta_rad, p.i_ab, p.torque_nm);
    }

    /// None before any period with current.
    pub fn stats(&self) -> Option<CurrentVectorStats> {
        (self.periods > 0).then(|| CurrentVectorStats {
            periods: self.periods,
            angle_error_e_rad: self.err_sin.atan2(self.err_cos),
            angle_error_e_pk_pk_rad: self.by_angle.pk_pk_rad(),
            torque_per_amp: self.torque_sum_nm.abs() / self.amps_sum / self.torque_constant_nm_a,
            mean_current_a: self.amps_sum / self.periods as f64,
        })
    }
}

/// The raw sensor's angle error against the rotor over `periods` (mechanical, within
/// ±π/N), averaged by rotor angle (360 bins, the constant offset removed), pk-pk: what
/// the sensor would cost uncorrected, measured the way hil-sim's windows do.
pub fn raw_error_pk_pk_rad(periods: &[PeriodTruth], probe: &Probe) -> f64 {
    let mut e = SpatialError::<360>::new();
    for p in periods {
        let t = &p.truth;
        e.add(t.theta_rad, probe.raw_error_rad(t.theta_rad, t.x, t.y));
    }
    e.pk_pk_rad()
}

/// Why a series of streamed estimates could not be scored.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ScoreError {
    #[error("record at t_ms = {t_ms} is not at a control period (t_ms·PWM/1000 = {ticks} is not whole): records come at the supervisor's divider ticks")]
    NotATick { t_ms: u32, ticks: f64 },
    #[error("record at t_ms = {t_ms} (control period {tick}) is outside the truth log (periods 1..={len})")]
    OutsideLog { t_ms: u32, tick: u64, len: usize },
    #[error("{records} records cannot fit {harmonics} harmonics (need at least {need})")]
    TooFew {
        records: usize,
        harmonics: u32,
        need: usize,
    },
    #[error("the records' rotor angles do not cover the revolution well enough to fit {harmonics} harmonics (condition {condition:.1e}): run longer or at a speed incommensurate with the record rate")]
    Coverage { harmonics: u32, condition: f64 },
    #[error("estimate at t_ms = {t_ms} is not finite")]
    NotFinite { t_ms: u32 },
}

/// Streamed estimates against the rotor: the raw sensor's error and the estimate's,
/// each as a spatial error over the rotor's angle (mechanical rad, within ±π/N, the
/// constant offset removed), from the same periods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimateScore {
    pub records: usize,
    pub harmonics: u32,
    /// pk-pk of the fitted spatial error (harmonics 1..=`harmonics` of the rotor angle).
    pub raw_pk_pk_rad: f64,
    pub estimate_pk_pk_rad: f64,
    /// What the fit leaves (noise, and error that is not a function of the angle).
    pub raw_residual_rms_rad: f64,
    pub estimate_residual_rms_rad: f64,
    /// The constant estimate-minus-rotor offset removed (within ±π/N).
    pub estimate_offset_rad: f64,
}

/// A spatial error fitted by harmonics of the rotor angle: (pk-pk, residual rms).
fn fit_spatial(thetas: &[f64], errors: &[f64], harmonics: u32) -> Result<(f64, f64), ScoreError> {
    let (pk_pk, rms, _) = fit_spatial_harmonics(thetas, errors, harmonics)?;
    Ok((pk_pk, rms))
}

/// [`fit_spatial`] with the amplitude of each fitted harmonic 1..=`harmonics` (rad).
fn fit_spatial_harmonics(
    thetas: &[f64],
    errors: &[f64],
    harmonics: u32,
) -> Result<(f64, f64, Vec<f64>), ScoreError> {
    let cols = 1 + 2 * harmonics as usize;
    let a = DMatrix::from_fn(thetas.len(), cols, |r, c| {
        if c == 0 {
            1.0
        } else {
            let m = c.div_ceil(2) as f64;
            if c % 2 == 1 {
                (m * thetas[r]).cos()
            } else {
                (m * thetas[r]).sin()
            }
        }
    });
    let b = DVector::from_column_slice(errors);
    let svd = a.clone().svd(true, true);
    let (hi, lo) = svd
        .singular_values
        .iter()
        .fold((0.0f64, f64::INFINITY), |(h, l), &s| (h.max(s), l.min(s)));
    // Angles bunched in a few places leave some harmonics unseen: refuse rather than
    // publish a fit of noise.
    let condition = if hi > 0.0 { lo / hi } else { 0.0 };
    if condition < 1e-3 {
        return Err(ScoreError::Coverage {
            harmonics,
            condition,
        });
    }
    let x = svd.solve(&b, 0.0).map_err(|_| ScoreError::Coverage {
        harmonics,
        condition,
    })?;
    let residual = &b - &a * &x;
    let rms = (residual.norm_squared() / thetas.len() as f64).sqrt();
    const GRID: usize = 4096;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for g in 0..GRID {
        let th = TAU * g as f64 / GRID as f64;
        let v: f64 = (1..=harmonics)
            .map(|m| {
                let k = 2 * m as usize;
                x[k - 1] * (m as f64 * th).cos() + x[k] * (m as f64 * th).sin()
            })
            .sum();
        lo = lo.min(v);
        hi = hi.max(v);
    }
    let amplitudes = (1..=harmonics as usize)
        .map(|m| x[2 * m - 1].hypot(x[2 * m]))
        .collect();
    Ok((hi - lo, rms, amplitudes))
}

/// Within ±π/N, with the constant offset (circular mean over N periods) removed.
fn centred(errors: &mut [f64], n: f64) -> f64 {
    let (s, c) = errors.iter().fold((0.0, 0.0), |(s, c), e| {
        let (se, ce) = (n * e).sin_cos();
        (s + se, c + ce)
    });
    let offset = s.atan2(c) / n;
    for e in errors.iter_mut() {
        *e = wrap_pi(n * (*e - offset)) / n;
    }
    offset
}

/// Score streamed `(t_ms, θ̂)` records (θ̂ mechanical, in the motor's frame: it turns
/// with the rotor, at any constant offset) against `log`, the plant's truth per control
/// period (`log[k - 1]` for period k, counted from 1 like the firmware's `ticks`, whose
/// `t_ms` is `ticks·1000/PWM`).
///
/// Records come every 11 ms, a few per revolution: binning them by angle would publish
/// the noise of nearly empty bins. The error is fitted instead by harmonics
/// 1..=`harmonics` of the rotor angle (least squares), whose pk-pk is reported with
/// what the fit leaves; the raw sensor's error at the same periods gets the same fit.
pub fn score_estimates(
    log: &[PeriodTruth],
    pwm_hz: f64,
    probe: &Probe,
    records: &[(u32, f32)],
    harmonics: u32,
) -> Result<EstimateScore, ScoreError> {
    let (thetas, raw, est, estimate_offset_rad) =
        errors_at_records(log, pwm_hz, probe, records, harmonics)?;
    let (raw_pk_pk_rad, raw_residual_rms_rad) = fit_spatial(&thetas, &raw, harmonics)?;
    let (estimate_pk_pk_rad, estimate_residual_rms_rad) = fit_spatial(&thetas, &est, harmonics)?;
    Ok(EstimateScore {
        records: records.len(),
        harmonics,
        raw_pk_pk_rad,
        estimate_pk_pk_rad,
        raw_residual_rms_rad,
        estimate_residual_rms_rad,
        estimate_offset_rad,
    })
}

/// [`score_estimates`] by harmonic: the amplitude (rad, mechanical) of each harmonic
/// m = 1..=`harmonics` of the rotor angle in the same fit, for the raw sensor's error
/// (`.0`) and the estimate's (`.1`), index m - 1. With N = 1 a torque ripple fixed to
/// the shaft moves the rotor at the same m as the sensor's error harmonics: m = 1, 2
/// are where the ripple is, m = 3.. where only the sensor's error is.
pub fn estimate_harmonics_rad(
    log: &[PeriodTruth],
    pwm_hz: f64,
    probe: &Probe,
    records: &[(u32, f32)],
    harmonics: u32,
) -> Result<(Vec<f64>, Vec<f64>), ScoreError> {
    let (thetas, raw, est, _) = errors_at_records(log, pwm_hz, probe, records, harmonics)?;
    let (_, _, raw_h) = fit_spatial_harmonics(&thetas, &raw, harmonics)?;
    let (_, _, est_h) = fit_spatial_harmonics(&thetas, &est, harmonics)?;
    Ok((raw_h, est_h))
}

/// The rotor's motion over `periods`: its true angle less a constant-speed fit, binned
/// over the rotor angle (360 bins): pk-pk of the bin means, and pk-pk (twice the
/// amplitude) of its harmonics 1 and 2 (rad), as hil-sim's truth spectrum measures it
/// (`truth_spectrum::TruthSpectrum::motion_*`). Meant for whole revolutions at a steady
/// speed: the fit is the speed, what is left the ripple a torque ripple makes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionRipple {
    pub pk_pk_rad: f64,
    pub h1_pk_pk_rad: f64,
    pub h2_pk_pk_rad: f64,
    /// Mean speed of the fit (rad/s) and revolutions travelled.
    pub speed_rad_s: f64,
    pub revs: f64,
}

/// [`MotionRipple`] of `periods`; None without any.
pub fn motion_ripple(periods: &[PeriodTruth]) -> Option<MotionRipple> {
    let (first, last) = (periods.first()?, periods.last()?);
    let points = periods.iter().map(|p| (p.truth.t_s, p.truth.theta_rad));
    let (t_mean, th_mean, slope_rad_s) = crate::baselines::line_fit(points);
    let mut bins = SpatialError::<360>::new();
    for p in periods {
        let motion = p.truth.theta_rad - th_mean - slope_rad_s * (p.truth.t_s - t_mean);
        bins.add(p.truth.theta_rad, motion);
    }
    Some(MotionRipple {
        pk_pk_rad: bins.pk_pk_rad(),
        h1_pk_pk_rad: 2.0 * bins.harmonic_amplitude_rad(1),
        h2_pk_pk_rad: 2.0 * bins.harmonic_amplitude_rad(2),
        speed_rad_s: slope_rad_s,
        revs: (last.truth.theta_rad - first.truth.theta_rad).abs() / TAU,
    })
}

/// The rotor angle at each record's period and the raw sensor's and the estimate's
/// error there (each centred), and the estimate's constant offset removed.
type ErrorsAtRecords = (Vec<f64>, Vec<f64>, Vec<f64>, f64);

fn errors_at_records(
    log: &[PeriodTruth],
    pwm_hz: f64,
    probe: &Probe,
    records: &[(u32, f32)],
    harmonics: u32,
) -> Result<ErrorsAtRecords, ScoreError> {
    let need = 2 * (1 + 2 * harmonics as usize);
    if records.len() < need {
        return Err(ScoreError::TooFew {
            records: records.len(),
            harmonics,
            need,
        });
    }
    let n = probe.sensor_periods;
    let (mut thetas, mut raw, mut est) = (Vec::new(), Vec::new(), Vec::new());
    for &(t_ms, theta_hat) in records {
        let ticks = t_ms as f64 * pwm_hz / 1000.0;
        if (ticks - ticks.round()).abs() > 1e-6 {
            return Err(ScoreError::NotATick { t_ms, ticks });
        }
        let tick = ticks.round() as u64;
        let p = (tick as usize)
            .checked_sub(1)
            .and_then(|i| log.get(i))
            .ok_or(ScoreError::OutsideLog {
                t_ms,
                tick,
                len: log.len(),
            })?;
        if !theta_hat.is_finite() {
            return Err(ScoreError::NotFinite { t_ms });
        }
        let th = p.truth.theta_rad;
        thetas.push(th);
        raw.push(probe.raw_error_rad(th, p.truth.x, p.truth.y));
        est.push(wrap_pi(n * (theta_hat as f64 - th)) / n);
    }
    centred(&mut raw, n);
    let estimate_offset_rad = centred(&mut est, n);
    Ok((thetas, raw, est, estimate_offset_rad))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensor::Mount;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    const PWM_HZ: f64 = 20_000.0;

    /// pk-pk of a function over a fine grid of one revolution.
    fn pk_pk(f: impl Fn(f64) -> f64) -> f64 {
        let v: Vec<f64> = (0..20_000).map(|i| f(TAU * i as f64 / 20_000.0)).collect();
        v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - v.iter().cloned().fold(f64::INFINITY, f64::min)
    }

    fn raw_error(th: f64) -> f64 {
        0.02 * (2.0 * th).sin() + 0.01 * (4.0 * th + 0.4).cos()
    }

    fn est_error(th: f64) -> f64 {
        0.6e-3 * (2.0 * th + 0.3).sin() + 0.2e-3 * (6.0 * th).cos()
    }

    /// A rotor at `rev_s` with a speed ripple for `seconds`: per-period truth of an
    /// N = 2 sensor mounted at `mount` whose angle is off by `raw_error`.
    fn log(rev_s: f64, seconds: f64, mount: Mount) -> Vec<PeriodTruth> {
        let probe = Probe {
            sensor_periods: 2.0,
            mount,
        };
        (1..=(seconds * PWM_HZ) as u64)
            .map(|k| {
                let t = k as f64 / PWM_HZ;
                let th = TAU * rev_s * t + 0.05 * (7.0 * t).sin();
                let a = 2.0 * (probe.magnet_rad(th) + raw_error(th));
                PeriodTruth {
                    truth: Truth {
                        t_s: t,
                        theta_rad: th,
                        omega_rad_s: TAU * rev_s,
                        x: a.cos() as f32,
                        y: a.sin() as f32,
                    },
                    i_ab: [0.0; 2],
                    torque_nm: 0.0,
                    duties: None,
                }
            })
            .collect()
    }

    /// Records every 10 ms: θ̂ in the motor frame at an offset, with `est_error`, noise
    /// and the half-revolution an N = 2 sensor cannot tell apart.
    fn records(log: &[PeriodTruth], sign: f64, noise_rad: f64) -> Vec<(u32, f32)> {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut out = Vec::new();
        for t_ms in (10..).step_by(10) {
            let tick = (t_ms as f64 * PWM_HZ / 1000.0) as usize;
            let Some(p) = log.get(tick - 1) else { break };
            let th = p.truth.theta_rad;
            let noise = noise_rad * (rng.random::<f64>() - 0.5) * 12f64.sqrt();
            let half = if t_ms % 30 == 0 { PI } else { 0.0 };
            let theta_hat = sign * th + 0.7 + half + est_error(th) + noise;
            out.push((t_ms, theta_hat.rem_euclid(TAU) as f32));
        }
        out
    }

    fn probe(mount: Mount) -> Probe {
        Probe {
            sensor_periods: 2.0,
            mount,
        }
    }

    #[test]
    fn estimates_score_their_spatial_error_against_the_raw_sensors() {
        let mount = Mount {
            offset_rad: 1.1,
            reversed: true,
        };
        // 3.37 rev/s against 100 Hz records: angles spread over the revolution.
        let log = log(3.37, 6.0, mount);
        let recs = records(&log, 1.0, 0.2e-3);
        let s = score_estimates(&log, PWM_HZ, &probe(mount), &recs, 16).unwrap();
        let raw = pk_pk(raw_error);
        let est = pk_pk(est_error);
        assert!((s.raw_pk_pk_rad / raw - 1.0).abs() < 0.02, "{s:?} vs {raw}");
        // θ̂ is stored as f32 (0.2 µrad steps at 2π) and noisy: within 10 %.
        assert!(
            (s.estimate_pk_pk_rad / est - 1.0).abs() < 0.1,
            "{s:?} vs {est}"
        );
        assert!(s.estimate_residual_rms_rad < 0.3e-3, "{s:?}");
        assert!(s.raw_residual_rms_rad < 1e-5, "{s:?}");
        // The offset is 0.7 within ±π/2 (the half-revolution removed).
        assert!((s.estimate_offset_rad - 0.7).abs() < 1e-3, "{s:?}");
    }

    /// By harmonic: the raw sensor's 20 mrad at m = 2 and 10 mrad at m = 4, the
    /// estimate's 0.6 mrad at m = 2 and 0.2 mrad at m = 6, nothing elsewhere.
    #[test]
    fn estimates_score_their_error_by_harmonic_of_the_rotor_angle() {
        let mount = Mount {
            offset_rad: 1.1,
            reversed: true,
        };
        let log = log(3.37, 6.0, mount);
        let recs = records(&log, 1.0, 0.0);
        let (raw, est) = estimate_harmonics_rad(&log, PWM_HZ, &probe(mount), &recs, 16).unwrap();
        assert_eq!((raw.len(), est.len()), (16, 16));
        for m in 1..=16 {
            let (want_raw, want_est) = match m {
                2 => (0.02, 0.6e-3),
                4 => (0.01, 0.0),
                6 => (0.0, 0.2e-3),
                _ => (0.0, 0.0),
            };
            let (r, e) = (raw[m - 1], est[m - 1]);
            assert!(
                (r - want_raw).abs() < 1e-4,
                "raw m = {m}: {r} vs {want_raw}"
            );
            // θ̂ is stored as f32: 0.2 µrad steps at 2π.
            assert!((e - want_est).abs() < 5e-6, "θ̂ m = {m}: {e} vs {want_est}");
        }
    }

    /// A rotor at a steady speed moved 1 mrad at 1x and 2 mrad at 2x of its angle: 2 and
    /// 4 mrad pk-pk, whatever the speed's own value.
    #[test]
    fn the_motion_ripple_is_the_angle_less_a_constant_speed_fit() {
        let w = TAU * 1.3;
        let periods: Vec<PeriodTruth> = (0..(4.0 / 1.3 * PWM_HZ) as usize)
            .map(|k| {
                let t = k as f64 / PWM_HZ;
                let th = w * t + 1e-3 * (w * t).sin() + 2e-3 * (2.0 * w * t + 0.3).cos();
                PeriodTruth {
                    truth: Truth {
                        t_s: t,
                        theta_rad: th,
                        omega_rad_s: w,
                        x: 0.0,
                        y: 0.0,
                    },
                    i_ab: [0.0; 2],
                    torque_nm: 0.0,
                    duties: None,
                }
            })
            .collect();
        let m = motion_ripple(&periods).unwrap();
        // Over 4 revolutions the constant-speed fit takes a few % of the 1x ripple for
        // speed (a sine correlates with time over a finite window; truth_spectrum's fit
        // does the same): within 5 %.
        assert!((m.h1_pk_pk_rad - 2e-3).abs() < 0.1e-3, "{m:?}");
        assert!((m.h2_pk_pk_rad - 4e-3).abs() < 0.05e-3, "{m:?}");
        assert!((m.speed_rad_s / w - 1.0).abs() < 1e-4, "{m:?}");
        assert!((m.revs - 4.0).abs() < 0.01, "{m:?}");
        assert!(motion_ripple(&[]).is_none());
    }

    #[test]
    fn an_estimate_turning_the_wrong_way_scores_far_worse_than_the_raw_sensor() {
        let mount = Mount::default();
        let log = log(3.37, 6.0, mount);
        let recs = records(&log, -1.0, 0.0);
        let s = score_estimates(&log, PWM_HZ, &probe(mount), &recs, 16).unwrap();
        assert!(s.estimate_pk_pk_rad > 10.0 * s.raw_pk_pk_rad, "{s:?}");
    }

    #[test]
    fn records_that_do_not_cover_the_revolution_are_refused() {
        let mount = Mount::default();
        // 5 rev/s: every 10 ms record at one of two angles.
        let log = log(5.0, 3.0, mount);
        let recs: Vec<_> = records(&log, 1.0, 0.0)
            .into_iter()
            .map(|(t, _)| (t, 0.0))
            .collect();
        let log_still: Vec<PeriodTruth> = log
            .iter()
            .map(|p| PeriodTruth {
                truth: Truth {
                    theta_rad: TAU * 5.0 * p.truth.t_s,
                    ..p.truth
                },
                ..*p
            })
            .collect();
        assert!(matches!(
            score_estimates(&log_still, PWM_HZ, &probe(mount), &recs, 16),
            Err(ScoreError::Coverage { .. })
        ));
    }

    #[test]
    fn records_off_the_period_grid_or_outside_the_log_are_refused() {
        let mount = Mount::default();
        let log = log(3.37, 1.0, mount);
        let mut recs = records(&log, 1.0, 0.0);
        let p = probe(mount);
        recs.push((5000, 0.0));
        assert!(matches!(
            score_estimates(&log, PWM_HZ, &p, &recs, 4),
            Err(ScoreError::OutsideLog { tick: 100_000, .. })
        ));
        recs.pop();
        // 40 kHz with a record at an odd 1/40 ms: never a period of its own.
        assert!(matches!(
            score_estimates(&log, 19_999.0, &p, &recs, 4),
            Err(ScoreError::NotATick { .. })
        ));
        assert!(matches!(
            score_estimates(&log, PWM_HZ, &p, &recs[..5], 4),
            Err(ScoreError::TooFew { need: 18, .. })
        ));
    }

    fn motor() -> MotorParams {
        MotorParams::default()
    }

    /// A current of |`amps`| pushing along the q axis of `amps`' sign, lagging it by
    /// `error_e` (towards -d), and the torque it makes.
    fn add_at(cv: &mut CurrentVector, th: f64, amps: f64, error_e: f64) {
        let m = motor();
        let dir = amps.signum();
        let (iq, id) = (amps * error_e.cos(), -dir * amps.abs() * error_e.sin());
        let (s, c) = (m.pole_pairs as f64 * th).sin_cos();
        let i = [id * c - iq * s, id * s + iq * c];
        cv.add(th, i, m.torque_constant_nm_a() * iq);
    }

    #[test]
    fn the_current_vector_on_the_q_axis_scores_zero_error_and_full_torque() {
        for amps in [2.0, -2.0] {
            let mut cv = CurrentVector::new(&motor());
            for k in 0..3600 {
                add_at(&mut cv, k as f64 * 0.01, amps, 0.0);
            }
            let s = cv.stats().unwrap();
            assert!(s.angle_error_e_rad.abs() < 1e-12, "{amps}: {s:?}");
            assert!((s.torque_per_amp - 1.0).abs() < 1e-12, "{amps}: {s:?}");
            assert!(s.angle_error_e_pk_pk_rad < 1e-12, "{amps}: {s:?}");
        }
    }

    #[test]
    fn an_electrical_offset_shows_as_angle_error_and_lost_torque() {
        for amps in [2.0, -2.0] {
            let mut cv = CurrentVector::new(&motor());
            for k in 0..3600 {
                add_at(&mut cv, k as f64 * 0.01, amps, 0.3);
            }
            let s = cv.stats().unwrap();
            assert!(
                (s.angle_error_e_rad.abs() - 0.3).abs() < 1e-9,
                "{amps}: {s:?}"
            );
            assert!(
                (s.torque_per_amp - 0.3f64.cos()).abs() < 1e-9,
                "{amps}: {s:?}"
            );
        }
    }

    #[test]
    fn an_angle_error_that_moves_with_the_rotor_shows_in_pk_pk_not_in_the_mean() {
        let mut cv = CurrentVector::new(&motor());
        // Ten whole revolutions.
        for k in 0..36_000 {
            let th = TAU * k as f64 / 3600.0;
            add_at(&mut cv, th, 2.0, 0.2 * (2.0 * th).sin());
        }
        let s = cv.stats().unwrap();
        assert!(s.angle_error_e_rad.abs() < 1e-3, "{s:?}");
        assert!((s.angle_error_e_pk_pk_rad - 0.4).abs() < 0.01, "{s:?}");
        assert!(s.torque_per_amp < 0.995, "{s:?}");
        assert!(CurrentVector::new(&motor()).stats().is_none());
    }
}

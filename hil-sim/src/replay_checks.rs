//! What replay reads from a recording before it runs the core: the sensor periods per
//! revolution N from the reference angle, and the shaft's own motion at the harmonics
//! where, at one speed, it cannot be told from the sensor's error (docs/theory.md §9).
//!
//! Both use `theta_rad`, the reference that replay otherwise only scores against: it
//! measures the shaft, which the sensor alone cannot (a sensor error and the shaft's
//! motion at the same harmonic give the same samples at one speed).

use crate::input_error::InputError;
use mras_sim::wrap_pi;
use serde::Serialize;
use std::f64::consts::TAU;

/// N when neither --config, --sensor-periods nor a reference angle gives it: the core's
/// default (a KMZ41-style magnetoresistive sensor, two periods per revolution).
pub const DEFAULT_SENSOR_PERIODS: u16 = 2;
/// Reference travel below which N is not read from it (rad, one revolution): over less,
/// the sensor's angle error at the two ends is a large share of its travel.
const MIN_REFERENCE_TRAVEL_RAD: f64 = TAU;
/// Largest |electrical travel - N·mechanical travel| accepted (rad electrical): the
/// sensor's own angle error at the two ends of the file, far below a radian for any
/// sensor the core tracks (its lock threshold is 1 rad). More means the reference is not
/// the shaft's mechanical angle in radians, or the sensor turns more than half a period
/// between samples (the unwrapped angle then slips periods).
const MAX_TRAVEL_RESIDUAL_RAD: f64 = 1.0;
/// Largest N a reference may give: a fine sin/cos encoder's line count is in the
/// thousands; more suggests the reference is not in radians.
const MAX_DETECTED_SENSOR_PERIODS: f64 = 4096.0;

/// Where N came from (report key `sensor_periods_source`, and its measurement).
#[derive(Clone, Debug, Serialize)]
pub struct SensorPeriodsReport {
    /// "config", "--sensor-periods", "from theta_rad" or "default".
    pub source: &'static str,
    pub value: u16,
    /// With a reference: the sensor angle's electrical travel, the reference's mechanical
    /// travel and their ratio (whether or not N was taken from them).
    pub electrical_travel_rad: Option<f64>,
    pub mechanical_travel_rad: Option<f64>,
    pub ratio: Option<f64>,
    pub reason: String,
}

/// The total travel of a sampled angle, unwrapped sample to sample.
fn travel_rad(n: usize, angle_rad: impl Fn(usize) -> f64) -> f64 {
    (1..n)
        .map(|k| wrap_pi(angle_rad(k) - angle_rad(k - 1)))
        .sum()
}

/// N from the recording: the scaled sensor vector's angle atan2(y, x), unwrapped, travels
/// N times the reference's mechanical travel. `angle_rad(k)` is the sensor's angle of
/// row k; `theta_rad` the reference. `Ok(None)`: the reference travels less than a
/// revolution (N is then not read from it). An implausible ratio is an error naming the
/// column and the figures.
pub fn sensor_periods_from_reference(
    name: &str,
    theta_rad: &[f64],
    angle_rad: impl Fn(usize) -> f64,
) -> Result<(Option<u16>, SensorPeriodsReport), InputError> {
    let n = theta_rad.len();
    let mech = travel_rad(n, |k| theta_rad[k]);
    let elec = travel_rad(n, angle_rad);
    let ratio = elec / mech;
    let mut report = SensorPeriodsReport {
        source: "from theta_rad",
        value: 0,
        electrical_travel_rad: Some(elec),
        mechanical_travel_rad: Some(mech),
        ratio: Some(ratio),
        reason: String::new(),
    };
    if mech.is_nan() || mech.abs() < MIN_REFERENCE_TRAVEL_RAD {
        report.reason = format!(
            "theta_rad travels {mech:.3} rad, less than a revolution: too little to read N from"
        );
        return Ok((None, report));
    }
    let periods = ratio.round();
    let residual_rad = elec - periods * mech;
    let why = |what: String| {
        InputError::new(
            name,
            format!(
                "column `theta_rad`: the sensor's angle atan2(y, x) travels {elec:.3} rad \
                 while theta_rad travels {mech:.3} rad, a ratio of {ratio:.4}: {what}; give \
                 the sensor periods per revolution with --sensor-periods (or \
                 `sensor_periods` in a --config file)"
            ),
        )
    };
    if periods < 1.0 {
        return Err(why(
            "not a positive number of sensor periods per revolution (a sensor turning \
             against the reference gives a negative one: negate theta_rad, or swap x and y)"
                .into(),
        ));
    }
    if periods > MAX_DETECTED_SENSOR_PERIODS {
        return Err(why(format!(
            "more than {MAX_DETECTED_SENSOR_PERIODS} sensor periods per revolution \
             (is theta_rad in radians?)"
        )));
    }
    if residual_rad.abs() > MAX_TRAVEL_RESIDUAL_RAD {
        return Err(why(format!(
            "{residual_rad:+.3} rad electrical from a whole N = {periods} (at most \
             ±{MAX_TRAVEL_RESIDUAL_RAD} rad: the sensor's error at the file's ends). Is \
             theta_rad the mechanical angle in radians, and does the sensor turn less than \
             half a period between samples?"
        )));
    }
    report.value = periods as u16;
    report.reason = format!(
        "the sensor's angle travels {elec:.3} rad, theta_rad {mech:.3} rad: {ratio:.4} \
         sensor periods per revolution, {residual_rad:+.3} rad electrical from N = {periods}"
    );
    Ok((Some(periods as u16), report))
}

/// Mechanical harmonics of the reference's motion measured (1..=16: a path reaches
/// m = 16 of θs).
pub const MOTION_HARMONICS: usize = 16;
/// The shaft's motion at a harmonic where the sensor's error lands too is flagged above
/// this share of the sensor's largest raw error harmonic: the survey gives no path to
/// an error below 1 % of the largest (`mras::survey::MIN_SHARE`), so a motion below it
/// is below what the correction resolves anyway.
pub const MOTION_SHARE: f64 = 0.01;

/// Largest deviation of one revolution's duration from their mean for the motion check
/// (fraction): a ripple of 10 mrad at 1x and 2x leaves it unchanged; a ramp or a speed
/// step does not.
const MAX_SPEED_SPREAD: f64 = 0.02;

/// One sensor harmonic m = 1, 2 of θs (mechanical harmonic N·m) and the shaft's motion
/// there.
#[derive(Clone, Debug, Serialize)]
pub struct MotionHarmonic {
    /// Harmonic of the sensor angle θs (1, 2: the offset and C/D paths').
    pub m: u8,
    /// The same harmonic of the shaft angle θrm (N·m).
    pub mechanical_harmonic: u32,
    /// The reference's deviation from a constant-speed fit at that harmonic (mrad,
    /// mechanical).
    pub motion_mrad: f64,
    /// The raw sensor's error at that harmonic against the reference (mrad, mechanical).
    pub raw_error_mrad: f64,
    /// Motion above the threshold: at one speed the MRAS would take it for sensor error.
    pub flagged: bool,
}

/// The shaft's motion where it coincides with the sensor's error (report key `motion`).
#[derive(Clone, Debug, Serialize)]
pub struct MotionReport {
    /// How it was measured, or why it was not.
    pub method: String,
    /// m = 1, 2 (empty without a reference).
    pub harmonics: Vec<MotionHarmonic>,
    /// max(noise floor, MOTION_SHARE of the largest raw error harmonic), mrad mechanical.
    pub threshold_mrad: f64,
    pub noise_floor_mrad: f64,
    /// The reference's motion at mechanical harmonics 1..16 (mrad), for the record.
    pub motion_spectrum_mrad: Vec<f64>,
    /// What replay did about it (null: nothing flagged).
    pub action: Option<String>,
    /// The warning printed in the summary (null: nothing flagged).
    pub warning: Option<String>,
}

impl MotionReport {
    pub fn not_measured(why: String) -> Self {
        Self {
            method: why,
            harmonics: Vec::new(),
            threshold_mrad: 0.0,
            noise_floor_mrad: 0.0,
            motion_spectrum_mrad: Vec::new(),
            action: None,
            warning: None,
        }
    }

    /// The flagged sensor harmonics m.
    pub fn flagged(&self) -> Vec<u8> {
        self.harmonics
            .iter()
            .filter(|h| h.flagged)
            .map(|h| h.m)
            .collect()
    }
}

/// Amplitude of harmonic k of `e` against the angle `angle_rad` (rad), by a DFT over
/// the samples (whole periods of the angle: exact).
fn dft_amplitude(e: &[f64], angle_rad: &[f64], k: f64) -> f64 {
    let (mut re, mut im) = (0.0, 0.0);
    for (v, a) in e.iter().zip(angle_rad) {
        re += v * (k * a).cos();
        im += v * (k * a).sin();
    }
    2.0 * re.hypot(im) / e.len() as f64
}

/// The shaft's motion at the sensor harmonics m = 1, 2 (mechanical N, 2N) over `rows`
/// (the scored half of the file), from the reference: theta_rad, unwrapped, less its
/// least-squares constant-speed fit, over the whole revolutions the window holds, its
/// DFT against the fitted angle. `raw_error_rad(k)` is the raw sensor's mechanical
/// error of row k against the reference (its harmonics set the threshold). `None` when
/// the window holds less than a whole revolution.
pub fn shaft_motion(
    theta_rad: &[f64],
    t_s: &[f64],
    rows: std::ops::Range<usize>,
    sensor_periods: u16,
    raw_error_rad: impl Fn(usize) -> f64,
) -> Option<MotionReport> {
    let start = rows.start;
    // Unwrapped reference from the window's start.
    let mut th = Vec::with_capacity(rows.len());
    let mut acc = theta_rad[start];
    th.push(acc);
    for k in start + 1..rows.end {
        acc += wrap_pi(theta_rad[k] - theta_rad[k - 1]);
        th.push(acc);
    }
    let travel = th[th.len() - 1] - th[0];
    let revs = (travel.abs() / TAU).floor();
    if revs < 1.0 {
        return None;
    }
    // Whole revolutions: up to the last sample within `revs` turns of the first.
    let len = th
        .iter()
        .rposition(|a| (a - th[0]).abs() <= revs * TAU)
        .map_or(th.len(), |i| i + 1);
    th.truncate(len);
    let t: Vec<f64> = t_s[start..start + len].to_vec();
    // One speed: the time each whole revolution takes (the motion at harmonics of the
    // revolution leaves it unchanged) within MAX_SPEED_SPREAD of their mean. A shaft
    // changing speed is not the case this check is for: its motion is not periodic in
    // the angle, and its deviation from one constant speed is not a ripple.
    let sign = travel.signum();
    let mut rev_s = Vec::new();
    let (mut next, mut last_t) = (1.0, t[0]);
    for k in 1..len {
        let level = th[0] + sign * next * TAU;
        if (th[k] - level) * sign >= 0.0 {
            // Linear interpolation of the crossing.
            let f = (level - th[k - 1]) / (th[k] - th[k - 1]);
            let tc = t[k - 1] + f * (t[k] - t[k - 1]);
            rev_s.push(tc - last_t);
            last_t = tc;
            next += 1.0;
        }
    }
    if rev_s.len() >= 2 {
        let mean = rev_s.iter().sum::<f64>() / rev_s.len() as f64;
        let spread = rev_s
            .iter()
            .map(|d| (d / mean - 1.0).abs())
            .fold(0.0, f64::max);
        if spread > MAX_SPEED_SPREAD {
            return Some(MotionReport::not_measured(format!(
                "the shaft's speed over the second half is not one speed (its revolutions \
                 take {:.4}..{:.4} s, ±{:.1} % of their mean, more than ±{:.0} %): not checked",
                rev_s.iter().copied().fold(f64::INFINITY, f64::min),
                rev_s.iter().copied().fold(0.0, f64::max),
                spread * 100.0,
                MAX_SPEED_SPREAD * 100.0
            )));
        }
    }
    // Least-squares line θ = a + b·t.
    let n = len as f64;
    let (tm, am) = (t.iter().sum::<f64>() / n, th.iter().sum::<f64>() / n);
    let (mut stt, mut sta) = (0.0, 0.0);
    for (ti, ai) in t.iter().zip(&th) {
        stt += (ti - tm) * (ti - tm);
        sta += (ti - tm) * (ai - am);
    }
    let b = sta / stt;
    let fit: Vec<f64> = t.iter().map(|ti| am + b * (ti - tm)).collect();
    let resid: Vec<f64> = th.iter().zip(&fit).map(|(a, f)| a - f).collect();
    let raw: Vec<f64> = (start..start + len).map(&raw_error_rad).collect();
    let raw_mean = raw.iter().sum::<f64>() / n;
    let raw: Vec<f64> = raw.iter().map(|v| v - raw_mean).collect();
    // Noise: the sample-to-sample differences of the residual, whose smooth part (the
    // motion, at a few harmonics of the revolution) is far below one sample's step; a
    // DFT bin's noise is 2σ/√K, and the floor is four of them (as the core's survey).
    let diff2 = resid.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>() / (n - 1.0);
    let sigma = (diff2 / 2.0).sqrt();
    let floor = 4.0 * 2.0 * sigma / n.sqrt();
    let spectrum: Vec<f64> = (1..=MOTION_HARMONICS)
        .map(|k| dft_amplitude(&resid, &fit, k as f64))
        .collect();
    let largest_raw = (1..=MOTION_HARMONICS)
        .map(|k| dft_amplitude(&raw, &fit, k as f64))
        .fold(0.0, f64::max);
    let threshold = floor.max(MOTION_SHARE * largest_raw);
    let harmonics = [1u8, 2]
        .into_iter()
        .map(|m| {
            let k = m as u32 * sensor_periods as u32;
            let motion = dft_amplitude(&resid, &fit, k as f64);
            MotionHarmonic {
                m,
                mechanical_harmonic: k,
                motion_mrad: motion * 1e3,
                raw_error_mrad: dft_amplitude(&raw, &fit, k as f64) * 1e3,
                flagged: motion > threshold,
            }
        })
        .collect();
    Some(MotionReport {
        method: format!(
            "theta_rad over rows {}..{} ({revs} whole revolutions of the second half), less \
             its least-squares constant-speed fit ({:.4} rad/s); harmonics by DFT against the \
             fitted angle; threshold: the larger of the noise floor (4 DFT bins' noise) and \
             {MOTION_SHARE} of the raw sensor error's largest harmonic (m = 1..{MOTION_HARMONICS})",
            start + 1,
            start + len,
            b
        ),
        harmonics,
        threshold_mrad: threshold * 1e3,
        noise_floor_mrad: floor * 1e3,
        motion_spectrum_mrad: spectrum.iter().map(|a| a * 1e3).collect(),
        action: None,
        warning: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn n_is_read_from_the_reference_and_a_bad_one_is_refused() {
        let rows = 4000;
        let theta: Vec<f64> = (0..rows)
            .map(|k| 0.3 + 4.0 * TAU * k as f64 / rows as f64)
            .collect();
        for n in [1u16, 2, 7] {
            let (got, rep) = sensor_periods_from_reference("IN.csv", &theta, |k| {
                let a = n as f64 * theta[k] + 0.05 * (3.0 * theta[k]).sin();
                a.sin().atan2(a.cos())
            })
            .unwrap();
            assert_eq!(got, Some(n), "{rep:?}");
        }
        // Against the reference: a negative ratio, named.
        let e = sensor_periods_from_reference("IN.csv", &theta, |k| -theta[k]).unwrap_err();
        assert!(e.to_string().contains("column `theta_rad`"), "{e}");
        assert!(e.to_string().contains("negate theta_rad"), "{e}");
        // A reference in degrees: 1.5 periods per "revolution" is refused.
        let e = sensor_periods_from_reference("IN.csv", &theta, |k| 1.5 * theta[k]).unwrap_err();
        assert!(e.to_string().contains("from a whole N"), "{e}");
        // Less than a revolution: not read.
        let short: Vec<f64> = theta[..500].to_vec();
        let (got, _) = sensor_periods_from_reference("IN.csv", &short, |k| short[k]).unwrap();
        assert_eq!(got, None);
    }

    #[test]
    fn motion_at_once_and_twice_per_revolution_is_measured() {
        let rows = 20_000;
        let t: Vec<f64> = (0..rows).map(|k| k as f64 * 1e-3).collect();
        let theta: Vec<f64> = t
            .iter()
            .map(|t| {
                let s = TAU * t;
                s + 5e-3 * (s + 0.3).sin() + 2e-3 * (2.0 * s).sin()
            })
            .collect();
        let rep = shaft_motion(&theta, &t, 0..rows, 1, |k| 3e-3 * (4.0 * theta[k]).sin()).unwrap();
        let m: Vec<f64> = rep.harmonics.iter().map(|h| h.motion_mrad).collect();
        assert!(
            (m[0] - 5.0).abs() < 0.05 && (m[1] - 2.0).abs() < 0.05,
            "{m:?}"
        );
        assert_eq!(rep.flagged(), [1, 2]);
        // A shaft speeding up: not one speed, not checked.
        let ramp: Vec<f64> = t.iter().map(|t| TAU * (t + 0.05 * t * t)).collect();
        let rep = shaft_motion(&ramp, &t, 0..rows, 1, |_| 0.0).unwrap();
        assert!(
            rep.harmonics.is_empty() && rep.method.contains("not one speed"),
            "{rep:?}"
        );
        // N = 2: the sensor's m = 1, 2 are the shaft's 2x and 4x.
        let rep = shaft_motion(&theta, &t, 0..rows, 2, |k| 3e-3 * (4.0 * theta[k]).sin()).unwrap();
        assert_eq!(rep.flagged(), [1]);
    }
}

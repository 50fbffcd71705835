//! `hil-sim replay`: the core, sample for sample, over a recorded sensor file.
//!
//! A published interface: the CSV column names, the report's keys and the flags below are
//! what scripts and other tools rely on; change them only with a version note.
//!
//! The whole input is read and checked before anything is written, and the outputs are
//! written to temporary files next to their destinations and renamed into place only
//! when everything succeeded, so a failing run never leaves a partial OUT.csv behind nor
//! destroys an existing one.

use crate::core_config::CoreConfigFile;
use crate::front_end::FrontEnd;
use crate::input_error::InputError;
use crate::pending::Pending;
use crate::replay_checks::{self, MotionReport, SensorPeriodsReport, DEFAULT_SENSOR_PERIODS};
use crate::survey::{self, Samples, SurveyReport};
use anyhow::{anyhow, bail, Context, Result};
use mras::{Config, Fault, PathKind, Tracker};
use mras_sim::{wrap_pi, SpatialError};
use serde::Serialize;
use std::f64::consts::TAU;
use std::fmt::Write as _;
use std::fs::{self, File};
use std::io::{BufWriter, Write as _};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Recorded CSV with a header; columns by name, any order: t_s (strictly increasing,
    /// fixed period), x, y (raw sensor units), optional torque_nm (feedforward, 0 when
    /// absent) and theta_rad (reference mechanical angle: for scoring, for N and for the
    /// check of the shaft's motion at the sensor's m = 1, 2). Others are ignored.
    #[arg(long)]
    pub input: PathBuf,
    /// Estimates, one row per input row: t_s, theta_hat_rad (unwrapped),
    /// omega_hat_rad_s, then <path>_re, <path>_im of every path coefficient.
    #[arg(long)]
    pub output: PathBuf,
    /// Core configuration (TOML; every key optional, see
    /// hil-sim/tests/data/core_config_full.toml). Without it: the core defaults, the
    /// paths from the data (--bank) and input scaling estimated from the data.
    /// Without [observer] eigenvalues_hz: the default 100/10/1 Hz, or scaled down to suit
    /// the recording's sample rate and speed (the summary and report say which and why).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Sensor periods per mechanical revolution N. Without it: `sensor_periods` in
    /// --config (which wins over the flag too), else read from the recording (the sensor
    /// angle's travel over theta_rad's, rounded and checked), else 2. The summary and
    /// report say which.
    #[arg(long)]
    pub sensor_periods: Option<u16>,
    /// Also write a JSON report: where N, the bank, the input scaling and the observer's
    /// eigenvalues came from, the motion check, faults, final coefficients, convergence
    /// and, with theta_rad, the raw and corrected spatial error and its harmonics.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// The path bank when --config gives no `paths` (which always win): `data` (the
    /// default) chooses it from the recording (the core's rounds: the bank adapts, the
    /// sensor's error spectrum m = 1..16 is surveyed with adaptation frozen and the bank
    /// grows by its largest harmonics, up to 16 paths; the summary and report name the
    /// paths and what was left); `default` takes the core's fixed bank (offset,
    /// amplitude-quadrature, h4..h8).
    #[arg(long, value_enum)]
    pub bank: Option<BankChoice>,
    /// The same as `--bank data`.
    #[arg(long, hide = true)]
    pub paths_from_data: bool,
}

/// `--bank`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BankChoice {
    /// From the recording's error spectrum (`mras::survey`).
    Data,
    /// The core's fixed default bank.
    Default,
}

/// Rows above which progress is printed to stderr.
const PROGRESS_ROWS: usize = 1_000_000;
/// Largest deviation of one t_s step from the mean period (fraction of it).
const MAX_PERIOD_DEVIATION: f64 = 0.10;
/// Bins of reference angle for the spatial error (as in the core's tests).
const ERROR_BINS: usize = 360;

/// The recording, column by column (validated: finite, t_s strictly increasing).
#[derive(Default)]
struct Recording {
    name: String,
    t_s: Vec<f64>,
    x: Vec<f32>,
    y: Vec<f32>,
    /// Empty when the file has no `torque_nm` column (0 is fed).
    torque_nm: Vec<f32>,
    /// Empty when the file has no `theta_rad` column.
    theta_rad: Vec<f64>,
    /// File line of each row, for messages.
    line: Vec<u64>,
}

impl Recording {
    fn rows(&self) -> usize {
        self.t_s.len()
    }
}

/// One required or optional column of the input.
fn column(name: &str, headers: &csv::StringRecord, col: &str) -> Result<Option<usize>, InputError> {
    let mut found = headers.iter().enumerate().filter(|(_, h)| *h == col);
    let first = found.next().map(|(i, _)| i);
    if found.next().is_some() {
        return Err(InputError::at(
            name,
            1,
            format!("column `{col}` appears twice in the header"),
        ));
    }
    Ok(first)
}

/// Parse one numeric field; `T` is f64 for time and angle, f32 for what the core takes
/// (parsed directly as f32 so that a value written with f32 `Display` comes back bit-exact).
fn field<T: std::str::FromStr + Copy>(
    name: &str,
    line: u64,
    rec: &csv::StringRecord,
    idx: usize,
    col: &str,
    finite: fn(T) -> bool,
) -> Result<T, InputError> {
    let raw = rec.get(idx).unwrap_or("");
    if raw.is_empty() {
        return Err(InputError::field(name, line, col, "empty"));
    }
    let v: T = raw
        .parse()
        .map_err(|_| InputError::field(name, line, col, format!("not a number: {raw:?}")))?;
    if !finite(v) {
        let why = if raw.parse::<f64>().is_ok_and(f64::is_finite) {
            "beyond the f32 range"
        } else {
            "not finite"
        };
        return Err(InputError::field(
            name,
            line,
            col,
            format!("{why}: {raw:?}"),
        ));
    }
    Ok(v)
}

fn csv_error(name: &str, e: csv::Error) -> InputError {
    let line = e.position().map(|p| p.line());
    let what = match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => format!("{len} fields, the header has {expected_len}"),
        csv::ErrorKind::Utf8 { err, .. } => format!("not UTF-8 text ({err})"),
        _ => e.to_string(),
    };
    InputError {
        line,
        ..InputError::new(name, what)
    }
}

/// Read and validate the whole input (nothing is written before this succeeds).
fn read_recording(path: &Path) -> Result<Recording> {
    let name = path.display().to_string();
    let file = File::open(path).with_context(|| format!("{name}: cannot open"))?;
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_reader(file);
    let headers = rdr.headers().map_err(|e| csv_error(&name, e))?.clone();
    if headers.iter().all(str::is_empty) {
        bail!(InputError::at(
            &name,
            1,
            "empty file: expected a header naming t_s, x, y [, torque_nm, theta_rad]"
        ));
    }
    let need = |col: &str| -> Result<usize, InputError> {
        column(&name, &headers, col)?.ok_or_else(|| {
            let have: Vec<&str> = headers.iter().collect();
            InputError::at(
                &name,
                1,
                format!(
                    "missing column `{col}` (the header has: {})",
                    have.join(", ")
                ),
            )
        })
    };
    let (i_t, i_x, i_y) = (need("t_s")?, need("x")?, need("y")?);
    let i_tq = column(&name, &headers, "torque_nm")?;
    let i_th = column(&name, &headers, "theta_rad")?;

    let mut r = Recording {
        name: name.clone(),
        ..Recording::default()
    };
    let mut rec = csv::StringRecord::new();
    let mut prev: Option<(f64, u64)> = None;
    let mut next_progress = PROGRESS_ROWS;
    while rdr.read_record(&mut rec).map_err(|e| csv_error(&name, e))? {
        let line = rec.position().map_or(0, |p| p.line());
        let t: f64 = field(&name, line, &rec, i_t, "t_s", f64::is_finite)?;
        if let Some((tp, lp)) = prev {
            if t <= tp {
                bail!(InputError::field(
                    &name,
                    line,
                    "t_s",
                    format!("not increasing ({t} after {tp} on line {lp})")
                ));
            }
        }
        prev = Some((t, line));
        r.t_s.push(t);
        r.x.push(field(&name, line, &rec, i_x, "x", f32::is_finite)?);
        r.y.push(field(&name, line, &rec, i_y, "y", f32::is_finite)?);
        if let Some(i) = i_tq {
            r.torque_nm
                .push(field(&name, line, &rec, i, "torque_nm", f32::is_finite)?);
        }
        if let Some(i) = i_th {
            r.theta_rad
                .push(field(&name, line, &rec, i, "theta_rad", f64::is_finite)?);
        }
        r.line.push(line);
        if r.t_s.len() == next_progress {
            next_progress += PROGRESS_ROWS;
            eprintln!("replay: read {} rows of {name}", r.t_s.len());
        }
    }
    if r.rows() < 2 {
        bail!(InputError::new(
            &name,
            format!(
                "{} data row(s): at least 2 are needed to derive the control period",
                r.rows()
            )
        ));
    }
    Ok(r)
}

/// The control period: the mean t_s step, computed as (t_last - t_first)/(n - 1) in f64
/// (exact telescoping of the steps) and then rounded to the core's f32. Refused when any
/// step is more than 10 % off: the core integrates with a fixed period.
fn control_period_s(r: &Recording) -> Result<f64, InputError> {
    let n = r.rows();
    let mean = (r.t_s[n - 1] - r.t_s[0]) / (n - 1) as f64;
    for k in 1..n {
        let step = r.t_s[k] - r.t_s[k - 1];
        if (step - mean).abs() > MAX_PERIOD_DEVIATION * mean {
            return Err(InputError::field(
                &r.name,
                r.line[k],
                "t_s",
                format!(
                    "step {step} s is {:+.1} % off the mean period {mean} s (limit ±10 %): \
                     the core needs a fixed control period (gap or jitter in the recording?)",
                    (step / mean - 1.0) * 100.0
                ),
            ));
        }
    }
    Ok(mean)
}

/// Nominal scaling estimated from the recording: per-channel offsets
/// `(max + min)/2` and one common gain `4/(span_x + span_y)`.
///
/// Not a least-squares ellipse fit, and it need not be: it only sets the core's starting
/// point. The offset and amplitude error it leaves (the harmonics shift the extremes by a
/// few %) is what the offset and amplitude-quadrature paths remove, and the health band
/// (|Z| in [0.25, 2] by default) is far wider than that residual. It needs the recording
/// to sweep at least one full sensor period.
///
/// One gain for both channels, not one each: separate gains would rescale the sensor's
/// harmonics, turning harmonics that are equal on x and y into unequal ones (k = -h
/// components at m = 5, 6 that the default paths do not cover). Measured on
/// `SensorModel::extreme()`: ~50x with per-channel gains, ~3 500x with one gain. The
/// amplitude imbalance itself is the C/D path's job. Give `[input]` in a --config file
/// to set per-channel gains (e.g. a known front-end gain mismatch).
fn estimate_scaling(r: &Recording) -> Result<[f32; 4], InputError> {
    let mut offsets = [0.0f64; 2];
    let mut span_sum = 0.0;
    for (i, (col, v)) in [("x", &r.x), ("y", &r.y)].into_iter().enumerate() {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &s| {
                (l.min(s as f64), h.max(s as f64))
            });
        let span = hi - lo;
        if !(span.is_finite() && span > 0.0 && ((2.0 / span) as f32).is_normal()) {
            return Err(InputError::new(
                &r.name,
                format!(
                    "column `{col}` spans [{lo}, {hi}]: cannot estimate its scaling; give \
                     [input] offset_{col} and gain_{col} in a --config file"
                ),
            ));
        }
        offsets[i] = 0.5 * (hi + lo);
        span_sum += span;
    }
    let gain = (4.0 / span_sum) as f32;
    Ok([offsets[0] as f32, gain, offsets[1] as f32, gain])
}

/// 2π·λ1·T of an eigenvalue set chosen from the recording: half the core's limit (0.2).
const CHOSEN_MAX_LAMBDA_T: f64 = 0.1;

/// Median |mechanical speed| of the recording (rad/s), from the scaled sensor vector's
/// angle, unwrapped (its advance must stay below π a sample; the core's own acquisition
/// assumes 0.5 rad).
///
/// Timed over whole sensor periods: the time between the unwrapped angle's successive
/// crossings of multiples of 2π (a crossing counts once the angle has moved a whole
/// period from the last one, so noise at a crossing does not count it twice). The
/// sensor's error is periodic in the sensor angle, so it is the same at both ends of
/// such an interval and drops out exactly; over a fixed window of samples it would not
/// (1.5 % at 2 rev/s, N = 1, the extreme sensor). The median weighted by time, over the
/// time the shaft turns whole periods: a start from rest, a stop or a sensor dropout in
/// part of the file does not move it. A file shorter than two crossings gives its mean
/// speed.
fn median_speed_rad_s(r: &Recording, input: &FrontEnd, n: u16, period_s: f64) -> f64 {
    let angle_rad = |k: usize| {
        let x = (r.x[k] as f64 - input.offset_x as f64) * input.gain_x as f64;
        let y = (r.y[k] as f64 - input.offset_y as f64) * input.gain_y as f64;
        y.atan2(x)
    };
    let rad_s = |travel_rad: f64, time_s: f64| travel_rad / (n as f64 * time_s);
    // (speed, duration) of every whole period, and the last crossing: (level, time).
    let mut periods: Vec<(f64, f64)> = Vec::new();
    let mut last: Option<(f64, f64)> = None;
    let (mut prev, mut phase_rad) = (angle_rad(0), 0.0);
    for k in 1..r.rows() {
        let a = angle_rad(k);
        let step = wrap_pi(a - prev);
        let before = phase_rad;
        phase_rad += step;
        prev = a;
        let t_s = |level: f64| period_s * ((k - 1) as f64 + (level - before) / step);
        match last {
            None => {
                let level = TAU * (before / TAU).floor();
                let crossed = [level, level + TAU]
                    .into_iter()
                    .find(|l| (before < *l) != (phase_rad < *l));
                last = crossed.map(|l| (l, t_s(l)));
            }
            Some((level, t0_s)) => {
                for next in [level + TAU, level - TAU] {
                    if (before < next) != (phase_rad < next) {
                        let t1_s = t_s(next);
                        periods.push((rad_s(TAU, t1_s - t0_s), t1_s - t0_s));
                        last = Some((next, t1_s));
                    }
                }
            }
        }
    }
    if periods.is_empty() {
        return rad_s(phase_rad.abs(), period_s * (r.rows() - 1) as f64);
    }
    periods.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half_s = 0.5 * periods.iter().map(|p| p.1).sum::<f64>();
    let mut sum_s = 0.0;
    for &(speed, dt_s) in &periods {
        sum_s += dt_s;
        if sum_s >= half_s {
            return speed;
        }
    }
    periods[periods.len() - 1].0
}

/// `v` > 0 rounded to two significant digits (0.0999997 → 0.1, 0.159 → 0.16), so that a
/// chosen set reads as typed; at most 5 % off the bounds it was computed from, well
/// inside their margins.
fn round_2_digits(v: f64) -> f64 {
    let unit = 10f64.powi(v.log10().floor() as i32 - 1);
    (v / unit).round() * unit
}

/// The observer's eigenvalues and where they came from (report key `observer`).
#[derive(Clone, Debug, Serialize)]
struct ObserverReport {
    /// "config", "default" or "chosen from the recording".
    source: &'static str,
    eigenvalues_hz: [f32; 3],
    /// 1/T of the recording.
    sample_rate_hz: f64,
    /// Median |mechanical speed|, measured from the sensor vector's phase advance.
    speed_rad_s: f64,
    speed_rev_s: f64,
    /// m·N·speed of the lowest error harmonic m the path bank nulls (Hz); null without paths.
    lowest_error_harmonic_hz: Option<f64>,
    /// Why this set.
    reason: String,
}

/// The observer's eigenvalues when the config file does not set them: the default
/// [100, 10, 1] Hz wherever it suits the recording, else that set scaled down (the 10:1
/// spacing the adaptation is tuned for kept) to the fastest one that satisfies both
///
/// * the sample rate, with margin: 2π·λ1·T ≤ 0.1, half the core's limit (Euler's pole
///   error ~1 %, and a set computed to the limit can fail it by f32 rounding), and
/// * the speed: the lowest error harmonic of the path bank, f_e = m·N·speed, at or above
///   the middle eigenvalue. The MRAS sees a harmonic only through
///   H = Π s/(s + λi) at j·2π·f_e; there |H| ≥ 0.07, above the compensation's floor
///   (0.05), so the adaptation runs at its full rate. Measured on the extreme sensor at
///   N = 1, 1 rev/s, 40 revolutions: 1 386x at 1 kHz with λ2 = f_e; 138x with
///   λ2 = 3.2·f_e (|H| = 0.009); 2x at 2 kHz with λ2 = 6·f_e (|H| = 0.002, below the gate
///   `min_h`: the offset path never adapts).
///
/// The fastest such set, not a slower one: without `torque_nm` the observer follows the
/// shaft's real speed changes only through its bandwidth (θ̂ - θ = -H·θ), so slowing it
/// further trades motion it no longer follows for noise it filters.
///
/// The default suits when the core accepts it (2π·100 Hz·T ≤ 0.2) and f_e ≥ 10 Hz (N = 2:
/// 5 rev/s); the 20 kHz recordings the tests replay are all in that range, and their
/// outputs are unchanged. Below the speed gate `gates.min_speed_rad_s` the core does not
/// adapt with any observer: then the default is kept if the core accepts it, and
/// otherwise replay refuses and asks for `[observer] eigenvalues_hz`.
fn observer_eigenvalues(
    file: &CoreConfigFile,
    cfg: &mut Config,
    front: &FrontEnd,
    r: &Recording,
    period_s: f64,
) -> Result<ObserverReport> {
    let n = cfg.sensor_periods;
    let speed_rad_s = median_speed_rad_s(r, front, n, period_s);
    let lowest_m = cfg.paths().iter().map(|p| p.error_harmonic()).min();
    let f_e_hz = lowest_m.map(|m| m as f64 * n as f64 * speed_rad_s / TAU);
    let mut report = ObserverReport {
        source: "config",
        eigenvalues_hz: cfg.observer.eigenvalues_hz,
        sample_rate_hz: 1.0 / period_s,
        speed_rad_s,
        speed_rev_s: speed_rad_s / TAU,
        lowest_error_harmonic_hz: f_e_hz,
        reason: String::new(),
    };
    if file.sets("observer.eigenvalues_hz") {
        report.reason = "set by the config file".into();
        return Ok(report);
    }
    let default_valid = match cfg.validate() {
        Ok(()) => true,
        Err(e) if e.field == "observer.eigenvalues_hz" => false,
        // A field checked before the eigenvalues (N, the input scaling): the caller's
        // validation names it, and the speed measured through it would mean nothing.
        Err(_) => {
            report.reason = "the default (the configuration is refused)".into();
            return Ok(report);
        }
    };
    let default = cfg.observer.eigenvalues_hz;
    let [fastest_hz, middle_hz] = [default[0] as f64, default[1] as f64];

    let harmonic = |f: f64| {
        format!(
            "the lowest error harmonic ({f:.3} Hz, m = {}, N = {n})",
            lowest_m.unwrap_or(0)
        )
    };
    report.source = "default";
    let s_see = match f_e_hz {
        None => f64::INFINITY,
        Some(f) if speed_rad_s > 0.0 && speed_rad_s >= cfg.gates.min_speed_rad_s as f64 => {
            f / middle_hz
        }
        Some(_) => {
            let why = format!(
                "the shaft turns at {:.3} rev/s (median |speed| {speed_rad_s:.3} rad/s), too \
                 slow for the MRAS to adapt with any observer (gates.min_speed_rad_s = {} rad/s)",
                report.speed_rev_s, cfg.gates.min_speed_rad_s
            );
            if !default_valid {
                bail!(
                    "{}: the default observer eigenvalues {default:?} Hz are too fast for the \
                     control period {:.3} µs, and none can be chosen from the recording: {why}; \
                     set [observer] eigenvalues_hz in a --config file",
                    r.name,
                    period_s * 1e6
                );
            }
            report.reason = format!(
                "{why}; the default kept (set [observer] eigenvalues_hz and \
                 gates.min_speed_rad_s in a --config file to adapt at this speed)"
            );
            eprintln!("replay: note: {}", report.reason);
            return Ok(report);
        }
    };
    if default_valid && s_see >= 1.0 {
        report.reason = match f_e_hz {
            Some(f) => format!(
                "valid at this sample rate, and {} at or above its middle eigenvalue",
                harmonic(f)
            ),
            None => "valid at this sample rate (no paths to see)".into(),
        };
        return Ok(report);
    }
    let s_rate = CHOSEN_MAX_LAMBDA_T / (TAU * fastest_hz * period_s);
    let scale = round_2_digits(s_rate.min(s_see).min(1.0));
    cfg.observer.eigenvalues_hz = default.map(|v| (v as f64 * scale) as f32);
    report.source = "chosen from the recording";
    report.eigenvalues_hz = cfg.observer.eigenvalues_hz;
    let why_not_default = if default_valid {
        format!(
            "its middle eigenvalue ({middle_hz} Hz) is above {}",
            harmonic(f_e_hz.unwrap_or(0.0))
        )
    } else {
        "it is too fast for the sample rate".into()
    };
    let set_by = if s_see < s_rate {
        "the speed"
    } else {
        "the sample rate"
    };
    report.reason = format!(
        "not the default {default:?} Hz: {why_not_default}; scaled by {scale} (10:1 spacing \
         kept) to the fastest set with 2π·λ1·T <= {CHOSEN_MAX_LAMBDA_T} (half the core's \
         limit) and the lowest error harmonic at or above its middle eigenvalue, here set by \
         {set_by}"
    );
    Ok(report)
}

/// What replay runs: the core configuration, the front end and how each was chosen.
struct Setup {
    cfg: Config,
    front: FrontEnd,
    /// The min/max scaling the raw sensor is scored through (`front` unless an ellipse
    /// fit replaced it).
    raw_front: FrontEnd,
    /// The scaling estimated from the recording (not given by `[input]`): "estimated
    /// from min/max", "ellipse fit" or "config".
    scaling_source: &'static str,
    observer: ObserverReport,
    survey: Option<SurveyReport>,
    sensor_periods: SensorPeriodsReport,
    bank: BankReport,
    motion: MotionReport,
}

/// Where the path bank came from (report key `bank`).
#[derive(Clone, Debug, Serialize)]
struct BankReport {
    /// "config", "data" or "default".
    source: &'static str,
    reason: String,
}

/// The scaled sensor vector's angle of row `k` (rad, sensor electrical).
fn sensor_angle_rad(r: &Recording, front: &FrontEnd, k: usize) -> f64 {
    let x = (r.x[k] as f64 - front.offset_x as f64) * front.gain_x as f64;
    let y = (r.y[k] as f64 - front.offset_y as f64) * front.gain_y as f64;
    y.atan2(x)
}

/// The raw sensor's mechanical error against theta_rad, row by row, its constant (a
/// circular mean, sensor electrical: the sensor's zero is arbitrary) removed.
fn raw_error_rad(r: &Recording, front: &FrontEnd, n: u16) -> Vec<f64> {
    let n = n as f64;
    let e: Vec<f64> = (0..r.rows())
        .map(|k| sensor_angle_rad(r, front, k) - n * r.theta_rad[k])
        .collect();
    let (sn, cs) = e
        .iter()
        .fold((0.0, 0.0), |(s, c), v| (s + v.sin(), c + v.cos()));
    let c = f64::atan2(sn, cs);
    e.iter().map(|v| wrap_pi(v - c) / n).collect()
}

/// The scaling an ellipse fit of the whole recording gives (offsets, amplitude ratio and
/// quadrature: the sensor's m = 1, 2 errors from the vector's shape, which the shaft's
/// motion does not change), common gain 1/ax.
fn ellipse_front_end(r: &Recording, base: &FrontEnd) -> Result<FrontEnd> {
    let samples: Vec<(f32, f32)> = r.x.iter().copied().zip(r.y.iter().copied()).collect();
    let fit = crate::baselines::Ellipse::fit(&samples)
        .map_err(|e| anyhow!("{}: ellipse fit of x, y: {e}", r.name))?;
    let p = fit.params();
    // x = ax·cos θ + ox, y = ay·sin(θ + φ) + oy: ax from x's RMS over the file.
    let ms =
        r.x.iter()
            .map(|&x| (x as f64 - p.offset_x).powi(2))
            .sum::<f64>()
            / r.rows() as f64;
    let g = 1.0 / (2.0 * ms).sqrt();
    let (sin_q, cos_q) = p.quadrature_rad.sin_cos();
    let front = FrontEnd {
        offset_x: p.offset_x as f32,
        offset_y: p.offset_y as f32,
        gain_x: g as f32,
        gain_y: (g / (p.amplitude_ratio * cos_q)) as f32,
        skew: (-sin_q / cos_q) as f32,
        ..*base
    };
    front
        .validate()
        .map_err(|e| anyhow!("{}: ellipse fit: {e}", r.name))?;
    Ok(front)
}

/// The core configuration: `--config` (or the defaults), N from the file, the flag, the
/// recording or the default, observer eigenvalues from the file or chosen from the
/// recording, paths from the file, the survey or the defaults, the shaft's motion at
/// m = 1, 2 checked against theta_rad; and the front end, its scaling from the file or
/// estimated.
fn build_config(a: &Args, r: &Recording, period_s: f64) -> Result<Setup> {
    let file = match &a.config {
        Some(p) => {
            let origin = p.display().to_string();
            let text = fs::read_to_string(p).with_context(|| format!("{origin}: cannot read"))?;
            CoreConfigFile::parse(&text, &origin)?
        }
        None => CoreConfigFile::parse("", "default configuration")?,
    };
    let mut cfg = Config {
        sample_period_s: period_s as f32,
        ..file.config
    };
    let estimated = !file.input_given();
    let mut front = file.input;
    if estimated {
        let [ox, gx, oy, gy] = estimate_scaling(r)?;
        (front.offset_x, front.gain_x, front.offset_y, front.gain_y) = (ox, gx, oy, gy);
    }
    let has_theta = !r.theta_rad.is_empty();

    // N: the file, the flag, the reference, the default.
    let no_travel = |reason: String| SensorPeriodsReport {
        source: "default",
        value: DEFAULT_SENSOR_PERIODS,
        electrical_travel_rad: None,
        mechanical_travel_rad: None,
        ratio: None,
        reason,
    };
    let n_report = if file.sets("sensor_periods") {
        SensorPeriodsReport {
            source: "config",
            value: cfg.sensor_periods,
            reason: "`sensor_periods` in the config file".into(),
            ..no_travel(String::new())
        }
    } else if let Some(n) = a.sensor_periods {
        if n == 0 {
            bail!("--sensor-periods must be at least 1");
        }
        SensorPeriodsReport {
            source: "--sensor-periods",
            value: n,
            reason: "given by --sensor-periods".into(),
            ..no_travel(String::new())
        }
    } else if has_theta {
        front.validate().map_err(|e| file.locate(e))?;
        let (n, mut rep) =
            replay_checks::sensor_periods_from_reference(&r.name, &r.theta_rad, |k| {
                sensor_angle_rad(r, &front, k)
            })?;
        match n {
            Some(n) => rep.value = n,
            None => {
                rep.source = "default";
                rep.value = DEFAULT_SENSOR_PERIODS;
                rep.reason = format!(
                    "{}; the default N = {DEFAULT_SENSOR_PERIODS} (give --sensor-periods)",
                    rep.reason
                );
            }
        }
        rep
    } else {
        no_travel(format!(
            "no theta_rad column to read it from: the default N = {DEFAULT_SENSOR_PERIODS} \
             (give --sensor-periods)"
        ))
    };
    cfg.sensor_periods = n_report.value;

    let locate = |e: mras::ConfigError| {
        let why = match e.field {
            "observer.eigenvalues_hz" | "sample_period_s" => format!(
                " (control period {:.3} µs derived from {}; set [observer] eigenvalues_hz \
                 in a --config file)",
                period_s * 1e6,
                r.name
            ),
            f if f.starts_with("input.") && estimated => {
                format!(" (scaling estimated from {})", r.name)
            }
            _ => String::new(),
        };
        let mut located = file.locate(e);
        located.problem.push_str(&why);
        located
    };
    // The front end first: the speed the eigenvalues are chosen by is measured through it.
    front.validate().map_err(locate)?;
    let raw_front = front;
    let mut observer = observer_eigenvalues(&file, &mut cfg, &front, r, period_s)?;
    cfg.validate().map_err(locate)?;

    // The bank: the file's `paths` win; then the flag; then from the data.
    let asked_data = a.paths_from_data || a.bank == Some(BankChoice::Data);
    if a.paths_from_data && a.bank == Some(BankChoice::Default) {
        bail!("--paths-from-data and --bank default: choose one");
    }
    let from_config = file.sets("paths");
    if from_config && asked_data {
        bail!(
            "{} and `paths` in the --config file: choose one",
            if a.paths_from_data {
                "--paths-from-data"
            } else {
                "--bank data"
            }
        );
    }

    // The shaft's motion where the sensor's m = 1, 2 land, from the reference.
    let mut motion = if has_theta {
        let raw_e = raw_error_rad(r, &raw_front, cfg.sensor_periods);
        replay_checks::shaft_motion(
            &r.theta_rad,
            &r.t_s,
            r.rows() / 2..r.rows(),
            cfg.sensor_periods,
            |k| raw_e[k],
        )
        .unwrap_or_else(|| {
            MotionReport::not_measured(
                "the second half of theta_rad holds less than a whole revolution".into(),
            )
        })
    } else {
        MotionReport::not_measured(
            "no theta_rad column: the shaft's own motion is not measured, and at one speed \
             the sensor alone cannot tell it from its error at m = 1, 2; they are corrected \
             as if the shaft turned evenly"
                .into(),
        )
    };
    let flagged = motion.flagged();
    let mut scaling_source = if estimated {
        "estimated from min/max"
    } else {
        "config"
    };
    let leave_m12 = !flagged.is_empty() && !from_config;
    // Without the fit (a recording it cannot fit), m = 1, 2 are left to the min/max
    // scaling, said so in the action.
    let mut fit_note = String::new();
    if leave_m12 && estimated {
        match ellipse_front_end(r, &front) {
            Ok(f) => {
                front = f;
                scaling_source = "ellipse fit";
            }
            Err(e) => fit_note = format!(" (no ellipse fit: {e:#})"),
        }
    }

    let (bank, survey) = if from_config {
        let b = BankReport {
            source: "config",
            reason: "`paths` in the config file".into(),
        };
        (b, None)
    } else if a.bank == Some(BankChoice::Default) {
        let b = BankReport {
            source: "default",
            reason: "--bank default: the core's fixed bank".into(),
        };
        (b, None)
    } else {
        let samples = Samples {
            t_s: &r.t_s,
            x: &r.x,
            y: &r.y,
            torque_nm: &r.torque_nm,
        };
        match survey::survey(&cfg, &front, &samples) {
            Ok(s) => {
                // The survey's bank, and the fixed bank's paths at the harmonics it left
                // out, where it has room. The rounds give paths to harmonics above a
                // quarter of the largest still without one, so a smaller harmonic (a
                // product of the large ones, a few % of them) can stay without a path:
                // the extreme sensor at N = 1, 1 kHz, 40 revolutions, 1 179x with the
                // survey's bank (offset, C/D, h4, h5), 1 374x with the fixed one. And a
                // recording that ends between rounds keeps the first round's bank:
                // the extreme sensor at N = 2, 16 revolutions, 3 525x against 5 184x.
                // With the fixed bank's paths joined, neither is below the fixed bank.
                let mut kinds = s.kinds.clone();
                let mut added = Vec::new();
                for p in Config::default().paths() {
                    let m = p.error_harmonic();
                    let covered = kinds.iter().any(|k| k.error_harmonic() == m);
                    if !covered && kinds.len() < mras::MAX_PATHS {
                        kinds.push(*p);
                        added.push(path_toml_name(*p));
                    }
                }
                kinds.sort_by_key(|k| k.error_harmonic());
                let joined = if added.is_empty() {
                    String::new()
                } else {
                    format!(", with the fixed bank's {} joined", added.join(", "))
                };
                let reason = if s.complete {
                    format!("the survey's bank{joined}")
                } else {
                    format!(
                        "the survey's last round's bank (the recording ended before the grown \
                         bank converged and was surveyed again){joined}"
                    )
                };
                cfg.set_paths(&kinds).map_err(locate)?;
                (
                    BankReport {
                        source: "data",
                        reason,
                    },
                    Some(s),
                )
            }
            // Too short for the survey: the default bank, said so.
            Err(e) if !asked_data => {
                let b = BankReport {
                    source: "default",
                    reason: format!(
                        "the core's fixed bank: the bank could not be chosen from the data \
                         ({e:#})"
                    ),
                };
                (b, None)
            }
            Err(e) => return Err(e.context(r.name.clone())),
        }
    };

    if !flagged.is_empty() {
        let harmonics: Vec<String> = motion
            .harmonics
            .iter()
            .filter(|h| h.flagged)
            .map(|h| {
                format!(
                    "m = {} (the shaft's {}x: {:.3} mrad of motion, raw sensor error {:.3} mrad)",
                    h.m, h.mechanical_harmonic, h.motion_mrad, h.raw_error_mrad
                )
            })
            .collect();
        motion.warning = Some(format!(
            "the shaft moves at {} above {:.3} mrad: at one speed the MRAS takes that motion \
             for sensor error (docs/theory.md §9); a corrected angle there is not claimed",
            harmonics.join(", "),
            motion.threshold_mrad
        ));
        if leave_m12 {
            let dropped: Vec<PathKind> = flagged
                .iter()
                .filter_map(|&m| mras::survey::path_for(m))
                .collect();
            let kept: Vec<PathKind> = cfg
                .paths()
                .iter()
                .copied()
                .filter(|p| !dropped.contains(p))
                .collect();
            cfg.set_paths(&kept).map_err(locate)?;
            // The eigenvalues again, for the bank's new lowest harmonic.
            cfg.observer = file.config.observer;
            observer = observer_eigenvalues(&file, &mut cfg, &front, r, period_s)?;
            motion.action = Some(
                format!(
                    "m = {flagged:?} left out of the bank ({}): corrected there only by {}, \
                 not fitted to the motion",
                    dropped
                        .iter()
                        .map(|p| path_toml_name(*p))
                        .collect::<Vec<_>>()
                        .join(", "),
                    if scaling_source == "ellipse fit" {
                        "the front end's ellipse fit (offsets, amplitude ratio, quadrature: the \
                     vector's shape, which the motion does not change)"
                    } else if estimated {
                        "the min/max scaling"
                    } else {
                        "the [input] scaling"
                    },
                ) + &fit_note,
            );
        } else {
            motion.action = Some(
                "none: `paths` in the config file are used as given (leave `offset` and \
                 `amplitude-quadrature` out to keep m = 1, 2 from being fitted to the motion)"
                    .into(),
            );
        }
    }
    cfg.validate().map_err(locate)?;
    Ok(Setup {
        cfg,
        front,
        raw_front,
        scaling_source,
        observer,
        survey,
        sensor_periods: n_report,
        bank,
        motion,
    })
}

/// A path's name in the TOML `paths` list: `offset`, `amplitude-quadrature`, `h4`, `h-2`.
pub fn path_toml_name(kind: PathKind) -> String {
    match kind {
        PathKind::Offset => "offset".into(),
        PathKind::AmplitudeQuadrature => "amplitude-quadrature".into(),
        PathKind::Harmonic(h) => format!("h{h}"),
    }
}

/// Column name of a path in OUT.csv: `offset`, `amplitude_quadrature`, `h4`, `h-2`.
pub fn path_column_name(kind: PathKind) -> String {
    match kind {
        PathKind::AmplitudeQuadrature => "amplitude_quadrature".into(),
        k => path_toml_name(k),
    }
}

/// Samples the core refused, per fault kind (report keys); `loss_of_lock` counts the
/// times a locked core lost its lock (it re-acquires by itself).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct FaultCounts {
    pub non_finite_input: u64,
    pub sensor_lost: u64,
    pub sensor_saturated: u64,
    pub loss_of_lock: u64,
    pub numerical_overflow: u64,
}

impl FaultCounts {
    fn count(&mut self, f: Fault) {
        *match f {
            Fault::NonFiniteInput => &mut self.non_finite_input,
            Fault::SensorLost => &mut self.sensor_lost,
            Fault::SensorSaturated => &mut self.sensor_saturated,
            Fault::LossOfLock => &mut self.loss_of_lock,
            Fault::NumericalOverflow => &mut self.numerical_overflow,
        } += 1;
    }

    fn total(&self) -> u64 {
        self.non_finite_input
            + self.sensor_lost
            + self.sensor_saturated
            + self.loss_of_lock
            + self.numerical_overflow
    }

    fn summary(&self) -> String {
        let parts: Vec<String> = [
            ("non_finite_input", self.non_finite_input),
            ("sensor_lost", self.sensor_lost),
            ("sensor_saturated", self.sensor_saturated),
            ("loss_of_lock", self.loss_of_lock),
            ("numerical_overflow", self.numerical_overflow),
        ]
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(k, n)| format!("{k} {n}"))
        .collect();
        if parts.is_empty() {
            "none".into()
        } else {
            parts.join(", ")
        }
    }
}

#[derive(Serialize)]
struct InputScalingReport {
    /// "config", "estimated from min/max" or "ellipse fit".
    source: &'static str,
    offset_x: f32,
    offset_y: f32,
    gain_x: f32,
    gain_y: f32,
    /// y += skew·x after scaling (the ellipse fit's quadrature; 0 otherwise).
    skew: f32,
}

#[derive(Serialize)]
struct CoefficientReport {
    path: String,
    re: f32,
    im: f32,
}

#[derive(Serialize)]
struct ConvergenceReport {
    revs_adapted: u32,
    converged: bool,
    /// Per path, configuration order (rad, sensor electrical).
    residual_rad: Vec<f32>,
    /// Per path, relative to |Z|.
    change_per_rev: Vec<f32>,
    /// Paths that did not see their error lately (|H| below `gates.min_h` at this speed):
    /// not converged, whatever their residual reads.
    unseen_paths: Vec<String>,
}

/// Spatial harmonics m of θrm the error is broken down into (m = 1..16: what a path
/// reaches with N = 1).
pub const SPECTRUM_HARMONICS: u32 = 16;

#[derive(Clone, Serialize)]
pub struct ErrorStats {
    pub pk_pk_rad: f64,
    pub rms_rad: f64,
    pub pk_pk_mrad: f64,
    pub rms_mrad: f64,
    /// RMS of the spatial harmonics m = 1, 2 of θrm (where, on one speed, a shaft's
    /// once- and twice-per-revolution motion and the sensor's error coincide) and of
    /// m = 3..16, from `harmonics_mrad` (√(Σ a²/2)).
    pub rms_m1_2_mrad: f64,
    pub rms_m3_16_mrad: f64,
    /// Amplitude of each spatial harmonic m = 1..16 of θrm (index m - 1).
    pub harmonics_mrad: Vec<f64>,
}

impl ErrorStats {
    fn of<const B: usize>(e: &SpatialError<B>) -> Self {
        let (pp, rms) = (e.pk_pk_rad(), e.rms_rad());
        let harmonics_mrad: Vec<f64> = (1..=SPECTRUM_HARMONICS)
            .map(|m| e.harmonic_amplitude_rad(m) * 1e3)
            .collect();
        let band = |ms: std::ops::Range<usize>| {
            (harmonics_mrad[ms].iter().map(|a| 0.5 * a * a).sum::<f64>()).sqrt()
        };
        Self {
            pk_pk_rad: pp,
            rms_rad: rms,
            pk_pk_mrad: pp * 1e3,
            rms_mrad: rms * 1e3,
            rms_m1_2_mrad: band(0..2),
            rms_m3_16_mrad: band(2..SPECTRUM_HARMONICS as usize),
            harmonics_mrad,
        }
    }
}

#[derive(Serialize)]
pub struct SpatialErrorReport {
    /// How and where the error was measured.
    pub method: String,
    /// First and last data row (1-based) of the measured window.
    pub first_row: usize,
    pub last_row: usize,
    /// Rows in the window the core accepted (refused samples are not scored).
    pub scored_rows: usize,
    pub filled_bins: usize,
    pub raw: ErrorStats,
    pub corrected: ErrorStats,
    /// raw pk-pk / corrected pk-pk.
    pub reduction: f64,
}

#[derive(Serialize)]
struct Report {
    input: String,
    output: String,
    config: Option<String>,
    rows: usize,
    sample_period_s: f32,
    sensor_periods: u16,
    /// Where N came from.
    sensor_periods_source: SensorPeriodsReport,
    paths: Vec<String>,
    /// Where the paths came from.
    bank: BankReport,
    input_scaling: InputScalingReport,
    /// The shaft's motion at the sensor's m = 1, 2 (from theta_rad) and what replay did.
    motion: MotionReport,
    observer: ObserverReport,
    /// With the bank from the data: the error spectrum it was chosen from.
    #[serde(skip_serializing_if = "Option::is_none")]
    survey: Option<SurveyReport>,
    faults: FaultCounts,
    faults_total: u64,
    /// Line of the first loss of lock (adaptation pauses until the core has re-acquired
    /// the lock by itself).
    first_loss_of_lock_line: Option<u64>,
    final_coefficients: Vec<CoefficientReport>,
    convergence: ConvergenceReport,
    /// Null without a theta_rad column (see `spatial_error_note`).
    spatial_error: Option<SpatialErrorReport>,
    spatial_error_note: Option<String>,
}

/// Raw and corrected spatial error over `window`, both against theta_rad with their
/// constant offsets removed.
///
/// Each constant is first taken out as a circular mean (raw: sensor electrical, so an
/// arbitrary sensor-to-reference zero works; corrected: mechanical, so a wrapped or
/// offset reference works) and the rest wrapped to (-π, π]: that handles the sensor's
/// electrical wrap without assuming where the reference's zero is.
fn spatial_error(
    r: &Recording,
    cfg: &Config,
    inp: &FrontEnd,
    window: std::ops::Range<usize>,
    theta_hat_rad: &[f64],
    accepted: &[bool],
) -> SpatialErrorReport {
    let n = cfg.sensor_periods as f64;
    let raw_e = |k: usize| {
        let xs = (r.x[k] as f64 - inp.offset_x as f64) * inp.gain_x as f64;
        let ys = (r.y[k] as f64 - inp.offset_y as f64) * inp.gain_y as f64;
        ys.atan2(xs) - n * r.theta_rad[k]
    };
    let hat_e = |k: usize| theta_hat_rad[k - window.start] - r.theta_rad[k];
    let scored = || window.clone().filter(|k| accepted[k - window.start]);
    let circular_mean = |f: &dyn Fn(usize) -> f64| {
        let (s, c) = scored().fold((0.0, 0.0), |(s, c), k| {
            let e = f(k);
            (s + e.sin(), c + e.cos())
        });
        f64::atan2(s, c)
    };
    let (raw_c, hat_c) = (circular_mean(&raw_e), circular_mean(&hat_e));
    let mut raw = SpatialError::<ERROR_BINS>::new();
    let mut hat = SpatialError::<ERROR_BINS>::new();
    for k in scored() {
        raw.add(r.theta_rad[k], wrap_pi(raw_e(k) - raw_c) / n);
        hat.add(r.theta_rad[k], wrap_pi(hat_e(k) - hat_c));
    }
    let (raw_s, hat_s) = (ErrorStats::of(&raw), ErrorStats::of(&hat));
    let reduction = raw_s.pk_pk_rad / hat_s.pk_pk_rad;
    SpatialErrorReport {
        method: format!(
            "second half of the file (rows {}..{}, after commissioning); error vs theta_rad \
             binned in {ERROR_BINS} bins of reference angle, constant offset removed; raw = \
             atan2 of the scaled input vector / N, corrected = theta_hat",
            window.start + 1,
            window.end
        ),
        first_row: window.start + 1,
        last_row: window.end,
        scored_rows: scored().count(),
        filled_bins: hat.filled_bins(),
        raw: raw_s,
        corrected: hat_s,
        reduction,
    }
}

/// Append a number's shortest round-trip form (`Display`) as one CSV field.
fn put<W: std::io::Write>(
    w: &mut csv::Writer<W>,
    buf: &mut String,
    v: impl std::fmt::Display,
) -> csv::Result<()> {
    buf.clear();
    let _ = write!(buf, "{v}");
    w.write_field(buf.as_bytes())
}

pub fn run(a: &Args) -> Result<()> {
    let rec = read_recording(&a.input)?;
    let same_as_input = |p: &Path| match (fs::canonicalize(&a.input), fs::canonicalize(p)) {
        (Ok(i), Ok(o)) => i == o,
        _ => false,
    };
    for (flag, p) in [
        ("--output", Some(&a.output)),
        ("--report", a.report.as_ref()),
    ] {
        if let Some(p) = p {
            if same_as_input(p) {
                bail!("{flag} {} would overwrite the input", p.display());
            }
        }
    }
    if a.report.as_ref().is_some_and(|r| *r == a.output) {
        bail!("--report and --output name the same file");
    }
    let period_s = control_period_s(&rec)?;
    let Setup {
        cfg,
        front,
        raw_front,
        scaling_source,
        observer,
        survey,
        sensor_periods,
        bank,
        motion,
    } = build_config(a, &rec, period_s)?;
    let mut tracker = Tracker::new(cfg)?;
    let paths: Vec<PathKind> = cfg.paths().to_vec();
    let rows = rec.rows();
    let has_theta = !rec.theta_rad.is_empty();
    let window = rows / 2..rows;

    let (out_pending, out_file) = Pending::create(&a.output)?;
    let out_name = a.output.display().to_string();
    let io_err = |e: csv::Error| anyhow!(e).context(out_name.clone());
    let mut w = csv::Writer::from_writer(BufWriter::new(out_file));
    let mut header = vec![
        "t_s".to_string(),
        "theta_hat_rad".into(),
        "omega_hat_rad_s".into(),
    ];
    for p in &paths {
        let c = path_column_name(*p);
        header.push(format!("{c}_re"));
        header.push(format!("{c}_im"));
    }
    w.write_record(&header).map_err(io_err)?;

    let mut faults = FaultCounts::default();
    let mut first_lock_loss = None;
    let mut theta_hat_rad = Vec::with_capacity(if has_theta { window.len() } else { 0 });
    let mut accepted = Vec::with_capacity(theta_hat_rad.capacity());
    let mut buf = String::new();
    let mut next_tenth = 1;
    for k in 0..rows {
        let tq = rec.torque_nm.get(k).copied().unwrap_or(0.0);
        let result = match front.scale(rec.x[k], rec.y[k]) {
            Ok((x, y)) => tracker.step(x, y, tq),
            Err(f) => Err(tracker.refuse(f)),
        };
        if let Err(f) = result {
            faults.count(f);
            if f == Fault::LossOfLock && first_lock_loss.is_none() {
                first_lock_loss = Some(rec.line[k]);
            }
        }
        // The held estimate on a refused sample; on loss of lock the observer has run.
        let est = result.unwrap_or_else(|_| tracker.last_estimate());
        if has_theta && k >= window.start {
            theta_hat_rad.push(est.theta_unwrapped_rad());
            accepted.push(matches!(result, Ok(_) | Err(Fault::LossOfLock)));
        }
        put(&mut w, &mut buf, rec.t_s[k]).map_err(io_err)?;
        put(&mut w, &mut buf, est.theta_unwrapped_rad()).map_err(io_err)?;
        put(&mut w, &mut buf, est.omega_rad_s).map_err(io_err)?;
        for (_, c) in tracker.coefficients().iter() {
            put(&mut w, &mut buf, c.re).map_err(io_err)?;
            put(&mut w, &mut buf, c.im).map_err(io_err)?;
        }
        w.write_record(None::<&[u8]>).map_err(io_err)?;
        if rows > PROGRESS_ROWS && (k + 1) * 10 >= next_tenth * rows {
            eprintln!("replay: {} % ({} of {rows} rows)", next_tenth * 10, k + 1);
            next_tenth += 1;
        }
    }
    let buffered = w
        .into_inner()
        .map_err(|e| anyhow!("{out_name}: {}", e.error()))?;
    buffered
        .into_inner()
        .map_err(|e| anyhow!("{out_name}: {}", e.error()))?
        .sync_all()
        .with_context(|| out_name.clone())?;

    let spatial =
        has_theta.then(|| spatial_error(&rec, &cfg, &raw_front, window, &theta_hat_rad, &accepted));
    let conv = tracker.convergence();
    let coefs = tracker.coefficients();
    let n_paths = paths.len();
    let report = Report {
        input: rec.name.clone(),
        output: out_name.clone(),
        config: a.config.as_ref().map(|p| p.display().to_string()),
        rows,
        sample_period_s: cfg.sample_period_s,
        sensor_periods: cfg.sensor_periods,
        sensor_periods_source: sensor_periods,
        paths: paths.iter().map(|p| path_toml_name(*p)).collect(),
        bank,
        input_scaling: InputScalingReport {
            source: scaling_source,
            offset_x: front.offset_x,
            offset_y: front.offset_y,
            gain_x: front.gain_x,
            gain_y: front.gain_y,
            skew: front.skew,
        },
        motion,
        observer,
        survey,
        faults,
        faults_total: faults.total(),
        first_loss_of_lock_line: first_lock_loss,
        final_coefficients: coefs
            .iter()
            .map(|(k, v)| CoefficientReport {
                path: path_toml_name(k),
                re: v.re,
                im: v.im,
            })
            .collect(),
        convergence: ConvergenceReport {
            revs_adapted: conv.revs_adapted,
            converged: conv.converged,
            residual_rad: conv.residual_rad[..n_paths].to_vec(),
            change_per_rev: conv.change_per_rev[..n_paths].to_vec(),
            unseen_paths: (paths.iter().enumerate())
                .filter(|(i, _)| conv.unseen_paths & (1 << i) != 0)
                .map(|(_, k)| path_toml_name(*k))
                .collect(),
        },
        spatial_error: spatial,
        spatial_error_note: (!has_theta).then(|| {
            format!(
                "{} has no theta_rad column: without a reference angle the error is not measured",
                rec.name
            )
        }),
    };

    let report_pending = match &a.report {
        Some(p) => {
            let (pending, f) = Pending::create(p)?;
            let name = p.display();
            let json = serde_json::to_string_pretty(&report).with_context(|| name.to_string())?;
            let mut f = BufWriter::new(f);
            f.write_all(json.as_bytes())
                .and_then(|_| f.write_all(b"\n"))
                .and_then(|_| f.flush())
                .with_context(|| name.to_string())?;
            Some(pending)
        }
        None => None,
    };
    out_pending.commit()?;
    if let Some(p) = report_pending {
        p.commit()?;
    }
    print_summary(a, &report, period_s);
    Ok(())
}

/// The motion check in one line, when nothing was flagged.
fn motion_line(m: &MotionReport) -> String {
    if m.harmonics.is_empty() {
        return format!("not checked ({})", m.method);
    }
    let each: Vec<String> = m
        .harmonics
        .iter()
        .map(|h| format!("m = {}: {:.4} mrad", h.m, h.motion_mrad))
        .collect();
    format!(
        "{} (below {:.4} mrad: none the MRAS would take for sensor error)",
        each.join(", "),
        m.threshold_mrad
    )
}

fn print_summary(a: &Args, r: &Report, period_s: f64) {
    println!("hil-sim replay: {} -> {}", r.input, r.output);
    println!(
        "  {} rows, control period {:.3} µs ({:.1} Hz, mean t_s step), N = {}",
        r.rows,
        period_s * 1e6,
        1.0 / period_s,
        r.sensor_periods
    );
    println!(
        "  N = {} ({}): {}",
        r.sensor_periods, r.sensor_periods_source.source, r.sensor_periods_source.reason
    );
    let s = &r.input_scaling;
    println!(
        "  input scaling ({}): x = (raw - {}) * {}, y = (raw - {}) * {}{}",
        s.source,
        s.offset_x,
        s.gain_x,
        s.offset_y,
        s.gain_y,
        if s.skew != 0.0 {
            format!(" + {} * x", s.skew)
        } else {
            String::new()
        }
    );
    let o = &r.observer;
    println!(
        "  observer eigenvalues {:?} Hz ({}): {}",
        o.eigenvalues_hz, o.source, o.reason
    );
    println!(
        "    measured: median speed {:.3} rev/s ({:.3} rad/s), sample rate {:.1} Hz{}",
        o.speed_rev_s,
        o.speed_rad_s,
        o.sample_rate_hz,
        o.lowest_error_harmonic_hz
            .map_or(String::new(), |f| format!(
                ", lowest error harmonic {f:.3} Hz"
            ))
    );
    println!(
        "  paths ({}: {}): {}",
        r.bank.source,
        r.bank.reason,
        r.paths.join(", ")
    );
    if let Some(w) = &r.motion.warning {
        println!("  WARNING: {w}");
        if let Some(act) = &r.motion.action {
            println!("    action: {act}");
        }
    }
    if let Some(s) = &r.survey {
        let spectrum: Vec<String> = s.error_mrad.iter().map(|e| format!("{e:.3}")).collect();
        println!(
            "  paths chosen from the data: survey of {:.1} sensor periods until t = {:.3} s, \
             error m = 1..16 [mrad]: {}",
            s.periods,
            s.until_t_s,
            spectrum.join(" ")
        );
        let left = match s.unobserved.as_slice() {
            [] => "none".to_string(),
            m => format!("m = {m:?} (the bank holds {} paths)", mras::MAX_PATHS),
        };
        println!(
            "    floors: noise {:.3} mrad, 1 % of the largest {:.3} mrad; left without a path: \
             {left}; {} survey round(s)",
            s.floor_mrad, s.min_mrad, s.rounds
        );
        if !s.complete {
            println!(
                "    note: the recording ended before the grown bank converged and was surveyed \
                 again: the bank is the last round's (a longer recording lets the rounds finish)"
            );
        }
    }
    if r.motion.warning.is_none() {
        println!("  shaft motion at m = 1, 2: {}", motion_line(&r.motion));
    }
    println!("  faults: {}", r.faults.summary());
    if let Some(line) = r.first_loss_of_lock_line {
        println!(
            "  note: the core lost lock first at line {line} ({} time(s)); adaptation paused \
             each time until the lock was re-acquired",
            r.faults.loss_of_lock
        );
    }
    println!(
        "  convergence: {} revolutions adapted, converged: {}",
        r.convergence.revs_adapted,
        if r.convergence.converged { "yes" } else { "no" }
    );
    if !r.convergence.unseen_paths.is_empty() {
        println!(
            "  note: no error seen lately by {} (|H| below gates.min_h at this speed; \
             slower observer eigenvalues make it visible)",
            r.convergence.unseen_paths.join(", ")
        );
    }
    match &r.spatial_error {
        Some(e) => {
            println!(
                "  spatial error over rows {}..{} (second half, after commissioning), constant removed:",
                e.first_row, e.last_row
            );
            println!(
                "    raw sensor : {:.3} mrad pk-pk, {:.3} mrad rms",
                e.raw.pk_pk_mrad, e.raw.rms_mrad
            );
            println!(
                "    corrected  : {:.4} mrad pk-pk, {:.4} mrad rms  ({:.0}x)",
                e.corrected.pk_pk_mrad, e.corrected.rms_mrad, e.reduction
            );
            println!(
                "    rms at m = 1, 2: raw {:.3}, corrected {:.4} mrad; at m = 3..16: raw {:.3}, \
                 corrected {:.4} mrad",
                e.raw.rms_m1_2_mrad,
                e.corrected.rms_m1_2_mrad,
                e.raw.rms_m3_16_mrad,
                e.corrected.rms_m3_16_mrad
            );
        }
        None => println!(
            "  spatial error: not measured ({})",
            r.spatial_error_note.as_deref().unwrap_or("")
        ),
    }
    println!("  final coefficients (scaled units):");
    for c in &r.final_coefficients {
        println!("    {:<22} {:+.6} {:+.6}j", c.path, c.re, c.im);
    }
    match &a.report {
        Some(p) => println!("  wrote {} and {}", r.output, p.display()),
        None => println!("  wrote {}", r.output),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_column_names() {
        let names: Vec<String> = [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(-2),
        ]
        .into_iter()
        .map(path_column_name)
        .collect();
        assert_eq!(names, ["offset", "amplitude_quadrature", "h4", "h-2"]);
    }

    #[test]
    fn two_significant_digits() {
        for (v, want) in [(0.0999997, 0.1), (0.159, 0.16), (1.0, 1.0), (0.0314, 0.031)] {
            assert!((round_2_digits(v) - want).abs() < 1e-12, "{v}");
        }
    }

    /// The extreme sensor (N = 2) 1 s at rest with noise, then turning at
    /// `speed_rad_s` for `turning_s`, sampled at 10 kHz.
    fn at_rest_then_turning(speed_rad_s: f64, turning_s: f64) -> Recording {
        let sensor = mras_sim::SensorModel::extreme();
        let period_s = 1.0e-4;
        let mut r = Recording {
            name: "test".into(),
            ..Recording::default()
        };
        let rest = 10_000;
        let rows = rest + (turning_s / period_s) as usize;
        for k in 0..rows {
            // Crossings are counted from the first sample's angle, so ±1 mrad of noise
            // at rest sits on one: it must count once, not thousands of times.
            let th = if k < rest {
                if k % 2 == 0 {
                    1e-3
                } else {
                    -1e-3
                }
            } else {
                speed_rad_s * (k - rest) as f64 * period_s
            };
            let (x, y) = sensor.vector(th);
            r.t_s.push(k as f64 * period_s);
            r.x.push(x as f32);
            r.y.push(y as f32);
            r.line.push(k as u64 + 2);
        }
        r
    }

    #[test]
    fn speed_is_timed_over_whole_sensor_periods() {
        for speed_rad_s in [13.0, -13.0, 300.0] {
            let r = at_rest_then_turning(speed_rad_s, 2.0);
            let got = median_speed_rad_s(&r, &FrontEnd::default(), 2, 1.0e-4);
            // The sensor's error (180 mrad pk-pk) drops out over whole periods; what is
            // left is the f32 samples and the linear interpolation of each crossing
            // (measured: 1e-8 at 13 rad/s, 1e-6 at 300 rad/s).
            let rel = got / speed_rad_s.abs() - 1.0;
            assert!(
                rel.abs() < 1e-5,
                "{speed_rad_s} rad/s: measured {got} ({rel:+e})"
            );
        }
        // Shorter than a sensor period: the mean speed over the file.
        let r = at_rest_then_turning(1.0, 0.5);
        let got = median_speed_rad_s(&r, &FrontEnd::default(), 2, 1.0e-4);
        assert!(got > 0.1 && got < 0.5, "{got}");
    }
}

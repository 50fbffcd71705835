//! The offline angle-sensor calibrations drive engineers use today, as baselines for
//! the online MRAS: min/max scaling (VESC, stm32-sine), the Heydemann (1981) ellipse
//! fit, and a position lookup table (VESC, SimpleFOC, moteus) with the constant-speed
//! reference a bench without an encoder has.
//!
//! All angles are sensor-electrical: `atan2(y, x)` of the sensor's two channels.
//! Samples are f32 as the ADC delivers them after scaling; all arithmetic is f64.
//!
//! Sensor convention of this module (and of its tests):
//! `x = ax·cos θ + ox`, `y = ay·sin(θ + φ) + oy`, quadrature error φ on Y.
//! `mras_sim::SensorModel` puts the phase on X instead (`x = bx1·cos(θs + φx1)`,
//! `y = by1·sin θs`); for it, [`EllipseParams::quadrature_rad`] is `-φx1` and the
//! corrected angle is `θs + φx1` (a constant offset, like a mounting error).

use core::f64::consts::{PI, TAU};
use mras_sim::wrap_pi;
use nalgebra::{Matrix5, Vector5};

/// Error when a calibration cannot be fitted from the data given.
#[derive(Debug, Clone, PartialEq)]
pub enum FitError {
    TooFewSamples {
        needed: usize,
        got: usize,
    },
    /// Sample (or reference) `index` is NaN or infinite.
    NonFinite {
        index: usize,
    },
    Degenerate(&'static str),
    /// LUT bin count outside 128..=4096.
    BadBins(usize),
    /// LUT bins that no sample fell into.
    IncompleteCoverage {
        empty_bins: usize,
    },
}

impl std::fmt::Display for FitError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FitError::TooFewSamples { needed, got } => {
                write!(f, "too few samples: needed at least {needed}, got {got}")
            }
            FitError::NonFinite { index } => {
                write!(f, "sample {index} is not finite (NaN or infinite)")
            }
            FitError::Degenerate(why) => write!(f, "degenerate data: {why}"),
            FitError::BadBins(bins) => {
                write!(
                    f,
                    "{bins} LUT bins: must be in {LUT_BINS_MIN}..={LUT_BINS_MAX}"
                )
            }
            FitError::IncompleteCoverage { empty_bins } => write!(
                f,
                "{empty_bins} LUT bins hold no sample: spin at least one whole revolution, \
                 slowly enough to visit every bin"
            ),
        }
    }
}

impl std::error::Error for FitError {}

/// Something that turns one raw (x, y) sample into a corrected sensor-electrical angle
/// in (-π, π].
pub trait Corrector: Send + Sync {
    /// Never panics; a non-finite input may give NaN.
    fn angle_rad(&self, x: f32, y: f32) -> f64;
    fn name(&self) -> &'static str;
}

/// `atan2` with the result in (-π, π] (atan2(-0, -1) is -π).
fn atan2_pi(y: f64, x: f64) -> f64 {
    wrap_pi(y.atan2(x))
}

/// At least `needed` samples, all finite: what every fit checks first.
fn check_samples(samples: &[(f32, f32)], needed: usize) -> Result<(), FitError> {
    if samples.len() < needed {
        return Err(FitError::TooFewSamples {
            needed,
            got: samples.len(),
        });
    }
    match samples
        .iter()
        .position(|(x, y)| !(x.is_finite() && y.is_finite()))
    {
        Some(index) => Err(FitError::NonFinite { index }),
        None => Ok(()),
    }
}

/// The uncorrected sensor: `atan2(y, x)`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Raw;

impl Corrector for Raw {
    fn angle_rad(&self, x: f32, y: f32) -> f64 {
        atan2_pi(y as f64, x as f64)
    }
    fn name(&self) -> &'static str {
        "raw"
    }
}

/// VESC / stm32-sine style: per channel, offset = (max + min)/2 and amplitude =
/// (max - min)/2 from samples over whole revolutions. Removes offsets and amplitude
/// imbalance; a quadrature error φ is left as an error `φ/2 + (φ/2)·cos 2θ`.
#[derive(Debug, Clone, PartialEq)]
pub struct MinMax {
    offset_x: f64,
    offset_y: f64,
    amplitude_x: f64,
    amplitude_y: f64,
}

impl MinMax {
    /// Fewest samples accepted; whole revolutions cannot be checked, so this is only a floor.
    pub const MIN_SAMPLES: usize = 16;

    pub fn fit(samples: &[(f32, f32)]) -> Result<Self, FitError> {
        check_samples(samples, Self::MIN_SAMPLES)?;
        let mut lo = (f64::INFINITY, f64::INFINITY);
        let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        for &(x, y) in samples {
            let (x, y) = (x as f64, y as f64);
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        let (amplitude_x, amplitude_y) = ((hi.0 - lo.0) / 2.0, (hi.1 - lo.1) / 2.0);
        if amplitude_x <= 0.0 || amplitude_y <= 0.0 {
            return Err(FitError::Degenerate("a channel has zero range"));
        }
        Ok(Self {
            offset_x: (hi.0 + lo.0) / 2.0,
            offset_y: (hi.1 + lo.1) / 2.0,
            amplitude_x,
            amplitude_y,
        })
    }

    /// (x, y) offsets, in sample units.
    pub fn offsets(&self) -> (f64, f64) {
        (self.offset_x, self.offset_y)
    }

    /// (x, y) amplitudes, in sample units.
    pub fn amplitudes(&self) -> (f64, f64) {
        (self.amplitude_x, self.amplitude_y)
    }
}

impl Corrector for MinMax {
    fn angle_rad(&self, x: f32, y: f32) -> f64 {
        atan2_pi(
            (y as f64 - self.offset_y) / self.amplitude_y,
            (x as f64 - self.offset_x) / self.amplitude_x,
        )
    }
    fn name(&self) -> &'static str {
        "min-max"
    }
}

/// The ellipse an [`Ellipse`] fit found, in the module's sensor convention
/// (`x = ax·cos θ + ox`, `y = ay·sin(θ + φ) + oy`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EllipseParams {
    pub offset_x: f64,
    pub offset_y: f64,
    /// ay / ax.
    pub amplitude_ratio: f64,
    /// φ, in (-π/2, π/2).
    pub quadrature_rad: f64,
}

/// Heydemann (1981) least-squares ellipse fit: corrects offsets, amplitude ratio and
/// quadrature error, but not harmonics (a distorted sensor is not an ellipse).
///
/// Fit: the samples are centred on their mean and scaled by their RMS radius, then
/// `A x² + B xy + C y² + D x + E y = 1` is solved by linear least squares (algebraic
/// distance, as Heydemann). Fixing the constant is safe after centring: the mean of
/// points on an ellipse lies strictly inside it, so the true conic's constant is
/// never zero there, and it keeps the solve linear (no eigenproblem).
///
/// The model's conic is `u²/ax² + v²/ay² - 2 sin φ·u v/(ax ay) = cos² φ` with
/// `u = x - ox`, `v = y - oy`, hence, for the fitted coefficients (with `A > 0`):
/// - centre: `ox = (B E - 2 C D)/(4AC - B²)`, `oy = (B D - 2 A E)/(4AC - B²)`,
/// - `r = ay/ax = √(A/C)`, `sin φ = -B / (2√(AC))`.
///
/// Correction (Heydemann's, in this convention): `u = x - ox`,
/// `w = (v/r - u·sin φ)/cos φ`; then `(u, w) = ax·(cos θ, sin θ)` is a circle and the
/// angle is `atan2(v/r - u·sin φ, u·cos φ)` (cos φ > 0, so the quadrant is kept).
#[derive(Debug, Clone, PartialEq)]
pub struct Ellipse {
    params: EllipseParams,
    inv_ratio: f64,
    sin_q: f64,
    cos_q: f64,
}

impl Ellipse {
    /// A conic has 5 free coefficients.
    pub const MIN_SAMPLES: usize = 5;

    /// Needs at least 5 samples ([`FitError::TooFewSamples`]); fewer than 5 distinct
    /// ones, collinear data or a fit that is not a real ellipse give
    /// [`FitError::Degenerate`].
    pub fn fit(samples: &[(f32, f32)]) -> Result<Self, FitError> {
        check_samples(samples, Self::MIN_SAMPLES)?;
        let mut distinct: Vec<(f32, f32)> = Vec::with_capacity(Self::MIN_SAMPLES);
        for &s in samples {
            if !distinct.contains(&s) {
                distinct.push(s);
                if distinct.len() == Self::MIN_SAMPLES {
                    break;
                }
            }
        }
        if distinct.len() < Self::MIN_SAMPLES {
            return Err(FitError::Degenerate("fewer than 5 distinct samples"));
        }

        // Centre and scale first: keeps the normal equations well conditioned and the
        // fixed constant valid (see the type's doc).
        let n = samples.len() as f64;
        let (mut mx, mut my) = (0.0, 0.0);
        for &(x, y) in samples {
            mx += x as f64;
            my += y as f64;
        }
        (mx, my) = (mx / n, my / n);
        let mut r2 = 0.0;
        for &(x, y) in samples {
            r2 += (x as f64 - mx).powi(2) + (y as f64 - my).powi(2);
        }
        let scale = (r2 / n).sqrt();
        if !(scale > 0.0 && scale.is_finite()) {
            return Err(FitError::Degenerate("samples have zero spread"));
        }

        let mut m = Matrix5::<f64>::zeros();
        let mut b = Vector5::<f64>::zeros();
        for &(x, y) in samples {
            let (x, y) = ((x as f64 - mx) / scale, (y as f64 - my) / scale);
            let phi = Vector5::new(x * x, x * y, y * y, x, y);
            m += phi * phi.transpose();
            b += phi;
        }
        let svd = m.svd(true, true);
        let s_max = svd.singular_values.max();
        let s_min = svd.singular_values.min();
        // NaN-safe: `<=` alone would let a NaN through.
        if s_min.is_nan() || s_min <= 1e-12 * s_max {
            return Err(FitError::Degenerate(
                "samples do not determine a conic (collinear or too few distinct points)",
            ));
        }
        let p = svd
            .solve(&b, 0.0)
            .map_err(|_| FitError::Degenerate("singular least-squares solve"))?;
        let (mut a, mut bb, mut c, mut d, mut e, mut f) = (p[0], p[1], p[2], p[3], p[4], -1.0);
        let disc = 4.0 * a * c - bb * bb;
        if disc.is_nan() || disc <= 1e-12 * (a * a + bb * bb + c * c) {
            return Err(FitError::Degenerate(
                "fitted conic is not an ellipse (hyperbola or parabola)",
            ));
        }
        if a < 0.0 {
            (a, bb, c, d, e, f) = (-a, -bb, -c, -d, -e, -f);
        }
        let cx = (bb * e - 2.0 * c * d) / disc;
        let cy = (bb * d - 2.0 * a * e) / disc;
        // Conic value at the centre: must be negative for a real (non-empty) ellipse.
        let f_centre = f + (d * cx + e * cy) / 2.0;
        if f_centre.is_nan() || f_centre >= 0.0 {
            return Err(FitError::Degenerate(
                "fitted conic is an imaginary ellipse (no real points)",
            ));
        }
        let sin_q = -bb / (2.0 * (a * c).sqrt());
        let cos_q = (1.0 - sin_q * sin_q).sqrt();
        let ratio = (a / c).sqrt();
        let params = EllipseParams {
            offset_x: mx + scale * cx,
            offset_y: my + scale * cy,
            amplitude_ratio: ratio,
            quadrature_rad: sin_q.asin(),
        };
        if !(params.offset_x.is_finite()
            && params.offset_y.is_finite()
            && ratio.is_finite()
            && cos_q > 0.0)
        {
            return Err(FitError::Degenerate(
                "fitted ellipse has non-finite parameters",
            ));
        }
        Ok(Self {
            params,
            inv_ratio: 1.0 / ratio,
            sin_q,
            cos_q,
        })
    }

    pub fn params(&self) -> EllipseParams {
        self.params
    }
}

impl Corrector for Ellipse {
    fn angle_rad(&self, x: f32, y: f32) -> f64 {
        let u = x as f64 - self.params.offset_x;
        let v = y as f64 - self.params.offset_y;
        atan2_pi(v * self.inv_ratio - u * self.sin_q, u * self.cos_q)
    }
    fn name(&self) -> &'static str {
        "ellipse"
    }
}

/// Fewest LUT bins accepted (coarser tables interpolate harmonics poorly).
pub const LUT_BINS_MIN: usize = 128;
/// Most LUT bins accepted (more than a calibration spin fills reliably).
pub const LUT_BINS_MAX: usize = 4096;

/// VESC / SimpleFOC / moteus style position lookup table: a correction per raw-angle
/// bin, linearly interpolated between bin centres (circularly across ±π).
#[derive(Debug, Clone, PartialEq)]
pub struct Lut {
    /// Correction (rad, in (-π, π]) at the centre of bin k, `-π + (k + ½)·2π/bins`.
    table_rad: Vec<f64>,
    bin_width_rad: f64,
}

impl Lut {
    /// `samples[i]` was taken when the reference angle was `reference_rad[i]`
    /// (unwrapped, continuous, either direction of rotation); the table is indexed by
    /// the raw atan2 angle in `bins` equal bins (128..=4096), each holding the mean of
    /// wrap(reference - raw) of the samples whose raw angle falls in it.
    ///
    /// The mean is circular: first the sin/cos mean as a pivot, then the arithmetic
    /// mean of the corrections unwrapped around it, so a bin whose corrections straddle
    /// ±π is averaged right and a tight bin gets its exact arithmetic mean.
    pub fn fit(
        samples: &[(f32, f32)],
        reference_rad: &[f64],
        bins: usize,
    ) -> Result<Self, FitError> {
        if !(LUT_BINS_MIN..=LUT_BINS_MAX).contains(&bins) {
            return Err(FitError::BadBins(bins));
        }
        if samples.len() != reference_rad.len() {
            return Err(FitError::Degenerate(
                "samples and reference_rad differ in length",
            ));
        }
        check_samples(samples, bins)?;
        if let Some(index) = reference_rad.iter().position(|r| !r.is_finite()) {
            return Err(FitError::NonFinite { index });
        }

        let bin_width_rad = TAU / bins as f64;
        let binned: Vec<(usize, f64)> = samples
            .iter()
            .zip(reference_rad)
            .map(|(&(x, y), &r)| {
                let raw = atan2_pi(y as f64, x as f64);
                let k = (((raw + PI) / bin_width_rad) as usize).min(bins - 1);
                (k, wrap_pi(r - raw))
            })
            .collect();

        let mut sin_cos = vec![(0.0f64, 0.0f64); bins];
        let mut count = vec![0usize; bins];
        for &(k, c) in &binned {
            sin_cos[k].0 += c.sin();
            sin_cos[k].1 += c.cos();
            count[k] += 1;
        }
        let empty_bins = count.iter().filter(|&&n| n == 0).count();
        if empty_bins > 0 {
            return Err(FitError::IncompleteCoverage { empty_bins });
        }
        let mut pivot = vec![0.0f64; bins];
        for k in 0..bins {
            let (s, c) = sin_cos[k];
            if s.hypot(c) < 1e-9 * count[k] as f64 {
                return Err(FitError::Degenerate(
                    "corrections in a LUT bin cancel out (reference inconsistent with samples)",
                ));
            }
            pivot[k] = s.atan2(c);
        }
        let mut dev = vec![0.0f64; bins];
        for &(k, c) in &binned {
            dev[k] += wrap_pi(c - pivot[k]);
        }
        let table_rad = (0..bins)
            .map(|k| wrap_pi(pivot[k] + dev[k] / count[k] as f64))
            .collect();
        Ok(Self {
            table_rad,
            bin_width_rad,
        })
    }

    pub fn bins(&self) -> usize {
        self.table_rad.len()
    }
}

impl Corrector for Lut {
    fn angle_rad(&self, x: f32, y: f32) -> f64 {
        let raw = atan2_pi(y as f64, x as f64);
        if !raw.is_finite() {
            return f64::NAN;
        }
        let bins = self.table_rad.len();
        // Position in bin-centre units: bin k's centre is at p = k.
        let p = (raw + PI) / self.bin_width_rad - 0.5;
        let k0 = p.floor();
        let frac = p - k0;
        let i0 = (k0 as isize).rem_euclid(bins as isize) as usize;
        let i1 = (i0 + 1) % bins;
        let (t0, t1) = (self.table_rad[i0], self.table_rad[i1]);
        wrap_pi(raw + t0 + frac * wrap_pi(t1 - t0))
    }
    fn name(&self) -> &'static str {
        "lut"
    }
}

/// Least-squares line through the points, on centred coordinates (no cancellation in
/// Σx²): the means of x and y, and the slope dy/dx.
pub(crate) fn line_fit(points: impl Iterator<Item = (f64, f64)> + Clone) -> (f64, f64, f64) {
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0usize);
    for (x, y) in points.clone() {
        sx += x;
        sy += y;
        n += 1;
    }
    let n = n.max(1) as f64;
    let (x_mean, y_mean) = (sx / n, sy / n);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (x, y) in points {
        let dx = x - x_mean;
        sxy += dx * (y - y_mean);
        sxx += dx * dx;
    }
    (x_mean, y_mean, sxy / sxx)
}

/// Fewest samples [`constant_speed_reference`] accepts.
pub const CONSTANT_SPEED_MIN_SAMPLES: usize = 16;

/// The reference a real bench has for a LUT spin without an encoder: constant speed
/// assumed. Fits `θ_ref(i) = θ0 + ω·i` by least squares to the unwrapped raw atan2
/// angle over the whole record and returns `θ_ref` for each sample (unwrapped).
///
/// The record must be sampled fast enough to unwrap (< π per sample) and should span
/// whole revolutions. The sensor's periodic error biases the slope by about
/// `0.3·a/(k·R²)` relative for an error `a·sin(kθ)` over R revolutions, and speed
/// ripple (cogging) goes straight into the LUT: both are what a real bench gets.
pub fn constant_speed_reference(samples: &[(f32, f32)]) -> Result<Vec<f64>, FitError> {
    check_samples(samples, CONSTANT_SPEED_MIN_SAMPLES)?;
    let mut unwrapped = Vec::with_capacity(samples.len());
    let mut prev_raw = atan2_pi(samples[0].1 as f64, samples[0].0 as f64);
    let mut acc = prev_raw;
    for &(x, y) in samples {
        let raw = atan2_pi(y as f64, x as f64);
        acc += wrap_pi(raw - prev_raw);
        prev_raw = raw;
        unwrapped.push(acc);
    }
    let span = unwrapped[unwrapped.len() - 1] - unwrapped[0];
    if span.is_nan() || span.abs() < PI {
        return Err(FitError::Degenerate(
            "record covers less than half a revolution; spin whole revolutions",
        ));
    }
    let (i_mean, theta_mean, omega) =
        line_fit(unwrapped.iter().enumerate().map(|(i, &t)| (i as f64, t)));
    let theta0 = theta_mean - omega * i_mean;
    Ok((0..unwrapped.len())
        .map(|i| theta0 + omega * i as f64)
        .collect())
}

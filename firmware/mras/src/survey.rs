//! The sensor's error spectrum, measured before adaptation, and a path bank given to the
//! harmonics that carry error.
//!
//! A bank nulls only the error harmonics it has paths for (paper §V.B). A fixed bank
//! (the default covers m = 1..7) leaves a real sensor's higher harmonics untouched, and
//! spends paths on harmonics that a given sensor does not have. Running the observer with
//! adaptation frozen, ε at sensor harmonic m is the sensor's angle error e_m seen
//! through the observer, ε_m = H(j·m·ω̂s)·e_m (`ObserverGains::error_transfer`), so
//! e_m = ε_m / H: a DFT of ε against θ̂s over whole sensor periods measures the
//! spectrum the bank has to cover.

use crate::complex::Cplx;
use crate::config::{PathKind, MAX_PATHS};
use crate::observer::ObserverGains;
use crate::trig::sqrt_f32;

/// Error harmonics m = 1..=`SURVEY_HARMONICS` of θs are measured; a path exists for each
/// (m = 16 is the largest a path reaches: h = -15).
pub const SURVEY_HARMONICS: usize = 16;

/// Accumulates ε against θ̂s while the observer tracks with adaptation frozen.
#[derive(Clone, Debug)]
pub struct ErrorSurvey {
    /// Σ ε·e^{-j m θ̂s}, m = 1..=16.
    sums: [Cplx; SURVEY_HARMONICS],
    /// Σ ε² and Σ ω̂s (sensor electrical, rad/s) over the samples.
    eps2_sum: f32,
    omega_e_sum: f32,
    samples: u32,
    /// θ̂s advance over the samples (rad, signed): whole sensor periods make the DFT exact.
    advance_rad: f32,
    last_theta_e_rad: Option<f32>,
}

/// What the survey measured: the sensor's angle error per harmonic m of θs (rad,
/// sensor electrical; index m - 1) and the noise floor a harmonic must clear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorSpectrum {
    pub amplitude_rad: [f32; SURVEY_HARMONICS],
    /// Four times the DFT's noise per bin, from the power ε has beyond the harmonics.
    /// Flat in m: sensor noise reaches ε through the same H as the error does, and ε's
    /// noise power is the sensor's (H ≈ 1 over most of the band, the observer's
    /// bandwidth being far below the sample rate).
    pub floor_rad: f32,
    /// Sensor periods the survey covered.
    pub periods: f32,
}

impl Default for ErrorSurvey {
    fn default() -> Self {
        Self {
            sums: [Cplx::ZERO; SURVEY_HARMONICS],
            eps2_sum: 0.0,
            omega_e_sum: 0.0,
            samples: 0,
            advance_rad: 0.0,
            last_theta_e_rad: None,
        }
    }
}

impl ErrorSurvey {
    /// One tracked sample: θ̂s (rad, sensor electrical), ε (rad) and ω̂s (rad/s, sensor
    /// electrical, i.e. N·ω̂rm).
    pub fn add(&mut self, theta_e_rad: f32, eps_rad: f32, omega_e_rad_s: f32) {
        if !(theta_e_rad.is_finite() && eps_rad.is_finite() && omega_e_rad_s.is_finite()) {
            return;
        }
        if let Some(prev) = self.last_theta_e_rad {
            let mut d = theta_e_rad - prev;
            // θ̂s is wrapped to [0, 2π): unwrap the step.
            if d > core::f32::consts::PI {
                d -= core::f32::consts::TAU;
            } else if d < -core::f32::consts::PI {
                d += core::f32::consts::TAU;
            }
            self.advance_rad += d;
        }
        self.last_theta_e_rad = Some(theta_e_rad);
        let (s, c) = crate::trig::sin_cos_f32(theta_e_rad);
        // e^{-j m θ} by repeated multiplication: one rotation per harmonic.
        let step = Cplx::new(c, -s);
        let mut rot = step;
        for sum in &mut self.sums {
            *sum += rot.scale(eps_rad);
            rot = rot * step;
        }
        self.eps2_sum += eps_rad * eps_rad;
        self.omega_e_sum += omega_e_rad_s;
        self.samples += 1;
    }

    /// Sensor periods covered so far (θ̂s advance / 2π, unsigned).
    pub fn periods(&self) -> f32 {
        libm::fabsf(self.advance_rad) / core::f32::consts::TAU
    }

    /// The spectrum, the observer's transfer undone at the mean speed; `None` before a
    /// sensor period or at standstill.
    pub fn spectrum(&self, gains: &ObserverGains) -> Option<ErrorSpectrum> {
        let k = self.samples as f32;
        let omega_e = self.omega_e_sum / k.max(1.0);
        // (Non-finite sums never happen: `add` takes finite values only.)
        if self.periods() < 1.0 || omega_e == 0.0 {
            return None;
        }
        let mut eps_m = [0.0f32; SURVEY_HARMONICS];
        let mut harmonic_power = 0.0;
        for (a, s) in eps_m.iter_mut().zip(&self.sums) {
            *a = 2.0 * s.abs() / k;
            harmonic_power += 0.5 * *a * *a;
        }
        // What is not in the harmonics is noise (and harmonics above 16); its DFT bin
        // amplitude is 2σ/√K.
        let noise_power = (self.eps2_sum / k - harmonic_power).max(0.0);
        let bin_noise = 2.0 * sqrt_f32(noise_power / k);
        let mut out = ErrorSpectrum {
            amplitude_rad: [0.0; SURVEY_HARMONICS],
            floor_rad: 4.0 * bin_noise,
            periods: self.periods(),
        };
        for (m, (a, e)) in out.amplitude_rad.iter_mut().zip(eps_m).enumerate() {
            *a = e * gains.inverse_error_transfer((m + 1) as f32 * omega_e).abs();
        }
        Some(out)
    }
}

/// The path that nulls error harmonic `m` (1..=16): offset, C/D, then h = m + 1, and
/// h = 1 - m where m + 1 would pass |h| ≤ 15.
pub fn path_for(m: u8) -> Option<PathKind> {
    match m {
        1 => Some(PathKind::Offset),
        2 => Some(PathKind::AmplitudeQuadrature),
        3..=14 => Some(PathKind::Harmonic(m as i8 + 1)),
        15..=16 => Some(PathKind::Harmonic(1 - m as i8)),
        _ => None,
    }
}

/// A bank chosen from a spectrum, and the harmonics above the floor left without a path.
#[derive(Clone, Debug, PartialEq)]
pub struct Allocation {
    /// In order of m.
    pub paths: heapless::Vec<PathKind, MAX_PATHS>,
    /// Harmonics m above the floor (and `min_rad`) with no path: the bank was full.
    pub unobserved: heapless::Vec<u8, SURVEY_HARMONICS>,
}

/// The `max_paths` (≤ [`MAX_PATHS`]) largest harmonics that clear their noise floor and
/// `min_rad` (rad, sensor electrical), each given its path.
pub fn allocate(spectrum: &ErrorSpectrum, max_paths: usize, min_rad: f32) -> Allocation {
    let mut order: [u8; SURVEY_HARMONICS] = core::array::from_fn(|m| m as u8 + 1);
    let amp = |m: u8| spectrum.amplitude_rad[m as usize - 1];
    // Largest first; insertion sort (16 entries, no allocation, no panics).
    for i in 1..order.len() {
        let mut j = i;
        while j > 0 && amp(order[j]) > amp(order[j - 1]) {
            order.swap(j, j - 1);
            j -= 1;
        }
    }
    let mut chosen: heapless::Vec<u8, MAX_PATHS> = heapless::Vec::new();
    let mut unobserved = heapless::Vec::new();
    for m in order {
        let a = amp(m);
        if !(a > spectrum.floor_rad && a > min_rad) {
            continue;
        }
        if chosen.len() < max_paths.min(MAX_PATHS) {
            let _ = chosen.push(m);
        } else {
            let _ = unobserved.push(m);
        }
    }
    chosen.sort_unstable();
    unobserved.sort_unstable();
    let mut paths = heapless::Vec::new();
    for k in chosen.iter().filter_map(|&m| path_for(m)) {
        let _ = paths.push(k);
    }
    Allocation { paths, unobserved }
}

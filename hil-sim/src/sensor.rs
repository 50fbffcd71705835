//! The simulated sensor front end: the paper's eq. (1)-(2) (`mras_sim::SensorModel`)
//! plus what a real board adds: noise, ADC quantisation, X/Y sampling skew, slow drift
//! of offsets and gain (temperature) and a mechanical once-per-revolution error
//! (magnet eccentricity).

use crate::input_error::InvalidParam;
use mras_sim::{Adc, CompiledSensor, SensorModel, MAX_SENSOR_HARMONICS};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Linear drift per second of run time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Drift {
    pub ax_per_s: f64,
    pub ay_per_s: f64,
    /// Relative change of both fundamental amplitudes per second.
    pub gain_per_s: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SensorParams {
    pub model: SensorModel,
    /// Gaussian noise on X and Y (scaled units).
    pub noise_std: f64,
    pub adc: Option<Adc>,
    /// Y is sampled this long after X (0 with dual simultaneous ADCs).
    pub skew_s: f64,
    pub drift: Drift,
    /// Mechanical angle error `e·sin(θrm + φ)` of the magnet or code wheel (rad).
    pub eccentricity_rad: f64,
    pub eccentricity_phase_rad: f64,
    /// How the sensor is mounted on the shaft.
    pub mount: Mount,
}

/// The sensor's mounting: the magnet's angle is `dir·θrm + offset_rad` (mechanical),
/// `dir = -1` when `reversed` (sensor on the other side, or X and Y swapped).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Mount {
    pub offset_rad: f64,
    pub reversed: bool,
}

impl SensorParams {
    /// The bare model: no noise, no ADC, no skew, drift or eccentricity.
    pub fn exact(model: SensorModel) -> Self {
        Self {
            model,
            noise_std: 0.0,
            adc: None,
            skew_s: 0.0,
            drift: Drift::default(),
            eccentricity_rad: 0.0,
            eccentricity_phase_rad: 0.0,
            mount: Mount::default(),
        }
    }

    pub fn validate(&self) -> Result<(), InvalidParam> {
        let out_of_range = |name, value, rule| InvalidParam::OutOfRange { name, value, rule };
        if !(self.noise_std.is_finite() && (0.0..=0.1).contains(&self.noise_std)) {
            return Err(out_of_range(
                "sensor.noise_std",
                self.noise_std,
                "must be in [0, 0.1]",
            ));
        }
        if !(self.skew_s.is_finite() && self.skew_s.abs() <= 1e-3) {
            return Err(out_of_range(
                "sensor.skew_s",
                self.skew_s,
                "must be within ±1 ms",
            ));
        }
        if !(self.eccentricity_rad.is_finite() && self.eccentricity_rad.abs() < 0.5) {
            return Err(out_of_range(
                "sensor.eccentricity_rad",
                self.eccentricity_rad,
                "must be within ±0.5 rad",
            ));
        }
        if !self.mount.offset_rad.is_finite() {
            return Err(InvalidParam::Rule(
                "`sensor.mount_offset_deg` must be finite",
            ));
        }
        if let Some(adc) = self.adc {
            if !(8..=24).contains(&adc.bits) || adc.full_scale.is_nan() || adc.full_scale <= 0.0 {
                return Err(InvalidParam::Rule(
                    "`sensor.adc_bits` must be 8..=24 and `sensor.adc_full_scale` > 0",
                ));
            }
        }
        if self.model.sensor_periods == 0 {
            return Err(InvalidParam::Rule("`sensor.sensor_periods` must be >= 1"));
        }
        Ok(())
    }
}

/// A seeded sensor: the same seed gives the same samples.
#[derive(Clone, Debug)]
pub struct SensorSim {
    pub params: SensorParams,
    compiled: CompiledSensor,
    rng: ChaCha8Rng,
    noise: Option<Normal<f64>>,
    /// The fast evaluation behind [`SensorSim::sample_codes`] (`None`: a model it does
    /// not cover).
    fast: Option<FastModel>,
}

/// Samples between exact sin/cos evaluations of the sensor angle in [`FastModel`].
const RESYNC_SAMPLES: u32 = 64;
/// Largest change of the sensor angle from one sample to the next that [`FastModel`]
/// carries by rotation (rad; 0.1 rad at 20 kHz and N = 2 is 80 rev/s).
const MAX_TURN_RAD: f64 = 0.1;
/// The guard band around a code boundary, relative to the signal's scale (see
/// [`FastModel`]): 1e-9 against a worst-case difference of some 1e-12.
const GUARD: f64 = 1e-9;

/// (h, Bxh·e^{jφxh}, Byh·e^{jφyh}) as (re, im) pairs.
type Harmonic = (i32, (f64, f64), (f64, f64));

/// [`CompiledSensor::vector_scaled`] without its sin/cos per sample: the sensor angle's
/// (sin, cos) is carried from one sample to the next by a rotation through the angle's
/// change (exact difference, Taylor-series sin/cos of it), re-evaluated exactly every
/// [`RESYNC_SAMPLES`] samples and on any large step.
///
/// Its X and Y differ from the exact evaluation by rounding only: a few ulp per
/// rotation, some 1e-14 after [`RESYNC_SAMPLES`] rotations, times the harmonic orders
/// and amplitudes, well under 1e-12 of the signal's scale. The converter's codes are
/// what leaves the sensor, and a code can only differ where the value lies within that
/// much of a code boundary: there [`SensorSim::sample_codes`] evaluates the exact model
/// instead ([`GUARD`] wide, a few samples in a million), so the codes are the exact
/// model's, bit for bit.
#[derive(Clone, Debug)]
struct FastModel {
    sensor_periods: f64,
    /// Bx1·e^{jφx1} and By1 (the fundamental), then (h, Bxh·e^{jφxh}, Byh·e^{jφyh}).
    fund_x: (f64, f64),
    fund_y: f64,
    harmonics: [Harmonic; MAX_SENSOR_HARMONICS],
    harmonic_count: usize,
    max_order: usize,
    /// Σ of the amplitudes: the scale of the guard band.
    amplitude_sum: f64,
    /// The angle the carried (sin, cos) belongs to, and samples until the next exact one.
    angle: f64,
    sin_cos: (f64, f64),
    left: u32,
}

impl FastModel {
    fn new(m: &SensorModel) -> Option<Self> {
        let polar = |b: f64, phi: f64| (b * phi.cos(), b * phi.sin());
        let mut f = Self {
            sensor_periods: m.sensor_periods as f64,
            fund_x: polar(m.bx1, m.phi_x1_rad),
            fund_y: m.by1,
            harmonics: [(0, (0.0, 0.0), (0.0, 0.0)); MAX_SENSOR_HARMONICS],
            harmonic_count: m.harmonic_count.min(MAX_SENSOR_HARMONICS),
            max_order: 1,
            amplitude_sum: m.bx1.abs() + m.by1.abs(),
            angle: 0.0,
            sin_cos: (0.0, 1.0),
            left: 0,
        };
        for (dst, hm) in f.harmonics.iter_mut().zip(&m.harmonics[..f.harmonic_count]) {
            *dst = (hm.h, polar(hm.bx, hm.phi_x_rad), polar(hm.by, hm.phi_y_rad));
            f.max_order = f.max_order.max(hm.h.unsigned_abs() as usize);
            f.amplitude_sum += hm.bx.abs() + hm.by.abs();
        }
        // The exact model caps the order at 31; leave such models to it.
        (f.max_order <= 31 && f.amplitude_sum.is_finite()).then_some(f)
    }

    /// (sin, cos) of the sensor angle `a`.
    fn turn_to(&mut self, a: f64) -> (f64, f64) {
        let d = a - self.angle;
        if self.left > 0 && d.abs() <= MAX_TURN_RAD {
            self.left -= 1;
            self.sin_cos = crate::plant::rotate(self.sin_cos, crate::plant::sin_cos_small(d));
        } else {
            self.left = RESYNC_SAMPLES;
            self.sin_cos = a.sin_cos();
        }
        self.angle = a;
        self.sin_cos
    }

    /// (X, Y) at the sensor angle whose (sin, cos) is given.
    fn vector(&self, (s, c): (f64, f64), ax: f64, ay: f64, gain: f64) -> (f64, f64) {
        let mut x = ax + gain * (self.fund_x.0 * c - self.fund_x.1 * s);
        let mut y = ay + gain * self.fund_y * s;
        if self.harmonic_count > 0 {
            let mut pw = [(1.0, 0.0); 32];
            for i in 1..=self.max_order {
                let (a, b) = pw[i - 1];
                pw[i] = (a * c - b * s, a * s + b * c);
            }
            for &(h, (axr, axi), (ayr, ayi)) in &self.harmonics[..self.harmonic_count] {
                let (pr, pi) = pw[h.unsigned_abs() as usize];
                let pi = if h < 0 { -pi } else { pi };
                x += axr * pr - axi * pi;
                y += ayr * pi + ayi * pr;
            }
        }
        (x, y)
    }
}

impl SensorSim {
    pub fn new(params: SensorParams, seed: u64) -> Result<Self, InvalidParam> {
        params.validate()?;
        let noise = if params.noise_std > 0.0 {
            Some(Normal::new(0.0, params.noise_std)?)
        } else {
            None
        };
        Ok(Self {
            compiled: params.model.compile(),
            fast: FastModel::new(&params.model),
            params,
            rng: ChaCha8Rng::seed_from_u64(seed),
            noise,
        })
    }

    /// The sensor as it has drifted by time t.
    pub fn model_at(&self, t_s: f64) -> SensorModel {
        let d = &self.params.drift;
        let mut m = self.params.model;
        m.ax += d.ax_per_s * t_s;
        m.ay += d.ay_per_s * t_s;
        let g = 1.0 + d.gain_per_s * t_s;
        m.bx1 *= g;
        m.by1 *= g;
        m
    }

    /// The angle the sensing element sees (mounting and eccentricity included).
    pub fn sensed_angle_rad(&self, theta_rm_rad: f64) -> f64 {
        let p = &self.params;
        let magnet = if p.eccentricity_rad == 0.0 {
            theta_rm_rad
        } else {
            theta_rm_rad + p.eccentricity_rad * (theta_rm_rad + p.eccentricity_phase_rad).sin()
        };
        let m = &p.mount;
        if m.reversed {
            m.offset_rad - magnet
        } else {
            m.offset_rad + magnet
        }
    }

    /// Sample X at θ and Y at θ + ω·skew, add noise, quantise.
    pub fn sample(&mut self, t_s: f64, theta_rm_rad: f64, omega_rad_s: f64) -> (f32, f32) {
        let (mut x, mut y) = self.sample_analog(t_s, theta_rm_rad, omega_rad_s);
        if let Some(adc) = self.params.adc {
            x = adc.quantise(x);
            y = adc.quantise(y);
        }
        (x as f32, y as f32)
    }

    /// [`SensorSim::sample`] as the converter's signed codes: `q` such that the quantised
    /// value is `q·lsb`, in `[-2^(bits-1), 2^(bits-1) - 1]` (NaN reads as the lowest
    /// code). The same conversion as `Adc::quantise`, without the detour through scaled
    /// units and back that reading counts from [`SensorSim::sample`] takes.
    ///
    /// # Panics
    /// Without an ADC (`params.adc` is `None`) or with more than 16 bits.
    pub fn sample_codes(&mut self, t_s: f64, theta_rm_rad: f64, omega_rad_s: f64) -> (i32, i32) {
        let adc = self.params.adc.expect("sample_codes needs an ADC");
        assert!(adc.bits <= 16, "sample_codes: at most 16 bits");
        // `Adc::quantise`'s lsb; its clamp to [-full_scale, full_scale - lsb] is the clamp
        // of the code to [-half, half - 1].
        let lsb = 2.0 * adc.full_scale / (1u64 << adc.bits) as f64;
        let half = 1i64 << (adc.bits - 1);
        let code = |v: f64| {
            if v.is_nan() {
                -half as i32
            } else {
                crate::exact::round_i64(v / lsb).clamp(-half, half - 1) as i32
            }
        };
        if self.params.skew_s != 0.0 || self.fast.is_none() {
            let (x, y) = self.sample_analog(t_s, theta_rm_rad, omega_rad_s);
            return (code(x), code(y));
        }
        let d = self.params.drift;
        let (ax, ay) = (
            self.compiled.ax + d.ax_per_s * t_s,
            self.compiled.ay + d.ay_per_s * t_s,
        );
        let gain = 1.0 + d.gain_per_s * t_s;
        let sensed = self.sensed_angle_rad(theta_rm_rad);
        let Some(fast) = self.fast.as_mut() else {
            unreachable!("checked above")
        };
        let sc = fast.turn_to(fast.sensor_periods * sensed);
        let (mut x, mut y) = fast.vector(sc, ax, ay, gain);
        let noise = match &self.noise {
            Some(n) => (n.sample(&mut self.rng), n.sample(&mut self.rng)),
            None => (0.0, 0.0),
        };
        if self.noise.is_some() {
            x += noise.0;
            y += noise.1;
        }
        // The code of `v` unless `v` is within the guard band of a code boundary. Here
        // v·(1/lsb) stands for v/lsb: below 2^20 they differ by less than 1e-9 of a
        // code, inside the band's floor of 1e-6.
        let inv_lsb = 1.0 / lsb;
        let band =
            GUARD * (1.0 + ax.abs() + ay.abs() + gain.abs() * fast.amplitude_sum) * inv_lsb + 1e-6;
        let clear = |v: f64| {
            let z = v * inv_lsb;
            let q = crate::exact::round_i64(z);
            (z.abs() < 1_048_576.0 && 0.5 - (z - q as f64).abs() > band)
                .then(|| q.clamp(-half, half - 1) as i32)
        };
        if let (Some(qx), Some(qy)) = (clear(x), clear(y)) {
            return (qx, qy);
        }
        // Near a boundary: the exact model, with the same noise.
        let (mut x, mut y) = self.exact_vector(t_s, sensed, gain);
        if self.noise.is_some() {
            x += noise.0;
            y += noise.1;
        }
        (code(x), code(y))
    }

    /// `CompiledSensor::vector_scaled` with the drift at `t_s`, at the sensed angle.
    fn exact_vector(&self, t_s: f64, sensed_rad: f64, gain: f64) -> (f64, f64) {
        let d = &self.params.drift;
        if d.ax_per_s == 0.0 && d.ay_per_s == 0.0 && t_s.is_finite() {
            // ax + 0·t is ax: no copy of the compiled model.
            self.compiled.vector_scaled(sensed_rad, gain)
        } else {
            let mut m = self.compiled;
            m.ax += d.ax_per_s * t_s;
            m.ay += d.ay_per_s * t_s;
            m.vector_scaled(sensed_rad, gain)
        }
    }

    /// X and Y with noise, before the converter.
    fn sample_analog(&mut self, t_s: f64, theta_rm_rad: f64, omega_rad_s: f64) -> (f64, f64) {
        // Drift, applied at evaluation (same as `model_at`, without recompiling).
        let gain = 1.0 + self.params.drift.gain_per_s * t_s;
        let (mut x, y0) = self.exact_vector(t_s, self.sensed_angle_rad(theta_rm_rad), gain);
        let mut y = if self.params.skew_s == 0.0 {
            y0
        } else {
            let th_y = theta_rm_rad + omega_rad_s * self.params.skew_s;
            self.exact_vector(t_s, self.sensed_angle_rad(th_y), gain).1
        };
        if let Some(n) = &self.noise {
            x += n.sample(&mut self.rng);
            y += n.sample(&mut self.rng);
        }
        (x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> SensorParams {
        SensorParams::exact(SensorModel::ideal(2))
    }

    #[test]
    fn skew_is_a_speed_proportional_phase_error_on_y() {
        let mut p = params();
        p.skew_s = 10e-6;
        let mut s = SensorSim::new(p, 1).unwrap();
        let w = 300.0;
        let th = 0.3;
        let (x, y) = s.sample(0.0, th, w);
        assert!((x as f64 - (2.0 * th).cos()).abs() < 1e-6);
        assert!((y as f64 - (2.0 * (th + w * 10e-6)).sin()).abs() < 1e-6);
    }

    #[test]
    fn drift_and_eccentricity_and_seeded_noise() {
        let mut p = params();
        p.drift.ax_per_s = 0.01;
        p.eccentricity_rad = 0.002;
        let s = SensorSim::new(p.clone(), 1).unwrap();
        assert!((s.model_at(2.0).ax - 0.02).abs() < 1e-12);
        assert!(
            (s.sensed_angle_rad(std::f64::consts::FRAC_PI_2)
                - (std::f64::consts::FRAC_PI_2 + 0.002))
                .abs()
                < 1e-9
        );
        p.noise_std = 1e-3;
        let mut a = SensorSim::new(p.clone(), 7).unwrap();
        let mut b = SensorSim::new(p, 7).unwrap();
        for k in 0..10 {
            assert_eq!(
                a.sample(k as f64, 0.1 * k as f64, 1.0),
                b.sample(k as f64, 0.1 * k as f64, 1.0)
            );
        }
    }

    #[test]
    fn fast_codes_are_the_exact_models_codes() {
        // Everything the fast evaluation carries: harmonics, drift, eccentricity, a
        // reversed mount, noise; speed swinging through zero up to ~95 rev/s.
        let mut p = SensorParams::exact(SensorModel::extreme());
        p.noise_std = 3e-4;
        p.adc = Some(Adc {
            bits: 12,
            full_scale: 1.5,
        });
        p.drift.ax_per_s = 1e-3;
        p.drift.gain_per_s = -2e-3;
        p.eccentricity_rad = 1e-3;
        p.mount = Mount {
            offset_rad: 1.27,
            reversed: true,
        };
        let mut fast = SensorSim::new(p.clone(), 3).unwrap();
        let mut exact = SensorSim::new(p.clone(), 3).unwrap();
        exact.fast = None;
        // The scaled-unit path the plant read counts from before.
        let mut scaled = SensorSim::new(p, 3).unwrap();
        let lsb = 3.0 / 4096.0;
        let (t_s, mut th) = (50e-6, 0.0);
        for k in 0..400_000 {
            let t = k as f64 * t_s;
            let w = 600.0 * (0.7 * t).sin();
            th += w * t_s;
            let a = fast.sample_codes(t, th, w);
            assert_eq!(a, exact.sample_codes(t, th, w), "sample {k}");
            let (x, y) = scaled.sample(t, th, w);
            let code = |v: f32| (v as f64 / lsb).round() as i32;
            assert_eq!(a, (code(x), code(y)), "sample {k}");
        }
    }

    #[test]
    fn out_of_range_parameters_are_named() {
        let mut p = params();
        p.noise_std = -1.0;
        assert!(SensorSim::new(p, 1)
            .unwrap_err()
            .to_string()
            .contains("sensor.noise_std"));
    }
}

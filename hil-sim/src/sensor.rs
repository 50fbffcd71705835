//! The simulated sensor front end: the paper's eq. (1)-(2) (`mras::sim::SensorModel`)
//! plus what a real board adds: noise, ADC quantisation, X/Y sampling skew, slow drift
//! of offsets and gain (temperature) and a mechanical once-per-revolution error
//! (magnet eccentricity).

use mras::sim::{Adc, CompiledSensor, SensorModel};
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

    pub fn validate(&self) -> Result<(), String> {
        if !(self.noise_std.is_finite() && (0.0..=0.1).contains(&self.noise_std)) {
            return Err(format!(
                "`sensor.noise_std` = {}: must be in [0, 0.1]",
                self.noise_std
            ));
        }
        if !(self.skew_s.is_finite() && self.skew_s.abs() <= 1e-3) {
            return Err(format!(
                "`sensor.skew_s` = {}: must be within ±1 ms",
                self.skew_s
            ));
        }
        if !(self.eccentricity_rad.is_finite() && self.eccentricity_rad.abs() < 0.5) {
            return Err(format!(
                "`sensor.eccentricity_rad` = {}: must be within ±0.5 rad",
                self.eccentricity_rad
            ));
        }
        if !self.mount.offset_rad.is_finite() {
            return Err("`sensor.mount_offset_deg` must be finite".into());
        }
        if let Some(adc) = self.adc {
            if !(8..=24).contains(&adc.bits) || adc.full_scale.is_nan() || adc.full_scale <= 0.0 {
                return Err(
                    "`sensor.adc_bits` must be 8..=24 and `sensor.adc_full_scale` > 0".into(),
                );
            }
        }
        if self.model.sensor_periods == 0 {
            return Err("`sensor.sensor_periods` must be >= 1".into());
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
}

impl SensorSim {
    pub fn new(params: SensorParams, seed: u64) -> Result<Self, String> {
        params.validate()?;
        let noise = if params.noise_std > 0.0 {
            Some(Normal::new(0.0, params.noise_std).map_err(|e| e.to_string())?)
        } else {
            None
        };
        Ok(Self {
            compiled: params.model.compile(),
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
        // Drift, applied at evaluation (same as `model_at`, without recompiling).
        let d = &self.params.drift;
        let mut m = self.compiled;
        m.ax += d.ax_per_s * t_s;
        m.ay += d.ay_per_s * t_s;
        let gain = 1.0 + d.gain_per_s * t_s;
        let (mut x, y0) = m.vector_scaled(self.sensed_angle_rad(theta_rm_rad), gain);
        let mut y = if self.params.skew_s == 0.0 {
            y0
        } else {
            let th_y = theta_rm_rad + omega_rad_s * self.params.skew_s;
            m.vector_scaled(self.sensed_angle_rad(th_y), gain).1
        };
        if let Some(n) = &self.noise {
            x += n.sample(&mut self.rng);
            y += n.sample(&mut self.rng);
        }
        if let Some(adc) = self.params.adc {
            x = adc.quantise(x);
            y = adc.quantise(y);
        }
        (x as f32, y as f32)
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
    fn out_of_range_parameters_are_named() {
        let mut p = params();
        p.noise_std = -1.0;
        assert!(SensorSim::new(p, 1)
            .unwrap_err()
            .contains("sensor.noise_std"));
    }
}

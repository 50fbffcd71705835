//! Simulation helpers shared by the core's tests, hil-sim and the emulator image: the
//! paper's sensor model (eq. 1-2), kinematic trajectories, a driver loop, the spatial
//! error measure, and the trace and vector record codecs. `no_std` like the core, so
//! that the emulated Cortex-M4F runs them, but apart from it: nothing here is part of
//! the control path, and the firmware does not link it.
//!
//! Everything "true" is computed in f64; only what a real ADC would deliver is f32.
#![no_std]

use core::f64::consts::{PI, TAU};
use mras::{Estimate, Fault, Tracker, Trig};

/// Most extra harmonics a [`SensorModel`] carries.
pub const MAX_SENSOR_HARMONICS: usize = 12;

/// One extra spatial harmonic `h` of the sensor signals (eq. 1-2).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SensorHarmonic {
    pub h: i32,
    pub bx: f64,
    pub phi_x_rad: f64,
    pub by: f64,
    pub phi_y_rad: f64,
}

impl SensorHarmonic {
    /// Equal on X and Y (the paper's assumption): B·e^{j(h θs + φ)}.
    pub fn equal(h: i32, b: f64, phi_rad: f64) -> Self {
        Self {
            h,
            bx: b,
            phi_x_rad: phi_rad,
            by: b,
            phi_y_rad: phi_rad,
        }
    }
}

/// The paper's sensor, eq. (1)-(2), with θs = N·θrm:
/// `X = Ax + Bx1 cos(θs + φx1) + Σ Bxh cos(h θs + φxh)`,
/// `Y = Ay + By1 sin(θs) + Σ Byh sin(h θs + φyh)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorModel {
    pub sensor_periods: u16,
    pub ax: f64,
    pub ay: f64,
    pub bx1: f64,
    pub by1: f64,
    pub phi_x1_rad: f64,
    pub harmonics: [SensorHarmonic; MAX_SENSOR_HARMONICS],
    pub harmonic_count: usize,
}

impl SensorModel {
    pub fn ideal(sensor_periods: u16) -> Self {
        Self {
            sensor_periods,
            ax: 0.0,
            ay: 0.0,
            bx1: 1.0,
            by1: 1.0,
            phi_x1_rad: 0.0,
            harmonics: [SensorHarmonic::default(); MAX_SENSOR_HARMONICS],
            harmonic_count: 0,
        }
    }

    /// The combined extreme sensor of the core's acceptance tests (N = 2): offsets
    /// 10 %/-8 %, 20 % amplitude imbalance, 6° quadrature, equal x/y harmonics
    /// h = 2..5 at 3, 5, 2 and 4 %.
    pub fn extreme() -> Self {
        let mut s = Self::ideal(2);
        s.ax = 0.10;
        s.ay = -0.08;
        s.bx1 = 1.2;
        s.by1 = 1.0;
        s.phi_x1_rad = 6.0 * PI / 180.0;
        s.with_harmonic(SensorHarmonic::equal(2, 0.03, 0.5))
            .with_harmonic(SensorHarmonic::equal(3, 0.05, -1.0))
            .with_harmonic(SensorHarmonic::equal(4, 0.02, 2.0))
            .with_harmonic(SensorHarmonic::equal(5, 0.04, 0.3))
    }

    /// Add a harmonic; ignored beyond [`MAX_SENSOR_HARMONICS`] (returns false).
    pub fn push_harmonic(&mut self, h: SensorHarmonic) -> bool {
        if self.harmonic_count < MAX_SENSOR_HARMONICS {
            self.harmonics[self.harmonic_count] = h;
            self.harmonic_count += 1;
            true
        } else {
            false
        }
    }

    pub fn with_harmonic(mut self, h: SensorHarmonic) -> Self {
        self.push_harmonic(h);
        self
    }

    /// The measured vector (X, Y) at mechanical angle θrm.
    pub fn vector(&self, theta_rm_rad: f64) -> (f64, f64) {
        let ts = self.sensor_periods as f64 * theta_rm_rad;
        let mut x = self.ax + self.bx1 * libm::cos(ts + self.phi_x1_rad);
        let mut y = self.ay + self.by1 * libm::sin(ts);
        for hm in &self.harmonics[..self.harmonic_count] {
            let a = hm.h as f64 * ts;
            x += hm.bx * libm::cos(a + hm.phi_x_rad);
            y += hm.by * libm::sin(a + hm.phi_y_rad);
        }
        (x, y)
    }

    /// The same model prepared for fast evaluation (one sin/cos per call).
    pub fn compile(&self) -> CompiledSensor {
        let polar = |b: f64, phi: f64| (b * libm::cos(phi), b * libm::sin(phi));
        let mut c = CompiledSensor {
            sensor_periods: self.sensor_periods,
            ax: self.ax,
            ay: self.ay,
            fund_x: polar(self.bx1, self.phi_x1_rad),
            fund_y: self.by1,
            harmonics: [(0, (0.0, 0.0), (0.0, 0.0)); MAX_SENSOR_HARMONICS],
            harmonic_count: self.harmonic_count,
            max_order: 1,
        };
        for (dst, hm) in c
            .harmonics
            .iter_mut()
            .zip(&self.harmonics[..self.harmonic_count])
        {
            *dst = (hm.h, polar(hm.bx, hm.phi_x_rad), polar(hm.by, hm.phi_y_rad));
            c.max_order = c.max_order.max(hm.h.unsigned_abs() as usize);
        }
        c
    }

    /// Mechanical angle error of `atan2(Y, X)/N` at θrm (rad, in (-π/N, π/N]).
    pub fn angle_error_rad(&self, theta_rm_rad: f64) -> f64 {
        let n = self.sensor_periods as f64;
        let (x, y) = self.vector(theta_rm_rad);
        wrap_pi(libm::atan2(y, x) - n * theta_rm_rad) / n
    }

    /// Pk-pk of the raw (atan2) spatial error over one revolution, constant removed.
    pub fn raw_error_pk_pk_rad(&self) -> f64 {
        let mut e = SpatialError::<720>::new();
        for i in 0..7200 {
            let th = TAU * (i as f64 + 0.5) / 7200.0;
            e.add(th, self.angle_error_rad(th));
        }
        e.pk_pk_rad()
    }
}

/// (h, Bxh·e^{jφxh}, Byh·e^{jφyh}) as (re, im) pairs.
type CompiledHarmonic = (i32, (f64, f64), (f64, f64));

/// A [`SensorModel`] with its phases folded into complex amplitudes, evaluated with one
/// sin/cos and powers of e^{jθs}: `X = Ax + Re(Σ Bxh e^{jφxh} e^{jhθs})`,
/// `Y = Ay + Im(Σ Byh e^{jφyh} e^{jhθs})` (the fundamental of Y has no phase).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompiledSensor {
    pub sensor_periods: u16,
    pub ax: f64,
    pub ay: f64,
    fund_x: (f64, f64),
    fund_y: f64,
    harmonics: [CompiledHarmonic; MAX_SENSOR_HARMONICS],
    harmonic_count: usize,
    max_order: usize,
}

impl CompiledSensor {
    /// (X, Y) at θrm with the fundamental amplitudes scaled by `gain` (drift).
    pub fn vector_scaled(&self, theta_rm_rad: f64, gain: f64) -> (f64, f64) {
        let (s, c) = libm::sincos(self.sensor_periods as f64 * theta_rm_rad);
        let mut x = self.ax + gain * (self.fund_x.0 * c - self.fund_x.1 * s);
        let mut y = self.ay + gain * self.fund_y * s;
        if self.harmonic_count > 0 {
            // pw[i] = e^{j i θs}
            let mut pw = [(1.0, 0.0); 32];
            let top = self.max_order.min(31);
            for i in 1..=top {
                let (a, b) = pw[i - 1];
                pw[i] = (a * c - b * s, a * s + b * c);
            }
            for &(h, (axr, axi), (ayr, ayi)) in &self.harmonics[..self.harmonic_count] {
                let (pr, pi) = pw[(h.unsigned_abs() as usize).min(31)];
                let pi = if h < 0 { -pi } else { pi };
                x += axr * pr - axi * pi;
                y += ayr * pi + ayi * pr;
            }
        }
        (x, y)
    }

    pub fn vector(&self, theta_rm_rad: f64) -> (f64, f64) {
        self.vector_scaled(theta_rm_rad, 1.0)
    }
}

/// Wrap to (-π, π].
pub fn wrap_pi(a: f64) -> f64 {
    // floor instead of `%`: fmod is several times slower and this runs every sample.
    let mut r = a - TAU * libm::floor(a / TAU);
    if r > PI {
        r -= TAU;
    } else if r <= -PI {
        r += TAU;
    }
    r
}

/// A mechanical motion profile: (θrm, ωrm, αrm) at time t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Trajectory {
    /// From rest at θ = 0, accelerate at |accel| to a constant `omega_rad_s` (either sign).
    Ramp { omega_rad_s: f64, accel_rad_s2: f64 },
    /// The paper's Fig. 8 profile: ω = A·sin(2π f t) from θ = 0.
    Sine { amplitude_rad_s: f64, freq_hz: f64 },
}

impl Trajectory {
    pub fn state(&self, t_s: f64) -> (f64, f64, f64) {
        match *self {
            Trajectory::Ramp {
                omega_rad_s,
                accel_rad_s2,
            } => {
                let a = libm::fabs(accel_rad_s2);
                let sgn = if omega_rad_s < 0.0 { -1.0 } else { 1.0 };
                let t_ramp = libm::fabs(omega_rad_s) / a;
                if t_s < t_ramp {
                    (sgn * 0.5 * a * t_s * t_s, sgn * a * t_s, sgn * a)
                } else {
                    let th0 = sgn * 0.5 * a * t_ramp * t_ramp;
                    (th0 + omega_rad_s * (t_s - t_ramp), omega_rad_s, 0.0)
                }
            }
            Trajectory::Sine {
                amplitude_rad_s,
                freq_hz,
            } => {
                let w = TAU * freq_hz;
                (
                    amplitude_rad_s / w * (1.0 - libm::cos(w * t_s)),
                    amplitude_rad_s * libm::sin(w * t_s),
                    amplitude_rad_s * w * libm::cos(w * t_s),
                )
            }
        }
    }

    /// Time at which a ramp reaches its constant speed (0 for the sine).
    pub fn settle_time_s(&self) -> f64 {
        match *self {
            Trajectory::Ramp {
                omega_rad_s,
                accel_rad_s2,
            } => libm::fabs(omega_rad_s / accel_rad_s2),
            Trajectory::Sine { .. } => 0.0,
        }
    }
}

/// An ideal ADC of `bits` over ±`full_scale`, in scaled units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adc {
    pub bits: u8,
    pub full_scale: f64,
}

impl Adc {
    pub fn quantise(&self, v: f64) -> f64 {
        let lsb = 2.0 * self.full_scale / (1u64 << self.bits) as f64;
        let c = libm::round(v / lsb) * lsb;
        c.clamp(-self.full_scale, self.full_scale - lsb)
    }
}

/// One simulated control period, as seen by the driver's callback.
#[derive(Clone, Copy, Debug)]
pub struct StepRecord {
    pub k: u64,
    pub t_s: f64,
    /// True continuous mechanical angle (rad).
    pub theta_rad: f64,
    pub omega_rad_s: f64,
    /// What was fed to the core.
    pub x: f32,
    pub y: f32,
    pub torque_nm: f32,
    pub result: Result<Estimate, Fault>,
    /// θ̂ (continuous) - θ (rad, mechanical), of this or the last good estimate.
    pub error_rad: f64,
}

/// A rigid rotor following a trajectory exactly, with a perfect torque feedforward
/// J·α, sampled by the sensor model: the minimal driver for the core.
#[derive(Clone, Copy, Debug)]
pub struct Kinematic {
    pub sensor: SensorModel,
    pub trajectory: Trajectory,
    pub sample_period_s: f64,
    pub inertia_kg_m2: f64,
    pub adc: Option<Adc>,
}

impl Kinematic {
    /// Run `steps` periods from `k0`; `noise()` supplies additive (x, y) noise;
    /// `on_step` sees every period and may act on the tracker (freeze, etc.).
    pub fn run<T: Trig>(
        &self,
        tracker: &mut Tracker<T>,
        k0: u64,
        steps: u64,
        mut noise: impl FnMut() -> (f64, f64),
        mut on_step: impl FnMut(&mut Tracker<T>, &StepRecord),
    ) {
        for k in k0..k0 + steps {
            let t = k as f64 * self.sample_period_s;
            let (th, w, a) = self.trajectory.state(t);
            let (mut x, mut y) = self.sensor.vector(th);
            let (nx, ny) = noise();
            x += nx;
            y += ny;
            if let Some(adc) = self.adc {
                x = adc.quantise(x);
                y = adc.quantise(y);
            }
            let tq = (self.inertia_kg_m2 * a) as f32;
            let result = tracker.step(x as f32, y as f32, tq);
            let est = result.unwrap_or_else(|_| tracker.last_estimate());
            let rec = StepRecord {
                k,
                t_s: t,
                theta_rad: th,
                omega_rad_s: w,
                x: x as f32,
                y: y as f32,
                torque_nm: tq,
                result,
                error_rad: est.theta_unwrapped_rad() - th,
            };
            on_step(tracker, &rec);
        }
    }
}

/// Position error binned by true mechanical angle: the *spatial* error, with the
/// constant (unobservable) offset removed.
#[derive(Clone, Debug)]
pub struct SpatialError<const B: usize> {
    sum: [f64; B],
    count: [u32; B],
}

impl<const B: usize> Default for SpatialError<B> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const B: usize> SpatialError<B> {
    pub fn new() -> Self {
        Self {
            sum: [0.0; B],
            count: [0; B],
        }
    }

    pub fn add(&mut self, theta_rm_rad: f64, error_rad: f64) {
        let t = theta_rm_rad / TAU;
        let u = t - libm::floor(t);
        let i = ((u * B as f64) as usize).min(B - 1);
        self.sum[i] += error_rad;
        self.count[i] += 1;
    }

    fn means(&self) -> impl Iterator<Item = f64> + '_ {
        self.sum
            .iter()
            .zip(&self.count)
            .filter(|(_, c)| **c > 0)
            .map(|(s, c)| s / *c as f64)
    }

    /// Mean over filled bins (the constant offset).
    pub fn offset_rad(&self) -> f64 {
        let (s, n) = self.means().fold((0.0, 0usize), |(s, n), m| (s + m, n + 1));
        if n == 0 {
            0.0
        } else {
            s / n as f64
        }
    }

    pub fn pk_pk_rad(&self) -> f64 {
        let (lo, hi) = self
            .means()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), m| {
                (l.min(m), h.max(m))
            });
        if hi >= lo {
            hi - lo
        } else {
            0.0
        }
    }

    pub fn rms_rad(&self) -> f64 {
        let off = self.offset_rad();
        let (s, n) = self.means().fold((0.0, 0usize), |(s, n), m| {
            (s + (m - off) * (m - off), n + 1)
        });
        if n == 0 {
            0.0
        } else {
            libm::sqrt(s / n as f64)
        }
    }

    /// (bin centre angle, mean error) of every filled bin, constant offset removed.
    pub fn bin_means(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        let off = self.offset_rad();
        self.sum
            .iter()
            .zip(&self.count)
            .enumerate()
            .filter(|(_, (_, c))| **c > 0)
            .map(move |(i, (s, c))| (TAU * (i as f64 + 0.5) / B as f64, s / *c as f64 - off))
    }

    /// Amplitude of the k-th spatial harmonic of the binned error (rad), by a DFT over
    /// the filled bins (exact when all bins are filled).
    pub fn harmonic_amplitude_rad(&self, k: u32) -> f64 {
        let (mut re, mut im, mut n) = (0.0, 0.0, 0usize);
        for (th, e) in self.bin_means() {
            re += e * libm::cos(k as f64 * th);
            im += e * libm::sin(k as f64 * th);
            n += 1;
        }
        if n == 0 {
            0.0
        } else {
            2.0 * libm::sqrt(re * re + im * im) / n as f64
        }
    }

    pub fn filled_bins(&self) -> usize {
        self.count.iter().filter(|c| **c > 0).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_only_sensor_error_is_first_harmonic_of_theta_s() {
        let mut s = SensorModel::ideal(2);
        s.ax = 0.1;
        // δ ≈ -Ax sin θs / N: pk-pk ≈ 2·0.1/2 = 0.1 rad mechanical.
        let pp = s.raw_error_pk_pk_rad();
        assert!((pp - 0.1).abs() < 0.002, "{pp}");
    }

    #[test]
    fn compiled_sensor_matches_the_model() {
        let mut s = SensorModel::extreme();
        s.push_harmonic(SensorHarmonic {
            h: -3,
            bx: 0.01,
            phi_x_rad: 0.4,
            by: 0.02,
            phi_y_rad: -1.1,
        });
        let c = s.compile();
        for i in 0..1000 {
            let th = -7.0 + 0.0137 * i as f64;
            let (x0, y0) = s.vector(th);
            let (x1, y1) = c.vector(th);
            assert!((x0 - x1).abs() < 1e-12 && (y0 - y1).abs() < 1e-12, "{th}");
        }
    }

    #[test]
    fn trajectories_are_consistent() {
        let r = Trajectory::Ramp {
            omega_rad_s: -10.0,
            accel_rad_s2: 100.0,
        };
        let (th, w, a) = r.state(1.0);
        assert_eq!((w, a), (-10.0, 0.0));
        assert!((th - (-0.5 - 9.0)).abs() < 1e-12);
        let s = Trajectory::Sine {
            amplitude_rad_s: 100.0,
            freq_hz: 1.0,
        };
        let dt = 1e-6;
        let (t0, w0, _) = s.state(0.3);
        let (t1, _, _) = s.state(0.3 + dt);
        assert!(((t1 - t0) / dt - w0).abs() < 1e-3);
    }

    #[test]
    fn spatial_error_removes_constant() {
        let mut e = SpatialError::<36>::new();
        for i in 0..3600 {
            let th = TAU * i as f64 / 3600.0;
            e.add(th, 0.5 + 0.01 * libm::sin(2.0 * th));
        }
        assert!((e.offset_rad() - 0.5).abs() < 1e-4);
        assert!((e.pk_pk_rad() - 0.02).abs() < 1e-3);
        assert!((e.rms_rad() - 0.01 / libm::sqrt(2.0)).abs() < 1e-3);
        assert!((e.harmonic_amplitude_rad(2) - 0.01).abs() < 1e-4);
        assert!(e.harmonic_amplitude_rad(3) < 1e-4);
    }

    #[test]
    fn revs_to_reduction_counts_the_first_good_revolution() {
        assert_eq!(
            revs_to_reduction(&[5.0, 2.0, 0.5, 0.4], 10.0, 10.0),
            Some(3)
        );
        assert_eq!(revs_to_reduction(&[0.5, 2.0, 0.5], 10.0, 10.0), Some(3));
        assert_eq!(revs_to_reduction(&[0.5, 0.5], 10.0, 10.0), Some(1));
        assert_eq!(revs_to_reduction(&[0.5, 2.0], 10.0, 10.0), None);
    }

    #[test]
    fn adc_quantises_and_clamps() {
        let adc = Adc {
            bits: 12,
            full_scale: 1.5,
        };
        let lsb = 3.0 / 4096.0;
        assert!((adc.quantise(0.1) - 0.1).abs() <= lsb / 2.0);
        assert_eq!(adc.quantise(9.0), 1.5 - lsb);
        assert_eq!(adc.quantise(-9.0), -1.5);
    }
}

/// A self-commissioning run at constant speed, as a drive does it: ramp up on the
/// uncorrected sensor with adaptation frozen, settle, then adapt for whole revolutions.
#[derive(Clone, Copy, Debug)]
pub struct CommissioningRun {
    pub sensor: SensorModel,
    /// Commissioning speed (rev/s, either sign).
    pub speed_rev_s: f64,
    pub sample_period_s: f64,
    pub inertia_kg_m2: f64,
    pub adc: Option<Adc>,
}

/// What a [`CommissioningRun`] reports after each revolution of adaptation.
#[derive(Clone, Copy, Debug)]
pub struct RevolutionReport {
    /// 1-based revolution count since adaptation started.
    pub rev: u32,
    /// Spatial error pk-pk of θ̂ over this revolution (64 bins, rad mechanical).
    pub error_pk_pk_rad: f64,
    /// Same for the uncorrected sensor's atan2 over the same samples.
    pub raw_pk_pk_rad: f64,
    /// Samples in this revolution that returned a fault.
    pub faults: u32,
}

impl CommissioningRun {
    /// Ramp acceleration used to reach the commissioning speed (rad/s²).
    pub const RAMP_ACCEL_RAD_S2: f64 = 2000.0;
    /// Settling time at speed before adaptation starts (s).
    pub const SETTLE_S: f64 = 0.2;

    /// The driver this run uses (to continue it, e.g. for a frozen verification).
    pub fn kinematic(&self) -> Kinematic {
        Kinematic {
            sensor: self.sensor,
            trajectory: Trajectory::Ramp {
                omega_rad_s: self.speed_rev_s * TAU,
                accel_rad_s2: Self::RAMP_ACCEL_RAD_S2,
            },
            sample_period_s: self.sample_period_s,
            inertia_kg_m2: self.inertia_kg_m2,
            adc: self.adc,
        }
    }

    /// Samples per revolution at the commissioning speed.
    pub fn steps_per_rev(&self) -> u64 {
        libm::round(1.0 / (libm::fabs(self.speed_rev_s) * self.sample_period_s)) as u64
    }

    /// Index of the first sample after `revs` revolutions of adaptation.
    pub fn step_after(&self, revs: u32) -> u64 {
        let settle = Trajectory::Ramp {
            omega_rad_s: self.speed_rev_s * TAU,
            accel_rad_s2: Self::RAMP_ACCEL_RAD_S2,
        }
        .settle_time_s();
        ((settle + Self::SETTLE_S) / self.sample_period_s) as u64
            + revs as u64 * self.steps_per_rev()
    }

    /// Run `revs` revolutions of adaptation; `on_rev` sees each revolution's report.
    /// Returns the number of samples faulted during spin-up (should be 0).
    pub fn run<T: Trig>(
        &self,
        tracker: &mut Tracker<T>,
        revs: u32,
        mut noise: impl FnMut() -> (f64, f64),
        mut on_rev: impl FnMut(&mut Tracker<T>, &RevolutionReport),
    ) -> u32 {
        let kin = self.kinematic();
        let k_start = self.step_after(0);
        let n = self.sensor.sensor_periods as f64;
        let was_frozen = tracker.is_frozen();
        tracker.set_frozen(true);
        let mut spin_up_faults = 0;
        kin.run(tracker, 0, k_start, &mut noise, |_, r| {
            spin_up_faults += r.result.is_err() as u32;
        });
        tracker.set_frozen(was_frozen);
        let steps_per_rev = self.steps_per_rev();
        for rev in 1..=revs {
            let mut est = SpatialError::<64>::new();
            let mut raw = SpatialError::<64>::new();
            let mut faults = 0;
            let k0 = k_start + (rev as u64 - 1) * steps_per_rev;
            kin.run(tracker, k0, steps_per_rev, &mut noise, |_, r| {
                est.add(r.theta_rad, r.error_rad);
                let raw_err = wrap_pi(libm::atan2(r.y as f64, r.x as f64) - n * r.theta_rad) / n;
                raw.add(r.theta_rad, raw_err);
                faults += r.result.is_err() as u32;
            });
            on_rev(
                tracker,
                &RevolutionReport {
                    rev,
                    error_pk_pk_rad: est.pk_pk_rad(),
                    raw_pk_pk_rad: raw.pk_pk_rad(),
                    faults,
                },
            );
        }
        spin_up_faults
    }
}

/// The first revolution (1-based) from which the error stays at or below
/// `raw / factor` for the rest of the record (`None` if the last one is still above).
pub fn revs_to_reduction(per_rev_pk_pk: &[f64], raw_pk_pk: f64, factor: f64) -> Option<usize> {
    let limit = raw_pk_pk / factor;
    match per_rev_pk_pk.iter().rposition(|e| *e > limit) {
        None => Some(1),
        Some(i) if i + 1 == per_rev_pk_pk.len() => None,
        Some(i) => Some(i + 2),
    }
}

/// Bytes per step of an input vector: x, y, torque feedforward as little-endian f32.
pub const VECTOR_RECORD_BYTES: usize = 12;

/// One input-vector record.
pub fn encode_vector_record(x: f32, y: f32, torque_nm: f32) -> [u8; VECTOR_RECORD_BYTES] {
    let mut b = [0u8; VECTOR_RECORD_BYTES];
    b[0..4].copy_from_slice(&x.to_bits().to_le_bytes());
    b[4..8].copy_from_slice(&y.to_bits().to_le_bytes());
    b[8..12].copy_from_slice(&torque_nm.to_bits().to_le_bytes());
    b
}

/// Inverse of [`encode_vector_record`]; short input reads as zeros.
pub fn decode_vector_record(b: &[u8]) -> (f32, f32, f32) {
    let word = |i: usize| {
        let mut w = [0u8; 4];
        for (j, v) in w.iter_mut().enumerate() {
            *v = b.get(4 * i + j).copied().unwrap_or(0);
        }
        f32::from_bits(u32::from_le_bytes(w))
    };
    (word(0), word(1), word(2))
}

/// One line of the bit-exactness trace: step index, result (0 or the fault's bit),
/// then θ̂, ω̂, ε, the tracked amplitude and every coefficient as f32 bit patterns.
/// The same function runs on the host and on the emulated Cortex-M4F.
pub fn write_trace_line<W: core::fmt::Write, T: Trig>(
    w: &mut W,
    k: usize,
    result: &Result<Estimate, Fault>,
    tracker: &Tracker<T>,
) -> core::fmt::Result {
    let fault = match result {
        Ok(_) => 0u8,
        Err(f) => 1u8 << (*f as u8),
    };
    let e = tracker.last_estimate();
    write!(
        w,
        "{k} {fault:02x} {:08x} {:08x} {:08x} {:08x}",
        e.theta_rad.to_bits(),
        e.omega_rad_s.to_bits(),
        e.epsilon_rad.to_bits(),
        e.amplitude.to_bits()
    )?;
    for (_, c) in tracker.coefficients().iter() {
        write!(w, " {:08x} {:08x}", c.re.to_bits(), c.im.to_bits())?;
    }
    writeln!(w)
}

//! Lock acquisition at speed (a recording or a power-up that begins with the rotor
//! turning) and re-acquisition after the sensor dropped out, on the extreme sensor.
mod common;

use common::*;
use mras::{Config, Fault, Tracker};
use mras_sim::{wrap_pi, SensorModel, SpatialError};
use std::f64::consts::TAU;

/// What a sample of the constant-speed drive fed the core.
#[derive(Clone, Copy, Debug)]
enum Feed {
    Sensor,
    /// Both channels at mid-scale: a disconnected sensor (refused as `SensorLost`).
    Dropout,
    /// A vector of nominal amplitude at a random angle: a sensor that reads garbage
    /// the core cannot refuse by its amplitude.
    Garbage,
    /// A railed ADC channel: refused by the front end, never reaching `step`.
    Railed,
}

/// A rotor at constant speed from the first sample (no spin-up), the extreme sensor
/// through a 12-bit converter with noise, no torque feedforward.
struct Spin {
    tracker: Tracker,
    sensor: SensorModel,
    omega_rad_s: f64,
    theta0_rad: f64,
    k: u64,
    noise: Box<dyn FnMut() -> (f64, f64)>,
    garbage: Box<dyn FnMut() -> (f64, f64)>,
}

impl Spin {
    fn new(speed_rev_s: f64, theta0_rad: f64, seed: u64) -> Self {
        let mut g = noise(seed ^ 0x5eed, 1.0);
        Self {
            tracker: Tracker::new(Config::default()).unwrap(),
            sensor: extreme_sensor(),
            omega_rad_s: speed_rev_s * TAU,
            theta0_rad,
            k: 0,
            noise: Box::new(noise(seed, NOISE_STD)),
            garbage: Box::new(move || {
                let (a, _) = g();
                (a.cos() * 0.9, a.sin() * 0.9)
            }),
        }
    }

    fn theta_rad(&self) -> f64 {
        self.theta0_rad + self.omega_rad_s * self.k as f64 * T_S
    }

    /// One sample; returns the core's answer and the estimate's error (mechanical rad,
    /// modulo a sensor period: the sensor cannot tell the periods apart).
    fn step(&mut self, feed: Feed) -> (Result<mras::Estimate, Fault>, f64) {
        let th = self.theta_rad();
        let (x, y) = match feed {
            Feed::Sensor => {
                let (x, y) = self.sensor.vector(th);
                let (nx, ny) = (self.noise)();
                (ADC_12BIT.quantise(x + nx), ADC_12BIT.quantise(y + ny))
            }
            Feed::Dropout => (0.0, 0.0),
            Feed::Garbage => (self.garbage)(),
            Feed::Railed => (f64::NAN, f64::NAN),
        };
        let r = match feed {
            Feed::Railed => Err(self.tracker.refuse(Fault::SensorSaturated)),
            _ => self.tracker.step(x as f32, y as f32, 0.0),
        };
        let est = r.unwrap_or_else(|_| self.tracker.last_estimate());
        let n = self.sensor.sensor_periods as f64;
        let err = wrap_pi(n * (est.theta_unwrapped_rad() - th)) / n;
        self.k += 1;
        (r, err)
    }

    fn samples_per_rev(&self) -> u64 {
        (TAU / (self.omega_rad_s.abs() * T_S)).round() as u64
    }

    /// One revolution of samples from the sensor: (spatial error pk-pk of the estimate,
    /// of the raw sensor angle) in mechanical rad, and the loss-of-lock answers.
    fn revolution(&mut self) -> (f64, f64, u32) {
        let n = self.sensor.sensor_periods as f64;
        let mut est = SpatialError::<64>::new();
        let mut raw = SpatialError::<64>::new();
        let mut lost = 0;
        for _ in 0..self.samples_per_rev() {
            let th = self.theta_rad();
            let (x, y) = self.sensor.vector(th);
            let (r, err) = self.step(Feed::Sensor);
            lost += (r == Err(Fault::LossOfLock)) as u32;
            est.add(th, err);
            raw.add(th, wrap_pi(y.atan2(x) - n * th) / n);
        }
        (est.pk_pk_rad(), raw.pk_pk_rad(), lost)
    }
}

/// From the first sample at ±100, ±70, ±20 and ±5 rev/s, at several angles: locked
/// within a few windows, never a loss of lock, and the error 100x below the raw
/// sensor's within 20 revolutions.
#[test]
fn flying_start_locks_and_converges_at_any_speed() {
    for (i, speed_rev_s) in [100.0, -100.0, 70.0, -70.0, 20.0, -20.0, 5.0, -5.0]
        .into_iter()
        .enumerate()
    {
        for theta0_rad in [0.3, 2.0, 4.4] {
            let mut s = Spin::new(speed_rev_s, theta0_rad, i as u64);
            // Locked within 5 ms (three windows of 1.6 ms at these eigenvalues).
            let mut locked_at = None;
            for k in 0..100 {
                let (r, _) = s.step(Feed::Sensor);
                assert!(
                    r.is_ok(),
                    "{speed_rev_s} rev/s, θ0 {theta0_rad}: sample {k}: {r:?}"
                );
                if s.tracker.is_locked() && locked_at.is_none() {
                    locked_at = Some(k);
                }
            }
            assert!(
                locked_at.is_some() && s.tracker.is_locked(),
                "{speed_rev_s} rev/s, θ0 {theta0_rad}: not locked after 5 ms"
            );
            let mut best = f64::INFINITY;
            let mut reached = None;
            for rev in 1..=20 {
                let (e, raw, lost) = s.revolution();
                assert_eq!(
                    lost, 0,
                    "{speed_rev_s} rev/s: lock lost in revolution {rev}"
                );
                best = best.min(e);
                if raw / e >= 100.0 && reached.is_none() {
                    reached = Some(rev);
                }
            }
            assert!(
                reached.is_some(),
                "{speed_rev_s} rev/s, θ0 {theta0_rad}: best {:.3} mrad",
                best * 1e3
            );
            assert!(
                !s.tracker.faults().contains(Fault::LossOfLock),
                "{:?}",
                s.tracker.faults()
            );
            eprintln!(
                "{speed_rev_s:+} rev/s θ0 {theta0_rad}: locked at sample {}, 100x at revolution {}",
                locked_at.unwrap(),
                reached.unwrap()
            );
        }
    }
}

/// Converged at speed, then 5 ms without a usable sensor (refused samples, or garbage
/// the core accepts): locked and adapting again within one revolution of the sensor's
/// return, and the error back to 100x below raw on the next revolution.
#[test]
fn dropout_at_speed_reacquires_within_a_revolution() {
    for (i, speed_rev_s) in [100.0, -100.0, 70.0, -70.0, 30.0].into_iter().enumerate() {
        for feed in [Feed::Dropout, Feed::Garbage, Feed::Railed] {
            let mut s = Spin::new(speed_rev_s, 1.0, 100 + i as u64);
            for _ in 0..10 {
                s.revolution();
            }
            let (e, raw, _) = s.revolution();
            assert!(
                raw / e > 100.0,
                "{speed_rev_s}: not converged before the dropout"
            );
            let coefs = s.tracker.coefficients();
            let dropout = (5.0e-3 / T_S) as u64;
            for _ in 0..dropout {
                let _ = s.step(feed);
            }
            let per_rev = s.samples_per_rev();
            let mut back = None;
            for k in 0..per_rev {
                let _ = s.step(Feed::Sensor);
                if back.is_none() && s.tracker.is_locked() && s.tracker.last_estimate().adapting {
                    back = Some(k);
                }
            }
            let what = format!("{feed:?}");
            let back = back.unwrap_or_else(|| {
                panic!("{speed_rev_s} rev/s, {what}: not adapting within a revolution")
            });
            assert!(s.tracker.is_locked() && s.tracker.last_estimate().adapting);
            // The garbage may have moved the coefficients a little before the loss was
            // seen, never far.
            for ((_, a), (_, b)) in coefs.iter().zip(s.tracker.coefficients().iter()) {
                assert!(
                    (a - b).abs() < 0.02,
                    "{speed_rev_s} rev/s, {what}: {a:?} → {b:?}"
                );
            }
            assert!(back <= 100, "{speed_rev_s} rev/s, {what}: {back} samples");
            // The observer's transient from its restart decays over the next revolution.
            let mut reduction = [0.0; 2];
            for r in &mut reduction {
                let (e, raw, lost) = s.revolution();
                assert_eq!(lost, 0);
                *r = raw / e;
            }
            assert!(
                reduction[0] > 30.0 && reduction[1] > 100.0,
                "{speed_rev_s} rev/s, {what}: {reduction:?} after re-acquisition"
            );
            eprintln!(
                "{speed_rev_s:+} rev/s, {what}: adapting again {back} samples ({:.2} ms) after \
                 the sensor returned; {:.0}x, {:.0}x below raw over the next two revolutions",
                back as f64 * T_S * 1e3,
                reduction[0],
                reduction[1]
            );
        }
    }
}

/// A sensor that stays wrong never passes for locked: no adaptation on garbage.
#[test]
fn garbage_never_locks() {
    let mut s = Spin::new(50.0, 0.0, 7);
    for _ in 0..5 {
        s.revolution();
    }
    let coefs = s.tracker.coefficients();
    let mut locked = 0;
    for _ in 0..20_000 {
        let _ = s.step(Feed::Garbage);
        locked += s.tracker.is_locked() as u32;
    }
    assert!(s.tracker.faults().contains(Fault::LossOfLock));
    assert!(locked < 50, "locked on {locked} garbage samples");
    assert!(!s.tracker.last_estimate().adapting);
    for ((_, a), (_, b)) in coefs.iter().zip(s.tracker.coefficients().iter()) {
        assert!((a - b).abs() < 0.02, "{a:?} → {b:?}");
    }
}

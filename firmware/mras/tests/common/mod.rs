//! Shared test driver pieces: sensors, noise, and a commissioning run at constant speed.
#![allow(dead_code)]

use mras::{AdaptationLaw, Config, Tracker};
use mras_sim::{revs_to_reduction, Adc, CommissioningRun, Kinematic, SensorModel, Trajectory};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

pub const T_S: f64 = 50.0e-6;
pub const J_KG_M2: f64 = 1.0e-4;

/// The "combined extreme" sensor: every error term at once (see `SensorModel::extreme`).
pub fn extreme_sensor() -> SensorModel {
    SensorModel::extreme()
}

/// 12-bit-class front end: σ = 0.3 mV-equivalent noise on a ±1.5 full scale, 12 bits.
pub const NOISE_STD: f64 = 3.0e-4;
pub const ADC_12BIT: Adc = Adc {
    bits: 12,
    full_scale: 1.5,
};

/// Deterministic Gaussian (x, y) noise.
pub fn noise(seed: u64, std: f64) -> impl FnMut() -> (f64, f64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, std).unwrap();
    move || (n.sample(&mut rng), n.sample(&mut rng))
}

pub fn no_noise() -> impl FnMut() -> (f64, f64) {
    || (0.0, 0.0)
}

pub fn paper_config() -> Config {
    Config {
        law: AdaptationLaw::PAPER_FIG8,
        ..Config::default()
    }
}

pub fn run(sensor: SensorModel, speed_rev_s: f64) -> CommissioningRun {
    CommissioningRun {
        sensor,
        speed_rev_s,
        sample_period_s: T_S,
        inertia_kg_m2: J_KG_M2,
        adc: None,
    }
}

/// Commission with `cfg` for `revs`; returns the tracker and each revolution's pk-pk
/// error, and the raw pk-pk. Panics (test failure) on any fault.
pub fn commission(
    cfg: Config,
    r: &CommissioningRun,
    revs: u32,
    noise: impl FnMut() -> (f64, f64),
) -> (Tracker, Vec<f64>, f64) {
    let mut t = Tracker::new(cfg).expect("valid config");
    let mut per_rev = Vec::new();
    let mut raw = 0.0;
    let spin_up_faults = r.run(&mut t, revs, noise, |_, rep| {
        assert_eq!(rep.faults, 0, "fault during revolution {}", rep.rev);
        per_rev.push(rep.error_pk_pk_rad);
        raw = rep.raw_pk_pk_rad;
    });
    assert_eq!(spin_up_faults, 0);
    assert!(t.faults().is_empty(), "faults {:?}", t.faults());
    (t, per_rev, raw)
}

/// Revolutions to a 10x reduction of the extreme sensor's error, 30 revolutions max.
pub fn revs_to_10x(cfg: Config, speed_rev_s: f64) -> Option<usize> {
    let (_, per_rev, raw) = commission(cfg, &run(extreme_sensor(), speed_rev_s), 30, no_noise());
    revs_to_reduction(&per_rev, raw, 10.0)
}

pub fn with_gain(gain: f32, proportional: f32) -> Config {
    Config {
        law: AdaptationLaw::Compensated {
            gain_per_rad: gain,
            offset_gain_per_mech_rad: 0.0,
            proportional,
            h_floor: 0.05,
        },
        ..Config::default()
    }
}

/// The paper's Fig. 8 motion: 1 Hz, 100 rad/s sine, extreme sensor, perfect feedforward.
pub fn paper_sine(adc: Option<Adc>) -> Kinematic {
    Kinematic {
        sensor: extreme_sensor(),
        trajectory: Trajectory::Sine {
            amplitude_rad_s: 100.0,
            freq_hz: 1.0,
        },
        sample_period_s: T_S,
        inertia_kg_m2: J_KG_M2,
        adc,
    }
}

//! The random sensor population: a documented distribution and its seeded generator.

use crate::sensor::{Drift, Mount, SensorParams};
use mras_sim::{Adc, SensorHarmonic, SensorModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::TAU;

/// The random sensor population, one constant shared by the generator and the results
/// page. Every parameter is drawn independently and uniformly in its range (noise
/// log-uniformly).
#[derive(Clone, Copy, Debug)]
pub struct Distribution {
    /// The population's name on the results page.
    pub name: &'static str,
    /// Sensor periods per revolution N.
    pub sensor_periods: u16,
    /// The drive's tracker (the firmware's code path) chooses its bank from the data
    /// (`mras::Config::paths_from_data`); otherwise it runs the core's default bank.
    pub bank_from_data: bool,
    /// |Ax|, |Ay| ≤ this (fraction of the nominal amplitude).
    pub offset_max: f64,
    /// Imbalance i = (Bx1 - By1)/mean within ±this (Bx1 = 1 + i/2, By1 = 1 - i/2).
    pub imbalance_max: f64,
    /// |φx1| ≤ this.
    pub quadrature_max_deg: f64,
    pub harmonics: Harmonics,
    /// Noise σ per channel in [min, max], log-uniform.
    pub noise_min: f64,
    pub noise_max: f64,
    pub adc: Adc,
    /// Y sampled this much after X, in [0, max].
    pub skew_max_s: f64,
    /// In the drift phase: dAx/dt, dAy/dt and the relative gain drift each in ±this.
    pub drift_max_per_s: f64,
}

/// The sensor's extra spatial harmonics.
#[derive(Clone, Copy, Debug)]
pub enum Harmonics {
    /// Every order present (h = 1 is the fundamental, h = 0 the offset), X and Y each
    /// their own: Bxh, Byh each in [0, max], phases φxh, φyh each in [0, 2π).
    AllOf { orders: [i32; 8], max: f64 },
    /// `count` (uniform in the range) rotating harmonics (equal on X and Y: one error
    /// harmonic each) at distinct error harmonics m drawn uniformly from 3..=`max_m`,
    /// each of either sequence (h = 1 + m or 1 - m; h = 1 + m only where 1 - m would
    /// pass |h| = 15), amplitude log-uniform in `amplitude`, phase in [0, 2π).
    Rotating {
        count: (usize, usize),
        max_m: u8,
        amplitude: (f64, f64),
    },
}

/// The documented distribution (docs/results.md prints it): KMZ41-like, N = 2.
pub const DISTRIBUTION: Distribution = Distribution {
    name: "N = 2 (KMZ41-like)",
    sensor_periods: 2,
    bank_from_data: false,
    offset_max: 0.10,
    imbalance_max: 0.15,
    quadrature_max_deg: 5.0,
    harmonics: Harmonics::AllOf {
        orders: [-3, -2, -1, 2, 3, 4, 5, 6],
        max: 0.03,
    },
    noise_min: 5e-4,
    noise_max: 5e-3,
    adc: Adc {
        bits: 12,
        full_scale: 1.5,
    },
    skew_max_s: 2e-6,
    drift_max_per_s: 0.01,
};

/// On-axis magnets and Hall arrays, N = 1: their error harmonics land anywhere up to
/// m = 16, a few of them large. The drive chooses its bank from the data. The rest as
/// [`DISTRIBUTION`].
pub const DISTRIBUTION_N1: Distribution = Distribution {
    name: "N = 1 (on-axis magnet, Hall array)",
    sensor_periods: 1,
    bank_from_data: true,
    harmonics: Harmonics::Rotating {
        count: (3, 6),
        max_m: 16,
        amplitude: (0.002, 0.03),
    },
    ..DISTRIBUTION
};

/// One random sensor: its parameters (without drift), the drift that starts in the
/// drift phase, and the seed of its noise.
#[derive(Clone, Debug)]
pub struct SensorCase {
    pub index: usize,
    pub population: &'static Distribution,
    pub params: SensorParams,
    pub drift: Drift,
    pub noise_seed: u64,
}

/// Sensor `index` of the population with `seed`: deterministic, and independent of how
/// many sensors are drawn (each index has its own ChaCha stream), so a reduced run's
/// sensors are the full run's first ones.
pub fn draw_sensor(seed: u64, index: usize) -> SensorCase {
    draw_sensor_in(&DISTRIBUTION, seed, index)
}

/// Sensor `index` of population `d` with `seed` (as [`draw_sensor`]).
pub fn draw_sensor_in(d: &'static Distribution, seed: u64, index: usize) -> SensorCase {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index as u64);
    let mut sym = |max: f64| rng.random_range(-max..=max);
    let mut m = SensorModel::ideal(d.sensor_periods);
    m.ax = sym(d.offset_max);
    m.ay = sym(d.offset_max);
    let imbalance = sym(d.imbalance_max);
    m.bx1 = 1.0 + imbalance / 2.0;
    m.by1 = 1.0 - imbalance / 2.0;
    m.phi_x1_rad = sym(d.quadrature_max_deg).to_radians();
    match d.harmonics {
        Harmonics::AllOf { orders, max } => {
            for h in orders {
                m.push_harmonic(SensorHarmonic {
                    h,
                    bx: rng.random_range(0.0..=max),
                    phi_x_rad: rng.random_range(0.0..TAU),
                    by: rng.random_range(0.0..=max),
                    phi_y_rad: rng.random_range(0.0..TAU),
                });
            }
        }
        Harmonics::Rotating {
            count,
            max_m,
            amplitude: (lo, hi),
        } => {
            let mut orders: Vec<u8> = (3..=max_m).collect();
            for _ in 0..rng.random_range(count.0..=count.1) {
                let m_err = orders.swap_remove(rng.random_range(0..orders.len()));
                let negative = rng.random_bool(0.5) && m_err <= 14;
                let h = if negative {
                    1 - m_err as i32
                } else {
                    1 + m_err as i32
                };
                let b = lo * (hi / lo).powf(rng.random_range(0.0..=1.0));
                m.push_harmonic(SensorHarmonic::equal(h, b, rng.random_range(0.0..TAU)));
            }
        }
    }
    let noise_std = d.noise_min * (d.noise_max / d.noise_min).powf(rng.random_range(0.0..=1.0));
    let skew_s = rng.random_range(0.0..=d.skew_max_s);
    let mut sym = |max: f64| rng.random_range(-max..=max);
    let drift = Drift {
        ax_per_s: sym(d.drift_max_per_s),
        ay_per_s: sym(d.drift_max_per_s),
        gain_per_s: sym(d.drift_max_per_s),
    };
    let noise_seed = rng.random();
    SensorCase {
        index,
        population: d,
        params: SensorParams {
            model: m,
            noise_std,
            adc: Some(d.adc),
            skew_s,
            drift: Drift::default(),
            eccentricity_rad: 0.0,
            eccentricity_phase_rad: 0.0,
            mount: Mount::default(),
        },
        drift,
        noise_seed,
    }
}

impl Distribution {
    /// The ranges as the results page's markdown table.
    pub fn table(&self) -> String {
        let pct = |x: f64| format!("{:.0}", 100.0 * x);
        let (noise, adc) = (100.0 * self.noise_min, &self.adc);
        let rows = [
            [
                "offsets Ax, Ay",
                &format!("±{} % of the amplitude", pct(self.offset_max)),
            ],
            [
                "amplitude imbalance i = (Bx1 - By1)/mean",
                &format!(
                    "±{} % (Bx1 = 1 + i/2, By1 = 1 - i/2)",
                    pct(self.imbalance_max)
                ),
            ],
            ["quadrature φx1", &format!("±{}°", self.quadrature_max_deg)],
            [
                "sensor periods per revolution N",
                &self.sensor_periods.to_string(),
            ],
            ["harmonics", &self.harmonics.describe()],
            [
                "noise σ per channel",
                &format!(
                    "{noise:.2} %..{:.1} % of the amplitude (log-uniform)",
                    100.0 * self.noise_max
                ),
            ],
            [
                "ADC",
                &format!("{} bits over ±{}", adc.bits, adc.full_scale),
            ],
            [
                "X/Y sampling skew",
                &format!("0..{:.0} µs (Y later)", self.skew_max_s * 1e6),
            ],
            [
                "drift, drift phase only",
                &format!(
                    "dAx/dt, dAy/dt, gain each ±{} %/s",
                    pct(self.drift_max_per_s)
                ),
            ],
            [
                "eccentricity",
                "none (a mechanical error no method here could see)",
            ],
        ];
        let rows = rows.map(|r| r.map(String::from).to_vec());
        super::tables::table("| parameter | range |\n|---|---|", rows)
    }
}

impl Harmonics {
    fn describe(&self) -> String {
        match *self {
            Harmonics::AllOf { orders, max } => format!(
                "h = {}, all present; Bxh and Byh each 0..{:.0} %, phases φxh, φyh each 0..2π",
                orders.map(|h| h.to_string()).join(", "),
                100.0 * max
            ),
            Harmonics::Rotating {
                count: (lo_n, hi_n),
                max_m,
                amplitude: (lo, hi),
            } => format!(
                "{lo_n} to {hi_n} rotating harmonics (equal on X and Y), at distinct error \
                 harmonics m drawn from 3..{max_m}, either sequence (h = 1 + m or 1 - m); \
                 amplitude {:.1} %..{:.0} % (log-uniform), phase 0..2π",
                100.0 * lo,
                100.0 * hi
            ),
        }
    }
}

//! Per spatial harmonic of the mechanical angle θrm, over the last whole revolutions of
//! Run: the raw sensor error, the drive's corrected angle against the true rotor angle,
//! the oracle, and the rotor's own motion ripple.
//!
//! Why this exists: with a sensor of one period per revolution (N = 1) the sensor's
//! error harmonics fall on the harmonics a shaft's real motion ripple has (cogging, a
//! load that varies with angle, once and twice per revolution). A sensor error is fixed
//! in angle and the same at any speed; the position ripple a torque ripple causes is
//! real and falls as 1/(J·ω²). The observer's error ε, which the MRAS correlates, holds
//! both at the same harmonic, so only the true rotor angle tells whether the corrected
//! angle got better or learned the motion. The oracle is the floor: the sensor's exact
//! static error map subtracted from each sample ([`crate::accuracy::oracle_angle_rad`],
//! the accuracy benchmark's), i.e. the best any static calibration could do; what it
//! leaves is noise and quantisation.

use crate::accuracy::oracle_angle_rad;
use crate::baselines::line_fit;
use crate::exact::wrap_pi;
use crate::rig::{Reference, Step};
use crate::scenario::{Probe, Scenario, SPECTRUM_HARMONICS_OF_THETA_RM};
use crate::sensor::{Drift, SensorSim};
use anyhow::{bail, Result};
use mras_sim::{SensorModel, SpatialError};
use serde::{Deserialize, Serialize};

/// The scenario's `[truth_spectrum]` table.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TruthSpectrumToml {
    /// Whole revolutions at the reference speed, at the end of each power-up's run, that
    /// the spectrum is taken over (whole, so that the constant-speed fit and the bins
    /// see every angle equally often).
    pub window_revs: u32,
}

impl TruthSpectrumToml {
    /// The window's length (s) for the scenario's reference speed, and the checks that
    /// make the oracle exact: a ramp reference to a non-zero speed, a sensor without
    /// drift (a static map would go stale) or eccentricity (not in the sensor model the
    /// oracle inverts), and a power-up sequence to run.
    pub fn window_s(&self, sc: &Scenario) -> Result<f64> {
        let f = &sc.file;
        if f.commissioning.is_none() {
            bail!("`[truth_spectrum]` needs `[commissioning]`: it measures the power-ups' Run");
        }
        if self.window_revs == 0 {
            bail!("`truth_spectrum.window_revs` must be at least 1");
        }
        let speed_rev_s = match f.control.to_params()?.reference {
            Reference::Ramp { speed_rev_s, .. } if speed_rev_s != 0.0 => speed_rev_s.abs(),
            _ => bail!("`[truth_spectrum]` needs a ramp reference to a non-zero speed"),
        };
        let p = f.sensor.to_params()?;
        if p.drift != Drift::default() || p.eccentricity_rad != 0.0 {
            bail!("`[truth_spectrum]`: the oracle inverts the sensor model, which has no drift or eccentricity; set them to 0");
        }
        let window_s = self.window_revs as f64 / speed_rev_s;
        if window_s > 0.5 * f.duration_s {
            bail!(
                "`truth_spectrum.window_revs` = {}: {window_s:.2} s at {speed_rev_s} rev/s, more than half of `duration_s`",
                self.window_revs
            );
        }
        Ok(window_s)
    }
}

/// One harmonic m of θrm: amplitudes (mrad) of each error against the true rotor angle.
#[derive(Clone, Debug, Serialize)]
pub struct HarmonicRow {
    pub m: u32,
    /// The uncorrected sensor angle (atan2 of the converted X, Y).
    pub raw_mrad: f64,
    /// θ̂, the observer's corrected angle the drive controls with.
    pub estimate_mrad: f64,
    /// arg(Zd), the decoupled vector's angle: the MRAS's correction of each sample alone,
    /// without the observer's filtering (what the oracle is the floor of).
    pub decoupled_mrad: f64,
    /// The oracle: the sensor's exact static error map subtracted.
    pub oracle_mrad: f64,
    /// The true rotor angle less a constant-speed fit (not an error: the shaft's motion).
    pub motion_mrad: f64,
    /// `estimate_mrad / oracle_mrad`.
    pub estimate_over_oracle: f64,
    /// Whether a path of the core's bank nulls this harmonic (a harmonic without one
    /// keeps its raw error whatever the adaptation does).
    pub in_path_bank: bool,
}

/// What the window measured.
#[derive(Clone, Debug, Serialize)]
pub struct TruthSpectrum {
    pub from_s: f64,
    pub to_s: f64,
    /// Revolutions the rotor travelled over the window, and its mean speed (the fit's).
    pub revs: f64,
    pub speed_rev_s: f64,
    /// The rotor's motion ripple binned over θrm (true angle less the constant-speed fit):
    /// pk-pk of the bin means, and pk-pk (twice the amplitude) of its harmonics 1 and 2.
    pub motion_pk_pk_mrad: f64,
    pub motion_1x_pk_pk_mrad: f64,
    pub motion_2x_pk_pk_mrad: f64,
    /// Harmonics m = 1..=16, amplitudes (a constant is removed from every error: it is a
    /// mounting offset no sensor observes).
    pub harmonics: Vec<HarmonicRow>,
    /// √Σ estimate² / √Σ oracle² over m = 3..=16 (where the motion ripple has no
    /// harmonic), over the harmonics with a path in the bank and over those without
    /// (`None`: no such harmonic).
    pub estimate_over_oracle_m3_up_in_bank: Option<f64>,
    pub estimate_over_oracle_m3_up_not_in_bank: Option<f64>,
    /// The same for arg(Zd), the corrected sensor angle (what the sensor correction
    /// leaves, without the observer's response to the unmodelled torque ripple), and
    /// over m = 1, 2 (where the motion ripple is): per harmonic, the oracle is one
    /// draw of the noise, so the ratios are of root sums of squares.
    pub decoupled_over_oracle_m1_m2: f64,
    pub decoupled_over_oracle_m3_up_in_bank: Option<f64>,
    pub decoupled_over_oracle_m3_up_not_in_bank: Option<f64>,
}

impl TruthSpectrum {
    /// arg Zd at m = 1, 2 (root sum of squares) over the noise floor there: the oracle's
    /// mean level over all 16 harmonics, for two. The oracle's own m = 1, 2 are two
    /// draws of the noise, which scatter by several times between runs; the mean over
    /// sixteen is its expected level.
    pub fn decoupled_over_floor_m1_m2(&self) -> f64 {
        let n = self.harmonics.len() as f64;
        let floor2 = 2.0
            * self
                .harmonics
                .iter()
                .map(|r| r.oracle_mrad.powi(2))
                .sum::<f64>()
            / n;
        let e2: f64 = self
            .harmonics
            .iter()
            .filter(|r| r.m <= 2)
            .map(|r| r.decoupled_mrad.powi(2))
            .sum();
        (e2 / floor2).sqrt()
    }

    /// The row of harmonic `m` (1-based).
    pub fn row(&self, m: u32) -> Option<&HarmonicRow> {
        self.harmonics.iter().find(|r| r.m == m)
    }

    /// The printed table, each line indented by `indent`.
    pub fn text(&self, indent: &str) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{indent}against the true rotor, last {:.2} revolutions of Run ({:.2}-{:.2} s, {:.3} rev/s):",
            self.revs, self.from_s, self.to_s, self.speed_rev_s
        );
        let _ = writeln!(
            s,
            "{indent}  rotor motion ripple (θ less a constant-speed fit): {:.2} mrad pk-pk; 1x {:.2}, 2x {:.2} mrad pk-pk",
            self.motion_pk_pk_mrad, self.motion_1x_pk_pk_mrad, self.motion_2x_pk_pk_mrad
        );
        let _ = writeln!(
            s,
            "{indent}  per harmonic m of θrm, amplitude (mrad): raw sensor, θ̂ and arg(Zd) against the rotor, oracle, rotor motion (* no path in the bank)"
        );
        let _ = writeln!(
            s,
            "{indent}  {:>4}{:>10}{:>10}{:>10}{:>10}{:>10}{:>12}",
            "m", "raw", "θ̂", "arg Zd", "oracle", "motion", "θ̂/oracle"
        );
        for r in &self.harmonics {
            let _ = writeln!(
                s,
                "{indent}  {:>3}{}{:>10.3}{:>10.3}{:>10.3}{:>10.4}{:>10.3}{:>12.0}",
                r.m,
                if r.in_path_bank { ' ' } else { '*' },
                r.raw_mrad,
                r.estimate_mrad,
                r.decoupled_mrad,
                r.oracle_mrad,
                r.motion_mrad,
                r.estimate_over_oracle
            );
        }
        let ratio = |m: u32| self.row(m).map_or(f64::NAN, |r| r.estimate_over_oracle);
        // "with a path, without": either may select no harmonic.
        let split = |with: Option<f64>, without: Option<f64>, digits: usize| {
            let part = |r: Option<f64>, what: &str| match r {
                Some(r) => format!("{r:.digits$}x {what}"),
                None => format!("no harmonic {what}"),
            };
            format!(
                "{}, {}",
                part(with, "with a path"),
                part(without, "without")
            )
        };
        let _ = writeln!(
            s,
            "{indent}  θ̂ over the oracle: m = 1 {:.0}x, m = 2 {:.0}x; m = 3..{} (root sum of squares) {}",
            ratio(1),
            ratio(2),
            SPECTRUM_HARMONICS_OF_THETA_RM,
            split(
                self.estimate_over_oracle_m3_up_in_bank,
                self.estimate_over_oracle_m3_up_not_in_bank,
                0
            )
        );
        let _ = writeln!(
            s,
            "{indent}  arg Zd over the oracle (root sums of squares): m = 1, 2 {:.1}x; m = 3..{} {}",
            self.decoupled_over_oracle_m1_m2,
            SPECTRUM_HARMONICS_OF_THETA_RM,
            split(
                self.decoupled_over_oracle_m3_up_in_bank,
                self.decoupled_over_oracle_m3_up_not_in_bank,
                1
            )
        );
        s
    }
}

/// One period in the window: the true angle, and each angle's error against it (rad,
/// mechanical).
#[derive(Clone, Copy, Debug)]
struct Sample {
    t_s: f64,
    theta_rad: f64,
    raw_rad: f64,
    estimate_rad: f64,
    decoupled_rad: f64,
    oracle_rad: f64,
}

/// Collects the window's periods of one power-up; [`Recorder::add`] is called for every
/// period spent in Run.
#[derive(Clone, Debug)]
pub struct Recorder {
    from_s: f64,
    to_s: f64,
    period_s: f64,
    probe: Probe,
    model: SensorModel,
    skew_s: f64,
    /// Harmonics of θrm that a path of the core's bank nulls.
    bank: Vec<u32>,
    samples: Vec<Sample>,
}

impl Recorder {
    /// A recorder for the scenario's `[truth_spectrum]` over a run of `duration_s`; None
    /// without the table. The table's rules are checked when the scenario is loaded
    /// ([`TruthSpectrumToml::window_s`]); a scenario changed since that has no ramp
    /// reference gets None too.
    pub fn new(sc: &Scenario, sensor: &SensorSim, duration_s: f64) -> Option<Self> {
        let table = sc.file.truth_spectrum?;
        let speed_rev_s = match sc.file.control.to_params().ok()?.reference {
            Reference::Ramp { speed_rev_s, .. } if speed_rev_s != 0.0 => speed_rev_s.abs(),
            _ => return None,
        };
        let window_s = table.window_revs as f64 / speed_rev_s;
        let period_s = sc.sample_period_s();
        let n = sensor.params.model.sensor_periods;
        let bank = sc
            .core_config(None)
            .ok()?
            .paths()
            .iter()
            .map(|p| p.mechanical_error_harmonic(n))
            .collect();
        let steps = (window_s / period_s).round().min(1e7) as usize;
        Some(Self {
            // The run's last period starts at duration - T.
            from_s: duration_s - window_s,
            to_s: duration_s,
            period_s,
            probe: Probe::of(&sensor.params),
            model: sensor.params.model,
            skew_s: sensor.params.skew_s,
            bank,
            samples: Vec::with_capacity(steps + 1),
        })
    }

    /// A period in Run.
    pub fn add(&mut self, s: &Step) {
        let t = s.truth.t_s;
        // Half a period of slack: the times are multiples of T computed in f64.
        if t < self.from_s - 0.5 * self.period_s {
            return;
        }
        let n = self.probe.sensor_periods;
        let th = s.truth.theta_rad;
        let magnet = self.probe.magnet_rad(th);
        let (raw_rad, estimate_rad) = self.probe.errors_rad(s);
        let zd = s.estimate.decoupled;
        let decoupled_rad = wrap_pi((zd.im as f64).atan2(zd.re as f64) - n * magnet) / n;
        // The sensed angle turns at ±ω: Y, sampled `skew_s` later, is that much further.
        let dir = if self.probe.mount.reversed { -1.0 } else { 1.0 };
        let skew_e_rad = n * dir * s.truth.omega_rad_s * self.skew_s;
        let oracle = oracle_angle_rad(&self.model, skew_e_rad, s.truth.x, s.truth.y, n * magnet);
        let oracle_rad = wrap_pi(oracle - n * magnet) / n;
        self.samples.push(Sample {
            t_s: t,
            theta_rad: th,
            raw_rad,
            estimate_rad,
            decoupled_rad,
            oracle_rad,
        });
    }

    /// The spectra, or None when the window was not spent in Run throughout (the
    /// power-up ended elsewhere, or reached Run too late).
    pub fn finish(&self) -> Option<TruthSpectrum> {
        let expected = ((self.to_s - self.from_s) / self.period_s).round() as usize;
        let first = self.samples.first()?;
        if first.t_s > self.from_s + 0.5 * self.period_s || self.samples.len() + 1 < expected {
            return None;
        }
        let (t_mean, th_mean, slope_rad_s) =
            line_fit(self.samples.iter().map(|s| (s.t_s, s.theta_rad)));
        let mut bins: [SpatialError<360>; 5] = Default::default();
        for s in &self.samples {
            let motion = s.theta_rad - th_mean - slope_rad_s * (s.t_s - t_mean);
            let errors = [
                s.raw_rad,
                s.estimate_rad,
                s.decoupled_rad,
                s.oracle_rad,
                motion,
            ];
            for (b, e) in bins.iter_mut().zip(errors) {
                b.add(s.theta_rad, e);
            }
        }
        let mrad = |b: &SpatialError<360>, m: u32| b.harmonic_amplitude_rad(m) * 1e3;
        let harmonics: Vec<HarmonicRow> = (1..=SPECTRUM_HARMONICS_OF_THETA_RM)
            .map(|m| {
                let (estimate_mrad, oracle_mrad) = (mrad(&bins[1], m), mrad(&bins[3], m));
                HarmonicRow {
                    m,
                    raw_mrad: mrad(&bins[0], m),
                    estimate_mrad,
                    decoupled_mrad: mrad(&bins[2], m),
                    oracle_mrad,
                    motion_mrad: mrad(&bins[4], m),
                    estimate_over_oracle: estimate_mrad / oracle_mrad,
                    in_path_bank: self.bank.contains(&m),
                }
            })
            .collect();
        // √Σ error² / √Σ oracle² over the harmonics `keep` selects, if any.
        let rss_ratio = |error: fn(&HarmonicRow) -> f64, keep: &dyn Fn(&HarmonicRow) -> bool| {
            let kept = || harmonics.iter().filter(|r| keep(r));
            let e: f64 = kept().map(|r| error(r).powi(2)).sum();
            let o: f64 = kept().map(|r| r.oracle_mrad.powi(2)).sum();
            (kept().count() > 0).then(|| (e / o).sqrt())
        };
        let estimate = |r: &HarmonicRow| r.estimate_mrad;
        let decoupled = |r: &HarmonicRow| r.decoupled_mrad;
        let m3_up = |in_bank: bool| move |r: &HarmonicRow| r.m >= 3 && r.in_path_bank == in_bank;
        let last = self.samples.last()?;
        Some(TruthSpectrum {
            from_s: first.t_s,
            to_s: last.t_s + self.period_s,
            revs: (last.theta_rad - first.theta_rad).abs() / std::f64::consts::TAU,
            speed_rev_s: slope_rad_s / std::f64::consts::TAU,
            motion_pk_pk_mrad: bins[4].pk_pk_rad() * 1e3,
            motion_1x_pk_pk_mrad: 2.0 * harmonics[0].motion_mrad,
            motion_2x_pk_pk_mrad: 2.0 * harmonics[1].motion_mrad,
            estimate_over_oracle_m3_up_in_bank: rss_ratio(estimate, &m3_up(true)),
            estimate_over_oracle_m3_up_not_in_bank: rss_ratio(estimate, &m3_up(false)),
            // m = 1, 2 are always in the spectrum.
            decoupled_over_oracle_m1_m2: rss_ratio(decoupled, &|r| r.m <= 2).unwrap_or(f64::NAN),
            decoupled_over_oracle_m3_up_in_bank: rss_ratio(decoupled, &m3_up(true)),
            decoupled_over_oracle_m3_up_not_in_bank: rss_ratio(decoupled, &m3_up(false)),
            harmonics,
        })
    }
}

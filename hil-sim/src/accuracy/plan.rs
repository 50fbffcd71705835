//! The phases every sensor's run goes through.

use super::{BINS, SAMPLE_PERIOD_S, SENSOR_PERIODS};
use crate::plant::MotorParams;

/// A plan the run cannot execute: the rule it breaks.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("the plan has no phases")]
    NoPhases,
    #[error("the plan must start with a commissioning phase and evaluate after")]
    Order,
    #[error("phase `{0}`: need 0 <= settle_s < duration_s")]
    Settle(&'static str),
    #[error("phase `{0}`: bad speed or acceleration")]
    Motion(&'static str),
    #[error(
        "{calibration_revs} calibration revolutions do not fit in the {revs:.1} revolutions \
         of adaptation"
    )]
    CalibrationTooLong { calibration_revs: u32, revs: f64 },
}

/// What a phase does besides holding its speed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PhaseKind {
    /// Spin-up from rest, our MRAS adapting, the offline methods' calibration spin.
    Commissioning,
    /// Evaluation at a constant speed.
    Steady,
    /// Load torque steps during the measurement window.
    LoadSteps,
    /// The sensor's offsets and gain drift from the start of the phase.
    Drift,
}

/// One phase of the run: ramp to `speed_rev_s`, hold, measure after `settle_s`.
#[derive(Clone, Debug, PartialEq)]
pub struct Phase {
    pub name: &'static str,
    /// Short name for CSV columns and plots.
    pub key: &'static str,
    pub kind: PhaseKind,
    pub speed_rev_s: f64,
    /// Ramp of the speed setpoint from the previous phase's speed.
    pub accel_rad_s2: f64,
    pub duration_s: f64,
    /// Commissioning: when adaptation starts; evaluation: when measurement starts.
    pub settle_s: f64,
    /// Load steps (time from the phase start, load torque as a fraction of rated).
    pub load_steps: Vec<(f64, f64)>,
}

/// The run every sensor goes through.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// The first is the commissioning phase, the rest are evaluated.
    pub phases: Vec<Phase>,
    /// The offline methods' calibration spin: the last this many whole revolutions of
    /// the commissioning phase.
    pub calibration_revs: u32,
    /// Cogging torque harmonics (of θrm) as (harmonic, fraction of rated torque).
    pub cogging: Vec<(u32, f64)>,
    /// Speed loop bandwidth (the `commissioning` scenario's).
    pub speed_loop_hz: f64,
}

/// Commissioning phase of [`Plan::full_n1`] (s): 52 revolutions of adaptation at
/// +20 rev/s; the N = 1 population's banks from the data complete within 41 (2.4 s gave
/// 40, short of a few banks that grow in a third round).
pub const COMMISSIONING_N1_S: f64 = 3.0;

/// The evaluated phase whose residual spectrum is reported (the first: steady at the
/// commissioning speed, nothing else going on).
pub const SPECTRUM_PHASE: usize = 0;

impl Plan {
    /// The phases as the results page's markdown table.
    pub fn table(&self) -> String {
        let rows = self.phases.iter().enumerate().map(|(i, p)| {
            let what = match p.kind {
                PhaseKind::Commissioning => format!(
                    "from rest; trackers frozen until {} s, then adapting; the offline \
                     calibration spin is its last {} revolutions",
                    p.settle_s, self.calibration_revs
                ),
                PhaseKind::Drift => "sensor offsets and gain drift from the phase start".into(),
                _ => p
                    .load_steps
                    .iter()
                    .map(|(t, pu)| format!("load {:.0} % rated at +{t} s", pu * 100.0))
                    .collect::<Vec<_>>()
                    .join(", "),
            };
            let from = match i {
                0 => "not scored".into(),
                _ => format!("+{} s", p.settle_s),
            };
            let (speed, ramp) = (p.speed_rev_s, p.accel_rad_s2);
            let cells = [format!("{speed:+} rev/s"), format!("{ramp} rad/s²")];
            [
                vec![p.name.into()],
                cells.into(),
                vec![format!("{} s", p.duration_s), from, what],
            ]
            .concat()
        });
        let head = "| phase | speed | ramp | duration | scored from | what else |\n\
                    |---|---:|---:|---:|---:|---|";
        super::tables::table(head, rows)
    }

    /// The plan's figures the results page names (`plan.*`, `spectrum.phase`).
    pub fn figures(&self) -> Vec<(&'static str, String)> {
        // The observer's angle lag under an unmodelled torque step: ΔT/K_so, with
        // K_so = Ĵ(λ1λ2 + λ1λ3 + λ2λ3) of the default observer and this motor's J.
        let motor = MotorParams::default();
        let steps = self.evaluation().iter().flat_map(|p| &p.load_steps);
        let step = steps.map(|(_, pu)| pu.abs()).fold(0.0, f64::max);
        let step_nm = step * motor.rated_torque_nm;
        let [l1, l2, l3] = mras::Config::default()
            .observer
            .eigenvalues_hz
            .map(|f| std::f64::consts::TAU * f as f64);
        let k_so = motor.j_kg_m2 * (l1 * l2 + l1 * l3 + l2 * l3);
        let cogging = self
            .cogging
            .iter()
            .map(|(h, pu)| format!("{:.0} % at harmonic {h}", pu * 100.0));
        let bin_deg = 360 / (BINS * SENSOR_PERIODS as usize);
        vec![
            ("plan.n", SENSOR_PERIODS.to_string()),
            ("plan.bins", BINS.to_string()),
            ("plan.bin_deg", bin_deg.to_string()),
            ("plan.cal_revs", self.calibration_revs.to_string()),
            ("plan.speed_loop_hz", self.speed_loop_hz.to_string()),
            ("plan.cogging", cogging.collect::<Vec<_>>().join(", ")),
            ("plan.step_nm", format!("{step_nm:.2}")),
            ("plan.k_so", format!("{k_so:.1}")),
            ("plan.lag_mrad", format!("{:.0}", 1e3 * step_nm / k_so)),
            (
                "spectrum.phase",
                self.evaluation()[SPECTRUM_PHASE].name.into(),
            ),
        ]
    }

    /// The published run: 4 s simulated per sensor. The other speed is +40 rev/s: the
    /// default 48 V motor's back-EMF reaches the inverter's voltage limit near 55 rev/s,
    /// where the speed loop winds up and the torque feedforward stops matching the
    /// torque (a longer +60 rev/s phase made every tracker lose lock at the next
    /// reversal: a drive limit, not a sensor one).
    pub fn full() -> Self {
        let steady = |name, key, speed_rev_s, accel_rad_s2, duration_s, settle_s| Phase {
            name,
            key,
            kind: PhaseKind::Steady,
            speed_rev_s,
            accel_rad_s2,
            duration_s,
            settle_s,
            load_steps: Vec::new(),
        };
        Self {
            phases: vec![
                Phase {
                    kind: PhaseKind::Commissioning,
                    ..steady(
                        "commissioning +20 rev/s",
                        "commissioning",
                        20.0,
                        500.0,
                        1.0,
                        0.4,
                    )
                },
                steady("+20 rev/s", "fwd20", 20.0, 2000.0, 0.45, 0.0),
                steady("+40 rev/s", "fwd40", 40.0, 2000.0, 0.6, 0.25),
                steady("-20 rev/s", "rev20", -20.0, 2000.0, 0.65, 0.35),
                Phase {
                    kind: PhaseKind::LoadSteps,
                    load_steps: vec![(0.25, 0.5), (0.45, 0.0)],
                    ..steady("+20 rev/s, load steps", "load", 20.0, 2000.0, 0.6, 0.2)
                },
                Phase {
                    kind: PhaseKind::Drift,
                    ..steady("+20 rev/s, drift", "drift", 20.0, 2000.0, 0.7, 0.2)
                },
            ],
            calibration_revs: 8,
            cogging: vec![(24, 0.04), (12, 0.02)],
            speed_loop_hz: 10.0,
        }
    }

    /// The published run for the N = 1 population: as [`Plan::full`], with a commissioning
    /// phase long enough for a bank from the data (its survey rounds cover whole
    /// revolutions at N = 1, and each round adapts until its bank converges).
    pub fn full_n1() -> Self {
        let mut plan = Self::full();
        plan.phases[0].duration_s = COMMISSIONING_N1_S;
        plan
    }

    /// Check the plan is one the run can execute.
    pub fn validate(&self) -> Result<(), PlanError> {
        let first = self.phases.first().ok_or(PlanError::NoPhases)?;
        if first.kind != PhaseKind::Commissioning || self.phases.len() < 2 {
            return Err(PlanError::Order);
        }
        for p in &self.phases {
            if !(p.duration_s > 0.0 && (0.0..p.duration_s).contains(&p.settle_s)) {
                return Err(PlanError::Settle(p.name));
            }
            if !(p.accel_rad_s2 > 0.0 && p.speed_rev_s.is_finite()) {
                return Err(PlanError::Motion(p.name));
            }
        }
        let c = first;
        let revs = (c.duration_s - c.settle_s) * c.speed_rev_s.abs();
        if (self.calibration_revs as f64) > revs - 0.5 {
            return Err(PlanError::CalibrationTooLong {
                calibration_revs: self.calibration_revs,
                revs,
            });
        }
        Ok(())
    }

    /// Start time of each phase (whole control periods).
    pub fn phase_starts_s(&self) -> Vec<f64> {
        let mut t = 0u64;
        self.phases
            .iter()
            .map(|p| {
                let start = t as f64 * SAMPLE_PERIOD_S;
                t += steps(p.duration_s);
                start
            })
            .collect()
    }

    pub fn duration_s(&self) -> f64 {
        self.phases.iter().map(|p| steps(p.duration_s)).sum::<u64>() as f64 * SAMPLE_PERIOD_S
    }

    /// The evaluated phases (all but commissioning).
    pub fn evaluation(&self) -> &[Phase] {
        &self.phases[1..]
    }
}

/// Whole control periods in `duration_s`.
pub(super) fn steps(duration_s: f64) -> u64 {
    (duration_s / SAMPLE_PERIOD_S).round() as u64
}

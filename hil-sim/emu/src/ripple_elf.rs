//! The torque-ripple learner on the release ELF (`cargo xtask ripple-elf`): the
//! `sensor-n1` build with Run at 1 rev/s (`slow-run`) and at 5 rev/s (`run-5rev`), each
//! with and without `learn-ripple`, on a board carrying `ripple-1rev`'s load and N = 1
//! sensor ([`Board::ripple_n1`]). Each build commissions from an erased flash, then
//! holds Run below half the commissioning speed, where the drive holds its coefficients
//! and the learner may run (at 1 rev/s the release observer shows none of the learner's
//! harmonics above its floor; at 5 rev/s it shows all four). Scored at the plant
//! only: the streamed θ̂ against the true rotor angle by harmonic of the rotor angle
//! ([`plant_truth::estimate_harmonics_rad`], the fit `power-up` scores θ̂ with), and the
//! rotor's own motion ([`plant_truth::motion_ripple`], as hil-sim's truth spectrum).
//!
//! Why N = 1: the load's once- and twice-per-revolution ripple moves the shaft at
//! m = 1, 2 of the rotor angle, which is then a harmonic of the sensor angle, the only
//! kind the learner models (drive's `ripple` module).

use crate::board::Board;
use crate::scenarios::{self, Outcome};
use crate::Emu;
use anyhow::{bail, Context, Result};
use hil_sim::plant_truth::{self, EstimateScore, MotionRipple};
use hil_sim::scenario::{Scenario, SPECTRUM_HARMONICS_OF_THETA_RM};
use hil_sim::stream::{self, Item};
use std::fmt::Write as _;

/// Emulated seconds the commissioning of the heavy N = 1 rig may take to reach Run
/// (survey rounds over whole revolutions at N = 1, docs/theory.md §8; `perf`'s N = 1
/// board takes 15 s at most).
const TO_RUN_LIMIT_S: f64 = 30.0;

/// How long the measurement runs: Run's entry, `settle_s` for the brake from the
/// commissioning speed and the speed loop to settle (and the learner, when on, to learn:
/// its model moves by half of what it lacks each revolution, drive's `RIPPLE_GAIN`),
/// then the whole revolutions nearest `window_s` (at least one) scored.
#[derive(Clone, Copy, Debug)]
pub struct Plan {
    pub settle_s: f64,
    pub window_s: f64,
}

/// 2 s to settle (two revolutions at 1 rev/s), 4 s scored: ~360 of the 11 ms records,
/// which fit 16 harmonics of the rotor angle at any speed.
pub const PLAN: Plan = Plan {
    settle_s: 2.0,
    window_s: 4.0,
};

/// One build measured.
#[derive(Clone, Debug)]
pub struct RippleElf {
    pub label: String,
    pub outcome: Outcome,
    /// When the stream said Run (firmware ms), and the scored window (emulated s).
    pub run_ms: u32,
    pub window_s: (f64, f64),
    pub motion: MotionRipple,
    /// Per harmonic m = 1..=16 of the rotor angle (index m - 1): the raw sensor's error
    /// and θ̂'s against the rotor at the records' periods (rad, mechanical).
    pub raw_rad: Vec<f64>,
    pub estimate_rad: Vec<f64>,
    pub score: EstimateScore,
    /// The control interrupt over the window in Run: est. cycles mean, max.
    pub isr_cycles_mean: f64,
    pub isr_cycles_max: u64,
    pub missed_in_window: usize,
    /// The streamed ω̂ over the window (what the drive's steadiness check sees, at the
    /// records' periods): its mean (rad/s), and the share of records further from it
    /// than `Params::speed_tolerance` of it. The learner learns only while the speed is
    /// steady by that tolerance (against ω̂'s 50 ms low-pass, 1 kHz).
    pub omega_mean_rad_s: f64,
    pub omega_unsteady_share: f64,
}

impl RippleElf {
    /// The root sum of squares of θ̂'s harmonics in `ms` (rad).
    pub fn estimate_rss_rad(&self, ms: std::ops::RangeInclusive<u32>) -> f64 {
        rss(&self.estimate_rad, ms)
    }

    pub fn raw_rss_rad(&self, ms: std::ops::RangeInclusive<u32>) -> f64 {
        rss(&self.raw_rad, ms)
    }
}

fn rss(h: &[f64], ms: std::ops::RangeInclusive<u32>) -> f64 {
    ms.filter_map(|m| h.get(m as usize - 1))
        .map(|a| a * a)
        .sum::<f64>()
        .sqrt()
}

/// Commission `elf` on the ripple board and measure its Run by [`Plan`].
pub fn run(label: &str, elf: &[u8], plan: Plan) -> Result<RippleElf> {
    let t0 = std::time::Instant::now();
    let mut emu = Emu::new(elf, Board::ripple_n1(1)?, None)?;
    scenarios::run_until_state(&mut emu, "Run", TO_RUN_LIMIT_S)?;
    let mut o = Outcome::default();
    scenarios::read_stream_of(&emu.elf, &emu.m().rtt.bytes, &mut o)?;
    let run_ms = o.entered(0, "Run").context("no Run in the stream")?;
    emu.run_for(plan.settle_s)?;
    let speed_rad_s = emu.m().board.truth().omega_rad_s.abs();
    if speed_rad_s < 0.5 {
        bail!("{label}: the rotor turns at {speed_rad_s:.2} rad/s {} s into Run: no steady Run to score", plan.settle_s);
    }
    let rev_s = std::f64::consts::TAU / speed_rad_s;
    // Rounded, not floored: the speed measured a hair under its setpoint must not cost
    // a revolution.
    let window = (plan.window_s / rev_s).round().max(1.0) * rev_s;
    let from_s = emu.m().time_s();
    let missed_before = emu.m().stats.missed_control();
    emu.m_mut().stats.restart_window();
    emu.run_for(window)?;
    let to_s = emu.m().time_s();
    let outcome = scenarios::finish(label, &emu, t0, Vec::new())?;
    if outcome.entered(0, "Safe").is_some() || outcome.boots != 1 {
        bail!("{label}: left Run: {}", outcome.state_lines().join("; "));
    }
    let period_s = emu.m().board.period_s();
    let log = scenarios::period_truth(&emu, 0);
    let from = (from_s / period_s).round() as usize;
    let periods = log.get(from..).unwrap_or(&[]);
    let motion = plant_truth::motion_ripple(periods).context("no periods in the window")?;
    let from_ms = (from_s * 1e3).ceil() as u32;
    let d = stream::decode(&emu.elf, &emu.m().rtt.bytes)?;
    let in_window: Vec<_> = d
        .items
        .iter()
        .filter_map(|i| match i {
            Item::Line(l) if l.kind == "mras" => l.record().ok(),
            _ => None,
        })
        .filter(|r| r.state == drive::commissioning::State::Run && r.t_ms >= from_ms)
        .collect();
    let records: Vec<(u32, f32)> = in_window.iter().map(|r| (r.t_ms, r.theta_rad)).collect();
    let omegas: Vec<f64> = in_window.iter().map(|r| r.omega_rad_s as f64).collect();
    let omega_mean_rad_s = omegas.iter().sum::<f64>() / omegas.len().max(1) as f64;
    let tolerance = drive::commissioning::Params::default().speed_tolerance as f64;
    let unsteady = omegas
        .iter()
        .filter(|w| (*w - omega_mean_rad_s).abs() > tolerance * omega_mean_rad_s.abs())
        .count();
    let omega_unsteady_share = unsteady as f64 / omegas.len().max(1) as f64;
    let pwm_hz = 1.0 / period_s;
    let probe = scenarios::probe(&emu);
    let h = SPECTRUM_HARMONICS_OF_THETA_RM;
    let (raw_rad, estimate_rad) =
        plant_truth::estimate_harmonics_rad(log, pwm_hz, &probe, &records, h)
            .with_context(|| format!("{label}: scoring {} streamed θ̂", records.len()))?;
    let score = plant_truth::score_estimates(log, pwm_hz, &probe, &records, h)?;
    let st = &emu.m().stats;
    Ok(RippleElf {
        label: label.to_string(),
        run_ms,
        window_s: (from_s, to_s),
        motion,
        raw_rad,
        estimate_rad,
        score,
        isr_cycles_mean: st.isr_cycles_mean(),
        isr_cycles_max: st.isr_cycles_max,
        missed_in_window: st.missed_control() - missed_before,
        omega_mean_rad_s,
        omega_unsteady_share,
        outcome,
    })
}

/// |H(j·k·N·ω)| for k = 1..=4 at `speed_rad_s` with the observer eigenvalues of the
/// `commissioning` scenario (the bench's, the firmware's board.rs core_config): the
/// learner learns harmonic k only where this is at least drive's `RIPPLE_MIN_H`.
fn shown(speed_rad_s: f64) -> Result<Vec<f64>> {
    let cfg = Scenario::load("commissioning")?.core_config(None)?;
    let g = mras::observer::ObserverGains::from_eigenvalues(
        cfg.observer.eigenvalues_hz,
        cfg.observer.inertia_kg_m2,
    );
    Ok((1..=drive::ripple::RIPPLE_HARMONICS)
        .map(|k| g.error_transfer((k as f64 * speed_rad_s) as f32).abs() as f64)
        .collect())
}

/// docs/performance.md's section: the builds side by side.
pub fn report(runs: &[RippleElf], plan: Plan) -> Result<String> {
    let mut s = String::new();
    let mrad = |r: f64| format!("{:.3}", r * 1e3);
    let _ = writeln!(
        s,
        "| build | Run: speed (rev/s), revolutions scored | rotor motion pk-pk at 1x / 2x (mrad) | θ̂ at m = 1 / m = 2 (mrad) | θ̂ at m = 3..16, root sum of squares (mrad) | raw sensor at m = 1 / 2; m = 3..16 (mrad) | θ̂ pk-pk, harmonics 1..16 (mrad) | control interrupt in the window, est. cycles mean / max | missed periods in the window |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---:|");
    for r in runs {
        let _ = writeln!(
            s,
            "| {} | {:.3}, {:.2} | {} / {} | {} / {} | {} | {} / {}; {} | {} | {:.0} / {} | {} |",
            r.label,
            r.motion.speed_rad_s / std::f64::consts::TAU,
            r.motion.revs,
            mrad(r.motion.h1_pk_pk_rad),
            mrad(r.motion.h2_pk_pk_rad),
            mrad(r.estimate_rad[0]),
            mrad(r.estimate_rad[1]),
            mrad(r.estimate_rss_rad(3..=16)),
            mrad(r.raw_rad[0]),
            mrad(r.raw_rad[1]),
            mrad(r.raw_rss_rad(3..=16)),
            mrad(r.score.estimate_pk_pk_rad),
            r.isr_cycles_mean,
            r.isr_cycles_max,
            r.missed_in_window
        );
    }
    s.push('\n');
    let mut speeds: Vec<f64> = Vec::new();
    for r in runs {
        let speed = r.motion.speed_rad_s.abs();
        if speeds.iter().any(|v| (v / speed - 1.0).abs() < 0.05) {
            continue;
        }
        speeds.push(speed);
        let h: Vec<String> = shown(speed)?
            .iter()
            .enumerate()
            .map(|(k, h)| format!("{h:.1e} at k = {}", k + 1))
            .collect();
        let _ = writeln!(
            s,
            "- At {:.2} rev/s the observer shows a harmonic k of the sensor angle by |H(j·k·ω)| = {} (eigenvalues of board.rs's core_config); the learner learns a harmonic only where |H| ≥ {} (drive's `RIPPLE_MIN_H`).",
            speed / std::f64::consts::TAU,
            h.join(", "),
            drive::ripple::RIPPLE_MIN_H
        );
    }
    for r in runs {
        let _ = writeln!(
            s,
            "- {}: {}; Run from {} ms, scored from {:.2} s to {:.2} s of emulated time ({} records); the streamed ω̂ over the window {:.2} rad/s mean, {:.0} % of its records more than {:.0} % from it (`Params::speed_tolerance`); {:.1} emulated s in {:.0} s wall",
            r.label,
            r.outcome.state_lines().join("; "),
            r.run_ms,
            r.window_s.0,
            r.window_s.1,
            r.score.records,
            r.omega_mean_rad_s,
            100.0 * r.omega_unsteady_share,
            100.0 * drive::commissioning::Params::default().speed_tolerance,
            r.outcome.emulated_s,
            r.outcome.wall_s
        );
    }
    let _ = writeln!(
        s,
        "\nEach build: power-up from an erased flash to Run, {:.1} s of Run to settle, then the whole revolutions nearest {:.1} s scored.",
        plan.settle_s, plan.window_s
    );
    Ok(s)
}

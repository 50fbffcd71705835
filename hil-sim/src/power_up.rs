//! The `commissioning` scenario: the firmware's control period and supervisor
//! (`drive::control`, `drive::supervisor`, with its flash record on simulated pages)
//! commissioning the simulated drive, for two power-ups: the first with an erased flash
//! (self-commissioning, electrical alignment, store), the second with what the first one
//! stored.

use crate::accuracy::stats::Dist;
use crate::plant_truth::CurrentVector;
use crate::rig::{Rig, SimFlash, Step, Streamed};
use crate::scenario::{NamedCoefficient, Probe, Scenario, Window, WindowStats};
use crate::stream::Losses;
use crate::truth_spectrum::{Recorder, TruthSpectrum};
use anyhow::{anyhow, Result};
use calib_record::{Alignment, RamFlash};
use drive::commissioning::{Cause, State};
use drive::handoff::{HANDOFF_DEPTH, UPDATE_DEPTH};
use drive::supervisor::Supervisor;
use drive::telemetry::{Event, Line};
use mras::F32Trig;
use std::f64::consts::TAU;

/// What one power-up did.
#[derive(Clone, Debug)]
pub struct Boot {
    /// (time, state entered).
    pub transitions: Vec<(f64, State)>,
    pub final_state: State,
    pub cause: Option<Cause>,
    pub loaded_from_flash: bool,
    /// Spatial error over the last 0.1 s of spin-up (uncorrected sensor), if reached.
    pub spin_up: Option<WindowStats>,
    /// Spatial error over the last 20 % of the run, if in Run by then.
    pub run: Option<WindowStats>,
    /// Time adapting (Adapt state) and revolutions over it.
    pub adapt_s: Option<f64>,
    pub adapt_revs: Option<f64>,
    /// Periods in which the control period latched a fault.
    pub faulted_samples: u32,
    pub coefficients: Vec<NamedCoefficient>,
    /// The alignment in force at the end.
    pub alignment: Alignment,
    /// Over the Run window, measured at the plant ([`CurrentVector`]): the mean error of
    /// the electrical angle of the current the bridge drives against the rotor's q axis.
    pub run_angle_error_e_rad: Option<f64>,
    /// Over the Run window, at the plant: mean torque over mean current magnitude,
    /// relative to the torque constant (1 when the current is all on the q axis); and
    /// the mean speed.
    pub run_torque_per_amp: Option<f64>,
    pub run_speed_rad_s: Option<f64>,
    /// Control periods that did not run (CPU stalled by flash).
    pub missed_periods: u64,
    /// The supervisor's lines, with the time they came out.
    pub streamed: Vec<Streamed>,
    /// The scenario's `[truth_spectrum]` over the end of Run (None without the table, or
    /// when the window was not all in Run).
    pub truth_spectrum: Option<TruthSpectrum>,
}

impl Boot {
    pub fn entered(&self, s: State) -> Option<f64> {
        self.transitions
            .iter()
            .find(|(_, x)| *x == s)
            .map(|(t, _)| *t)
    }

    /// What the stream says was lost: the firmware's counters in the records
    /// (hand-over, updates, events) and gaps in `seq`.
    pub fn losses(&self) -> Losses {
        crate::stream::losses_of(&self.streamed)
    }

    /// The motor's constants the identification streamed (the last, if several).
    pub fn identified(&self) -> Option<drive::ident::Identified> {
        self.streamed.iter().rev().find_map(|s| match s.line {
            Line::Event(Event::Identified {
                r_ohm,
                ld_h,
                lq_h,
                v_inverter_v,
                ..
            }) => Some(drive::ident::Identified {
                r_ohm,
                ld_h,
                lq_h,
                v_inverter_v,
            }),
            _ => None,
        })
    }

    /// The motion constants the last `mras-motion` event put in force.
    pub fn motion(&self) -> Option<Motion> {
        self.streamed.iter().rev().find_map(|s| match s.line {
            Line::Event(Event::Motion {
                flux_wb,
                inertia_kg_m2,
                viscous_nm_s_rad,
                coulomb_nm,
                ..
            }) => Some(Motion {
                flux_wb,
                inertia_kg_m2,
                viscous_nm_s_rad,
                coulomb_nm,
            }),
            _ => None,
        })
    }

    /// The records streamed, in order.
    pub fn records(&self) -> impl Iterator<Item = &drive::telemetry::Record> + '_ {
        self.streamed.iter().filter_map(|s| match &s.line {
            Line::Record(r) => Some(r),
            _ => None,
        })
    }
}

/// The motor's mechanical constants as a power-up streamed them (`mras-motion`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    pub flux_wb: f32,
    pub inertia_kg_m2: f32,
    pub viscous_nm_s_rad: f32,
    pub coulomb_nm: f32,
}

/// What an experiment does to the rig during a power-up, after each period.
pub type Hook<'a, const H: usize = HANDOFF_DEPTH, const U: usize = UPDATE_DEPTH> =
    &'a mut dyn FnMut(&mut Rig<F32Trig, H, U>, &Step);

/// The scenario's rig with the firmware's supervisor on `flash`.
pub fn rig(sc: &Scenario, flash: SimFlash, seed: u64) -> Result<Rig> {
    rig_with(sc, flash, seed, |_| {})
}

/// [`rig`] with the controller's configuration adjusted.
pub fn rig_with(
    sc: &Scenario,
    flash: SimFlash,
    seed: u64,
    adjust: impl FnOnce(&mut drive::control::DriveConfig),
) -> Result<Rig> {
    let f = &sc.file;
    let c = f
        .commissioning
        .ok_or_else(|| anyhow!("{}: no [commissioning] table", sc.origin))?;
    let mut cfg = sc.core_config(None)?;
    // The plant is not the controller: the drive starts from the firmware's nominal
    // motor (pole pairs, R, L, ψ, and J for the motion loops and the observer, unless
    // the scenario configures another J) and identifies the plant's at power-up.
    let j = c
        .inertia_kg_m2
        .map_or(board_map::motor::INERTIA_KG_M2, |j| j as f32);
    cfg.observer.inertia_kg_m2 = j;
    let rig = sc.rig_with(cfg, seed, |d| {
        let m = &mut d.motor;
        m.pole_pairs = board_map::motor::POLE_PAIRS;
        m.r_ohm = board_map::motor::R_OHM;
        m.l_h = board_map::motor::L_H;
        m.flux_wb = board_map::motor::FLUX_WB;
        m.inertia_kg_m2 = j;
        adjust(d)
    })?;
    let d = rig.period.config();
    let hash = rig.period.calibration_hash();
    let rate_hz = (1.0 / sc.sample_period_s()).round() as u32;
    let n = rig.period.tracker().config().sensor_periods;
    let sup = Supervisor::new(
        c.params()?,
        hash,
        rate_hz,
        d.supervisor_divider,
        &d.motor,
        n,
    );
    Ok(rig.with_supervisor(sup, flash))
}

/// Run one power-up for `duration_s` on `flash`; `hook` runs after every period.
pub fn boot(
    sc: &Scenario,
    flash: SimFlash,
    seed: u64,
    duration_s: f64,
    hook: Option<Hook>,
) -> Result<(Boot, SimFlash)> {
    let mut rig = rig(sc, flash, seed)?;
    let boot = run_boot(&mut rig, sc, duration_s, hook);
    let flash = rig.into_flash().unwrap_or_default();
    Ok((boot, flash))
}

/// Run a power-up on a rig made by [`rig`] or [`rig_with`] (with any queue depths); Run
/// is measured over the last fifth of `duration_s`.
pub fn run_boot<const H: usize, const U: usize>(
    rig: &mut Rig<F32Trig, H, U>,
    sc: &Scenario,
    duration_s: f64,
    hook: Option<Hook<H, U>>,
) -> Boot {
    run_boot_measured(rig, sc, duration_s, None, hook)
}

/// [`run_boot`], with Run measured from `settle_s` after its entry to the end (where
/// motors reach Run at different times, the same share of each one's Run: the last fifth
/// of the run could fall within the first moments of a late one's).
pub fn run_boot_settled<const H: usize, const U: usize>(
    rig: &mut Rig<F32Trig, H, U>,
    sc: &Scenario,
    duration_s: f64,
    settle_s: f64,
    hook: Option<Hook<H, U>>,
) -> Boot {
    run_boot_measured(rig, sc, duration_s, Some(settle_s), hook)
}

fn run_boot_measured<const H: usize, const U: usize>(
    rig: &mut Rig<F32Trig, H, U>,
    sc: &Scenario,
    duration_s: f64,
    settle_s: Option<f64>,
    mut hook: Option<Hook<H, U>>,
) -> Boot {
    let t_s = sc.sample_period_s();
    let probe = Probe::of(&rig.plant.sensor.params);
    let steps = (duration_s / t_s).round() as u64;
    let mut transitions = vec![(0.0, State::CheckSensor)];
    let mut faulted = 0u32;
    // Spin-up error: the last complete 0.1 s slice before adaptation starts.
    const SLICE_S: f64 = 0.1;
    let (mut spin_slice, mut spin_up): (Option<(f64, Window)>, Option<Window>) = (None, None);
    let mut run_from = 0.8 * duration_s;
    let mut run = Window::new(run_from, duration_s + t_s);
    let (mut speed_sum, mut run_n) = (0.0, 0u64);
    let mut current = CurrentVector::new(&rig.plant.motor);
    let mut adapt_start: Option<(f64, f64)> = None;
    let mut spectrum = Recorder::new(sc, &rig.plant.sensor, duration_s);
    let (mut adapt_s, mut adapt_revs) = (None, None);
    // States as the supervisor published them (a flash operation delays its output).
    let (mut state, mut seen) = (State::CheckSensor, 0);
    for _ in 0..steps {
        let s = rig.step();
        faulted += s.fault.is_some() as u32;
        for item in &rig.streamed()[seen..] {
            match item.line {
                Line::Event(Event::State { state: x, .. }) => state = x,
                Line::Event(Event::Fault { .. }) => state = State::Safe,
                _ => {}
            }
        }
        seen = rig.streamed().len();
        if transitions.last().map(|(_, x)| *x) != Some(state) {
            transitions.push((s.truth.t_s, state));
            if let (State::Run, Some(settle_s)) = (state, settle_s) {
                run_from = s.truth.t_s + settle_s;
                run = Window::new(run_from, duration_s + t_s);
            }
            if state == State::Adapt {
                adapt_start = Some((s.truth.t_s, s.truth.theta_rad));
            } else if let Some((t0, th0)) = adapt_start.take() {
                adapt_s = Some(s.truth.t_s - t0);
                adapt_revs = Some((s.truth.theta_rad - th0).abs() / TAU);
            }
        }
        match state {
            State::SpinUp => {
                let (t0, w) = spin_slice
                    .get_or_insert_with(|| (s.truth.t_s, Window::new(0.0, f64::INFINITY)));
                if s.truth.t_s - *t0 >= SLICE_S {
                    spin_up = spin_slice.take().map(|(_, w)| w);
                } else {
                    w.add(&s, &probe);
                }
            }
            State::Run => {
                run.add(&s, &probe);
                if let Some(r) = spectrum.as_mut() {
                    r.add(&s);
                }
                if s.truth.t_s >= run_from {
                    speed_sum += s.truth.omega_rad_s;
                    run_n += 1;
                    // The plant at the end of the period just driven: its rotor angle and
                    // currents there, and the period's mean torque (as the emulator
                    // pairs them at each sampling instant).
                    let p = &rig.plant;
                    current.add(p.theta_rad(), p.currents_ab(), s.torque_nm);
                }
            }
            _ => {}
        }
        if let Some(h) = hook.as_mut() {
            h(rig, &s);
        }
    }
    let sup = rig.supervisor();
    let final_state = sup.map_or(State::Safe, |p| p.state());
    let alignment = sup.map_or(Alignment::IDENTITY, |p| p.alignment());
    let in_run = final_state == State::Run;
    Boot {
        final_state,
        cause: sup.and_then(|p| p.cause()),
        loaded_from_flash: sup.is_some_and(|p| p.calibration_loaded()),
        spin_up: spin_up.map(|w| w.stats()),
        run: in_run.then(|| run.stats()),
        adapt_s,
        adapt_revs,
        faulted_samples: faulted,
        coefficients: rig
            .adaptation()
            .adapter()
            .coefficients()
            .iter()
            .map(|(k, v)| (crate::scenario::path_name(k), v.re, v.im))
            .collect(),
        alignment,
        run_angle_error_e_rad: current
            .stats()
            .filter(|_| in_run)
            .map(|c| c.angle_error_e_rad),
        run_torque_per_amp: current.stats().filter(|_| in_run).map(|c| c.torque_per_amp),
        run_speed_rad_s: (in_run && run_n > 0).then(|| speed_sum / run_n as f64),
        missed_periods: rig.missed_periods,
        streamed: rig.streamed().to_vec(),
        transitions,
        truth_spectrum: spectrum.and_then(|r| r.finish()),
    }
}

/// Both power-ups: erased flash, then the flash the first one left.
pub fn run(sc: &Scenario, duration_s: f64) -> Result<(Boot, Boot)> {
    let flash = SimFlash::new(RamFlash::default());
    let (first, flash) = boot(sc, flash, sc.file.seed, duration_s, None)?;
    let (second, _) = boot(sc, flash, sc.file.seed + 1, duration_s, None)?;
    Ok((first, second))
}

/// arg Zd over the oracle (root sums of squares) of one power-up's truth spectrum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OracleRatios {
    /// Over m = 1, 2, where the motion ripple is.
    pub m1_m2: f64,
    /// Over m = 1, 2, to the oracle's mean level over all harmonics
    /// ([`TruthSpectrum::decoupled_over_floor_m1_m2`]).
    pub m1_m2_floor: f64,
    /// Over m = 3..16 with a path in the bank.
    pub m3_up: f64,
}

/// A scenario with a truth spectrum run at several sensor-noise seeds. Per harmonic the
/// oracle is one draw of the noise (a few µrad once the sensor error is corrected), so
/// one run's ratio to it is one draw too; its spread over seeds is the figure.
#[derive(Clone, Debug)]
pub struct SeedSpread {
    /// Per seed: both power-ups' ratios.
    pub runs: Vec<(u64, [OracleRatios; 2])>,
}

impl SeedSpread {
    /// Both power-ups at seeds 1, 3, .., 2·`seeds` - 1 (the second power-up of a run
    /// takes the next seed: odd seeds keep every power-up's noise its own), in parallel.
    pub fn run(sc: &Scenario, duration_s: f64, seeds: u64) -> Result<Self> {
        use rayon::prelude::*;
        if sc.file.commissioning.is_none() || sc.file.truth_spectrum.is_none() {
            return Err(anyhow!(
                "{}: a spread over seeds needs [commissioning] and [truth_spectrum]",
                sc.file.name
            ));
        }
        let runs = (0..seeds)
            .into_par_iter()
            .map(|k| {
                let seed = 2 * k + 1;
                let mut sc = sc.clone();
                sc.file.seed = seed;
                let (first, second) = run(&sc, duration_s)?;
                let ratios = |b: &Boot| {
                    b.truth_spectrum.as_ref().map(|t| OracleRatios {
                        m1_m2: t.decoupled_over_oracle_m1_m2,
                        m1_m2_floor: t.decoupled_over_floor_m1_m2(),
                        m3_up: t.decoupled_over_oracle_m3_up_in_bank.unwrap_or(f64::NAN),
                    })
                };
                match (ratios(&first), ratios(&second)) {
                    (Some(a), Some(b)) => Ok((seed, [a, b])),
                    _ => Err(anyhow!(
                        "seed {seed}: a power-up was not in Run over the whole window"
                    )),
                }
            })
            .collect::<Result<_>>()?;
        Ok(Self { runs })
    }

    fn over(&self, pick: fn(&OracleRatios) -> f64) -> Dist {
        Dist::of(self.runs.iter().flat_map(|(_, r)| r.iter().map(pick)))
    }

    /// Over every power-up, m = 1, 2.
    pub fn m1_m2(&self) -> Dist {
        self.over(|r| r.m1_m2)
    }

    /// Over every power-up, m = 1, 2 to the noise floor.
    pub fn m1_m2_floor(&self) -> Dist {
        self.over(|r| r.m1_m2_floor)
    }

    /// Over every power-up, m = 3..16 with a path.
    pub fn m3_up(&self) -> Dist {
        self.over(|r| r.m3_up)
    }
}

/// The events of a power-up as text lines (state changes, faults, flash).
pub fn event_lines(b: &Boot) -> Vec<String> {
    b.streamed
        .iter()
        .filter_map(|s| {
            let t = s.t_s;
            match &s.line {
                Line::Event(e) => Some(format!("{t:8.3} s  {}", describe(e))),
                Line::Record(_) => None,
                Line::Paths(b) => Some(format!(
                    "{t:8.3} s  paths: {}",
                    drive::telemetry::bank_names(b.as_slice())
                )),
            }
        })
        .collect()
}

fn describe(e: &Event) -> String {
    use drive::telemetry::cause_name;
    match *e {
        Event::State { state, .. } => state.name().to_string(),
        Event::Fault { cause, state, .. } => {
            format!("SAFE STATE: {} (in {})", cause_name(cause), state.name())
        }
        Event::Loaded { sequence, .. } => format!("calibration loaded (record {sequence})"),
        Event::NotLoaded { reason, .. } => format!("no stored calibration ({reason})"),
        Event::Stored { .. } => "calibration stored".into(),
        Event::StoreFailed { reason, .. } => format!("store failed ({reason})"),
        Event::Aligned {
            offset_e_rad,
            reversed,
            ratio,
            pole_pairs,
            ..
        } => format!(
            "aligned: electrical offset {offset_e_rad:+.3} rad, {}, {ratio:.3} sensor periods per period, {pole_pairs} pole pairs",
            if reversed { "reversed" } else { "forward" }
        ),
        Event::OffsetCorrected { offset_e_rad, .. } => {
            format!("electrical offset moved onto the corrected angle: {offset_e_rad:+.3} rad")
        }
        Event::Identified {
            r_ohm,
            ld_h,
            lq_h,
            v_inverter_v,
            ..
        } => format!(
            "identified: R {r_ohm:.4} ohm, Ld {:.1} uH, Lq {:.1} uH, inverter error {v_inverter_v:.3} V",
            1e6 * ld_h,
            1e6 * lq_h
        ),
        Event::Motion {
            flux_wb,
            inertia_kg_m2,
            viscous_nm_s_rad,
            coulomb_nm,
            ..
        } => format!(
            "motion constants in force: flux linkage {:.3} mWb, inertia {inertia_kg_m2:.4e} kg m^2, friction {viscous_nm_s_rad:.3e} N m s/rad and {coulomb_nm:.3e} N m",
            1e3 * flux_wb
        ),
        Event::Refined {
            speed_rad_s,
            second_speed_rad_s,
            motion_max,
            ..
        } => {
            let rev_s = |w: f32| w / std::f32::consts::TAU;
            if second_speed_rad_s > 0.0 {
                format!(
                    "refined at {:.2} and {:.2} rev/s: motion separated, up to {:.4} mrad at the first",
                    rev_s(speed_rad_s),
                    rev_s(second_speed_rad_s),
                    1e3 * motion_max
                )
            } else {
                format!("refined at {:.2} rev/s (mean coefficients)", rev_s(speed_rad_s))
            }
        }
    }
}

/// One power-up in `summary.json` (scenarios with `[truth_spectrum]`).
#[derive(serde::Serialize)]
struct BootJson<'a> {
    power_up: &'a str,
    final_state: &'static str,
    cause: Option<String>,
    loaded_from_flash: bool,
    adapt_s: Option<f64>,
    adapt_revs: Option<f64>,
    faulted_samples: u32,
    run_speed_rev_s: Option<f64>,
    /// What the stream lost (zero everywhere on a healthy drive).
    losses: Losses,
    coefficients: &'a [NamedCoefficient],
    truth_spectrum: Option<&'a TruthSpectrum>,
}

/// `summary.json` of a power-up scenario: per power-up, the figures of its report that a
/// script compares (the per-harmonic spectra in full).
pub fn summary_json(sc: &Scenario, duration_s: f64, boots: &[(&str, &Boot)]) -> Result<String> {
    #[derive(serde::Serialize)]
    struct Summary<'a> {
        scenario: &'a str,
        duration_s: f64,
        power_ups: Vec<BootJson<'a>>,
    }
    let power_ups = boots
        .iter()
        .map(|(title, b)| BootJson {
            power_up: title,
            final_state: b.final_state.name(),
            cause: b.cause.map(|c| format!("{c:?}")),
            loaded_from_flash: b.loaded_from_flash,
            adapt_s: b.adapt_s,
            adapt_revs: b.adapt_revs,
            faulted_samples: b.faulted_samples,
            run_speed_rev_s: b.run_speed_rad_s.map(|w| w / TAU),
            losses: b.losses(),
            coefficients: &b.coefficients,
            truth_spectrum: b.truth_spectrum.as_ref(),
        })
        .collect();
    Ok(serde_json::to_string_pretty(&Summary {
        scenario: &sc.file.name,
        duration_s,
        power_ups,
    })?)
}

/// The printed report.
pub fn report(sc: &Scenario, boots: &[(&str, &Boot)]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "scenario {}: {}", sc.file.name, sc.file.description);
    for (title, b) in boots {
        let _ = writeln!(s, "  power-up {title}:");
        for line in event_lines(b) {
            let _ = writeln!(s, "    {line}");
        }
        if b.cause.is_none() {
            let _ = writeln!(
                s,
                "    calibration {}",
                if b.loaded_from_flash {
                    "loaded from flash"
                } else {
                    "commissioned and stored"
                }
            );
        }
        if let Some(e) = b.run_angle_error_e_rad {
            let _ = writeln!(
                s,
                "    electrical angle error in Run (mean, against the rotor): {:+.1} mrad electrical",
                e * 1e3
            );
        }
        if let (Some(t), Some(r)) = (b.adapt_s, b.adapt_revs) {
            let _ = writeln!(
                s,
                "    adaptation converged in {t:.2} s / {r:.1} revolutions"
            );
        }
        if let Some(w) = &b.spin_up {
            let _ = writeln!(
                s,
                "    spatial error at the end of spin-up (uncorrected): raw {:.2}, θ̂ {:.2} mrad pk-pk",
                w.raw_pk_pk_mrad, w.estimate_pk_pk_mrad
            );
        }
        if let Some(w) = &b.run {
            let _ = writeln!(
                s,
                "    spatial error in Run (last 20 %): raw {:.2}, θ̂ {:.4} mrad pk-pk ({:.0}x), RMS {:.4} mrad",
                w.raw_pk_pk_mrad,
                w.estimate_pk_pk_mrad,
                w.raw_pk_pk_mrad / w.estimate_pk_pk_mrad,
                w.estimate_rms_mrad
            );
        }
        if let (Some(k), Some(w)) = (b.run_torque_per_amp, b.run_speed_rad_s) {
            let _ = writeln!(
                s,
                "    Run: {:.2} rev/s, torque per amp {:.4} of the torque constant",
                w / TAU,
                k
            );
        }
        let _ = writeln!(
            s,
            "    faulted periods: {}, missed control periods: {}",
            b.faulted_samples, b.missed_periods
        );
        let _ = writeln!(s, "    losses: {}", b.losses().describe());
        if sc.file.truth_spectrum.is_some() {
            match &b.truth_spectrum {
                Some(t) => s += &t.text("    "),
                None => {
                    let _ = writeln!(
                        s,
                        "    against the true rotor: not measured (the window was not all in Run)"
                    );
                }
            }
        }
        let coefs: Vec<String> = b
            .coefficients
            .iter()
            .map(|(n, re, im)| format!("{n} {re:+.4}{im:+.4}j"))
            .collect();
        let _ = writeln!(s, "    coefficients: {}", coefs.join(", "));
    }
    s
}

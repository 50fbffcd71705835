//! The firmware-in-the-loop scenarios: the release ELF on the emulated board, each
//! ending in what a bench engineer would check (the streamed states and faults, MOE,
//! the reset cause) and what the emulator measured (missed control periods, the control
//! interrupt's executed instructions, the longest interrupt-masked stretch).

use crate::board::Board;
use crate::periph::tim1::Tim1;
use crate::periph::{ticks, TICK_HZ};
use crate::Emu;
use anyhow::{bail, Context, Result};
use hil_sim::stream::{self, Item};
use std::fmt::Write as _;

/// Every scenario, in the order of docs/performance.md.
pub const ALL: &[&str] = &[
    "power-up",
    "wire-break",
    "overcurrent",
    "watchdog",
    "store-flash-error",
    "rtt-host-stops",
];

/// One streamed event: emulator time, the firmware's own t_ms, kind and fields.
#[derive(Clone, Debug)]
pub struct Event {
    pub boot: usize,
    pub kind: String,
    pub text: String,
}

/// What a scenario measured.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    pub name: String,
    /// Per boot: the states entered with the firmware's t_ms.
    pub states: Vec<Vec<(String, u32)>>,
    pub events: Vec<Event>,
    pub missed_periods: u64,
    pub control_periods: u64,
    pub isr_instrs_mean: f64,
    pub isr_instrs_max: u64,
    /// The same interrupts' estimated Cortex-M4 cycles (`profile`).
    pub isr_cycles_mean: f64,
    pub isr_cycles_max: u64,
    /// The PWM (control) period the firmware programmed, in CPU cycles.
    pub period_cycles: u64,
    pub masked_max_instrs: u64,
    pub latency_max_instrs: u64,
    pub boots: usize,
    pub hard_faults: usize,
    /// Scenario-specific figures, printed as `key = value`.
    pub notes: Vec<(String, String)>,
    /// Rules the firmware broke (the models' counters), empty when none.
    pub violations: Vec<String>,
    pub emulated_s: f64,
    pub wall_s: f64,
}

impl Outcome {
    pub fn entered(&self, boot: usize, state: &str) -> Option<u32> {
        self.states
            .get(boot)?
            .iter()
            .find(|(s, _)| s == state)
            .map(|(_, t)| *t)
    }

    pub fn has_event(&self, kind: &str, text_contains: &str) -> bool {
        self.events
            .iter()
            .any(|e| e.kind == kind && e.text.contains(text_contains))
    }

    pub fn note(&self, key: &str) -> Option<&str> {
        self.notes
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// The state sequence of each boot, as one line per boot.
    pub fn state_lines(&self) -> Vec<String> {
        self.states
            .iter()
            .enumerate()
            .map(|(b, s)| {
                let seq: Vec<String> = s.iter().map(|(n, t)| format!("{n} {t} ms")).collect();
                if seq.is_empty() {
                    format!("boot {}: no state change streamed", b + 1)
                } else {
                    format!("boot {}: {}", b + 1, seq.join(" → "))
                }
            })
            .collect()
    }
}

/// The firmware's stream: states per boot (a new boot starts at the banner) and events.
fn read_stream(emu: &Emu, out: &mut Outcome) -> Result<()> {
    let d = stream::decode(&emu.elf, &emu.m().rtt.bytes).context("decoding the RTT stream")?;
    let mut boot = 0usize;
    let mut seen_banner = false;
    out.states = vec![Vec::new()];
    for item in d.items {
        match item {
            Item::Other(o) if o.starts_with("drive-fw:") => {
                if seen_banner {
                    boot += 1;
                    out.states.push(Vec::new());
                }
                seen_banner = true;
            }
            Item::Other(o) => out.events.push(Event {
                boot,
                kind: "log".into(),
                text: o,
            }),
            Item::Line(l) if l.kind == "mras" || l.kind == "mras-paths" => {}
            Item::Line(l) => {
                if l.kind == "mras-state" {
                    if let (Some(s), Some(t)) = (l.get("state"), l.t_ms()) {
                        out.states[boot].push((s.text(), t));
                    }
                }
                out.events.push(Event {
                    boot,
                    kind: l.kind.clone(),
                    text: l.describe(),
                });
            }
        }
    }
    Ok(())
}

/// The rules the models count, as sentences (empty when the firmware kept them all).
pub fn violations(emu: &Emu) -> Vec<String> {
    let m = emu.m();
    let mut v = Vec::new();
    let a = m.adcs.violations;
    if a.aden_ignored > 0 {
        v.push(format!(
            "ADC: ADEN set within 4 ADC clocks of ADCAL clearing, ignored {} times (RM0440 §21.4.9)",
            a.aden_ignored
        ));
    }
    if a.cal_without_regulator > 0 {
        v.push(format!(
            "ADC: calibration started before the regulator settled ({}×, §21.4.6)",
            a.cal_without_regulator
        ));
    }
    if a.no_clock > 0 {
        v.push(format!("ADC: no ADC clock ({}×, §21.4.3)", a.no_clock));
    }
    for (p, n) in &m.unmodelled.gated {
        v.push(format!(
            "clock gating: {n} accesses to {p} with its RCC enable off (§7.4)"
        ));
    }
    if m.rcc.overclocked > 0 {
        v.push("RCC/PWR: 170 MHz without range-1 boost (PWR_CR5.R1MODE = 1, §6.1.5)".into());
    }
    if m.rcc.latency_too_low > 0 {
        v.push("FLASH: too few wait states for SYSCLK (§3.3.3)".into());
    }
    if m.flash_ctl.stale_flag_refusals > 0 {
        v.push(format!(
            "FLASH: {} operations refused with PGSERR, error flags of an earlier one still set (§3.3.7)",
            m.flash_ctl.stale_flag_refusals
        ));
    }
    if m.flash_ctl.code_bank_erases > 0 {
        v.push(format!(
            "FLASH: {} page erases in the bank the code runs from: CPU stalled {} ms each (§3.3.8)",
            m.flash_ctl.code_bank_erases,
            crate::periph::flash::ERASE_S * 1e3
        ));
    }
    let peaks = m.tim1.peaks.max(1);
    if m.tim1.updates > peaks + 2 {
        v.push(format!(
            "TIM1: {} update events in {} PWM periods: CCRs load twice per period, at peak and valley (RCR = 0, §28.3.3)",
            m.tim1.updates, peaks
        ));
    }
    if m.tim1.breaks_unrouted > 0 {
        v.push(format!(
            "TIM1: over-current on BKIN not routed to the break (AF1.BKINE = 0, §28.6.27): {} comparator trips ignored",
            m.tim1.breaks_unrouted
        ));
    }
    if !m.unmodelled.unknown.is_empty() {
        let list: Vec<String> = m
            .unmodelled
            .unknown
            .keys()
            .map(|a| format!("{a:#010x}"))
            .collect();
        v.push(format!(
            "bus: accesses to registers no model knows: {}",
            list.join(", ")
        ));
    }
    v
}

fn finish(
    name: &str,
    emu: &Emu,
    t0: std::time::Instant,
    notes: Vec<(String, String)>,
) -> Result<Outcome> {
    let m = emu.m();
    let mut out = Outcome {
        name: name.into(),
        missed_periods: m.adcs.missed_triggers,
        control_periods: m.stats.isr_count_total,
        isr_instrs_mean: m.stats.isr_mean(),
        isr_instrs_max: m.stats.isr_instrs_max,
        isr_cycles_mean: m.stats.isr_cycles_mean(),
        isr_cycles_max: m.stats.isr_cycles_max,
        period_cycles: period_cycles(emu),
        masked_max_instrs: m.stats.masked_max,
        latency_max_instrs: m.stats.latency_max,
        boots: m.stats.boots.len(),
        hard_faults: m.stats.hard_faults.len(),
        notes,
        violations: violations(emu),
        emulated_s: m.time_s(),
        wall_s: t0.elapsed().as_secs_f64(),
        ..Outcome::default()
    };
    read_stream(emu, &mut out)?;
    Ok(out)
}

/// The control period the firmware's timer runs, in CPU cycles (the tick is 170 MHz).
pub fn period_cycles(emu: &Emu) -> u64 {
    emu.m().board.period_ticks() / emu.m().rcc.ticks_per_instr.max(1)
}

/// Run until the stream of the current boot satisfies `done`, or `limit_s`.
fn run_until(
    emu: &mut Emu,
    what: &str,
    limit_s: f64,
    done: impl Fn(&Outcome, usize) -> bool,
) -> Result<f64> {
    let step = 0.05;
    let boots = emu.m().stats.boots.len();
    while emu.m().time_s() < limit_s {
        emu.run_for(step)?;
        let mut o = Outcome::default();
        read_stream(emu, &mut o)?;
        let b = o.states.len() - 1;
        if emu.m().stats.boots.len() == boots && done(&o, b) {
            return Ok(emu.m().time_s());
        }
    }
    let mut o = Outcome::default();
    read_stream(emu, &mut o)?;
    let m = emu.m();
    bail!(
        "{what} not seen within {limit_s} s of emulated time\n  states: {}\n  other log lines: {}\n  \
         boots: {}, HardFaults: {:?}, pc now {:#010x}, control interrupts: {}\n  rules broken:\n    {}",
        o.state_lines().join("; "),
        o.events.iter().filter(|e| e.kind == "log" || e.kind == "mras-fault").map(|e| e.text.clone()).collect::<Vec<_>>().join(" | "),
        m.stats.boots.len(),
        m.stats.hard_faults,
        emu.pc(),
        m.stats.isr_count_total,
        violations(emu).join("\n    ")
    )
}

/// Run until the stream shows `state` entered in the current boot.
fn run_until_state(emu: &mut Emu, state: &str, limit_s: f64) -> Result<f64> {
    run_until(emu, &format!("state `{state}`"), limit_s, |o, b| {
        o.entered(b, state).is_some()
    })
}

/// A board with an erased calibration area, powered on.
fn fresh(elf: &[u8], flash: Option<Vec<u8>>) -> Result<Emu> {
    Emu::new(elf, Board::commissioning(1)?, flash)
}

/// Run a scenario on the firmware `elf`.
pub fn run(name: &str, elf: &[u8]) -> Result<Outcome> {
    let t0 = std::time::Instant::now();
    let mut notes = Vec::new();
    let mut note = |k: &str, v: String| notes.push((k.to_string(), v));
    let emu = match name {
        "power-up" => {
            // Two power-ups (erased, then with the stored calibration), one outcome.
            let mut p = power_up_run(elf)?;
            p.outcome.wall_s = t0.elapsed().as_secs_f64();
            p.outcome.notes.push((
                "raw sensor error in Run".into(),
                format!("{:.1} mrad pk-pk", p.raw_error_pkpk_rad * 1e3),
            ));
            p.outcome.notes.push((
                "MRAS residual, first in Adapt → Run".into(),
                format!(
                    "{:.2} → {:.3} mrad",
                    p.residual_first_rad * 1e3,
                    p.residual_run_rad * 1e3
                ),
            ));
            return Ok(p.outcome);
        }
        "wire-break" => {
            let mut emu = fresh(elf, None)?;
            run_until_state(&mut emu, "Run", 4.0)?;
            emu.run_for(0.2)?;
            // Both wires of the sensor's bridge open: X and Y at the amplifier's zero.
            let mut broken = emu.m().board.plant.sensor.params.clone();
            broken.model = mras_sim::SensorModel::ideal(2);
            broken.model.bx1 = 0.0;
            broken.model.by1 = 0.0;
            emu.m_mut().board.plant.sensor = hil_sim::sensor::SensorSim::new(broken, 7)?;
            // From the first sampling instant that sees the broken sensor.
            let t_break = emu.m().now;
            while emu.m().stats.last_trigger < t_break {
                emu.run_for(0.5e-6)?;
            }
            let t_sample = emu.m().stats.last_trigger;
            while Tim1::moe(&emu.m().regs) && emu.m().now < t_break + ticks(0.01) {
                emu.run_for(0.5e-6)?;
            }
            let dt = (emu.m().now - t_sample) as f64 / TICK_HZ;
            note(
                "bridge off after the first broken sample",
                format!("{:.1} µs", dt * 1e6),
            );
            note(
                "bridge off in control periods",
                format!("{:.2}", dt / emu.m().board.period_s()),
            );
            // Run rides through a sensor fault while the core re-acquires; a sensor that
            // stays broken ends in the safe state after the supervisor's timeout (50 ms).
            emu.run_for(0.1)?;
            emu
        }
        "overcurrent" => {
            let mut emu = fresh(elf, None)?;
            run_until_state(&mut emu, "Run", 4.0)?;
            emu.run_for(0.2)?;
            // The comparator's threshold below the running current: it trips.
            emu.m_mut().board.plant.break_level_a = 0.05;
            let t_trip = emu.m().now;
            while !emu.m().board.plant.comparator_tripped() && emu.m().now < t_trip + ticks(0.01) {
                emu.run_for(1.0e-6)?;
            }
            let tripped_at = emu.m().now;
            while Tim1::moe(&emu.m().regs) && emu.m().now < tripped_at + ticks(0.01) {
                emu.run_for(0.2e-6)?;
            }
            let hw = emu.m().tim1.breaks;
            note("MOE cleared by the break (hardware)", (hw > 0).to_string());
            note(
                "bridge off after the trip",
                format!(
                    "{:.1} µs",
                    (emu.m().now - tripped_at) as f64 / TICK_HZ * 1e6
                ),
            );
            emu.run_for(0.05)?;
            emu
        }
        "watchdog" => {
            let mut emu = fresh(elf, None)?;
            run_until_state(&mut emu, "Run", 4.0)?;
            emu.run_for(0.1)?;
            // A stuck interrupt line: the control interrupt re-enters forever and the
            // supervisor that feeds the watchdog never runs.
            emu.m_mut().stuck_control_irq = true;
            let t_stall = emu.m().time_s();
            let boots = emu.m().stats.boots.len();
            while emu.m().stats.boots.len() == boots && emu.m().time_s() < t_stall + 0.5 {
                emu.run_for(0.005)?;
            }
            emu.m_mut().stuck_control_irq = false;
            note(
                "watchdog reset after the stall",
                format!("{:.0} ms", (emu.m().time_s() - t_stall) * 1e3),
            );
            emu.run_for(0.3)?;
            emu
        }
        "store-flash-error" => {
            let mut board = Board::commissioning(1)?;
            // The calibration pages write-protected in the option bytes (WRP2A).
            board.wrp2a_pages = Some((126, 127));
            let mut emu = Emu::new(elf, board, None)?;
            run_until(&mut emu, "the store's fault", 4.0, |o, _| {
                o.has_event("mras-fault", "StoreFailed")
            })?;
            emu.run_for(0.1)?;
            note("MOE in Safe", Tim1::moe(&emu.m().regs).to_string());
            emu
        }
        "rtt-host-stops" => {
            let mut emu = fresh(elf, None)?;
            emu.run_for(0.5)?;
            // The host stops reading: the 1 KiB up-buffer fills, the firmware drops
            // whole frames and keeps controlling.
            emu.m_mut().rtt.reading = false;
            let isr0 = emu.m().stats.isr_count_total;
            emu.run_for(1.0)?;
            let during = emu.m().stats.isr_count_total - isr0;
            note(
                "control periods while the host did not read (1 s)",
                during.to_string(),
            );
            emu.m_mut().rtt.reading = true;
            run_until_state(&mut emu, "Run", 5.0)?;
            emu.run_for(0.2)?;
            emu
        }
        other => bail!("unknown scenario `{other}` (known: {})", ALL.join(", ")),
    };
    finish(name, &emu, t0, notes)
}

/// The main job's power-up: both boots with their streams and the errors.
pub struct PowerUp {
    pub outcome: Outcome,
    /// The raw defmt capture of each boot.
    pub captures: Vec<Vec<u8>>,
    pub raw_error_pkpk_rad: f64,
    pub residual_first_rad: f64,
    pub residual_run_rad: f64,
}

/// Erased-flash power-up to Run, then a second power-up with the kept flash.
pub fn power_up_run(elf: &[u8]) -> Result<PowerUp> {
    let t0 = std::time::Instant::now();
    let mut emu = fresh(elf, None)?;
    let t_run = run_until_state(&mut emu, "Run", 4.0)?;
    emu.run_for(0.5)?;
    let first = finish("power-up", &emu, t0, Vec::new())?;
    let (first_res, run_res) = residuals(&emu)?;
    let raw = raw_error_pkpk(&emu, t_run);
    let mut again = fresh(elf, Some(emu.flash()))?;
    run_until_state(&mut again, "Run", 2.0)?;
    again.run_for(0.3)?;
    let second = finish("power-up", &again, t0, Vec::new())?;
    let mut outcome = second.clone();
    outcome.states = [first.states.clone(), second.states.clone()].concat();
    outcome.events = first.events.clone();
    outcome.events.extend(second.events.iter().map(|e| Event {
        boot: e.boot + 1,
        ..e.clone()
    }));
    outcome.missed_periods += first.missed_periods;
    outcome.control_periods += first.control_periods;
    outcome.isr_instrs_mean = (first.isr_instrs_mean * first.control_periods as f64
        + second.isr_instrs_mean * second.control_periods as f64)
        / (first.control_periods + second.control_periods).max(1) as f64;
    outcome.isr_instrs_max = first.isr_instrs_max.max(second.isr_instrs_max);
    outcome.isr_cycles_mean = (first.isr_cycles_mean * first.control_periods as f64
        + second.isr_cycles_mean * second.control_periods as f64)
        / (first.control_periods + second.control_periods).max(1) as f64;
    outcome.isr_cycles_max = first.isr_cycles_max.max(second.isr_cycles_max);
    outcome.masked_max_instrs = first.masked_max_instrs.max(second.masked_max_instrs);
    outcome.violations = [first.violations.clone(), second.violations.clone()].concat();
    outcome.emulated_s = first.emulated_s + second.emulated_s;
    outcome.boots = first.boots + second.boots;
    Ok(PowerUp {
        outcome,
        captures: vec![emu.m().rtt.bytes.clone(), again.m().rtt.bytes.clone()],
        raw_error_pkpk_rad: raw,
        residual_first_rad: first_res,
        residual_run_rad: run_res,
    })
}

/// The streamed MRAS residual: the first record in Adapt with a residual, the last in Run.
fn residuals(emu: &Emu) -> Result<(f64, f64)> {
    let d = stream::decode(&emu.elf, &emu.m().rtt.bytes)?;
    let recs: Vec<_> = d
        .items
        .iter()
        .filter_map(|i| match i {
            Item::Line(l) if l.kind == "mras" => l.record().ok(),
            _ => None,
        })
        .collect();
    let first = recs
        .iter()
        .find(|r| r.state == drive::commissioning::State::Adapt && r.residual_max_rad > 0.0)
        .map_or(f64::NAN, |r| r.residual_max_rad as f64);
    let run = recs
        .iter()
        .rev()
        .find(|r| r.state == drive::commissioning::State::Run)
        .map_or(f64::NAN, |r| r.residual_max_rad as f64);
    Ok((first, run))
}

/// The raw sensor's angle error against the simulated rotor (mechanical, within one
/// sensor period), pk-pk over Run.
fn raw_error_pkpk(emu: &Emu, from_s: f64) -> f64 {
    let p = &emu.m().board.plant.sensor.params;
    let n = p.model.sensor_periods as f64;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for t in emu.m().board.truth_log.iter().filter(|t| t.t_s >= from_s) {
        let magnet = if p.mount.reversed {
            p.mount.offset_rad - t.theta_rad
        } else {
            p.mount.offset_rad + t.theta_rad
        };
        let e = drive::align::wrap_pi(
            (t.y as f64).atan2(t.x as f64) as f32
                - (n * magnet).rem_euclid(std::f64::consts::TAU) as f32,
        ) as f64
            / n;
        lo = lo.min(e);
        hi = hi.max(e);
    }
    hi - lo
}

/// docs/performance.md's per-scenario table and details.
pub fn report(outcomes: &[Outcome], elf_note: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| scenario | boots | missed periods | control periods | ISR instructions mean / max | ISR est. cycles mean / max | longest masked stretch (instructions) | longest request→entry (instructions) | emulated |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    for o in outcomes {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.0} / {} | {:.0} / {} | {} | {} | {:.2} s |",
            o.name,
            o.boots,
            o.missed_periods,
            o.control_periods,
            o.isr_instrs_mean,
            o.isr_instrs_max,
            o.isr_cycles_mean,
            o.isr_cycles_max,
            o.masked_max_instrs,
            o.latency_max_instrs,
            o.emulated_s
        );
    }
    let _ = writeln!(s);
    for o in outcomes {
        let _ = writeln!(s, "### {}\n", o.name);
        for l in o.state_lines() {
            let _ = writeln!(s, "- {l}");
        }
        for e in o.events.iter().filter(|e| {
            e.kind == "mras-fault"
                || e.kind.contains("failed")
                || e.kind == "mras-not-loaded"
                || e.kind == "mras-loaded"
                || e.kind == "mras-stored"
        }) {
            let _ = writeln!(s, "- boot {}: `{} {}`", e.boot + 1, e.kind, e.text);
        }
        for (k, v) in &o.notes {
            let _ = writeln!(s, "- {k}: {v}");
        }
        if o.violations.is_empty() {
            let _ = writeln!(s, "- rules broken: none");
        }
        for v in &o.violations {
            let _ = writeln!(s, "- rule broken: {v}");
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "{elf_note}");
    s
}

/// The control interrupt measured over Run: the commissioning power-up of an erased
/// board, the measurement window restarted when the stream reports `Run` (the stream is
/// polled every 50 ms of emulated time), then `window_s` in Run.
#[derive(Clone, Debug)]
pub struct Perf {
    /// The PWM rate of the timer, and the one the firmware's banner states.
    pub pwm_hz: f64,
    pub firmware_pwm_hz: Option<u32>,
    pub period_cycles: u64,
    /// The states of the power-up with the firmware's t_ms.
    pub states: Vec<(String, u32)>,
    /// Missed periods over the whole power-up (every trigger that found the previous
    /// sequence unread), those after the control interrupt first ran (control periods
    /// lost), and in the window.
    pub missed_total: u64,
    pub missed_control: u64,
    pub missed_window: u64,
    pub hard_faults: usize,
    pub violations: Vec<String>,
    pub isr_count: u64,
    pub isr_instrs_mean: f64,
    pub isr_instrs_max: u64,
    pub isr_cycles_mean: f64,
    pub isr_cycles_max: u64,
    /// Per stage: (label, instructions mean, max, cycles mean, max).
    pub stages: Vec<(&'static str, f64, u64, f64, u64)>,
    pub masked_max_instrs: u64,
    /// Over the power-up before the window: the longest interrupt-masked stretch
    /// (instructions, ending at ms), the longest interrupt (instructions, cycles).
    pub powerup_masked_max: (u64, f64),
    pub powerup_isr_max: (u64, u64),
    /// When the power-up's longest interrupt ended (ms) and its largest stage (label,
    /// est. cycles).
    pub powerup_isr_max_at: (f64, &'static str, u64),
    /// The adaptation task's longest run before Run and in the window: est. cycles
    /// (preemptions included), control interrupts during it, when it ended (ms).
    pub powerup_task_max: (u64, u64, f64),
    pub task_max: (u64, u64, f64),
    /// The missed periods: (ms, why, pc of the code running then).
    pub missed: Vec<(f64, String, u32)>,
    pub window_s: f64,
    pub wall_s: f64,
    /// Every path bank the stream named, in order (the first is init's).
    pub banks: Vec<Vec<String>>,
}

/// The sensor the emulated board carries: it must be the one the firmware was built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SensorBoard {
    /// The `commissioning` scenario's N = 2 sensor (the default build).
    Kmz41,
    /// An N = 1 sensor with harmonics up to m = 16 ([`Board::commissioning_n1`]; the
    /// `sensor-n1` build, which chooses its bank from the data).
    N1,
}

/// Commission `elf` to Run and measure the control interrupt over `window_s` of Run.
pub fn perf_run(elf: &[u8], window_s: f64, sensor: SensorBoard) -> Result<Perf> {
    let t0 = std::time::Instant::now();
    let (board, to_run_s) = match sensor {
        SensorBoard::Kmz41 => (Board::commissioning(1)?, 4.0),
        // Survey rounds over whole revolutions at N = 1 (docs/theory.md §8).
        SensorBoard::N1 => (Board::commissioning_n1(1)?, 15.0),
    };
    let mut emu = Emu::new(elf, board, None)?;
    run_until_state(&mut emu, "Run", to_run_s)?;
    let missed_before = emu.m().adcs.missed_triggers;
    let st = &emu.m().stats;
    let powerup_masked_max = (st.masked_max, st.masked_max_at as f64 / TICK_HZ * 1e3);
    let powerup_isr_max = (st.isr_instrs_max, st.isr_cycles_max);
    let task_max = |st: &crate::stats::Stats| {
        (
            st.task_cycles_max,
            st.task_periods_max,
            st.task_max_at as f64 / TICK_HZ * 1e3,
        )
    };
    let powerup_task_max = task_max(st);
    let powerup_isr_max_at = {
        let (k, c) = st
            .isr_max_stages
            .iter()
            .enumerate()
            .max_by_key(|(_, s)| s.1)
            .map_or((0, 0), |(k, s)| (k, s.1));
        let label = crate::profile::Stage::ALL
            .iter()
            .find(|s| **s as usize == k)
            .map_or("?", |s| s.label());
        (st.isr_cycles_max_at as f64 / TICK_HZ * 1e3, label, c)
    };
    emu.m_mut().stats.restart_window();
    emu.run_for(window_s)?;
    let out = finish("perf", &emu, t0, Vec::new())?;
    let m = emu.m();
    let st = &m.stats;
    let n = st.isr_count.max(1) as f64;
    let stages = crate::profile::Stage::ALL
        .iter()
        .map(|s| {
            let k = *s as usize;
            (
                s.label(),
                st.stage_sum[k].0 as f64 / n,
                st.stage_max[k].0,
                st.stage_sum[k].1 as f64 / n,
                st.stage_max[k].1,
            )
        })
        .collect();
    let d = stream::decode(&emu.elf, &m.rtt.bytes).context("decoding the RTT stream")?;
    // Every bank the stream named (`mras-paths`): init's, then each rebuild's.
    let banks: Vec<Vec<String>> = d
        .items
        .iter()
        .filter_map(|i| match i {
            Item::Line(l) if l.kind == "mras-paths" => l.paths().ok(),
            _ => None,
        })
        .collect();
    // "drive-fw: 20000 Hz PWM, SYSCLK ..."
    let firmware_pwm_hz = d.items.iter().find_map(|i| match i {
        Item::Other(o) => o
            .strip_prefix("drive-fw: ")?
            .split(" Hz PWM")
            .next()?
            .parse()
            .ok(),
        _ => None,
    });
    Ok(Perf {
        banks,
        pwm_hz: 1.0 / m.board.period_s(),
        firmware_pwm_hz,
        period_cycles: period_cycles(&emu),
        states: out.states.first().cloned().unwrap_or_default(),
        missed_total: m.adcs.missed_triggers,
        missed_control: st.missed.iter().filter(|x| !x.before_control).count() as u64,
        missed_window: m.adcs.missed_triggers - missed_before,
        hard_faults: st.hard_faults.len(),
        violations: out.violations,
        isr_count: st.isr_count,
        isr_instrs_mean: st.isr_mean(),
        isr_instrs_max: st.isr_instrs_max,
        isr_cycles_mean: st.isr_cycles_mean(),
        isr_cycles_max: st.isr_cycles_max,
        stages,
        masked_max_instrs: st.masked_max,
        powerup_masked_max,
        powerup_isr_max,
        powerup_isr_max_at,
        powerup_task_max,
        task_max: task_max(st),
        missed: st
            .missed
            .iter()
            .map(|x| {
                let when = if x.before_control {
                    "before the control interrupt first ran (init), "
                } else {
                    ""
                };
                let why = match (x.in_isr_instrs, x.masked_instrs) {
                    (Some(n), _) => {
                        format!("the control interrupt still running ({n} instructions in)")
                    }
                    (None, Some(n)) => format!("interrupts masked for {n} instructions"),
                    (None, None) => "the interrupt pending behind another".to_string(),
                };
                (x.t as f64 / TICK_HZ * 1e3, format!("{when}{why}"), x.pc)
            })
            .collect(),
        window_s,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

/// docs/performance.md's table of one build: the stages, the whole interrupt and the
/// period's figures.
pub fn perf_table(p: &Perf, title: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "#### {title}: PWM {:.0} kHz, a period of {} cycles\n",
        p.pwm_hz / 1e3,
        p.period_cycles
    );
    let _ = writeln!(
        s,
        "| stage | instructions mean | instructions max | est. cycles mean | est. cycles max |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|");
    for (label, im, ix, cm, cx) in &p.stages {
        let _ = writeln!(s, "| {label} | {im:.0} | {ix} | {cm:.0} | {cx} |");
    }
    let _ = writeln!(
        s,
        "| **whole interrupt** | **{:.0}** | **{}** | **{:.0}** | **{}** |\n",
        p.isr_instrs_mean, p.isr_instrs_max, p.isr_cycles_mean, p.isr_cycles_max
    );
    let share = |c: f64| 100.0 * c / p.period_cycles.max(1) as f64;
    let states: Vec<String> = p
        .states
        .iter()
        .map(|(n, t)| format!("{n} {t} ms"))
        .collect();
    let _ = writeln!(
        s,
        "- whole interrupt: {:.0} cycles mean ({:.1} % of the period), {} max ({:.1} %), over {} interrupts in {:.1} s of Run",
        p.isr_cycles_mean,
        share(p.isr_cycles_mean),
        p.isr_cycles_max,
        share(p.isr_cycles_max as f64),
        p.isr_count,
        p.window_s
    );
    let _ = writeln!(
        s,
        "- longest interrupt-masked stretch in Run: {} instructions",
        p.masked_max_instrs
    );
    let _ = writeln!(
        s,
        "- missed control periods: {} after the control interrupt started, {} in the window (trigger overruns over the whole power-up, init included: {}); HardFaults: {}; rules broken: {}",
        p.missed_control,
        p.missed_window,
        p.missed_total,
        p.hard_faults,
        if p.violations.is_empty() { "none".to_string() } else { p.violations.join("; ") }
    );
    let _ = writeln!(
        s,
        "- before Run: longest interrupt-masked stretch {} instructions (ending at {:.1} ms), longest interrupt {} instructions / {} est. cycles ({:.1} % of the period; ending at {:.1} ms, {} of them in {})",
        p.powerup_masked_max.0,
        p.powerup_masked_max.1,
        p.powerup_isr_max.0,
        p.powerup_isr_max.1,
        100.0 * p.powerup_isr_max.1 as f64 / p.period_cycles.max(1) as f64,
        p.powerup_isr_max_at.0,
        p.powerup_isr_max_at.2,
        p.powerup_isr_max_at.1
    );
    let _ = writeln!(
        s,
        "- adaptation task (its updates are due {} periods after their sample): longest run {} est. cycles before Run (ending at {:.1} ms), {} in Run, control interrupts included; during it at most {} control periods before Run, {} in Run",
        mras::UPDATE_LATENCY_PERIODS,
        p.powerup_task_max.0,
        p.powerup_task_max.2,
        p.task_max.0,
        p.powerup_task_max.1,
        p.task_max.1
    );
    for (ms, why, _) in &p.missed {
        let _ = writeln!(s, "- trigger overrun at {ms:.1} ms: {why}");
    }
    let _ = writeln!(s, "- power-up: {}", states.join(" → "));
    if p.banks.len() > 1 {
        let _ = writeln!(
            s,
            "- path banks streamed: {} (the last in force in Run)",
            p.banks
                .iter()
                .map(|b| format!("`{}`", b.join(", ")))
                .collect::<Vec<_>>()
                .join(" → ")
        );
    }
    s
}

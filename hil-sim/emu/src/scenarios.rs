//! The firmware-in-the-loop scenarios: the release ELF on the emulated board, each
//! ending in what a bench engineer would check (the streamed states and faults, MOE,
//! the reset cause) and what the emulator measured (missed control periods, the control
//! interrupt's executed instructions and estimated cycles, the adaptation task against
//! its deadline, the longest interrupt-masked stretch, and in Run the plant's own
//! measures of the drive).

use crate::board::Board;
use crate::budget::{self, Build, Measured};
use crate::machine::Machine;
use crate::periph::tim1::Tim1;
use crate::periph::{ticks, TICK_HZ};
use crate::stats::Missed;
use crate::Emu;
use anyhow::{bail, Context, Result};
use hil_sim::plant_truth::{self, CurrentVector, CurrentVectorStats, EstimateScore, PeriodTruth};
use hil_sim::scenario::Probe;
use hil_sim::stream::{self, Item, Losses};
use std::fmt::Write as _;

/// Every scenario, in the order of docs/performance.md.
pub const ALL: &[&str] = &[
    "power-up",
    "wire-break",
    "overcurrent",
    "watchdog",
    "store-flash-error",
    "torn-store",
    "rtt-host-stops",
    "attach-halt",
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
    /// Missed control periods after the control interrupt first ran (each boot), and
    /// triggers init overran before it; every one with its cause, time and code.
    pub missed_periods: u64,
    pub overruns_before_control: u64,
    pub missed: Vec<Missed>,
    pub control_periods: u64,
    pub isr_instrs_mean: f64,
    pub isr_instrs_max: u64,
    /// The same interrupts' estimated Cortex-M4 cycles (`profile`).
    pub isr_cycles_mean: f64,
    pub isr_cycles_max: u64,
    /// The PWM (control) period the firmware programmed, in CPU cycles, and its rate.
    pub period_cycles: u64,
    pub pwm_hz: f64,
    /// The longest control interrupt of the whole run (est. cycles) and when it
    /// returned (ms of emulated time).
    pub isr_longest_cycles: u64,
    pub isr_longest_at_ms: f64,
    /// The adaptation task: the most control interrupts entered between a sample and
    /// the return of the run that served it, and the runs past their deadline.
    pub task_interrupts_max: u64,
    pub task_deadline_misses: u64,
    /// The longest interrupt-masked stretch of the whole run.
    pub masked_max_instrs: u64,
    pub latency_max_instrs: u64,
    pub boots: usize,
    pub hard_faults: usize,
    /// NMIs taken (double ECC errors of flash reads).
    pub nmis: u64,
    /// Scenario-specific figures, printed as `key = value`.
    pub notes: Vec<(String, String)>,
    /// Rules the firmware broke (the models' counters), empty when none.
    pub violations: Vec<String>,
    /// What the stream says was lost: the drive's own counters (samples, updates,
    /// events) and the frames missing from `seq`, summed over the boots.
    pub losses: Losses,
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

    /// The budgets of `budget.rs` this run is checked against (no Run window: the
    /// Run-only budget is `perf`'s).
    pub fn budget_measures(&self, sensor: SensorBoard) -> Measured {
        Measured {
            build: Build {
                pwm_hz: self.pwm_hz.round() as u32,
                sensor,
            },
            hard_faults: self.hard_faults,
            rules_broken: self.violations.len(),
            missed_periods: self.missed_periods as usize,
            run_isr_cycles_max: None,
            power_up_isr_cycles_max: None,
            task_run_cycles_max: None,
            isr_longest_cycles: self.isr_longest_cycles,
            period_cycles: self.period_cycles,
            masked_max_instrs: self.masked_max_instrs,
            task_interrupts_max: self.task_interrupts_max,
        }
    }

    /// Several power-ups as one outcome: states, events and missed periods per boot in
    /// order, counts added, maxima kept.
    fn merged(parts: &[Outcome]) -> Outcome {
        let mut out = parts.last().cloned().unwrap_or_default();
        let total: u64 = parts.iter().map(|o| o.control_periods).sum();
        let mean = |f: fn(&Outcome) -> f64| {
            parts
                .iter()
                .map(|o| f(o) * o.control_periods as f64)
                .sum::<f64>()
                / total.max(1) as f64
        };
        out.isr_instrs_mean = mean(|o| o.isr_instrs_mean);
        out.isr_cycles_mean = mean(|o| o.isr_cycles_mean);
        out.states.clear();
        out.events.clear();
        out.missed.clear();
        out.violations.clear();
        for o in parts {
            let b0 = out.states.len();
            out.events.extend(o.events.iter().map(|e| Event {
                boot: e.boot + b0,
                ..e.clone()
            }));
            out.states.extend(o.states.iter().cloned());
            out.missed.extend(o.missed.iter().copied());
            out.violations.extend(o.violations.iter().cloned());
        }
        out.control_periods = total;
        out.missed_periods = parts.iter().map(|o| o.missed_periods).sum();
        out.overruns_before_control = parts.iter().map(|o| o.overruns_before_control).sum();
        out.isr_instrs_max = parts.iter().map(|o| o.isr_instrs_max).max().unwrap_or(0);
        out.isr_cycles_max = parts.iter().map(|o| o.isr_cycles_max).max().unwrap_or(0);
        if let Some(l) = parts.iter().max_by_key(|o| o.isr_longest_cycles) {
            (out.isr_longest_cycles, out.isr_longest_at_ms) =
                (l.isr_longest_cycles, l.isr_longest_at_ms);
        }
        out.task_interrupts_max = parts
            .iter()
            .map(|o| o.task_interrupts_max)
            .max()
            .unwrap_or(0);
        out.task_deadline_misses = parts.iter().map(|o| o.task_deadline_misses).sum();
        out.masked_max_instrs = parts.iter().map(|o| o.masked_max_instrs).max().unwrap_or(0);
        out.latency_max_instrs = parts
            .iter()
            .map(|o| o.latency_max_instrs)
            .max()
            .unwrap_or(0);
        out.boots = parts.iter().map(|o| o.boots).sum();
        out.hard_faults = parts.iter().map(|o| o.hard_faults).sum();
        out.nmis = parts.iter().map(|o| o.nmis).sum();
        out.losses = parts
            .iter()
            .fold(Losses::default(), |a, o| a.plus(&o.losses));
        out.emulated_s = parts.iter().map(|o| o.emulated_s).sum();
        out
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
    read_stream_of(&emu.elf, &emu.m().rtt.bytes, out)
}

/// [`read_stream`] of `bytes` written by the firmware `elf` (a capture, or the part of
/// the board's stream a newly flashed firmware wrote).
pub fn read_stream_of(elf: &[u8], bytes: &[u8], out: &mut Outcome) -> Result<()> {
    let d = stream::decode(elf, bytes).context("decoding the RTT stream")?;
    out.losses = d.losses();
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
    violations_of(emu.m())
}

/// Every counter of the models that means the firmware did something the hardware
/// would not accept, or that the emulator does not model, as a sentence.
pub fn violations_of(m: &Machine) -> Vec<String> {
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
    let f = &m.flash_ctl;
    if f.stale_flag_refusals > 0 {
        v.push(format!(
            "FLASH: {} operations refused with PGSERR, error flags of an earlier one still set (§3.3.7)",
            f.stale_flag_refusals
        ));
    }
    for (n, what) in [
        (
            f.errors.progerr,
            "double words programmed over data not erased (PROGERR, §3.3.8)",
        ),
        (
            f.errors.pgaerr,
            "programming writes misaligned or out of double-word order (PGAERR, §3.3.8)",
        ),
        (
            f.errors.sizerr,
            "programming writes narrower than a word (SIZERR, §3.3.8)",
        ),
        (
            f.errors.pgserr,
            "flash writes without PG, while locked, or with PG and PER both set (PGSERR, §3.7.5)",
        ),
    ] {
        if n > 0 {
            v.push(format!("FLASH: {n} {what}"));
        }
    }
    if f.while_busy > 0 {
        v.push(format!(
            "FLASH: {} operations started while BSY (§3.3.7, §3.3.8: wait for BSY first); dropped here, what silicon does with them is not modelled",
            f.while_busy
        ));
    }
    if f.code_bank_erases > 0 {
        v.push(format!(
            "FLASH: {} page erases in the bank the code runs from: CPU stalled {} ms each (§3.3.8)",
            f.code_bank_erases,
            crate::periph::flash::ERASE_S * 1e3
        ));
    }
    if m.unmodelled.bank_swap > 0 {
        v.push("SYSCFG: flash bank swap (MEMRMP.FB_MODE = 1, §10.2.1) set: not modelled, the code still runs from the image at 0x0800_0000".into());
    }
    if m.cordic.unsupported > 0 {
        v.push(format!(
            "CORDIC: {} arguments for a function the model does not compute (cosine and sine only, §17.3)",
            m.cordic.unsupported
        ));
    }
    if m.iwdg.protected_writes > 0 {
        v.push(format!(
            "IWDG: {} writes to PR/RLR without the 0x5555 key, ignored (§42.3.5)",
            m.iwdg.protected_writes
        ));
    }
    let peaks = m.tim1.peaks.max(1);
    if m.tim1.updates > peaks + 2 {
        v.push(format!(
            "TIM1: {} update events in {} PWM periods: CCRs load twice per period, at peak and valley (RCR = 0, §28.3.3)",
            m.tim1.updates, peaks
        ));
    }
    for (n, what) in [
        (
            a.late_results_read,
            "wrong results of a conversion more than 1 ms after the last conversion or calibration read (ES0430 ADC erratum: do a dummy conversion first and drop it)",
        ),
        (
            a.jexten_not_rising,
            "TIM1 TRGO2 edges with JEXTEN other than 01, rising (§21.4.18 table 162)",
        ),
        (
            a.common_write_refused,
            "ADC_CCR CKMODE/DUAL writes with an ADC enabled, refused (§21.7.2)",
        ),
        (
            a.dual_mismatch,
            "dual injected-simultaneous triggers with sequences of different lengths or a pair of different sampling times (§21.4.31)",
        ),
    ] {
        if n > 0 {
            v.push(format!("ADC: {n} {what}"));
        }
    }
    if m.tim1.bkin_floating > 0 {
        v.push(format!(
            "TIM1: BKIN floating ({}×): the comparator's open-drain line routed with the break enabled and no pull-up (board_map::over_current::BOARD_PULL_UP, GPIOx_PUPDR), read low: break",
            m.tim1.bkin_floating
        ));
    }
    if m.stats.glitch_breaks > 0 {
        v.push(format!(
            "TIM1: {} breaks latched by comparator glitches at switching edges (BDTR.BKF shorter than {} ns, §28.6.20)",
            m.stats.glitch_breaks,
            crate::machine::GLITCH_S * 1e9
        ));
    }
    if m.tim1.gate_polarity_wrong > 0 {
        v.push(format!(
            "TIM1: a complementary output enabled with a polarity or idle level the gate driver does not take ({}×, CCER.CCxNP §28.6.11, CR2.OISxN §28.6.2; board_map::gate_driver): its low side does not follow the PWM, or stays on with MOE = 0",
            m.tim1.gate_polarity_wrong
        ));
    }
    if m.tim1.breaks_unrouted > 0 {
        v.push(format!(
            "TIM1: over-current on BKIN not routed to the break (AF1.BKINE = 0, §28.6.27): {} comparator trips ignored",
            m.tim1.breaks_unrouted
        ));
    }
    if m.tim1.moe_refused > 0 {
        v.push(format!(
            "TIM1: MOE written 1 while the break input was active, refused {} times (§28.3.21): the firmware tried to re-arm the bridge during an over-current",
            m.tim1.moe_refused
        ));
    }
    if m.tim1.aoe_writes > 0 {
        v.push(format!(
            "TIM1: BDTR written with AOE = 1 ({}×): MOE set again by the update event after a break is not modelled (§28.3.21)",
            m.tim1.aoe_writes
        ));
    }
    let addrs = |map: &std::collections::BTreeMap<u32, u64>| {
        map.keys()
            .map(|a| format!("{a:#010x}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if !m.unmodelled.unknown.is_empty() {
        v.push(format!(
            "bus: accesses to registers no model knows: {}",
            addrs(&m.unmodelled.unknown)
        ));
    }
    if !m.unmodelled.unknown_ppb.is_empty() {
        v.push(format!(
            "private peripheral bus: accesses to registers no model knows (kept as plain memory): {}",
            addrs(&m.unmodelled.unknown_ppb)
        ));
    }
    v
}

pub(crate) fn finish(
    name: &str,
    emu: &Emu,
    t0: std::time::Instant,
    notes: Vec<(String, String)>,
) -> Result<Outcome> {
    let m = emu.m();
    let st = &m.stats;
    let mut out = Outcome {
        name: name.into(),
        missed_periods: st.missed_control() as u64,
        overruns_before_control: st.missed.iter().filter(|x| x.before_control).count() as u64,
        missed: st.missed.clone(),
        control_periods: st.isr_count_total,
        isr_instrs_mean: st.isr_mean(),
        isr_instrs_max: st.isr_instrs_max,
        isr_cycles_mean: st.isr_cycles_mean(),
        isr_cycles_max: st.isr_cycles_max,
        period_cycles: period_cycles(emu),
        pwm_hz: 1.0 / m.board.period_s(),
        isr_longest_cycles: st.isr_longest.cycles,
        isr_longest_at_ms: st.isr_longest.at as f64 / TICK_HZ * 1e3,
        task_interrupts_max: st.task_from_pend_max,
        task_deadline_misses: st.task_deadline_misses,
        masked_max_instrs: st.masked_max_run,
        latency_max_instrs: st.latency_max,
        boots: st.boots.len(),
        hard_faults: st.hard_faults.len(),
        nmis: st.nmis,
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
        if emu.m().powered_off {
            bail!(
                "{what}: the board's power was cut at {:.1} ms",
                emu.m().time_s() * 1e3
            );
        }
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
         boots: {}, HardFaults: {:?}, pc now {:#010x}, control interrupts: {}\n  \
         missed control periods: {}{}\n  lost (stream): {}\n  rules broken:\n    {}",
        o.state_lines().join("; "),
        o.events.iter().filter(|e| e.kind == "log" || e.kind == "mras-fault").map(|e| e.text.clone()).collect::<Vec<_>>().join(" | "),
        m.stats.boots.len(),
        m.stats.hard_faults,
        emu.pc(),
        m.stats.isr_count_total,
        m.stats.missed_control(),
        missed_lines(&m.stats.missed, 3)
            .iter()
            .map(|l| format!("\n    {l}"))
            .collect::<String>(),
        o.losses.describe(),
        violations(emu).join("\n    ")
    )
}

/// Run until the stream shows `state` entered in the current boot.
pub(crate) fn run_until_state(emu: &mut Emu, state: &str, limit_s: f64) -> Result<f64> {
    run_until(emu, &format!("state `{state}`"), limit_s, |o, b| {
        o.entered(b, state).is_some()
    })
}

/// One power-up on an erased flash with the plant's motor changed by `adjust` (the
/// firmware keeps its nominal constants and identifies the plant's): to Run, then
/// 0.2 s in it. Also the plant's motor, to measure the identification against.
pub fn motor_run(
    elf: &[u8],
    adjust: impl FnOnce(&mut hil_sim::plant::MotorParams),
) -> Result<(Outcome, hil_sim::plant::MotorParams)> {
    let t0 = std::time::Instant::now();
    let board = Board::commissioning_with_motor(1, adjust)?;
    let motor = board.plant.motor.clone();
    let mut emu = Emu::new(elf, board, None)?;
    // Another pole-pair count than the firmware's is aligned and swept twice.
    run_until_state(&mut emu, "Run", 6.5)?;
    emu.run_for(0.2)?;
    Ok((finish("motor", &emu, t0, Vec::new())?, motor))
}

/// A board with an erased calibration area, powered on.
fn fresh(elf: &[u8], flash: Option<crate::cpu::KeptFlash>) -> Result<Emu> {
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
            for (b, c) in p.run_current.iter().enumerate() {
                if let Some(c) = c {
                    p.outcome.notes.push((
                        format!(
                            "boot {}: the current against the rotor's q axis in Run (plant)",
                            b + 1
                        ),
                        describe_current(c),
                    ));
                }
            }
            for (b, e) in p.estimate.iter().enumerate() {
                p.outcome.notes.push((
                    format!(
                        "boot {}: the streamed θ̂ against the rotor in Run (plant)",
                        b + 1
                    ),
                    describe_estimate(e),
                ));
            }
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
            // The comparator's threshold below the running current: it trips within the
            // next period, the break path clears MOE in hardware.
            let normal_a = emu.m().board.plant.break_level_a;
            emu.m_mut().board.plant.break_level_a = 0.05;
            let (t_trip, sets_before) = (emu.m().now, emu.m().tim1.moe_sets);
            while emu.m().stats.breaks.is_empty() && emu.m().now < t_trip + ticks(0.01) {
                emu.run_for(1.0e-6)?;
            }
            let b = *emu
                .m()
                .stats
                .breaks
                .first()
                .context("over-current: no break within 10 ms of the comparator's trip")?;
            note(
                "comparator crossing → MOE cleared (break filter)",
                format!(
                    "{:.3} µs",
                    (b.moe_cleared - b.crossing) as f64 / TICK_HZ * 1e6
                ),
            );
            // The open bridge lets the current fall back under the level; later the
            // fault is gone altogether (the level back to normal). The supervisor holds
            // the safe state: nothing may set MOE again.
            emu.run_for(0.05)?;
            note(
                "comparator still over its level 50 ms after the trip",
                emu.m().board.plant.comparator_over().to_string(),
            );
            emu.m_mut().board.plant.break_level_a = normal_a;
            emu.run_for(0.25)?;
            note(
                "MOE set again after the trip",
                (emu.m().tim1.moe_sets - sets_before).to_string(),
            );
            note("MOE at the end", Tim1::moe(&emu.m().regs).to_string());
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
            // The stall's missed periods (the interrupt never returns for long), and
            // those after the reset.
            let reset = emu.m().stats.boots.last().map_or(0, |b| b.0);
            let during = emu.m().stats.missed.iter().filter(|x| x.t < reset).count();
            note("missed periods during the stall", during.to_string());
            emu.run_for(0.3)?;
            let after = emu.m().stats.missed.iter().filter(|x| x.t >= reset).count();
            note("missed periods after the reset", after.to_string());
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
        "torn-store" => {
            let o = torn_store(elf, t0)?;
            return Ok(o);
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
        "attach-halt" => {
            let mut emu = fresh(elf, None)?;
            run_until_state(&mut emu, "Run", 4.0)?;
            emu.run_for(0.3)?;
            for hold_s in ATTACH_HOLDS_S {
                let h = attach_halt(&mut emu, hold_s)?;
                let ms = hold_s * 1e3;
                note(
                    &format!("{ms:.0} ms halt: bridge on while halted"),
                    format!("{} of {} samples", h.bridge_on_samples, h.samples),
                );
                note(
                    &format!("{ms:.0} ms halt: the probe read PC, RTT header"),
                    format!("{:#010x}, {}", h.pc, h.rtt_id),
                );
                note(
                    &format!("{ms:.0} ms halt: rotor speed at the halt → at the resume"),
                    format!(
                        "{:.1} → {:.1} rad/s",
                        h.speed_at_halt_rad_s, h.speed_at_resume_rad_s
                    ),
                );
                for (when, c) in [("before", &h.before), ("after", &h.after)] {
                    note(
                        &format!("{ms:.0} ms halt: the current against the rotor's q axis {when} (plant)"),
                        c.as_ref().map_or("no periods".into(), describe_current),
                    );
                }
                let after = h
                    .after
                    .as_ref()
                    .context("no control period after the resume")?;
                note(
                    &format!("{ms:.0} ms halt: torque per amp after"),
                    format!("{:.4}", after.torque_per_amp),
                );
            }
            emu
        }
        other => bail!("unknown scenario `{other}` (known: {})", ALL.join(", ")),
    };
    finish(name, &emu, t0, notes)
}

/// How long the `attach-halt` scenario holds the core halted, in turn: a probe's
/// session (halt, read, resume: about a millisecond) and a slow one.
pub const ATTACH_HOLDS_S: [f64; 2] = [1.0e-3, 100.0e-3];

/// What a probe's attach did to a drive in Run.
pub struct AttachHalt {
    /// The bridge sampled every 100 µs while the core was halted.
    pub samples: u32,
    pub bridge_on_samples: u32,
    /// What the probe read while halted: the PC (DCRSR/DCRDR) and the RTT control
    /// block's id.
    pub pc: u32,
    pub rtt_id: String,
    pub speed_at_halt_rad_s: f64,
    pub speed_at_resume_rad_s: f64,
    /// The current vector against the rotor over 250 ms before the halt and over 250
    /// ms from 50 ms after the resume (plant).
    pub before: Option<CurrentVectorStats>,
    pub after: Option<CurrentVectorStats>,
}

/// A probe attaches to the running drive as probe-rs does (the debug port's own
/// registers: DHCSR halt, DCRSR/DCRDR, a memory read), holds the core halted for
/// `hold_s`, resumes and detaches; the drive runs on for 300 ms.
pub fn attach_halt(emu: &mut Emu, hold_s: f64) -> Result<AttachHalt> {
    use crate::debug::*;
    let ap = |f: ApFault| anyhow::anyhow!("{f}");
    let window = |emu: &mut Emu, s: f64| -> Result<Option<CurrentVectorStats>> {
        let from = period_truth(emu, 0).len();
        emu.run_for(s)?;
        Ok(current_over(emu, &period_truth(emu, 0)[from..]))
    };
    let before = window(emu, 0.25)?;
    let speed_at_halt_rad_s = emu.m().board.plant.omega_rad_s();
    let w = |emu: &mut Emu, a: u32, v: u32| emu.write(a, 4, &v.to_le_bytes()).map_err(ap);
    let r = |emu: &mut Emu, a: u32| -> Result<u32> {
        let mut b = [0; 4];
        emu.read(a, 4, &mut b).map_err(ap)?;
        Ok(u32::from_le_bytes(b))
    };
    w(emu, DHCSR, DBGKEY << 16 | C_DEBUGEN | C_HALT)?;
    if r(emu, DHCSR)? & S_HALT == 0 {
        bail!("attach: the core did not halt");
    }
    w(emu, DCRSR, 15)?;
    let pc = r(emu, DCRDR)?;
    let rtt_id = match emu.m().rtt.block {
        Some(a) => {
            let mut id = [0; 16];
            emu.read(a, 4, &mut id).map_err(ap)?;
            String::from_utf8_lossy(&id)
                .trim_end_matches('\0')
                .to_string()
        }
        None => "no RTT block".into(),
    };
    let (t_halt, step) = (emu.m().now, ticks(100e-6));
    let (mut samples, mut bridge_on_samples) = (0, 0);
    while emu.m().now < t_halt + ticks(hold_s) {
        emu.advance(step.min(t_halt + ticks(hold_s) - emu.m().now))?;
        if !emu.m().halted() {
            bail!("attach: the core left the halt by itself");
        }
        samples += 1;
        bridge_on_samples += emu.m().bridge_on() as u32;
    }
    let speed_at_resume_rad_s = emu.m().board.plant.omega_rad_s();
    w(emu, DHCSR, DBGKEY << 16 | C_DEBUGEN)?;
    w(emu, DHCSR, DBGKEY << 16)?;
    emu.run_for(0.05)?;
    let after = window(emu, 0.25)?;
    Ok(AttachHalt {
        samples,
        bridge_on_samples,
        pc,
        rtt_id,
        speed_at_halt_rad_s,
        speed_at_resume_rad_s,
        before,
        after,
    })
}

/// The double word of the calibration record whose programming the power cut
/// interrupts (the record is 28 double words: this one is in its middle, before the
/// commit).
pub const TORN_DOUBLE_WORD: u32 = 14;

/// A power cut while the first store programs the record: the next power-up reads a
/// torn double word (FLASH_ECCR.ECCD, NMI), must neither fault nor load it, and
/// commissions again; the one after loads the new record.
fn torn_store(elf: &[u8], t0: std::time::Instant) -> Result<Outcome> {
    let mut emu = fresh(elf, None)?;
    emu.m_mut().power_cut_at_program = Some(TORN_DOUBLE_WORD);
    emu.run_until(4.0)?;
    let torn = emu.m().flash_ctl.torn.clone();
    if !emu.m().powered_off || torn.is_empty() {
        bail!(
            "torn-store: the store did not program {TORN_DOUBLE_WORD} double words within 4 s ({} programmed)",
            emu.m().flash_ctl.programs
        );
    }
    let cut = finish("torn-store", &emu, t0, Vec::new())?;
    let mut again = fresh(elf, Some(emu.flash()))?;
    run_until_state(&mut again, "Run", 6.0)?;
    again.run_for(0.2)?;
    let m = again.m();
    let notes = vec![
        (
            "power cut while programming".into(),
            format!(
                "double word {TORN_DOUBLE_WORD} of the record, at {:#010x}, {:.1} ms after power-on",
                crate::elf::FLASH_BASE + torn[0],
                emu.m().time_s() * 1e3
            ),
        ),
        (
            "boot 2: double ECC errors read (FLASH_ECCR.ECCD), NMIs taken".into(),
            format!("{}, {}", m.flash_ctl.ecc_double_errors, m.stats.nmis),
        ),
        (
            "boot 2: torn double words left after its store".into(),
            m.flash_ctl.torn.len().to_string(),
        ),
    ];
    let second = finish("torn-store", &again, t0, notes)?;
    let mut third = fresh(elf, Some(again.flash()))?;
    run_until_state(&mut third, "Run", 2.0)?;
    third.run_for(0.1)?;
    let last = finish("torn-store", &third, t0, Vec::new())?;
    let mut out = Outcome::merged(&[cut, second.clone(), last]);
    out.notes = second.notes;
    out.wall_s = t0.elapsed().as_secs_f64();
    Ok(out)
}

/// The current the bridge drove against the rotor's q axis, measured at the plant.
pub fn describe_current(c: &CurrentVectorStats) -> String {
    format!(
        "mean angle error {:+.1} mrad electrical, pk-pk over the rotor angle {:.1} mrad, torque per amp {:.4} (at {:.2} A mean)",
        c.angle_error_e_rad * 1e3,
        c.angle_error_e_pk_pk_rad * 1e3,
        c.torque_per_amp,
        c.mean_current_a
    )
}

/// The streamed θ̂ against the rotor, beside the raw sensor's error at the same periods.
pub fn describe_estimate(e: &EstimateScore) -> String {
    format!(
        "spatial error {:.1} mrad pk-pk raw → {:.3} mrad pk-pk θ̂ ({:.0}x; harmonics 1..{} of the rotor angle fitted to {} records, {:.3} mrad RMS left by the fit)",
        e.raw_pk_pk_rad * 1e3,
        e.estimate_pk_pk_rad * 1e3,
        e.raw_pk_pk_rad / e.estimate_pk_pk_rad,
        e.harmonics,
        e.records,
        e.estimate_residual_rms_rad * 1e3
    )
}

/// The main job's power-up: both boots with their streams and the errors.
pub struct PowerUp {
    pub outcome: Outcome,
    /// The raw defmt capture of each boot.
    pub captures: Vec<Vec<u8>>,
    pub raw_error_pkpk_rad: f64,
    pub residual_first_rad: f64,
    pub residual_run_rad: f64,
    /// Per boot, over Run (from [`RUN_SETTLE_S`] after entering it to the end): the
    /// current the bridge drove against the true rotor's q axis, from the plant.
    pub run_current: [Option<CurrentVectorStats>; 2],
    /// Per boot, over the same window: the θ̂ the records streamed against the rotor
    /// at their control periods, beside the raw sensor's error at the same periods.
    pub estimate: [EstimateScore; 2],
    /// The flash the first boot left (its calibration stored).
    pub commissioned: crate::cpu::KeptFlash,
}

/// A power-up on `flash` (a stored calibration) of a board whose sensor has been
/// remounted `offset_shift_rad` (mechanical) since: the calibration's electrical offset
/// is then wrong by `offset_shift_rad`·p. Its states, and the current against the rotor's
/// q axis over Run (plant).
pub fn remounted_power_up(
    elf: &[u8],
    flash: crate::cpu::KeptFlash,
    offset_shift_rad: f64,
) -> Result<(Outcome, Option<CurrentVectorStats>)> {
    let t0 = std::time::Instant::now();
    let mut board = Board::commissioning(1)?;
    let mut p = board.plant.sensor.params.clone();
    p.mount.offset_rad += offset_shift_rad;
    board.plant.sensor = hil_sim::sensor::SensorSim::new(p, 1)?;
    let mut emu = Emu::new(elf, board, Some(flash))?;
    run_until_state(&mut emu, "Run", 2.0)?;
    emu.run_for(0.3)?;
    let o = finish("remounted", &emu, t0, Vec::new())?;
    let c = run_current(&emu, &o, 0);
    Ok((o, c))
}

/// How long each power-up runs once the stream says Run: enough records (one every
/// `drive::supervisor::RECORD_DIVIDER` ms) after [`RUN_SETTLE_S`] to fit the θ̂ score's
/// 16 harmonics of the rotor angle twice over.
pub const RUN_WINDOW_S: f64 = 1.2;

/// Run measures start this long after the stream says Run (the speed ramp to the
/// application speed of a loaded boot included, the hand-over from commissioning not).
pub const RUN_SETTLE_S: f64 = 0.1;

/// The plant per control period of boot `boot` (0 = power-on) of `emu`: the entry
/// for the firmware's `ticks` = k is at k - 1.
pub fn period_truth(emu: &Emu, boot: usize) -> &[PeriodTruth] {
    emu.m().period_truth.get(boot).map_or(&[], |v| v.as_slice())
}

/// The sensor on the board, as the plant-side measures need it.
pub fn probe(emu: &Emu) -> Probe {
    Probe::of(&emu.m().board.plant.sensor.params)
}

/// Streamed estimates of boot `boot`, `(t_ms, θ̂)` with θ̂ mechanical in the motor
/// frame, against the rotor at their control periods: raw-vs-corrected spatial error
/// pk-pk (harmonics 1..=16 of the rotor angle, see [`plant_truth::score_estimates`]).
pub fn score_estimates(emu: &Emu, boot: usize, records: &[(u32, f32)]) -> Result<EstimateScore> {
    let pwm_hz = 1.0 / emu.m().board.period_s();
    Ok(plant_truth::score_estimates(
        period_truth(emu, boot),
        pwm_hz,
        &probe(emu),
        records,
        hil_sim::scenario::SPECTRUM_HARMONICS_OF_THETA_RM,
    )?)
}

/// The periods of boot `boot` from `RUN_SETTLE_S` after the stream's Run to the end.
fn run_periods<'a>(emu: &'a Emu, o: &Outcome, boot: usize) -> &'a [PeriodTruth] {
    let log = period_truth(emu, boot);
    let Some(run_ms) = o.entered(boot, "Run") else {
        return &[];
    };
    let from = ((run_ms as f64 / 1e3 + RUN_SETTLE_S) / emu.m().board.period_s()).round() as usize;
    log.get(from..).unwrap_or(&[])
}

/// The `(t_ms, θ̂)` of boot `boot`'s records from [`RUN_SETTLE_S`] after the stream's
/// Run to the end.
fn run_records(emu: &Emu, o: &Outcome, boot: usize) -> Result<Vec<(u32, f32)>> {
    let Some(run_ms) = o.entered(boot, "Run") else {
        bail!("boot {}: no Run to score θ̂ in", boot + 1);
    };
    let from_ms = run_ms + (RUN_SETTLE_S * 1e3).round() as u32;
    let d = stream::decode(&emu.elf, &emu.m().rtt.bytes)?;
    Ok(d.items
        .iter()
        .filter_map(|i| match i {
            Item::Line(l) if l.kind == "mras" => l.record().ok(),
            _ => None,
        })
        .filter(|r| r.state == drive::commissioning::State::Run && r.t_ms >= from_ms)
        .map(|r| (r.t_ms, r.theta_rad))
        .collect())
}

/// The streamed θ̂ of boot `boot`'s Run against the rotor (plant).
fn run_estimate(emu: &Emu, o: &Outcome, boot: usize) -> Result<EstimateScore> {
    let records = run_records(emu, o, boot)?;
    score_estimates(emu, boot, &records)
        .with_context(|| format!("scoring the {} streamed θ̂ of Run", records.len()))
}

/// The current vector over a boot's Run (plant).
fn run_current(emu: &Emu, o: &Outcome, boot: usize) -> Option<CurrentVectorStats> {
    current_over(emu, run_periods(emu, o, boot))
}

/// The current vector the bridge drove against the rotor over `periods` (plant).
fn current_over(emu: &Emu, periods: &[PeriodTruth]) -> Option<CurrentVectorStats> {
    let mut cv = CurrentVector::new(&emu.m().board.plant.motor);
    for p in periods {
        cv.add_period(p);
    }
    cv.stats()
}

/// Erased-flash power-up to Run, then a second power-up with the kept flash.
pub fn power_up_run(elf: &[u8]) -> Result<PowerUp> {
    let t0 = std::time::Instant::now();
    let mut emu = fresh(elf, None)?;
    run_until_state(&mut emu, "Run", 4.0)?;
    emu.run_for(RUN_WINDOW_S)?;
    let first = finish("power-up", &emu, t0, Vec::new())?;
    let (first_res, run_res) = residuals(&emu)?;
    let raw = plant_truth::raw_error_pk_pk_rad(run_periods(&emu, &first, 0), &probe(&emu));
    let current_1 = run_current(&emu, &first, 0);
    let estimate_1 = run_estimate(&emu, &first, 0).context("boot 1")?;
    let commissioned = emu.flash();
    let mut again = fresh(elf, Some(commissioned.clone()))?;
    run_until_state(&mut again, "Run", 2.0)?;
    again.run_for(RUN_WINDOW_S)?;
    let second = finish("power-up", &again, t0, Vec::new())?;
    let current_2 = run_current(&again, &second, 0);
    let estimate_2 = run_estimate(&again, &second, 0).context("boot 2")?;
    let outcome = Outcome::merged(&[first, second]);
    Ok(PowerUp {
        outcome,
        captures: vec![emu.m().rtt.bytes.clone(), again.m().rtt.bytes.clone()],
        raw_error_pkpk_rad: raw,
        residual_first_rad: first_res,
        residual_run_rad: run_res,
        run_current: [current_1, current_2],
        estimate: [estimate_1, estimate_2],
        commissioned,
    })
}

/// How hard the bridge is driven over a window of periods (plant): the modulation
/// index |v| / (Vdc/√3) of the applied duties, and the highest duty among each
/// period's two lower ones (the shunts a three-shunt board reads).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Modulation {
    pub periods: u64,
    pub mean: f64,
    pub max: f64,
    pub lower_two_duty_max: f64,
    /// The highest duty of any phase.
    pub duty_max: f64,
}

/// [`Modulation`] of the periods with the bridge on; None if there are none.
pub fn modulation(periods: &[PeriodTruth], vdc_v: f64) -> Option<Modulation> {
    let limit = vdc_v / 3f64.sqrt();
    let mut m = Modulation {
        periods: 0,
        mean: 0.0,
        max: 0.0,
        lower_two_duty_max: 0.0,
        duty_max: 0.0,
    };
    for d in periods.iter().filter_map(|p| p.duties) {
        let [va, vb] = hil_sim::plant::duties_to_ab(&d, vdc_v);
        let k = va.hypot(vb) / limit;
        let mut sorted = d.map(f64::from);
        sorted.sort_by(f64::total_cmp);
        m.periods += 1;
        m.mean += k;
        m.max = m.max.max(k);
        m.lower_two_duty_max = m.lower_two_duty_max.max(sorted[1]);
        m.duty_max = m.duty_max.max(sorted[2]);
    }
    (m.periods > 0).then(|| Modulation {
        mean: m.mean / m.periods as f64,
        ..m
    })
}

/// A commissioning power-up to Run and [`RUN_WINDOW_S`] of Run, measured at the plant:
/// the current against the rotor's q axis and the modulation. Run on the `fast-run`
/// build it drives the bridge near its voltage limit.
pub struct RunAtPlant {
    pub outcome: Outcome,
    pub current: Option<CurrentVectorStats>,
    pub modulation: Option<Modulation>,
    pub speed_rad_s: f64,
}

pub fn run_at_plant(elf: &[u8]) -> Result<RunAtPlant> {
    let t0 = std::time::Instant::now();
    let mut emu = fresh(elf, None)?;
    run_until_state(&mut emu, "Run", 4.0)?;
    emu.run_for(RUN_WINDOW_S)?;
    let outcome = finish("run-at-plant", &emu, t0, Vec::new())?;
    let periods = run_periods(&emu, &outcome, 0);
    let vdc_v = emu.m().board.plant.motor.vdc_v;
    let speed_rad_s = periods.last().map_or(0.0, |p| p.truth.omega_rad_s);
    Ok(RunAtPlant {
        current: run_current(&emu, &outcome, 0),
        modulation: modulation(periods, vdc_v),
        speed_rad_s,
        outcome,
    })
}

/// The name [`modulation_report`]'s piece is saved under ([`pieces`]).
pub const AT_PLANT_PIECE: &str = "run-at-plant";

/// The details' section on Run near the voltage limit: the release build's Run and the
/// `fast-run` build's, at the plant.
pub fn modulation_report(low: &RunAtPlant, high: &RunAtPlant) -> String {
    let mut s = String::from(
        "\n## Run near the voltage limit\n\nThe release build's Run (10 rev/s) and the `fast-run` build's (24 rev/s), each \
         over 1.2 s from 0.1 s after entering Run, measured at the plant: the duties the bridge applied \
         and the current against the rotor's q axis. The board's shunts show a phase current only while \
         that phase's low side conducts; the drive reads the two phases with the lowest duties.\n\n\
         | build | speed | modulation, duties | current against the q axis |\n|---|---|---|---|\n",
    );
    for (name, r) in [("release", low), ("fast-run", high)] {
        let m = r
            .modulation
            .as_ref()
            .map_or("bridge never on".into(), describe_modulation);
        let c = r
            .current
            .as_ref()
            .map_or("no Run window".into(), describe_current);
        let _ = writeln!(
            s,
            "| {name} | {:.1} rev/s | {m} | {c} |",
            r.speed_rad_s / std::f64::consts::TAU
        );
    }
    s
}

/// One line: the modulation of a window.
pub fn describe_modulation(m: &Modulation) -> String {
    format!(
        "modulation {:.1} % mean, {:.1} % max of Vdc/√3; duties up to {:.3}, the lower two up to {:.3}",
        m.mean * 100.0,
        m.max * 100.0,
        m.duty_max,
        m.lower_two_duty_max
    )
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

/// A scenario's table and its details (what `drive-emu scenarios` prints).
pub fn report(outcomes: &[Outcome], elf_note: &str) -> String {
    format!(
        "{}\n{}",
        report_table(outcomes),
        report_details(outcomes, elf_note)
    )
}

/// docs/performance.md's table: a row per scenario.
pub fn report_table(outcomes: &[Outcome]) -> String {
    let rows: Vec<String> = outcomes.iter().map(report_row).collect();
    report_table_of(&rows)
}

/// The table around rows written by [`report_row`].
pub fn report_table_of(rows: &[String]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| scenario | boots | control periods | missed periods | control interrupt, est. cycles mean / max (longest, % of the period) | longest masked stretch, instructions | adaptation task: interrupts from a sample to its return (late) | lost (stream) | rules broken |");
    let _ = writeln!(s, "|---|---:|---:|---:|---|---:|---|---|---:|");
    for r in rows {
        s.push_str(r);
    }
    s
}

/// One scenario's row of [`report_table`].
pub fn report_row(o: &Outcome) -> String {
    format!(
        "| {} | {} | {} | {} | {:.0} / {} ({:.1} %) | {} | {} ({}) | {} | {} |\n",
        o.name,
        o.boots,
        o.control_periods,
        o.missed_periods,
        o.isr_cycles_mean,
        o.isr_cycles_max,
        100.0 * o.isr_longest_cycles as f64 / o.period_cycles.max(1) as f64,
        o.masked_max_instrs,
        o.task_interrupts_max,
        o.task_deadline_misses,
        o.losses.describe(),
        o.violations.len()
    )
}

/// docs/emulator.md's details: per scenario, what the stream and the plant showed.
pub fn report_details(outcomes: &[Outcome], elf_note: &str) -> String {
    let mut s: String = outcomes.iter().map(report_detail).collect();
    let _ = writeln!(s, "{elf_note}");
    s
}

/// One scenario's section of [`report_details`].
pub fn report_detail(o: &Outcome) -> String {
    let mut s = String::new();
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
    for l in missed_lines(&o.missed, 3) {
        let _ = writeln!(s, "- {l}");
    }
    let _ = writeln!(
        s,
        "- lost, as the stream counts it (the drive's drop counters, gaps in `seq`): {}",
        o.losses.describe()
    );
    if o.violations.is_empty() {
        let _ = writeln!(s, "- rules broken: none");
    }
    for v in &o.violations {
        let _ = writeln!(s, "- rule broken: {v}");
    }
    let _ = writeln!(s);
    s
}

/// The report's pieces a run leaves behind for another process to assemble: the
/// emulator's tests run every scenario of the report, and `cargo xtask ci` then builds
/// the report from what they measured instead of emulating them all a second time.
/// Each piece is keyed by its name and the ELFs it ran (a hash of their bytes), so a
/// piece of another build is never taken.
pub mod pieces {
    use anyhow::{Context, Result};
    use std::path::{Path, PathBuf};

    /// The directory the tests write into when set (`cargo xtask ci` sets it).
    pub const ENV: &str = "DRIVE_EMU_PIECES";

    /// FNV-1a over the ELFs' bytes: a key, not a defence against a crafted file.
    pub fn elf_key(elfs: &[&[u8]]) -> String {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for elf in elfs {
            for &b in elf.iter().chain((elf.len() as u64).to_le_bytes().iter()) {
                h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
            }
        }
        format!("{h:016x}")
    }

    fn path(dir: &Path, name: &str, elfs: &[&[u8]], part: &str) -> PathBuf {
        dir.join(format!("{name}.{}.{part}.md", elf_key(elfs)))
    }

    /// Writes `parts` (`(part, text)`) of `name` run on `elfs` into the directory
    /// [`ENV`] names; nothing when it is unset.
    pub fn save(name: &str, elfs: &[&[u8]], parts: &[(&str, &str)]) -> Result<()> {
        let Some(dir) = std::env::var_os(ENV) else {
            return Ok(());
        };
        let dir = PathBuf::from(dir);
        std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
        for (part, text) in parts {
            let p = path(&dir, name, elfs, part);
            std::fs::write(&p, text).with_context(|| p.display().to_string())?;
        }
        Ok(())
    }

    /// The `parts` of `name` run on `elfs` from `dir`, when every one is there.
    pub fn load(dir: &Path, name: &str, elfs: &[&[u8]], parts: &[&str]) -> Option<Vec<String>> {
        parts
            .iter()
            .map(|part| std::fs::read_to_string(path(dir, name, elfs, part)).ok())
            .collect()
    }
}

/// The missed periods, the first `max` in full and the rest counted by cause.
pub fn missed_lines(missed: &[Missed], max: usize) -> Vec<String> {
    let mut out: Vec<String> = missed
        .iter()
        .take(max)
        .map(|x| {
            format!(
                "missed period at {:.2} ms: {}",
                x.t as f64 / TICK_HZ * 1e3,
                why(x)
            )
        })
        .collect();
    if missed.len() > max {
        let mut by: Vec<(&str, usize)> = Vec::new();
        for x in &missed[max..] {
            match by.iter_mut().find(|(c, _)| *c == x.cause.describe()) {
                Some((_, n)) => *n += 1,
                None => by.push((x.cause.describe(), 1)),
            }
        }
        let rest: Vec<String> = by.iter().map(|(c, n)| format!("{n} × {c}")).collect();
        out.push(format!(
            "and {} more missed periods: {}",
            missed.len() - max,
            rest.join(", ")
        ));
    }
    out
}

/// Why a period was missed, in words.
fn why(x: &Missed) -> String {
    let when = if x.before_control {
        "before the control interrupt first ran (init), "
    } else {
        ""
    };
    let held = match (x.in_isr_instrs, x.masked_instrs) {
        (Some(n), _) => format!(", the control interrupt {n} instructions in"),
        (None, Some(n)) => format!(", interrupts masked for {n} instructions"),
        (None, None) => String::new(),
    };
    format!("{when}{}{held}", x.cause.describe())
}

/// The control interrupt measured over Run: the commissioning power-up of an erased
/// board, the measurement window restarted when the stream reports `Run` (the stream is
/// polled every 50 ms of emulated time), then `window_s` in Run.
#[derive(Clone, Debug)]
pub struct Perf {
    pub sensor: SensorBoard,
    /// The PWM rate of the timer, and the one the firmware's banner states.
    pub pwm_hz: f64,
    pub firmware_pwm_hz: Option<u32>,
    pub period_cycles: u64,
    /// The states of the power-up with the firmware's t_ms.
    pub states: Vec<(String, u32)>,
    /// Missed control periods after the control interrupt first ran (power-up and
    /// window), those in the window, and init's overruns before it.
    pub missed_control: u64,
    pub missed_window: u64,
    pub overruns_before_control: u64,
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
    /// The whole run's longest interrupt (est. cycles, ending at ms) and masked stretch.
    pub longest_isr: (u64, f64),
    pub masked_max_run: u64,
    /// The adaptation task's longest run before Run and in the window: est. cycles
    /// (preemptions included), when it ended (ms).
    pub powerup_task_max: (u64, f64),
    pub task_max: (u64, f64),
    /// Over the whole run: the most control interrupts entered from a sample to the
    /// return of the task run that served it (when, ms), and the runs past the deadline.
    pub task_interrupts_max: (u64, f64),
    pub task_deadline_misses: u64,
    /// The missed periods: (ms, why, pc of the code running then).
    pub missed: Vec<(f64, String, u32)>,
    pub window_s: f64,
    pub wall_s: f64,
    /// Every path bank the stream named, in order (the first is init's).
    pub banks: Vec<Vec<String>>,
}

impl Perf {
    /// What the gate checks ([`budget`]).
    pub fn budget_measures(&self) -> Measured {
        Measured {
            build: Build {
                pwm_hz: self.pwm_hz.round() as u32,
                sensor: self.sensor,
            },
            hard_faults: self.hard_faults,
            rules_broken: self.violations.len(),
            missed_periods: self.missed_control as usize,
            run_isr_cycles_max: Some(self.isr_cycles_max),
            power_up_isr_cycles_max: Some(self.powerup_isr_max.1),
            task_run_cycles_max: Some(self.powerup_task_max.0.max(self.task_max.0)),
            isr_longest_cycles: self.longest_isr.0,
            period_cycles: self.period_cycles,
            masked_max_instrs: self.masked_max_run,
            task_interrupts_max: self.task_interrupts_max.0,
        }
    }
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
    let missed_before = emu.m().stats.missed_control();
    let st = &emu.m().stats;
    let powerup_masked_max = (st.masked_max, st.masked_max_at as f64 / TICK_HZ * 1e3);
    let powerup_isr_max = (st.isr_instrs_max, st.isr_cycles_max);
    let task_max =
        |st: &crate::stats::Stats| (st.task_cycles_max, st.task_max_at as f64 / TICK_HZ * 1e3);
    let powerup_task_max = task_max(st);
    // The power-up's longest interrupt: the run's, as no window has started yet.
    let powerup_isr_max_at = {
        let (k, c) = st
            .isr_longest
            .stages
            .iter()
            .enumerate()
            .max_by_key(|(_, s)| s.1)
            .map_or((0, 0), |(k, s)| (k, s.1));
        let label = crate::profile::Stage::ALL
            .iter()
            .find(|s| **s as usize == k)
            .map_or("?", |s| s.label());
        (st.isr_longest.at as f64 / TICK_HZ * 1e3, label, c)
    };
    emu.m_mut().stats.restart_window();
    emu.run_for(window_s)?;
    let out = finish("perf", &emu, t0, Vec::new())?;
    let tag = format!("{sensor:?}-{:.0}hz", 1.0 / emu.m().board.period_s());
    dump_isr_blocks(elf, &emu.m().stats, &tag)?;
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
    let ms = |t: u64| t as f64 / TICK_HZ * 1e3;
    Ok(Perf {
        sensor,
        banks,
        pwm_hz: 1.0 / m.board.period_s(),
        firmware_pwm_hz,
        period_cycles: period_cycles(&emu),
        states: out.states.first().cloned().unwrap_or_default(),
        missed_control: st.missed_control() as u64,
        missed_window: (st.missed_control() - missed_before) as u64,
        overruns_before_control: out.overruns_before_control,
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
        longest_isr: (st.isr_longest.cycles, ms(st.isr_longest.at)),
        masked_max_run: st.masked_max_run,
        powerup_task_max,
        task_max: task_max(st),
        task_interrupts_max: (st.task_from_pend_max, ms(st.task_from_pend_max_at)),
        task_deadline_misses: st.task_deadline_misses,
        missed: st.missed.iter().map(|x| (ms(x.t), why(x), x.pc)).collect(),
        window_s,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

/// docs/performance.md's table of one build: the stages, the whole interrupt, the
/// period's figures and the gate's verdicts.
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
        "- whole interrupt in Run: {:.0} cycles mean ({:.1} % of the period), {} max ({:.1} %), over {} interrupts in {:.1} s of Run",
        p.isr_cycles_mean,
        share(p.isr_cycles_mean),
        p.isr_cycles_max,
        share(p.isr_cycles_max as f64),
        p.isr_count,
        p.window_s
    );
    let _ = writeln!(
        s,
        "- longest control interrupt at any moment: {} est. cycles ({:.1} % of the period), ending at {:.1} ms",
        p.longest_isr.0,
        share(p.longest_isr.0 as f64),
        p.longest_isr.1
    );
    let _ = writeln!(
        s,
        "- longest interrupt-masked stretch: {} instructions in Run, {} over the run",
        p.masked_max_instrs, p.masked_max_run
    );
    let _ = writeln!(
        s,
        "- missed control periods (a trigger finding the control interrupt running, the previous sequence unread or converting, or the ADC not armed): {} after the control interrupt started, {} in the window; init's overruns before it: {}; HardFaults: {}; rules broken: {}",
        p.missed_control,
        p.missed_window,
        p.overruns_before_control,
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
        share(p.powerup_isr_max.1 as f64),
        p.powerup_isr_max_at.0,
        p.powerup_isr_max_at.2,
        p.powerup_isr_max_at.1
    );
    let _ = writeln!(
        s,
        "- adaptation task (an update is in force {} periods after its sample: the task returns before the {}th control interrupt after it enters): at most {} control interrupts entered from a sample to the return that served it{}, {} runs late; longest run {} est. cycles before Run (ending at {:.1} ms), {} in Run, control interrupts included",
        mras::UPDATE_LATENCY_PERIODS,
        mras::UPDATE_LATENCY_PERIODS,
        p.task_interrupts_max.0,
        if p.task_interrupts_max.0 > 0 {
            format!(" (ending at {:.1} ms)", p.task_interrupts_max.1)
        } else {
            String::new()
        },
        p.task_deadline_misses,
        p.powerup_task_max.0,
        p.powerup_task_max.1,
        p.task_max.0,
    );
    for (ms, why, _) in p.missed.iter().take(5) {
        let _ = writeln!(s, "- missed period at {ms:.2} ms: {why}");
    }
    if p.missed.len() > 5 {
        let _ = writeln!(s, "- and {} more missed periods", p.missed.len() - 5);
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
    let _ = writeln!(s, "\nThe gate (`drive-emu perf`):\n");
    s.push_str(&budget::verdict_lines(&budget::evaluate(
        &p.budget_measures(),
    )));
    s
}

/// Diagnostics (`DRIVE_EMU_ISR_BLOCKS=DIR`): the run's longest control interrupt, the
/// window's and the adaptation task's longest run, cycles by function (innermost inlined
/// frame, under its two callers) into `DIR/<tag>-{longest,window,task}.txt`, and by block
/// with its first source line into `DIR/<tag>-<same>-blocks.txt`.
pub fn dump_isr_blocks(elf: &[u8], st: &crate::stats::Stats, tag: &str) -> Result<()> {
    let Some(dir) = std::env::var_os("DRIVE_EMU_ISR_BLOCKS") else {
        return Ok(());
    };
    let dir = std::path::PathBuf::from(dir);
    std::fs::create_dir_all(&dir)?;
    for (name, blocks) in [
        ("longest", &st.blocks_longest),
        ("window", &st.blocks_window),
        ("task", &st.task_blocks_longest),
    ] {
        let pcs: Vec<u32> = blocks.iter().map(|b| b.0).collect();
        let chains = m4_cycles::chains_of_elf(elf, &pcs)?;
        let mut by: std::collections::BTreeMap<String, u64> = Default::default();
        // Each block at its address with its first instruction's source line: where
        // a function's share above is spent.
        let mut at: std::collections::BTreeMap<u32, u64> = Default::default();
        for (pc, c) in blocks {
            *at.entry(*pc).or_default() += c;
        }
        let mut lines = String::new();
        for (pc, c) in &at {
            let loc = chains
                .get(pc)
                .and_then(|ch| ch.first())
                .map(|f| format!("{} {}", f.location, f.function))
                .unwrap_or_default();
            lines.push_str(&format!("{pc:#010x} {c:6} {loc}\n"));
        }
        std::fs::write(dir.join(format!("{tag}-{name}-blocks.txt")), lines)?;
        for (pc, c) in &at {
            let key = chains
                .get(pc)
                .map(|ch| {
                    ch.iter()
                        .take(3)
                        .map(|f| f.function.as_str())
                        .collect::<Vec<_>>()
                        .join(" < ")
                })
                .unwrap_or_else(|| format!("{pc:#x}"));
            *by.entry(key).or_default() += c;
        }
        let mut v: Vec<_> = by.into_iter().collect();
        v.sort_by_key(|x| std::cmp::Reverse(x.1));
        let total: u64 = v.iter().map(|x| x.1).sum();
        let mut text = format!("{total} est. cycles (entry/exit excluded)\n");
        for (k, c) in v {
            text.push_str(&format!("{c:6} {k}\n"));
        }
        std::fs::write(dir.join(format!("{tag}-{name}.txt")), text)?;
    }
    Ok(())
}

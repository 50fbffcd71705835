//! The release firmware on the emulated board: every scenario of docs/performance.md.
//! Needs the release ELF (`cargo xtask build-cross`); `DRIVE_EMU_ELF` runs another one
//! (e.g. an older firmware, to see which rules it breaks).

use drive_emu::budget;
use drive_emu::scenarios::{self, pieces, Outcome, SensorBoard};
use drive_emu::stats::MissCause;

fn elf() -> Vec<u8> {
    let path = std::env::var_os("DRIVE_EMU_ELF")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(hil_sim::stream::release_elf);
    std::fs::read(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e}: build the release firmware first (`cargo xtask build-cross`)",
            path.display()
        )
    })
}

/// The `fast-run` build (Run at 25 rev/s, near the voltage limit): `DRIVE_EMU_FAST_ELF`,
/// or the one `cargo xtask ci` builds aside.
fn fast_elf() -> Vec<u8> {
    let path = std::env::var_os("DRIVE_EMU_FAST_ELF")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| hil_sim::checkout::target_dir().join("fast-run/drive-fw-fast-run"));
    std::fs::read(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e}: build the fast-run firmware first (`cargo xtask ci` builds it aside)",
            path.display()
        )
    })
}

/// The scenario `name` on the release ELF; its report's row and section left for
/// `drive-emu scenarios --reuse` when `DRIVE_EMU_PIECES` names a directory.
fn run(name: &str) -> Outcome {
    let elf = elf();
    let o = scenarios::run(name, &elf).unwrap_or_else(|e| panic!("{name}: {e:#}"));
    eprintln!("{}", scenarios::report(std::slice::from_ref(&o), ""));
    let (row, details) = (scenarios::report_row(&o), scenarios::report_detail(&o));
    pieces::save(name, &[&elf], &[("row", &row), ("details", &details)])
        .unwrap_or_else(|e| panic!("{name}: {e:#}"));
    o
}

/// What every scenario must show: nothing lost (the drive's own drop counters and the
/// stream's `seq`, read from the stream), and the budgets of `budget.rs` (no missed control
/// period, no HardFault, no hardware rule broken, every control interrupt within its
/// share of the period, masked stretches and the adaptation task's deadline; a build's
/// known failures as listed there).
fn healthy(o: &Outcome) {
    assert!(
        o.losses.is_none(),
        "{}: the stream says it lost: {}",
        o.name,
        o.losses.describe()
    );
    within_budget(o);
}

/// The budgets alone (see [`healthy`]).
fn within_budget(o: &Outcome) {
    let v = budget::evaluate(&o.budget_measures(SensorBoard::Kmz41));
    let failed: Vec<String> = v
        .iter()
        .filter(|x| x.fails())
        .map(|x| x.describe())
        .collect();
    assert!(
        failed.is_empty(),
        "{}: over budget:\n  {}\nrules broken: {:#?}\nmissed: {:#?}",
        o.name,
        failed.join("\n  "),
        o.violations,
        scenarios::missed_lines(&o.missed, 5)
    );
}

/// The note `key` as a number (its unit after a space, if any).
fn number(o: &Outcome, key: &str) -> f64 {
    let v = o
        .note(key)
        .unwrap_or_else(|| panic!("{}: no note `{key}`", o.name));
    v.split(' ')
        .next()
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("{}: `{key}` = `{v}` is not a number", o.name))
}

fn event_in(o: &Outcome, boot: usize, kind: &str, text: &str) -> bool {
    o.events
        .iter()
        .any(|e| e.boot == boot && e.kind == kind && e.text.contains(text))
}

fn states(o: &Outcome, boot: usize) -> Vec<&str> {
    o.states[boot].iter().map(|(s, _)| s.as_str()).collect()
}

const COMMISSIONING: [&str; 10] = [
    "LoadCalibration",
    "Identify",
    "Align",
    "Sweep",
    "SpinUp",
    "Adapt",
    "Verify",
    "Motion",
    "Store",
    "Run",
];

/// [`COMMISSIONING`] on a motor of another pole-pair count than the firmware's: the
/// first sweep finds the count, the second confirms it.
const SWEPT_TWICE: [&str; 12] = [
    "LoadCalibration",
    "Identify",
    "Align",
    "Sweep",
    "Align",
    "Sweep",
    "SpinUp",
    "Adapt",
    "Verify",
    "Motion",
    "Store",
    "Run",
];

#[test]
fn erased_flash_commissions_to_run_then_the_next_power_up_loads() {
    let o = run("power-up");
    healthy(&o);
    assert_eq!(states(&o, 0), COMMISSIONING);
    assert!(o.has_event("mras-stored", ""));
    assert_eq!(states(&o, 1), ["LoadCalibration", "Identify", "Run"]);
    assert!(o.has_event("mras-loaded", ""));
    // At once: the on-rotor identification alone (R and L follow the winding's
    // temperature; ψ and J are loaded). It takes about 0.2 s: the d-axis current turns a
    // rotor resting a few electrical degrees off it, and each level is then measured
    // between two instants the sensor reads alike, 50 ms apart at least.
    assert!(
        o.entered(1, "Run").unwrap() < 350,
        "the stored calibration loads at once"
    );
}

/// The drive at the plant, in Run, both boots, from what the plant did (never from what
/// the firmware says of itself): the current the bridge drives against the true
/// rotor's q axis, and the θ̂ the records stream against the true rotor angle at their
/// control periods. The figures this release ELF gives are published by
/// `cargo xtask docs emu-report` (docs/figures/emu-report.md, the power-up's notes);
/// the bounds sit at about twice them: the current's mean angle within 10 mrad
/// electrical and its pk-pk over the rotor angle within 120 mrad (bin means of 64
/// periods each: the shunts' noise of ±2 counts, 30 mA, leaves about 20; the board's
/// 820 ns of dead time distorts the 0.8 A current at each phase's zero crossing, to
/// about 57 mrad with or without the identified error fed forward), torque per amp at
/// least 0.999 (the cost of a 45 mrad error), θ̂'s spatial error within 1 mrad pk-pk
/// and at least 180x below the raw sensor's. A drive commuting 0.3 rad off gives
/// 300 mrad and 0.955; a correction of the wrong sign doubles the raw sensor's error
/// (over 100 mrad mechanical here), far past both (`cargo xtask mutants` builds both).
/// The offset case also runs here: the calibration loaded on a sensor remounted since.
#[test]
fn in_run_the_current_and_the_streamed_angle_follow_the_rotor_at_the_plant() {
    let p = scenarios::power_up_run(&elf()).unwrap_or_else(|e| panic!("{e:#}"));
    assert!(
        p.raw_error_pkpk_rad > 0.1,
        "raw {} rad",
        p.raw_error_pkpk_rad
    );
    assert!(
        p.outcome.losses.is_none(),
        "lost: {}",
        p.outcome.losses.describe()
    );
    // Every measure, then one verdict naming each that is off.
    let mut off = Vec::new();
    for (b, c) in p.run_current.iter().enumerate() {
        let c = c.unwrap_or_else(|| panic!("boot {}: no Run window", b + 1));
        eprintln!("boot {}: {c:?}", b + 1);
        assert!(c.periods > 2_000, "boot {}: {c:?}", b + 1);
        if c.angle_error_e_rad.abs() >= 10e-3 || c.angle_error_e_pk_pk_rad >= 120e-3 {
            off.push(format!(
                "boot {}: the current's electrical angle error at the plant: mean {:+.1} mrad, pk-pk {:.1} mrad",
                b + 1,
                c.angle_error_e_rad * 1e3,
                c.angle_error_e_pk_pk_rad * 1e3
            ));
        }
        if c.torque_per_amp <= 0.999 {
            off.push(format!(
                "boot {}: torque per amp at the plant: {:.4} of Kt",
                b + 1,
                c.torque_per_amp
            ));
        }
    }
    for (b, e) in p.estimate.iter().enumerate() {
        eprintln!("boot {}: {}", b + 1, scenarios::describe_estimate(e));
        if e.estimate_pk_pk_rad >= 1e-3 || e.raw_pk_pk_rad <= 180.0 * e.estimate_pk_pk_rad {
            off.push(format!(
                "boot {}: the streamed θ̂ against the rotor at the plant: {}",
                b + 1,
                scenarios::describe_estimate(e)
            ));
        }
    }
    assert!(off.is_empty(), "{}", off.join("\n"));
    // The same bounds fail a drive whose electrical offset is 0.3 rad wrong: the
    // stored calibration loaded on a board whose sensor was remounted 0.3/p rad since.
    let p_pairs = drive_emu::board::Board::commissioning(1)
        .unwrap()
        .plant
        .motor
        .pole_pairs as f64;
    let (o, c) = scenarios::remounted_power_up(&elf(), p.commissioned, 0.3 / p_pairs)
        .unwrap_or_else(|e| panic!("{e:#}"));
    let c = c.expect("a Run window");
    eprintln!("remounted: {c:?}");
    assert_eq!(states(&o, 0), ["LoadCalibration", "Identify", "Run"]);
    assert!(c.angle_error_e_rad.abs() > 0.2, "{c:?}");
    assert!(c.torque_per_amp < 0.98, "{c:?}");
}

#[test]
fn a_sensor_wire_break_in_run_turns_the_bridge_off_within_one_period() {
    let o = run("wire-break");
    healthy(&o);
    // Off at once; the safe state once the lock has not come back within the
    // supervisor's re-acquisition timeout (the sensor stays broken).
    assert!(o.has_event("mras-fault", "cause=LossOfLock"));
    let periods: f64 = o
        .note("bridge off in control periods")
        .unwrap()
        .parse()
        .unwrap();
    assert!(periods <= 1.0, "bridge off after {periods} periods");
}

#[test]
fn over_current_on_bkin_clears_moe_in_hardware_and_the_bridge_stays_off() {
    let o = run("overcurrent");
    healthy(&o);
    assert!(o.has_event("mras-fault", "cause=OverCurrent"));
    // The comparator's crossing to MOE clear: the break filter (BKF), more than
    // nothing and within a period.
    let us = number(&o, "comparator crossing → MOE cleared (break filter)");
    assert!(us > 0.0 && us < 1e6 / o.pwm_hz, "{us} µs");
    // The supervisor holds the safe state after OverCurrent (it releases only on a
    // restart, which nothing asks for): MOE stays 0 once the current has fallen back
    // under the level, and after the level is back to normal.
    assert_eq!(
        o.note("comparator still over its level 50 ms after the trip"),
        Some("false")
    );
    assert_eq!(number(&o, "MOE set again after the trip"), 0.0);
    assert_eq!(o.note("MOE at the end"), Some("false"));
}

#[test]
fn a_stalled_firmware_is_reset_by_the_watchdog_and_reports_it() {
    let o = run("watchdog");
    assert_eq!(o.boots, 2, "one watchdog reset");
    assert!(o.has_event("mras-fault", "cause=Watchdog"));
    let ms = number(&o, "watchdog reset after the stall");
    assert!(
        (90.0..=120.0).contains(&ms),
        "IWDG after {ms} ms (100 ms configured)"
    );
    // The stuck line keeps the control interrupt running: every trigger of the stall
    // is a missed period, and none after the reset.
    let period_ms = 1e3 / o.pwm_hz;
    assert!(number(&o, "missed periods during the stall") > 0.9 * ms / period_ms);
    assert!(o
        .missed
        .iter()
        .all(|x| x.cause == MissCause::ControlRunning));
    assert_eq!(number(&o, "missed periods after the reset"), 0.0);
    assert_eq!(o.hard_faults, 0);
    assert!(o.violations.is_empty(), "{:#?}", o.violations);
}

/// Made to last 1.5 periods, the control interrupt of the release firmware (its real
/// code, then a busy-wait the emulator adds before the return) misses periods: the
/// firmware reads JEOS at entry, so no sequence is ever left unread, and yet no trigger
/// finds the interrupt idle. The gate fails such a build.
#[test]
fn a_control_interrupt_of_one_and_a_half_periods_is_reported_missing_periods() {
    let mut emu = drive_emu::Emu::new(
        &elf(),
        drive_emu::board::Board::commissioning(1).unwrap(),
        None,
    )
    .unwrap();
    emu.run_for(0.1).unwrap();
    assert!(emu.m().stats.missed.is_empty());
    let period = emu.m().board.period_ticks();
    emu.m_mut().control_busy_ticks = 3 * period / 2;
    emu.run_for(0.05).unwrap();
    let m = emu.m();
    let periods = 0.05 / m.board.period_s();
    let missed = &m.stats.missed;
    assert!(
        missed.len() as f64 > 0.9 * periods,
        "{} of {periods}",
        missed.len()
    );
    assert!(missed.iter().all(|x| x.cause == MissCause::ControlRunning));
    let o = scenarios::violations(&emu);
    assert!(o.is_empty(), "{o:#?}");
    let longest = m.stats.isr_longest.cycles as f64 / scenarios::period_cycles(&emu) as f64;
    assert!(longest > 1.5, "{longest} periods");
}

#[test]
fn a_store_that_hits_a_flash_error_ends_safe_with_its_cause() {
    let o = run("store-flash-error");
    healthy(&o);
    assert!(o.has_event("mras-store-failed", "reason=WrpErr"));
    assert!(o.has_event("mras-fault", "cause=StoreFailed"));
    assert_eq!(o.note("MOE in Safe"), Some("false"));
}

/// A power cut while the first store programs the record's 14th double word: the
/// next power-up reads the torn word (FLASH_ECCR.ECCD, NMI), the firmware's NMI handler
/// turns it into a failed read, the drive neither faults nor runs on the record: it
/// says why it commissions again, does, and stores; the power-up after loads that.
#[test]
fn a_power_cut_during_the_store_tears_the_record_and_the_next_power_up_commissions_again() {
    let o = run("torn-store");
    healthy(&o);
    let first = states(&o, 0);
    assert_eq!(first.last(), Some(&"Store"), "{first:?}");
    assert!(!event_in(&o, 0, "mras-stored", ""));
    assert!(event_in(&o, 1, "mras-not-loaded", "reason=EccDouble"));
    assert!(!event_in(&o, 1, "mras-loaded", ""));
    assert!(!o.has_event("mras-fault", ""), "no fault: {:#?}", o.events);
    let ecc = o
        .note("boot 2: double ECC errors read (FLASH_ECCR.ECCD), NMIs taken")
        .unwrap();
    let (errors, nmis) = ecc.split_once(", ").unwrap();
    assert!(
        errors.parse::<u32>().unwrap() >= 1 && nmis.parse::<u32>().unwrap() >= 1,
        "{ecc}"
    );
    assert_eq!(states(&o, 1), COMMISSIONING);
    assert!(event_in(&o, 1, "mras-stored", ""));
    assert_eq!(states(&o, 2), ["LoadCalibration", "Identify", "Run"]);
    assert!(event_in(&o, 2, "mras-loaded", ""));
}

#[test]
fn a_host_that_stops_reading_rtt_costs_no_control_period() {
    let o = run("rtt-host-stops");
    within_budget(&o);
    // Frames that found the up-buffer full are lost whole, and the stream's `seq`
    // counts them; the drive itself lost nothing.
    let l = o.losses;
    assert!(l.frames_lost > 10, "{}", l.describe());
    assert_eq!(
        (
            l.handoffs_dropped,
            l.updates_dropped,
            l.updates_late,
            l.events_dropped
        ),
        (0, 0, 0, 0),
        "{}",
        l.describe()
    );
    let during = number(&o, "control periods while the host did not read (1 s)");
    // One control period per PWM period: the rate the firmware programmed (170 MHz).
    assert_eq!(during as u64, 170_000_000 / o.period_cycles);
    assert!(o.entered(0, "Run").is_some());
}

/// The control interrupt by stage over Run (what `cargo xtask perf` reports): the
/// stages add up to the whole interrupt, each has work, the period the emulator drives
/// the plant with is the one the firmware says it runs (its banner), and the build
/// passes the gate. `DRIVE_EMU_ELF` = the 40 kHz build checks that one.
#[test]
fn the_control_interrupt_by_stage_adds_up_and_the_build_passes_the_gate() {
    let p =
        scenarios::perf_run(&elf(), 0.1, SensorBoard::Kmz41).unwrap_or_else(|e| panic!("{e:#}"));
    eprintln!("{}", scenarios::perf_table(&p, "test"));
    assert_eq!(p.firmware_pwm_hz, Some(p.pwm_hz.round() as u32));
    assert_eq!(
        p.period_cycles,
        170_000_000 / p.firmware_pwm_hz.unwrap() as u64
    );
    let sum_instrs: f64 = p.stages.iter().map(|s| s.1).sum();
    let sum_cycles: f64 = p.stages.iter().map(|s| s.3).sum();
    assert!(
        (sum_instrs - p.isr_instrs_mean).abs() < 0.5,
        "{sum_instrs} vs {}",
        p.isr_instrs_mean
    );
    assert!(
        (sum_cycles - p.isr_cycles_mean).abs() < 0.5,
        "{sum_cycles} vs {}",
        p.isr_cycles_mean
    );
    for (label, instrs_mean, _, cycles_mean, cycles_max) in &p.stages {
        assert!(
            *instrs_mean > 0.0 && *cycles_mean > 0.0,
            "{label}: nothing charged"
        );
        assert!(*cycles_max as f64 >= *cycles_mean, "{label}");
    }
    let v = budget::evaluate(&p.budget_measures());
    let failed: Vec<String> = v
        .iter()
        .filter(|x| x.fails())
        .map(|x| x.describe())
        .collect();
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}

/// Near the voltage limit a shunt whose low side conducts too briefly cannot be read:
/// the drive reads the two phases with the lowest duties and reconstructs the third.
/// The `fast-run` build holds Run at 25 rev/s, about 91 % of Vdc/√3, on the emulated
/// board whose shunts show the phase current only while their low sides conduct (dead
/// time and settling included, at each conversion's own instant). Its current loop
/// keeps the current on the q axis (mean and pk-pk angle within the power-up test's
/// bounds) and its torque per amp within 2 % of the default build's Run at 36 %. A
/// drive that reads phases a and b whatever the duties (`cargo xtask mutants`) fails:
/// in the `fast-run` build its commissioning refuses it (`InertiaOutOfRange`).
#[test]
fn near_the_voltage_limit_the_current_loop_keeps_its_torque_per_amp_at_the_plant() {
    let (elf, fast) = (elf(), fast_elf());
    let low = scenarios::run_at_plant(&elf).unwrap_or_else(|e| panic!("{e:#}"));
    let high = scenarios::run_at_plant(&fast).unwrap_or_else(|e| panic!("{e:#}"));
    let text = scenarios::modulation_report(&low, &high);
    pieces::save(
        scenarios::AT_PLANT_PIECE,
        &[&elf, &fast],
        &[("modulation", &text)],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    let mut off = Vec::new();
    let (lc, hc) = (low.current.expect("a Run window"), high.current);
    let (lm, hm) = (low.modulation.expect("bridge on in Run"), high.modulation);
    eprintln!(
        "low: {:.1} rad/s, {lc:?}, {}",
        low.speed_rad_s,
        scenarios::describe_modulation(&lm)
    );
    healthy(&low.outcome);
    match (hc, hm) {
        (Some(c), Some(m)) => {
            eprintln!(
                "high: {:.1} rad/s, {c:?}, {}",
                high.speed_rad_s,
                scenarios::describe_modulation(&m)
            );
            if m.mean < 0.85 {
                off.push(format!(
                    "the fast build is not near the voltage limit: {}",
                    scenarios::describe_modulation(&m)
                ));
            }
            if c.torque_per_amp < 0.98 * lc.torque_per_amp {
                off.push(format!(
                    "torque per amp at the plant: {:.4} of Kt near the voltage limit against {:.4} at {:.0} %",
                    c.torque_per_amp,
                    lc.torque_per_amp,
                    lm.mean * 100.0
                ));
            }
            if c.angle_error_e_rad.abs() >= 10e-3 || c.angle_error_e_pk_pk_rad >= 120e-3 {
                off.push(format!(
                    "the current's electrical angle error at the plant: mean {:+.1} mrad, pk-pk {:.1} mrad",
                    c.angle_error_e_rad * 1e3,
                    c.angle_error_e_pk_pk_rad * 1e3
                ));
            }
        }
        _ => off.push(format!(
            "no Run window at the plant near the voltage limit; states {:?}",
            states(&high.outcome, 0)
        )),
    }
    assert!(off.is_empty(), "{}", off.join("\n"));
    healthy(&high.outcome);
}

/// A probe attaches to the drive in Run as probe-rs does (halt, read PC and the RTT
/// block, resume) and holds the halt 1 ms, then 100 ms: TIM1 frozen keeps the bridge
/// off throughout (DBG_TIM1_STOP), the watchdog pauses (DBG_IWDG_STOP) so there is no
/// reset, no fault is latched, and the drive re-acquires the coasting rotor and runs
/// on with its current on the q axis. The one rule broken is ES0430's: the first
/// conversion of each ADC after a halt longer than 1 ms is wrong and the firmware uses
/// it (one period, ridden through).
#[test]
fn attaching_in_run_halts_with_the_bridge_off_and_the_drive_runs_on() {
    let o = run("attach-halt");
    assert_eq!(o.boots, 1, "a reset while or after halted");
    assert_eq!(states(&o, 0), COMMISSIONING, "{:?}", o.states);
    assert!(!event_in(&o, 0, "mras-fault", ""), "{:#?}", o.events);
    assert!(o.losses.is_none(), "lost: {}", o.losses.describe());
    assert_eq!((o.missed_periods, o.hard_faults), (0, 0));
    for (hold_s, samples) in [(1e-3, 10), (100e-3, 1000)] {
        let ms = hold_s * 1e3;
        let on = o
            .note(&format!("{ms:.0} ms halt: bridge on while halted"))
            .unwrap_or_default();
        assert_eq!(on, format!("0 of {samples} samples"), "{ms} ms");
        let tpa = number(&o, &format!("{ms:.0} ms halt: torque per amp after"));
        assert!(
            tpa > 0.999,
            "{ms} ms: torque per amp {tpa} after the resume"
        );
    }
    let erratum: Vec<&String> = o
        .violations
        .iter()
        .filter(|v| v.contains("ES0430"))
        .collect();
    assert_eq!(erratum.len(), o.violations.len(), "{:#?}", o.violations);
    assert!(
        erratum
            .iter()
            .all(|v| v.starts_with("ADC: 4 wrong results")),
        "one wrong conversion per ADC and halt, no more: {erratum:?}"
    );
}

/// The release ELF identifies motors its constants do not describe (they stay the
/// nominal 4 pole pairs, R 0.3 ohm, L 0.5 mH, ψ 20 mWb, J 2e-4): the smallest
/// inductance, the highest resistance and the lowest resistance of the ratings, with 6,
/// 2 and 8 pole pairs and each its own magnet and inertia, behind the board's 820 ns of
/// dead time (the scenario's fan load scaled with the torque constant, as in hil-sim's
/// population). Each commissions to Run within budget (aligned and swept twice), with
/// its pole pairs found, R within 5 %, Ld, Lq within 10 %, ψ within 3 % and J within
/// 10 % of the plant's, as the stream's `mras-aligned`, `mras-identified` and
/// `mras-motion` say.
#[test]
fn the_release_elf_identifies_three_motors_it_was_not_built_for() {
    let elf = elf();
    for (pole_pairs, r_ohm, l_h, flux_wb, j_kg_m2) in [
        (6, 0.2, 30e-6, 8e-3, 1e-4),
        (2, 1.8, 1.5e-3, 12e-3, 3e-4),
        (8, 0.06, 0.15e-3, 4e-3, 1e-4),
    ] {
        let (o, m) = scenarios::motor_run(&elf, |m| {
            m.viscous_nm_s_rad *= (pole_pairs as f64 * flux_wb) / (m.pole_pairs as f64 * m.flux_wb);
            m.pole_pairs = pole_pairs;
            m.r_ohm = r_ohm;
            m.l_h = l_h;
            m.flux_wb = flux_wb;
            m.j_kg_m2 = j_kg_m2;
        })
        .unwrap_or_else(|e| panic!("R {r_ohm} L {l_h}: {e:#}"));
        let what = format!(
            "p {pole_pairs}, R {r_ohm} ohm, L {:.0} uH, flux {:.0} mWb, J {j_kg_m2:.0e}",
            1e6 * l_h,
            1e3 * flux_wb
        );
        healthy(&o);
        assert_eq!(states(&o, 0), SWEPT_TWICE, "{what}");
        let field = |kind: &str, k: &str| -> f64 {
            let text = &o
                .events
                .iter()
                .find(|e| e.kind == kind)
                .unwrap_or_else(|| panic!("{what}: no {kind}"))
                .text;
            text.split_whitespace()
                .find_map(|kv| kv.strip_prefix(&format!("{k}=")))
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("{what}: no {k} in `{text}`"))
        };
        // The last alignment's count: the one in force.
        let found = o
            .events
            .iter()
            .rev()
            .find(|e| e.kind == "mras-aligned")
            .and_then(|e| {
                e.text
                    .split_whitespace()
                    .find_map(|kv| kv.strip_prefix("pole_pairs="))
                    .and_then(|v| v.parse::<u32>().ok())
            });
        assert_eq!(found, Some(pole_pairs), "{what}");
        let identified = |k: &str| field("mras-identified", k);
        let (r, ld, lq) = (identified("r_ohm"), identified("ld_h"), identified("lq_h"));
        let (psi, j) = (
            field("mras-motion", "flux_wb"),
            field("mras-motion", "inertia_kg_m2"),
        );
        eprintln!(
            "{what}: {pole_pairs} pole pairs found; identified R {r:.4} ohm ({:+.2} %), Ld {:.1} uH ({:+.2} %), Lq {:.1} uH ({:+.2} %), inverter {} V, flux {:.3} mWb ({:+.2} %), J {j:.3e} ({:+.2} %); Identify {} ms, Run at {} ms",
            100.0 * (r / m.r_ohm - 1.0),
            1e6 * ld,
            100.0 * (ld / m.l_h - 1.0),
            1e6 * lq,
            100.0 * (lq / m.l_h - 1.0),
            identified("v_inverter_v"),
            1e3 * psi,
            100.0 * (psi / m.flux_wb - 1.0),
            100.0 * (j / m.j_kg_m2 - 1.0),
            o.entered(0, "Align").unwrap() - o.entered(0, "Identify").unwrap(),
            o.entered(0, "Run").unwrap()
        );
        assert!((r / m.r_ohm - 1.0).abs() < 0.05, "{what}: R {r}");
        assert!((ld / m.l_h - 1.0).abs() < 0.10, "{what}: Ld {ld}");
        assert!((lq / m.l_h - 1.0).abs() < 0.10, "{what}: Lq {lq}");
        assert!((psi / m.flux_wb - 1.0).abs() < 0.03, "{what}: flux {psi}");
        assert!((j / m.j_kg_m2 - 1.0).abs() < 0.10, "{what}: J {j}");
    }
}

//! The release firmware on the emulated board: every scenario of docs/performance.md.
//! Needs the release ELF (`cargo xtask build-cross`); `DRIVE_EMU_ELF` runs another one
//! (e.g. an older firmware, to see which rules it breaks).

use drive_emu::scenarios::{self, Outcome};

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

fn run(name: &str) -> Outcome {
    let o = scenarios::run(name, &elf()).unwrap_or_else(|e| panic!("{name}: {e:#}"));
    eprintln!("{}", scenarios::report(std::slice::from_ref(&o), ""));
    o
}

/// What every scenario must show: no missed control period, no fault the scenario did
/// not cause, no hardware rule broken.
fn healthy(o: &Outcome) {
    assert_eq!(o.missed_periods, 0, "{}: missed control periods", o.name);
    assert_eq!(o.hard_faults, 0, "{}: HardFault", o.name);
    assert!(
        o.violations.is_empty(),
        "{}: rules broken: {:#?}",
        o.name,
        o.violations
    );
    assert!(
        o.isr_cycles_max < o.period_cycles,
        "{}: the control interrupt overran the period",
        o.name
    );
}

#[test]
fn erased_flash_commissions_to_run_then_the_next_power_up_loads() {
    let o = run("power-up");
    healthy(&o);
    let seq: Vec<&str> = o.states[0].iter().map(|(s, _)| s.as_str()).collect();
    assert_eq!(
        seq,
        [
            "LoadCalibration",
            "Align",
            "Sweep",
            "SpinUp",
            "Adapt",
            "Verify",
            "Store",
            "Run"
        ]
    );
    assert!(o.has_event("mras-stored", ""));
    let second: Vec<&str> = o.states[1].iter().map(|(s, _)| s.as_str()).collect();
    assert_eq!(second, ["LoadCalibration", "Run"]);
    assert!(o.has_event("mras-loaded", ""));
    assert!(
        o.entered(1, "Run").unwrap() < 200,
        "the stored calibration loads at once"
    );
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
fn over_current_on_bkin_clears_moe_in_hardware() {
    let o = run("overcurrent");
    healthy(&o);
    assert_eq!(o.note("MOE cleared by the break (hardware)"), Some("true"));
    assert!(o.has_event("mras-fault", "cause=OverCurrent"));
}

#[test]
fn a_stalled_firmware_is_reset_by_the_watchdog_and_reports_it() {
    let o = run("watchdog");
    assert_eq!(o.missed_periods, 0);
    assert_eq!(o.boots, 2, "one watchdog reset");
    assert!(o.has_event("mras-fault", "cause=Watchdog"));
    let ms: f64 = o
        .note("watchdog reset after the stall")
        .unwrap()
        .trim_end_matches(" ms")
        .parse()
        .unwrap();
    assert!(
        (90.0..=120.0).contains(&ms),
        "IWDG after {ms} ms (100 ms configured)"
    );
}

#[test]
fn a_store_that_hits_a_flash_error_ends_safe_with_its_cause() {
    let o = run("store-flash-error");
    healthy(&o);
    assert!(o.has_event("mras-store-failed", "reason=WrpErr"));
    assert!(o.has_event("mras-fault", "cause=StoreFailed"));
    assert_eq!(o.note("MOE in Safe"), Some("false"));
}

#[test]
fn a_host_that_stops_reading_rtt_costs_no_control_period() {
    let o = run("rtt-host-stops");
    healthy(&o);
    let during: u64 = o
        .note("control periods while the host did not read (1 s)")
        .unwrap()
        .parse()
        .unwrap();
    // One control period per PWM period: the rate the firmware programmed (170 MHz).
    assert_eq!(during, 170_000_000 / o.period_cycles);
    assert!(o.entered(0, "Run").is_some());
}

/// The control interrupt by stage over Run (what `cargo xtask perf` reports): the
/// stages add up to the whole interrupt, each has work, cycles weigh more than
/// instructions, and the period the emulator drives the plant with is the one the
/// firmware says it runs (its banner). `DRIVE_EMU_ELF` = the 40 kHz build checks that.
#[test]
fn the_control_interrupt_by_stage_adds_up_and_fits_the_period_in_run() {
    let p = scenarios::perf_run(&elf(), 0.1, scenarios::SensorBoard::Kmz41)
        .unwrap_or_else(|e| panic!("{e:#}"));
    eprintln!("{}", scenarios::perf_table(&p, "test"));
    assert_eq!(p.missed_control, 0, "missed control periods");
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
    assert!(p.isr_cycles_mean > p.isr_instrs_mean);
    assert!(
        p.isr_cycles_max < p.period_cycles,
        "the interrupt overran the period"
    );
}

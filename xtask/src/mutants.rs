//! `cargo xtask mutants`: the emulator's checks fail on firmware that is wrong.
//!
//! Each mutant is the release firmware with one deliberate fault (a `mutant-*` feature of
//! `drive-fw`, firmware/app/Cargo.toml), built to `target/mutants/`. The emulator test
//! that must catch it runs on that ELF (`DRIVE_EMU_ELF`); the mutant is killed when the
//! test fails and its failure names what caught it (a measure at the plant, a missed
//! period, a loss in the stream). A mutant that passes, or fails for another reason
//! (it did not build, the test did not run), fails this command: a check that passes
//! whatever the firmware does is what this exists to find.

use crate::{build_aside, cross_build, emulator, run, FIRMWARE};
use anyhow::{bail, Context, Result};
use std::process::Stdio;

/// One deliberately broken firmware and the check that must fail on it.
struct Mutant {
    /// The `drive-fw` feature that breaks it.
    feature: &'static str,
    /// What is broken, for the report.
    broken: &'static str,
    /// The test of `hil-sim/emu/tests/scenarios.rs` that must fail on it.
    test: &'static str,
    /// Text the test's failure must contain: what caught it.
    caught_by: &'static str,
    /// The variable that hands the test the mutant's ELF.
    env: &'static str,
}

const MUTANTS: [Mutant; 5] = [
    Mutant {
        feature: "mutant-correction-sign",
        broken:
            "the correction of the angle the drive commutes with and streams has the wrong sign",
        test: "in_run_the_current_and_the_streamed_angle_follow_the_rotor_at_the_plant",
        caught_by: "at the plant",
        env: "DRIVE_EMU_ELF",
    },
    Mutant {
        feature: "mutant-electrical-offset",
        broken: "the drive commutes 0.3 rad electrical off its alignment",
        test: "in_run_the_current_and_the_streamed_angle_follow_the_rotor_at_the_plant",
        caught_by: "at the plant",
        env: "DRIVE_EMU_ELF",
    },
    Mutant {
        feature: "mutant-slow-control",
        broken: "the control interrupt lasts 1.5 control periods",
        test: "erased_flash_commissions_to_run_then_the_next_power_up_loads",
        caught_by: "missed control periods",
        env: "DRIVE_EMU_ELF",
    },
    Mutant {
        feature: "mutant-starve-updates",
        broken: "the adaptation's update queue has room for one update",
        test: "erased_flash_commissions_to_run_then_the_next_power_up_loads",
        caught_by: "updates dropped",
        env: "DRIVE_EMU_ELF",
    },
    Mutant {
        feature: "fast-run,mutant-fixed-current-phases",
        broken: "near the voltage limit, the currents read from shunts a and b whatever the duties",
        test: "near_the_voltage_limit_the_current_loop_keeps_its_torque_per_amp_at_the_plant",
        // Its commissioning refuses it: Motion's inertia fit finds the q current it
        // integrates at the commissioning speed inconsistent with the motion.
        caught_by: "InertiaOutOfRange",
        env: "DRIVE_EMU_FAST_ELF",
    },
];

/// `cargo test` of the emulator's scenario tests, as CI runs them.
fn scenario_tests() -> std::process::Command {
    let mut c = emulator("test");
    c.args(["--test", "scenarios"]);
    c
}

/// Build every mutant, run its test, and fail unless each is caught as expected. The
/// default release ELF is rebuilt last, so that other commands keep using it.
pub fn check() -> Result<()> {
    // The test binary once, before the mutants (so a build error is not taken for a kill).
    let mut c = scenario_tests();
    c.arg("--no-run");
    run(c)?;
    // The default build aside: a test that compares a mutant with it reads it from
    // there, not from the release path each mutant's build overwrites.
    let default = build_aside(&[], "mutants", FIRMWARE)?;
    let mut report = Vec::new();
    let mut survivors = Vec::new();
    for m in &MUTANTS {
        let name = format!("{FIRMWARE}-{}", m.feature.replace(',', "+"));
        let elf = build_aside(&["--features", m.feature], "mutants", &name)?;
        let mut c = scenario_tests();
        c.args([m.test, "--", "--exact"]);
        c.env("DRIVE_EMU_ELF", &default);
        c.env(m.env, &elf);
        c.stdout(Stdio::piped()).stderr(Stdio::piped());
        eprintln!("\nxtask mutants: {} ({}) ...", m.feature, m.broken);
        let out = c.output().context("cannot run the emulator's test")?;
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        let ran = text.contains("running 1 test");
        let caught = !out.status.success() && ran && text.contains(m.caught_by);
        // The assertion that caught it, for the report: the panic message's first line
        // and those naming what caught it.
        let message: Vec<&str> = text
            .lines()
            .skip_while(|l| !l.contains("panicked at"))
            .skip(1)
            .take_while(|l| !l.starts_with("stack backtrace") && !l.starts_with("note:"))
            .map(str::trim)
            .collect();
        let why = message
            .iter()
            .enumerate()
            .filter(|(k, l)| *k == 0 || l.contains(m.caught_by))
            .map(|(_, l)| *l)
            .collect::<Vec<_>>()
            .join(" | ");
        if caught {
            eprintln!("  caught by `{}`: {why}", m.test);
            report.push(format!("{}: caught ({why})", m.feature));
        } else {
            let verdict = if out.status.success() {
                "the test passed".to_string()
            } else if !ran {
                "the test did not run".to_string()
            } else {
                format!("the test failed without naming `{}`: {why}", m.caught_by)
            };
            eprintln!("{text}");
            survivors.push(format!("{} ({}): {verdict}", m.feature, m.broken));
        }
    }
    run(cross_build(FIRMWARE))?;
    eprintln!("\nxtask mutants:");
    for r in &report {
        eprintln!("  {r}");
    }
    if !survivors.is_empty() {
        bail!(
            "mutants not caught by the check meant for them:\n  {}",
            survivors.join("\n  ")
        );
    }
    Ok(())
}

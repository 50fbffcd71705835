//! The bench workflow on the emulated board: `hil_sim::probe_bench::power_up`, the
//! very function a bench engineer runs with a real probe, driven through the emulator's
//! virtual probe ([`crate::vprobe`]) against an erased emulated STM32G474 turning the
//! simulated motor. probe-rs's own flash algorithm flashes the ELF, its RTT client
//! records both boots; the emulator, which only observes the RTT buffer, checks that
//! each capture is exactly what the firmware wrote, and reports what the board saw
//! (missed periods, HardFaults, broken hardware rules).

use crate::board::Board;
use crate::cpu::Emu;
use crate::rtt::RttMode;
use crate::vprobe::{EmuThread, Pacing};
use anyhow::{anyhow, bail, Context, Result};
use hil_sim::probe_bench::{self, PowerUpOptions, PowerUpReport};
use std::path::Path;

/// The chip probe-rs is told it talks to (the name `.cargo/config.toml`'s runner uses).
pub const CHIP: &str = "STM32G474RETx";

/// What the emulated board saw over the workflow.
pub struct BenchRun {
    pub report: PowerUpReport,
    /// Per boot recorded through probe-rs: the bytes the firmware wrote in that boot
    /// (seen by the emulator), of which the capture must be the beginning.
    pub written: Vec<Vec<u8>>,
    pub missed_periods: usize,
    pub hard_faults: usize,
    pub violations: Vec<String>,
    pub emulated_s: f64,
}

/// Flash, record, reflash, record: `power_up` on an erased emulated G474 (the
/// `commissioning` scenario's motor and sensor), then the captures against what the
/// firmware wrote.
pub fn power_up(elf_path: &Path, out: &Path, opts: &PowerUpOptions) -> Result<BenchRun> {
    let elf = std::fs::read(elf_path).with_context(|| elf_path.display().to_string())?;
    let emu = EmuThread::spawn(
        move || {
            let mut e = Emu::blank(Board::commissioning(1)?)?;
            // The emulator's measurements know which ELF the probe flashes; its own RTT
            // reader stands aside and only watches what the firmware writes.
            e.set_firmware(&elf)?;
            e.m_mut().rtt.mode = RttMode::Observe;
            Ok(e)
        },
        Pacing::Wall,
    )?;
    let mut open = || probe_bench::attach(emu.probe(), CHIP);
    let report = probe_bench::power_up(&mut open, elf_path, out, opts)?;
    let (written, missed_periods, hard_faults, violations, emulated_s) = emu.finish(|e| {
        let m = e.m();
        let boots: Vec<Vec<u8>> = m.rtt.boots().into_iter().map(<[u8]>::to_vec).collect();
        (
            boots,
            m.stats.missed.len(),
            m.stats.hard_faults.len(),
            crate::scenarios::violations(&e),
            m.time_s(),
        )
    })?;
    // Each capture is the beginning of one boot's stream: the boots recorded are the
    // last ones (a probe may reset the chip while flashing).
    let mut matched = Vec::new();
    for (k, b) in report.boots.iter().enumerate() {
        let captured =
            std::fs::read(&b.raw_path).with_context(|| b.raw_path.display().to_string())?;
        let seg = written
            .iter()
            .rev()
            .find(|w| !captured.is_empty() && w.starts_with(&captured))
            .ok_or_else(|| {
                anyhow!(
                    "boot {}: the capture probe-rs recorded ({} bytes) is not what the firmware \
                     wrote in any boot (the emulator saw {} boots)",
                    k + 1,
                    captured.len(),
                    written.len()
                )
            })?;
        matched.push(seg.clone());
    }
    if matched.len() != 2 {
        bail!("expected two recorded boots, got {}", matched.len());
    }
    Ok(BenchRun {
        report,
        written: matched,
        missed_periods,
        hard_faults,
        violations,
        emulated_s,
    })
}

/// The summary `drive-emu bench` prints after the tool's own.
pub fn describe(r: &BenchRun) -> String {
    let mut s = String::new();
    for (b, w) in r.report.boots.iter().zip(&r.written) {
        s.push_str(&format!(
            "  {}: probe-rs's RTT capture, {} bytes, is the first {} of the {} bytes the \
             firmware wrote in that boot (the rest after the capture stopped)\n",
            b.name,
            b.bytes,
            b.bytes,
            w.len()
        ));
    }
    s.push_str(&format!(
        "  the emulated board over {:.2} s: {} missed control periods, {} HardFaults, {}\n",
        r.emulated_s,
        r.missed_periods,
        r.hard_faults,
        if r.violations.is_empty() {
            "no hardware rule broken".to_string()
        } else {
            format!("rules broken: {}", r.violations.join("; "))
        }
    ));
    s
}

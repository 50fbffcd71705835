//! The core on an emulated Cortex-M4F (QEMU `netduinoplus2`, an STM32F405: same core,
//! FPU and flash/SRAM addresses as the STM32G474, so the image links with the drive's
//! own memory.x).
//!
//! `bit_exact`: hil-sim writes an input vector and the host core's trace over it; the
//! emulated image runs the same vector and prints the same trace; they must be equal.
//! `cycles`: the image runs the path configurations with markers around each
//! measured step under a one-instruction-per-block execution trace; instructions are
//! counted between the markers and weighted by Cortex-M4 cycle counts (TRM r0p1 §3.3).

use crate::{cross_build, hil_sim, output_of, root, run, TARGET};
use anyhow::{anyhow, bail, Context, Result};
use m4_cycles::{insn_cycles, is_register_save, is_single_ldst, Insn};
use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

const MACHINE: &str = "netduinoplus2";
const IMAGE: &str = "mras-qemu";
/// In measurement order: per path configuration, the front (`Front::step`, what runs in
/// the control interrupt), then the adapter (`Adapter::step`, the adaptation task).
const CONFIGS: [&str; 10] = [
    "front (control interrupt), observer only",
    "adapter (task), no paths",
    "front, observer + offset + amplitude/quadrature",
    "adapter, offset + amplitude/quadrature",
    "front, observer + offset + amplitude/quadrature + h4 + h5",
    "adapter, offset + amplitude/quadrature + h4 + h5",
    "front, default bank: observer + offset + C/D + h4..h8 (m = 1..7)",
    "adapter, default bank (7 paths)",
    "front, full bank: observer + offset + C/D + h4..h15, h-14, h-15 (m = 1..16)",
    "adapter, full bank (16 paths)",
];
/// The configuration broken down by stage unless `MRAS_CYCLES_PROFILE` says otherwise:
/// the front with the default bank, the part the control interrupt carries.
const PROFILED_DEFAULT: usize = 6;

fn dir() -> PathBuf {
    root().join("target").join("qemu")
}

/// `apt-get install` (then `apt-get update` and again) until `installed` holds.
fn apt_install(package: &str, installed: impl Fn() -> bool) -> bool {
    let install = || {
        Command::new("apt-get")
            .args(["install", "-y", "-qq", package])
            .env("DEBIAN_FRONTEND", "noninteractive")
            .status()
            .is_ok_and(|s| s.success())
    };
    (install() && installed())
        || (Command::new("apt-get")
            .args(["update", "-qq"])
            .status()
            .is_ok()
            && install()
            && installed())
}

/// Install a Debian package that provides no command (a library) when missing.
pub(crate) fn ensure_package(package: &str) -> Result<()> {
    let installed = || {
        output_of("dpkg-query", &["-W", "-f=${Status}", package])
            .is_some_and(|s| s.contains("install ok installed"))
    };
    if installed() {
        return Ok(());
    }
    eprintln!("xtask: installing {package}");
    if apt_install(package, installed) {
        Ok(())
    } else {
        Err(anyhow!(
            "`apt-get install {package}` failed: install it (root needed)"
        ))
    }
}

/// Install a Debian package when its command is missing (the machines here run as root).
pub(crate) fn ensure(command: &str, package: &str) -> Result<()> {
    let installed = || output_of("which", &[command]).is_some();
    if installed() {
        return Ok(());
    }
    eprintln!("xtask: installing {package} (provides {command})");
    if apt_install(package, installed) {
        Ok(())
    } else {
        Err(anyhow!(
            "{command} not found and `apt-get install {package}` failed: install it (root needed)"
        ))
    }
}

fn vector() -> Result<(PathBuf, PathBuf)> {
    let (v, t) = (dir().join("vector.bin"), dir().join("host-trace.txt"));
    let mut c = hil_sim(&["qemu-vector"]);
    c.arg("--vector").arg(&v).arg("--trace").arg(&t);
    run(c)?;
    Ok((v, t))
}

/// Build the image for `mode` ("trace" or "cycles") and copy it aside.
fn image(vector: &PathBuf, mode: &str) -> Result<PathBuf> {
    let mut c = cross_build(IMAGE);
    c.env("MRAS_QEMU_VECTOR", vector)
        .env("MRAS_QEMU_MODE", mode);
    run(c)?;
    let built = root()
        .join("target")
        .join(TARGET)
        .join("release")
        .join(IMAGE);
    let out = dir().join(format!("{IMAGE}-{mode}"));
    std::fs::copy(&built, &out).with_context(|| out.display().to_string())?;
    Ok(out)
}

fn qemu(image: &PathBuf) -> Command {
    let mut c = Command::new("qemu-system-arm");
    c.args([
        "-M",
        MACHINE,
        "-nographic",
        "-semihosting-config",
        "enable=on,target=native",
    ]);
    c.arg("-kernel").arg(image);
    c
}

pub fn bit_exact() -> Result<()> {
    ensure("qemu-system-arm", "qemu-system-arm")?;
    let (v, host_trace) = vector()?;
    let img = image(&v, "trace")?;
    eprintln!(
        "\n$ qemu-system-arm -M {MACHINE} ... -kernel {}",
        img.display()
    );
    let out = qemu(&img)
        .stderr(Stdio::inherit())
        .output()
        .context("qemu-system-arm")?;
    if !out.status.success() {
        bail!("the emulated image failed ({})", out.status);
    }
    let target = String::from_utf8_lossy(&out.stdout);
    let target_trace = dir().join("target-trace.txt");
    std::fs::write(&target_trace, target.as_bytes())
        .with_context(|| target_trace.display().to_string())?;
    let host =
        std::fs::read_to_string(&host_trace).with_context(|| host_trace.display().to_string())?;
    let steps = same_trace(&host, &target)?;
    eprintln!(
        "xtask qemu: {steps} steps bit-exact between the host and the emulated Cortex-M4F (θ̂, ω̂, ε, |Z|, every coefficient)"
    );
    Ok(())
}

/// The number of steps of two equal traces; an error at the first step they differ, or
/// when either is empty (two empty traces prove nothing).
fn same_trace(host: &str, target: &str) -> Result<usize> {
    let (h, t): (Vec<&str>, Vec<&str>) = (host.lines().collect(), target.lines().collect());
    if h.is_empty() || t.is_empty() {
        bail!(
            "not bit-exact: the host trace has {} steps, the emulated image's {}",
            h.len(),
            t.len()
        );
    }
    if let Some(i) = (0..h.len().max(t.len())).find(|&i| h.get(i) != t.get(i)) {
        bail!(
            "not bit-exact at step {i}:\n  host   {}\n  target {}",
            h.get(i).unwrap_or(&"<missing>"),
            t.get(i).unwrap_or(&"<missing>")
        );
    }
    Ok(h.len())
}

/// The core's cycle tables (markdown, also printed): docs/figures/cycles.md.
pub fn cycles() -> Result<String> {
    use std::fmt::Write as _;
    let mut out = String::new();
    ensure("qemu-system-arm", "qemu-system-arm")?;
    let (v, _) = vector()?;
    let img = image(&v, "cycles")?;
    let insns = m4_cycles::disassemble(&img)?;
    eprintln!(
        "\n$ qemu-system-arm -M {MACHINE} -singlestep -d exec,nochain ... (instruction trace)"
    );
    let mut child = qemu(&img)
        .args(["-singlestep", "-d", "exec,nochain"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("qemu-system-arm")?;
    let stderr = child.stderr.take().ok_or_else(|| anyhow!("no trace"))?;
    // Per measured step: (instructions, cycles); per function: cycles of all steps.
    let mut steps: Vec<(u64, u64)> = Vec::new();
    let mut by_fn: Vec<HashMap<String, u64>> = vec![HashMap::new(); CONFIGS.len()];
    // Cycles per instruction address in the last configuration, for the stage breakdown.
    let mut by_pc: HashMap<u32, (u64, String)> = HashMap::new();
    // The configuration profiled by stage.
    let profiled = std::env::var("MRAS_CYCLES_PROFILE")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|&k| k < CONFIGS.len())
        .unwrap_or(PROFILED_DEFAULT);
    let (mut counting, mut in_begin) = (false, false);
    let (mut n, mut cyc) = (0u64, 0u64);
    let mut prev: Option<(u32, String)> = None;
    let mut after_ldst = false;
    for line in BufReader::new(stderr).lines() {
        let line = line.context("qemu-system-arm trace")?;
        // "Trace 0: 0x7f.. [00800400/08002090/00000010/ff000201] mras_step_begin"
        let Some(pc) = line
            .split('/')
            .nth(1)
            .and_then(|p| u32::from_str_radix(p, 16).ok())
        else {
            continue;
        };
        let func = line.rsplit(' ').next().unwrap_or("").to_string();
        // Charge the previous instruction now that we know whether it branched.
        if let Some((ppc, pfunc)) = prev.take() {
            if let Some(i) = insns.get(&ppc) {
                let taken = pc != ppc + i.size;
                let c = insn_cycles(i, taken, after_ldst) as u64;
                after_ldst = is_single_ldst(i);
                cyc += c;
                let config = (steps.len() / STEPS_PER_CONFIG).min(CONFIGS.len() - 1);
                if config == profiled {
                    by_pc.entry(ppc).or_insert((0, pfunc.clone())).0 += c;
                }
                *by_fn[config].entry(pfunc).or_default() += c;
            } else {
                cyc += 1;
            }
        }
        match func.as_str() {
            "mras_step_begin" => in_begin = true,
            "mras_step_end" if counting => {
                steps.push((n, cyc));
                counting = false;
                (n, cyc) = (0, 0);
            }
            _ if in_begin => {
                in_begin = false;
                counting = true;
            }
            _ => {}
        }
        if counting {
            n += 1;
            prev = Some((pc, func));
        }
    }
    let status = child.wait().context("qemu-system-arm")?;
    if !status.success() || steps.len() != STEPS_PER_CONFIG * CONFIGS.len() {
        bail!(
            "instruction trace incomplete: {} of {} steps ({status})",
            steps.len(),
            STEPS_PER_CONFIG * CONFIGS.len()
        );
    }
    let _ = writeln!(
        out,
        "The core on the emulated Cortex-M4F (thumbv7em-none-eabihf, release): `Front::step`"
    );
    let _ = writeln!(
        out,
        "runs in the control interrupt, `Adapter::step` in the adaptation task below it;"
    );
    let _ = writeln!(
        out,
        "{STEPS_PER_CONFIG} steps per configuration after spin-up, adaptation running:\n"
    );
    let _ = writeln!(out, "| configuration | instructions/step (mean, max) | est. cycles/step (mean, max) | µs at 170 MHz | share of a 20 kHz period |");
    let _ = writeln!(out, "|---|---:|---:|---:|---:|");
    for (k, name) in CONFIGS.iter().enumerate() {
        let s = &steps[k * STEPS_PER_CONFIG..(k + 1) * STEPS_PER_CONFIG];
        let mean = |f: fn(&(u64, u64)) -> u64| s.iter().map(f).sum::<u64>() as f64 / s.len() as f64;
        let (im, cm) = (mean(|x| x.0), mean(|x| x.1));
        let (ix, cx) = (
            s.iter().map(|x| x.0).max().unwrap_or(0),
            s.iter().map(|x| x.1).max().unwrap_or(0),
        );
        let _ = writeln!(
            out,
            "| {name} | {im:.0}, {ix} | {cm:.0}, {cx} | {:.2} | {:.1} % |",
            cm / 170.0,
            100.0 * cm / (170e6 / 20e3)
        );
    }
    let _ = writeln!(
        out,
        "\nWhere the cycles go, {} (each executed instruction charged to the \
         innermost core stage it was inlined from, after its debug line info):\n",
        CONFIGS[profiled]
    );
    let _ = writeln!(out, "| stage | cycles/step | share |");
    let _ = writeln!(out, "|---|---:|---:|");
    let stages = stages(&img, &insns, &by_pc)?;
    // Per-address profile for whoever optimises next (a disassembly beside it).
    let mut pcs: Vec<_> = by_pc.iter().collect();
    pcs.sort_by_key(|x| *x.0);
    let profile: String = pcs
        .iter()
        .map(|(pc, (c, f))| format!("{pc:08x} {:.2} {f}\n", *c as f64 / STEPS_PER_CONFIG as f64))
        .collect();
    let profile_path = dir().join("cycles-by-address.txt");
    std::fs::write(&profile_path, profile).with_context(|| profile_path.display().to_string())?;
    let total: u64 = stages.iter().map(|x| x.1).sum();
    for (name, c) in &stages {
        let _ = writeln!(
            out,
            "| {name} | {:.0} | {:.0} % |",
            *c as f64 / STEPS_PER_CONFIG as f64,
            100.0 * *c as f64 / total.max(1) as f64
        );
    }
    eprintln!(
        "\nCycles per instruction address: {}",
        profile_path.display()
    );
    print!("{out}");
    Ok(out)
}

/// Core stages, matched against the inlined call chain of an instruction from the
/// innermost frame outwards: the first frame naming one of them gets the cycles.
const STAGES: [(&str, &str); 13] = [
    ("sin_cos", "reference vector: sin/cos"),
    (
        "update_powers",
        "powers of e^{jθ̂} (complex multiplications)",
    ),
    (
        "sqrt",
        "1/|Zd| (inline inverse square root) and other roots",
    ),
    (
        "inverse_error_transfer",
        "path update: compensation 1/H(jmNω̂)",
    ),
    ("update_path", "path update: filters, integration, clamp"),
    ("Smoothed", "smoothing of ω̂ and |Zd|"),
    ("tick", "every stride: speed gates, revolution count"),
    (
        "PathBank::step",
        "gates, block sums ε·e^{-jmθ̂} (correlation)",
    ),
    ("Injection::vector", "decoupling vector D(θ̂)"),
    (
        "ObserverState",
        "observer (Fig. 5) and its finiteness check",
    ),
    (
        "estimate_of",
        "the estimate (output record, kept and returned)",
    ),
    (
        "Front<T>::",
        "input checks and scaling, ε, cos check, hand-over, state commit",
    ),
    ("", "call, return and the rest"),
];

/// Function entry and exit: register saves and restores, charged to their own line.
const ENTRY_EXIT: &str = "function entry and exit (register saves)";

/// Sum the per-address cycles into [`STAGES`] by the inlined frames of each address (the
/// image's DWARF).
fn stages(
    image: &Path,
    insns: &HashMap<u32, Insn>,
    by_pc: &HashMap<u32, (u64, String)>,
) -> Result<Vec<(&'static str, u64)>> {
    let pcs: Vec<u32> = by_pc.keys().copied().collect();
    let chains = m4_cycles::inlined_chains(image, &pcs)?;
    let mut totals = vec![0u64; STAGES.len()];
    let mut entry_exit = 0u64;
    for (pc, (c, symbol)) in by_pc {
        let saves = insns.get(pc).is_some_and(is_register_save);
        if saves {
            entry_exit += c;
            continue;
        }
        let mut frames: Vec<String> = chains
            .get(pc)
            .map(|c| c.iter().map(|f| f.function.clone()).collect())
            .unwrap_or_default();
        frames.push(symbol.clone());
        let stage = frames
            .iter()
            .find_map(|f| {
                STAGES[..STAGES.len() - 1]
                    .iter()
                    .position(|(pat, _)| f.contains(pat))
            })
            .unwrap_or(STAGES.len() - 1);
        totals[stage] += c;
    }
    let mut out: Vec<_> = STAGES
        .iter()
        .map(|s| s.1)
        .zip(totals)
        .chain([(ENTRY_EXIT, entry_exit)])
        .filter(|x| x.1 > 0)
        .collect();
    out.sort_by_key(|x| std::cmp::Reverse(x.1));
    Ok(out)
}

/// Must match `MEASURED_STEPS` in firmware/qemu-test/src/main.rs.
const STEPS_PER_CONFIG: usize = 64;

#[cfg(test)]
mod tests {
    use super::same_trace;

    #[test]
    fn empty_or_different_traces_are_not_bit_exact() {
        assert_eq!(same_trace("a\nb\n", "a\nb\n").unwrap(), 2);
        for (h, t) in [("", ""), ("a\n", ""), ("", "a\n")] {
            let e = same_trace(h, t).unwrap_err().to_string();
            assert!(e.contains("steps"), "{e}");
        }
        let e = same_trace("a\nb\n", "a\nc\n").unwrap_err().to_string();
        assert!(e.contains("step 1"), "{e}");
        let e = same_trace("a\nb\n", "a\n").unwrap_err().to_string();
        assert!(e.contains("<missing>"), "{e}");
    }
}

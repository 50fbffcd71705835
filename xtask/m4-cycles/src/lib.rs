//! One Cortex-M4 cycle model for the project's tools (`cargo xtask cycles` on QEMU's
//! trace, `drive-emu` on the firmware in the loop): each instruction of an image's
//! disassembly weighted after the Cortex-M4 TRM (r0p1, table 3-1 and §3.3.2; table 7-1
//! for the FPU), and the inlined call chain of an address from its debug line info, to
//! sum cycles into stages. Uses the `binutils-arm-none-eabi` commands.
//!
//! MIT: the GPL emulator may depend on this crate, never the reverse.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};

/// A binutils command that could not run or failed. A leaf error: the I/O error's text
/// is part of the message, so it is not repeated as a source.
#[derive(Debug, thiserror::Error)]
pub enum ToolError {
    /// The command could not be started or talked to (not installed, broken pipe).
    #[error("{command}: {error}")]
    Run {
        command: &'static str,
        error: std::io::Error,
    },
    /// objdump refused the image.
    #[error("arm-none-eabi-objdump -d {}: {stderr}", .image.display())]
    Disassemble { image: PathBuf, stderr: String },
    /// addr2line exited with an error.
    #[error("arm-none-eabi-addr2line failed ({0})")]
    Addr2line(ExitStatus),
    #[error("addr2line: no stdin")]
    NoStdin,
    #[error("addr2line: writer panicked")]
    WriterPanicked,
}

const OBJDUMP: &str = "arm-none-eabi-objdump";
const ADDR2LINE: &str = "arm-none-eabi-addr2line";

fn run_error(command: &'static str) -> impl FnOnce(std::io::Error) -> ToolError {
    move |error| ToolError::Run { command, error }
}

/// One disassembled instruction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Insn {
    pub mnemonic: String,
    pub operands: String,
    /// Bytes (2 or 4).
    pub size: u32,
}

/// Every instruction of `image` by address (`arm-none-eabi-objdump -d`).
pub fn disassemble(image: &Path) -> Result<HashMap<u32, Insn>, ToolError> {
    let out = Command::new(OBJDUMP)
        .arg("-d")
        .arg(image)
        .output()
        .map_err(run_error(OBJDUMP))?;
    if !out.status.success() {
        return Err(ToolError::Disassemble {
            image: image.to_path_buf(),
            stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        });
    }
    Ok(parse_objdump(&String::from_utf8_lossy(&out.stdout)))
}

/// The instructions of an `objdump -d` listing by address.
pub fn parse_objdump(listing: &str) -> HashMap<u32, Insn> {
    let mut map = HashMap::new();
    for line in listing.lines() {
        // " 8002090:\tb580      \tpush\t{r7, lr}"
        let mut f = line.split('\t');
        let (Some(addr), Some(hex), Some(mn)) = (f.next(), f.next(), f.next()) else {
            continue;
        };
        let Ok(addr) = u32::from_str_radix(addr.trim().trim_end_matches(':'), 16) else {
            continue;
        };
        let size = hex.split_whitespace().map(|w| w.len() as u32 / 2).sum();
        map.insert(
            addr,
            Insn {
                mnemonic: mn.trim().to_string(),
                operands: f.next().unwrap_or("").trim().to_string(),
                size,
            },
        );
    }
    map
}

/// Registers in a `{r4, r5, lr}` / `{s16-s19}` / `{d8}` list (d counts as two words).
pub fn reg_count(ops: &str) -> u32 {
    let inner = ops
        .split('{')
        .nth(1)
        .and_then(|s| s.split('}').next())
        .unwrap_or("");
    inner
        .split(',')
        .map(|r| {
            let r = r.trim();
            let w = if r.starts_with('d') { 2 } else { 1 };
            match r.split_once('-') {
                Some((a, b)) => {
                    let n = |x: &str| {
                        x.trim_start_matches(|c: char| c.is_alphabetic())
                            .parse::<u32>()
                            .unwrap_or(0)
                    };
                    w * (n(b).saturating_sub(n(a)) + 1)
                }
                None if r.is_empty() => 0,
                None => w,
            }
        })
        .sum()
}

/// Whether `i` is a single integer load or store (the ones the M4 pipelines, TRM §3.3.2).
pub fn is_single_ldst(i: &Insn) -> bool {
    let m = i.mnemonic.as_str();
    (m.starts_with("ldr") || m.starts_with("str"))
        && !m.starts_with("ldrd")
        && !m.starts_with("strd")
}

/// Cortex-M4 cycles (TRM r0p1 table 3-1; P, the pipeline refill of a taken branch, = 2;
/// SDIV/UDIV 2-12, counted as 7). Single integer loads and stores per §3.3.2: a store
/// with an immediate offset is one cycle, a load is two unless it follows another
/// single load or store; FPU loads and stores are 2 (table 7-1, no overlap credited).
pub fn insn_cycles(i: &Insn, taken: bool, after_ldst: bool) -> u32 {
    let m = i.mnemonic.split('.').next().unwrap_or("");
    let base = m.trim_end_matches('w');
    let is_branch = matches!(base, "b" | "bl" | "bx" | "blx" | "cbz" | "cbnz")
        || (base.starts_with('b')
            && base.len() == 3
            && !base.starts_with("bi")
            && !base.starts_with("bf"));
    let refill = if taken { 2 } else { 0 };
    if is_branch {
        return 1 + refill;
    }
    if base == "tbb" || base == "tbh" {
        // Table branch: load (2), add, pipeline reload (3), §3.3.2.
        return 6;
    }
    match base {
        "push" | "stmdb" | "stm" | "stmia" => 1 + reg_count(&i.operands),
        "pop" | "ldm" | "ldmia" | "ldmdb" => {
            1 + reg_count(&i.operands) + if i.operands.contains("pc") { 2 } else { 0 }
        }
        "vpush" | "vpop" | "vldmia" | "vstmia" | "vldmdb" | "vstmdb" | "vldm" | "vstm" => {
            1 + reg_count(&i.operands)
        }
        "vldr" | "vstr" => {
            if i.operands.starts_with('d') {
                3
            } else {
                2
            }
        }
        "ldrd" | "strd" => 3,
        "vdiv" | "vsqrt" => 14,
        "vmla" | "vmls" | "vnmla" | "vnmls" | "vfma" | "vfms" | "vfnma" | "vfnms" => 3,
        "sdiv" | "udiv" => 7,
        _ if base.starts_with("str") => {
            if i.operands.contains('#') || !i.operands.contains(", r") {
                1
            } else {
                2
            }
        }
        _ if base.starts_with("ldr") => {
            if i.operands.contains("[pc") {
                // A literal load contends with instruction fetch.
                3
            } else if after_ldst {
                1
            } else {
                2
            }
        }
        "vmov" if i.operands.matches(',').count() >= 3 => 2,
        _ => 1,
    }
}

/// Whether `i` is a branch the pipeline refills after when taken (P = 2): its cost with
/// the branch taken minus not taken.
pub fn taken_refill(i: &Insn) -> u32 {
    insn_cycles(i, true, false) - insn_cycles(i, false, false)
}

/// Whether `i` saves or restores registers on the stack (function entry and exit).
pub fn is_register_save(i: &Insn) -> bool {
    matches!(i.mnemonic.as_str(), "push" | "pop" | "vpush" | "vpop")
        || (i.operands.starts_with("sp!") && i.mnemonic.starts_with("stmdb"))
        || (i.operands.starts_with("sp!") && i.mnemonic.starts_with("ldmia"))
}

/// One frame of an inlined call chain: the function and the `file:line` in it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub function: String,
    pub location: String,
}

/// The inlined call chain of each address, innermost frame first
/// (`arm-none-eabi-addr2line -a -f -i -C`; addresses on stdin, so any number fits).
pub fn inlined_chains(image: &Path, pcs: &[u32]) -> Result<HashMap<u32, Vec<Frame>>, ToolError> {
    let mut child = Command::new(ADDR2LINE)
        .arg("-e")
        .arg(image)
        .args(["-a", "-f", "-i", "-C"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .map_err(run_error(ADDR2LINE))?;
    let input: String = pcs.iter().map(|pc| format!("{pc:#x}\n")).collect();
    let mut stdin = child.stdin.take().ok_or(ToolError::NoStdin)?;
    // Written from a thread: addr2line answers as it reads, and a full stdout pipe
    // would otherwise block both sides.
    let writer = std::thread::spawn(move || stdin.write_all(input.as_bytes()));
    let out = child.wait_with_output().map_err(run_error(ADDR2LINE))?;
    writer
        .join()
        .map_err(|_| ToolError::WriterPanicked)?
        .map_err(run_error(ADDR2LINE))?;
    if !out.status.success() {
        return Err(ToolError::Addr2line(out.status));
    }
    Ok(parse_chains(&String::from_utf8_lossy(&out.stdout)))
}

/// `addr2line -a -f -i` output: an address line "0x0800048c", then (function,
/// file:line) pairs, innermost first.
pub fn parse_chains(text: &str) -> HashMap<u32, Vec<Frame>> {
    let mut chains: HashMap<u32, Vec<Frame>> = HashMap::new();
    let mut current: Option<u32> = None;
    let mut function: Option<String> = None;
    for line in text.lines() {
        if let Some(pc) = line
            .strip_prefix("0x")
            .and_then(|h| u32::from_str_radix(h, 16).ok())
        {
            current = Some(pc);
            chains.entry(pc).or_default();
            function = None;
            continue;
        }
        let Some(pc) = current else { continue };
        match function.take() {
            None => function = Some(line.to_string()),
            Some(f) => chains.entry(pc).or_default().push(Frame {
                function: f,
                location: line.to_string(),
            }),
        }
    }
    chains
}

#[cfg(test)]
mod tests {
    use super::*;

    fn insn(m: &str, ops: &str) -> Insn {
        Insn {
            mnemonic: m.into(),
            operands: ops.into(),
            size: 2,
        }
    }

    #[test]
    fn objdump_lines_parse_to_address_mnemonic_operands_size() {
        let l =
            " 8002090:\tb580      \tpush\t{r7, lr}\n 8002092:\tf8d0 1004 \tldr.w\tr1, [r0, #4]\n";
        let m = parse_objdump(l);
        assert_eq!(m[&0x0800_2090], insn("push", "{r7, lr}"));
        assert_eq!(m[&0x0800_2092].size, 4);
        assert_eq!(m[&0x0800_2092].mnemonic, "ldr.w");
    }

    #[test]
    fn register_lists_count_words() {
        assert_eq!(reg_count("{r4, r5, r6, r7, lr}"), 5);
        assert_eq!(reg_count("{s16-s19}"), 4);
        assert_eq!(reg_count("{d8-d9}"), 4);
    }

    #[test]
    fn trm_costs() {
        assert_eq!(
            insn_cycles(&insn("push", "{r4, r5, r7, lr}"), false, false),
            5
        );
        assert_eq!(insn_cycles(&insn("pop", "{r4, pc}"), true, false), 5);
        assert_eq!(insn_cycles(&insn("b.n", "8000"), true, false), 3);
        assert_eq!(insn_cycles(&insn("bne.n", "8000"), false, false), 1);
        assert_eq!(taken_refill(&insn("bl", "8000")), 2);
        assert_eq!(taken_refill(&insn("adds", "r0, #1")), 0);
        let ld = insn("ldr", "r0, [r1, #4]");
        assert_eq!(insn_cycles(&ld, false, false), 2);
        assert_eq!(insn_cycles(&ld, false, true), 1);
        assert_eq!(insn_cycles(&insn("ldr", "r0, [pc, #8]"), false, true), 3);
        assert_eq!(
            insn_cycles(&insn("vdiv.f32", "s0, s1, s2"), false, false),
            14
        );
        assert!(is_single_ldst(&ld) && !is_single_ldst(&insn("ldrd", "r0, r1, [r2]")));
    }

    #[test]
    fn addr2line_chains_keep_function_and_location_innermost_first() {
        let t = "0x08000238\ninner\n/a/firmware/app/src/adc.rs:3\nouter\n/a/main.rs:9\n0x0800023a\nonly\n??:0\n";
        let c = parse_chains(t);
        assert_eq!(c[&0x0800_0238].len(), 2);
        assert_eq!(c[&0x0800_0238][0].function, "inner");
        assert_eq!(c[&0x0800_0238][1].location, "/a/main.rs:9");
        assert_eq!(c[&0x0800_023a][0].function, "only");
    }
}

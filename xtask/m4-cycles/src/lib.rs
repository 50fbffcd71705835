//! One Cortex-M4 cycle model for the project's tools (`cargo xtask cycles` on QEMU's
//! trace, `drive-emu` on the firmware in the loop): each instruction of an image's
//! disassembly weighted after the Cortex-M4 TRM (r0p1, table 3-1 and §3.3.2; table 7-1
//! for the FPU), and the inlined call chain of an address from its debug line info, to
//! sum cycles into stages.
//!
//! The disassembly is Capstone's (Thumb-2 and FPv4-SP as an M-profile core runs them),
//! guided by the ELF's mapping symbols so that literal pools and jump tables stay data,
//! with its text in the conventions the cost model reads (binutils' register names and
//! branch targets); each instruction also says how it can change the PC ([`Flow`]), for
//! `cargo xtask isr-check`. The inlined call chains come from the ELF's DWARF (gimli's
//! `addr2line`). No external tool is run.
//!
//! MIT: the GPL emulator may depend on this crate, never the reverse.

mod disasm;
mod dwarf;

pub use disasm::{decode_thumb, Flow, Function, Image, Mapping};
pub use dwarf::{chains_of_elf, Chains};

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// An image that could not be read, disassembled or symbolised.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{}: {error}", .path.display())]
    Read {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("not an ELF file: {0}")]
    Elf(#[from] object::Error),
    #[error("Capstone (the disassembler): {0}")]
    Capstone(String),
    #[error("DWARF debug info: {0}")]
    Dwarf(#[from] addr2line::gimli::Error),
}

/// One disassembled instruction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Insn {
    /// As binutils spells it: condition and width suffixes included (`addne`, `ldr.w`).
    pub mnemonic: String,
    /// As binutils spells them: `r9` (not `sb`), `sl`, `fp`, `ip`; a branch's target as
    /// bare hex (`bl 8000244`).
    pub operands: String,
    /// Bytes (2 or 4).
    pub size: u32,
    /// The encoding: the halfword, or the first halfword above the second, as the
    /// Architecture Reference Manual writes a 32-bit Thumb instruction (`0xf8d01004`).
    pub encoding: u32,
    /// Executes under a condition: inside an IT block (other than `al`), `b<c>`, `cbz`,
    /// `cbnz`. A conditional PC write may also not happen.
    pub conditional: bool,
    /// How it can change the PC.
    pub flow: Flow,
}

fn read(image: &Path) -> Result<Vec<u8>, Error> {
    std::fs::read(image).map_err(|error| Error::Read {
        path: image.to_path_buf(),
        error,
    })
}

/// Every instruction of the code sections of the ELF file `image` by address.
pub fn disassemble(image: &Path) -> Result<HashMap<u32, Insn>, Error> {
    Ok(Image::parse(&read(image)?)?.insns.into_iter().collect())
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
    // `push.w` / `pop.w` are binutils' `stmdb sp!` / `ldmia.w sp!`.
    let base = i.mnemonic.split('.').next().unwrap_or("");
    matches!(base, "push" | "pop" | "vpush" | "vpop")
        || (i.operands.starts_with("sp!") && i.mnemonic.starts_with("stmdb"))
        || (i.operands.starts_with("sp!") && i.mnemonic.starts_with("ldmia"))
}

/// One frame of an inlined call chain: the function and the `file:line` in it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Demangled, without the hash (`drive::foc::svpwm`); `??` where the DWARF names none.
    pub function: String,
    /// `file:line`, the file as the DWARF names it; `??:?` where it has none.
    pub location: String,
}

/// The inlined call chain of each address, innermost frame first, from the DWARF of the
/// ELF file `image`.
pub fn inlined_chains(image: &Path, pcs: &[u32]) -> Result<HashMap<u32, Vec<Frame>>, Error> {
    chains_of_elf(&read(image)?, pcs)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Thumb encodings as the ARM ARM writes them (first halfword first).
    pub(crate) fn code(halfwords: &[u16]) -> Vec<u8> {
        halfwords.iter().flat_map(|h| h.to_le_bytes()).collect()
    }

    fn one(halfwords: &[u16]) -> Insn {
        let d = decode_thumb(0x0800_0000, &code(halfwords)).unwrap();
        assert_eq!(d.len(), 1, "{d:?}");
        d.into_iter().next().unwrap().1
    }

    #[test]
    fn register_lists_count_words() {
        assert_eq!(reg_count("{r4, r5, r6, r7, lr}"), 5);
        assert_eq!(reg_count("{s16-s19}"), 4);
        assert_eq!(reg_count("{d8-d9}"), 4);
        assert_eq!(reg_count("{s16, s17, s18, s19}"), 4);
    }

    /// The costs of TRM table 3-1 on instructions decoded from their encodings.
    #[test]
    fn trm_costs() {
        // push {r4, r5, r7, lr}
        let push = one(&[0xb5b0]);
        assert_eq!(
            (push.mnemonic.as_str(), push.operands.as_str()),
            ("push", "{r4, r5, r7, lr}")
        );
        assert_eq!(insn_cycles(&push, false, false), 5);
        assert!(is_register_save(&push));
        // pop {r4, pc}
        assert_eq!(insn_cycles(&one(&[0xbd10]), true, false), 5);
        // b.n (to itself), bne.n not taken, bl
        assert_eq!(insn_cycles(&one(&[0xe7fe]), true, false), 3);
        let bne = one(&[0xd1fe]);
        assert_eq!(bne.mnemonic, "bne");
        assert_eq!(insn_cycles(&bne, false, false), 1);
        assert_eq!(taken_refill(&one(&[0xf000, 0xf800])), 2);
        // adds r0, #1
        assert_eq!(taken_refill(&one(&[0x3001])), 0);
        // ldr r0, [r1, #4]: 2, 1 behind a single load or store
        let ld = one(&[0x6848]);
        assert_eq!(ld.operands, "r0, [r1, #4]");
        assert_eq!(insn_cycles(&ld, false, false), 2);
        assert_eq!(insn_cycles(&ld, false, true), 1);
        // ldr r0, [pc, #8]: a literal load
        assert_eq!(insn_cycles(&one(&[0x4802]), false, true), 3);
        // vdiv.f32 s0, s1, s2
        let vdiv = one(&[0xee80, 0x0a81]);
        assert_eq!(vdiv.mnemonic, "vdiv.f32");
        assert_eq!(insn_cycles(&vdiv, false, false), 14);
        // ldrd r0, r1, [r2]
        let ldrd = one(&[0xe9d2, 0x0100]);
        assert!(is_single_ldst(&ld) && !is_single_ldst(&ldrd));
        assert_eq!(insn_cycles(&ldrd, false, false), 3);
        // str r0, [r1, r9]: a register offset, named as binutils names r9
        let str_reg = one(&[0xf841, 0x0009]);
        assert_eq!(str_reg.operands, "r0, [r1, r9]");
        assert_eq!(insn_cycles(&str_reg, false, false), 2);
        // vpush {d8, d9}: four words
        assert_eq!(insn_cycles(&one(&[0xed2d, 0x8b04]), false, false), 5);
    }
}

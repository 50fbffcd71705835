//! The code of a Thumb ELF, decoded with Capstone where its mapping symbols say code.

use crate::{Error, Insn};
use capstone::arch::arm::{ArchExtraMode, ArchMode, ArmCC, ArmInsn, ArmInsnGroup, ArmOperandType};
use capstone::arch::{BuildsCapstone, BuildsCapstoneExtraMode, DetailsArchInsn};
use capstone::{Capstone, RegId};
use object::{Object, ObjectSection, ObjectSymbol, SectionFlags, SectionKind, SymbolKind};
use std::collections::{BTreeMap, VecDeque};
use std::ops::Range;

/// How an instruction can change the PC.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Flow {
    /// It does not write the PC: the next instruction follows.
    Next,
    /// `b`, `b<c>`, `cbz`, `cbnz` to `target`.
    Branch { target: u32 },
    /// `bl` or `blx <imm>` of `target`, then the next instruction. `to_arm`: `blx <imm>`,
    /// a switch to the Arm state, which an M-profile core faults on.
    Call { target: u32, to_arm: bool },
    /// `bx rN` (`link` false) or `blx rN`; `reg` 0..=15.
    Register { reg: u8, link: bool },
    /// `pop {.., pc}` or `ldm rN{!}, {.., pc}`: the PC loaded from memory at `base`
    /// (`pop` is `base` 13 with `writeback`, `increment_after`).
    LoadMultiple {
        base: u8,
        writeback: bool,
        increment_after: bool,
    },
    /// `ldr pc, [..]`; `pop`: `ldr pc, [sp], #4`, the one-register pop.
    Load { pop: bool },
    /// `tbb [rN, rM]` (`halfwords` false) or `tbh [rN, rM, lsl #1]`; `base` 15 (pc):
    /// the table follows the instruction.
    Table { halfwords: bool, base: u8 },
    /// Any other write to the PC (`add pc, rN`, `mov pc, rN`, ...).
    Other,
    /// `udf`: permanently undefined, a UsageFault.
    Udf,
}

/// What an ELF mapping symbol says the bytes from its address on are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mapping {
    /// `$t`: Thumb instructions.
    Thumb,
    /// `$d`: data (literal pools, jump tables).
    Data,
    /// `$a`: Arm instructions, which an M-profile core cannot execute.
    Arm,
}

/// A function of the symbol table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Function {
    /// Demangled, without the hash.
    pub name: String,
    /// Its first instruction (the symbol's Thumb bit cleared).
    pub start: u32,
    pub size: u32,
}

impl Function {
    pub fn end(&self) -> u32 {
        self.start + self.size
    }
}

/// The code of an image: its instructions, what in its code sections is data or does not
/// decode, its functions, and its loaded bytes.
#[derive(Clone, Debug, Default)]
pub struct Image {
    pub insns: BTreeMap<u32, Insn>,
    /// What the mapping symbols mark as data (`$d`, and `$a`) in the code sections.
    pub data: Vec<Range<u32>>,
    /// Each halfword of code (`$t`) from which no instruction decodes.
    pub undecodable: Vec<u32>,
    /// By start address.
    pub functions: Vec<Function>,
    /// (address, bytes) of each loaded section.
    pub memory: Vec<(u32, Vec<u8>)>,
    /// The code sections' address ranges.
    pub code: Vec<Range<u32>>,
}

/// Capstone for the Cortex-M4: Thumb-2 with the M-profile's system instructions.
fn capstone() -> Result<Capstone, Error> {
    Capstone::new()
        .arm()
        .mode(ArchMode::Thumb)
        .extra_mode([ArchExtraMode::MClass].into_iter())
        .detail(true)
        .build()
        .map_err(|e| Error::Capstone(e.to_string()))
}

fn mapping_of(name: &str) -> Option<Mapping> {
    let (kind, rest) = name.split_at_checked(2)?;
    if !(rest.is_empty() || rest.starts_with('.')) {
        return None;
    }
    match kind {
        "$t" => Some(Mapping::Thumb),
        "$d" => Some(Mapping::Data),
        "$a" => Some(Mapping::Arm),
        _ => None,
    }
}

/// A symbol's name as binutils' `-C` prints it.
pub(crate) fn demangle(name: &str) -> String {
    match rustc_demangle::try_demangle(name) {
        Ok(d) => format!("{d:#}"),
        Err(_) => name.to_string(),
    }
}

impl Image {
    /// The code sections of an ELF file, decoded as its mapping symbols say (Thumb
    /// where a section has none).
    pub fn parse(elf: &[u8]) -> Result<Image, Error> {
        let file = object::File::parse(elf)?;
        let mut mapping: Vec<(u32, Mapping)> = Vec::new();
        let mut functions = Vec::new();
        for s in file.symbols() {
            let Ok(name) = s.name() else { continue };
            if let Some(m) = mapping_of(name) {
                mapping.push((s.address() as u32, m));
            } else if s.kind() == SymbolKind::Text && s.size() > 0 {
                functions.push(Function {
                    name: demangle(name),
                    start: s.address() as u32 & !1,
                    size: s.size() as u32,
                });
            }
        }
        mapping.sort_by_key(|m| m.0);
        functions.sort_by(|a, b| (a.start, &a.name).cmp(&(b.start, &b.name)));
        let mut image = Image {
            functions,
            ..Image::default()
        };
        let cs = capstone()?;
        for s in file.sections() {
            // What is loaded (SHF_ALLOC); not debug info or the symbol table.
            let loaded = matches!(s.flags(), SectionFlags::Elf { sh_flags } if sh_flags & u64::from(object::elf::SHF_ALLOC) != 0);
            if !loaded {
                continue;
            }
            let Ok(data) = s.data() else { continue };
            let address = s.address() as u32;
            if s.kind() == SectionKind::Text {
                let end = address + data.len() as u32;
                let in_section: Vec<_> = mapping
                    .iter()
                    .copied()
                    .filter(|(a, _)| (address..end).contains(a))
                    .collect();
                image.decode_section(&cs, address, data, &in_section)?;
                image.code.push(address..end);
            }
            image.memory.push((address, data.to_vec()));
        }
        Ok(image)
    }

    /// An image of one code section at `address` (for tests and hand-made code):
    /// `mapping` as the ELF's mapping symbols (Thumb from `address` unless it says
    /// otherwise), `functions` as its symbol table.
    pub fn from_code(
        address: u32,
        code: &[u8],
        mapping: &[(u32, Mapping)],
        functions: Vec<Function>,
    ) -> Result<Image, Error> {
        let mut image = Image {
            functions,
            ..Image::default()
        };
        image.functions.sort_by_key(|f| f.start);
        image.decode_section(&capstone()?, address, code, mapping)?;
        image.code.push(address..address + code.len() as u32);
        image.memory.push((address, code.to_vec()));
        Ok(image)
    }

    fn decode_section(
        &mut self,
        cs: &Capstone,
        address: u32,
        data: &[u8],
        mapping: &[(u32, Mapping)],
    ) -> Result<(), Error> {
        let end = address + data.len() as u32;
        // Thumb up to the first mapping symbol: an M-profile core has no other state.
        let mut marks = vec![(address, Mapping::Thumb)];
        marks.extend(mapping.iter().copied());
        for (k, &(from, kind)) in marks.iter().enumerate() {
            let to = marks.get(k + 1).map_or(end, |m| m.0);
            if to <= from {
                continue;
            }
            if kind == Mapping::Thumb {
                let bytes = &data[(from - address) as usize..(to - address) as usize];
                let (insns, undecodable) = decode(cs, from, bytes)?;
                self.insns.extend(insns);
                self.undecodable.extend(undecodable);
            } else {
                self.data.push(from..to);
            }
        }
        Ok(())
    }

    /// The byte at `addr` of a loaded section.
    pub fn byte(&self, addr: u32) -> Option<u8> {
        self.memory.iter().find_map(|(start, data)| {
            let off = addr.checked_sub(*start)?;
            data.get(usize::try_from(off).ok()?).copied()
        })
    }

    /// The function whose symbol covers `addr` (the innermost start at or below it).
    pub fn function_containing(&self, addr: u32) -> Option<&Function> {
        self.functions
            .iter()
            .rev()
            .find(|f| f.start <= addr && addr < f.end())
    }

    /// The function named `name`.
    pub fn function(&self, name: &str) -> Option<&Function> {
        self.functions.iter().find(|f| f.name == name)
    }

    /// The data range (`$d`, `$a`) that holds `addr`.
    pub fn data_at(&self, addr: u32) -> Option<Range<u32>> {
        self.data.iter().find(|r| r.contains(&addr)).cloned()
    }

    /// Whether `addr` is in a code section.
    pub fn in_code(&self, addr: u32) -> bool {
        self.code.iter().any(|r| r.contains(&addr))
    }
}

/// The instructions of Thumb code at `address` by address (what does not decode is
/// left out).
pub fn decode_thumb(address: u32, code: &[u8]) -> Result<BTreeMap<u32, Insn>, Error> {
    Ok(decode(&capstone()?, address, code)?.0)
}

/// Thumb code at `address`: its instructions, and the halfwords no instruction decodes
/// from (decoding resumes at the next one).
fn decode(
    cs: &Capstone,
    address: u32,
    code: &[u8],
) -> Result<(BTreeMap<u32, Insn>, Vec<u32>), Error> {
    let mut insns = BTreeMap::new();
    let mut undecodable = Vec::new();
    // The conditions of the instructions an IT still covers (ARM ARM A7.3.3): tracked
    // here rather than taken from Capstone, which forgets them when it resumes.
    let mut it: VecDeque<u8> = VecDeque::new();
    let mut off = 0usize;
    while off + 2 <= code.len() {
        let decoded = cs
            .disasm_all(&code[off..], u64::from(address) + off as u64)
            .map_err(|e| Error::Capstone(e.to_string()))?;
        for i in decoded.iter() {
            let Some(insn) = describe(cs, i, it.front().copied())? else {
                // Not a Cortex-M4F instruction: it would fault (UsageFault).
                break;
            };
            it.pop_front();
            if i.id().0 == ArmInsn::ARM_INS_IT as u32 {
                it = it_conditions(insn.encoding);
            }
            off += i.len();
            insns.insert(i.address() as u32, insn);
        }
        if off + 2 <= code.len() {
            undecodable.push(address + off as u32);
            it.pop_front();
            off += 2;
        }
    }
    Ok((insns, undecodable))
}

/// The conditions of the (up to four) instructions an `IT` with this encoding covers.
fn it_conditions(encoding: u32) -> VecDeque<u8> {
    let firstcond = ((encoding >> 4) & 0xf) as u8;
    let mask = (encoding & 0xf) as u8;
    if mask == 0 {
        return VecDeque::new();
    }
    let count = 4 - mask.trailing_zeros() as usize;
    (0..count)
        .map(|k| {
            if k == 0 {
                firstcond
            } else {
                (firstcond & 0xe) | ((mask >> (4 - k)) & 1)
            }
        })
        .collect()
}

/// 0..=15 of a core register as Capstone names it.
fn core_reg(cs: &Capstone, reg: RegId) -> Option<u8> {
    let name = cs.reg_name(reg)?;
    Some(match name.as_str() {
        "sb" => 9,
        "sl" => 10,
        "fp" => 11,
        "ip" => 12,
        "sp" => 13,
        "lr" => 14,
        "pc" => 15,
        r => r.strip_prefix('r')?.parse().ok().filter(|n| *n < 13)?,
    })
}

/// binutils' spelling of Capstone's operand text: `r9` for `sb`.
fn binutils_operands(ops: &str) -> String {
    let mut out = String::with_capacity(ops.len());
    let mut word = String::new();
    let flush = |word: &mut String, out: &mut String| {
        out.push_str(if word == "sb" { "r9" } else { word });
        word.clear();
    };
    for c in ops.chars() {
        if c.is_ascii_alphanumeric() || c == '_' {
            word.push(c);
        } else {
            flush(&mut word, &mut out);
            out.push(c);
        }
    }
    flush(&mut word, &mut out);
    out
}

/// Capstone's instruction groups of what the Cortex-M4F (Armv7E-M, FPv4-SP) does not
/// implement: Advanced SIMD, double-precision and Armv8 floating point, Armv8, crypto,
/// CRC, the A and R profiles' Arm state, security, virtualisation and multiprocessing
/// extensions.
const NOT_ON_THE_M4F: [u32; 11] = [
    ArmInsnGroup::ARM_GRP_NEON,
    ArmInsnGroup::ARM_GRP_DPVFP,
    ArmInsnGroup::ARM_GRP_FPARMV8,
    ArmInsnGroup::ARM_GRP_V8,
    ArmInsnGroup::ARM_GRP_CRYPTO,
    ArmInsnGroup::ARM_GRP_CRC,
    ArmInsnGroup::ARM_GRP_ARM,
    ArmInsnGroup::ARM_GRP_NOTMCLASS,
    ArmInsnGroup::ARM_GRP_TRUSTZONE,
    ArmInsnGroup::ARM_GRP_VIRTUALIZATION,
    ArmInsnGroup::ARM_GRP_MULTPRO,
];

/// The instruction `i`, or `None` if the Cortex-M4F does not implement it.
fn describe(cs: &Capstone, i: &capstone::Insn, it_cond: Option<u8>) -> Result<Option<Insn>, Error> {
    let bytes = i.bytes();
    let half = |k: usize| u32::from(u16::from_le_bytes([bytes[k], bytes[k + 1]]));
    let encoding = if bytes.len() == 4 {
        half(0) << 16 | half(2)
    } else {
        half(0)
    };
    let detail = cs
        .insn_detail(i)
        .map_err(|e| Error::Capstone(e.to_string()))?;
    if detail
        .groups()
        .iter()
        .any(|g| NOT_ON_THE_M4F.contains(&u32::from(g.0)))
    {
        return Ok(None);
    }
    let arch = detail.arch_detail();
    let arm = arch
        .arm()
        .ok_or_else(|| Error::Capstone("no Arm detail".into()))?;
    let ops: Vec<_> = arm.operands().collect();
    let reg = |k: usize| match ops.get(k).map(|o| &o.op_type) {
        Some(ArmOperandType::Reg(r)) => core_reg(cs, *r),
        _ => None,
    };
    let imm = || {
        ops.iter().rev().find_map(|o| match o.op_type {
            ArmOperandType::Imm(v) => Some(v as u32),
            _ => None,
        })
    };
    let lists_pc = ops
        .iter()
        .any(|o| matches!(o.op_type, ArmOperandType::Reg(r) if core_reg(cs, r) == Some(15)));
    let writes_pc = detail
        .regs_write()
        .iter()
        .any(|r| core_reg(cs, *r) == Some(15))
        || ops.iter().any(|o| {
            matches!(o.op_type, ArmOperandType::Reg(r) if core_reg(cs, r) == Some(15))
                && o.access.is_some_and(|a| a.is_writable())
        });
    let id = i.id().0;
    let is = |insn: ArmInsn| id == insn as u32;
    let missing = |what: &str| {
        Error::Capstone(format!(
            "{what} of `{} {}` at {:#x}",
            i.mnemonic().unwrap_or("?"),
            i.op_str().unwrap_or(""),
            i.address()
        ))
    };
    // UDF T1 (0xdexx; LLVM calls 0xdefe `trap`) and T2.
    let udf = (bytes.len() == 2 && encoding & 0xff00 == 0xde00)
        || (bytes.len() == 4 && encoding & 0xfff0_f000 == 0xf7f0_a000);
    let flow = if udf {
        Flow::Udf
    } else if is(ArmInsn::ARM_INS_B) || is(ArmInsn::ARM_INS_CBZ) || is(ArmInsn::ARM_INS_CBNZ) {
        Flow::Branch {
            target: imm().ok_or_else(|| missing("no target"))?,
        }
    } else if is(ArmInsn::ARM_INS_BL) {
        Flow::Call {
            target: imm().ok_or_else(|| missing("no target"))?,
            to_arm: false,
        }
    } else if is(ArmInsn::ARM_INS_BLX) || is(ArmInsn::ARM_INS_BX) {
        match reg(0) {
            Some(reg) => Flow::Register {
                reg,
                link: is(ArmInsn::ARM_INS_BLX),
            },
            None if is(ArmInsn::ARM_INS_BLX) => Flow::Call {
                target: imm().ok_or_else(|| missing("no target"))?,
                to_arm: true,
            },
            None => Flow::Other,
        }
    } else if is(ArmInsn::ARM_INS_TBB) || is(ArmInsn::ARM_INS_TBH) {
        let base = ops.iter().find_map(|o| match &o.op_type {
            ArmOperandType::Mem(m) => core_reg(cs, m.base()),
            _ => None,
        });
        Flow::Table {
            halfwords: is(ArmInsn::ARM_INS_TBH),
            base: base.ok_or_else(|| missing("no base register"))?,
        }
    } else if is(ArmInsn::ARM_INS_POP) && lists_pc {
        Flow::LoadMultiple {
            base: 13,
            writeback: true,
            increment_after: true,
        }
    } else if (is(ArmInsn::ARM_INS_LDM) || is(ArmInsn::ARM_INS_LDMDB)) && lists_pc {
        Flow::LoadMultiple {
            base: reg(0).ok_or_else(|| missing("no base register"))?,
            writeback: arm.writeback(),
            increment_after: is(ArmInsn::ARM_INS_LDM),
        }
    } else if is(ArmInsn::ARM_INS_LDR) && reg(0) == Some(15) {
        // LDR (immediate) T4, Rn = sp, Rt = pc, post-indexed by +4 with writeback.
        Flow::Load {
            pop: encoding == 0xf85d_fb04,
        }
    } else if writes_pc {
        Flow::Other
    } else {
        Flow::Next
    };
    let in_it = it_cond.is_some_and(|c| c != 0xe);
    let cc = arm.cc();
    let conditional = in_it
        || is(ArmInsn::ARM_INS_CBZ)
        || is(ArmInsn::ARM_INS_CBNZ)
        || (is(ArmInsn::ARM_INS_B) && cc != ArmCC::ARM_CC_AL && cc != ArmCC::ARM_CC_INVALID);
    let mut mnemonic = i.mnemonic().unwrap_or("").to_string();
    let mut operands = binutils_operands(i.op_str().unwrap_or(""));
    if udf {
        // binutils: `udf #254`.
        let imm = if bytes.len() == 2 {
            encoding & 0xff
        } else {
            (encoding >> 4 & 0xf000) | (encoding & 0xfff)
        };
        mnemonic = if bytes.len() == 2 { "udf" } else { "udf.w" }.to_string();
        operands = format!("#{imm}");
    }
    if let Flow::Branch { target } | Flow::Call { target, .. } = flow {
        // binutils writes a branch's target as bare hex.
        let hash = format!("#{target:#x}");
        operands = operands.replace(&hash, &format!("{target:x}"));
    }
    Ok(Some(Insn {
        mnemonic,
        operands,
        size: i.len() as u32,
        encoding,
        conditional,
        flow,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::code;

    fn text(i: &Insn) -> String {
        format!("{} {}", i.mnemonic, i.operands)
    }

    fn at(image: &Image, a: u32) -> &Insn {
        image
            .insns
            .get(&a)
            .unwrap_or_else(|| panic!("{a:#x}: {image:?}"))
    }

    /// The PC writes of Thumb-2, each named, with the conditions an IT gives them.
    #[test]
    fn flows_and_it_conditions_come_from_the_encodings() {
        let base = 0x0800_0100;
        let c = code(&[
            0xbf18, // it ne
            0x4798, // blxne r3
            0xbf08, // it eq
            0x4770, // bxeq lr
            0x4718, // bx r3
            0x4487, // add pc, r0
            0x46f7, // mov pc, lr
            0xe890, 0x8001, // ldm.w r0, {r0, pc}
            0xe8bd, 0x8010, // pop.w {r4, pc}
            0xf85d, 0xfb04, // ldr pc, [sp], #4
            0xf8d0, 0xf004, // ldr.w pc, [r0, #4]
            0xe8df, 0xf000, // tbb [pc, r0]
            0xe8d1, 0xf010, // tbh [r1, r0, lsl #1]
            0xbf1c, // itt ne
            0xf7ff, 0xffea, // blne (to base)
            0xbd10, // popne {r4, pc}
            0xb100, // cbz r0, +4
            0xd0fe, // beq (to itself)
            0x3001, // adds r0, #1
            0xdefe, // udf #254
            0xf7f0, 0xa001, // udf.w #1
        ]);
        let image = Image::from_code(base, &c, &[], Vec::new()).unwrap();
        let flow = |a: u32| (at(&image, a).flow.clone(), at(&image, a).conditional);
        assert_eq!(at(&image, base + 2).mnemonic, "blxne");
        assert_eq!(
            flow(base + 2),
            (Flow::Register { reg: 3, link: true }, true)
        );
        assert_eq!(
            flow(base + 6),
            (
                Flow::Register {
                    reg: 14,
                    link: false
                },
                true
            )
        );
        assert_eq!(
            flow(base + 8),
            (
                Flow::Register {
                    reg: 3,
                    link: false
                },
                false
            )
        );
        assert_eq!(flow(base + 10), (Flow::Other, false));
        assert_eq!(flow(base + 12), (Flow::Other, false));
        let ldm = |base, writeback| Flow::LoadMultiple {
            base,
            writeback,
            increment_after: true,
        };
        assert_eq!(flow(base + 14), (ldm(0, false), false));
        assert_eq!(flow(base + 18), (ldm(13, true), false));
        assert_eq!(flow(base + 22), (Flow::Load { pop: true }, false));
        assert_eq!(flow(base + 26), (Flow::Load { pop: false }, false));
        let table = |halfwords, base| Flow::Table { halfwords, base };
        assert_eq!(flow(base + 30), (table(false, 15), false));
        assert_eq!(flow(base + 34), (table(true, 1), false));
        assert_eq!(at(&image, base + 40).mnemonic, "blne");
        assert_eq!(
            flow(base + 40),
            (
                Flow::Call {
                    target: base,
                    to_arm: false
                },
                true
            )
        );
        assert_eq!(at(&image, base + 44).mnemonic, "popne");
        assert_eq!(flow(base + 44), (ldm(13, true), true));
        assert_eq!(flow(base + 46), (Flow::Branch { target: base + 50 }, true));
        assert_eq!(flow(base + 48), (Flow::Branch { target: base + 48 }, true));
        assert_eq!(at(&image, base + 48).operands, format!("{:x}", base + 48));
        // Past the IT block: unconditional again.
        assert_eq!(flow(base + 50), (Flow::Next, false));
        assert_eq!(flow(base + 52), (Flow::Udf, false));
        assert_eq!(text(at(&image, base + 52)), "udf #254");
        assert_eq!(flow(base + 54), (Flow::Udf, false));
        assert_eq!(text(at(&image, base + 54)), "udf.w #1");
        assert_eq!(image.insns.len(), 21);
        assert!(image.undecodable.is_empty());
    }

    /// `$d` keeps a literal pool out of the instructions; bytes that decode to nothing
    /// are listed, and decoding resumes after them.
    #[test]
    fn mapping_symbols_keep_data_out_and_undecodable_halfwords_are_listed() {
        let base = 0x0800_0200;
        let c = code(&[
            0x4801, // ldr r0, [pc, #4]
            0x4770, // bx lr
            0xbf00, // nop (padding)
            0xbf00, // nop
            0x4770, 0x4770, // a literal that would decode as two `bx lr`
            0xffff, 0xffff, // in $t: no instruction
            0x4770, // bx lr
        ]);
        let image = Image::from_code(
            base,
            &c,
            &[(base + 8, Mapping::Data), (base + 12, Mapping::Thumb)],
            vec![Function {
                name: "f".into(),
                start: base,
                size: c.len() as u32,
            }],
        )
        .unwrap();
        assert_eq!(image.data, vec![(base + 8)..(base + 12)]);
        assert!(!image.insns.contains_key(&(base + 8)));
        assert!(!image.insns.contains_key(&(base + 10)));
        assert!(!image.undecodable.is_empty());
        assert!(image
            .undecodable
            .iter()
            .all(|a| (base + 12..base + 16).contains(a)));
        assert_eq!(at(&image, base + 16).mnemonic, "bx");
        assert_eq!(image.function_containing(base + 16).unwrap().name, "f");
        assert_eq!(image.byte(base + 8), Some(0x70));
    }

    #[test]
    fn it_masks_give_each_instruction_its_condition() {
        // it ne: one; ite eq: eq, ne; itttt hi: four hi.
        assert_eq!(it_conditions(0xbf18), [0x1]);
        assert_eq!(it_conditions(0xbf0c), [0x0, 0x1]);
        assert_eq!(it_conditions(0xbf81), [0x8, 0x8, 0x8, 0x8]);
        assert!(it_conditions(0xbf00).is_empty());
    }

    #[test]
    fn operand_text_names_registers_as_binutils_does() {
        assert_eq!(binutils_operands("r0, [sb, #4]"), "r0, [r9, #4]");
        assert_eq!(binutils_operands("{r4, sb, sl, fp}"), "{r4, r9, sl, fp}");
    }
}

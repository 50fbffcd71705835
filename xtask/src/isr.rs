//! `cargo xtask isr-check`: what the control interrupt can reach, proven on a firmware
//! ELF's disassembly, failing closed.
//!
//! From the `ADC1_2` handler (and the `USART3` one, the adaptation task the control
//! interrupt hands its samples to), every path is followed instruction by instruction
//! (`m4_cycles::Image`: Capstone's decoding, the ELF's mapping symbols and function
//! symbols): fall-through, branches in and out of a function (a tail call), calls, both
//! sides of anything conditional (`b<c>`, `cbz`, and whatever an IT block makes
//! conditional: `bleq` is a call and a fall-through, `bxne lr` a return and a
//! fall-through), and jump tables (`tbb`/`tbh [pc, ..]`, decoded from the bytes). The
//! check fails if the reachable code
//! - enters an f64 soft-float routine (`__aeabi_d*`, `__aeabi_*2d`, libgcc's `__*df*`):
//!   the Cortex-M4F's FPU is single precision, so f64 is software, hundreds of cycles a
//!   operation;
//! - enters a panic path (`core::panicking::*`, `*_fail`, `unwrap_failed`, ...) or runs
//!   an `udf`: a panic in the control interrupt leaves the bridge to whatever the panic
//!   handler does, instead of the control period's own safe state;
//! - writes the PC in any way it cannot follow: `bx rN` other than `bx lr`, `blx rN`,
//!   `ldr pc, ..` other than the one-register pop, `ldm .., {.., pc}` other than a pop,
//!   `add pc, ..`, `mov pc, ..`, a jump table it cannot decode, `blx` to the Arm state;
//! - runs into what is not code it can prove: bytes that decode to no Cortex-M4F
//!   instruction, data (`$d`: literal pools, tables), an address that is not an
//!   instruction's first byte, code outside every function symbol, the end of a function
//!   (falling through into whatever follows);
//! - branches or calls into the middle of a function (followed from the target, so that
//!   what it reaches from there is checked too).

use anyhow::{anyhow, Context, Result};
use m4_cycles::{Flow, Function, Image, Insn};
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// The control interrupt, and the adaptation task it hands every sample to (RTIC binds it
/// to USART3's vector): neither may reach f64 soft-float, a panic or an unprovable jump.
const ROOTS: [&str; 2] = ["ADC1_2", "USART3"];

/// The Thumb `nop` encoding (a jump table's padding to a word).
const THUMB_NOP: u16 = 0xbf00;

/// An f64 soft-float routine, by its (demangled) name's last segment.
fn is_f64_routine(name: &str) -> bool {
    let last = name.rsplit("::").next().unwrap_or(name);
    if let Some(rest) = last.strip_prefix("__aeabi_") {
        return rest.starts_with('d') || rest.ends_with("2d");
    }
    last.starts_with("__") && last.contains("df")
}

/// A panic path, by its demangled name.
fn is_panic_path(name: &str) -> bool {
    let last = name.rsplit("::").next().unwrap_or(name);
    name.contains("panic")
        || last.ends_with("_fail")
        || last.contains("unwrap_failed")
        || last.contains("expect_failed")
        || last.contains("assert_failed")
        || last.contains("rust_begin_unwind")
}

/// What the scan of one root found.
#[derive(Debug, Default, PartialEq)]
struct Findings {
    /// Functions with at least one reachable instruction.
    reachable_functions: usize,
    reachable_instructions: usize,
    /// Each offence, with the call chain from the root.
    problems: Vec<String>,
}

/// Where the scan entered code: the root, a call's or a tail call's target.
struct Entry {
    /// The function's name, `+0x..` when entered in its middle.
    name: String,
    /// The entry it was reached from.
    parent: Option<usize>,
}

struct Scan<'a> {
    image: &'a Image,
    entries: Vec<Entry>,
    entered: HashMap<u32, usize>,
    /// (address, entry it belongs to, the instruction that led there).
    todo: Vec<(u32, usize, Option<u32>)>,
    seen: HashSet<u32>,
    functions: HashSet<u32>,
    problems: Vec<String>,
}

fn text(i: &Insn) -> String {
    if i.operands.is_empty() {
        i.mnemonic.clone()
    } else {
        format!("{} {}", i.mnemonic, i.operands)
    }
}

impl<'a> Scan<'a> {
    /// `root -> caller -> .. -> entry`.
    fn chain(&self, mut at: usize) -> String {
        let mut names = vec![self.entries[at].name.as_str()];
        while let Some(up) = self.entries[at].parent {
            names.push(&self.entries[up].name);
            at = up;
        }
        names.reverse();
        names.join(" -> ")
    }

    fn problem(&mut self, what: String, entry: usize) {
        let chain = self.chain(entry);
        self.problems.push(format!("{what}: {chain}"));
    }

    /// `addr` reached by a call or a branch out of its function from the instruction at
    /// `site` (in `from`): checked by the name of the function it enters, then followed.
    fn enter(&mut self, addr: u32, from: usize, site: u32) {
        if self.entered.contains_key(&addr) {
            return;
        }
        let image = self.image;
        let function = image.function_containing(addr);
        let name = match function {
            Some(f) if f.start == addr => f.name.clone(),
            Some(f) => format!("{}+{:#x}", f.name, addr - f.start),
            None => format!("{addr:#x}"),
        };
        let k = self.entries.len();
        self.entries.push(Entry {
            name,
            parent: Some(from),
        });
        self.entered.insert(addr, k);
        let Some(f) = function else {
            self.problem(
                format!("branch at {site:#x} to {addr:#x}, in no function"),
                k,
            );
            return;
        };
        if is_f64_routine(&f.name) {
            self.problem("f64 soft-float".into(), k);
            return;
        }
        if is_panic_path(&f.name) {
            self.problem("panic path".into(), k);
            return;
        }
        if f.start != addr {
            self.problem(
                format!(
                    "branch at {site:#x} into the middle of `{}` ({addr:#x}), followed from there",
                    f.name
                ),
                k,
            );
        }
        self.todo.push((addr, k, Some(site)));
    }

    /// A branch from `site` in `function` to `target`: inside it, the path goes on
    /// there; elsewhere, a tail call.
    fn branch(&mut self, function: &Function, target: u32, entry: usize, site: u32) {
        if (function.start..function.end()).contains(&target) {
            self.todo.push((target, entry, Some(site)));
        } else {
            self.enter(target, entry, site);
        }
    }

    /// The targets of the jump table of `tbb [pc, rN]` / `tbh [pc, rN, lsl #1]` at
    /// `site`: entries (bytes or halfwords) right after the instruction, each a forward
    /// offset in halfwords from there; the table ends where its data (`$d`) ends or the
    /// first target begins, whichever is first, or at its padding (an entry into the table
    /// itself, or a `nop` halfword followed by zeros or pointing out of `function`: rustc
    /// pads a table to a word with a `nop`, and may place the function's literal pool
    /// between it and the first target).
    fn table_targets(
        &self,
        site: u32,
        halfwords: bool,
        function: core::ops::Range<u32>,
    ) -> Result<Vec<u32>, String> {
        let table = site + 4;
        let size = if halfwords { 2 } else { 1 };
        let mut end = self.image.data_at(table).map_or(u32::MAX, |r| r.end);
        let mut targets = Vec::new();
        let mut k = 0;
        while table + k * size < end {
            let at = table + k * size;
            let byte = |a: u32| {
                self.image
                    .byte(a)
                    .ok_or_else(|| format!("table entry at {a:#x} outside the image"))
            };
            let entry = if halfwords {
                u32::from(u16::from_le_bytes([byte(at)?, byte(at + 1)?]))
            } else {
                u32::from(byte(at)?)
            };
            let t = table + 2 * entry;
            k += 1;
            if t < table + k * size {
                // Into the table itself: no entry can (its targets follow it), so this
                // is the alignment padding after the last one.
                break;
            }
            if halfwords
                && entry == u32::from(THUMB_NOP)
                && (self.zeros(at + size, end) || !function.contains(&t))
            {
                // A `tbh` table padded with a Thumb `nop` (then zeros to the first
                // target's alignment, or literals): padding, not an entry 97 KiB on.
                break;
            }
            end = end.min(t);
            targets.push(t);
        }
        if targets.is_empty() {
            return Err("no entries".into());
        }
        Ok(targets)
    }

    /// Whether the bytes from `start` to `end` are all zero (none: true).
    fn zeros(&self, start: u32, end: u32) -> bool {
        (start..end).all(|a| self.image.byte(a) == Some(0))
    }

    /// Follow every path from the queue.
    fn run(&mut self) {
        let image = self.image;
        while let Some((addr, entry, from)) = self.todo.pop() {
            if !self.seen.insert(addr) {
                continue;
            }
            let via = from.map_or(String::new(), |s| format!(" (from {s:#x})"));
            let Some(i) = image.insns.get(&addr) else {
                let what = if let Some(r) = image.data_at(addr) {
                    format!(
                        "data reached as code at {addr:#x}{via} (data {:#x}..{:#x})",
                        r.start, r.end
                    )
                } else if image.undecodable.contains(&addr) {
                    format!("no Cortex-M4F instruction decodes at {addr:#x}{via}")
                } else if let Some((a, i)) = image.insns.range(..addr).next_back() {
                    if a + i.size > addr {
                        format!(
                            "{addr:#x}{via} is inside the instruction at {a:#x} (`{}`), not at its start",
                            text(i)
                        )
                    } else {
                        format!("{addr:#x}{via} is not code")
                    }
                } else {
                    format!("{addr:#x}{via} is not code")
                };
                self.problem(what, entry);
                continue;
            };
            let Some(function) = image.function_containing(addr) else {
                self.problem(
                    format!("`{}` at {addr:#x}{via} is in no function", text(i)),
                    entry,
                );
                continue;
            };
            self.functions.insert(function.start);
            let next = addr + i.size;
            let at = |what: &str| format!("{what} `{}` at {addr:#x}", text(i));
            // The path past this instruction, where it has one.
            let mut falls_through = i.conditional;
            match i.flow {
                Flow::Udf => self.problem(at("udf"), entry),
                Flow::Next => falls_through = true,
                Flow::Branch { target } => self.branch(function, target, entry, addr),
                Flow::Call { to_arm: true, .. } => {
                    self.problem(at("call to the Arm state"), entry);
                }
                Flow::Call { target, .. } => {
                    self.enter(target, entry, addr);
                    falls_through = true;
                }
                // Returns.
                Flow::Register {
                    reg: 14,
                    link: false,
                }
                | Flow::Load { pop: true }
                | Flow::LoadMultiple {
                    base: 13,
                    writeback: true,
                    increment_after: true,
                } => {}
                Flow::Register { .. } => self.problem(at("indirect branch"), entry),
                Flow::Load { pop: false } => self.problem(at("PC loaded from memory"), entry),
                Flow::LoadMultiple { .. } => {
                    self.problem(at("PC loaded from memory, not a pop"), entry)
                }
                Flow::Table {
                    base: 15,
                    halfwords,
                } => match self.table_targets(addr, halfwords, function.start..function.end()) {
                    Ok(targets) => {
                        for t in targets {
                            if (function.start..function.end()).contains(&t) {
                                self.todo.push((t, entry, Some(addr)));
                            } else {
                                self.problem(
                                    format!(
                                        "{}: target {t:#x} outside `{}`",
                                        at("jump table"),
                                        function.name
                                    ),
                                    entry,
                                );
                            }
                        }
                    }
                    Err(why) => {
                        self.problem(format!("{} not decoded: {why}", at("jump table")), entry)
                    }
                },
                Flow::Table { .. } => {
                    self.problem(at("jump table not at the PC"), entry);
                }
                Flow::Other => self.problem(at("PC write not followed"), entry),
            }
            if falls_through {
                if next < function.end() {
                    self.todo.push((next, entry, None));
                } else {
                    self.problem(
                        format!(
                            "{} falls through past the end of `{}` ({:#x})",
                            at("the path through"),
                            function.name,
                            function.end()
                        ),
                        entry,
                    );
                }
            }
        }
    }
}

fn scan(image: &Image, root: &str) -> Result<Findings> {
    let start = image
        .function(root)
        .ok_or_else(|| anyhow!("no function `{root}` in the symbol table"))?
        .start;
    let mut s = Scan {
        image,
        entries: vec![Entry {
            name: root.to_string(),
            parent: None,
        }],
        entered: HashMap::from([(start, 0)]),
        todo: vec![(start, 0, None)],
        seen: HashSet::new(),
        functions: HashSet::new(),
        problems: Vec::new(),
    };
    s.run();
    let mut problems = s.problems;
    problems.sort();
    problems.dedup();
    Ok(Findings {
        reachable_functions: s.functions.len(),
        reachable_instructions: s
            .seen
            .iter()
            .filter(|a| image.insns.contains_key(a))
            .count(),
        problems,
    })
}

/// Scan the firmware ELF `elf`; error (listing every problem) if any.
pub fn check(elf: &Path) -> Result<()> {
    let name = elf.display().to_string();
    let data = std::fs::read(elf).with_context(|| format!("{name} (build the firmware first)"))?;
    let image = Image::parse(&data).with_context(|| name.clone())?;
    let mut failed = 0;
    for root in ROOTS {
        let f = scan(&image, root).with_context(|| name.clone())?;
        eprintln!(
            "isr-check {name}: {root} reaches {} functions, {} instructions",
            f.reachable_functions, f.reachable_instructions
        );
        for p in &f.problems {
            eprintln!("isr-check: {p}");
        }
        failed += f.problems.len();
    }
    if failed == 0 {
        eprintln!(
            "isr-check {name}: no f64 soft-float routine, no panic path, every PC write followed"
        );
        Ok(())
    } else {
        Err(anyhow!(
            "{name}: the control interrupt or the adaptation task reaches {failed} forbidden routine(s), unprovable jump(s) or non-code"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use m4_cycles::Mapping;

    /// One Thumb instruction of a hand-assembled test program.
    #[derive(Clone, Copy)]
    enum I {
        /// A 16-bit encoding.
        H(u16),
        /// A 32-bit encoding (first halfword first).
        W(u16, u16),
        /// `bl <target>`
        Bl(u32),
        /// `b.w <target>`
        Bw(u32),
        /// `b<cond>.n <target>`
        Bc(u8, u32),
    }
    use I::*;

    /// The halfwords of BL (`link`) or B.W (T4) at `pc` to `target` (ARM ARM A7.7.12,
    /// A7.7.18): S, J1, J2, imm10, imm11 of the offset from `pc + 4`.
    fn branch_t4(pc: u32, target: u32, link: bool) -> [u16; 2] {
        let off = target.wrapping_sub(pc + 4) as i32;
        assert!((-(1 << 24)..(1 << 24)).contains(&off) && off % 2 == 0);
        let s = u16::from(off < 0);
        let i1 = ((off >> 23) & 1) as u16;
        let i2 = ((off >> 22) & 1) as u16;
        let (j1, j2) = ((i1 ^ 1) ^ s, (i2 ^ 1) ^ s);
        let imm10 = ((off >> 12) & 0x3ff) as u16;
        let imm11 = ((off >> 1) & 0x7ff) as u16;
        let second = if link { 0xd000 } else { 0x9000 };
        [
            0xf000 | s << 10 | imm10,
            second | j1 << 13 | j2 << 11 | imm11,
        ]
    }

    fn assemble(start: u32, body: &[I]) -> Vec<u16> {
        let mut out = Vec::new();
        for i in body {
            let pc = start + 2 * out.len() as u32;
            match *i {
                H(h) => out.push(h),
                W(a, b) => out.extend([a, b]),
                Bl(t) => out.extend(branch_t4(pc, t, true)),
                Bw(t) => out.extend(branch_t4(pc, t, false)),
                Bc(cond, t) => {
                    let off = t.wrapping_sub(pc + 4) as i32 / 2;
                    assert!((-128..128).contains(&off));
                    out.push(0xd000 | u16::from(cond) << 8 | (off as u16 & 0xff));
                }
            }
        }
        out
    }

    const BASE: u32 = 0x0800_0000;
    /// Each function at its own 0x100 bytes; the gaps hold `udf`.
    fn at(k: u32) -> u32 {
        BASE + 0x100 * k
    }

    /// An image of `functions` (name, slot, body) with `data` (from, to) marked `$d`.
    fn image(functions: &[(&str, u32, Vec<I>)], data: &[(u32, u32)]) -> Image {
        let slots = functions.iter().map(|f| f.1).max().unwrap() + 1;
        let mut halfwords = vec![0xde00u16; (0x80 * slots) as usize];
        let mut symbols = Vec::new();
        for (name, slot, body) in functions {
            let code = assemble(at(*slot), body);
            let from = (0x80 * slot) as usize;
            halfwords[from..from + code.len()].copy_from_slice(&code);
            symbols.push(Function {
                name: name.to_string(),
                start: at(*slot),
                size: 2 * code.len() as u32,
            });
        }
        let mut mapping = Vec::new();
        for &(from, to) in data {
            mapping.extend([(from, Mapping::Data), (to, Mapping::Thumb)]);
        }
        let bytes: Vec<u8> = halfwords.iter().flat_map(|h| h.to_le_bytes()).collect();
        Image::from_code(BASE, &bytes, &mapping, symbols).unwrap()
    }

    const PUSH: I = H(0xb580); // push {r7, lr}
    const POP: I = H(0xbd80); // pop {r7, pc}
    const BX_LR: I = H(0x4770);
    const NOP: I = H(THUMB_NOP);
    const CMP: I = H(0x2800); // cmp r0, #0
    const EQ: u8 = 0;
    const NE: u8 = 1;

    /// The root calls a helper that tail-calls into f64 addition, and a safe
    /// single-precision routine; a conditional branch skips a `cbz`-guarded call of a
    /// checked routine that panics; one function is unreachable.
    #[test]
    fn follows_calls_and_tail_calls_and_names_the_chain() {
        let p = image(
            &[
                (
                    "ADC1_2",
                    0,
                    vec![
                        PUSH,
                        Bl(at(1)),
                        Bl(at(2)),
                        CMP,
                        Bc(EQ, at(0) + 20),
                        H(0xb108), // cbz r0, +6 (to the pop)
                        Bl(at(3)),
                        POP,
                    ],
                ),
                ("helper", 1, vec![W(0xee00, 0x0a10), Bw(at(4))]), // vmov s0, r0
                ("__aeabi_fmul", 2, vec![W(0xee20, 0x0a20), BX_LR]), // vmul.f32 s0, s0, s1
                ("checked", 3, vec![PUSH, Bl(at(5)), POP]),
                ("compiler_builtins::float::add::__adddf3", 4, vec![BX_LR]),
                ("core::panicking::panic_bounds_check", 5, vec![H(0xdefe)]),
                ("unreachable_udf", 6, vec![H(0xdefe)]),
            ],
            &[],
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            [
                "f64 soft-float: ADC1_2 -> helper -> compiler_builtins::float::add::__adddf3",
                "panic path: ADC1_2 -> checked -> core::panicking::panic_bounds_check",
            ]
        );
        // ADC1_2, helper, fmul, checked: the f64 and panic routines are named, not run.
        assert_eq!(f.reachable_functions, 4);
        assert_eq!(f.reachable_instructions, 8 + 2 + 2 + 3);
    }

    /// `it ne; blxne r3` in a routine the handler calls: a conditional call through a
    /// register is indirect whatever the condition.
    #[test]
    fn a_conditional_indirect_call_in_an_it_block_fails_naming_it() {
        let p = image(
            &[
                ("ADC1_2", 0, vec![PUSH, Bl(at(1)), POP]),
                (
                    "dispatch",
                    1,
                    vec![CMP, H(0xbf18), H(0x4798), BX_LR], // it ne; blxne r3
                ),
            ],
            &[],
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            ["indirect branch `blxne r3` at 0x8000104: ADC1_2 -> dispatch"]
        );
        // Both sides of the IT: the not-taken path reaches the return.
        assert_eq!(f.reachable_instructions, 3 + 4);
    }

    /// Conditional calls and returns in IT blocks are followed on both sides.
    #[test]
    fn conditional_calls_and_returns_are_followed_both_ways() {
        let p = image(
            &[
                (
                    "ADC1_2",
                    0,
                    vec![
                        PUSH,
                        CMP,
                        H(0xbf08), // it eq
                        Bl(at(1)), // bleq __aeabi_dmul
                        H(0xbf18), // it ne
                        H(0xbd80), // popne {r7, pc}
                        H(0xbf08), // it eq
                        H(0x4770), // bxeq lr
                        Bl(at(2)), // after both conditional returns
                        POP,
                    ],
                ),
                ("__aeabi_dmul", 1, vec![BX_LR]),
                ("core::option::unwrap_failed", 2, vec![H(0xdefe)]),
            ],
            &[],
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            [
                "f64 soft-float: ADC1_2 -> __aeabi_dmul",
                "panic path: ADC1_2 -> core::option::unwrap_failed",
            ]
        );
    }

    /// Every PC write that is not a branch, call, return or PC-relative table is an
    /// error naming the instruction, whether or not it is conditional.
    #[test]
    fn pc_writes_it_cannot_follow_are_errors() {
        for (body, named) in [
            (vec![H(0x4487)], "PC write not followed `add pc, r0`"),
            (vec![H(0x46f7)], "PC write not followed `mov pc, lr`"),
            (
                vec![W(0xe890, 0x8001)],
                "PC loaded from memory, not a pop `ldm.w r0, {r0, pc}`",
            ),
            (
                vec![W(0xf8d0, 0xf004)],
                "PC loaded from memory `ldr.w pc, [r0, #4]`",
            ),
            (
                vec![CMP, H(0xbf18), H(0x4718), BX_LR],
                "indirect branch `bxne r3`",
            ),
            (
                vec![W(0xe8d1, 0xf010)],
                "jump table not at the PC `tbh [r1, r0, lsl #1]`",
            ),
            (vec![H(0xdefe)], "udf `udf #254`"),
        ] {
            let p = image(&[("ADC1_2", 0, body)], &[]);
            let f = scan(&p, "ADC1_2").unwrap();
            assert_eq!(f.problems.len(), 1, "{named}: {:?}", f.problems);
            assert!(
                f.problems[0].starts_with(named),
                "{named}: {:?}",
                f.problems
            );
        }
    }

    /// A branch into data, into the middle of an instruction, out of the code, or a path
    /// that runs off its function's end: each an error.
    #[test]
    fn what_is_not_code_is_an_error() {
        // ADC1_2: beq into the literal pool, bne into the second halfword of the
        // `ldr.w`.
        let p = image(
            &[(
                "ADC1_2",
                0,
                vec![
                    CMP,
                    Bc(EQ, at(0) + 12),
                    Bc(NE, at(0) + 8),
                    W(0xf8d0, 0x0004), // ldr.w r0, [r0, #4]
                    BX_LR,
                    H(0x1234),
                    H(0x5678),
                    BX_LR,
                ],
            )],
            &[(at(0) + 12, at(0) + 16)],
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            [
                "0x8000008 (from 0x8000004) is inside the instruction at 0x8000006 (`ldr.w r0, [r0, #4]`), not at its start: ADC1_2",
                "data reached as code at 0x800000c (from 0x8000002) (data 0x800000c..0x8000010): ADC1_2",
            ]
        );
        // Falling off the end into the next function; an undecodable halfword.
        let p = image(
            &[
                (
                    "ADC1_2",
                    0,
                    vec![CMP, Bc(EQ, at(0) + 8), NOP, H(0xffff), H(0xffff)],
                ),
                ("next", 1, vec![BX_LR]),
            ],
            &[],
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(f.problems.len(), 2, "{:?}", f.problems);
        assert!(f.problems[0].starts_with("no Cortex-M4F instruction decodes at 0x8000006"));
        assert!(f.problems[1].starts_with("no Cortex-M4F instruction decodes at 0x8000008"));
        let p = image(&[("ADC1_2", 0, vec![NOP]), ("next", 1, vec![BX_LR])], &[]);
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            ["the path through `nop` at 0x8000000 falls through past the end of `ADC1_2` (0x8000002): ADC1_2"]
        );
    }

    /// A call into the middle of a function is an error, and what it reaches from its
    /// target (not from the function's entry) is checked.
    #[test]
    fn a_mid_function_entry_is_an_error_and_followed_from_the_target() {
        let p = image(
            &[
                ("ADC1_2", 0, vec![PUSH, Bl(at(1) + 6), POP]),
                (
                    "two_ways",
                    1,
                    vec![PUSH, Bl(at(2)), Bl(at(3)), POP], // entered at the second call
                ),
                ("core::panicking::panic", 2, vec![H(0xdefe)]),
                ("__aeabi_ddiv", 3, vec![BX_LR]),
            ],
            &[],
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            [
                "branch at 0x8000002 into the middle of `two_ways` (0x8000106), followed from there: ADC1_2 -> two_ways+0x6",
                "f64 soft-float: ADC1_2 -> two_ways+0x6 -> __aeabi_ddiv",
            ]
        );
    }

    /// `tbh [pc, r0, lsl #1]` with `entries` entries, then the halfwords `padding`, then
    /// the one target (which calls `a`): the scan follows one table to one target.
    fn padded_tbh_is_one_table(entries: u16, padding: &[u16]) {
        let skip = entries + padding.len() as u16;
        let mut body = vec![W(0xe8df, 0xf010)];
        body.extend((0..entries).map(|_| H(skip)));
        body.extend(padding.iter().map(|&h| H(h)));
        body.extend([Bl(at(1)), BX_LR]);
        let table = [(at(0) + 4, at(0) + 4 + 2 * u32::from(skip))];
        let p = image(&[("ADC1_2", 0, body), ("a", 1, vec![BX_LR])], &table);
        let f = scan(&p, "ADC1_2").unwrap();
        assert!(f.problems.is_empty(), "{:?}", f.problems);
        assert_eq!(f.reachable_instructions, 3 + 1);
    }

    /// A `tbh` table of an odd count of entries, padded to a word with a `nop` right
    /// before its first target (as rustc lays one out): the `nop` is padding, not an
    /// entry far beyond the function.
    #[test]
    fn a_tbh_tables_nop_padding_is_not_an_entry() {
        padded_tbh_is_one_table(1, &[THUMB_NOP]);
    }

    /// A `tbh` table padded with a `nop` and zeros to its first target's word (rustc's
    /// layout of a table of four entries ahead of a word-aligned target): padding too.
    #[test]
    fn a_tbh_tables_nop_and_zero_padding_is_not_an_entry() {
        padded_tbh_is_one_table(4, &[THUMB_NOP, 0, 0]);
    }

    /// A `tbh` table padded with a `nop`, then literals (a constant pool rustc placed
    /// between the table and its first target, here -2π): the `nop` is padding, the
    /// literals are not entries.
    #[test]
    fn a_tbh_tables_nop_before_literals_is_not_an_entry() {
        padded_tbh_is_one_table(4, &[THUMB_NOP, 0x0fdb, 0xc0c9]);
    }

    /// A `tbb` table: its entries are followed, the table bytes are data; an entry out
    /// of the function is an error.
    #[test]
    fn jump_tables_are_followed() {
        // tbb [pc, r0]; the table (2, 5) and its padding; targets +8 and +14.
        let body = |second: u8| {
            vec![
                W(0xe8df, 0xf000),
                H(u16::from_le_bytes([2, second])),
                H(0x0000),
                Bl(at(1)),
                BX_LR,
                Bl(at(2)),
                BX_LR,
            ]
        };
        let table = [(at(0) + 4, at(0) + 8)];
        let p = image(
            &[
                ("ADC1_2", 0, body(5)),
                ("a", 1, vec![BX_LR]),
                ("__aeabi_dmul", 2, vec![BX_LR]),
            ],
            &table,
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(f.problems, ["f64 soft-float: ADC1_2 -> __aeabi_dmul"]);
        assert_eq!(f.reachable_instructions, 5 + 1);
        // An entry far beyond the function.
        let p = image(
            &[
                ("ADC1_2", 0, body(0x7f)),
                ("a", 1, vec![BX_LR]),
                ("__aeabi_dmul", 2, vec![BX_LR]),
            ],
            &table,
        );
        let f = scan(&p, "ADC1_2").unwrap();
        assert!(
            f.problems.iter().any(|p| p.starts_with(
                "jump table `tbb [pc, r0]` at 0x8000000: target 0x8000102 outside `ADC1_2`"
            )),
            "{:?}",
            f.problems
        );
    }

    #[test]
    fn f64_and_panic_names() {
        for n in [
            "__aeabi_dadd",
            "__aeabi_dcmpge",
            "__aeabi_f2d",
            "__aeabi_i2d",
            "__aeabi_ul2d",
            "__muldf3",
            "__extendsfdf2",
            "__truncdfsf2",
            "compiler_builtins::float::conv::__floatsidf",
        ] {
            assert!(is_f64_routine(n), "{n}");
        }
        for n in [
            "__aeabi_fmul",
            "__aeabi_uidivmod",
            "__aeabi_l2f",
            "__addsf3",
            "__udivmoddi4",
            "__aeabi_memcpy",
            "mras_vsqrt_f32",
        ] {
            assert!(!is_f64_routine(n), "{n}");
        }
        assert!(is_panic_path("core::slice::index::slice_index_fail"));
        assert!(is_panic_path("core::option::unwrap_failed"));
        assert!(!is_panic_path("drive::control::ControlPeriod<T>::step"));
    }

    /// A relocatable ARM ELF as the linker's output looks to the check: `.text` at 0,
    /// Thumb function symbols (bit 0 set, Rust-mangled where Rust's are), mapping
    /// symbols around a literal pool. `dispatch` is the body of the routine the handler
    /// calls.
    fn elf(dispatch: &[I]) -> Vec<u8> {
        use object::write::{Object, Symbol, SymbolSection};
        use object::{
            Architecture, BinaryFormat, Endianness, SymbolFlags, SymbolKind, SymbolScope,
        };
        // ADC1_2 at 0: push; bl dispatch; ldr r0, [pc, #4] (the pool at 12); pop; nop;
        // the pool word. USART3 at 0x10, the dispatch routine at 0x20.
        let mut code = assemble(0, &[PUSH, Bl(0x20), H(0x4801), POP, NOP]);
        code.extend([0x5678, 0x1234]);
        code.extend(assemble(0x10, &[BX_LR]));
        code.resize(0x10, 0xde00);
        code.extend(assemble(0x20, dispatch));
        let bytes: Vec<u8> = code.iter().flat_map(|h| h.to_le_bytes()).collect();
        let mut o = Object::new(BinaryFormat::Elf, Architecture::Arm, Endianness::Little);
        let text = o.add_section(Vec::new(), b".text".to_vec(), object::SectionKind::Text);
        o.append_section_data(text, &bytes, 4);
        let mut symbol = |name: &str, value: u64, size: u64, kind| {
            o.add_symbol(Symbol {
                name: name.as_bytes().to_vec(),
                value,
                size,
                kind,
                scope: if kind == SymbolKind::Text {
                    SymbolScope::Linkage
                } else {
                    SymbolScope::Compilation
                },
                weak: false,
                section: SymbolSection::Section(text),
                flags: SymbolFlags::None,
            });
        };
        symbol("ADC1_2", 1, 0x10, SymbolKind::Text);
        symbol("USART3", 0x11, 2, SymbolKind::Text);
        symbol(
            "_ZN5drive8dispatch17h0123456789abcdefE",
            0x21,
            2 * dispatch.len() as u64,
            SymbolKind::Text,
        );
        symbol("$t", 0, 0, SymbolKind::Label);
        symbol("$d", 0xc, 0, SymbolKind::Label);
        symbol("$t", 0x10, 0, SymbolKind::Label);
        o.write().unwrap()
    }

    /// `blxne r3` on an ELF file: the check reads the symbols and the mapping
    /// symbols and fails naming `blxne r3`; without it, the same file passes.
    #[test]
    fn check_fails_on_an_elf_whose_handler_reaches_blxne_r3() {
        let dir = std::env::temp_dir();
        let good = dir.join(format!("isr-check-good-{}.elf", std::process::id()));
        let bad = dir.join(format!("isr-check-blxne-{}.elf", std::process::id()));
        std::fs::write(&good, elf(&[CMP, H(0xbf18), H(0x4608), BX_LR])).unwrap(); // movne r0, r1
        let blxne = elf(&[CMP, H(0xbf18), H(0x4798), BX_LR]);
        std::fs::write(&bad, &blxne).unwrap();
        let (ok, failed) = (check(&good), check(&bad));
        let _ = (std::fs::remove_file(&good), std::fs::remove_file(&bad));
        ok.unwrap();
        let e = failed.unwrap_err().to_string();
        assert!(e.contains("reaches 1 forbidden"), "{e}");
        let image = Image::parse(&blxne).unwrap();
        assert_eq!(image.data, vec![0xc..0x10]);
        let f = scan(&image, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            ["indirect branch `blxne r3` at 0x24: ADC1_2 -> drive::dispatch"]
        );
        assert_eq!(
            (f.reachable_functions, f.reachable_instructions),
            (2, 4 + 4)
        );
    }

    #[test]
    fn a_missing_root_is_an_error() {
        let p = image(&[("ADC1_2", 0, vec![BX_LR])], &[]);
        assert!(scan(&p, "TIM1_UP").is_err());
    }
}

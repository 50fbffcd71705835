//! `cargo xtask isr-check`: what the control interrupt can reach, proven on the release
//! ELF's disassembly.
//!
//! From the `ADC1_2` handler (and the `USART3` one, the adaptation task the control
//! interrupt hands its samples to), every direct call (`bl`, `blx <imm>`) and every branch that
//! leaves the current function (a tail call: `b`, `b<cond>`, `cbz`, `cbnz`) is followed,
//! transitively. The check fails if the reachable code
//! - calls an f64 soft-float routine (`__aeabi_d*`, `__aeabi_*2d`, libgcc's `__*df*`):
//!   the Cortex-M4F's FPU is single precision, so f64 is software, hundreds of cycles a
//!   operation;
//! - reaches a panic path (`core::panicking::*`, `*_fail`, `unwrap_failed`, ...) or an
//!   `udf`: a panic in the control interrupt leaves the bridge to whatever the panic
//!   handler does, instead of the control period's own safe state;
//! - jumps or calls through a register out of its function (`blx rN`, `bx rN` other than
//!   `bx lr`, `mov pc, rN`, `ldr pc, ...` other than a pop): what it reaches cannot be
//!   proven here.

use crate::{output_of, root, TARGET};
use anyhow::{anyhow, Context, Result};
use std::collections::{BTreeMap, HashMap, VecDeque};

/// The control interrupt, and the adaptation task it hands every sample to (RTIC binds it
/// to USART3's vector): neither may reach f64 soft-float, a panic or an indirect call.
const ROOTS: [&str; 2] = ["ADC1_2", "USART3"];

/// One instruction of the disassembly.
#[derive(Clone, Debug, PartialEq)]
struct Insn {
    addr: u64,
    mnemonic: String,
    operands: String,
}

/// Functions (by name, in address order of their start) and their instructions, and
/// the loaded bytes (for jump tables).
#[derive(Debug, Default)]
struct Program {
    functions: BTreeMap<u64, (String, Vec<Insn>)>,
    /// (address, bytes) of each loaded section.
    memory: Vec<(u64, Vec<u8>)>,
}

impl Program {
    /// From `objdump -d --no-show-raw-insn -C` text.
    fn parse(text: &str) -> Self {
        let mut functions = BTreeMap::new();
        let mut current: Option<(u64, String, Vec<Insn>)> = None;
        for line in text.lines() {
            if let Some((addr, name)) = function_header(line) {
                if let Some((a, n, body)) = current.take() {
                    functions.insert(a, (n, body));
                }
                current = Some((addr, name.to_string(), Vec::new()));
            } else if let (Some(i), Some(f)) = (instruction(line), current.as_mut()) {
                f.2.push(i);
            }
        }
        if let Some((a, n, body)) = current {
            functions.insert(a, (n, body));
        }
        Self {
            functions,
            memory: Vec::new(),
        }
    }

    fn byte(&self, addr: u64) -> Option<u8> {
        self.memory.iter().find_map(|(start, data)| {
            let off = addr.checked_sub(*start)?;
            data.get(usize::try_from(off).ok()?).copied()
        })
    }

    /// The targets of the jump table of `tbb [pc, rN]` / `tbh [pc, rN, lsl #1]` at
    /// `i`: entries (bytes or halfwords) right after the instruction, each a forward
    /// offset in halfwords from there; the table ends where the first target begins.
    fn table_targets(&self, i: &Insn) -> Option<Vec<u64>> {
        if !i.operands.starts_with("[pc,") {
            return None;
        }
        let half = base(&i.mnemonic) == "tbh";
        let table = i.addr + 4;
        let size = if half { 2 } else { 1 };
        let mut end = u64::MAX;
        let mut targets = Vec::new();
        let mut k = 0;
        while table + k * size < end && k < 4096 {
            let at = table + k * size;
            let entry = if half {
                u16::from_le_bytes([self.byte(at)?, self.byte(at + 1)?]) as u64
            } else {
                self.byte(at)? as u64
            };
            let t = table + 2 * entry;
            k += 1;
            if t < table + k * size {
                // Into the table itself: alignment padding after the last entry.
                break;
            }
            end = end.min(t);
            targets.push(t);
        }
        Some(targets)
    }

    fn by_name(&self, name: &str) -> Option<u64> {
        self.functions
            .iter()
            .find(|(_, (n, _))| n == name)
            .map(|(a, _)| *a)
    }

    /// The function containing `addr`.
    fn containing(&self, addr: u64) -> Option<u64> {
        let (&start, (_, body)) = self.functions.range(..=addr).next_back()?;
        let end = body.last().map_or(start, |i| i.addr);
        (addr <= end).then_some(start)
    }
}

/// `08000238 <ADC1_2>:` → (0x08000238, "ADC1_2").
fn function_header(line: &str) -> Option<(u64, &str)> {
    let (addr, rest) = line.split_once(' ')?;
    let name = rest.strip_prefix('<')?.strip_suffix(">:")?;
    Some((u64::from_str_radix(addr, 16).ok()?, name))
}

/// ` 8000238:\tpush\t{r4, lr}` → the instruction.
fn instruction(line: &str) -> Option<Insn> {
    let (addr, rest) = line.trim_start().split_once(":\t")?;
    let addr = u64::from_str_radix(addr, 16).ok()?;
    let mut parts = rest.splitn(2, '\t');
    let mnemonic = parts.next()?.trim().to_string();
    if mnemonic.is_empty() || mnemonic.starts_with('.') {
        return None;
    }
    let operands = parts.next().unwrap_or("").trim().to_string();
    Some(Insn {
        addr,
        mnemonic,
        operands,
    })
}

/// A direct branch's target address (`bl 800d940 <...>`, `cbz r0, 8000a10 <...>`).
fn direct_target(i: &Insn) -> Option<u64> {
    let m = i.mnemonic.trim_end_matches(".w").trim_end_matches(".n");
    let is_branch = m == "bl"
        || m == "blx"
        || m == "b"
        || m == "cbz"
        || m == "cbnz"
        || (m.len() == 3 && m.starts_with('b') && is_condition(&m[1..]));
    if !is_branch {
        return None;
    }
    let ops = i.operands.split('<').next().unwrap_or("");
    let target = ops.rsplit([' ', ',']).find(|s| !s.is_empty())?;
    u64::from_str_radix(target.trim(), 16).ok()
}

fn is_condition(c: &str) -> bool {
    [
        "eq", "ne", "cs", "cc", "hs", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt",
        "le",
    ]
    .contains(&c)
}

/// How an instruction ends or continues the path through its function.
#[derive(Debug, PartialEq)]
enum Flow {
    /// Falls through to the next instruction.
    Next,
    /// Return: the path ends.
    Return,
    /// Unconditional branch to `target` (in or out of the function).
    Jump(u64),
    /// Conditional branch to `target`, or fall through.
    Branch(u64),
    /// Call of `target`, then fall through.
    Call(u64),
    /// Through a register out of the function: unprovable.
    Indirect,
    /// A jump table (`tbb`, `tbh`): its targets are data.
    Table,
    Udf,
}

fn base(mnemonic: &str) -> &str {
    mnemonic.trim_end_matches(".w").trim_end_matches(".n")
}

fn flow(i: &Insn) -> Flow {
    let m = base(&i.mnemonic);
    let ops = i.operands.as_str();
    let pops_pc = ops.contains("pc}");
    match m {
        "udf" => Flow::Udf,
        "tbb" | "tbh" => Flow::Table,
        "bx" if ops == "lr" => Flow::Return,
        "bx" => Flow::Indirect,
        "pop" if pops_pc => Flow::Return,
        "ldmia" | "ldm" if ops.starts_with("sp!") && pops_pc => Flow::Return,
        "ldr" if ops.starts_with("pc, [sp]") => Flow::Return,
        "ldr" | "mov" if ops.starts_with("pc,") => Flow::Indirect,
        "blx" if !ops.starts_with(|c: char| c.is_ascii_hexdigit()) => Flow::Indirect,
        _ => match (direct_target(i), m) {
            (Some(t), "bl" | "blx") => Flow::Call(t),
            (Some(t), "b") => Flow::Jump(t),
            (Some(t), _) => Flow::Branch(t),
            (None, _) => Flow::Next,
        },
    }
}

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

/// What the scan found.
#[derive(Debug, Default, PartialEq)]
struct Findings {
    reachable_functions: usize,
    reachable_instructions: usize,
    /// Offending (function or instruction) with the call chain from the root.
    problems: Vec<String>,
}

fn scan(p: &Program, root_name: &str) -> Result<Findings> {
    let root_addr = p
        .by_name(root_name)
        .ok_or_else(|| anyhow!("no function `{root_name}` in the disassembly"))?;
    let mut parent: HashMap<u64, Option<u64>> = HashMap::from([(root_addr, None)]);
    let mut queue = VecDeque::from([root_addr]);
    let mut f = Findings::default();
    let chain = |parent: &HashMap<u64, Option<u64>>, mut at: u64| {
        let mut names = Vec::new();
        loop {
            names.push(
                p.functions
                    .get(&at)
                    .map_or("?", |(n, _)| n.as_str())
                    .to_string(),
            );
            match parent.get(&at).copied().flatten() {
                Some(up) => at = up,
                None => break,
            }
        }
        names.reverse();
        names.join(" -> ")
    };
    while let Some(start) = queue.pop_front() {
        let Some((name, body)) = p.functions.get(&start) else {
            continue;
        };
        f.reachable_functions += 1;
        if is_f64_routine(name) {
            f.problems
                .push(format!("f64 soft-float: {}", chain(&parent, start)));
            continue;
        }
        if is_panic_path(name) {
            f.problems
                .push(format!("panic path: {}", chain(&parent, start)));
            continue;
        }
        // The function's own control flow from its entry: padding and literal pools
        // after its last return are data, not code.
        let index: HashMap<u64, usize> =
            body.iter().enumerate().map(|(k, i)| (i.addr, k)).collect();
        let mut seen = vec![false; body.len()];
        let mut todo = vec![0usize];
        let mut enter =
            |callee: u64, at: &Insn, f: &mut Findings, parent: &mut HashMap<u64, Option<u64>>| {
                match p.containing(callee) {
                    Some(c) if c != start => {
                        if let std::collections::hash_map::Entry::Vacant(e) = parent.entry(c) {
                            e.insert(Some(start));
                            queue.push_back(c);
                        }
                    }
                    Some(_) => {}
                    None => f.problems.push(format!(
                        "branch to {callee:#x} outside any function at {:#x}: {}",
                        at.addr,
                        chain(parent, start)
                    )),
                }
            };
        while let Some(k) = todo.pop() {
            let mut k = k;
            while let Some(i) = body.get(k) {
                if std::mem::replace(&mut seen[k], true) {
                    break;
                }
                f.reachable_instructions += 1;
                let local = |t: u64| index.get(&t).copied();
                match flow(i) {
                    Flow::Next => k += 1,
                    Flow::Return => break,
                    Flow::Udf => {
                        f.problems
                            .push(format!("udf at {:#x}: {}", i.addr, chain(&parent, start)));
                        break;
                    }
                    Flow::Indirect => {
                        f.problems.push(format!(
                            "indirect `{} {}` at {:#x}: {}",
                            i.mnemonic,
                            i.operands,
                            i.addr,
                            chain(&parent, start)
                        ));
                        break;
                    }
                    Flow::Table => {
                        match p.table_targets(i) {
                            Some(ts) if ts.iter().all(|t| local(*t).is_some()) => {
                                todo.extend(ts.iter().filter_map(|t| local(*t)));
                            }
                            _ => f.problems.push(format!(
                                "jump table `{} {}` at {:#x} not decoded: {}",
                                i.mnemonic,
                                i.operands,
                                i.addr,
                                chain(&parent, start)
                            )),
                        }
                        break;
                    }
                    Flow::Call(t) => {
                        enter(t, i, &mut f, &mut parent);
                        k += 1;
                    }
                    Flow::Jump(t) => match local(t) {
                        Some(j) => k = j,
                        None => {
                            enter(t, i, &mut f, &mut parent);
                            break;
                        }
                    },
                    Flow::Branch(t) => {
                        match local(t) {
                            Some(j) => todo.push(j),
                            None => enter(t, i, &mut f, &mut parent),
                        }
                        k += 1;
                    }
                }
            }
        }
    }
    f.problems.sort();
    Ok(f)
}

/// (address, bytes) of the ELF's sections that hold code or data.
fn loaded_sections(elf: &[u8]) -> Result<Vec<(u64, Vec<u8>)>> {
    use object::{Object, ObjectSection};
    let file = object::File::parse(elf)?;
    Ok(file
        .sections()
        .filter(|s| s.address() != 0)
        .filter_map(|s| Some((s.address(), s.data().ok()?.to_vec())))
        .collect())
}

/// Scan the release firmware; error (listing every problem) if any.
pub fn check() -> Result<()> {
    crate::qemu::ensure("arm-none-eabi-objdump", "binutils-arm-none-eabi")?;
    let elf = root()
        .join("target")
        .join(TARGET)
        .join("release")
        .join(crate::FIRMWARE);
    let elf = elf.to_string_lossy().into_owned();
    let text = output_of(
        "arm-none-eabi-objdump",
        &["-d", "--no-show-raw-insn", "-C", &elf],
    )
    .ok_or_else(|| anyhow!("arm-none-eabi-objdump -d {elf} failed (build the firmware first)"))?;
    let data = std::fs::read(&elf).with_context(|| elf.clone())?;
    let mut program = Program::parse(&text);
    program.memory = loaded_sections(&data).with_context(|| elf.clone())?;
    let mut failed = 0;
    for root in ROOTS {
        let f = scan(&program, root)?;
        if f.problems.is_empty() {
            eprintln!(
                "isr-check: {root} reaches {} functions, {} instructions: no f64 soft-float routine, no panic path, no indirect call",
                f.reachable_functions, f.reachable_instructions
            );
        } else {
            for p in &f.problems {
                eprintln!("isr-check: {p}");
            }
            failed += f.problems.len();
        }
    }
    if failed == 0 {
        Ok(())
    } else {
        Err(anyhow!(
            "the control interrupt or the adaptation task reaches {failed} forbidden routine(s) or unprovable jump(s)"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small program: the root calls a helper that tail-calls into f64 addition, and
    /// calls a safe single-precision routine; another helper panics; one is unreachable.
    const TEXT: &str = "
08000100 <ADC1_2>:
 8000100:\tpush\t{r7, lr}
 8000102:\tbl\t8000200 <helper>
 8000106:\tbl\t8000300 <__aeabi_fmul>
 800010a:\tbeq.w\t8000110 <ADC1_2+0x10>
 800010e:\tcbz\tr0, 8000400 <checked>
 8000110:\tpop\t{r7, pc}

08000200 <helper>:
 8000200:\tvmov\ts0, r0
 8000204:\tb.w\t8000500 <compiler_builtins::float::add::__adddf3>

08000300 <__aeabi_fmul>:
 8000300:\tvmul.f32\ts0, s0, s1
 8000304:\tbx\tlr

08000400 <checked>:
 8000400:\tbl\t8000600 <core::panicking::panic_bounds_check>
 8000404:\tbx\tlr

08000500 <compiler_builtins::float::add::__adddf3>:
 8000500:\tbx\tlr

08000600 <core::panicking::panic_bounds_check>:
 8000600:\tudf\t#254

08000700 <unreachable_udf>:
 8000700:\tudf\t#254
";

    #[test]
    fn follows_calls_and_tail_calls_and_names_the_chain() {
        let f = scan(&Program::parse(TEXT), "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            [
                "f64 soft-float: ADC1_2 -> helper -> compiler_builtins::float::add::__adddf3",
                "panic path: ADC1_2 -> checked -> core::panicking::panic_bounds_check",
            ]
        );
        // ADC1_2, helper, fmul, checked, adddf3, panic: not the unreachable one.
        assert_eq!(f.reachable_functions, 6);
    }

    /// Indirect calls and reachable `udf`s are problems; what follows a return or an
    /// unconditional branch is not code unless something branches to it (padding,
    /// literal pools).
    #[test]
    fn indirect_calls_and_udf_are_problems_and_returns_end_a_path() {
        let text = "
08000100 <ADC1_2>:
 8000100:\tpush\t{r4, lr}
 8000102:\tcbz\tr0, 800010a <ADC1_2+0xa>
 8000104:\tcmp\tr1, #0
 8000106:\tbeq.n\t800010e <ADC1_2+0xe>
 8000108:\tblx\tr3
 800010a:\tudf\t#0
 800010c:\tudf\t#1
 800010e:\tpop\t{r4, pc}
 8000110:\tudf\t#2
 8000112:\tbmi.n\t8000200 <panic>
 8000114:\tb.n\t8000118 <ADC1_2+0x18>
 8000116:\tudf\t#3
 8000118:\tbx\tlr

08000200 <panic>:
 8000200:\tudf\t#254
";
        let f = scan(&Program::parse(text), "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            [
                "indirect `blx r3` at 0x8000108: ADC1_2",
                "udf at 0x800010a: ADC1_2"
            ],
        );
        assert_eq!(f.reachable_functions, 1);
        // Neither the padding after the return nor the dead branch to `panic`.
        assert_eq!(f.reachable_instructions, 7);
    }

    /// A `tbb` table: its entries are followed, the table bytes are not code.
    #[test]
    fn jump_tables_are_followed() {
        let text = "
08000100 <ADC1_2>:
 8000100:\ttbb\t[pc, r0]
 8000104:\tmovs\tr0, r0
 8000106:\tudf\t#7
 8000108:\tbl\t8000200 <a>
 800010c:\tbx\tlr
 800010e:\tbl\t8000300 <__aeabi_dmul>
 8000112:\tbx\tlr

08000200 <a>:
 8000200:\tbx\tlr

08000300 <__aeabi_dmul>:
 8000300:\tbx\tlr
";
        let mut p = Program::parse(text);
        // Two entries (bytes 2 and 5): targets 0x8000108 and 0x800010e; the table
        // (0x8000104..0x8000106) and its padding up to the first target are data.
        p.memory = vec![(0x0800_0104, vec![2, 5, 0, 0])];
        let f = scan(&p, "ADC1_2").unwrap();
        assert_eq!(
            f.problems,
            ["f64 soft-float: ADC1_2 -> __aeabi_dmul"],
            "{:?}",
            f.problems
        );
        let mut undecoded = Program::parse(text);
        undecoded.memory.clear();
        let f = scan(&undecoded, "ADC1_2").unwrap();
        assert!(f.problems[0].contains("not decoded"), "{:?}", f.problems);
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

    #[test]
    fn a_missing_root_is_an_error() {
        assert!(scan(&Program::parse(TEXT), "TIM1_UP").is_err());
    }
}

//! Estimated Cortex-M4 cycles of what the emulated CPU executes, and the control
//! interrupt's stages. One cycle model with `cargo xtask cycles`: each instruction of
//! the ELF's disassembly is weighted by `m4_cycles::insn_cycles` (TRM r0p1 table 3-1),
//! once per ELF; a translated block's cost is the sum over its instructions (with the
//! single-load pipelining inside the block), and the taken-branch refill of a block's
//! last instruction is charged when the next block does not start where it ends.
//!
//! Stages: each address is attributed once, by its inlined call chain (the ELF's DWARF,
//! `m4_cycles::chains_of_elf`); at run time a shadow call stack gives out-of-line
//! callees (`fmaxf`, `mras_vsqrt_f32`, `memclr`) the stage of their call site.

use anyhow::{anyhow, Context, Result};
use m4_cycles::{Frame, Insn};
use object::{Object, ObjectSymbol};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Exception entry and return of the Cortex-M4 with zero wait-state memory (TRM r0p1
/// §3.3.1 "interrupt latency": 12 cycles in, 10 cycles out, frame push and pop
/// included).
pub const ENTRY_CYCLES: u64 = 12;
pub const EXIT_CYCLES: u64 = 10;
/// An FP frame (the FPU is on) with lazy stacking (FPCCR.LSPEN = 1, the reset value the
/// firmware keeps): entry only reserves S0-S15 and FPSCR, the handler's first FP
/// instruction stacks them and the return restores them. The control interrupt always
/// executes FP instructions, so we charge the 17 words both ways (one cycle per word,
/// as a multiple transfer).
pub const LAZY_FP_WORDS: u64 = 17;

/// The control interrupt's handler symbol (RTIC binds the task to the vector's name).
pub const HANDLER: &str = "ADC1_2";

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    AdcRead,
    Scaling,
    Core,
    CurrentLoop,
    Svpwm,
    PwmWrite,
    Telemetry,
    Rest,
    EntryExit,
}

pub const STAGE_COUNT: usize = 9;

impl Stage {
    pub const ALL: [Stage; STAGE_COUNT] = [
        Stage::AdcRead,
        Stage::Scaling,
        Stage::Core,
        Stage::CurrentLoop,
        Stage::Svpwm,
        Stage::PwmWrite,
        Stage::Telemetry,
        Stage::Rest,
        Stage::EntryExit,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Stage::AdcRead => "ADC read (app adc.rs)",
            Stage::Scaling => "scaling (drive::adc)",
            Stage::Core => "core (mras)",
            Stage::CurrentLoop => "current loop (Clarke, Park, PI, inverse Park)",
            Stage::Svpwm => "SVPWM (drive::foc::svpwm)",
            Stage::PwmWrite => "PWM write (app pwm.rs)",
            Stage::Telemetry => "telemetry (snapshot, publish, cycle stats)",
            Stage::Rest => "rest: motion loops, supervisor countdown, latch, RTIC",
            Stage::EntryExit => "entry/exit (push/pop, exception entry and return)",
        }
    }

    /// The stage of code whose static chain says `self`, run from a call site of stage
    /// `caller`: telemetry wins along the whole (static and dynamic) chain, then the
    /// core, then the innermost named stage.
    pub fn under(self, caller: Option<Stage>) -> Stage {
        let Some(c) = caller else { return self };
        if c == Stage::Telemetry || self == Stage::Telemetry {
            Stage::Telemetry
        } else if c == Stage::Core || self == Stage::Core {
            Stage::Core
        } else if self == Stage::Rest {
            c
        } else {
            self
        }
    }
}

fn is_telemetry(f: &Frame) -> bool {
    let n = f.function.as_str();
    (n.contains("ControlPeriod") && n.contains("::snapshot"))
        || n.contains("TelemetrySlot")
        || n.contains("CycleStats")
}

fn is_core(f: &Frame) -> bool {
    let n = f.function.as_str();
    n.starts_with("mras::")
        || n.contains("<mras::")
        || n.starts_with("mras_")
        || f.location.contains("firmware/mras/")
}

fn named_stage(f: &Frame) -> Option<Stage> {
    let n = f.function.as_str();
    if n.contains("drive::foc::svpwm") {
        Some(Stage::Svpwm)
    } else if ["CurrentLoop", "clarke", "::park", "inverse_park"]
        .iter()
        .any(|p| n.contains("drive::foc::") && n.contains(p))
    {
        Some(Stage::CurrentLoop)
    } else if f.location.contains("app/src/adc.rs") {
        Some(Stage::AdcRead)
    } else if n.starts_with("drive::adc::") || f.location.contains("drive/src/adc.rs") {
        Some(Stage::Scaling)
    } else if f.location.contains("app/src/pwm.rs") {
        Some(Stage::PwmWrite)
    } else {
        None
    }
}

/// The stage of an address from its inlined chain (innermost first): telemetry anywhere
/// on the chain, else the core anywhere, else the innermost frame naming a stage.
pub fn classify(chain: &[Frame]) -> Stage {
    if chain.iter().any(is_telemetry) {
        Stage::Telemetry
    } else if chain.iter().any(is_core) {
        Stage::Core
    } else {
        chain.iter().find_map(named_stage).unwrap_or(Stage::Rest)
    }
}

/// One instruction's cost.
#[derive(Clone, Copy, Debug)]
struct Cost {
    size: u32,
    /// Cycles when not pipelined behind a single load/store.
    cycles: u32,
    /// What pipelining behind a single load or store saves (TRM §3.3.2).
    pipelined_credit: u32,
    single_ldst: bool,
    /// The pipeline refill when it branches (P = 2), else 0.
    refill: u32,
    call: bool,
    stage: Stage,
}

/// A translated block's cost, computed once per (address, size).
#[derive(Clone, Copy, Debug, Default)]
pub struct BlockCost {
    pub instrs: u32,
    pub cycles: u32,
    pub end: u32,
    /// Cycles saved when the previous block falls through into this one after a single
    /// load or store and this one starts with a single load.
    pub first_credit: u32,
    pub first_stage: Option<Stage>,
    pub last_single_ldst: bool,
    pub last_refill: u32,
    pub last_stage: Option<Stage>,
    pub last_is_call: bool,
    /// (instructions, cycles) per stage of the static chain.
    pub by_stage: [(u32, u32); STAGE_COUNT],
}

/// The per-address costs and stages of one firmware ELF.
pub struct Profile {
    costs: HashMap<u32, Cost>,
}

fn elf_key(elf: &[u8]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    elf.hash(&mut h);
    h.finish()
}

impl Profile {
    /// The profile of `elf`, computed once per process and ELF (the tests build many
    /// boards of the same firmware).
    pub fn for_elf(elf: &[u8]) -> Result<Arc<Profile>> {
        static CACHE: OnceLock<Mutex<HashMap<u64, Arc<Profile>>>> = OnceLock::new();
        let key = elf_key(elf);
        let cache = CACHE.get_or_init(Default::default);
        if let Some(p) = cache
            .lock()
            .map_err(|_| anyhow!("profile cache"))?
            .get(&key)
        {
            return Ok(p.clone());
        }
        let p = Arc::new(Self::compute(elf)?);
        cache
            .lock()
            .map_err(|_| anyhow!("profile cache"))?
            .insert(key, p.clone());
        Ok(p)
    }

    fn compute(elf: &[u8]) -> Result<Profile> {
        let file = object::File::parse(elf).context("not an ELF file")?;
        let handler = file
            .symbols()
            .find(|s| s.name() == Ok(HANDLER))
            .map(|s| (s.address() as u32 & !1)..(s.address() + s.size()) as u32);
        let insns: HashMap<u32, Insn> = m4_cycles::Image::parse(elf)
            .context("disassembling the firmware ELF")?
            .insns
            .into_iter()
            .collect();
        let pcs: Vec<u32> = insns.keys().copied().collect();
        let chains = m4_cycles::chains_of_elf(elf, &pcs).context("the firmware ELF's DWARF")?;
        Ok(Self::from_parts(&insns, &chains, handler))
    }

    /// The profile of a disassembly, its inlined chains and the control interrupt
    /// handler's address range (its register saves are entry/exit).
    pub fn from_parts(
        insns: &HashMap<u32, Insn>,
        chains: &HashMap<u32, Vec<Frame>>,
        handler: Option<std::ops::Range<u32>>,
    ) -> Profile {
        let mut costs = HashMap::with_capacity(insns.len());
        for (&pc, i) in insns {
            let in_handler = handler.as_ref().is_some_and(|h| h.contains(&pc));
            let stage = if in_handler && m4_cycles::is_register_save(i) {
                Stage::EntryExit
            } else {
                chains.get(&pc).map_or(Stage::Rest, |c| classify(c))
            };
            let cycles = m4_cycles::insn_cycles(i, false, false);
            let base = i.mnemonic.split('.').next().unwrap_or("");
            costs.insert(
                pc,
                Cost {
                    size: i.size.max(2),
                    cycles,
                    pipelined_credit: cycles - m4_cycles::insn_cycles(i, false, true),
                    single_ldst: m4_cycles::is_single_ldst(i),
                    refill: m4_cycles::taken_refill(i),
                    call: base == "bl" || base == "blx",
                    stage,
                },
            );
        }
        Profile { costs }
    }

    /// The cost of the block at `addr` of `size` bytes. Addresses the disassembly does
    /// not know (code in RAM) cost one cycle per halfword pair, as an instruction.
    pub fn block(&self, addr: u32, size: u32) -> BlockCost {
        let mut b = BlockCost {
            end: addr + size,
            ..BlockCost::default()
        };
        let mut a = addr;
        let mut after_ldst = false;
        let mut first = true;
        while a < b.end || first {
            let c = self.costs.get(&a).copied().unwrap_or(Cost {
                size: 2,
                cycles: 1,
                pipelined_credit: 0,
                single_ldst: false,
                refill: 0,
                call: false,
                stage: Stage::Rest,
            });
            let cycles = c.cycles - if after_ldst { c.pipelined_credit } else { 0 };
            if first {
                b.first_credit = c.pipelined_credit;
                b.first_stage = Some(c.stage);
                first = false;
            }
            b.instrs += 1;
            b.cycles += cycles;
            let s = &mut b.by_stage[c.stage as usize];
            s.0 += 1;
            s.1 += cycles;
            b.last_single_ldst = c.single_ldst;
            b.last_refill = c.refill;
            b.last_stage = Some(c.stage);
            b.last_is_call = c.call;
            after_ldst = c.single_ldst;
            a += c.size;
        }
        b
    }

    /// The stage of the instruction at `pc`.
    pub fn stage(&self, pc: u32) -> Option<Stage> {
        self.costs.get(&pc).map(|c| c.stage)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(function: &str, location: &str) -> Frame {
        Frame {
            function: function.into(),
            location: location.into(),
        }
    }

    #[test]
    fn telemetry_wins_over_core_and_core_over_the_rest() {
        let c = [
            frame(
                "mras::tracker::Tracker<T>::estimate_of",
                "/w/firmware/mras/src/tracker.rs:9",
            ),
            frame(
                "drive::control::ControlPeriod<T>::snapshot",
                "/w/firmware/drive/src/control.rs:1",
            ),
            frame("ADC1_2", "/w/firmware/app/src/main.rs:35"),
        ];
        assert_eq!(classify(&c), Stage::Telemetry);
        assert_eq!(classify(&[c[0].clone(), c[2].clone()]), Stage::Core);
        let svpwm = [
            frame("drive::foc::svpwm", "/w/firmware/drive/src/foc.rs:3"),
            frame(
                "drive::foc::CurrentLoop::step",
                "/w/firmware/drive/src/foc.rs:9",
            ),
        ];
        assert_eq!(classify(&svpwm), Stage::Svpwm);
        assert_eq!(classify(&svpwm[1..]), Stage::CurrentLoop);
        let read = [
            frame(
                "stm32g4::generic::Reg<REG>::read",
                "/r/stm32g4/src/generic.rs:1",
            ),
            frame(
                "drive_fw::adc::Adcs::read",
                "/w/firmware/app/src/adc.rs:120",
            ),
        ];
        assert_eq!(classify(&read), Stage::AdcRead);
        assert_eq!(
            classify(&[frame(
                "drive::adc::scale_pair",
                "/w/firmware/drive/src/adc.rs:1"
            )]),
            Stage::Scaling
        );
        assert_eq!(
            classify(&[frame(
                "drive::motion::Loop::step",
                "/w/firmware/drive/src/motion.rs:1"
            )]),
            Stage::Rest
        );
    }

    #[test]
    fn a_block_sums_its_instructions_with_pipelined_loads_and_keeps_the_refill_for_later() {
        // push {r7, lr}; ldr r0, [r1, #0]; ldr r1, [r2, #0]; bl 0x8000244
        let code: Vec<u8> = [0xb580u16, 0x6808, 0x6811, 0xf000, 0xf801]
            .iter()
            .flat_map(|h| h.to_le_bytes())
            .collect();
        let insns: HashMap<u32, Insn> = m4_cycles::decode_thumb(0x0800_0238, &code)
            .unwrap()
            .into_iter()
            .collect();
        assert_eq!(insns.len(), 4);
        let mut chains = HashMap::new();
        for pc in [0x0800_023a, 0x0800_023c] {
            chains.insert(
                pc,
                vec![frame(
                    "drive_fw::adc::Adcs::read",
                    "/w/firmware/app/src/adc.rs:1",
                )],
            );
        }
        let p = Profile::from_parts(&insns, &chains, Some(0x0800_0238..0x0800_0244));
        let b = p.block(0x0800_0238, 10);
        // push {r7, lr} 3, ldr 2, ldr after a load 1, bl 1 (its refill comes with the
        // next block, when it is known to have branched).
        assert_eq!((b.instrs, b.cycles), (4, 7));
        assert_eq!(b.by_stage[Stage::EntryExit as usize], (1, 3));
        assert_eq!(b.by_stage[Stage::AdcRead as usize], (2, 3));
        assert_eq!(b.by_stage[Stage::Rest as usize], (1, 1));
        assert!(b.last_is_call && b.last_refill == 2 && b.end == 0x0800_0242);
        // Entered at the second load: not pipelined within the block, but it can be
        // after a fall-through.
        let b = p.block(0x0800_023c, 2);
        assert_eq!((b.cycles, b.first_credit), (2, 1));
    }

    #[test]
    fn callees_take_the_call_site_stage_unless_their_own_chain_outranks_it() {
        assert_eq!(
            Stage::Rest.under(Some(Stage::CurrentLoop)),
            Stage::CurrentLoop
        );
        assert_eq!(Stage::Core.under(Some(Stage::Telemetry)), Stage::Telemetry);
        assert_eq!(Stage::Svpwm.under(Some(Stage::Core)), Stage::Core);
        assert_eq!(Stage::Scaling.under(Some(Stage::Rest)), Stage::Scaling);
        assert_eq!(Stage::Rest.under(None), Stage::Rest);
    }
}

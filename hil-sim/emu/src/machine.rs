//! The emulated STM32G474: Unicorn executes the Thumb-2 code; everything else is here:
//! the memory map, the Cortex-M4 exception model (ARMv7-M ARM B1.5), resets, the
//! private peripheral bus, the peripheral models and the plant they drive.
//!
//! Time is counted in 170 MHz ticks: each executed instruction costs one cycle of the
//! current system clock (no wait states, no multi-cycle instructions: the time base is
//! instruction counts). Estimated Cortex-M4 cycles (`profile`) are counted beside it
//! for the reports. Peripheral events (timer edges, ADC conversions, flash
//! operations, the watchdog) stop the CPU at the next block boundary.

use crate::board::Board;
use crate::nvic::{self, Nvic};
use crate::periph::adc::{self, Adcs};
use crate::periph::flash::{self, FlashCtl};
use crate::periph::misc::{self, Cordic, Iwdg};
use crate::periph::rcc::{self, Rcc, ResetKind};
use crate::periph::tim1::{self, Edge, Tim1};
use crate::periph::{ticks, TICK_HZ};
use crate::profile::{BlockCost, Profile, Stage};
use crate::regfile::RegFile;
use crate::rtt::Rtt;
use crate::stats::{Break, MissCause, Missed, Stats};
use hil_sim::plant_truth::PeriodTruth;
use std::collections::{BTreeMap, HashMap};
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::Arc;

/// The block-cost cache's hasher: one multiply per (address, size) key. The lookup runs
/// once per executed block, where SipHash cost a visible share of the emulation.
#[derive(Default)]
pub struct BlockKeyHasher(u64);

impl Hasher for BlockKeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }

    fn write_u64(&mut self, k: u64) {
        // Fibonacci hashing (Knuth): the high bits are well mixed.
        self.0 = (self.0 ^ k)
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .rotate_left(32);
    }
}

pub const SRAM: u32 = 0x2000_0000;
pub const SRAM_BYTES: u32 = 128 * 1024;
/// System memory (bootloader, FLASH_SIZE and the other device data).
pub const SYSMEM: u32 = 0x1FFF_0000;
pub const SYSMEM_BYTES: u32 = 0x8000;
/// The peripheral regions the models answer (base, bytes): APB/AHB1, AHB2 GPIO, AHB2
/// ADC; the CPU and a probe's bus both reach them through `mmio_read`/`mmio_write`.
pub const PERIPHERALS: [(u32, u32); 3] = [
    (0x4000_0000, 0x4_0000),
    (0x4800_0000, 0x2000),
    (0x5000_0000, 0x1000),
];
/// The control interrupt: ADC1_2 is IRQ 18 (RM0440 §16.3 table 97).
pub const ADC1_2_IRQ: u16 = 18;
/// The adaptation task: RTIC binds it to USART3's vector, IRQ 39 (RM0440 §16.3 table
/// 97), which no peripheral raises here; the control interrupt pends it.
pub const USART3_IRQ: u16 = 39;

/// Why the CPU must leave Unicorn at the next block boundary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// Read, write or fetch outside the memory map (BusFault → HardFault).
    Bus(u32),
    /// An undefined instruction (UsageFault → HardFault).
    Undefined(u32),
    /// A floating-point instruction with CP10/CP11 off in CPACR (UsageFault NOCP).
    NoCoprocessor(u32),
}

/// A bus access to something the models do not know or a clock that is off.
#[derive(Clone, Debug, Default)]
pub struct Unmodelled {
    /// Accesses to a peripheral whose RCC enable bit was off: ignored, as on silicon.
    pub gated: BTreeMap<&'static str, u64>,
    /// Registers the PAC does not describe, by address.
    pub unknown: BTreeMap<u32, u64>,
    /// Private peripheral bus registers no model knows (stored and read back as plain
    /// memory), by address.
    pub unknown_ppb: BTreeMap<u32, u64>,
    /// Flash bank swap (SYSCFG_MEMRMP.FB_MODE) set at some time: not modelled.
    pub bank_swap: u64,
}

/// Private peripheral bus registers the firmware may use that need no behaviour here:
/// SysTick (B3.3: CSR, RVR, CVR, CALIB; the firmware does not start it), the MPU's
/// (B3.5; no region is enabled) and the FPU's FPCAR (B3.2.23, written by lazy stacking
/// only). Stored and read back.
const PPB_PLAIN_KNOWN: &[(u32, u32)] = &[
    (0xE000_E010, 0xE000_E01C),
    (0xE000_ED90, 0xE000_EDB8),
    (0xE000_EF38, 0xE000_EF3C),
];

pub struct Machine {
    pub regs: RegFile,
    pub nvic: Nvic,
    pub rcc: Rcc,
    pub adcs: Adcs,
    pub tim1: Tim1,
    pub flash_ctl: FlashCtl,
    pub cordic: Cordic,
    pub iwdg: Iwdg,
    /// The flash array (kept over resets and between boots).
    pub flash: Vec<u8>,
    /// Time (170 MHz ticks) and executed instructions.
    pub now: u64,
    pub instrs: u64,
    /// Estimated Cortex-M4 cycles executed (instructions when there is no profile).
    pub cycles: u64,
    /// The firmware's per-address costs and stages (None: cycles = instructions).
    pub profile: Option<Arc<Profile>>,
    pub block_costs: HashMap<u64, BlockCost, BuildHasherDefault<BlockKeyHasher>>,
    /// The block executed last (for the taken-branch refill), None after an exception
    /// entry or return (whose cost covers the refill).
    pub prev_block: Option<BlockCost>,
    /// The stage the previous block's last instruction was charged to.
    pub prev_stage: Option<Stage>,
    /// Inside the control interrupt: (return address, stage of the call site) of the
    /// out-of-line calls under way, so that callees take their caller's stage.
    pub call_stack: Vec<(u32, Stage)>,
    /// Leave Unicorn when `now` reaches this.
    pub deadline: u64,
    pub stop: bool,
    /// The next block is the first of a slice: it runs whatever the deadline says.
    pub first_block: bool,
    pub idle: bool,
    pub fault: Option<Fault>,
    pub exc_return: Option<u32>,
    pub reset_request: Option<ResetKind>,
    /// The CPU does not execute until then (a flash erase of the code's bank).
    pub stall_until: u64,
    /// Core lockup: a fault in the HardFault or NMI handler (B1.5.15).
    pub lockup: bool,
    // Private peripheral bus.
    pub cpacr: u32,
    pub vtor: u32,
    pub shcsr: u32,
    pub cfsr: u32,
    pub hfsr: u32,
    pub scr: u32,
    pub ccr: u32,
    pub fpccr: u32,
    pub demcr: u32,
    pub dwt_ctrl: u32,
    /// CYCCNT = instrs - base while enabled.
    pub cyccnt_base: u64,
    pub cyccnt_frozen: u32,
    pub ppb_plain: BTreeMap<u32, u32>,
    // The drive.
    pub board: Board,
    pub rtt: Rtt,
    pub stats: Stats,
    pub unmodelled: Unmodelled,
    /// The ADC1_2 line's level.
    pub adc_irq_high: bool,
    /// Fault injection: the control interrupt's line stuck active (it pends again at
    /// every return).
    pub stuck_control_irq: bool,
    /// Fault injection: each control interrupt busy-waits this many ticks before it
    /// returns (a firmware whose interrupt overruns), and the return held back now
    /// (EXC_RETURN, until when).
    pub control_busy_ticks: u64,
    pub busy_exit: Option<(u32, u64)>,
    /// Per boot: the plant at the sampling instant of each control interrupt, in order
    /// (entry k - 1 for the firmware's control period `ticks` = k).
    pub period_truth: Vec<Vec<PeriodTruth>>,
    /// A break the filter validates after the period it was seen in ended: (crossing,
    /// MOE clear), ticks.
    pub pending_break: Option<(u64, u64)>,
    /// Cut the power when the flash starts programming its n-th double word (counted
    /// over the run), leaving it torn; the board is then off and runs no more.
    pub power_cut_at_program: Option<u32>,
    pub powered_off: bool,
    /// [`Machine::halt_core`]'s halt ends then (ticks).
    pub halted_until: Option<u64>,
    /// Halting debug (DHCSR, DFSR, DCRDR): see [`crate::debug::DebugState`].
    pub dbg: crate::debug::DebugState,
    /// A BKPT halted the core at this address (the CPU loop puts the PC back there).
    pub bkpt_at: Option<u32>,
    /// The core fetches its instructions from flash (where the current run of it
    /// started): an erase of that bank stalls it. Code copied to RAM (a probe's flash
    /// algorithm) runs on (§3.3.8: only a read of the bank being erased waits).
    pub fetching_from_flash: bool,
    /// Breakpoints (ARMv7-M ARM C1.11).
    pub fpb: crate::debug::Fpb,
    /// Bank-1 bytes the flash model changed (offsets [lo, hi)), for Unicorn's copy.
    pub bank1_dirty: Option<(u32, u32)>,
}

/// The over-current comparator's output glitches at a switching edge when a phase
/// current is within this fraction of its level: the switching ringing on the shunt
/// (the same that `current_sense::SETTLE_NS` lets die out) adds some tens of counts to
/// the comparator's input, about a tenth of a trip level set near full scale.
pub const GLITCH_MARGIN: f64 = 0.10;
/// How long the glitch holds the output low (s): the first lobes of that ringing, a
/// few hundred ns (shorter than the 1 µs it takes to settle). A break filter
/// (BDTR.BKF) longer than this rejects it; a shorter one, or none, latches the break.
pub const GLITCH_S: f64 = 300.0e-9;

/// Is this halfword the first of a 32-bit Thumb-2 instruction (A6.1)?
pub fn is_wide(hw: u16) -> bool {
    matches!(hw >> 11, 0b11101..=0b11111)
}

/// A VFP/Advanced SIMD instruction for coprocessors 10/11 (A6.3.18, A7.8).
pub fn is_vfp(hw1: u16, hw2: u16) -> bool {
    let top = hw1 & 0xEF00;
    let cp = (hw2 >> 8) & 0xF;
    (matches!(top, 0xEC00 | 0xED00 | 0xEE00)) && (cp == 10 || cp == 11)
}

impl Machine {
    pub fn new(flash_image: Vec<u8>, board: Board, rtt: Rtt) -> Self {
        let mut m = Self {
            regs: RegFile::new(crate::regs_g474::REGS),
            nvic: Nvic::default(),
            rcc: Rcc::with_hse(board.hse_hz),
            adcs: Adcs::default(),
            tim1: Tim1::default(),
            flash_ctl: FlashCtl::default(),
            cordic: Cordic::default(),
            iwdg: Iwdg::default(),
            flash: flash_image,
            now: 0,
            instrs: 0,
            cycles: 0,
            profile: None,
            block_costs: HashMap::default(),
            prev_block: None,
            prev_stage: None,
            call_stack: Vec::new(),
            deadline: 0,
            stop: false,
            first_block: false,
            idle: false,
            fault: None,
            exc_return: None,
            reset_request: None,
            stall_until: 0,
            lockup: false,
            cpacr: 0,
            vtor: 0,
            shcsr: 0,
            cfsr: 0,
            hfsr: 0,
            scr: 0,
            ccr: 0x200,
            fpccr: 0xC000_0000,
            demcr: 0,
            dwt_ctrl: 0x4000_0000,
            cyccnt_base: 0,
            cyccnt_frozen: 0,
            ppb_plain: BTreeMap::new(),
            board,
            rtt,
            stats: Stats {
                trace_blocks: std::env::var_os("DRIVE_EMU_ISR_BLOCKS").is_some(),
                ..Stats::default()
            },
            unmodelled: Unmodelled::default(),
            adc_irq_high: false,
            stuck_control_irq: false,
            control_busy_ticks: 0,
            busy_exit: None,
            period_truth: Vec::new(),
            pending_break: None,
            power_cut_at_program: None,
            powered_off: false,
            halted_until: None,
            dbg: Default::default(),
            bkpt_at: None,
            fetching_from_flash: true,
            fpb: Default::default(),
            bank1_dirty: None,
        };
        m.reset_peripherals(ResetKind::PowerOn);
        m
    }

    /// Peripherals and core registers of the private bus to their reset state; flash,
    /// RAM, the plant and the reset flags survive (RM0440 §7.1.2 system reset).
    pub fn reset_peripherals(&mut self, kind: ResetKind) {
        let csr = self.regs.get(rcc::CSR);
        // DBGMCU_CR and the freeze registers are reset by a power-on reset only
        // (RM0440 §46.16.2-5); DEMCR by a power-on reset only (ARMv7-M ARM C1.6.5).
        let kept_dbgmcu: Vec<(u32, u32)> = (0xE004_2004..=0xE004_2010)
            .step_by(4)
            .map(|a| (a, self.regs.get(a)))
            .collect();
        let power_on = kind == ResetKind::PowerOn;
        self.regs.reset();
        if !power_on {
            for (a, v) in kept_dbgmcu {
                self.regs.set(a, v);
            }
        }
        self.regs.set(
            crate::debug::DBGMCU_IDCODE,
            (crate::debug::REV_ID_G474 as u32) << 16 | self.board.dev_id as u32,
        );
        self.rcc.reset(&mut self.regs);
        self.rcc.record_reset(&mut self.regs, kind, csr);
        self.adcs.reset();
        self.tim1.reset();
        self.flash_ctl.reset(&mut self.regs);
        self.cordic = Cordic::default();
        self.iwdg.reset();
        self.nvic = Nvic::default();
        self.board.reset_option_bytes(&mut self.regs);
        self.stall_until = 0;
        self.lockup = false;
        self.cpacr = 0;
        self.vtor = 0;
        self.shcsr = 0;
        self.cfsr = 0;
        self.hfsr = 0;
        self.scr = 0;
        self.ccr = 0x200;
        self.fpccr = 0xC000_0000;
        if power_on {
            self.demcr = 0;
            self.dbg = Default::default();
        }
        self.dbg.reset_st = true;
        self.dwt_ctrl = 0x4000_0000;
        self.ppb_plain.clear();
        self.adc_irq_high = false;
        self.busy_exit = None;
        self.pending_break = None;
        self.stats.armed = false;
        self.stats.masked_since = None;
        self.stats.isr_entered_at = None;
        self.stats.isr_cycles_entered_at = None;
        self.stats.task_entered_at = None;
        self.stats.task_pend = None;
        self.stats.task_serving = None;
        self.rtt.reset();
        self.stats.boots.push((self.now, kind));
        self.period_truth.push(Vec::new());
    }

    // ---- exceptions: what the measurements need at entry and return ----

    /// Exception `n` was entered (frame pushed, `cost` est. cycles of entry).
    pub fn exception_entered(&mut self, n: u16, cost: u64) {
        self.nvic.take(n);
        self.prev_block = None;
        self.prev_stage = None;
        if n == nvic::irq(ADC1_2_IRQ) {
            let instrs = self.instrs;
            let st = &mut self.stats;
            if let Some(since) = st.pending_since.take() {
                st.latency_max = st.latency_max.max(instrs - since);
            }
            // Taken, so no longer masked: a stretch that a lock's release ended right
            // before this entry ends here, not after the interrupt returns (the block
            // hook does not look at the mask inside the control interrupt).
            if let Some(t0) = st.masked_since.take() {
                st.masked_ended(instrs - t0, self.now);
            }
            st.isr_entered_at = Some(instrs);
            st.isr_cycles_entered_at = Some(self.cycles);
            st.stage_now = Default::default();
            st.charge(Stage::EntryExit, 0, cost);
            st.armed = true;
            st.isr_entries += 1;
            self.call_stack.clear();
            // The sample this interrupt reads: the plant at the last trigger.
            let truth = self.board.period_truth();
            if let Some(log) = self.period_truth.last_mut() {
                log.push(truth);
            }
        }
        if n == nvic::irq(USART3_IRQ) {
            self.stats.task_entered_at = Some(self.cycles);
            self.stats.task_serving = self.stats.task_pend.take();
        }
        if n == nvic::NMI {
            self.stats.nmis += 1;
        }
        self.cycles += cost;
    }

    /// The innermost active exception returned (`cost` est. cycles of the return);
    /// which one it was.
    pub fn exception_returned(&mut self, cost: u64) -> Option<u16> {
        let done = self.nvic.active.pop();
        self.cycles += cost;
        self.prev_block = None;
        self.prev_stage = None;
        if done == Some(nvic::irq(ADC1_2_IRQ)) {
            let st = &mut self.stats;
            if let Some(t0) = st.isr_entered_at.take() {
                let n = self.instrs - t0;
                st.isr_count += 1;
                st.isr_count_total += 1;
                st.isr_instrs_sum += n;
                st.isr_instrs_max = st.isr_instrs_max.max(n);
                if let Some(c0) = st.isr_cycles_entered_at.take() {
                    let c = self.cycles - c0;
                    st.isr_cycles_sum += c;
                    st.charge(Stage::EntryExit, 0, cost);
                    st.isr_cycles_max = st.isr_cycles_max.max(c);
                    if st.trace_blocks {
                        if c > st.blocks_window_cycles {
                            st.blocks_window_cycles = c;
                            st.blocks_window = st.blocks_now.clone();
                        }
                        if c > st.isr_longest.cycles {
                            st.blocks_longest = st.blocks_now.clone();
                        }
                        st.blocks_now.clear();
                    }
                    if c > st.isr_longest.cycles {
                        st.isr_longest = crate::stats::Longest {
                            cycles: c,
                            instrs: n,
                            at: self.now,
                            stages: st.stage_now,
                        };
                    }
                    st.close_stages();
                }
            }
            self.call_stack.clear();
            // A level-sensitive line still high pends again (B3.4.1).
            if self.adc_irq_high || self.stuck_control_irq {
                self.nvic.pend_irq(ADC1_2_IRQ);
            }
        }
        if done == Some(nvic::irq(USART3_IRQ)) {
            let st = &mut self.stats;
            if let Some(c0) = st.task_entered_at.take() {
                let c = self.cycles - c0;
                if c > st.task_cycles_max {
                    st.task_cycles_max = c;
                    st.task_max_at = self.now;
                }
                if st.trace_blocks {
                    if c > st.task_blocks_cycles {
                        st.task_blocks_cycles = c;
                        st.task_blocks_longest = std::mem::take(&mut st.task_blocks_now);
                    }
                    st.task_blocks_now.clear();
                }
            }
            if let Some(k) = st.task_serving.take() {
                let entered = st.isr_entries - k;
                if entered > st.task_from_pend_max {
                    st.task_from_pend_max = entered;
                    st.task_from_pend_max_at = self.now;
                }
                if entered >= mras::UPDATE_LATENCY_PERIODS as u64 {
                    st.task_deadline_misses += 1;
                }
            }
        }
        done
    }

    /// The adaptation task was pended (by the control interrupt, with a sample).
    fn task_pended(&mut self) {
        if self.stats.task_pend.is_none() {
            self.stats.task_pend = Some(self.stats.isr_entries);
        }
    }

    /// Is the control interrupt active (entered, not returned)?
    pub fn control_active(&self) -> bool {
        self.nvic.active.contains(&nvic::irq(ADC1_2_IRQ))
    }

    pub fn time_s(&self) -> f64 {
        self.now as f64 / TICK_HZ
    }

    /// FPU enabled for unprivileged and privileged code (CPACR CP10, CP11 = 0b11).
    pub fn fpu_enabled(&self) -> bool {
        self.cpacr & (0xF << 20) == 0xF << 20
    }

    /// Instructions in a translated block at `addr` of `size` bytes, from the image.
    pub fn count_instrs(&self, addr: u32, size: u32) -> (u64, bool) {
        let Some(off) = addr.checked_sub(crate::elf::FLASH_BASE) else {
            return ((size as u64 / 2).max(1), false);
        };
        let code = &self.flash;
        let (mut i, end) = (off as usize, (off + size) as usize);
        let (mut n, mut vfp) = (0, false);
        while i + 1 < end.min(code.len()) {
            let hw = u16::from_le_bytes([code[i], code[i + 1]]);
            if is_wide(hw) && i + 3 < code.len() {
                let hw2 = u16::from_le_bytes([code[i + 2], code[i + 3]]);
                vfp |= is_vfp(hw, hw2);
                i += 4;
            } else {
                i += 2;
            }
            n += 1;
        }
        (n.max(1), vfp)
    }

    /// The estimated cycles of the block at `addr` of `size` bytes (`n` instructions):
    /// its cached cost, the previous block's taken-branch refill when this one does not
    /// follow it, the pipelined first load when it does; inside the control interrupt,
    /// the same by stage.
    pub fn account_cycles(&mut self, addr: u32, size: u32, n: u64) {
        let Some(p) = self.profile.as_ref() else {
            self.cycles += n;
            return;
        };
        let b = *self
            .block_costs
            .entry((addr as u64) << 32 | size as u64)
            .or_insert_with(|| p.block(addr, size));
        let in_isr = self.stats.isr_entered_at.is_some();
        let mut credit = 0;
        if let Some(prev) = self.prev_block {
            if addr != prev.end {
                let refill = prev.last_refill as u64;
                self.cycles += refill;
                if let (true, Some(s)) = (in_isr, self.prev_stage) {
                    self.stats.charge(s, 0, refill);
                    // A call: its callee runs for the call site's stage until it
                    // returns to the instruction after the call (bounded: recursion
                    // or a missed return must not grow it without end).
                    if prev.last_is_call && self.call_stack.len() < 64 {
                        self.call_stack.push((prev.end, s));
                    } else if self.call_stack.last().is_some_and(|&(r, _)| r == addr) {
                        self.call_stack.pop();
                    }
                }
            } else if prev.last_single_ldst {
                credit = b.first_credit;
            }
        }
        self.cycles += (b.cycles - credit) as u64;
        if self.stats.trace_blocks {
            let c = (b.cycles - credit) as u64;
            if in_isr {
                self.stats.blocks_now.push((addr, c));
            } else if self.stats.task_entered_at.is_some() {
                self.stats.task_blocks_now.push((addr, c));
            }
        }
        if in_isr {
            let caller = self.call_stack.last().map(|c| c.1);
            for s in Stage::ALL {
                let (i, c) = b.by_stage[s as usize];
                if i > 0 {
                    self.stats.charge(s.under(caller), i as u64, c as u64);
                }
            }
            if let (true, Some(s)) = (credit > 0, b.first_stage) {
                self.stats.stage_now[s.under(caller) as usize].1 -= credit as u64;
            }
            self.prev_stage = b.last_stage.map(|s| s.under(caller));
        }
        self.prev_block = Some(b);
    }

    /// Is the block at `addr` the idle loop `b .` (0xE7FE)?
    pub fn is_idle_branch(&self, addr: u32, size: u32) -> bool {
        size == 2
            && addr
                .checked_sub(crate::elf::FLASH_BASE)
                .and_then(|o| self.flash.get(o as usize..o as usize + 2))
                .is_some_and(|b| b == [0xFE, 0xE7])
    }

    // ---- events ----

    /// The next time a model needs the CPU stopped.
    pub fn next_event(&self) -> u64 {
        let mut t = u64::MAX;
        if let Some((e, _)) = self.tim1.next_event() {
            t = t.min(e);
        }
        for e in [
            self.adcs.next_event(),
            self.rcc.next_event(),
            self.pending_break.map(|b| b.1),
            self.halted_until,
            self.busy_exit.map(|b| b.1),
            self.flash_ctl.next_event(),
            self.iwdg.expiry(&self.regs),
            Some(self.rtt.next_poll),
            Some(self.board.next_coast(self.now)),
        ]
        .into_iter()
        .flatten()
        {
            t = t.min(e);
        }
        t
    }

    /// Process every event due by `now`.
    pub fn service_events(&mut self) {
        if self.halted_until.is_some_and(|t| t <= self.now) {
            self.halted_until = None;
            self.debug_resume();
        }
        loop {
            let mut progressed = false;
            if let Some((t, e)) = self.tim1.next_event() {
                if t <= self.now {
                    self.tim1.fire(&mut self.regs, t, e);
                    if e == Edge::Trgo2 {
                        self.adc_trigger(t);
                    }
                    progressed = true;
                }
            }
            if self.adcs.next_event().is_some_and(|t| t <= self.now) {
                self.adcs.complete(&mut self.regs, self.now);
                progressed = true;
            }
            if self.flash_ctl.next_event().is_some_and(|t| t <= self.now) {
                self.flash_ctl.complete(&mut self.regs, self.now);
                progressed = true;
            }
            if self.rcc.next_event().is_some_and(|t| t <= self.now) {
                let latency = self.regs.get(flash::ACR) & 0xF;
                self.rcc.update(&mut self.regs, self.now, latency);
                progressed = true;
            }
            if let Some((crossing, clear)) = self.pending_break.filter(|b| b.1 <= self.now) {
                self.pending_break = None;
                self.filtered_break(crossing, clear);
                progressed = true;
            }
            if !progressed {
                break;
            }
        }
        self.update_irq_lines();
        if self.iwdg.expiry(&self.regs).is_some_and(|t| t <= self.now) {
            self.iwdg.expiries += 1;
            self.reset_request = Some(ResetKind::Watchdog);
        }
        // No trigger for a while (reset, boot, timer stopped): the motor coasts.
        self.arm_break_path();
        if self.board.coast(self.now) {
            self.check_break();
        }
    }

    /// Tell the plant what the timer's break path does to the bridge in the coming
    /// period: with the comparator routed to an enabled break, MOE on and the pin's
    /// polarity active low, the bridge opens the filter's latency after a crossing.
    /// The timer's kernel clock is the tick, as for its counter.
    fn arm_break_path(&mut self) {
        let armed =
            self.board.bkin(&self.regs, false).routed && Tim1::break_armed_for_low_pin(&self.regs);
        self.board.plant.break_path_delay_s =
            armed.then(|| Tim1::break_filter_s(&self.regs, TICK_HZ));
    }

    /// A crossing the filter validated: MOE cleared, BIF set, at `clear` (ticks).
    fn filtered_break(&mut self, crossing: u64, clear: u64) {
        if self
            .tim1
            .apply_break(&mut self.regs, clear.min(self.now), true)
        {
            self.stats.breaks.push(Break {
                crossing,
                moe_cleared: clear,
            });
        }
    }

    /// TRGO2 at `t`: the plant catches up to the sampling instant and the ADCs convert.
    fn adc_trigger(&mut self, t: u64) {
        self.stats.last_trigger = t;
        let (duties, on) = self.tim1.take_applied(&self.regs, t);
        let period = self.tim1.period_ticks();
        self.arm_break_path();
        let armed_delay = self.board.plant.break_path_delay_s;
        self.board.advance_to(t, duties, on, period);
        // A crossing in the period just integrated: the break path (if armed) cleared
        // MOE its filter's latency later, which may still be to come.
        if let (Some(tc), Some(d)) = (self.board.plant.crossing_s(), armed_delay) {
            let crossing = self.board.last_period_start() + crate::periph::ticks(tc);
            let clear = crossing + crate::periph::ticks(d);
            if clear <= self.now {
                self.filtered_break(crossing, clear);
            } else {
                self.pending_break = Some((crossing, clear));
            }
        }
        self.comparator_glitch(on);
        self.check_break();
        let out = tim1::OutRegs::of(&self.regs);
        let (board, tim) = (&self.board, &self.tim1);
        let mut read =
            |adc: usize, ch: u32, from: u64, to: u64| board.input(tim, &out, adc, ch, from, to);
        let found = self.adcs.trgo2(&mut self.regs, t, &mut read);
        // As the hardware sees it: a trigger while the control interrupt still runs,
        // onto an unread or unfinished sequence, or lost on an ADC not armed once the
        // control interrupt has run.
        let cause = match found {
            _ if self.control_active() => Some(MissCause::ControlRunning),
            adc::Trigger::Started { unread: true, .. } => Some(MissCause::SequenceUnread),
            adc::Trigger::Started {
                converting: true, ..
            } => Some(MissCause::StillConverting),
            adc::Trigger::NotArmed if self.stats.armed => Some(MissCause::AdcNotArmed),
            _ => None,
        };
        if let Some(cause) = cause {
            let instrs = self.instrs;
            self.stats.missed.push(Missed {
                t,
                cause,
                before_control: !self.stats.armed,
                pc: self.prev_block.map_or(0, |b| b.end),
                in_isr_instrs: self.stats.isr_entered_at.map(|t0| instrs - t0),
                masked_instrs: self.stats.masked_since.map(|t0| instrs - t0),
            });
        }
    }

    /// The over-current comparator's level on PA6 → TIM1 break (and the core's lockup
    /// when SYSCFG routes it): a break still active clears MOE.
    pub fn check_break(&mut self) {
        let over = self.board.plant.comparator_over();
        let lock = self.lockup && misc::lockup_to_break(&self.regs);
        let pin_low = self.bkin_input_low();
        let active = tim1::Tim1::break_input(&self.regs, pin_low, lock);
        if over && !active && tim1::Tim1::moe(&self.regs) {
            self.tim1.breaks_unrouted += 1;
        }
        self.tim1.apply_break(&mut self.regs, self.now, active);
    }

    /// TIM1's BKIN input: the pin's level once it is in its alternate function. Before
    /// that the timer's input is not connected to the pin; RM0440 does not say what it
    /// reads then, and it is taken as low (active with BKP = 0), so that a break
    /// enabled before the pin is configured latches BIF (the firmware's boot-time
    /// clear). A routed pin left floating (no pull-up on the board or the pin) reads
    /// low too: counted as `Tim1::bkin_floating` while the break is enabled.
    fn bkin_input_low(&mut self) -> bool {
        let pin = self.board.bkin(&self.regs, false);
        let floating = pin.routed && pin.floating && self.regs.bit(tim1::BDTR, 1 << 12);
        self.tim1.note_bkin_floating(floating);
        !pin.routed || pin.low
    }

    /// A glitch of the comparator at the switching edges of the period just integrated
    /// (see [`GLITCH_MARGIN`], [`GLITCH_S`]): through the break path, it latches the
    /// break when the filter (BDTR.BKF) is shorter than the glitch.
    fn comparator_glitch(&mut self, bridge_on: bool) {
        let level = self.board.plant.break_level_a;
        let i = self.board.plant.currents_ab();
        let s3 = 3f64.sqrt() / 2.0;
        let peak = i[0]
            .abs()
            .max((0.5 * i[0] - s3 * i[1]).abs())
            .max((0.5 * i[0] + s3 * i[1]).abs());
        let near = level > 0.0 && peak <= level && peak > level * (1.0 - GLITCH_MARGIN);
        if !(bridge_on && near) {
            return;
        }
        self.stats.comparator_glitches += 1;
        let routed = self.board.bkin(&self.regs, true).routed;
        if !(routed && Tim1::break_armed_for_low_pin(&self.regs)) {
            return;
        }
        let filter_s = Tim1::break_filter_s(&self.regs, TICK_HZ);
        if GLITCH_S > filter_s {
            // The first edge of the period, taken at its start.
            let edge = self.board.last_period_start();
            self.stats.glitch_breaks += 1;
            self.filtered_break(edge, edge + ticks(filter_s));
        }
    }

    // ---- debug halt ----

    /// A debugger halts the core for `ticks`, then lets it run: the Debug state a
    /// probe's DHCSR.C_HALT enters ([`Machine::debug_halt`]), ended by the machine
    /// itself. No instructions run and no exception is taken, time, the peripherals and
    /// the plant go on. With DBGMCU_APB2FZR.DBG_TIM1_STOP set, TIM1 stops counting and
    /// its outputs are disabled as if MOE were reset (RM0440 §28.3.31 Debug mode): no
    /// trigger, the motor coasts with the bridge off; without it the timer keeps
    /// switching on its last duties. IWDG pauses with DBG_IWDG_STOP.
    pub fn halt_core(&mut self, ticks: u64) {
        self.halted_until = Some(self.now + ticks);
        self.debug_halt(crate::debug::DFSR_HALTED);
    }

    /// DHCSR as read (C1.6.2): S_RESET_ST and S_RETIRE_ST clear on read.
    pub fn dhcsr_read(&mut self) -> u32 {
        use crate::debug::*;
        let d = &mut self.dbg;
        let mut v = d.ctrl | S_REGRDY;
        if d.halted {
            v |= S_HALT;
        }
        if self.lockup {
            v |= S_LOCKUP;
        }
        if std::mem::take(&mut d.reset_st) {
            v |= S_RESET_ST;
        }
        if std::mem::take(&mut d.retire_st) {
            v |= S_RETIRE_ST;
        }
        v
    }

    /// A DHCSR write (C1.6.2): ignored without DBGKEY in [31:16]; C_HALT with
    /// C_DEBUGEN halts, C_HALT cleared resumes (with C_STEP: one instruction).
    pub fn dhcsr_write(&mut self, v: u32) {
        use crate::debug::*;
        if v >> 16 != DBGKEY {
            return;
        }
        let ctrl = v & (C_DEBUGEN | C_HALT | C_STEP | C_MASKINTS);
        self.dbg.ctrl = if ctrl & C_DEBUGEN == 0 { 0 } else { ctrl };
        let ctrl = self.dbg.ctrl;
        if ctrl & C_DEBUGEN != 0 && ctrl & C_HALT != 0 {
            self.debug_halt(DFSR_HALTED);
        } else if self.dbg.halted {
            if ctrl & C_STEP != 0 {
                self.dbg.step_pending = true;
            } else {
                self.debug_resume();
            }
        }
    }

    /// Enter Debug state (C1.5): the core stops at the next instruction boundary.
    pub fn debug_halt(&mut self, reason: u32) {
        // Entering Debug state is one of the two ways out of lockup, a reset the other
        // (ARMv7-M ARM B1.5.15): a probe can halt a locked-up core (an erased chip
        // fetching its vectors from 0xFFFF_FFFF) and then flash it.
        self.lockup = false;
        self.dbg.dfsr |= reason;
        self.dbg.ctrl |= crate::debug::C_HALT;
        if !self.dbg.halted {
            self.dbg.halted = true;
            if self.regs.bit(tim1::DBGMCU_APB2FZR, tim1::DBG_TIM1_STOP) {
                self.tim1.freeze(&self.regs, self.now);
            }
        }
        self.stop = true;
    }

    /// Leave Debug state.
    pub fn debug_resume(&mut self) {
        self.halted_until = None;
        if self.dbg.halted {
            self.dbg.halted = false;
            self.dbg.ctrl &= !crate::debug::C_HALT;
            self.tim1.unfreeze(&self.regs, self.now);
        }
    }

    /// Is the core in Debug state (a probe's halt or [`Machine::halt_core`])?
    pub fn halted(&self) -> bool {
        self.dbg.halted
    }

    /// Does the bridge drive the motor now (TIM1 running, MOE set, not frozen)?
    pub fn bridge_on(&self) -> bool {
        self.tim1.bridge_on(&self.regs)
    }

    /// Level-sensitive interrupt lines into the NVIC.
    pub fn update_irq_lines(&mut self) {
        let high = Adcs::irq_line(&self.regs);
        if high && !self.adc_irq_high {
            self.nvic.pend_irq(ADC1_2_IRQ);
            self.stats.control_requests += 1;
            self.stats.pending_since = Some(self.instrs);
        }
        self.adc_irq_high = high;
    }

    // ---- bus ----

    /// The peripheral a register address belongs to.
    fn periph_of(addr: u32) -> Option<&'static str> {
        crate::regs_g474::PERIPHS
            .iter()
            .find(|p| (p.base..p.base + p.size).contains(&addr))
            .map(|p| p.name)
    }

    pub fn mmio_read(&mut self, addr: u32, size: usize) -> u32 {
        let word = addr & !3;
        let v = self.read_word(word);
        let shift = (addr & 3) * 8;
        match size {
            1 => (v >> shift) & 0xFF,
            2 => (v >> shift) & 0xFFFF,
            _ => v,
        }
    }

    fn read_word(&mut self, addr: u32) -> u32 {
        if let Some(p) = Self::periph_of(addr) {
            if !Rcc::clocked(&self.regs, p) {
                *self.unmodelled.gated.entry(p).or_default() += 1;
                return 0;
            }
        }
        match addr {
            a if (adc::ADC1..adc::ADC1 + 0x400).contains(&a) => {
                self.adcs.update(&mut self.regs, self.now);
                self.adcs.on_read(a);
            }
            tim1::CNT => {
                let c = self.tim1.cnt(self.now);
                self.regs.set(tim1::CNT, c);
            }
            misc::CORDIC_RDATA => return self.cordic.read_result(&mut self.regs),
            misc::IWDG_SR => self.iwdg.update(&mut self.regs, self.now),
            a if a == crate::board::bkin_pin().0 + 0x10 => {
                // The comparator's open-drain output with its pull-up: low on
                // over-current, or floating with none (read low).
                let (port, pin, _) = crate::board::bkin_pin();
                let low = self.board.bkin(&self.regs, false).low;
                self.regs.set_bits(port + 0x10, 1 << pin, !low);
            }
            _ => {}
        }
        match self.regs.def(addr) {
            Some(d) if d.readable => self.regs.get(addr),
            Some(_) => 0,
            None => {
                *self.unmodelled.unknown.entry(addr).or_default() += 1;
                0
            }
        }
    }

    pub fn mmio_write(&mut self, addr: u32, size: usize, v: u32) {
        let word = addr & !3;
        let v = if size < 4 {
            // Narrow writes: the other bytes keep their value.
            let shift = (addr & 3) * 8;
            let mask = if size == 1 { 0xFF } else { 0xFFFF } << shift;
            (self.regs.get(word) & !mask) | ((v << shift) & mask)
        } else {
            v
        };
        if let Some(p) = Self::periph_of(word) {
            if !Rcc::clocked(&self.regs, p) {
                *self.unmodelled.gated.entry(p).or_default() += 1;
                return;
            }
        }
        let Some((old, _new)) = self.regs.bus_write(word, v) else {
            *self.unmodelled.unknown.entry(word).or_default() += 1;
            return;
        };
        self.after_write(word, old, v);
    }

    fn after_write(&mut self, addr: u32, old: u32, v: u32) {
        let now = self.now;
        match addr {
            a if (rcc::RCC..rcc::RCC + 0x400).contains(&a)
                || (rcc::PWR..rcc::PWR + 0x400).contains(&a) =>
            {
                let latency = self.regs.get(flash::ACR) & 0xF;
                self.rcc.on_write(&mut self.regs, addr, old, now, latency);
            }
            a if a == adc::ADC1 + adc::CR || a == adc::ADC2 + adc::CR => {
                let i = usize::from(a == adc::ADC2 + adc::CR);
                let start = self.adcs.on_cr_write(&mut self.regs, i, old, v, now);
                if start != adc::SoftStart::None {
                    let out = tim1::OutRegs::of(&self.regs);
                    let (board, tim) = (&self.board, &self.tim1);
                    let mut read = |adc: usize, ch: u32, from: u64, to: u64| {
                        board.input(tim, &out, adc, ch, from, to)
                    };
                    self.adcs
                        .software_start(&mut self.regs, start, now, &mut read);
                }
            }
            adc::COMMON_CCR => self.adcs.on_common_write(&mut self.regs, old),
            a if (tim1::TIM1..tim1::TIM1 + 0x400).contains(&a) => {
                let pin_low = self.bkin_input_low();
                let lock = self.lockup && misc::lockup_to_break(&self.regs);
                let brk = tim1::Tim1::break_input(&self.regs, pin_low, lock);
                self.tim1.on_write(&mut self.regs, addr, old, now, brk);
                self.tim1.check_gate_polarity(
                    &self.regs,
                    board_map::gate_driver::LOW_SIDE_INPUT_ACTIVE_LOW,
                );
                // A level: an active input latches as soon as the break is enabled.
                self.check_break();
            }
            a if (misc::GPIOA..misc::GPIOA + 0x1C00).contains(&a) => self.check_break(),
            a if (flash::FLASH..flash::FLASH + 0x400).contains(&a) => {
                // The code is linked for 0x0800_0000: bank 1, unless FB_MODE maps bank
                // 2 there (the swap itself is not modelled and is reported).
                let code_bank2 = misc::banks_swapped(&self.regs);
                let fetching = self.fetching_from_flash && !self.dbg.halted;
                let eff =
                    self.flash_ctl
                        .on_write(&mut self.regs, addr, old, now, code_bank2, fetching);
                self.apply_flash(eff);
            }
            misc::CORDIC_WDATA => self.cordic.write_arg(&mut self.regs, v),
            misc::SYSCFG_MEMRMP if misc::banks_swapped(&self.regs) => {
                self.unmodelled.bank_swap += 1
            }
            a if (misc::IWDG..misc::IWDG + 0x400).contains(&a) => {
                self.iwdg.on_write(&mut self.regs, addr, old, now)
            }
            _ => {}
        }
        // A write may raise or drop an interrupt line (flags cleared by the ISR).
        self.update_irq_lines();
        if self.nvic.any_pending() {
            self.stop = true;
        }
    }

    pub fn apply_flash(&mut self, eff: flash::Effect) {
        if std::env::var_os("DRIVE_EMU_TRACE").is_some() {
            match &eff {
                flash::Effect::Erase { offset, stall_cpu } => {
                    eprintln!("erase {offset:#x} stall={stall_cpu} t={:.4}", self.time_s())
                }
                flash::Effect::Program { offset, lo, hi } => {
                    eprintln!("program {offset:#x} {lo:#x} {hi:#x}")
                }
                flash::Effect::None => eprintln!(
                    "flash op: none, SR={:#x} CR={:#x}",
                    self.regs.get(flash::SR),
                    self.regs.get(flash::CR)
                ),
            }
        }
        match eff {
            flash::Effect::None => {}
            flash::Effect::Erase { offset, stall_cpu } => {
                let page = flash::PAGE_BYTES;
                let end = ((offset + page) as usize).min(self.flash.len());
                self.flash[offset as usize..end].fill(0xFF);
                self.mark_bank1(offset, end as u32);
                self.flash_ctl
                    .torn
                    .retain(|&t| !(offset..offset + page).contains(&t));
                if stall_cpu {
                    self.stall_until = self.now + ticks(flash::ERASE_S);
                    self.stop = true;
                }
            }
            flash::Effect::Program { offset, lo, hi } => {
                let o = offset as usize;
                self.flash[o..o + 4].copy_from_slice(&lo.to_le_bytes());
                self.flash[o + 4..o + 8].copy_from_slice(&hi.to_le_bytes());
                self.mark_bank1(offset, offset + 8);
                if self.power_cut_at_program == Some(self.flash_ctl.programs) {
                    self.power_cut();
                    self.powered_off = true;
                    self.stop = true;
                }
            }
        }
    }

    /// Bank 1 (Unicorn's memory copy) changed in [lo, hi): resynced by the CPU loop.
    fn mark_bank1(&mut self, lo: u32, hi: u32) {
        let hi = hi.min(flash::BANK_BYTES);
        if lo >= hi {
            return;
        }
        self.bank1_dirty = Some(match self.bank1_dirty {
            Some((a, b)) => (a.min(lo), b.max(hi)),
            None => (lo, hi),
        });
        self.stop = true;
    }

    /// Power cut: a double word being programmed is left torn, its first word written
    /// and its second still erased (what the next read finds besides the ECC error).
    /// Returns its offset in the flash image.
    pub fn power_cut(&mut self) -> Option<u32> {
        let dw = self.flash_ctl.power_cut()? as usize;
        self.flash[dw + 4..dw + 8].fill(0xFF);
        Some(dw as u32)
    }

    /// A read of the bank-2 array (the calibration pages).
    pub fn flash_read(&mut self, offset: u32, size: usize) -> u32 {
        if self.flash_ctl.on_array_read(&mut self.regs, offset) {
            self.nvic.nmi_pending = true;
            self.stop = true;
        }
        let o = offset as usize;
        let mut b = [0u8; 4];
        b[..size].copy_from_slice(&self.flash[o..o + size]);
        u32::from_le_bytes(b)
    }

    pub fn flash_write(&mut self, offset: u32, size: usize, v: u32) {
        let addr = crate::elf::FLASH_BASE + offset;
        let flash = &self.flash;
        let erased = |o: u32| flash[o as usize..o as usize + 8].iter().all(|&b| b == 0xFF);
        let eff = self
            .flash_ctl
            .on_array_write(&mut self.regs, addr, size, v, self.now, &erased);
        self.apply_flash(eff);
    }

    // ---- private peripheral bus (ARMv7-M B3) ----

    pub fn cyccnt(&self) -> u32 {
        if self.demcr & (1 << 24) != 0 && self.dwt_ctrl & 1 != 0 {
            (self.instrs - self.cyccnt_base) as u32
        } else {
            self.cyccnt_frozen
        }
    }

    pub fn ppb_read(&mut self, addr: u32) -> u32 {
        match addr {
            0xE000_1000 => self.dwt_ctrl,
            0xE000_1004 => self.cyccnt(),
            0xE000_E004 => 7, // ICTR: 256 interrupt lines
            a @ 0xE000_E100..=0xE000_E11F => self.nvic.enabled[((a - 0xE000_E100) / 4) as usize],
            a @ 0xE000_E180..=0xE000_E19F => self.nvic.enabled[((a - 0xE000_E180) / 4) as usize],
            a @ 0xE000_E200..=0xE000_E21F => {
                self.nvic.pending_word(((a - 0xE000_E200) / 4) as usize)
            }
            a @ 0xE000_E280..=0xE000_E29F => {
                self.nvic.pending_word(((a - 0xE000_E280) / 4) as usize)
            }
            a @ 0xE000_E300..=0xE000_E31F => {
                let w = (a - 0xE000_E300) / 4;
                self.nvic
                    .active
                    .iter()
                    .filter(|&&n| n >= 16 && (n - 16) / 32 == w as u16)
                    .fold(0, |acc, &n| acc | 1 << ((n - 16) % 32))
            }
            a @ 0xE000_E400..=0xE000_E4EF => {
                let i = (a - 0xE000_E400) as usize;
                u32::from_le_bytes([
                    self.nvic.ipr[i],
                    self.nvic.ipr[i + 1],
                    self.nvic.ipr[i + 2],
                    self.nvic.ipr[i + 3],
                ])
            }
            0xE000_ED00 => 0x410F_C241, // CPUID: Cortex-M4 r0p1
            0xE000_ED04 => {
                let active = self.nvic.active.last().copied().unwrap_or(0) as u32;
                let pending = self.nvic.most_urgent_pending().map_or(0, |(n, _)| n as u32);
                active | pending << 12 | (self.nvic.pendsv_pending as u32) << 28
            }
            0xE000_ED08 => self.vtor,
            0xE000_ED0C => 0xFA05_0000 | (self.nvic.prigroup as u32) << 8,
            0xE000_ED10 => self.scr,
            0xE000_ED14 => self.ccr,
            a @ 0xE000_ED18..=0xE000_ED23 => {
                let i = (a - 0xE000_ED18) as usize;
                u32::from_le_bytes([
                    self.nvic.shpr[i],
                    self.nvic.shpr[i + 1],
                    self.nvic.shpr[i + 2],
                    self.nvic.shpr[i + 3],
                ])
            }
            0xE000_ED24 => self.shcsr,
            0xE000_ED28 => self.cfsr,
            0xE000_ED2C => self.hfsr,
            0xE000_ED88 => self.cpacr,
            0xE000_EDFC => self.demcr,
            crate::debug::DHCSR => self.dhcsr_read(),
            a if (crate::debug::FP_CTRL..crate::debug::FP_END).contains(&a) => {
                self.fpb.read(a).unwrap_or(0)
            }
            crate::debug::DFSR => self.dbg.dfsr,
            crate::debug::DCRDR => self.dbg.dcrdr,
            // MVFR0/MVFR1 of the Cortex-M4F (Cortex-M4 TRM r0p1 §7.3).
            0xE000_EF40 => 0x1011_0021,
            0xE000_EF44 => 0x1100_0011,
            0xE000_EF34 => self.fpccr,
            a if (0xE004_2000..0xE004_2400).contains(&a) => self.read_word(a),
            a => {
                self.ppb_plain_access(a);
                *self.ppb_plain.get(&a).unwrap_or(&0)
            }
        }
    }

    pub fn ppb_write(&mut self, addr: u32, size: usize, v: u32) {
        match (addr, size) {
            (a @ 0xE000_E400..=0xE000_E4EF, s) | (a @ 0xE000_ED18..=0xE000_ED23, s) => {
                let bytes = v.to_le_bytes();
                let (arr, i): (&mut [u8], usize) = if a >= 0xE000_ED18 {
                    (&mut self.nvic.shpr, (a - 0xE000_ED18) as usize)
                } else {
                    (&mut self.nvic.ipr, (a - 0xE000_E400) as usize)
                };
                for k in 0..s.min(arr.len() - i) {
                    // 4 priority bits implemented on the STM32G4 (PM0214 §4.3.7).
                    arr[i + k] = bytes[k] & 0xF0;
                }
            }
            _ => self.ppb_write_word(addr, v),
        }
        if self.nvic.any_pending() {
            self.stop = true;
        }
    }

    fn ppb_write_word(&mut self, addr: u32, v: u32) {
        match addr {
            0xE000_1000 => {
                let was = self.dwt_ctrl & 1 != 0;
                if v & 1 != 0 && !was {
                    self.cyccnt_base = self.instrs - self.cyccnt_frozen as u64;
                } else if v & 1 == 0 && was {
                    self.cyccnt_frozen = self.cyccnt();
                }
                self.dwt_ctrl = (self.dwt_ctrl & !1) | (v & 1);
            }
            0xE000_1004 => {
                self.cyccnt_base = self.instrs - v as u64;
                self.cyccnt_frozen = v;
            }
            a @ 0xE000_E100..=0xE000_E11F => {
                self.nvic.enabled[((a - 0xE000_E100) / 4) as usize] |= v
            }
            a @ 0xE000_E180..=0xE000_E19F => {
                self.nvic.enabled[((a - 0xE000_E180) / 4) as usize] &= !v
            }
            a @ 0xE000_E200..=0xE000_E21F => {
                let w = ((a - 0xE000_E200) / 4) as usize;
                self.nvic.set_pending_word(w, v, 0);
                if w == (USART3_IRQ / 32) as usize && v & 1 << (USART3_IRQ % 32) != 0 {
                    self.task_pended();
                }
            }
            a @ 0xE000_E280..=0xE000_E29F => {
                self.nvic
                    .set_pending_word(((a - 0xE000_E280) / 4) as usize, 0, v)
            }
            0xE000_EF00 => {
                self.nvic.pend_irq((v & 0x1FF) as u16);
                if v & 0x1FF == USART3_IRQ as u32 {
                    self.task_pended();
                }
            }
            0xE000_ED04 => {
                if v & (1 << 31) != 0 {
                    self.nvic.nmi_pending = true;
                }
                if v & (1 << 28) != 0 {
                    self.nvic.pendsv_pending = true;
                }
                if v & (1 << 27) != 0 {
                    self.nvic.pendsv_pending = false;
                }
                if v & (1 << 26) != 0 {
                    self.nvic.systick_pending = true;
                }
            }
            0xE000_ED08 => self.vtor = v & 0xFFFF_FF80,
            0xE000_ED0C => {
                if v >> 16 == 0x05FA {
                    self.nvic.prigroup = ((v >> 8) & 7) as u8;
                    if v & (1 << 2) != 0 {
                        self.reset_request = Some(ResetKind::Software);
                        self.stop = true;
                    }
                }
            }
            0xE000_ED10 => self.scr = v,
            0xE000_ED14 => self.ccr = v,
            0xE000_ED24 => self.shcsr = v,
            0xE000_ED28 => self.cfsr &= !v,
            0xE000_ED2C => self.hfsr &= !v,
            0xE000_ED88 => self.cpacr = v & (0xF << 20),
            0xE000_EDFC => self.demcr = v,
            crate::debug::DHCSR => self.dhcsr_write(v),
            a if self.fpb.write(a, v) => {}
            crate::debug::DFSR => self.dbg.dfsr &= !v,
            crate::debug::DCRDR => self.dbg.dcrdr = v,
            0xE000_EF34 => self.fpccr = v,
            a if (0xE004_2000..0xE004_2400).contains(&a) => self.mmio_write(a, 4, v),
            a => {
                self.ppb_plain_access(a);
                self.ppb_plain.insert(a, v);
            }
        }
    }

    /// A private-bus register with no model: known ones are plain storage, the others
    /// are reported.
    fn ppb_plain_access(&mut self, a: u32) {
        if !PPB_PLAIN_KNOWN
            .iter()
            .any(|&(lo, hi)| (lo..=hi).contains(&a))
        {
            *self.unmodelled.unknown_ppb.entry(a).or_default() += 1;
        }
    }

    /// The vector of exception `n`.
    pub fn vector(&self, n: u16) -> u32 {
        let mut a = self.vtor.wrapping_add(4 * n as u32);
        // Boot from main flash: address 0 aliases it (RM0440 §2.6, SYSCFG_MEMRMP = 0).
        if a < crate::elf::FLASH_BASE {
            a += crate::elf::FLASH_BASE;
        }
        let o = a.wrapping_sub(crate::elf::FLASH_BASE) as usize;
        self.flash
            .get(o..o + 4)
            .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// Priority of the control interrupt.
    pub fn control_priority(&self) -> i16 {
        self.nvic.priority(nvic::irq(ADC1_2_IRQ))
    }
}

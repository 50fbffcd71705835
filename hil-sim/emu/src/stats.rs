//! What a run measured: boots, the control interrupt's executed instructions, its
//! estimated cycles (total and per stage) and latency, the longest interrupt-masked
//! stretch, faults.

use crate::periph::rcc::ResetKind;
use crate::profile::{Stage, STAGE_COUNT};

/// A trigger that found the previous sequence unread: at `t` (ticks), with the control
/// interrupt running for `in_isr_instrs` instructions, or masked for `masked_instrs`;
/// `before_control` when the control interrupt had not run since the reset (init).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Missed {
    pub t: u64,
    pub before_control: bool,
    pub in_isr_instrs: Option<u64>,
    pub masked_instrs: Option<u64>,
    /// The block the CPU executed last (where the firmware was).
    pub pc: u32,
}

#[derive(Clone, Debug, Default)]
pub struct Stats {
    /// Resets: (time in ticks, kind); the first is the power-on.
    pub boots: Vec<(u64, ResetKind)>,
    /// Rising edges of the ADC1_2 line: control periods requested.
    pub control_requests: u64,
    pub pending_since: Option<u64>,
    /// Control interrupts completed over the whole run, and in the window: their
    /// executed instructions (sum, max).
    pub isr_count_total: u64,
    pub isr_count: u64,
    pub isr_instrs_sum: u64,
    pub isr_instrs_max: u64,
    pub isr_entered_at: Option<u64>,
    /// The same interrupts' estimated cycles (sum, max) and the cycle count at entry
    /// (before the exception entry's own cost).
    pub isr_cycles_sum: u64,
    pub isr_cycles_max: u64,
    pub isr_cycles_entered_at: Option<u64>,
    /// The longest interrupt (by cycles): when it returned (ticks), and its stages.
    pub isr_cycles_max_at: u64,
    pub isr_max_stages: [(u64, u64); STAGE_COUNT],
    /// Per stage: (instructions, cycles) of the interrupt under way, summed over the
    /// window, and the largest of one interrupt.
    pub stage_now: [(u64, u64); STAGE_COUNT],
    pub stage_sum: [(u64, u64); STAGE_COUNT],
    pub stage_max: [(u64, u64); STAGE_COUNT],
    /// The adaptation task (USART3) under way: est. cycles and control interrupts
    /// completed at its entry; over the window, its longest run from entry to return
    /// (est. cycles, the control interrupts that preempted it included), how many
    /// control periods that run spanned, and when it ended (ticks).
    pub task_entered_at: Option<(u64, u64)>,
    pub task_cycles_max: u64,
    pub task_periods_max: u64,
    pub task_max_at: u64,
    /// Longest wait from the request to the handler (instructions).
    pub latency_max: u64,
    /// Longest stretch with the control interrupt masked by PRIMASK or BASEPRI
    /// (instructions) and when it ended (ticks).
    pub masked_max: u64,
    pub masked_max_at: u64,
    pub masked_since: Option<u64>,
    /// The window is open: the control interrupt has run since the last reset (init
    /// runs masked by design and is not counted).
    pub armed: bool,
    /// Missed control periods: when, and what held the interrupt off (see `Missed`).
    pub missed: Vec<Missed>,
    /// HardFault entries: (ticks, stacked pc).
    pub hard_faults: Vec<(u64, u32)>,
    pub lockups: u64,
    /// The last TRGO2 (ticks): the sampling instant.
    pub last_trigger: u64,
}

impl Stats {
    /// Forget the interrupt figures (start a measurement window).
    pub fn restart_window(&mut self) {
        self.isr_count = 0;
        self.isr_instrs_sum = 0;
        self.isr_instrs_max = 0;
        self.isr_cycles_sum = 0;
        self.isr_cycles_max = 0;
        self.stage_sum = Default::default();
        self.stage_max = Default::default();
        self.latency_max = 0;
        self.task_cycles_max = 0;
        self.task_periods_max = 0;
        self.masked_max = 0;
        self.masked_since = None;
    }

    pub fn isr_mean(&self) -> f64 {
        self.isr_instrs_sum as f64 / self.isr_count.max(1) as f64
    }

    pub fn isr_cycles_mean(&self) -> f64 {
        self.isr_cycles_sum as f64 / self.isr_count.max(1) as f64
    }

    /// Charge `instrs` and `cycles` to `stage` of the control interrupt under way.
    pub fn charge(&mut self, stage: Stage, instrs: u64, cycles: u64) {
        let s = &mut self.stage_now[stage as usize];
        s.0 += instrs;
        s.1 += cycles;
    }

    /// The control interrupt returned: its stages into the window's sums and maxima.
    pub fn close_stages(&mut self) {
        for k in 0..STAGE_COUNT {
            let (i, c) = self.stage_now[k];
            self.stage_sum[k].0 += i;
            self.stage_sum[k].1 += c;
            self.stage_max[k].0 = self.stage_max[k].0.max(i);
            self.stage_max[k].1 = self.stage_max[k].1.max(c);
        }
        self.stage_now = Default::default();
    }
}

//! What a run measured: boots, the control interrupt's executed instructions, its
//! estimated cycles (total and per stage) and latency, the adaptation task against its
//! deadline, the longest interrupt-masked stretch, missed control periods with their
//! cause, breaks, faults.

use crate::periph::rcc::ResetKind;
use crate::profile::{Stage, STAGE_COUNT};

/// Why a TIM1 TRGO2 was a control period the firmware did not run, as the hardware
/// sees it (in this order when several hold).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MissCause {
    /// The control interrupt was still active (entered, not yet returned), whatever
    /// the ADC's flags say: the firmware clears JEOS at entry, so an interrupt up to
    /// about two periods long leaves no unread sequence behind.
    ControlRunning,
    /// The previous injected sequence was unread (JEOS still set).
    SequenceUnread,
    /// The previous sequence was still converting.
    StillConverting,
    /// The ADC was not armed for the trigger (not ready, JADSTART clear, another
    /// trigger selected) after the control interrupt had run since the reset: the
    /// trigger is lost without any flag.
    AdcNotArmed,
}

impl MissCause {
    pub fn describe(self) -> &'static str {
        match self {
            MissCause::ControlRunning => "the control interrupt still running",
            MissCause::SequenceUnread => "the previous sequence unread (JEOS set)",
            MissCause::StillConverting => "the previous sequence still converting",
            MissCause::AdcNotArmed => "the ADC not armed for the trigger",
        }
    }
}

/// A missed control period: at `t` (ticks), why, with the control interrupt running
/// for `in_isr_instrs` instructions, or masked for `masked_instrs`;
/// `before_control` when the control interrupt had not run since the reset (init).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Missed {
    pub t: u64,
    pub cause: MissCause,
    pub before_control: bool,
    pub in_isr_instrs: Option<u64>,
    pub masked_instrs: Option<u64>,
    /// The block the CPU executed last (where the firmware was).
    pub pc: u32,
}

/// The longest control interrupt: estimated cycles, executed instructions, when it
/// returned (ticks), and its stages (instructions, cycles).
#[derive(Clone, Copy, Debug, Default)]
pub struct Longest {
    pub cycles: u64,
    pub instrs: u64,
    pub at: u64,
    pub stages: [(u64, u64); STAGE_COUNT],
}

/// An over-current break: when the comparator crossed its level and when the timer
/// cleared MOE (ticks).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Break {
    pub crossing: u64,
    pub moe_cleared: u64,
}

#[derive(Clone, Debug, Default)]
pub struct Stats {
    /// Resets: (time in ticks, kind); the first is the power-on.
    pub boots: Vec<(u64, ResetKind)>,
    /// Rising edges of the ADC1_2 line: control periods requested.
    pub control_requests: u64,
    pub pending_since: Option<u64>,
    /// Control interrupts entered over the whole run (all boots): the adaptation task's
    /// deadline counts them.
    pub isr_entries: u64,
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
    /// The longest interrupt of the whole run (power-up, every boot; by cycles), never
    /// restarted: before the first window it is also that window's longest.
    pub isr_longest: Longest,
    /// Per stage: (instructions, cycles) of the interrupt under way, summed over the
    /// window, and the largest of one interrupt.
    pub stage_now: [(u64, u64); STAGE_COUNT],
    pub stage_sum: [(u64, u64); STAGE_COUNT],
    pub stage_max: [(u64, u64); STAGE_COUNT],
    /// The adaptation task (USART3) under way: est. cycles at its entry; over the
    /// window, its longest run from entry to return (est. cycles, the control interrupts
    /// that preempted it included) and when it ended (ticks). Its deadline is measured
    /// by the `task_pend` figures below.
    pub task_entered_at: Option<u64>,
    pub task_cycles_max: u64,
    pub task_max_at: u64,
    /// The deadline: the oldest pend of the task not yet served (the control
    /// interrupt's entry count when it handed the sample over), the pend the run under
    /// way serves, and over the whole run the most control interrupts entered between
    /// a sample's hand-over and the return of the run that served it (an update is in
    /// force `mras::UPDATE_LATENCY_PERIODS` periods after its sample, so the task must
    /// return before that many have entered), when, and the runs that returned late.
    pub task_pend: Option<u64>,
    pub task_serving: Option<u64>,
    pub task_from_pend_max: u64,
    pub task_from_pend_max_at: u64,
    pub task_deadline_misses: u64,
    /// Longest wait from the request to the handler (instructions).
    pub latency_max: u64,
    /// Longest stretch with the control interrupt masked by PRIMASK or BASEPRI
    /// (instructions) and when it ended (ticks), in the window and over the run.
    pub masked_max: u64,
    pub masked_max_at: u64,
    pub masked_max_run: u64,
    pub masked_since: Option<u64>,
    /// The window is open: the control interrupt has run since the last reset (init
    /// runs masked by design and is not counted).
    pub armed: bool,
    /// Missed control periods: when, why, and what held the interrupt off.
    pub missed: Vec<Missed>,
    /// HardFault entries: (ticks, stacked pc).
    pub hard_faults: Vec<(u64, u32)>,
    pub lockups: u64,
    /// NMI entries (a double ECC error of a flash read, in this firmware).
    pub nmis: u64,
    /// Over-current breaks, in order.
    pub breaks: Vec<Break>,
    /// The last TRGO2 (ticks): the sampling instant.
    pub last_trigger: u64,
    /// Comparator glitches at switching edges (a phase current near the trip level),
    /// and breaks they latched through a break filter shorter than the glitch.
    pub comparator_glitches: u64,
    pub glitch_breaks: u64,
    /// Diagnostics (`DRIVE_EMU_ISR_BLOCKS`): the control interrupt's translated blocks
    /// and their est. cycles, for the interrupt under way, the run's longest and the
    /// window's longest (`blocks_window_cycles` its length).
    pub trace_blocks: bool,
    pub blocks_now: Vec<(u32, u64)>,
    pub blocks_longest: Vec<(u32, u64)>,
    pub blocks_window: Vec<(u32, u64)>,
    pub blocks_window_cycles: u64,
    /// The same for the adaptation task's longest run (its own blocks only).
    pub task_blocks_now: Vec<(u32, u64)>,
    pub task_blocks_longest: Vec<(u32, u64)>,
    pub task_blocks_cycles: u64,
}

impl Stats {
    /// Forget the interrupt figures (start a measurement window). The whole run's
    /// longest interrupt, masked stretch, task deadline and missed periods stay.
    pub fn restart_window(&mut self) {
        self.isr_count = 0;
        self.isr_instrs_sum = 0;
        self.isr_instrs_max = 0;
        self.isr_cycles_sum = 0;
        self.isr_cycles_max = 0;
        self.blocks_window_cycles = 0;
        self.stage_sum = Default::default();
        self.stage_max = Default::default();
        self.latency_max = 0;
        self.task_cycles_max = 0;
        self.masked_max = 0;
        self.masked_since = None;
    }

    pub fn isr_mean(&self) -> f64 {
        self.isr_instrs_sum as f64 / self.isr_count.max(1) as f64
    }

    pub fn isr_cycles_mean(&self) -> f64 {
        self.isr_cycles_sum as f64 / self.isr_count.max(1) as f64
    }

    /// Missed control periods after the control interrupt first ran (init's overruns
    /// left out).
    pub fn missed_control(&self) -> usize {
        self.missed.iter().filter(|m| !m.before_control).count()
    }

    /// Charge `instrs` and `cycles` to `stage` of the control interrupt under way.
    pub fn charge(&mut self, stage: Stage, instrs: u64, cycles: u64) {
        let s = &mut self.stage_now[stage as usize];
        s.0 += instrs;
        s.1 += cycles;
    }

    /// A masked stretch of `len` instructions ended at `at`.
    pub fn masked_ended(&mut self, len: u64, at: u64) {
        if len > self.masked_max {
            self.masked_max = len;
            self.masked_max_at = at;
        }
        self.masked_max_run = self.masked_max_run.max(len);
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

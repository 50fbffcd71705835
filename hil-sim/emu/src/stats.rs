//! What a run measured: boots, the control interrupt's executed instructions and
//! latency, the longest interrupt-masked stretch, faults.

use crate::periph::rcc::ResetKind;

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
        self.latency_max = 0;
        self.masked_max = 0;
        self.masked_since = None;
    }

    pub fn isr_mean(&self) -> f64 {
        self.isr_instrs_sum as f64 / self.isr_count.max(1) as f64
    }
}

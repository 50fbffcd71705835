//! TIM1 (RM0440 §28): the centre-aligned counter, preload and the update event with the
//! repetition counter, OC4REF on TRGO2 for the ADCs, dead time, the break input and MOE.
//! The counter is computed from time, not ticked: events are the valleys (underflow),
//! the peaks (overflow) and the TRGO2 edge.

use crate::regfile::RegFile;

pub const TIM1: u32 = 0x4001_2C00;
pub const CR1: u32 = TIM1;
pub const CR2: u32 = TIM1 + 0x04;
pub const SR: u32 = TIM1 + 0x10;
pub const EGR: u32 = TIM1 + 0x14;
pub const CCMR1: u32 = TIM1 + 0x18;
pub const CCMR2: u32 = TIM1 + 0x1C;
pub const CNT: u32 = TIM1 + 0x24;
pub const PSC: u32 = TIM1 + 0x28;
pub const ARR: u32 = TIM1 + 0x2C;
pub const RCR: u32 = TIM1 + 0x30;
pub const CCR1: u32 = TIM1 + 0x34;
pub const BDTR: u32 = TIM1 + 0x44;
pub const AF1: u32 = TIM1 + 0x60;

const CR1_CEN: u32 = 1 << 0;
const CR1_CKD_SHIFT: u32 = 8;
const CR1_UDIS: u32 = 1 << 1;
const CR1_ARPE: u32 = 1 << 7;
const SR_UIF: u32 = 1 << 0;
pub const SR_BIF: u32 = 1 << 7;
pub const BDTR_MOE: u32 = 1 << 15;
/// BDTR.OSSI: with MOE = 0 the outputs are driven to their idle levels (§28.6.20).
pub const BDTR_OSSI: u32 = 1 << 10;
const BDTR_BKE: u32 = 1 << 12;
const BDTR_BKP: u32 = 1 << 13;
const BDTR_AOE: u32 = 1 << 14;
const BDTR_BKF_SHIFT: u32 = 16;
const AF1_BKINE: u32 = 1 << 0;
const AF1_BKINP: u32 = 1 << 9;
pub const CCER: u32 = TIM1 + 0x20;
/// DBGMCU_APB2FZR.DBG_TIM1_STOP (RM0440 §46.16.5): TIM1 stopped while the core is halted.
pub const DBGMCU_APB2FZR: u32 = 0xE004_2010;
pub const DBG_TIM1_STOP: u32 = 1 << 11;
/// Entries of the compare-register history kept (the sampling windows look back a few
/// microseconds: two updates suffice, a few more for writes without preload).
const CCR_HISTORY: usize = 8;

/// Timer events, in time order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Edge {
    Valley,
    Peak,
    Trgo2,
}

#[derive(Debug, Default, Clone)]
pub struct Tim1 {
    running: bool,
    /// Ticks per counter step ((PSC + 1) timer clocks).
    step: u64,
    /// Next over/underflow: time and whether it is the peak.
    next_flow: Option<(u64, bool)>,
    /// The TRGO2 rising edge in the half period under way.
    trgo2_at: Option<u64>,
    /// Active (shadow) registers, loaded at the update event.
    arr: u32,
    ccr: [u32; 4],
    /// The repetition down-counter (§28.3.3).
    rep: u32,
    rcr_active: u32,
    /// Duty bookkeeping of the bridge since the last mark: Σ duty·dt per phase, Σ dt,
    /// and whether MOE was off at any time.
    acc: [f64; 3],
    acc_ticks: u64,
    mark: u64,
    moe_dropped: bool,
    /// Update events of the counter (not UG) and over/underflows, for the
    /// one-update-per-period rule.
    pub updates: u64,
    pub peaks: u64,
    /// MOE written 1 while the break was active (refused by hardware).
    pub moe_refused: u64,
    /// MOE set by a write (0 → 1), and the time of the last one (ticks).
    pub moe_sets: u64,
    pub moe_set_at: Option<u64>,
    /// BDTR written with AOE (MOE set again by the update event), which is not modelled.
    pub aoe_writes: u64,
    /// Breaks that cleared MOE.
    pub breaks: u64,
    /// Periods the comparator was tripped with the bridge on and no break routed.
    pub breaks_unrouted: u64,
    /// The active CCR1..4 and from when each set was in force (ticks), oldest first.
    ccr_hist: Vec<(u64, [u32; 4])>,
    /// A time at which the counter was at its peak (the triangle's phase).
    anchor_peak: Option<u64>,
    /// Debug freeze (DBG_TIM1_STOP with the core halted): since when.
    frozen_at: Option<u64>,
    /// BKIN routed and floating (no pull-up) with the break enabled: times it began.
    pub bkin_floating: u64,
    /// A complementary output enabled with the polarity or idle level the gate driver
    /// does not take (`gate_polarity_wrong`): times it began.
    pub gate_polarity_wrong: u64,
    polarity_wrong_now: bool,
    floating_now: bool,
    /// TIM1_SR.BIF cleared by a write (1 → 0), and when last (ticks).
    pub bif_clears: u64,
    pub bif_cleared_at: Option<u64>,
    /// BIF latched by the break (0 → 1), and when first (ticks, since the reset).
    pub bif_sets: u64,
    pub bif_first_set_at: Option<u64>,
}

/// TIM1's output-stage registers, copied (the ADC model samples while it holds the
/// register file).
#[derive(Clone, Copy, Debug, Default)]
pub struct OutRegs {
    pub ccmr: [u32; 2],
    pub ccer: u32,
    pub bdtr: u32,
}

impl OutRegs {
    pub fn of(regs: &RegFile) -> Self {
        Self {
            ccmr: [regs.get(CCMR1), regs.get(CCMR2)],
            ccer: regs.get(CCER),
            bdtr: regs.get(BDTR),
        }
    }
}

/// Whether a phase's low side conducted over a window, and the last switching edge of
/// that phase before the window's end (ticks).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LowSide {
    pub conducts: bool,
    pub last_edge: Option<u64>,
}

impl Tim1 {
    /// Whether an enabled complementary output (CCxNE, §28.6.11) has a polarity (CCxNP)
    /// or an idle level (CR2.OISxN, §28.6.2) that turns the low side on for a gate
    /// driver whose low-side input is active low (`low_active_low`) or high: its
    /// switches would not follow OCxREF, or MOE = 0 with OSSI = 1 would hold the low
    /// side on instead of off.
    pub fn gate_polarity_wrong_for(regs: &RegFile, low_active_low: bool) -> bool {
        let (ccer, cr2, bdtr) = (regs.get(CCER), regs.get(CR2), regs.get(BDTR));
        // With MOE = 0 and OSSI = 0 the outputs are disabled (not driven by the timer):
        // the order of the configuration writes does not matter until one is set.
        if bdtr & (BDTR_MOE | BDTR_OSSI) == 0 {
            return false;
        }
        (0..3).any(|x| {
            let enabled = ccer >> (2 + 4 * x) & 1 == 1;
            let inverted = ccer >> (3 + 4 * x) & 1 == 1;
            let idle_high = cr2 >> (9 + 2 * x) & 1 == 1;
            enabled && (inverted != low_active_low || idle_high != low_active_low)
        })
    }

    /// Count a wrong gate polarity when it begins (after any TIM1 write).
    pub fn check_gate_polarity(&mut self, regs: &RegFile, low_active_low: bool) {
        let wrong = Self::gate_polarity_wrong_for(regs, low_active_low);
        if wrong && !self.polarity_wrong_now {
            self.gate_polarity_wrong += 1;
        }
        self.polarity_wrong_now = wrong;
    }

    pub fn reset(&mut self) {
        *self = Self {
            updates: self.updates,
            peaks: self.peaks,
            moe_refused: self.moe_refused,
            moe_sets: self.moe_sets,
            moe_set_at: self.moe_set_at,
            aoe_writes: self.aoe_writes,
            breaks: self.breaks,
            breaks_unrouted: self.breaks_unrouted,
            bif_clears: self.bif_clears,
            bkin_floating: self.bkin_floating,
            gate_polarity_wrong: self.gate_polarity_wrong,
            bif_sets: self.bif_sets,
            ..Self::default()
        };
    }

    /// The active compare registers changed at `t`.
    fn ccr_changed(&mut self, t: u64) {
        if self.ccr_hist.last().map(|h| h.1) == Some(self.ccr) {
            return;
        }
        self.ccr_hist.push((t, self.ccr));
        if self.ccr_hist.len() > CCR_HISTORY {
            self.ccr_hist.remove(0);
        }
    }

    /// The active CCR1..4 at `t` (as far as the history reaches).
    fn ccr_at(&self, t: u64) -> [u32; 4] {
        self.ccr_hist
            .iter()
            .rev()
            .find(|h| h.0 <= t)
            .or(self.ccr_hist.first())
            .map_or(self.ccr, |h| h.1)
    }

    /// The counter at `t` (past or future), ARR unchanged: the centre-aligned triangle
    /// through the last peak. None when the counter is not running.
    pub fn cnt_at(&self, t: u64) -> Option<(u32, bool)> {
        let peak = self.anchor_peak.filter(|_| self.running && self.arr > 0)?;
        let half = self.arr as i128 * self.step.max(1) as i128;
        let p = (t as i128 - peak as i128).rem_euclid(2 * half);
        let steps = (p / self.step.max(1) as i128) as u32;
        Some(if p < half {
            // Counting down from the peak.
            (self.arr - steps.min(self.arr), false)
        } else {
            (steps - self.arr, true)
        })
    }

    /// OCxREF of channel `k` (0-based) at `t`: PWM mode 1 active while CNT < CCR, mode 2
    /// the opposite, forced modes as forced (§28.3.13, §28.6.7); other modes are taken
    /// as PWM mode 1.
    fn ocref_at(&self, o: &OutRegs, k: usize, t: u64) -> bool {
        let ccmr = o.ccmr[k / 2];
        let sh = 8 * (k as u32 % 2);
        let m = ((ccmr >> (4 + sh)) & 0b111) | ((ccmr >> (16 + sh)) & 1) << 3;
        let Some((cnt, _)) = self.cnt_at(t) else {
            return false;
        };
        let below = cnt < self.ccr_at(t)[k];
        match m {
            0b0100 => false,
            0b0101 => true,
            0b0111 => !below,
            _ => below,
        }
    }

    /// Does the low side of phase `k` (CHxN, complementary of OCxREF with dead time)
    /// conduct throughout [`from` - `settle`, `to`]? It conducts at t when OCxREF was low
    /// over [t - dead time, t], with MOE set, the timer not frozen and CCxNE set (with
    /// CCxNE clear the output is Hi-Z or inactive, §28.6.11 table 265). The polarity
    /// bits are taken as matching the gate driver. Sampled every 4 ticks (24 ns).
    pub fn low_side(&self, o: &OutRegs, k: usize, from: u64, to: u64, settle: u64) -> LowSide {
        let enabled = o.bdtr & BDTR_MOE != 0
            && self.frozen_at.is_none()
            && o.ccer & (1 << (2 + 4 * k as u32)) != 0
            && self.running;
        let dt = Self::dead_time_of(o.bdtr) as u64;
        let start = from.saturating_sub(settle + dt);
        // Look back a further half period for the last edge (the ringing's origin).
        let look = start.saturating_sub(self.arr as u64 * self.step);
        let mut conducts = enabled;
        let mut last_edge = None;
        let mut prev = None;
        let mut t = look;
        while t <= to {
            let r = self.ocref_at(o, k, t);
            if prev.is_some_and(|p| p != r) {
                last_edge = Some(t);
            }
            if t >= start && r {
                conducts = false;
            }
            prev = Some(r);
            t += 4;
        }
        if self.ocref_at(o, k, to) {
            conducts = false;
        }
        LowSide {
            conducts,
            last_edge,
        }
    }

    /// The BKIN pin is (or is not) routed and floating with the break enabled: counts
    /// the times it begins.
    pub fn note_bkin_floating(&mut self, floating: bool) {
        if floating && !self.floating_now {
            self.bkin_floating += 1;
        }
        self.floating_now = floating;
    }

    /// Is the bridge driven now (running, MOE set, not frozen by the debug halt)?
    pub fn bridge_on(&self, regs: &RegFile) -> bool {
        self.running && Self::moe(regs) && self.frozen_at.is_none()
    }

    /// The core halted with DBG_TIM1_STOP set (RM0440 §28.3.31, Debug mode): the counter
    /// stops and the outputs are disabled as if MOE were reset (OSSI: inactive level or
    /// released to the GPIO, Hi-Z; neither drives a low side here).
    pub fn freeze(&mut self, regs: &RegFile, now: u64) {
        if self.frozen_at.is_none() {
            self.mark(regs, now);
            self.frozen_at = Some(now);
            self.moe_dropped = true;
        }
    }

    /// The core resumed: the counter continues where it stopped.
    pub fn unfreeze(&mut self, regs: &RegFile, now: u64) {
        if let Some(t0) = self.frozen_at.take() {
            let d = now.saturating_sub(t0);
            self.next_flow = self.next_flow.map(|(t, p)| (t + d, p));
            self.trgo2_at = self.trgo2_at.map(|t| t + d);
            self.anchor_peak = self.anchor_peak.map(|t| t + d);
            for h in &mut self.ccr_hist {
                h.0 += d;
            }
            self.mark = now;
            self.moe_dropped = !Self::moe(regs);
        }
    }

    pub fn frozen(&self) -> bool {
        self.frozen_at.is_some()
    }

    /// The PWM period (ticks) of the running counter: up to ARR and down again, (PSC + 1)
    /// ticks per step; 0 before the counter started.
    pub fn period_ticks(&self) -> u64 {
        2 * self.arr as u64 * self.step
    }

    pub fn moe(regs: &RegFile) -> bool {
        regs.bit(BDTR, BDTR_MOE)
    }

    /// The duties currently driven (centre-aligned PWM mode 1: high side on while
    /// CNT < CCR, a fraction CCR/ARR of each half period).
    fn duties(&self) -> [f64; 3] {
        let arr = self.arr.max(1) as f64;
        [0, 1, 2].map(|k| (self.ccr[k] as f64 / arr).clamp(0.0, 1.0))
    }

    /// Close the duty segment up to `now`.
    pub fn mark(&mut self, regs: &RegFile, now: u64) {
        let dt = now.saturating_sub(self.mark);
        if self.frozen_at.is_some() {
            self.moe_dropped = true;
        } else if dt > 0 {
            let d = self.duties();
            for (a, d) in self.acc.iter_mut().zip(d) {
                *a += d * dt as f64;
            }
            self.acc_ticks += dt;
        }
        if !Self::moe(regs) {
            self.moe_dropped = true;
        }
        self.mark = now;
    }

    /// What the bridge drove since the last call: mean duties and whether it was on all
    /// the time. Starts a new interval.
    pub fn take_applied(&mut self, regs: &RegFile, now: u64) -> ([f32; 3], bool) {
        self.mark(regs, now);
        let n = self.acc_ticks.max(1) as f64;
        let d = self.acc.map(|a| (a / n) as f32);
        let on = !self.moe_dropped && self.acc_ticks > 0 && self.running;
        self.acc = [0.0; 3];
        self.acc_ticks = 0;
        self.moe_dropped = !Self::moe(regs);
        (d, on)
    }

    /// A bus write to a TIM1 register (already applied with its semantics).
    pub fn on_write(&mut self, regs: &mut RegFile, addr: u32, old: u32, now: u64, break_in: bool) {
        self.mark(regs, now);
        match addr {
            SR if old & SR_BIF != 0 && !regs.bit(SR, SR_BIF) => {
                self.bif_clears += 1;
                self.bif_cleared_at = Some(now);
            }
            CR1 => {
                let cr1 = regs.get(CR1);
                if cr1 & CR1_CEN != 0 && old & CR1_CEN == 0 {
                    self.start(regs, now);
                } else if cr1 & CR1_CEN == 0 {
                    self.running = false;
                    self.next_flow = None;
                    self.trgo2_at = None;
                }
            }
            EGR if regs.get(EGR) & 1 != 0 => {
                // UG: counter to 0, update event, repetition counter reloaded (§28.6.6).
                regs.set(EGR, 0);
                regs.set(CNT, 0);
                self.rep = 0;
                self.update_event(regs, true, now);
                if self.running {
                    self.start(regs, now);
                }
            }
            ARR if regs.get(CR1) & CR1_ARPE == 0 => self.arr = regs.get(ARR),
            a if (CCR1..CCR1 + 16).contains(&a) => {
                let k = ((a - CCR1) / 4) as usize;
                if !self.preloaded(regs, k) {
                    self.ccr[k] = regs.get(a);
                    self.ccr_changed(now);
                }
            }
            BDTR => {
                let bdtr = regs.get(BDTR);
                if bdtr & BDTR_AOE != 0 {
                    self.aoe_writes += 1;
                }
                if bdtr & BDTR_MOE != 0 && old & BDTR_MOE == 0 {
                    if break_in && bdtr & BDTR_BKE != 0 {
                        // §28.3.21: MOE cannot be set while the break input is active.
                        regs.set_bits(BDTR, BDTR_MOE, false);
                        self.moe_refused += 1;
                    } else {
                        self.moe_sets += 1;
                        self.moe_set_at = Some(now);
                    }
                }
            }
            _ => {}
        }
        if !Self::moe(regs) {
            self.moe_dropped = true;
        }
        regs.set(EGR, 0);
    }

    fn preloaded(&self, regs: &RegFile, k: usize) -> bool {
        let ccmr = if k < 2 {
            regs.get(CCMR1)
        } else {
            regs.get(CCMR2)
        };
        ccmr & (1 << (3 + 8 * (k as u32 % 2))) != 0
    }

    fn start(&mut self, regs: &RegFile, now: u64) {
        self.running = true;
        self.step = (regs.get(PSC) as u64 & 0xFFFF) + 1;
        if self.arr == 0 {
            self.arr = regs.get(ARR);
        }
        self.mark = now;
        // Counting up from CNT.
        let cnt = regs.get(CNT) as u64;
        let to_peak = (self.arr as u64).saturating_sub(cnt) * self.step;
        self.next_flow = Some((now + to_peak, true));
        self.anchor_peak = Some(now + to_peak);
        self.ccr_changed(now);
        self.schedule_trgo2(regs, now, now - cnt * self.step, true);
    }

    /// The update event: shadow registers loaded (§28.3.3, §28.3.10).
    fn update_event(&mut self, regs: &mut RegFile, forced: bool, t: u64) {
        if regs.bit(CR1, CR1_UDIS) && !forced {
            return;
        }
        // The rule counts the counter's own update events; a UG (init, after each reset)
        // is the firmware's, once per start.
        self.updates += u64::from(!forced);
        self.arr = regs.get(ARR);
        for k in 0..4 {
            self.ccr[k] = regs.get(CCR1 + 4 * k as u32);
        }
        self.ccr_changed(t);
        self.rcr_active = regs.get(RCR) & 0xFFFF;
        regs.set_bits(SR, SR_UIF, true);
    }

    /// The OC4REF rising edge in the half period that starts at `t_from` (counting up
    /// from the valley if `up`): PWM mode 2 rises on the up-count at CNT = CCR4, mode 1
    /// on the down-count (§28.3.16).
    fn schedule_trgo2(&mut self, regs: &RegFile, now: u64, t_valley_or_peak: u64, up: bool) {
        self.trgo2_at = None;
        if (regs.get(CR2) >> 20) & 0xF != 0b0111 {
            return;
        }
        let ccmr2 = regs.get(CCMR2);
        let oc4m = ((ccmr2 >> 12) & 0b111) | ((ccmr2 >> 24) & 1) << 3;
        let c4 = self.ccr[3].min(self.arr) as u64;
        let arr = self.arr as u64;
        let t = match (oc4m, up) {
            (0b0111, true) => t_valley_or_peak + c4 * self.step,
            (0b0110, false) => t_valley_or_peak + (arr - c4) * self.step,
            _ => return,
        };
        if t >= now {
            self.trgo2_at = Some(t);
        }
    }

    pub fn next_event(&self) -> Option<(u64, Edge)> {
        if self.frozen_at.is_some() {
            return None;
        }
        let flow = self
            .next_flow
            .map(|(t, peak)| (t, if peak { Edge::Peak } else { Edge::Valley }));
        match (flow, self.trgo2_at) {
            (Some(f), Some(t)) if t <= f.0 => Some((t, Edge::Trgo2)),
            (f, None) => f,
            (Some(f), Some(_)) => Some(f),
            (None, Some(t)) => Some((t, Edge::Trgo2)),
        }
    }

    /// Process the event at its time `t`; the caller acts on TRGO2.
    pub fn fire(&mut self, regs: &mut RegFile, t: u64, e: Edge) {
        match e {
            Edge::Trgo2 => self.trgo2_at = None,
            Edge::Peak | Edge::Valley => {
                self.mark(regs, t);
                let peak = e == Edge::Peak;
                if peak {
                    self.peaks += 1;
                }
                // §28.3.3: the repetition counter counts over- and underflows; the
                // update event comes when it is zero, and reloads it from RCR. After
                // UG it starts at zero, so an odd RCR updates at the overflows.
                if peak {
                    self.anchor_peak = Some(t);
                }
                if self.rep == 0 {
                    self.update_event(regs, false, t);
                    self.rep = self.rcr_active;
                } else {
                    self.rep -= 1;
                }
                let half = self.arr as u64 * self.step;
                self.next_flow = Some((t + half, !peak));
                self.schedule_trgo2(regs, t, t, !peak);
            }
        }
    }

    /// The counter value at `now` (centre-aligned).
    pub fn cnt(&self, now: u64) -> u32 {
        match self.next_flow {
            Some((t, peak)) if self.running => {
                let left = (t.saturating_sub(now) / self.step.max(1)) as u32;
                if peak {
                    self.arr.saturating_sub(left)
                } else {
                    left.min(self.arr)
                }
            }
            _ => 0,
        }
    }

    /// The break input as TIM1 sees it: the BKIN pin (active low unless BKINP) routed by
    /// AF1.BKINE (§28.6.27), and the core lockup when SYSCFG_CFGR2.CLL routes it.
    pub fn break_input(regs: &RegFile, pin_low: bool, lockup: bool) -> bool {
        let af1 = regs.get(AF1);
        // BKP gives the active level (0: low); BKINP inverts the pin before it.
        let active_low = !regs.bit(BDTR, BDTR_BKP);
        let pin_active = (pin_low == active_low) != (af1 & AF1_BKINP != 0);
        (af1 & AF1_BKINE != 0 && pin_active) || lockup
    }

    /// Apply the break (§28.3.21): MOE cleared asynchronously, BIF set. Returns
    /// whether it cleared MOE.
    pub fn apply_break(&mut self, regs: &mut RegFile, now: u64, active: bool) -> bool {
        if !(active && regs.bit(BDTR, BDTR_BKE)) {
            return false;
        }
        self.mark(regs, now);
        let cleared = regs.bit(BDTR, BDTR_MOE);
        if cleared {
            self.breaks += 1;
        }
        regs.set_bits(BDTR, BDTR_MOE, false);
        if !regs.bit(SR, SR_BIF) {
            self.bif_sets += 1;
            self.bif_first_set_at.get_or_insert(now);
        }
        regs.set_bits(SR, SR_BIF, true);
        self.moe_dropped = true;
        cleared
    }

    /// Would an active-low comparator output on the BKIN pin break the bridge now:
    /// break enabled, the pin routed (AF1.BKINE), the polarity (BKP, BKINP) such that
    /// low is active, and MOE on?
    pub fn break_armed_for_low_pin(regs: &RegFile) -> bool {
        regs.bit(BDTR, BDTR_BKE)
            && Self::moe(regs)
            && Self::break_input(regs, true, false)
            && !Self::break_input(regs, false, false)
    }

    /// The break input filter's latency (s): N consecutive samples at f_SAMPLING
    /// (TIMx_BDTR.BKF, RM0440 §28.6.20), f_DTS from CR1.CKD; 0 without a filter (the
    /// break acts asynchronously). `timer_clock_hz` is f_tim_ker_ck (= f_CK_INT). The
    /// sampling phase is not modelled: N whole sampling periods.
    pub fn break_filter_s(regs: &RegFile, timer_clock_hz: f64) -> f64 {
        let bkf = (regs.get(BDTR) >> BDTR_BKF_SHIFT) & 0xF;
        let dts_div = match (regs.get(CR1) >> CR1_CKD_SHIFT) & 0b11 {
            0 => 1.0,
            1 => 2.0,
            _ => 4.0,
        };
        // (divider of f_CK_INT, or of f_DTS when `dts`; N)
        let (dts, div, n) = match bkf {
            0 => return 0.0,
            1 => (false, 1.0, 2.0),
            2 => (false, 1.0, 4.0),
            3 => (false, 1.0, 8.0),
            4 => (true, 2.0, 6.0),
            5 => (true, 2.0, 8.0),
            6 => (true, 4.0, 6.0),
            7 => (true, 4.0, 8.0),
            8 => (true, 8.0, 6.0),
            9 => (true, 8.0, 8.0),
            10 => (true, 16.0, 5.0),
            11 => (true, 16.0, 6.0),
            12 => (true, 16.0, 8.0),
            13 => (true, 32.0, 5.0),
            14 => (true, 32.0, 6.0),
            _ => (true, 32.0, 8.0),
        };
        let f_sampling = timer_clock_hz / if dts { dts_div * div } else { div };
        n / f_sampling
    }

    /// Dead time in ticks from BDTR.DTG (§28.6.20, t_DTS = t_CK_INT with CKD = 0).
    pub fn dead_time_ticks(regs: &RegFile) -> u32 {
        Self::dead_time_of(regs.get(BDTR))
    }

    /// Dead time in ticks of a BDTR value.
    pub fn dead_time_of(bdtr: u32) -> u32 {
        let dtg = bdtr & 0xFF;
        match dtg >> 5 {
            0..=3 => dtg,
            4 | 5 => (64 + (dtg & 0x3F)) * 2,
            6 => (32 + (dtg & 0x1F)) * 8,
            _ => (32 + (dtg & 0x1F)) * 16,
        }
    }
}

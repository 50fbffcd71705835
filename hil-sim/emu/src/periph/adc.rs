//! ADC1 and ADC2 (RM0440 §21): the power-up sequence with its timing rules, and the
//! dual injected-simultaneous conversion triggered by TIM1 TRGO2.

use crate::regfile::RegFile;

pub const ADC1: u32 = 0x5000_0000;
pub const ADC2: u32 = 0x5000_0100;
pub const COMMON_CCR: u32 = 0x5000_0308;
pub const ISR: u32 = 0x00;
pub const IER: u32 = 0x04;
pub const CR: u32 = 0x08;
const SMPR1: u32 = 0x14;
const SMPR2: u32 = 0x18;
const JSQR: u32 = 0x4C;
const JDR1: u32 = 0x80;

const ISR_ADRDY: u32 = 1 << 0;
const ISR_JEOC: u32 = 1 << 5;
pub const ISR_JEOS: u32 = 1 << 6;
const CR_ADEN: u32 = 1 << 0;
const CR_ADDIS: u32 = 1 << 1;
const CR_JADSTART: u32 = 1 << 3;
const CR_ADVREGEN: u32 = 1 << 28;
const CR_DEEPPWD: u32 = 1 << 29;
const CR_ADCAL: u32 = 1 << 31;

/// t_ADCVREG_STUP: the regulator's start-up time (§21.4.6, DS12288), 20 µs.
const T_VREG_S: f64 = 20.0e-6;
/// Calibration: 116 ADC clock cycles (§21.4.8, DS12288 t_CAL).
const CAL_CLOCKS: u64 = 116;
/// §21.4.9 / ST's ADC_Enable: ADEN set within 4 ADC clocks of ADCAL clearing is reset
/// by the calibration logic.
const ADEN_BLANK_CLOCKS: u64 = 4;
/// ADRDY after ADEN: t_STAB, one conversion's worth of clocks.
const STAB_CLOCKS: u64 = 15;
/// JEXTSEL of TIM1_TRGO2 for ADC1/2 (§21.4.18 table 163).
const JEXTSEL_TIM1_TRGO2: u32 = 8;
/// DUAL = 00101: injected simultaneous mode only (§21.7.2).
const DUAL_INJECTED_SIMULTANEOUS: u32 = 0b00101;

/// One converter's timing state.
#[derive(Debug, Default, Clone)]
pub struct Converter {
    vreg_on_at: Option<u64>,
    cal_done_at: Option<u64>,
    cal_ended_at: Option<u64>,
    rdy_at: Option<u64>,
    /// Conversion results and when the sequence ends.
    pending: Option<(u64, [u16; 4], u32)>,
}

/// What broke a rule, counted for the tests.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct AdcViolations {
    /// ADEN written within 4 ADC clocks of the end of calibration: ignored.
    pub aden_ignored: u32,
    /// ADCAL started in deep power-down or before the regulator settled.
    pub cal_without_regulator: u32,
    /// ADCAL or ADEN with no ADC clock (CKMODE = 0 and no kernel clock selected).
    pub no_clock: u32,
}

#[derive(Debug, Default, Clone)]
pub struct Adcs {
    pub conv: [Converter; 2],
    pub violations: AdcViolations,
    /// Triggers that started a sequence.
    pub triggers: u64,
}

/// What a TIM1 TRGO2 found on ADC1 (the master of the dual sequence).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trigger {
    /// Not ready, JADSTART clear, or listening to another trigger: the trigger is lost
    /// and no flag says so.
    NotArmed,
    /// A sequence started; the previous one was unread (JEOS set) or still converting.
    Started { unread: bool, converting: bool },
}

fn base(i: usize) -> u32 {
    [ADC1, ADC2][i]
}

impl Adcs {
    pub fn reset(&mut self) {
        *self = Self {
            violations: self.violations,
            triggers: self.triggers,
            ..Self::default()
        };
    }

    /// ADC clock period in ticks: synchronous HCLK/1, /2, /4 (CKMODE, §21.4.3); the
    /// asynchronous kernel clock needs RCC_CCIPR.ADC12SEL (SYSCLK assumed when set).
    fn clock_ticks(regs: &RegFile) -> Option<u64> {
        match (regs.get(COMMON_CCR) >> 16) & 0b11 {
            1 => Some(1),
            2 => Some(2),
            3 => Some(4),
            _ => ((regs.get(crate::periph::rcc::CCIPR) >> 28) & 0b11 != 0).then_some(1),
        }
    }

    /// Bring the lazily timed bits up to `now`: ADCAL clearing, ADRDY setting.
    pub fn update(&mut self, regs: &mut RegFile, now: u64) {
        for (i, c) in self.conv.iter_mut().enumerate() {
            let b = base(i);
            if let Some(t) = c.cal_done_at.filter(|&t| t <= now) {
                regs.set_bits(b + CR, CR_ADCAL, false);
                c.cal_done_at = None;
                c.cal_ended_at = Some(t);
            }
            if let Some(_t) = c.rdy_at.filter(|&t| t <= now) {
                regs.set_bits(b + ISR, ISR_ADRDY, true);
                c.rdy_at = None;
            }
        }
    }

    /// ADC_CR write of `v` (already applied with its rs semantics) at `now`.
    pub fn on_cr_write(&mut self, regs: &mut RegFile, i: usize, old: u32, v: u32, now: u64) {
        self.update(regs, now);
        let b = base(i);
        let clk = Self::clock_ticks(regs);
        let c = &mut self.conv[i];
        let cr = regs.get(b + CR);
        if cr & CR_DEEPPWD != 0 || cr & CR_ADVREGEN == 0 {
            c.vreg_on_at = None;
        } else if old & CR_ADVREGEN == 0 || c.vreg_on_at.is_none() {
            c.vreg_on_at = Some(now);
        }
        if v & CR_ADCAL != 0 && old & CR_ADCAL == 0 {
            let settled = c
                .vreg_on_at
                .is_some_and(|t| now >= t + super::ticks(T_VREG_S));
            if !settled || cr & CR_ADEN != 0 {
                self.violations.cal_without_regulator += 1;
            }
            match clk {
                Some(k) => c.cal_done_at = Some(now + CAL_CLOCKS * k),
                None => self.violations.no_clock += 1,
            }
        }
        if v & CR_ADEN != 0 && old & CR_ADEN == 0 {
            let blanked = c
                .cal_ended_at
                .zip(clk)
                .is_some_and(|(t, k)| now < t + ADEN_BLANK_CLOCKS * k);
            let calibrating = cr & CR_ADCAL != 0;
            let powered = c.vreg_on_at.is_some();
            if blanked || calibrating || !powered {
                if blanked {
                    self.violations.aden_ignored += 1;
                }
                regs.set_bits(b + CR, CR_ADEN, false);
            } else if let Some(k) = clk {
                c.rdy_at = Some(now + STAB_CLOCKS * k);
            } else {
                self.violations.no_clock += 1;
            }
        }
        if v & CR_ADDIS != 0 {
            regs.set_bits(b + CR, CR_ADEN | CR_ADDIS | CR_JADSTART, false);
            regs.set_bits(b + ISR, ISR_ADRDY, false);
        }
        if v & CR_JADSTART != 0 && !regs.bit(b + ISR, ISR_ADRDY) {
            // §21.4.15: JADSTART is only accepted with the ADC ready.
            regs.set_bits(b + CR, CR_JADSTART, false);
        }
    }

    fn ready(regs: &RegFile, i: usize) -> bool {
        let b = base(i);
        regs.bit(b + CR, CR_ADEN) && regs.bit(b + ISR, ISR_ADRDY)
    }

    /// Conversion time of one channel: sampling + 12.5 clocks (§21.4.12), in ADC clocks
    /// times two (half clocks).
    fn conv_half_clocks(regs: &RegFile, i: usize, ch: u32) -> u64 {
        let b = base(i);
        let smp = if ch < 10 {
            (regs.get(b + SMPR1) >> (3 * ch)) & 0b111
        } else {
            (regs.get(b + SMPR2) >> (3 * (ch - 10))) & 0b111
        };
        let sample2 = [5, 13, 25, 49, 95, 185, 495, 1281][smp as usize];
        sample2 + 25
    }

    /// TIM1 TRGO2 rose at `now`: start the injected sequences that listen to it.
    /// `sample(adc, channel)` is the analog front end at this instant, in counts.
    pub fn trgo2(
        &mut self,
        regs: &mut RegFile,
        now: u64,
        sample: &dyn Fn(usize, u32) -> u16,
    ) -> Trigger {
        self.update(regs, now);
        let jsqr = regs.get(ADC1 + JSQR);
        let armed = Self::ready(regs, 0)
            && regs.bit(ADC1 + CR, CR_JADSTART)
            && (jsqr >> 7) & 0b11 != 0
            && (jsqr >> 2) & 0x1F == JEXTSEL_TIM1_TRGO2;
        let Some(clk) = Self::clock_ticks(regs).filter(|_| armed) else {
            return Trigger::NotArmed;
        };
        self.triggers += 1;
        let dual = regs.get(COMMON_CCR) & 0x1F == DUAL_INJECTED_SIMULTANEOUS;
        let found = Trigger::Started {
            unread: regs.bit(ADC1 + ISR, ISR_JEOS),
            converting: self.conv[0].pending.is_some(),
        };
        for i in 0..2 {
            if i == 1 && !(dual && Self::ready(regs, 1)) {
                continue;
            }
            let b = base(i);
            let jsqr = regs.get(b + JSQR);
            let n = (jsqr & 0b11) as usize + 1;
            let mut vals = [0u16; 4];
            let mut half_clocks = 0;
            for (k, v) in vals.iter_mut().enumerate().take(n) {
                let ch = (jsqr >> [9, 15, 21, 27][k]) & 0x1F;
                *v = sample(i, ch);
                half_clocks += Self::conv_half_clocks(regs, i, ch);
            }
            let end = now + half_clocks * clk / 2;
            self.conv[i].pending = Some((end, vals, n as u32));
        }
        found
    }

    /// The next end of a sequence.
    pub fn next_event(&self) -> Option<u64> {
        self.conv
            .iter()
            .filter_map(|c| c.pending.map(|p| p.0))
            .min()
    }

    /// Sequences that ended by `now`: data and flags (JEOC, JEOS). Returns whether the
    /// ADC1_2 interrupt line is high.
    pub fn complete(&mut self, regs: &mut RegFile, now: u64) {
        for i in 0..2 {
            let b = base(i);
            if let Some((t, vals, n)) = self.conv[i].pending {
                if t <= now {
                    for (k, v) in vals.iter().enumerate().take(n as usize) {
                        regs.set(b + JDR1 + 4 * k as u32, *v as u32);
                    }
                    regs.set_bits(b + ISR, ISR_JEOC | ISR_JEOS, true);
                    self.conv[i].pending = None;
                }
            }
        }
    }

    /// The ADC1_2 interrupt line: any enabled flag of either ADC (§21.5).
    pub fn irq_line(regs: &RegFile) -> bool {
        (0..2).any(|i| {
            let b = base(i);
            regs.get(b + ISR) & regs.get(b + IER) & 0x7FF != 0
        })
    }
}

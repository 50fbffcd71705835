//! ADC1 and ADC2 (RM0440 §21): the power-up sequence with its timing rules, and the
//! dual injected-simultaneous conversion triggered by TIM1 TRGO2.

use crate::regfile::RegFile;

pub const ADC1: u32 = 0x5000_0000;
pub const ADC2: u32 = 0x5000_0100;
pub const COMMON_CCR: u32 = 0x5000_0308;
pub const ISR: u32 = 0x00;
pub const IER: u32 = 0x04;
pub const CR: u32 = 0x08;
const CFGR: u32 = 0x0C;
const SMPR1: u32 = 0x14;
const SMPR2: u32 = 0x18;
const SQR1: u32 = 0x30;
const DR: u32 = 0x40;
const JSQR: u32 = 0x4C;
const JDR1: u32 = 0x80;
const ISR_EOC: u32 = 1 << 2;
const ISR_EOS: u32 = 1 << 3;
const CR_ADSTART: u32 = 1 << 2;
/// ADC_CCR fields writable only with both ADCs disabled (RM0440 §21.7.2: "software is
/// allowed to write these bits only when the ADCs are disabled"): CKMODE and DUAL.
const CCR_LOCKED_WITH_ADEN: u32 = 0b11 << 16 | 0x1F;
/// The trigger's latency to the start of sampling in synchronous clock mode
/// (CKMODE ≠ 00, no jitter), in eighths of an ADC clock: 2.625 ADC clock cycles, as
/// recalled from RM0440 §21.4.3's latency table (the table was not found in the
/// reference pages at hand: check it).
const TRIGGER_LATENCY_EIGHTHS: u64 = 21;
/// ES0430 (STM32G471/473/474/483/484 errata; ES0431 is the G431/441 sheet with the same
/// ADC limitation) "Wrong ADC result if conversion done late after calibration or
/// previous conversion": a conversion more than 1 ms after the ADC's previous
/// conversion or calibration may give a wrong result; workaround, a dummy conversion
/// whose result is dropped.
const ERRATUM_IDLE_S: f64 = 1.0e-3;
/// How wrong: the errata gives no figure; modelled as a fixed error of 256 counts
/// (6 % of full scale), far outside any noise, so that a used one shows.
const ERRATUM_ERROR_COUNTS: i32 = 256;

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
    pending: Option<Pending>,
    /// The end of the last conversion or calibration (for the errata's 1 ms).
    last_activity: Option<u64>,
    /// Results held in JDR1..4 (and DR, index 4) that the erratum made wrong.
    wrong: [bool; 5],
}

/// A sequence under way.
#[derive(Debug, Clone, Copy)]
struct Pending {
    end: u64,
    vals: [u16; 4],
    n: usize,
    wrong: [bool; 4],
    how: Started,
}

/// How a sequence was started, which says how it ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Started {
    /// The injected sequence by TIM1 TRGO2: JDRx, JEOC/JEOS.
    Trigger,
    /// The injected sequence by software: the same, and JADSTART cleared.
    Injected,
    /// A regular (software) conversion: DR, EOC/EOS, ADSTART cleared.
    Regular,
}

/// What an ADC_CR write asks the machine to start (it has the analog inputs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SoftStart {
    None,
    /// JADSTART with JEXTEN = 00: the injected sequence now (both ADCs in dual mode
    /// when written on the master).
    Injected(usize),
    /// ADSTART with EXTEN = 00: the regular sequence now.
    Regular(usize),
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
    /// Conversions the ES0430 erratum hit (more than 1 ms after the ADC's previous
    /// conversion or calibration): not a fault by itself (a dummy conversion is).
    pub late_conversions: u32,
    /// Wrong results of such conversions read by software (JDRx, DR): the dummy
    /// conversion missing or its result used.
    pub late_results_read: u32,
    /// TIM1 TRGO2 edges with JEXTEN other than 01 (rising): 10 loses the trigger at the
    /// rising edge, 11 converts at both edges (§21.4.18 table 162).
    pub jexten_not_rising: u32,
    /// ADC_CCR.CKMODE or DUAL written with an ADC enabled: refused (§21.7.2).
    pub common_write_refused: u32,
    /// Dual injected-simultaneous triggers with sequences of different lengths or a
    /// simultaneous pair of different sampling times (§21.4.31: same length, and the
    /// pair's conversions of equal duration, or the ADCs lose synchronism).
    pub dual_mismatch: u32,
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
    /// A sequence started, the previous one unread (JEOS set); or, with `converting`,
    /// the trigger was ignored (§21.4.18) because the previous one still converts.
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
                c.last_activity = Some(t);
            }
            if let Some(_t) = c.rdy_at.filter(|&t| t <= now) {
                regs.set_bits(b + ISR, ISR_ADRDY, true);
                c.rdy_at = None;
            }
        }
    }

    /// ADC_CR write of `v` (already applied with its rs semantics) at `now`.
    pub fn on_cr_write(
        &mut self,
        regs: &mut RegFile,
        i: usize,
        old: u32,
        v: u32,
        now: u64,
    ) -> SoftStart {
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
        let cr = regs.get(b + CR);
        let enabled = cr & CR_ADEN != 0 && cr & CR_ADDIS == 0;
        if v & CR_JADSTART != 0 && !enabled {
            // §21.6.3 (ADC_CR.JADSTART): software may set it only with ADEN = 1 and
            // ADDIS = 0; ST gates on ADEN, not ADRDY.
            regs.set_bits(b + CR, CR_JADSTART, false);
        }
        if v & CR_ADSTART != 0 && !enabled {
            regs.set_bits(b + CR, CR_ADSTART, false);
        }
        let cr = regs.get(b + CR);
        let rose = |bit: u32| v & bit != 0 && old & bit == 0 && cr & bit != 0;
        // JEXTEN / EXTEN = 00: a software trigger starts the sequence at once.
        if rose(CR_JADSTART) && (regs.get(b + JSQR) >> 7) & 0b11 == 0 {
            return SoftStart::Injected(i);
        }
        if rose(CR_ADSTART) && (regs.get(b + CFGR) >> 10) & 0b11 == 0 {
            return SoftStart::Regular(i);
        }
        SoftStart::None
    }

    /// Enabled (ADEN): ST's gate for JADSTART and triggers; a trigger before ADRDY
    /// starts converting once the ADC is ready.
    fn ready(regs: &RegFile, i: usize) -> bool {
        regs.bit(base(i) + CR, CR_ADEN)
    }

    /// Sampling time of a channel in half ADC clocks (SMPRx, §21.4.12, 2.5..640.5).
    fn sample_half_clocks(regs: &RegFile, i: usize, ch: u32) -> u64 {
        let b = base(i);
        let smp = if ch < 10 {
            (regs.get(b + SMPR1) >> (3 * ch)) & 0b111
        } else {
            (regs.get(b + SMPR2) >> (3 * (ch.min(19) - 10))) & 0b111
        };
        [5, 13, 25, 49, 95, 185, 495, 1281][smp as usize]
    }

    /// The injected channels of ADC `i` (JSQ1..JSQ(JL+1)).
    fn injected_channels(regs: &RegFile, i: usize) -> Vec<u32> {
        let jsqr = regs.get(base(i) + JSQR);
        let n = (jsqr & 0b11) as usize + 1;
        (0..n)
            .map(|k| (jsqr >> [9, 15, 21, 27][k]) & 0x1F)
            .collect()
    }

    /// The regular channels of ADC `i` (SQ1.., the first four).
    fn regular_channels(regs: &RegFile, i: usize) -> Vec<u32> {
        let sqr1 = regs.get(base(i) + SQR1);
        let n = ((sqr1 & 0xF) as usize + 1).min(4);
        (0..n)
            .map(|k| (sqr1 >> [6, 12, 18, 24][k]) & 0x1F)
            .collect()
    }

    /// Convert `chans` on ADC `i` from the trigger at `t0`: each conversion samples over
    /// its own window after the trigger latency (`sample(adc, channel, window start,
    /// window end)`, the hold instant at the end) and takes its sampling time + 12.5
    /// clocks (§21.4.12). Returns the end of the sequence.
    fn convert(
        &mut self,
        regs: &RegFile,
        i: usize,
        chans: &[u32],
        t0: u64,
        clk: u64,
        sample: &mut dyn FnMut(usize, u32, u64, u64) -> u16,
    ) -> ([u16; 4], [bool; 4], u64) {
        let idle = super::ticks(ERRATUM_IDLE_S);
        // Times in eighths of a tick, to keep the half clocks exact.
        let mut t8 = t0 * 8 + TRIGGER_LATENCY_EIGHTHS * clk;
        let (mut vals, mut wrong) = ([0u16; 4], [false; 4]);
        for (k, &ch) in chans.iter().enumerate().take(4) {
            let smp = Self::sample_half_clocks(regs, i, ch);
            let ws = t8 / 8;
            let we = (t8 + smp * clk * 4) / 8;
            let mut v = sample(i, ch, ws, we);
            let c = &mut self.conv[i];
            if c.last_activity.is_none_or(|a| ws > a + idle) {
                self.violations.late_conversions += 1;
                v = (v as i32 + ERRATUM_ERROR_COUNTS).clamp(0, 4095) as u16;
                wrong[k] = true;
            }
            t8 += (smp + 25) * clk * 4;
            c.last_activity = Some(t8.div_ceil(8));
            vals[k] = v;
        }
        (vals, wrong, t8.div_ceil(8))
    }

    /// ADC `i` starts converting `chans` at `now` (or once ready, if a trigger came
    /// before ADRDY): the sequence under way until its end.
    fn begin(
        &mut self,
        regs: &RegFile,
        i: usize,
        chans: &[u32],
        now: u64,
        how: Started,
        sample: &mut dyn FnMut(usize, u32, u64, u64) -> u16,
    ) {
        // Both callers start only with an ADC clock.
        let Some(clk) = Self::clock_ticks(regs) else {
            return;
        };
        let t0 = self.conv[i].rdy_at.map_or(now, |r| r.max(now));
        let (vals, wrong, end) = self.convert(regs, i, chans, t0, clk, sample);
        self.conv[i].pending = Some(Pending {
            end,
            vals,
            n: chans.len().min(4),
            wrong,
            how,
        });
    }

    /// Start the sequences of a software trigger (see [`SoftStart`]).
    pub fn software_start(
        &mut self,
        regs: &mut RegFile,
        what: SoftStart,
        now: u64,
        sample: &mut dyn FnMut(usize, u32, u64, u64) -> u16,
    ) {
        if Self::clock_ticks(regs).is_none() {
            return;
        }
        let dual = regs.get(COMMON_CCR) & 0x1F == DUAL_INJECTED_SIMULTANEOUS;
        let (adcs, how): (Vec<usize>, Started) = match what {
            SoftStart::None => return,
            SoftStart::Injected(0) if dual => (vec![0, 1], Started::Injected),
            SoftStart::Injected(i) => (vec![i], Started::Injected),
            SoftStart::Regular(i) => (vec![i], Started::Regular),
        };
        for i in adcs {
            if !regs.bit(base(i) + CR, CR_ADEN) {
                continue;
            }
            let chans = if how == Started::Regular {
                Self::regular_channels(regs, i)
            } else {
                Self::injected_channels(regs, i)
            };
            self.begin(regs, i, &chans, now, how, sample);
        }
    }

    /// An ADC_CCR write (applied): CKMODE and DUAL refused with an ADC enabled.
    pub fn on_common_write(&mut self, regs: &mut RegFile, old: u32) {
        let v = regs.get(COMMON_CCR);
        let enabled = (0..2).any(|i| regs.bit(base(i) + CR, CR_ADEN));
        if enabled && (v ^ old) & CCR_LOCKED_WITH_ADEN != 0 {
            self.violations.common_write_refused += 1;
            regs.set(
                COMMON_CCR,
                (v & !CCR_LOCKED_WITH_ADEN) | (old & CCR_LOCKED_WITH_ADEN),
            );
        }
    }

    /// A bus read of an ADC register: a wrong result (the erratum) read is counted.
    pub fn on_read(&mut self, addr: u32) {
        for i in 0..2 {
            let off = addr.wrapping_sub(base(i));
            let slot = match off {
                DR => 4,
                o if (JDR1..JDR1 + 16).contains(&o) => ((o - JDR1) / 4) as usize,
                _ => continue,
            };
            if std::mem::take(&mut self.conv[i].wrong[slot]) {
                self.violations.late_results_read += 1;
            }
        }
    }

    /// TIM1 TRGO2 rose at `now`: start the injected sequences that listen to it.
    /// `sample(adc, channel, from, to)` is the analog front end over the sampling
    /// window [from, to] (ticks), in counts.
    pub fn trgo2(
        &mut self,
        regs: &mut RegFile,
        now: u64,
        sample: &mut dyn FnMut(usize, u32, u64, u64) -> u16,
    ) -> Trigger {
        self.update(regs, now);
        let jsqr = regs.get(ADC1 + JSQR);
        let jexten = (jsqr >> 7) & 0b11;
        let listening = Self::ready(regs, 0)
            && regs.bit(ADC1 + CR, CR_JADSTART)
            && jexten != 0
            && (jsqr >> 2) & 0x1F == JEXTSEL_TIM1_TRGO2;
        if listening && jexten != 0b01 {
            self.violations.jexten_not_rising += 1;
        }
        // 10: falling edge only; the rising edge starts nothing (the falling edge is not
        // modelled: those sequences are lost).
        let armed = listening && jexten != 0b10;
        if !armed || Self::clock_ticks(regs).is_none() {
            return Trigger::NotArmed;
        }
        let dual = regs.get(COMMON_CCR) & 0x1F == DUAL_INJECTED_SIMULTANEOUS;
        let found = Trigger::Started {
            unread: regs.bit(ADC1 + ISR, ISR_JEOS),
            converting: self.conv[0].pending.is_some(),
        };
        if self.conv[0].pending.is_some() {
            // §21.4.18: "Any hardware triggers which occur while a conversion is
            // ongoing are ignored."
            return found;
        }
        self.triggers += 1;
        let slave = dual && Self::ready(regs, 1);
        if slave {
            let (c1, c2) = (
                Self::injected_channels(regs, 0),
                Self::injected_channels(regs, 1),
            );
            let same_times = c1.iter().zip(&c2).all(|(&a, &b)| {
                Self::sample_half_clocks(regs, 0, a) == Self::sample_half_clocks(regs, 1, b)
            });
            if c1.len() != c2.len() || !same_times {
                self.violations.dual_mismatch += 1;
            }
        }
        for i in 0..2 {
            if i == 1 && !slave {
                continue;
            }
            let chans = Self::injected_channels(regs, i);
            self.begin(regs, i, &chans, now, Started::Trigger, sample);
        }
        found
    }

    /// The next end of a sequence.
    pub fn next_event(&self) -> Option<u64> {
        self.conv
            .iter()
            .filter_map(|c| c.pending.map(|p| p.end))
            .min()
    }

    /// Sequences that ended by `now`: data and flags (JEOC, JEOS; EOC, EOS for a regular
    /// one).
    pub fn complete(&mut self, regs: &mut RegFile, now: u64) {
        for i in 0..2 {
            let b = base(i);
            let Some(p) = self.conv[i].pending.filter(|p| p.end <= now) else {
                continue;
            };
            let c = &mut self.conv[i];
            if p.how == Started::Regular {
                regs.set(b + DR, p.vals[p.n - 1] as u32);
                c.wrong[4] = p.wrong[p.n - 1];
                regs.set_bits(b + ISR, ISR_EOC | ISR_EOS, true);
                regs.set_bits(b + CR, CR_ADSTART, false);
            } else {
                for k in 0..p.n {
                    regs.set(b + JDR1 + 4 * k as u32, p.vals[k] as u32);
                    c.wrong[k] = p.wrong[k];
                }
                regs.set_bits(b + ISR, ISR_JEOC | ISR_JEOS, true);
                if p.how == Started::Injected {
                    regs.set_bits(b + CR, CR_JADSTART, false);
                }
            }
            c.pending = None;
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

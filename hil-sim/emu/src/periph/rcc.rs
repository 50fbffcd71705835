//! RCC (RM0440 §7) and PWR (§6): oscillator and PLL ready bits, the system clock
//! switch, reset flags, the peripheral clock enables that gate bus access, and the
//! range-1 boost mode that 170 MHz needs.

use crate::regfile::RegFile;

pub const RCC: u32 = 0x4002_1000;
pub const CR: u32 = RCC;
pub const CFGR: u32 = RCC + 0x08;
pub const PLLCFGR: u32 = RCC + 0x0C;
pub const AHB1ENR: u32 = RCC + 0x48;
pub const AHB2ENR: u32 = RCC + 0x4C;
pub const APB1ENR1: u32 = RCC + 0x58;
pub const APB2ENR: u32 = RCC + 0x60;
pub const CCIPR: u32 = RCC + 0x88;
pub const CSR: u32 = RCC + 0x94;

pub const PWR: u32 = 0x4000_7000;
pub const PWR_CR1: u32 = PWR;
pub const PWR_SR2: u32 = PWR + 0x14;
pub const PWR_CR5: u32 = PWR + 0x80;

/// RCC_CSR reset flags (§7.4.29).
pub const CSR_RMVF: u32 = 1 << 23;
pub const CSR_PINRSTF: u32 = 1 << 26;
pub const CSR_BORRSTF: u32 = 1 << 27;
pub const CSR_SFTRSTF: u32 = 1 << 28;
pub const CSR_IWDGRSTF: u32 = 1 << 29;
const CSR_LSION: u32 = 1 << 0;
const CSR_LSIRDY: u32 = 1 << 1;

/// Which reset ended the previous run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResetKind {
    PowerOn,
    Software,
    Watchdog,
    /// NRST pulled low (a debug probe's reset line).
    Pin,
}

/// The enable bit that clocks a peripheral's registers (§7.4.14-7.4.20): (enable
/// register, bit). None: always clocked (RCC, FLASH interface, IWDG on LSI, debug).
pub fn clock_gate(periph: &str) -> Option<(u32, u32)> {
    Some(match periph {
        "CORDIC" => (AHB1ENR, 3),
        "CRC" => (AHB1ENR, 12),
        "GPIOA" => (AHB2ENR, 0),
        "GPIOB" => (AHB2ENR, 1),
        "GPIOC" => (AHB2ENR, 2),
        "ADC1" | "ADC2" | "ADC12_COMMON" => (AHB2ENR, 13),
        "USART2" => (APB1ENR1, 17),
        "PWR" => (APB1ENR1, 28),
        "SYSCFG" => (APB2ENR, 0),
        "TIM1" => (APB2ENR, 11),
        "USART1" => (APB2ENR, 14),
        _ => return None,
    })
}

/// Oscillator start-up: HSI16 (t_su(HSI16)), the HSE crystal (t_SU(HSE)) and the PLL
/// (t_LOCK), typical figures of the STM32G474 datasheet (DS12288) as recalled; what they
/// enforce does not hang on their values: a ready bit comes up after its enable, and a
/// clock switch to a source not yet ready waits for it (§7.2.7).
const HSI16_STARTUP_S: f64 = 1.0e-6;
const HSE_STARTUP_S: f64 = 2.0e-3;
const PLL_LOCK_S: f64 = 40.0e-6;

const CR_HSION: u32 = 1 << 8;
const CR_HSIRDY: u32 = 1 << 10;
const CR_HSEON: u32 = 1 << 16;
const CR_HSERDY: u32 = 1 << 17;
const CR_PLLON: u32 = 1 << 24;
const CR_PLLRDY: u32 = 1 << 25;

#[derive(Debug, Default)]
pub struct Rcc {
    /// The crystal on OSC_IN/OSC_OUT (Hz): the board's ([`crate::board::Board::hse_hz`]).
    pub hse_hz: f64,
    /// When HSI16, HSE and the PLL become ready (ticks), while they start.
    ready_at: [Option<u64>; 3],
    /// A switch (CFGR.SW) to a source not ready yet: it takes effect when it is.
    pending_sw: Option<u32>,
    /// Ticks per executed instruction at the current SYSCLK (170 MHz → 1; HSI16 → 11).
    pub ticks_per_instr: u64,
    /// The system clock in Hz, as the switch status says.
    pub sysclk_hz: u32,
    /// 170 MHz with range-1 boost off (PWR_CR5.R1MODE = 1), beyond the 150 MHz allowed
    /// (§6.1.5): counted once per clock switch.
    pub overclocked: u32,
    /// Flash wait states too few for SYSCLK (§3.3.3 table 9).
    pub latency_too_low: u32,
}

impl Rcc {
    /// The RCC of a board whose HSE crystal runs at `hse_hz`.
    pub fn with_hse(hse_hz: f64) -> Self {
        Self {
            hse_hz,
            ..Self::default()
        }
    }

    pub fn reset(&mut self, regs: &mut RegFile) {
        // HSI16 is on and ready out of reset (§7.2.2).
        regs.set_bits(CR, CR_HSIRDY, true);
        self.sysclk_hz = 16_000_000;
        self.ticks_per_instr = 11;
        self.ready_at = [None; 3];
        self.pending_sw = None;
    }

    /// The next oscillator to become ready (ticks).
    pub fn next_event(&self) -> Option<u64> {
        self.ready_at.iter().flatten().min().copied()
    }

    /// Ready bits that came up by `now`, and a switch that waited for one.
    pub fn update(&mut self, regs: &mut RegFile, now: u64, flash_latency: u32) {
        for (k, rdy) in [CR_HSIRDY, CR_HSERDY, CR_PLLRDY].into_iter().enumerate() {
            if self.ready_at[k].is_some_and(|t| t <= now) {
                self.ready_at[k] = None;
                regs.set_bits(CR, rdy, true);
            }
        }
        if let Some(sw) = self.pending_sw {
            if Self::source_ready(regs, sw) {
                self.pending_sw = None;
                self.switch(regs, sw, flash_latency);
            }
        }
    }

    fn source_ready(regs: &RegFile, sw: u32) -> bool {
        match sw {
            1 => regs.bit(CR, CR_HSIRDY),
            2 => regs.bit(CR, CR_HSERDY),
            3 => regs.bit(CR, CR_PLLRDY),
            _ => false,
        }
    }

    fn switch(&mut self, regs: &mut RegFile, sw: u32, flash_latency: u32) {
        let cfgr = regs.get(CFGR);
        regs.set(CFGR, (cfgr & !0b1100) | (sw << 2));
        self.update_sysclk(regs, flash_latency);
    }

    /// Write side effects: an oscillator's ready bit comes up its start-up time after
    /// its enable, and drops with it; the switch takes effect when its source is ready.
    pub fn on_write(
        &mut self,
        regs: &mut RegFile,
        addr: u32,
        old: u32,
        now: u64,
        flash_latency: u32,
    ) {
        match addr {
            CR => {
                let cr = regs.get(CR);
                let oscillators = [
                    (CR_HSION, CR_HSIRDY, HSI16_STARTUP_S),
                    (CR_HSEON, CR_HSERDY, HSE_STARTUP_S),
                    (CR_PLLON, CR_PLLRDY, PLL_LOCK_S),
                ];
                for (k, (on, rdy, startup_s)) in oscillators.into_iter().enumerate() {
                    // The PLL locks only with a source selected (PLLCFGR.PLLSRC).
                    let can_run = on != CR_PLLON || regs.get(PLLCFGR) & 0b11 != 0;
                    if cr & on == 0 || !can_run {
                        regs.set_bits(CR, rdy, false);
                        self.ready_at[k] = None;
                    } else if old & on == 0 && !regs.bit(CR, rdy) {
                        self.ready_at[k] = Some(now + super::ticks(startup_s));
                    }
                }
            }
            CFGR => {
                let sw = regs.get(CFGR) & 0b11;
                if Self::source_ready(regs, sw) {
                    self.pending_sw = None;
                    self.switch(regs, sw, flash_latency);
                } else {
                    self.pending_sw = Some(sw);
                }
            }
            CSR => {
                let csr = regs.get(CSR);
                if csr & CSR_RMVF != 0 {
                    regs.set(CSR, csr & !(0xFE00_0000 | CSR_RMVF));
                }
                regs.set_bits(CSR, CSR_LSIRDY, regs.bit(CSR, CSR_LSION));
            }
            PWR_CR1 => {
                // Voltage scaling settles at once (VOSF = 0).
                regs.set_bits(PWR_SR2, 1 << 10, false);
            }
            _ => {}
        }
    }

    fn update_sysclk(&mut self, regs: &RegFile, flash_latency: u32) {
        let cfgr = regs.get(CFGR);
        let hz = match (cfgr >> 2) & 0b11 {
            1 => 16_000_000,
            2 => self.hse_hz as u32,
            3 => {
                let p = regs.get(PLLCFGR);
                let input = if p & 0b11 == 3 { self.hse_hz } else { 16.0e6 };
                let m = ((p >> 4) & 0xF) + 1;
                let n = (p >> 8) & 0x7F;
                let r = 2 * (((p >> 25) & 0b11) + 1);
                (input / m as f64 * n as f64 / r as f64) as u32
            }
            _ => 16_000_000,
        };
        // AHB prescaler (HPRE) during the boost sequence divides HCLK.
        let hpre = (cfgr >> 4) & 0xF;
        let div = if hpre < 8 { 1 } else { 1 << (hpre - 7) };
        self.sysclk_hz = hz / div;
        self.ticks_per_instr = (170_000_000 / self.sysclk_hz.max(1) as u64).max(1);
        if self.sysclk_hz > 150_000_000 && regs.bit(PWR_CR5, 1 << 8) {
            self.overclocked += 1;
        }
        // §3.3.3: 4 wait states from 136 MHz in boost mode.
        if self.sysclk_hz > 136_000_000 && flash_latency < 4 {
            self.latency_too_low += 1;
        }
    }

    /// Set the flags of the reset that just happened (§7.4.29).
    pub fn record_reset(&mut self, regs: &mut RegFile, kind: ResetKind, kept_csr: u32) {
        let flags = match kind {
            ResetKind::PowerOn => CSR_BORRSTF | CSR_PINRSTF,
            ResetKind::Software => kept_csr & 0xFE00_0000 | CSR_SFTRSTF | CSR_PINRSTF,
            ResetKind::Watchdog => kept_csr & 0xFE00_0000 | CSR_IWDGRSTF | CSR_PINRSTF,
            ResetKind::Pin => kept_csr & 0xFE00_0000 | CSR_PINRSTF,
        };
        regs.set(CSR, (regs.get(CSR) & !0xFE00_0000) | flags);
    }

    /// Is the peripheral's bus clock on?
    pub fn clocked(regs: &RegFile, periph: &str) -> bool {
        clock_gate(periph).is_none_or(|(reg, bit)| regs.bit(reg, 1 << bit))
    }
}

//! ADC1 and ADC2 in dual injected-simultaneous mode, triggered by TIM1 TRGO2 just
//! after the counter peak: slot by slot (`board_map::INJECTED_SEQUENCE`) the shunts of
//! phases U and V, then W and the bus voltage, while the low sides conduct; then the
//! sensor's X and Y at the same instant. RM0440 §21 "Analog-to-digital converters".

use board_map::{Adc, Signal, INJECTED_SEQUENCE, SLOT_SAMPLING_HALF_CYCLES};
use cortex_m::peripheral::DWT;
use drive::control::Sample;
use stm32g4xx_hal::stm32::{ADC1, ADC12_COMMON, ADC2, RCC};

/// Arms the conversions, from `idle`: it runs once init's resources are in place and
/// interrupts are on, so the first trigger's interrupt runs at once. (Armed in init, a
/// 40 kHz trigger could come twice while init's resources were still being moved.)
pub struct Start(());

impl Start {
    /// §21.4.18: JADSTART = 1 lets the master's injected trigger (TIM1 TRGO2) start the
    /// sequence; in dual mode the slave follows.
    pub fn conversions(&mut self) {
        // SAFETY: one read-modify-write of ADC1_CR. Its other writer (init) has
        // finished, and the control task reads JDRx and writes ISR, never CR.
        let adc1 = unsafe { &*ADC1::ptr() };
        adc1.cr().modify(|_, w| w.jadstart().set_bit());
    }
}

pub struct Adcs {
    adc1: ADC1,
    adc2: ADC2,
}

/// Longest wait for an ADC step: 1 ms of core cycles (a step takes tens of µs at most).
const STEP_TIMEOUT_CYCLES: u32 = crate::board::SYSCLK_HZ / 1_000;
/// t_ADCVREG_STUP, the regulator's start-up time: 20 µs (ST's
/// `LL_ADC_DELAY_INTERNAL_REGUL_STAB_US`).
const REGULATOR_STARTUP_CYCLES: u32 = crate::board::SYSCLK_HZ / 50_000;

/// Core cycles since `t0` (DWT CYCCNT, enabled in init before the ADCs).
fn cycles_since(t0: u32) -> u32 {
    DWT::cycle_count().wrapping_sub(t0)
}

/// `adc` is ADC`n` (for the message): a step that does not finish in
/// `STEP_TIMEOUT_CYCLES` ends in a panic naming the ADC and the step (the panic handler
/// disarms and leaves the cause for the next boot) instead of a silent hang until the
/// watchdog.
fn power_up_and_calibrate(adc: &stm32g4xx_hal::stm32::adc1::RegisterBlock, n: u8) {
    // §21.4.6: leave deep power-down, enable the regulator, wait t_ADCVREG_STUP (20 µs;
    // the regulator has no ready flag, so this wait is timed, not polled).
    adc.cr().modify(|_, w| w.deeppwd().clear_bit());
    adc.cr().modify(|_, w| w.advregen().set_bit());
    let t0 = DWT::cycle_count();
    while cycles_since(t0) < REGULATOR_STARTUP_CYCLES {}
    if !adc.cr().read().advregen().bit_is_set() {
        defmt::panic!(
            "ADC{=u8}: voltage regulator not enabled (ADVREGEN reads 0)",
            n
        );
    }
    // §21.4.8: single-ended calibration.
    adc.cr()
        .modify(|_, w| w.adcaldif().clear_bit().adcal().set_bit());
    let t0 = DWT::cycle_count();
    while adc.cr().read().adcal().bit_is_set() {
        if cycles_since(t0) > STEP_TIMEOUT_CYCLES {
            defmt::panic!("ADC{=u8}: calibration (ADCAL) did not end within 1 ms", n);
        }
    }
    // §21.4.9: enable and wait for ADRDY. ADEN set less than 4 ADC clocks after ADCAL
    // cleared is reset by the calibration logic (ST HAL ADC_Enable, MCSDK R3_2_ADCxInit),
    // and one write comes that soon: keep setting ADEN until ADRDY = 1.
    adc.isr().write(|w| w.adrdy().clear_bit_by_one());
    let t0 = DWT::cycle_count();
    while adc.isr().read().adrdy().bit_is_clear() {
        if adc.cr().read().aden().bit_is_clear() {
            adc.cr().modify(|_, w| w.aden().set_bit());
        }
        if cycles_since(t0) > STEP_TIMEOUT_CYCLES {
            defmt::panic!("ADC{=u8}: enable (ADRDY) not reached within 1 ms", n);
        }
    }
}

// `read` takes the data registers in this order.
const _: () = assert!(
    matches!(INJECTED_SEQUENCE[0], (Signal::CurrentU, Signal::CurrentV))
        && matches!(INJECTED_SEQUENCE[1], (Signal::CurrentW, Signal::BusVoltage))
        && matches!(INJECTED_SEQUENCE[2], (Signal::SensorX, Signal::SensorY))
);

/// The channels ADC `adc` converts, slot by slot.
const fn sequence(adc: Adc) -> [u8; 3] {
    let mut out = [0; 3];
    let mut k = 0;
    while k < 3 {
        let (s1, s2) = INJECTED_SEQUENCE[k];
        out[k] = board_map::channel(match adc {
            Adc::Adc1 => s1,
            Adc::Adc2 => s2,
        });
        k += 1;
    }
    out
}

/// SMPR1 and SMPR2 (§21.7.6, 3 bits per channel: 0-9 in SMPR1, 10-18 in SMPR2) with
/// each channel of ADC `adc`'s sequence at its slot's sampling time.
const fn smpr(adc: Adc) -> (u32, u32) {
    let seq = sequence(adc);
    let (mut r1, mut r2) = (0u32, 0u32);
    let mut k = 0;
    while k < 3 {
        let code = board_map::smp_code(SLOT_SAMPLING_HALF_CYCLES[k]) as u32;
        let ch = seq[k] as u32;
        if ch < 10 {
            r1 |= code << (3 * ch);
        } else {
            r2 |= code << (3 * (ch - 10));
        }
        k += 1;
    }
    (r1, r2)
}

/// The STM32G47x/G48x errata (ES0430, ADC): a conversion started more than 1 ms after
/// the ADC's previous conversion or its calibration may be wrong. One software-started
/// regular conversion of `channel` after the enable, its result left unread and its
/// flags cleared (RM0440 §21.4: a regular conversion started by ADSTART, ended by EOC),
/// so that the first triggered sequence, well under 1 ms later, is right.
fn discard_first_conversion(adc: &stm32g4xx_hal::stm32::adc1::RegisterBlock, n: u8, channel: u8) {
    // SAFETY: L = 0 (one conversion) and a channel number of the board (1..=18).
    adc.sqr1()
        .write(|w| unsafe { w.l().bits(0).sq1().bits(channel) });
    adc.cr().modify(|_, w| w.adstart().set_bit());
    let t0 = DWT::cycle_count();
    while adc.isr().read().eoc().bit_is_clear() {
        if cycles_since(t0) > STEP_TIMEOUT_CYCLES {
            defmt::panic!(
                "ADC{=u8}: the discarded first conversion did not end within 1 ms",
                n
            );
        }
    }
    adc.isr()
        .write(|w| w.eos().clear_bit_by_one().eoc().clear_bit_by_one());
}

impl Adcs {
    /// Configured, not converting: [`Start`] arms the trigger.
    pub fn new(adc1: ADC1, adc2: ADC2, common: ADC12_COMMON) -> (Self, Start) {
        // SAFETY: init-time enable of the ADC12 clock.
        let rcc = unsafe { &*RCC::ptr() };
        rcc.ahb2enr().modify(|_, w| w.adc12en().set_bit());
        // §7.4 (RCC_AHB2ENR): read the enable back before the first ADC access, ST's
        // "delay after an RCC peripheral clock enabling"; a lost CCR write would leave
        // the ADCs without a clock.
        let _ = rcc.ahb2enr().read();
        // §21.7.2: synchronous clock HCLK/4 = 42.5 MHz; dual mode, injected simultaneous
        // only (DUAL = 00101).
        common
            .ccr()
            .write(|w| w.ckmode().sync_div4().dual().dual_j());
        for (adc, which) in [(&*adc1, Adc::Adc1), (&*adc2, Adc::Adc2)] {
            let n = which.index() as u8 + 1;
            power_up_and_calibrate(adc, n);
            discard_first_conversion(adc, n, sequence(which)[0]);
            // §21.7.6: each slot's sampling time (`SLOT_SAMPLING_HALF_CYCLES`); the two
            // channels of a slot get the same one, as simultaneous conversions must.
            let (smpr1, smpr2) = smpr(which);
            // SAFETY: every 3-bit SMP field holds a defined encoding (`board_map::smp_code`).
            adc.smpr1().write(|w| unsafe { w.bits(smpr1) });
            adc.smpr2().write(|w| unsafe { w.bits(smpr2) });
        }
        // §21.4.12: injected sequences of three conversions (JL = 2) of equal length on
        // both ADCs; the master's trigger (TIM1 TRGO2, rising edge) starts both.
        let [x1, x2, x3] = sequence(Adc::Adc1);
        let [y1, y2, y3] = sequence(Adc::Adc2);
        // SAFETY: channel numbers 1..=18 (board-map's, checked against ST's pin data)
        // and JL = 2 are valid values.
        adc1.jsqr().write(|w| unsafe {
            w.jl().set(2);
            w.jextsel().tim1_trgo2().jexten().bits(0b01);
            w.jsq1().bits(x1).jsq2().bits(x2).jsq3().bits(x3)
        });
        adc2.jsqr().write(|w| unsafe {
            w.jl().set(2);
            w.jsq1().bits(y1).jsq2().bits(y2).jsq3().bits(y3)
        });
        // End of the injected sequence on the master raises ADC1_2.
        adc1.ier().write(|w| w.jeosie().set_bit());
        (Self { adc1, adc2 }, Start(()))
    }

    /// Read the sequence and acknowledge the interrupt (counts; the hardware flags of the
    /// sample are the caller's). The bus voltage (ADC2 JDR2) fills the slot beside
    /// phase W, keeping the two sequences of equal length; the control does not use it.
    #[inline]
    pub fn read(&self) -> Sample {
        let s = Sample {
            ia: self.adc1.jdr1().read().jdata().bits(),
            ib: self.adc2.jdr1().read().jdata().bits(),
            ic: self.adc1.jdr2().read().jdata().bits(),
            x: self.adc1.jdr3().read().jdata().bits(),
            y: self.adc2.jdr3().read().jdata().bits(),
            overcurrent: false,
            cycles: 0,
        };
        self.adc1
            .isr()
            .write(|w| w.jeos().clear_bit_by_one().jeoc().clear_bit_by_one());
        s
    }
}

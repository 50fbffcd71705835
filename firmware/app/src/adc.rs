//! ADC1 and ADC2 in dual injected-simultaneous mode, triggered by TIM1 TRGO2: the
//! sensor's X and Y are converted at the same instant (ADC1 JSQ1 = X, ADC2 JSQ1 = Y),
//! followed by the phase currents (JSQ2). RM0440 §21 "Analog-to-digital converters".

use crate::board::pins;
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
        for (adc, n) in [(&*adc1, 1), (&*adc2, 2)] {
            power_up_and_calibrate(adc, n);
            // 24.5 ADC cycles (0.58 µs): the sensor amplifier's source impedance.
            adc.smpr1().modify(|_, w| {
                w.smp1().cycles24_5().smp2().cycles24_5();
                w.smp6().cycles24_5().smp7().cycles24_5()
            });
        }
        // §21.4.12: injected sequence of two conversions; the master's trigger (TIM1
        // TRGO2, rising edge) starts both ADCs.
        // SAFETY: channel numbers 1..=18 and JL = 1 (two conversions) are valid values.
        adc1.jsqr().write(|w| unsafe {
            w.jl().set(1);
            w.jextsel().tim1_trgo2().jexten().bits(0b01);
            w.jsq1().bits(pins::SENSOR_X_ADC1_CHANNEL);
            w.jsq2().bits(pins::CURRENT_A_ADC1_CHANNEL)
        });
        adc2.jsqr().write(|w| unsafe {
            w.jl().set(1);
            w.jsq1().bits(pins::SENSOR_Y_ADC2_CHANNEL);
            w.jsq2().bits(pins::CURRENT_B_ADC2_CHANNEL)
        });
        // End of the injected sequence on the master raises ADC1_2.
        adc1.ier().write(|w| w.jeosie().set_bit());
        (Self { adc1, adc2 }, Start(()))
    }

    /// Read the sequence and acknowledge the interrupt (counts; the hardware flags of the
    /// sample are the caller's).
    #[inline]
    pub fn read(&self) -> Sample {
        let s = Sample {
            x: self.adc1.jdr1().read().jdata().bits(),
            ia: self.adc1.jdr2().read().jdata().bits(),
            y: self.adc2.jdr1().read().jdata().bits(),
            ib: self.adc2.jdr2().read().jdata().bits(),
            overcurrent: false,
            cycles: 0,
        };
        self.adc1
            .isr()
            .write(|w| w.jeos().clear_bit_by_one().jeoc().clear_bit_by_one());
        s
    }
}

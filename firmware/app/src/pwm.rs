//! TIM1: centre-aligned complementary PWM with dead time and break input, TRGO2 for the
//! ADCs, MOE as the safe-state switch (RM0440 §28 "Advanced-control timers").

use crate::board::{ADC_TRIGGER_AFTER_PEAK_TICKS, DEAD_TIME_TICKS, PWM_ARR};
use stm32g4xx_hal::stm32::{RCC, TIM1};

pub struct Pwm {
    tim: TIM1,
}

impl Pwm {
    /// Configure and start the counter with the outputs off (MOE = 0, OSSI = 1: driven
    /// to their off level). Call before the pins are switched to AF6, so that the
    /// outputs are never left floating (MOE = 0 with OSSI = 0 is Hi-Z, §28.6.20 BDTR).
    /// The break flag may latch while BKIN is not on its pin yet: see `clear_boot_break`.
    pub fn new(tim: TIM1) -> Self {
        // SAFETY: single write of the TIM1 enable bit during init, before interrupts run.
        let rcc = unsafe { &*RCC::ptr() };
        rcc.apb2enr().modify(|_, w| w.tim1en().set_bit());
        // §7.4 (RCC_APB2ENR): read the enable back before the first TIM1 access, ST's
        // "delay after an RCC peripheral clock enabling"; a lost CR1 write would give
        // edge-aligned PWM.
        let _ = rcc.apb2enr().read();
        tim.cr1().write(|w| {
            // §28.4.1: CMS = 01, centre-aligned mode 1; ARR preloaded.
            w.cms().center_aligned1().arpe().set_bit()
        });
        tim.psc().write(|w| w.psc().set(0));
        tim.arr().write(|w| w.arr().set(PWM_ARR as u32));
        // §28.6.7-8: channels 1-3 PWM mode 1 with preload: CCRx is loaded at the update
        // event, which RCR = 1 (below) makes once per period, at the counter peak. Each
        // high-side pulse (centred on the valley) therefore has one duty.
        tim.ccmr1_output().write(|w| {
            w.oc1m().pwm_mode1().oc1pe().enabled();
            w.oc2m().pwm_mode1().oc2pe().enabled()
        });
        // Channel 4 in PWM mode 1 with CCR4 = ARR - k: OC4REF (active while CNT < CCR4)
        // rises on the down-count k ticks after the counter peak, so
        // that the shunt conversions sit inside the low sides' conduction around the
        // peak (board::ADC_TRIGGER_AFTER_PEAK_TICKS says how k follows from dead time,
        // settling and the ADC's timing).
        tim.ccmr2_output().write(|w| {
            w.oc3m().pwm_mode1().oc3pe().enabled();
            w.oc4m().pwm_mode1().oc4pe().enabled()
        });
        tim.ccr4()
            .write(|w| w.ccr().set(PWM_ARR as u32 - ADC_TRIGGER_AFTER_PEAK_TICKS));
        for ccr in [tim.ccr1(), tim.ccr2(), tim.ccr3()] {
            ccr.write(|w| w.ccr().set(PWM_ARR as u32 / 2));
        }
        // §28.6.2: MMS2 = 0111, TRGO2 = OC4REF: the ADCs' injected trigger.
        // SAFETY: 0b0111 is a defined MMS2 encoding.
        tim.cr2().modify(|_, w| unsafe { w.mms2().bits(0b0111) });
        // §28.6.2 TIM1_CR2 OISxN: with MOE = 0 and OSSI = 1 the outputs take their idle
        // levels; an active-low low-side input idles high, so the bridge's off state has
        // every switch off (OISx = 0: the high-side inputs idle low). Set before the
        // outputs are enabled, so that no enabled output ever has the wrong idle level.
        let low_inverted = board_map::gate_driver::LOW_SIDE_INPUT_ACTIVE_LOW;
        tim.cr2().modify(|_, w| {
            w.ois1n().bit(low_inverted);
            w.ois2n().bit(low_inverted);
            w.ois3n().bit(low_inverted)
        });
        // §28.6.11 TIM1_CCER: the gate driver's low-side input may be active low
        // (board_map::gate_driver, the IHM08M1's L6398): CHxN inverted (CCxNP = 1), so
        // that the low side conducts while OCxREF is inactive, as with an active-high
        // input.
        tim.ccer().write(|w| {
            w.cc1e()
                .set_bit()
                .cc1ne()
                .set_bit()
                .cc1np()
                .bit(low_inverted);
            w.cc2e()
                .set_bit()
                .cc2ne()
                .set_bit()
                .cc2np()
                .bit(low_inverted);
            w.cc3e()
                .set_bit()
                .cc3ne()
                .set_bit()
                .cc3np()
                .bit(low_inverted);
            w.cc4e().set_bit()
        });
        // §28.6.27 TIM1_AF1: the BKIN pin feeds the break (BKINE = 1), not inverted
        // (BKINP = 0). Written explicitly: the reset value differs between the SVD (0,
        // pin not connected) and the reference manual, and the over-current protection
        // rests on this bit. No comparator inputs (BKCMPxE = 0).
        tim.af1().write(|w| w.bkine().set_bit().bkinp().clear_bit());
        // §28.6.20: dead time, break input enabled active low (shunt comparator), OSSR/
        // OSSI so that outputs go to their idle (off) level, MOE off until armed. BKF =
        // 1010 (f_DTS/16, N = 5: 470 ns): the comparator's output rings for a few hundred
        // ns at the switching edges when a phase current nears its level, and a glitch
        // shorter than the filter does not latch a break (BKF = 0011, 47 ns, let them
        // through); a real over-current still opens the bridge within half a µs. One
        // write: the LOCK bits can write-protect all of these fields, so they are all set
        // in the first BDTR write.
        tim.bdtr().write(|w| {
            w.dtg().set(DEAD_TIME_TICKS);
            w.bke().set_bit().bkp().clear_bit();
            // SAFETY: 0b1010 is a defined BKF encoding.
            unsafe { w.bkf().bits(0b1010) };
            w.ossr().set_bit().ossi().set_bit();
            w.moe().clear_bit()
        });
        // §28.3.3 repetition counter: in centre-aligned mode it counts overflows and
        // underflows, so RCR = 1 gives one update event (CCR shadow load) per PWM period;
        // written before the first UG and CEN, that event falls on the overflow (counter
        // peak), where the ADCs sample. RCR = 0 would also load at the valley, in the
        // middle of the high-side pulse.
        tim.rcr().write(|w| w.rep().set(1));
        // §28.6.6: UG loads ARR, PSC, RCR and the CCRs into their shadow registers.
        tim.egr().write(|w| w.ug().set_bit());
        tim.cr1().modify(|_, w| w.cen().set_bit());
        Self { tim }
    }

    /// Duties 0..=1 of phases a, b, c; loaded at the next update event (preload).
    #[inline]
    pub fn set_duties(&self, d: [f32; 3]) {
        let arr = PWM_ARR as f32;
        // A saturating conversion, not compares and branches (a NaN gives 0).
        let to_ccr = |x: f32| (mras::clamp_01_f32(x) * arr) as u32;
        self.tim.ccr1().write(|w| w.ccr().set(to_ccr(d[0])));
        self.tim.ccr2().write(|w| w.ccr().set(to_ccr(d[1])));
        self.tim.ccr3().write(|w| w.ccr().set(to_ccr(d[2])));
    }

    /// The control period's output: duties and MOE.
    #[inline]
    pub fn apply(&self, out: &drive::control::Output) {
        if out.enable {
            self.set_duties(out.duties);
            if !self.armed() {
                self.arm();
            }
        } else {
            self.disarm();
        }
    }

    /// Outputs on (MOE = 1). Refused while the break input is active.
    pub fn arm(&self) -> bool {
        if self.break_active() {
            return false;
        }
        self.tim.bdtr().modify(|_, w| w.moe().set_bit());
        true
    }

    /// The safe state: all outputs to their idle (off) level at once.
    #[inline]
    pub fn disarm(&self) {
        self.tim.bdtr().modify(|_, w| w.moe().clear_bit());
    }

    pub fn armed(&self) -> bool {
        self.tim.bdtr().read().moe().bit_is_set()
    }

    /// Break (over-current) seen since the last clear; hardware already cleared MOE.
    pub fn break_active(&self) -> bool {
        self.tim.sr().read().bif().bit_is_set()
    }

    pub fn clear_break(&self) {
        self.tim.sr().modify(|_, w| w.bif().clear_bit());
    }

    /// Once, after the pins are on AF6: clear a break latched during configuration
    /// (BKIN read low while its pin was still analog), unless the break input is active
    /// now (`bkin_low`, the pin's level: active low). An active break stays latched, and
    /// `break_active()` reports it as an over-current.
    pub fn clear_boot_break(&self, bkin_low: bool) {
        // §28.6.5 TIM1_SR.BIF (rc_w0): cleared only with the input inactive, so a
        // real over-current at boot is not hidden.
        if !bkin_low {
            self.clear_break();
        }
    }
}

/// Clear MOE from any context (HardFault): the one register write the safe state needs.
pub fn disarm_from_anywhere() {
    // SAFETY: a single read-modify-write of BDTR.MOE; called when nothing else runs.
    unsafe { (*TIM1::ptr()).bdtr().modify(|_, w| w.moe().clear_bit()) };
}

//! TIM1: centre-aligned complementary PWM with dead time and break input, TRGO2 for the
//! ADCs, MOE as the safe-state switch (RM0440 §28 "Advanced-control timers").

use crate::board::{DEAD_TIME_TICKS, PWM_ARR};
use stm32g4xx_hal::stm32::{RCC, TIM1};

pub struct Pwm {
    tim: TIM1,
}

impl Pwm {
    /// Configure and start the counter with the outputs off (MOE = 0).
    pub fn new(tim: TIM1) -> Self {
        // SAFETY: single write of the TIM1 enable bit during init, before interrupts run.
        unsafe { (*RCC::ptr()).apb2enr().modify(|_, w| w.tim1en().set_bit()) };
        tim.cr1().write(|w| {
            // §28.4.1: CMS = 01, centre-aligned mode 1; ARR preloaded.
            w.cms().center_aligned1().arpe().set_bit()
        });
        tim.psc().write(|w| w.psc().set(0));
        tim.arr().write(|w| w.arr().set(PWM_ARR as u32));
        // §28.6.7-8: channels 1-3 PWM mode 1 with preload, so that a period never mixes
        // old and new duties (CCRx is loaded at the update event).
        tim.ccmr1_output().write(|w| {
            w.oc1m().pwm_mode1().oc1pe().enabled();
            w.oc2m().pwm_mode1().oc2pe().enabled()
        });
        // Channel 4 in PWM mode 2 with CCR4 = ARR - 1: OC4REF rises just before the
        // counter peak, where the low-side switches conduct (shunt currents valid).
        tim.ccmr2_output().write(|w| {
            w.oc3m().pwm_mode1().oc3pe().enabled();
            w.oc4m().pwm_mode2().oc4pe().enabled()
        });
        tim.ccr4().write(|w| w.ccr().set(PWM_ARR as u32 - 1));
        for ccr in [tim.ccr1(), tim.ccr2(), tim.ccr3()] {
            ccr.write(|w| w.ccr().set(PWM_ARR as u32 / 2));
        }
        // §28.6.2: MMS2 = 0111, TRGO2 = OC4REF: the ADCs' injected trigger.
        // SAFETY: 0b0111 is a defined MMS2 encoding.
        tim.cr2().modify(|_, w| unsafe { w.mms2().bits(0b0111) });
        tim.ccer().write(|w| {
            w.cc1e().set_bit().cc1ne().set_bit();
            w.cc2e().set_bit().cc2ne().set_bit();
            w.cc3e().set_bit().cc3ne().set_bit();
            w.cc4e().set_bit()
        });
        // §28.6.20: dead time, break input enabled active low (shunt comparator), OSSR/
        // OSSI so that outputs go to their idle (off) level, MOE off until armed.
        tim.bdtr().write(|w| {
            w.dtg().set(DEAD_TIME_TICKS);
            w.bke().set_bit().bkp().clear_bit();
            w.ossr().set_bit().ossi().set_bit();
            w.moe().clear_bit()
        });
        tim.egr().write(|w| w.ug().set_bit());
        tim.cr1().modify(|_, w| w.cen().set_bit());
        Self { tim }
    }

    /// Duties 0..=1 of phases a, b, c; loaded at the next update event (preload).
    #[inline]
    pub fn set_duties(&self, d: [f32; 3]) {
        let arr = PWM_ARR as f32;
        let to_ccr = |x: f32| (x.clamp(0.0, 1.0) * arr) as u32;
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
}

/// Clear MOE from any context (HardFault): the one register write the safe state needs.
pub fn disarm_from_anywhere() {
    // SAFETY: a single read-modify-write of BDTR.MOE; called when nothing else runs.
    unsafe { (*TIM1::ptr()).bdtr().modify(|_, w| w.moe().clear_bit()) };
}

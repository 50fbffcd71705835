//! The CORDIC co-processor (RM0440 §17) as the core's trigonometry: configuration and
//! the two registers; the scaling and the read order live in `drive::cordic` (tested on
//! the host).

use drive::cordic::{CordicPort, CordicTrig};
use stm32g4xx_hal::stm32::{CORDIC, RCC};

/// The configured co-processor. Owned by the control task only: a calculation is one
/// WDATA write and two RDATA reads that must not interleave with another user.
pub struct Cordic {
    _cordic: CORDIC,
}

/// The core's trigonometry in the firmware.
pub type Trig = CordicTrig<Cordic>;

impl Cordic {
    /// Clock it and select cosine (RES1 = cos θ, RES2 = sin θ with the modulus ARG2 at
    /// its reset value 1), 24 iterations (6 clock cycles), one 32-bit q1.31 argument,
    /// two 32-bit results (§17.4.1 CORDIC_CSR).
    pub fn new(cordic: CORDIC) -> Trig {
        // SAFETY: single write of the CORDIC enable bit during init.
        let rcc = unsafe { &*RCC::ptr() };
        rcc.ahb1enr().modify(|_, w| w.cordicen().set_bit());
        // §7.4 (RCC_AHB1ENR): read the enable back before the CSR write, ST's "delay after
        // an RCC peripheral clock enabling".
        let _ = rcc.ahb1enr().read();
        cordic.csr().write(|w| {
            w.func().cosine();
            w.precision().iters24();
            // SAFETY: scale 0 (no scaling) is the only value valid for cosine.
            unsafe { w.scale().bits(0) };
            w.nres().num2();
            w.nargs().num1();
            w.ressize().bits32();
            w.argsize().bits32()
        });
        CordicTrig(Self { _cordic: cordic })
    }

    fn regs() -> &'static stm32g4xx_hal::stm32::cordic::RegisterBlock {
        // SAFETY: `Cordic` owns the peripheral; WDATA and RDATA are plain data registers.
        unsafe { &*CORDIC::ptr() }
    }
}

impl CordicPort for Cordic {
    #[inline(always)]
    fn write_arg(&self, q31: i32) {
        // SAFETY: any 32-bit value is a valid q1.31 argument.
        Self::regs()
            .wdata()
            .write(|w| unsafe { w.arg().bits(q31 as u32) });
    }

    #[inline(always)]
    fn read_result(&self) -> i32 {
        // Reading before the result is ready inserts bus wait states (§17.3.6, zero-
        // overhead mode): no polling needed.
        Self::regs().rdata().read().res().bits() as i32
    }
}

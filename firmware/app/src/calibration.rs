//! The calibration record in flash: `calib-record`'s two alternating slots on the last
//! two 2 KiB pages of bank 2 (dual-bank mode). The code runs from bank 1, and the banks
//! read while the other is written (RM0440 §3.3.8 read-while-write), so an erase or a
//! programming stalls nothing but the supervisor task that waits for it: the control
//! interrupt keeps running. The page addresses come from `memory.x` (symbol
//! `_calib_start`), the one owner of the memory map. RM0440 §3.3.5 (unlock), §3.3.7
//! (page erase), §3.3.8 (double-word programming), §3.7.5 (FLASH_SR).
//!
//! The supervisor task owns the [`Flash`] (an RTIC local resource); nothing here masks
//! interrupts or logs.

use calib_record::{FlashSlots, Slot, PAGE_BYTES};
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::DWT;
use stm32g4xx_hal::stm32::FLASH;

extern "C" {
    /// First byte of the two calibration pages (memory.x).
    static _calib_start: u8;
}

/// Bank 2 in dual-bank mode (RM0440 §3.3.1, 512 KiB devices, DBANK = 1).
const BANK2_START: usize = 0x0804_0000;
const BANK2_END: usize = 0x0808_0000;
/// The flash size data register (KiB; RM0440, "Device electronic signature"): a 128 or
/// 256 KiB part has its bank 2 elsewhere, or none.
const FLASH_SIZE_KIB: *const u16 = 0x1FFF_75E0 as *const u16;
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;
/// Longest wait for BSY: a page erase is 40 ms at most (DS12288, as recalled); beyond
/// 50 ms the flash is not answering. Under the watchdog's 100 ms.
const BUSY_TIMEOUT_CYCLES: u32 = crate::board::SYSCLK_HZ / 20;

/// Set by the NMI handler when a flash read hit a double ECC error (RM0440 §3.3.4): a
/// double word torn by a power cut during programming. `read` turns it into an error, so
/// `calib_record::load` falls back to the other slot instead of the drive resetting
/// forever on the same bad word.
static ECC_FAULT: AtomicBool = AtomicBool::new(false);

#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    // SAFETY (of the handler, per cortex-m-rt): it touches only FLASH_ECCR, the atomic
    // flag and, on the other path, TIM1's MOE before a reset.
    let flash = &*FLASH::ptr();
    if flash.eccr().read().eccd().bit_is_set() {
        flash.eccr().modify(|_, w| w.eccd().set_bit());
        ECC_FAULT.store(true, Ordering::SeqCst);
    } else {
        // Any other NMI source (clock security system): safe state, reset, reported at
        // boot as a watchdog-less reset.
        crate::pwm::disarm_from_anywhere();
        cortex_m::peripheral::SCB::sys_reset();
    }
}

/// Why a flash operation failed, by FLASH_SR error flag (§3.7.5) or by the checks here.
/// Several flags can be set at once; the first in this order is reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum FlashError {
    /// PROGERR: programming a double word that is not erased.
    ProgErr,
    /// WRPERR: the page is write protected.
    WrpErr,
    /// PGAERR: misaligned address or size.
    PgaErr,
    /// SIZERR: a write narrower than a double word.
    SizErr,
    /// PGSERR: wrong programming sequence (e.g. PG and PER both set).
    PgsErr,
    /// MISSERR: the second word of a double word came too late.
    MissErr,
    /// FASTERR: fast programming interrupted.
    FastErr,
    /// RDERR: read of a PCROP area.
    RdErr,
    /// OPTVERR: option bytes invalid.
    OptvErr,
    /// OPERR: an operation error without a more specific flag.
    OpErr,
    /// A double ECC error while reading (NMI).
    EccDouble,
    /// BSY did not clear in time.
    Timeout,
    /// FLASH_OPTR.DBANK = 0 (single-bank mode): the pages are not where memory.x says.
    SingleBank,
    /// `_calib_start` is not in bank 2: an erase would stall the code's bank.
    NotInBank2,
    /// The device has less than the 512 KiB memory.x describes (FLASH_SIZE register).
    FlashSize,
}

impl FlashError {
    /// From the SR bits an operation raised, None if none.
    fn from_sr(sr: u32) -> Option<Self> {
        [
            (3, FlashError::ProgErr),
            (4, FlashError::WrpErr),
            (5, FlashError::PgaErr),
            (6, FlashError::SizErr),
            (7, FlashError::PgsErr),
            (8, FlashError::MissErr),
            (9, FlashError::FastErr),
            (14, FlashError::RdErr),
            (15, FlashError::OptvErr),
            (1, FlashError::OpErr),
        ]
        .into_iter()
        .find(|(bit, _)| sr & (1 << bit) != 0)
        .map(|(_, e)| e)
    }
}

impl drive::supervisor::NamedError for FlashError {
    fn name(&self) -> &'static str {
        match self {
            FlashError::ProgErr => "ProgErr",
            FlashError::WrpErr => "WrpErr",
            FlashError::PgaErr => "PgaErr",
            FlashError::SizErr => "SizErr",
            FlashError::PgsErr => "PgsErr",
            FlashError::MissErr => "MissErr",
            FlashError::FastErr => "FastErr",
            FlashError::RdErr => "RdErr",
            FlashError::OptvErr => "OptvErr",
            FlashError::OpErr => "OpErr",
            FlashError::EccDouble => "EccDouble",
            FlashError::Timeout => "Timeout",
            FlashError::SingleBank => "SingleBank",
            FlashError::NotInBank2 => "NotInBank2",
            FlashError::FlashSize => "FlashSize",
        }
    }
}

/// The SR error flags (§3.7.5), write 1 to clear.
const SR_ERRORS: u32 = 0xC3FA;

/// The calibration pages, owned by the supervisor task.
pub struct Flash {
    regs: FLASH,
    /// The layout check of [`Flash::new`]: every operation fails with it if it failed.
    usable: Result<(), FlashError>,
}

fn slot_addr(slot: Slot) -> usize {
    // Only the address of the linker symbol is taken, never its value.
    let base = core::ptr::addr_of!(_calib_start) as usize;
    base + slot.index() * PAGE_BYTES
}

/// Clears PER/PG and re-locks on every exit of an operation, early returns included.
struct Unlocked<'a>(&'a FLASH);

impl Drop for Unlocked<'_> {
    fn drop(&mut self) {
        let f = self.0;
        f.cr()
            .modify(|_, w| w.per().clear_bit().pg().clear_bit().lock().set_bit());
        // Reads after a write must not hit stale data-cache lines (§3.3.3): reset the
        // data cache with it disabled.
        f.acr().modify(|_, w| w.dcen().clear_bit());
        f.acr().modify(|_, w| w.dcrst().set_bit());
        f.acr()
            .modify(|_, w| w.dcrst().clear_bit().dcen().set_bit());
    }
}

impl Flash {
    /// Take the flash; check the device's flash size, that it is in dual-bank mode and
    /// that memory.x put the pages in bank 2.
    pub fn new(regs: FLASH) -> Self {
        let start = slot_addr(Slot::A);
        // SAFETY: a read-only system-memory register present on every STM32G4.
        let size_kib = unsafe { FLASH_SIZE_KIB.read_volatile() };
        let usable = if size_kib < 512 {
            Err(FlashError::FlashSize)
        } else if regs.optr().read().dbank().bit_is_clear() {
            Err(FlashError::SingleBank)
        } else if !(BANK2_START..BANK2_END).contains(&start)
            || !(BANK2_START..=BANK2_END).contains(&(slot_addr(Slot::B) + PAGE_BYTES))
        {
            Err(FlashError::NotInBank2)
        } else {
            Ok(())
        };
        Self { regs, usable }
    }

    /// Why the pages cannot be used, if they cannot.
    pub fn check(&self) -> Result<(), FlashError> {
        self.usable
    }

    fn wait_idle(&self) -> Result<(), FlashError> {
        let t0 = DWT::cycle_count();
        while self.regs.sr().read().bsy().bit_is_set() {
            if DWT::cycle_count().wrapping_sub(t0) > BUSY_TIMEOUT_CYCLES {
                return Err(FlashError::Timeout);
            }
        }
        Ok(())
    }

    /// Wait for the previous operation, clear flags left by anything earlier (a stray
    /// write, an option-byte check at boot) without failing on them, unlock.
    fn begin(&self) -> Result<Unlocked<'_>, FlashError> {
        self.usable?;
        self.wait_idle()?;
        // SAFETY: writing ones to the rc_w1 flags clears them (EOP included).
        self.regs.sr().write(|w| unsafe { w.bits(SR_ERRORS | 1) });
        if self.regs.cr().read().lock().bit_is_set() {
            // SAFETY: the documented unlock sequence (§3.3.5).
            self.regs.keyr().write(|w| unsafe { w.keyr().bits(KEY1) });
            self.regs.keyr().write(|w| unsafe { w.keyr().bits(KEY2) });
        }
        Ok(Unlocked(&self.regs))
    }

    /// Wait for the operation just started; the errors it raised.
    fn finish(regs: &FLASH, t_busy: Result<(), FlashError>) -> Result<(), FlashError> {
        t_busy?;
        match FlashError::from_sr(regs.sr().read().bits() & SR_ERRORS) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

impl FlashSlots for Flash {
    type Error = FlashError;

    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), FlashError> {
        self.usable?;
        let base = slot_addr(slot) as *const u8;
        ECC_FAULT.store(false, Ordering::SeqCst);
        for (i, b) in buf.iter_mut().take(PAGE_BYTES).enumerate() {
            // SAFETY: inside the calibration pages, which memory.x reserves.
            *b = unsafe { base.add(i).read_volatile() };
        }
        if ECC_FAULT.swap(false, Ordering::SeqCst) {
            Err(FlashError::EccDouble)
        } else {
            Ok(())
        }
    }

    fn erase(&mut self, slot: Slot) -> Result<(), FlashError> {
        // Page index within bank 2 (BKER = 1), below 128 (checked in `new`).
        let page = ((slot_addr(slot) - BANK2_START) / PAGE_BYTES) as u8;
        let guard = self.begin()?;
        let f = guard.0;
        // SAFETY: PNB is a page index of bank 2, below 128.
        f.cr()
            .modify(|_, w| unsafe { w.per().set_bit().bker().set_bit().pnb().bits(page) });
        f.cr().modify(|_, w| w.strt().set_bit());
        let busy = self.wait_idle();
        Self::finish(&self.regs, busy)
    }

    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), FlashError> {
        let base = slot_addr(slot) + offset;
        let guard = self.begin()?;
        guard.0.cr().modify(|_, w| w.pg().set_bit());
        for (k, dw) in data.chunks_exact(8).enumerate() {
            let addr = (base + 8 * k) as *mut u32;
            let lo = u32::from_le_bytes([dw[0], dw[1], dw[2], dw[3]]);
            let hi = u32::from_le_bytes([dw[4], dw[5], dw[6], dw[7]]);
            // SAFETY: double-word aligned address inside the calibration pages; the two
            // words are written back to back as §3.3.8 requires.
            unsafe {
                addr.write_volatile(lo);
                addr.add(1).write_volatile(hi);
            }
            let busy = self.wait_idle();
            Self::finish(&self.regs, busy)?;
        }
        Ok(())
    }
}

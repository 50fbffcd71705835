//! The calibration record in flash: `calib-record`'s two alternating slots on two 2 KiB
//! pages of bank 1 (below 256 KiB: stm32g4xx-hal 0.1.0 mishandles dual-bank page numbers
//! above that, and we program through the PAC the same way). The page addresses come
//! from `memory.x` (symbol `_calib_start`), the one owner of the memory map.
//! RM0440 §3.3.7 (page erase), §3.3.8 (double-word programming).

use calib_record::{config_hash, FlashSlots, Slot, PAGE_BYTES};
use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::interrupt::Mutex;
use mras::{Coefficients, Config};
use stm32g4xx_hal::stm32::FLASH;

extern "C" {
    /// First byte of the two calibration pages (memory.x).
    static _calib_start: u8;
}

const FLASH_BASE: usize = 0x0800_0000;
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;

static FLASH_PERIPHERAL: Mutex<RefCell<Option<FLASH>>> = Mutex::new(RefCell::new(None));

/// Set by the NMI handler when a flash read hit a double ECC error (RM0440 §3.3.4): a
/// double word torn by a power cut during programming. `read` turns it into an error, so
/// `calib_record::load` falls back to the other slot instead of the drive resetting
/// forever on the same bad word.
static ECC_FAULT: AtomicBool = AtomicBool::new(false);

/// The value `FlashError` carries for an ECC double error (not an SR bit).
const ECC_DOUBLE_ERROR: u32 = 1 << 31;

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

pub fn init(flash: FLASH) {
    cortex_m::interrupt::free(|cs| FLASH_PERIPHERAL.borrow(cs).replace(Some(flash)));
}

fn slot_addr(slot: Slot) -> usize {
    // Only the address of the linker symbol is taken, never its value.
    let base = core::ptr::addr_of!(_calib_start) as usize;
    base + slot.index() * PAGE_BYTES
}

/// Why a flash operation failed: the SR error bits (PROGERR, WRPERR, PGAERR, ...).
#[derive(Clone, Copy, Debug, defmt::Format)]
pub struct FlashError(pub u32);

struct Pages<'a>(&'a FLASH);

impl Pages<'_> {
    fn wait(&self) -> Result<(), FlashError> {
        while self.0.sr().read().bsy().bit_is_set() {}
        // Error flags: bits 1..=15 of SR (§3.7.5); write 1 to clear.
        let sr = self.0.sr().read().bits();
        let errors = sr & 0xC3FA;
        // SAFETY: writing ones to the rc_w1 flags clears them.
        self.0.sr().write(|w| unsafe { w.bits(errors | 1) });
        if errors != 0 {
            Err(FlashError(errors))
        } else {
            Ok(())
        }
    }

    fn unlock(&self) {
        if self.0.cr().read().lock().bit_is_set() {
            // SAFETY: the documented unlock sequence (§3.3.5).
            self.0.keyr().write(|w| unsafe { w.keyr().bits(KEY1) });
            self.0.keyr().write(|w| unsafe { w.keyr().bits(KEY2) });
        }
    }

    fn lock(&self) {
        self.0.cr().modify(|_, w| w.lock().set_bit());
        // Reads after a write must not hit stale data-cache lines (§3.3.3).
        self.0.acr().modify(|_, w| w.dcen().clear_bit());
        self.0.acr().modify(|_, w| w.dcrst().set_bit());
        self.0
            .acr()
            .modify(|_, w| w.dcrst().clear_bit().dcen().set_bit());
    }
}

impl FlashSlots for Pages<'_> {
    type Error = FlashError;

    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), FlashError> {
        let base = slot_addr(slot) as *const u8;
        ECC_FAULT.store(false, Ordering::SeqCst);
        for (i, b) in buf.iter_mut().take(PAGE_BYTES).enumerate() {
            // SAFETY: inside the calibration pages, which memory.x reserves.
            *b = unsafe { base.add(i).read_volatile() };
        }
        if ECC_FAULT.swap(false, Ordering::SeqCst) {
            Err(FlashError(ECC_DOUBLE_ERROR))
        } else {
            Ok(())
        }
    }

    fn erase(&mut self, slot: Slot) -> Result<(), FlashError> {
        let page = ((slot_addr(slot) - FLASH_BASE) / PAGE_BYTES) as u8;
        self.unlock();
        self.wait()?;
        // SAFETY: PNB is the page index within bank 1 (BKER = 0), below 128.
        self.0
            .cr()
            .modify(|_, w| unsafe { w.per().set_bit().bker().clear_bit().pnb().bits(page) });
        self.0.cr().modify(|_, w| w.strt().set_bit());
        let r = self.wait();
        self.0.cr().modify(|_, w| w.per().clear_bit());
        self.lock();
        r
    }

    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), FlashError> {
        self.unlock();
        self.wait()?;
        self.0.cr().modify(|_, w| w.pg().set_bit());
        let mut r = Ok(());
        for (k, dw) in data.chunks_exact(8).enumerate() {
            let addr = (slot_addr(slot) + offset + 8 * k) as *mut u32;
            let lo = u32::from_le_bytes([dw[0], dw[1], dw[2], dw[3]]);
            let hi = u32::from_le_bytes([dw[4], dw[5], dw[6], dw[7]]);
            // SAFETY: double-word aligned address inside the calibration pages; the two
            // words are written back to back as §3.3.8 requires.
            unsafe {
                addr.write_volatile(lo);
                addr.add(1).write_volatile(hi);
            }
            r = self.wait();
            if r.is_err() {
                break;
            }
        }
        self.0.cr().modify(|_, w| w.pg().clear_bit());
        self.lock();
        r
    }
}

/// The stored coefficients, if a record valid for `cfg` exists.
pub fn load(cfg: &Config) -> Option<Coefficients> {
    cortex_m::interrupt::free(|cs| {
        let f = FLASH_PERIPHERAL.borrow(cs).borrow();
        let flash = f.as_ref()?;
        match calib_record::load(&Pages(flash), config_hash(cfg)) {
            Ok(l) => {
                defmt::info!("calibration: loaded sequence {=u32}", l.record.sequence);
                Some(l.record.coefficients)
            }
            Err(_) => {
                defmt::info!("calibration: no valid record, commissioning");
                None
            }
        }
    })
}

/// Store `coefs` for `cfg`; false on any failure (the previous record stays valid).
/// Called with the PWM outputs off: the erase stalls code fetch from bank 1.
pub fn store(coefs: &Coefficients, cfg: &Config) -> bool {
    cortex_m::interrupt::free(|cs| {
        let f = FLASH_PERIPHERAL.borrow(cs).borrow();
        let Some(flash) = f.as_ref() else {
            return false;
        };
        match calib_record::store(&mut Pages(flash), coefs, config_hash(cfg)) {
            Ok(_) => {
                defmt::info!("calibration: stored");
                true
            }
            Err(_) => {
                defmt::error!("calibration: store failed");
                false
            }
        }
    })
}

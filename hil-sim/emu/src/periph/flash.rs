//! The flash interface (RM0440 §3): unlock, bank-aware page erase, double-word
//! programming with its error flags, write protection from the option bytes, and the
//! double ECC error of a torn double word.

use crate::elf::FLASH_BASE;
use crate::regfile::RegFile;

pub const FLASH: u32 = 0x4002_2000;
pub const ACR: u32 = FLASH;
pub const KEYR: u32 = FLASH + 0x08;
pub const SR: u32 = FLASH + 0x10;
pub const CR: u32 = FLASH + 0x14;
pub const ECCR: u32 = FLASH + 0x18;
pub const OPTR: u32 = FLASH + 0x20;
pub const WRP2AR: u32 = FLASH + 0x4C;

const SR_EOP: u32 = 1 << 0;
const SR_PROGERR: u32 = 1 << 3;
const SR_WRPERR: u32 = 1 << 4;
const SR_PGAERR: u32 = 1 << 5;
const SR_SIZERR: u32 = 1 << 6;
const SR_PGSERR: u32 = 1 << 7;
/// All error flags (§3.7.5).
pub const SR_ERRORS: u32 = 0xC3FA;
const SR_BSY: u32 = 1 << 16;
const CR_PG: u32 = 1 << 0;
const CR_PER: u32 = 1 << 1;
const CR_BKER: u32 = 1 << 11;
const CR_STRT: u32 = 1 << 16;
const CR_EOPIE: u32 = 1 << 24;
const CR_LOCK: u32 = 1 << 31;
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;
const OPTR_DBANK: u32 = 1 << 22;
const ECCR_ECCD: u32 = 1 << 31;

/// Page size in dual-bank mode and the bank size (§3.3.1).
pub const PAGE_BYTES: u32 = 2048;
pub const BANK_BYTES: u32 = 256 * 1024;
/// t_ERASE (DS12288: 22 ms typical) and t_PROG per double word (82 µs typical).
pub const ERASE_S: f64 = 22.0e-3;
pub const PROGRAM_S: f64 = 82.0e-6;

/// A deliberately wrong flash controller, for a check that a flash tool notices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashMutation {
    /// CR.PNB read 6 bits wide instead of 7 (§3.7.6: PNB is CR[9:3]): pages 64-127 of
    /// a bank erase pages 0-63.
    PnbWrongWidth,
    /// The keys in the wrong order: KEY2 then KEY1 unlocks, and the order §3.3.5
    /// requires (KEY1 then KEY2) locks the controller out until reset, so a correct
    /// tool fails to unlock. (Accepting both orders would not fail a correct tool.)
    KeysAnyOrder,
}

#[derive(Debug, Default, Clone)]
pub struct FlashCtl {
    /// A wrong model on purpose (None: RM0440's). Survives resets.
    pub mutation: Option<FlashMutation>,
    key_stage: u8,
    /// Locked until the next reset after a wrong key (§3.3.5).
    key_locked_out: bool,
    busy_until: Option<u64>,
    /// The first word of a double word being programmed.
    first_word: Option<(u32, u32)>,
    /// Torn double words (a power cut while programming): reads raise a double ECC error.
    pub torn: Vec<u32>,
    /// The double word being programmed (offset into the image), until BSY clears.
    pub in_flight: Option<u32>,
    /// Erases of the bank the CPU is fetching its code from: it stalls (no
    /// read-while-write).
    pub code_bank_erases: u32,
    pub erases: u32,
    pub programs: u32,
    /// Operations refused because error flags of an earlier one were still set.
    pub stale_flag_refusals: u32,
    /// What the firmware asked of the flash and the hardware refused (FLASH_SR flags,
    /// §3.7.5): programming a double word that is not erased (PROGERR), misaligned
    /// (PGAERR), narrower than a word (SIZERR), or without PG / while locked (PGSERR).
    pub errors: FlashErrors,
    /// Operations started while BSY (erase STRT, a double word's second write): RM0440
    /// does not say what silicon does with them; dropped here.
    pub while_busy: u32,
    /// Reads of torn double words (double ECC errors, each raising the NMI).
    pub ecc_double_errors: u32,
}

/// Programming errors the firmware caused, by flag.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct FlashErrors {
    pub progerr: u32,
    pub pgaerr: u32,
    pub sizerr: u32,
    pub pgserr: u32,
}

/// What a flash operation needs from the machine.
pub enum Effect {
    None,
    /// Erase these bytes (offset into the flash image, length).
    Erase {
        offset: u32,
        stall_cpu: bool,
    },
    /// Program a double word at this offset.
    Program {
        offset: u32,
        lo: u32,
        hi: u32,
    },
}

impl FlashCtl {
    pub fn reset(&mut self, regs: &mut RegFile) {
        *self = Self {
            torn: std::mem::take(&mut self.torn),
            code_bank_erases: self.code_bank_erases,
            erases: self.erases,
            programs: self.programs,
            stale_flag_refusals: self.stale_flag_refusals,
            errors: self.errors,
            while_busy: self.while_busy,
            ecc_double_errors: self.ecc_double_errors,
            mutation: self.mutation,
            ..Self::default()
        };
        regs.set_bits(CR, CR_LOCK, true);
    }

    pub fn busy(&self) -> bool {
        self.busy_until.is_some()
    }

    pub fn next_event(&self) -> Option<u64> {
        self.busy_until
    }

    /// The end of an operation: BSY clears, EOP if enabled (§3.7.5).
    pub fn complete(&mut self, regs: &mut RegFile, now: u64) {
        if self.busy_until.is_some_and(|t| t <= now) {
            self.busy_until = None;
            self.in_flight = None;
            regs.set_bits(SR, SR_BSY, false);
            if regs.bit(CR, CR_EOPIE) {
                regs.set_bits(SR, SR_EOP, true);
            }
        }
    }

    fn dual_bank(regs: &RegFile) -> bool {
        regs.bit(OPTR, OPTR_DBANK)
    }

    /// Write-protected by the bank-2 WRP areas (§3.5.2): page in [STRT, END].
    fn protected(regs: &RegFile, bank2: bool, page: u32) -> bool {
        if !bank2 {
            return false;
        }
        [WRP2AR, WRP2AR + 4].iter().any(|&r| {
            let v = regs.get(r);
            let (strt, end) = (v & 0x7F, (v >> 16) & 0x7F);
            strt <= end && (strt..=end).contains(&page)
        })
    }

    pub fn on_write(
        &mut self,
        regs: &mut RegFile,
        addr: u32,
        old: u32,
        now: u64,
        code_bank2: bool,
        cpu_fetching_from_flash: bool,
    ) -> Effect {
        match addr {
            KEYR => {
                let v = regs.get(KEYR);
                let any_order = self.mutation == Some(FlashMutation::KeysAnyOrder);
                match (self.key_stage, v) {
                    (0, KEY2) if any_order => self.key_stage = 2,
                    (0, KEY1) if !any_order => self.key_stage = 1,
                    (2, KEY1) if any_order => {
                        regs.set_bits(CR, CR_LOCK, false);
                        self.key_stage = 0;
                    }
                    (1, KEY2) if !self.key_locked_out => {
                        regs.set_bits(CR, CR_LOCK, false);
                        self.key_stage = 0;
                    }
                    _ => {
                        self.key_locked_out = true;
                        self.key_stage = 0;
                    }
                }
                Effect::None
            }
            CR => {
                if old & CR_LOCK != 0 {
                    // Locked: writes ignored (LOCK itself stays set).
                    regs.set(CR, old);
                    return Effect::None;
                }
                let cr = regs.get(CR);
                if cr & CR_STRT == 0 {
                    return Effect::None;
                }
                regs.set_bits(CR, CR_STRT, false);
                if cr & CR_PER == 0 {
                    return Effect::None;
                }
                if self.refuse_stale(regs) || self.refuse_busy() {
                    return Effect::None;
                }
                if cr & CR_PG != 0 {
                    regs.set_bits(SR, SR_PGSERR, true);
                    self.errors.pgserr += 1;
                    return Effect::None;
                }
                let dual = Self::dual_bank(regs);
                let page = if self.mutation == Some(FlashMutation::PnbWrongWidth) {
                    (cr >> 3) & 0x3F
                } else {
                    (cr >> 3) & 0x7F
                };
                let bank2 = cr & CR_BKER != 0;
                let page_bytes = if dual { PAGE_BYTES } else { 2 * PAGE_BYTES };
                let offset = if bank2 { BANK_BYTES } else { 0 } + page * page_bytes;
                if Self::protected(regs, bank2, page) {
                    regs.set_bits(SR, SR_WRPERR, true);
                    return Effect::None;
                }
                self.erases += 1;
                let stall_cpu = cpu_fetching_from_flash && (!dual || bank2 == code_bank2);
                if stall_cpu {
                    self.code_bank_erases += 1;
                }
                self.busy_until = Some(now + super::ticks(ERASE_S));
                regs.set_bits(SR, SR_BSY, true);
                Effect::Erase { offset, stall_cpu }
            }
            _ => Effect::None,
        }
    }

    /// Error flags of an earlier operation still set: the new one is refused with
    /// PGSERR (§3.3.7 step 2, §3.3.8 step 2: "check and clear all error flags").
    fn refuse_stale(&mut self, regs: &mut RegFile) -> bool {
        if regs.get(SR) & SR_ERRORS != 0 {
            regs.set_bits(SR, SR_PGSERR, true);
            self.stale_flag_refusals += 1;
            true
        } else {
            false
        }
    }

    fn refuse_busy(&mut self) -> bool {
        if self.busy() {
            self.while_busy += 1;
        }
        self.busy()
    }

    /// A power cut: the double word being programmed is left torn (data and ECC
    /// inconsistent; its next read is a double ECC error). Returns its offset.
    pub fn power_cut(&mut self) -> Option<u32> {
        let dw = self.in_flight.take()?;
        self.busy_until = None;
        if !self.torn.contains(&dw) {
            self.torn.push(dw);
        }
        Some(dw)
    }

    /// A bus write into the flash array (programming, §3.3.8). `erased` tells whether
    /// the double word at an offset is all ones.
    pub fn on_array_write(
        &mut self,
        regs: &mut RegFile,
        addr: u32,
        size: usize,
        v: u32,
        now: u64,
        erased: &dyn Fn(u32) -> bool,
    ) -> Effect {
        if !regs.bit(CR, CR_PG) || regs.bit(CR, CR_LOCK) {
            regs.set_bits(SR, SR_PGSERR, true);
            self.errors.pgserr += 1;
            return Effect::None;
        }
        if size != 4 {
            regs.set_bits(SR, SR_SIZERR, true);
            self.errors.sizerr += 1;
            return Effect::None;
        }
        match self.first_word.take() {
            None => {
                if !addr.is_multiple_of(8) {
                    regs.set_bits(SR, SR_PGAERR, true);
                    self.errors.pgaerr += 1;
                    return Effect::None;
                }
                self.first_word = Some((addr, v));
                Effect::None
            }
            Some((a0, lo)) => {
                if addr != a0 + 4 {
                    regs.set_bits(SR, SR_PGAERR, true);
                    self.errors.pgaerr += 1;
                    return Effect::None;
                }
                if self.refuse_stale(regs) || self.refuse_busy() {
                    return Effect::None;
                }
                let offset = a0 - FLASH_BASE;
                let bank2 = offset >= BANK_BYTES;
                let page = (offset % BANK_BYTES) / PAGE_BYTES;
                if Self::protected(regs, bank2, page) {
                    regs.set_bits(SR, SR_WRPERR, true);
                    return Effect::None;
                }
                // PROGERR: the double word is not erased, unless the data is all zeros
                // (§3.7.5 FLASH_SR.PROGERR).
                if !erased(offset) && (lo, v) != (0, 0) {
                    regs.set_bits(SR, SR_PROGERR, true);
                    self.errors.progerr += 1;
                    return Effect::None;
                }
                self.programs += 1;
                self.in_flight = Some(offset);
                self.busy_until = Some(now + super::ticks(PROGRAM_S));
                regs.set_bits(SR, SR_BSY, true);
                self.torn.retain(|&t| t != offset);
                Effect::Program { offset, lo, hi: v }
            }
        }
    }

    /// A read of the array at `offset`: a torn double word sets ECCD and raises the NMI
    /// (§3.3.4). Returns whether the NMI is raised.
    pub fn on_array_read(&mut self, regs: &mut RegFile, offset: u32) -> bool {
        let dw = offset & !7;
        if !self.torn.contains(&dw) {
            return false;
        }
        self.ecc_double_errors += 1;
        let bank2 = dw >= BANK_BYTES;
        let addr = (dw % BANK_BYTES) & 0x7FFFF;
        regs.set(
            ECCR,
            (regs.get(ECCR) & 0x0F00_0000) | ECCR_ECCD | (bank2 as u32) << 21 | addr,
        );
        true
    }
}

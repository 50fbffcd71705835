//! An in-memory [`FlashSlots`] that enforces the STM32G4 flash rules and can lose power
//! at any step, for host tests (and the simulator).

use crate::layout::{DOUBLE_WORDS_PER_PAGE, DOUBLE_WORD_BYTES, ERASED_BYTE, PAGE_BYTES};
use crate::slots::{FlashSlots, Slot};

/// A [`RamFlash`] operation refused, as the hardware would (or could not run at all).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RamFlashError {
    /// Beyond the page.
    OutOfBounds,
    /// Program offset or length not a multiple of a double word.
    Misaligned,
    /// Programming a double word that was programmed since its last erase, or is not
    /// all 0xFF (on the chip: PROGERR, or a corrupt ECC).
    NotErased,
    /// Power was cut (see [`RamFlash::cut_power_after`]); nothing works until
    /// [`RamFlash::power_on`].
    PowerLost,
}

/// Two flash pages in RAM.
///
/// Power loss: every erase and every programmed double word is one *operation*.
/// [`RamFlash::cut_power_after`]`(n, torn)` lets `n` more operations complete; the
/// next one is interrupted. A clean interruption changes nothing; a torn one leaves a
/// partial result: a torn erase erases only the odd double words of the page (magic
/// intact, body half gone: the worst case for a decoder), a torn program writes only
/// the first 4 bytes of the double word.
#[derive(Clone, Debug)]
pub struct RamFlash {
    pages: [[u8; PAGE_BYTES]; 2],
    /// Double words programmed since their last erase.
    programmed: [[bool; DOUBLE_WORDS_PER_PAGE]; 2],
    /// Operations left before the power cut, and whether it tears the operation.
    cut: Option<(u32, bool)>,
    powered: bool,
    operations: u32,
    erases: [u32; 2],
}

impl Default for RamFlash {
    fn default() -> Self {
        Self::new()
    }
}

impl RamFlash {
    /// Both pages erased, power on.
    pub const fn new() -> Self {
        Self {
            pages: [[ERASED_BYTE; PAGE_BYTES]; 2],
            programmed: [[false; DOUBLE_WORDS_PER_PAGE]; 2],
            cut: None,
            powered: true,
            operations: 0,
            erases: [0; 2],
        }
    }

    /// The raw page of a slot.
    pub fn page(&self, slot: Slot) -> &[u8; PAGE_BYTES] {
        &self.pages[slot.index()]
    }

    /// Raw write access, bypassing the flash rules (to plant corruption in tests).
    pub fn page_mut(&mut self, slot: Slot) -> &mut [u8; PAGE_BYTES] {
        &mut self.pages[slot.index()]
    }

    /// Let `operations` more erases/double-word programs complete, then interrupt the
    /// next one (`torn`: leave it half done) and cut the power.
    pub fn cut_power_after(&mut self, operations: u32, torn: bool) {
        self.cut = Some((operations, torn));
    }

    /// Restore power (a reboot) and cancel any pending cut.
    pub fn power_on(&mut self) {
        self.powered = true;
        self.cut = None;
    }

    pub fn is_powered(&self) -> bool {
        self.powered
    }

    /// Erases plus double words programmed since creation.
    pub fn operations(&self) -> u32 {
        self.operations
    }

    /// Erases of one slot's page since creation.
    pub fn erase_count(&self, slot: Slot) -> u32 {
        self.erases[slot.index()]
    }

    /// Account for one operation; `Err(torn)` if the power goes during it.
    fn begin_operation(&mut self) -> Result<(), bool> {
        match self.cut {
            Some((0, torn)) => {
                self.powered = false;
                self.cut = None;
                Err(torn)
            }
            Some((n, torn)) => {
                self.cut = Some((n - 1, torn));
                self.operations = self.operations.saturating_add(1);
                Ok(())
            }
            None => {
                self.operations = self.operations.saturating_add(1);
                Ok(())
            }
        }
    }
}

impl FlashSlots for RamFlash {
    type Error = RamFlashError;

    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), RamFlashError> {
        if !self.powered {
            return Err(RamFlashError::PowerLost);
        }
        let src = self.pages[slot.index()]
            .get(..buf.len())
            .ok_or(RamFlashError::OutOfBounds)?;
        buf.copy_from_slice(src);
        Ok(())
    }

    fn erase(&mut self, slot: Slot) -> Result<(), RamFlashError> {
        if !self.powered {
            return Err(RamFlashError::PowerLost);
        }
        let i = slot.index();
        match self.begin_operation() {
            Ok(()) => {
                self.pages[i].fill(ERASED_BYTE);
                self.programmed[i].fill(false);
                self.erases[i] = self.erases[i].saturating_add(1);
                Ok(())
            }
            Err(torn) => {
                if torn {
                    for dw in self.pages[i]
                        .chunks_exact_mut(DOUBLE_WORD_BYTES)
                        .skip(1)
                        .step_by(2)
                    {
                        dw.fill(ERASED_BYTE);
                    }
                }
                Err(RamFlashError::PowerLost)
            }
        }
    }

    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), RamFlashError> {
        if !self.powered {
            return Err(RamFlashError::PowerLost);
        }
        if offset % DOUBLE_WORD_BYTES != 0 || data.len() % DOUBLE_WORD_BYTES != 0 {
            return Err(RamFlashError::Misaligned);
        }
        if offset
            .checked_add(data.len())
            .is_none_or(|end| end > PAGE_BYTES)
        {
            return Err(RamFlashError::OutOfBounds);
        }
        let i = slot.index();
        let first = offset / DOUBLE_WORD_BYTES;
        // The chip checks each double word as it goes; so do we.
        for (n, dw) in data.chunks_exact(DOUBLE_WORD_BYTES).enumerate() {
            let w = first + n;
            let at = w * DOUBLE_WORD_BYTES;
            let range = at..at + DOUBLE_WORD_BYTES;
            if self.programmed[i][w]
                || self.pages[i][range.clone()]
                    .iter()
                    .any(|&b| b != ERASED_BYTE)
            {
                return Err(RamFlashError::NotErased);
            }
            // A torn program writes the first half only.
            let (written, result) = match self.begin_operation() {
                Ok(()) => (DOUBLE_WORD_BYTES, Ok(())),
                Err(true) => (DOUBLE_WORD_BYTES / 2, Err(RamFlashError::PowerLost)),
                Err(false) => (0, Err(RamFlashError::PowerLost)),
            };
            if written > 0 {
                // Programming only clears bits.
                for (t, &d) in self.pages[i][range].iter_mut().zip(dw).take(written) {
                    *t &= d;
                }
                self.programmed[i][w] = true;
            }
            result?;
        }
        Ok(())
    }
}

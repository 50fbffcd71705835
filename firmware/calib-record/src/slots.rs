//! Two alternating slots: loading the newest valid record and storing a new one
//! without ever endangering the last good one.

use crate::layout::{COMMIT_OFFSET, RECORD_BYTES};
use crate::record::{decode, decode_intact, encode, Calibration, Record, RecordError};

/// One of the two record slots (slot A = page n, slot B = page n + 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Slot {
    A,
    B,
}

impl Slot {
    pub const BOTH: [Slot; 2] = [Slot::A, Slot::B];

    /// The slot a store alternates to.
    pub const fn other(self) -> Slot {
        match self {
            Slot::A => Slot::B,
            Slot::B => Slot::A,
        }
    }

    /// 0 for A, 1 for B (page n + index).
    pub const fn index(self) -> usize {
        match self {
            Slot::A => 0,
            Slot::B => 1,
        }
    }
}

/// The two flash pages, as the firmware (HAL/PAC) or a test double provides them.
///
/// Offsets are bytes from the start of the slot's page. Each slot is a whole page of
/// [`crate::PAGE_BYTES`]; erasing one slot must not touch the other.
pub trait FlashSlots {
    type Error;

    /// Read `buf.len()` bytes from the start of `slot`.
    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), Self::Error>;

    /// Erase the page of `slot` (every byte becomes 0xFF).
    fn erase(&mut self, slot: Slot) -> Result<(), Self::Error>;

    /// Program `data` at `offset`. This crate only passes an `offset` and a
    /// `data.len()` that are multiples of [`crate::DOUBLE_WORD_BYTES`], onto double
    /// words erased since they were last programmed, and programs them in address
    /// order.
    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), Self::Error>;
}

/// Why a slot's content was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejected<E> {
    Record(RecordError),
    /// The read itself failed.
    Flash(E),
}

impl<E> Rejected<E> {
    /// [`RecordError::name`], or "Flash" for a failed read.
    pub const fn name(&self) -> &'static str {
        match self {
            Rejected::Record(e) => e.name(),
            Rejected::Flash(_) => "Flash",
        }
    }

    /// How much the rejection says about what the slot holds, for
    /// [`LoadError::reason`]: nothing (erased) lowest, then a failed read, then damaged
    /// or interrupted writes (in [`decode`]'s order), then a record of another format
    /// version, then a sealed record with invalid content, and highest an intact record
    /// of another configuration.
    const fn rank(&self) -> u8 {
        match self {
            Rejected::Record(RecordError::Erased) => 0,
            Rejected::Flash(_) => 1,
            Rejected::Record(RecordError::Truncated) => 2,
            Rejected::Record(RecordError::BadMagic) => 3,
            Rejected::Record(RecordError::Incomplete) => 4,
            Rejected::Record(RecordError::BadCrc) => 5,
            Rejected::Record(RecordError::UnsupportedVersion { .. }) => 6,
            Rejected::Record(RecordError::BadPathList) => 7,
            Rejected::Record(RecordError::NonFiniteValue) => 8,
            Rejected::Record(RecordError::BadAlignment) => 9,
            Rejected::Record(RecordError::BadMotor) => 10,
            Rejected::Record(RecordError::ConfigMismatch { .. }) => 11,
        }
    }
}

/// What the slot that was not loaded holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OtherSlot<E> {
    /// A valid record that is not newer (the previous calibration).
    Superseded {
        sequence: u32,
    },
    Rejected(Rejected<E>),
}

/// The newest valid record, where it came from, and what the other slot holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Loaded<E> {
    pub record: Record,
    pub slot: Slot,
    pub other: OtherSlot<E>,
}

/// Neither slot holds a record valid for this configuration: self-commission.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadError<E> {
    NoValidRecord { a: Rejected<E>, b: Rejected<E> },
}

impl<E> LoadError<E> {
    /// The more informative of the two slots' rejections: `Erased` only if both slots
    /// are erased; otherwise the one that says more about what the flash holds: a
    /// record of another configuration or format version over a damaged or
    /// interrupted write (e.g. a version-1 record's `UnsupportedVersion` over an
    /// interrupted store's `Incomplete`, a `ConfigMismatch` over a `BadCrc`). Slot A's
    /// on a tie.
    pub const fn reason(&self) -> &Rejected<E> {
        match self {
            LoadError::NoValidRecord { a, b } => {
                if b.rank() > a.rank() {
                    b
                } else {
                    a
                }
            }
        }
    }

    /// The name of [`LoadError::reason`] (see [`RecordError::name`]; "Flash" for a
    /// failed read): why the drive self-commissions, for the log.
    pub const fn name(&self) -> &'static str {
        self.reason().name()
    }
}

/// Why a store did not complete. In every case the previous newest valid record is
/// untouched: [`load`] still returns it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreError<E> {
    /// The calibration would not decode (non-finite coefficient, invalid path list,
    /// alignment offset not finite or outside [-π, π], invalid motor constants); flash
    /// was not touched.
    InvalidCalibration(RecordError),
    /// Erase, program or read failed.
    Flash(E),
    /// The read-back differs from what was programmed.
    VerifyFailed,
}

impl<E> StoreError<E> {
    /// The variant's name, without its fields: stable, for logs.
    pub const fn name(&self) -> &'static str {
        match self {
            StoreError::InvalidCalibration(_) => "InvalidCalibration",
            StoreError::Flash(_) => "Flash",
            StoreError::VerifyFailed => "VerifyFailed",
        }
    }
}

impl<E> From<E> for StoreError<E> {
    fn from(e: E) -> Self {
        StoreError::Flash(e)
    }
}

/// Sequence number of the first record written to a blank pair of slots.
pub const FIRST_SEQUENCE: u32 = 1;

/// Serial-number arithmetic (RFC 1982): `a` is newer than `b` if it is less than 2³¹
/// steps ahead, so the counter may wrap.
pub const fn is_newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

fn examine<F: FlashSlots>(
    flash: &F,
    slot: Slot,
    check: impl Fn(&[u8]) -> Result<Record, RecordError>,
) -> Result<Record, Rejected<F::Error>> {
    let mut buf = [0u8; RECORD_BYTES];
    flash.read(slot, &mut buf).map_err(Rejected::Flash)?;
    check(&buf).map_err(Rejected::Record)
}

/// Read both slots and return the newest record valid for `expected_hash` (on equal
/// sequence numbers, slot A).
pub fn load<F: FlashSlots>(
    flash: &F,
    expected_hash: u32,
) -> Result<Loaded<F::Error>, LoadError<F::Error>> {
    let check = |b: &[u8]| decode(b, expected_hash);
    let a = examine(flash, Slot::A, check);
    let b = examine(flash, Slot::B, check);
    match (a, b) {
        (Ok(ra), Ok(rb)) if is_newer(rb.sequence, ra.sequence) => Ok(Loaded {
            record: rb,
            slot: Slot::B,
            other: OtherSlot::Superseded {
                sequence: ra.sequence,
            },
        }),
        (Ok(ra), Ok(rb)) => Ok(Loaded {
            record: ra,
            slot: Slot::A,
            other: OtherSlot::Superseded {
                sequence: rb.sequence,
            },
        }),
        (Ok(ra), Err(e)) => Ok(Loaded {
            record: ra,
            slot: Slot::A,
            other: OtherSlot::Rejected(e),
        }),
        (Err(e), Ok(rb)) => Ok(Loaded {
            record: rb,
            slot: Slot::B,
            other: OtherSlot::Rejected(e),
        }),
        (Err(a), Err(b)) => Err(LoadError::NoValidRecord { a, b }),
    }
}

/// Write `calibration` as a new record and return the slot it went to.
///
/// The target is the slot *not* holding the record [`load`] would return for
/// `cfg_hash` (failing that, not the newest intact record of another configuration);
/// that slot is never erased. Order: erase the target, program the body, program the
/// last double word (CRC + commit mark), read back and compare. A power loss at any
/// point leaves `load` returning the previous record or the new one. The sequence
/// number is one past the newest intact record in either slot.
///
/// Each store erases one page; the STM32G4 flash is rated for 10 000 cycles per page,
/// so store once per commissioning, not periodically.
pub fn store<F: FlashSlots>(
    flash: &mut F,
    calibration: &Calibration,
    cfg_hash: u32,
) -> Result<Slot, StoreError<F::Error>> {
    let a = examine(flash, Slot::A, decode_intact).ok();
    let b = examine(flash, Slot::B, decode_intact).ok();
    let keep = |r: &Record| (r.config_hash == cfg_hash, r.sequence);
    let protected = match (&a, &b) {
        (Some(ra), Some(rb)) => {
            let (ma, sa) = keep(ra);
            let (mb, sb) = keep(rb);
            if mb && !ma || mb == ma && is_newer(sb, sa) {
                Some(Slot::B)
            } else {
                Some(Slot::A)
            }
        }
        (Some(_), None) => Some(Slot::A),
        (None, Some(_)) => Some(Slot::B),
        (None, None) => None,
    };
    let target = protected.map_or(Slot::A, Slot::other);
    let newest_seq = match (&a, &b) {
        (Some(ra), Some(rb)) if is_newer(rb.sequence, ra.sequence) => Some(rb.sequence),
        (Some(ra), _) => Some(ra.sequence),
        (None, Some(rb)) => Some(rb.sequence),
        (None, None) => None,
    };
    let sequence = newest_seq.map_or(FIRST_SEQUENCE, |s| s.wrapping_add(1));

    let mut buf = [0u8; RECORD_BYTES];
    encode(calibration, sequence, cfg_hash, &mut buf);
    // Refuse before erasing anything what load would refuse.
    decode(&buf, cfg_hash).map_err(StoreError::InvalidCalibration)?;

    let (body, commit) = buf.split_at(COMMIT_OFFSET);
    flash.erase(target)?;
    flash.program(target, 0, body)?;
    flash.program(target, COMMIT_OFFSET, commit)?;

    let mut back = [0u8; RECORD_BYTES];
    flash.read(target, &mut back)?;
    if back != buf {
        return Err(StoreError::VerifyFailed);
    }
    Ok(target)
}

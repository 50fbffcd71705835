//! Flash geometry (STM32G474, RM0440 §3) and the record layout: the one place for
//! these numbers.
//!
//! # Slots and pages
//!
//! Two slots, **one flash page each** (slot A = page n, slot B = page n + 1): a page is
//! the erase unit, so erasing one slot never disturbs the other. The firmware keeps them
//! in the flash bank it does not run from (read-while-write). The addresses belong to
//! `memory.x`; this crate only sees slots through [`crate::FlashSlots`].
//!
//! # Record (little-endian, [`RECORD_BYTES`] = 256 bytes at the start of a slot)
//!
//! Format version 5. Version 4 (this layout with bytes 20..24 reserved: no pole-pair
//! count), version 3 (224 bytes: without the motor block, the CRC over bytes 0..216 at
//! offset 216), version 2 (128 bytes, room for 8 paths) and
//! version 1 (120 bytes, no alignment, a configuration hash without the pole-pair
//! count) are refused as [`crate::RecordError::UnsupportedVersion`], and the drive
//! commissions again.
//!
//! | offset | size | field |
//! |---:|---:|---|
//! | 0 | 4 | magic [`MAGIC`] ("MRAS" read as a big-endian u32) |
//! | 4 | 2 | format version [`FORMAT_VERSION`] |
//! | 6 | 1 | path count (≤ `MAX_PATHS` = 16) |
//! | 7 | 1 | direction flags: bit 0 = alignment `reversed`; bits 1-7 are 0 (else refused) |
//! | 8 | 4 | sequence number (serial-number arithmetic, wraps) |
//! | 12 | 4 | configuration hash ([`crate::config_hash`]) |
//! | 16 | 4 | alignment `offset_e_rad` (f32 bits, finite, within [-π, π]) |
//! | 20 | 2 | alignment `pole_pairs` (u16, ≥ 1) |
//! | 22 | 2 | reserved, written 0 |
//! | 24 + 12·i | 12 | path i: kind tag (u8), h (i8), 2 reserved (0), re (f32 bits), im (f32 bits) |
//! | 216 | 4 | motor `r_ohm` (f32 bits, finite, > 0) |
//! | 220 | 4 | motor `ld_h` (f32 bits, finite, > 0) |
//! | 224 | 4 | motor `lq_h` (f32 bits, finite, > 0) |
//! | 228 | 4 | motor `v_inverter_v` (f32 bits, finite, ≥ 0) |
//! | 232 | 4 | motor `flux_wb` (f32 bits, finite, > 0) |
//! | 236 | 4 | motor `inertia_kg_m2` (f32 bits, finite, > 0) |
//! | 240 | 4 | motor `viscous_nm_s_rad` (f32 bits, finite, any sign) |
//! | 244 | 4 | motor `coulomb_nm` (f32 bits, finite, any sign) |
//! | 248 | 4 | CRC-32/ISO-HDLC over bytes 0..248 |
//! | 252 | 4 | commit mark [`COMMIT_MARK`] |
//!
//! The motor block ([`MOTOR_OFFSET`], [`MOTOR_BYTES`]) holds the [`MOTOR_FIELDS`]
//! [`crate::MotorConstants`] in their declaration order, and nothing else (no reserved
//! bytes).
//!
//! All sixteen path entries are always present (unused ones are zero), so the motor
//! block and the CRC sit at fixed offsets that do not depend on the (untrusted) path
//! count. The last double word (CRC + commit mark) is programmed last; since the mark
//! is not 0xFFFF_FFFF, a write interrupted before it can never look complete, whatever
//! the CRC value.
//! Reserved bytes are covered by the CRC but not otherwise checked: a layout change
//! bumps [`FORMAT_VERSION`] rather than giving them a meaning.

use mras::MAX_PATHS;

/// Flash page in dual-bank mode (DBANK = 1, the default): the erase unit.
pub const PAGE_BYTES: usize = 2048;
/// Programming unit: a 64-bit double word, programmable once after an erase (the
/// flash stores its ECC with it).
pub const DOUBLE_WORD_BYTES: usize = 8;
/// Every byte of an erased page.
pub const ERASED_BYTE: u8 = 0xFF;
/// Double words per page.
pub const DOUBLE_WORDS_PER_PAGE: usize = PAGE_BYTES / DOUBLE_WORD_BYTES;

/// "MRAS" as a big-endian u32; stored little-endian.
pub const MAGIC: u32 = 0x4D52_4153;
/// Bumped whenever the layout or the meaning of a field (or of the config hash) changes.
pub const FORMAT_VERSION: u16 = 5;
/// Second half of the last double word: any value other than all-ones proves that the
/// last double word was programmed.
pub const COMMIT_MARK: u32 = !MAGIC;

/// Magic, version, count, direction flags, sequence, hash, alignment offset and pole
/// pairs, reserved.
pub const HEADER_BYTES: usize = 24;
/// Tag, h, 2 reserved, re, im.
pub const PATH_ENTRY_BYTES: usize = 12;
/// Start of the motor block, right after the sixteen path entries.
pub const MOTOR_OFFSET: usize = HEADER_BYTES + MAX_PATHS * PATH_ENTRY_BYTES;
/// The [`crate::MotorConstants`] fields in the record (one f32 each).
pub const MOTOR_FIELDS: usize = 8;
/// Motor block: the [`MOTOR_FIELDS`] constants (f32 bits), nothing reserved.
pub const MOTOR_BYTES: usize = MOTOR_FIELDS * 4;
/// Offset of the CRC, i.e. length of the CRC-protected part.
pub const CRC_OFFSET: usize = MOTOR_OFFSET + MOTOR_BYTES;
/// The last double word (CRC + commit mark) starts here; it is programmed last.
pub const COMMIT_OFFSET: usize = CRC_OFFSET;
/// Size of an encoded record: a whole number of double words.
pub const RECORD_BYTES: usize = COMMIT_OFFSET + DOUBLE_WORD_BYTES;

/// Bit 0 of the direction flags byte: [`crate::Alignment::reversed`].
pub(crate) const FLAG_REVERSED: u8 = 0x01;

/// [`crate::PathKind`] tags in the record (and in the configuration hash).
pub(crate) const TAG_OFFSET: u8 = 0;
pub(crate) const TAG_AMPLITUDE_QUADRATURE: u8 = 1;
pub(crate) const TAG_HARMONIC: u8 = 2;

const _: () = {
    assert!(HEADER_BYTES % DOUBLE_WORD_BYTES == 0);
    assert!(MOTOR_OFFSET % DOUBLE_WORD_BYTES == 0);
    assert!(MOTOR_BYTES % DOUBLE_WORD_BYTES == 0);
    assert!(CRC_OFFSET == MOTOR_OFFSET + MOTOR_BYTES);
    assert!(COMMIT_OFFSET % DOUBLE_WORD_BYTES == 0);
    assert!(RECORD_BYTES % DOUBLE_WORD_BYTES == 0);
    assert!(RECORD_BYTES <= PAGE_BYTES);
    assert!(RECORD_BYTES < 1024);
    assert!(COMMIT_MARK != u32::MAX);
    assert!(MAX_PATHS <= u8::MAX as usize);
    // The table above.
    assert!(MAX_PATHS == 16);
    assert!(MOTOR_FIELDS == 8 && MOTOR_OFFSET == 216 && MOTOR_BYTES == 32);
    assert!(CRC_OFFSET == 248 && COMMIT_OFFSET == 248);
    assert!(RECORD_BYTES == 256);
};

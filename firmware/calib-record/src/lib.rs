//! Power-loss-safe flash record of the drive's sensor calibration, so that a drive
//! can skip self-commissioning at the next power-up.
//!
//! A [`Calibration`] (the [`mras::Coefficients`] snapshot, the electrical
//! [`Alignment`] and the motor's identified [`MotorConstants`]) is stored as a
//! checksummed record (magic, format version, configuration hash, sequence number,
//! CRC) in one of two alternating slots, one flash page each. [`store`] always writes
//! the slot that does not hold the record [`load`] would return and programs the commit
//! double word last, so a power loss at any point leaves either the previous
//! calibration or the new one. Layout and flash rules: [`layout`]. Records of another
//! format version are refused ([`RecordError::UnsupportedVersion`]); every error has a
//! stable `name()` for logs.
//!
//! `no_std`, no allocation, no panics on any flash content.
//!
//! ```
//! use calib_record::{
//!     config_hash, load, store, Alignment, Calibration, InputScaling, MotorConstants, RamFlash,
//! };
//! use mras::{Coefficients, Config, Cplx, PathKind};
//!
//! let cfg = Config::default();
//! let pole_pairs = 4;
//! let hash = config_hash(&cfg, pole_pairs, &InputScaling::IDENTITY);
//! let mut coefficients = Coefficients::zeros(cfg.paths());
//! coefficients.set(PathKind::Offset, Cplx::new(0.1, -0.08));
//! let calibration = Calibration {
//!     coefficients,
//!     alignment: Alignment { offset_e_rad: -1.2, reversed: true, pole_pairs: 4 },
//!     motor: MotorConstants {
//!         r_ohm: 0.3,
//!         ld_h: 5.0e-4,
//!         lq_h: 6.0e-4,
//!         v_inverter_v: 0.5,
//!         flux_wb: 0.02,
//!         inertia_kg_m2: 2.0e-4,
//!         viscous_nm_s_rad: 1.0e-5,
//!         coulomb_nm: 3.0e-3,
//!     },
//! };
//!
//! let mut flash = RamFlash::new(); // the firmware implements `FlashSlots` on the chip
//! match load(&flash, hash) {
//!     Ok(_) => unreachable!("blank flash"),
//!     Err(e) => assert_eq!(e.name(), "Erased"), // self-commission, then store
//! }
//! store(&mut flash, &calibration, hash).unwrap();
//! let loaded = load(&flash, hash).unwrap();
//! assert_eq!(loaded.record.calibration, calibration);
//! ```
#![no_std]
#![deny(unsafe_code)]

pub mod layout;
mod ram_flash;
mod record;
mod slots;

pub use layout::{DOUBLE_WORD_BYTES, PAGE_BYTES, RECORD_BYTES};
pub use ram_flash::{RamFlash, RamFlashError};
pub use record::{
    config_hash, decode, encode, Alignment, Calibration, InputScaling, MotorConstants, Record,
    RecordError,
};
pub use slots::{
    is_newer, load, store, FlashSlots, LoadError, Loaded, OtherSlot, Rejected, Slot, StoreError,
    FIRST_SEQUENCE,
};

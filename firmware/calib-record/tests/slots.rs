//! Two-slot load/store, including a power loss at every step of a store.

mod common;

use core::f32::consts::PI;

use calib_record::layout::{DOUBLE_WORD_BYTES, FORMAT_VERSION};
use calib_record::{
    is_newer, load, store, Calibration, FlashSlots, LoadError, Loaded, OtherSlot, RamFlash,
    RamFlashError, RecordError, Rejected, Slot, StoreError, FIRST_SEQUENCE, PAGE_BYTES,
    RECORD_BYTES,
};
use common::{
    calib, encoded, same_bits, v1_record, v2_record, v3_record, v4_record, with_identity, HASH,
    OTHER_HASH,
};
use mras::{Coefficients, Cplx, PathKind};

type Load = Result<Loaded<RamFlashError>, LoadError<RamFlashError>>;

fn plant(flash: &mut RamFlash, slot: Slot, c: &Calibration, seq: u32, hash: u32) {
    flash.erase(slot).unwrap();
    flash.program(slot, 0, &encoded(c, seq, hash)).unwrap();
}

fn loaded(flash: &RamFlash) -> Loaded<RamFlashError> {
    load(flash, HASH).expect("a valid record")
}

fn rec(e: RecordError) -> Rejected<RamFlashError> {
    Rejected::Record(e)
}

#[test]
fn blank_flash_has_no_record() {
    let flash = RamFlash::new();
    assert_eq!(
        load(&flash, HASH),
        Err(LoadError::NoValidRecord {
            a: rec(RecordError::Erased),
            b: rec(RecordError::Erased)
        })
    );
}

#[test]
fn first_store_goes_to_slot_a() {
    let mut flash = RamFlash::new();
    assert_eq!(store(&mut flash, &calib(1.0), HASH), Ok(Slot::A));
    let l = loaded(&flash);
    assert_eq!(l.slot, Slot::A);
    assert_eq!(l.record.sequence, FIRST_SEQUENCE);
    assert_eq!(l.record.calibration, calib(1.0));
    assert_eq!(l.other, OtherSlot::Rejected(rec(RecordError::Erased)));
    // One erase and RECORD_BYTES / 8 double words.
    assert_eq!(
        flash.operations() as usize,
        1 + RECORD_BYTES / DOUBLE_WORD_BYTES
    );
}

#[test]
fn stores_alternate_and_load_picks_the_newest() {
    let mut flash = RamFlash::new();
    let mut expect_slot = Slot::A;
    for n in 0..8u32 {
        let before = flash.clone();
        let slot = store(&mut flash, &calib(n as f32), HASH).unwrap();
        assert_eq!(slot, expect_slot);
        // The slot with the previous record was neither erased nor changed.
        let kept = slot.other();
        assert_eq!(flash.erase_count(kept), before.erase_count(kept));
        assert_eq!(flash.page(kept), before.page(kept));
        let l = loaded(&flash);
        assert_eq!(l.slot, slot);
        assert_eq!(l.record.sequence, FIRST_SEQUENCE + n);
        assert_eq!(l.record.calibration, calib(n as f32));
        if n > 0 {
            assert_eq!(
                l.other,
                OtherSlot::Superseded {
                    sequence: FIRST_SEQUENCE + n - 1
                }
            );
        }
        expect_slot = expect_slot.other();
    }
}

#[test]
fn newest_wins_in_either_slot() {
    for (seq_a, seq_b, newer) in [(5, 6, Slot::B), (6, 5, Slot::A), (u32::MAX, 0, Slot::B)] {
        let mut flash = RamFlash::new();
        plant(&mut flash, Slot::A, &calib(1.0), seq_a, HASH);
        plant(&mut flash, Slot::B, &calib(2.0), seq_b, HASH);
        let l = loaded(&flash);
        assert_eq!(l.slot, newer, "{seq_a} vs {seq_b}");
        // The next store overwrites the older slot.
        assert_eq!(store(&mut flash, &calib(3.0), HASH), Ok(newer.other()));
    }
}

#[test]
fn serial_number_arithmetic() {
    assert!(is_newer(1, 0));
    assert!(!is_newer(0, 1));
    assert!(!is_newer(7, 7));
    assert!(is_newer(0, u32::MAX));
    assert!(is_newer(3, u32::MAX - 3));
    assert!(!is_newer(u32::MAX, 0));
    assert!(is_newer(0x7FFF_FFFF, 0));
    // Exactly half the circle apart: neither is newer (load then prefers slot A).
    assert!(!is_newer(0x8000_0000, 0) && !is_newer(0, 0x8000_0000));
}

#[test]
fn sequence_wraps() {
    let mut flash = RamFlash::new();
    plant(&mut flash, Slot::A, &calib(1.0), u32::MAX - 1, HASH);
    plant(&mut flash, Slot::B, &calib(2.0), u32::MAX, HASH);
    assert_eq!(store(&mut flash, &calib(3.0), HASH), Ok(Slot::A));
    let l = loaded(&flash);
    assert_eq!((l.slot, l.record.sequence), (Slot::A, 0));
    assert_eq!(l.other, OtherSlot::Superseded { sequence: u32::MAX });
    assert_eq!(store(&mut flash, &calib(4.0), HASH), Ok(Slot::B));
    let l = loaded(&flash);
    assert_eq!((l.slot, l.record.sequence), (Slot::B, 1));
    assert_eq!(l.record.calibration, calib(4.0));
}

#[test]
fn corrupted_newest_falls_back_to_previous() {
    let mut flash = RamFlash::new();
    store(&mut flash, &calib(1.0), HASH).unwrap();
    store(&mut flash, &calib(2.0), HASH).unwrap(); // slot B, newest
    flash.page_mut(Slot::B)[40] ^= 0x10;
    let l = loaded(&flash);
    assert_eq!(l.slot, Slot::A);
    assert_eq!(l.record.calibration, calib(1.0));
    assert_eq!(l.other, OtherSlot::Rejected(rec(RecordError::BadCrc)));
    // The next store repairs the corrupted slot and keeps the good one.
    let a = *flash.page(Slot::A);
    assert_eq!(store(&mut flash, &calib(3.0), HASH), Ok(Slot::B));
    assert_eq!(flash.page(Slot::A), &a);
    let l = loaded(&flash);
    assert_eq!((l.slot, l.record.sequence), (Slot::B, FIRST_SEQUENCE + 1));
}

#[test]
fn configuration_change() {
    let mut flash = RamFlash::new();
    plant(&mut flash, Slot::A, &calib(1.0), 10, OTHER_HASH);
    assert_eq!(
        load(&flash, HASH),
        Err(LoadError::NoValidRecord {
            a: rec(RecordError::ConfigMismatch {
                stored: OTHER_HASH,
                expected: HASH
            }),
            b: rec(RecordError::Erased)
        })
    );
    // The new configuration's record goes next to the old one, with a newer sequence.
    assert_eq!(store(&mut flash, &calib(2.0), HASH), Ok(Slot::B));
    let l = loaded(&flash);
    assert_eq!((l.slot, l.record.sequence), (Slot::B, 11));
    assert!(matches!(
        l.other,
        OtherSlot::Rejected(Rejected::Record(RecordError::ConfigMismatch { .. }))
    ));
    // Switching back finds the old configuration's calibration.
    assert_eq!(load(&flash, OTHER_HASH).unwrap().slot, Slot::A);
    // A further store for HASH protects HASH's record and replaces the other one.
    assert_eq!(store(&mut flash, &calib(3.0), HASH), Ok(Slot::A));
    assert_eq!(loaded(&flash).record.sequence, 12);
}

/// A record valid for `HASH` is protected even when the other slot holds a newer
/// record of another configuration.
#[test]
fn matching_record_is_protected_over_a_newer_foreign_one() {
    let mut flash = RamFlash::new();
    plant(&mut flash, Slot::A, &calib(1.0), 5, HASH);
    plant(&mut flash, Slot::B, &calib(2.0), 9, OTHER_HASH);
    let a = *flash.page(Slot::A);
    assert_eq!(store(&mut flash, &calib(3.0), HASH), Ok(Slot::B));
    assert_eq!(flash.page(Slot::A), &a);
    assert_eq!(loaded(&flash).record.sequence, 10);
}

#[test]
fn invalid_calibration_is_refused_before_touching_flash() {
    let mut flash = RamFlash::new();
    store(&mut flash, &calib(1.0), HASH).unwrap();
    let before = flash.clone();

    let mut nan = calib(2.0);
    nan.coefficients
        .set(PathKind::Harmonic(4), Cplx::new(f32::NAN, 0.0));
    assert_eq!(
        store(&mut flash, &nan, HASH),
        Err(StoreError::InvalidCalibration(RecordError::NonFiniteValue))
    );
    let dup = with_identity(Coefficients::zeros(&[
        PathKind::Harmonic(4),
        PathKind::Harmonic(-2),
    ]));
    assert_eq!(
        store(&mut flash, &dup, HASH),
        Err(StoreError::InvalidCalibration(RecordError::BadPathList))
    );
    for offset in [
        f32::NAN,
        f32::INFINITY,
        -4.0,
        f32::from_bits(PI.to_bits() + 1),
    ] {
        let mut bad = calib(2.0);
        bad.alignment.offset_e_rad = offset;
        let err = store(&mut flash, &bad, HASH).unwrap_err();
        assert_eq!(
            err,
            StoreError::InvalidCalibration(RecordError::BadAlignment),
            "{offset}"
        );
        assert_eq!(err.name(), "InvalidCalibration");
    }
    // Motor constants that are not finite, not > 0 (resistance, inductances, flux,
    // inertia) or < 0 (inverter error); the friction terms may have any sign, but must
    // be finite.
    let bad_motors: [fn(&mut Calibration); 11] = [
        |c| c.motor.r_ohm = 0.0,
        |c| c.motor.ld_h = f32::NAN,
        |c| c.motor.lq_h = -6e-4,
        |c| c.motor.v_inverter_v = -0.1,
        |c| c.motor.flux_wb = f32::INFINITY,
        |c| c.motor.inertia_kg_m2 = -0.0,
        |c| c.motor.viscous_nm_s_rad = f32::NEG_INFINITY,
        |c| c.motor.viscous_nm_s_rad = f32::NAN,
        |c| c.motor.coulomb_nm = f32::INFINITY,
        |c| c.motor.coulomb_nm = -f32::NAN,
        |c| c.motor.v_inverter_v = f32::NAN,
    ];
    for (n, spoil) in bad_motors.iter().enumerate() {
        let mut bad = calib(2.0);
        spoil(&mut bad);
        let err = store(&mut flash, &bad, HASH).unwrap_err();
        assert_eq!(
            err,
            StoreError::InvalidCalibration(RecordError::BadMotor),
            "case {n}: {:?}",
            bad.motor
        );
    }
    assert_eq!(flash.operations(), before.operations());
    assert_eq!(flash.page(Slot::A), before.page(Slot::A));
    assert_eq!(flash.page(Slot::B), before.page(Slot::B));
}

/// Negative viscous or constant friction (a fit that separates them only weakly) is a
/// valid calibration: stored, and loaded back bit for bit.
#[test]
fn negative_friction_is_stored_and_loaded() {
    let mut flash = RamFlash::new();
    let cases: [fn(&mut Calibration); 3] = [
        |c| c.motor.viscous_nm_s_rad = -1e-6,
        |c| c.motor.coulomb_nm = -2e-3,
        |c| {
            c.motor.viscous_nm_s_rad = -0.0;
            c.motor.coulomb_nm = -f32::MIN_POSITIVE;
        },
    ];
    for (n, set) in cases.iter().enumerate() {
        let mut c = calib(1.0);
        set(&mut c);
        store(&mut flash, &c, HASH).unwrap_or_else(|e| panic!("case {n}: {e:?}"));
        let l = loaded(&flash);
        assert_eq!(l.record.calibration, c, "case {n}");
        assert!(same_bits(&l.record.calibration, &c), "case {n}");
    }
}

#[test]
fn store_error_names() {
    assert_eq!(
        StoreError::<RamFlashError>::InvalidCalibration(RecordError::BadCrc).name(),
        "InvalidCalibration"
    );
    assert_eq!(StoreError::Flash(RamFlashError::PowerLost).name(), "Flash");
    assert_eq!(
        StoreError::<RamFlashError>::VerifyFailed.name(),
        "VerifyFailed"
    );
}

/// A drive updated from version-1, version-2 (8-path), version-3 (no motor block) or
/// version-4 (no pole pairs) firmware: records of the old formats, however intact, are refused by name, and the
/// first store (after commissioning, the motor identified) replaces one of them.
#[test]
fn older_format_records_are_refused_by_name() {
    for version in [1, 2, 3, 4] {
        older_format_records_are_refused(version);
    }
}

fn older_format_records_are_refused(version: u16) {
    let old_refused = rec(RecordError::UnsupportedVersion {
        found: version,
        expected: FORMAT_VERSION,
    });
    let plant_old = |flash: &mut RamFlash, slot: Slot, tag: f32, seq: u32| {
        flash.erase(slot).unwrap();
        let bytes = match version {
            1 => v1_record(&calib(tag).coefficients, seq, HASH).to_vec(),
            2 => v2_record(&calib(tag), seq, HASH).to_vec(),
            3 => v3_record(&calib(tag), seq, HASH).to_vec(),
            _ => v4_record(&calib(tag), seq, HASH).to_vec(),
        };
        flash.program(slot, 0, &bytes).unwrap();
    };

    // Both slots hold old records (two stores of the old firmware).
    let mut flash = RamFlash::new();
    plant_old(&mut flash, Slot::A, 1.0, 1);
    plant_old(&mut flash, Slot::B, 2.0, 2);
    let err = load(&flash, HASH).unwrap_err();
    assert_eq!(
        err,
        LoadError::NoValidRecord {
            a: old_refused,
            b: old_refused
        }
    );
    assert_eq!(err.name(), "UnsupportedVersion");
    assert_eq!(err.reason(), &old_refused);
    // Whatever the hash: the version is checked first.
    assert_eq!(
        load(&flash, OTHER_HASH).unwrap_err().name(),
        "UnsupportedVersion"
    );

    // One old record and an erased slot, either way round.
    for old_slot in Slot::BOTH {
        let mut flash = RamFlash::new();
        plant_old(&mut flash, old_slot, 1.0, 1);
        let err = load(&flash, HASH).unwrap_err();
        assert_eq!(
            err.name(),
            "UnsupportedVersion",
            "v{version} in {old_slot:?}"
        );
        assert_eq!(err.reason(), &old_refused);
    }

    // Commissioning stores a v4 record; it loads, the remaining old record is reported.
    let c = calib(3.0);
    assert_eq!(store(&mut flash, &c, HASH), Ok(Slot::A));
    let l = loaded(&flash);
    assert_eq!(l.slot, Slot::A);
    assert_eq!(l.record.sequence, FIRST_SEQUENCE);
    assert!(same_bits(&l.record.calibration, &c));
    assert_eq!(l.other, OtherSlot::Rejected(old_refused));
}

/// `LoadError::reason`: "Erased" only if both slots are erased, otherwise the
/// rejection that says more about the content (a record of another configuration or
/// version over a damaged or interrupted write); slot A on a tie.
#[test]
fn load_error_reports_the_most_informative_rejection() {
    let erased = rec(RecordError::Erased);
    let v1 = rec(RecordError::UnsupportedVersion {
        found: 1,
        expected: FORMAT_VERSION,
    });
    let mismatch = rec(RecordError::ConfigMismatch {
        stored: OTHER_HASH,
        expected: HASH,
    });
    let flash_err = Rejected::Flash(RamFlashError::OutOfBounds);
    let cases = [
        (erased, erased, "Erased"),
        (erased, rec(RecordError::BadCrc), "BadCrc"),
        (rec(RecordError::BadMagic), erased, "BadMagic"),
        (flash_err, erased, "Flash"),
        (erased, flash_err, "Flash"),
        (flash_err, rec(RecordError::Incomplete), "Incomplete"),
        (rec(RecordError::Incomplete), v1, "UnsupportedVersion"),
        (v1, rec(RecordError::BadMagic), "UnsupportedVersion"),
        (
            rec(RecordError::BadCrc),
            rec(RecordError::Incomplete),
            "BadCrc",
        ),
        (rec(RecordError::BadCrc), v1, "UnsupportedVersion"),
        (v1, rec(RecordError::BadAlignment), "BadAlignment"),
        (rec(RecordError::BadCrc), mismatch, "ConfigMismatch"),
        (mismatch, rec(RecordError::BadAlignment), "ConfigMismatch"),
        (v1, rec(RecordError::BadMotor), "BadMotor"),
        (
            rec(RecordError::BadAlignment),
            rec(RecordError::BadMotor),
            "BadMotor",
        ),
        (mismatch, rec(RecordError::BadMotor), "ConfigMismatch"),
        (
            rec(RecordError::BadPathList),
            rec(RecordError::BadAlignment),
            "BadAlignment",
        ),
    ];
    for (a, b, name) in cases {
        let e = LoadError::NoValidRecord { a, b };
        assert_eq!(e.name(), name, "{a:?} / {b:?}");
        assert_eq!(e.reason().name(), name);
        // Symmetric: the same reason whichever slot holds it.
        let swapped = LoadError::NoValidRecord { a: b, b: a };
        assert_eq!(swapped.name(), name, "{b:?} / {a:?}");
    }
    // A tie: slot A's rejection, payload included.
    let other_v = rec(RecordError::UnsupportedVersion {
        found: 7,
        expected: FORMAT_VERSION,
    });
    let tie = LoadError::NoValidRecord { a: other_v, b: v1 };
    assert_eq!(tie.reason(), &other_v);

    // On the flash: slot A interrupted by a power cut, slot B a version-1 record.
    let mut flash = RamFlash::new();
    flash.erase(Slot::B).unwrap();
    flash
        .program(Slot::B, 0, &v1_record(&calib(1.0).coefficients, 1, HASH))
        .unwrap();
    flash.cut_power_after(3, false);
    assert!(store(&mut flash, &calib(2.0), HASH).is_err());
    flash.power_on();
    let err = load(&flash, HASH).unwrap_err();
    assert_eq!(
        err,
        LoadError::NoValidRecord {
            a: rec(RecordError::Incomplete),
            b: v1
        }
    );
    assert_eq!(err.name(), "UnsupportedVersion");
}

/// Flash whose programming flips a bit, or whose slot A cannot be read.
struct Faulty {
    inner: RamFlash,
    flip_on_program: bool,
    fail_read_a: bool,
}

impl FlashSlots for Faulty {
    type Error = RamFlashError;
    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), RamFlashError> {
        if self.fail_read_a && slot == Slot::A {
            return Err(RamFlashError::OutOfBounds);
        }
        self.inner.read(slot, buf)
    }
    fn erase(&mut self, slot: Slot) -> Result<(), RamFlashError> {
        self.inner.erase(slot)
    }
    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), RamFlashError> {
        let mut d = [0u8; RECORD_BYTES];
        let d = &mut d[..data.len()];
        d.copy_from_slice(data);
        if self.flip_on_program && offset == 0 {
            d[20] ^= 0x01;
        }
        self.inner.program(slot, offset, d)
    }
}

#[test]
fn read_back_mismatch_is_reported_and_old_record_kept() {
    let mut flash = Faulty {
        inner: RamFlash::new(),
        flip_on_program: false,
        fail_read_a: false,
    };
    store(&mut flash, &calib(1.0), HASH).unwrap();
    flash.flip_on_program = true;
    assert_eq!(
        store(&mut flash, &calib(2.0), HASH),
        Err(StoreError::VerifyFailed)
    );
    let l = load(&flash, HASH).unwrap();
    assert_eq!((l.slot, l.record.calibration), (Slot::A, calib(1.0)));
}

#[test]
fn unreadable_slot_is_reported_and_the_other_used() {
    let mut flash = Faulty {
        inner: RamFlash::new(),
        flip_on_program: false,
        fail_read_a: false,
    };
    store(&mut flash, &calib(1.0), HASH).unwrap(); // A
    store(&mut flash, &calib(2.0), HASH).unwrap(); // B
    store(&mut flash, &calib(3.0), HASH).unwrap(); // A, newest
    flash.fail_read_a = true;
    let l = load(&flash, HASH).unwrap();
    assert_eq!((l.slot, l.record.calibration), (Slot::B, calib(2.0)));
    assert_eq!(
        l.other,
        OtherSlot::Rejected(Rejected::Flash(RamFlashError::OutOfBounds))
    );
}

/// Flash that logs every erase and program.
struct Recorder {
    inner: RamFlash,
    log: Vec<(&'static str, Slot, usize, usize)>,
}

impl FlashSlots for Recorder {
    type Error = RamFlashError;
    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), RamFlashError> {
        self.inner.read(slot, buf)
    }
    fn erase(&mut self, slot: Slot) -> Result<(), RamFlashError> {
        self.log.push(("erase", slot, 0, PAGE_BYTES));
        self.inner.erase(slot)
    }
    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), RamFlashError> {
        self.log.push(("program", slot, offset, data.len()));
        self.inner.program(slot, offset, data)
    }
}

/// Erase the other slot, program the body, then the commit double word, last; never
/// touch the slot holding the newest record.
#[test]
fn store_order_commit_double_word_last() {
    let mut flash = Recorder {
        inner: RamFlash::new(),
        log: Vec::new(),
    };
    let commit = RECORD_BYTES - DOUBLE_WORD_BYTES;
    for (n, slot) in [Slot::A, Slot::B, Slot::A].into_iter().enumerate() {
        flash.log.clear();
        assert_eq!(store(&mut flash, &calib(n as f32), HASH), Ok(slot));
        assert_eq!(
            flash.log,
            [
                ("erase", slot, 0, PAGE_BYTES),
                ("program", slot, 0, commit),
                ("program", slot, commit, DOUBLE_WORD_BYTES),
            ]
        );
    }
}

// ---- power loss ----

struct Scenario {
    name: &'static str,
    flash: RamFlash,
    /// What load returns before the store (the record that must survive).
    old: Option<(Slot, Calibration)>,
}

fn scenarios() -> Vec<Scenario> {
    let mut v = Vec::new();
    v.push(Scenario {
        name: "blank",
        flash: RamFlash::new(),
        old: None,
    });

    let mut f = RamFlash::new();
    store(&mut f, &calib(1.0), HASH).unwrap();
    v.push(Scenario {
        name: "one record",
        flash: f.clone(),
        old: Some((Slot::A, calib(1.0))),
    });

    store(&mut f, &calib(2.0), HASH).unwrap();
    v.push(Scenario {
        name: "two records, B newest",
        flash: f.clone(),
        old: Some((Slot::B, calib(2.0))),
    });

    store(&mut f, &calib(3.0), HASH).unwrap();
    v.push(Scenario {
        name: "two records, A newest",
        flash: f.clone(),
        old: Some((Slot::A, calib(3.0))),
    });

    // An earlier store into B was interrupted half-way, torn.
    let mut g = f.clone();
    g.cut_power_after(6, true);
    assert!(store(&mut g, &calib(9.0), HASH).is_err());
    g.power_on();
    v.push(Scenario {
        name: "A newest, B half-written",
        flash: g,
        old: Some((Slot::A, calib(3.0))),
    });

    let mut g = RamFlash::new();
    plant(&mut g, Slot::A, &calib(4.0), u32::MAX, HASH);
    plant(&mut g, Slot::B, &calib(5.0), u32::MAX - 1, HASH);
    v.push(Scenario {
        name: "A newest at the wrap",
        flash: g,
        old: Some((Slot::A, calib(4.0))),
    });

    let mut g = RamFlash::new();
    plant(&mut g, Slot::A, &calib(6.0), 3, HASH);
    plant(&mut g, Slot::B, &calib(7.0), 8, OTHER_HASH);
    v.push(Scenario {
        name: "A valid, B newer foreign configuration",
        flash: g,
        old: Some((Slot::A, calib(6.0))),
    });

    let mut g = f.clone();
    g.page_mut(Slot::A)[17] ^= 4;
    v.push(Scenario {
        name: "A corrupted, B valid",
        flash: g,
        old: Some((Slot::B, calib(2.0))),
    });

    // Firmware updated from format version 1: nothing loadable to protect.
    let mut g = RamFlash::new();
    for (slot, seq) in [(Slot::A, 7), (Slot::B, 8)] {
        g.erase(slot).unwrap();
        g.program(
            slot,
            0,
            &v1_record(&calib(seq as f32).coefficients, seq, HASH),
        )
        .unwrap();
    }
    v.push(Scenario {
        name: "version-1 records in both slots",
        flash: g,
        old: None,
    });

    // Firmware updated from format version 3 (no motor block): nothing loadable either.
    let mut g = RamFlash::new();
    for (slot, seq) in [(Slot::A, 7), (Slot::B, 8)] {
        g.erase(slot).unwrap();
        g.program(slot, 0, &v3_record(&calib(seq as f32), seq, HASH))
            .unwrap();
    }
    v.push(Scenario {
        name: "version-3 records in both slots",
        flash: g,
        old: None,
    });
    v
}

fn check_after_power_loss(s: &Scenario, flash: &RamFlash, new: &Calibration, what: &str) {
    let got: Load = load(flash, HASH);
    match (&s.old, got) {
        (Some((slot, old)), Ok(l)) => {
            let is_old = l.slot == *slot && same_bits(&l.record.calibration, old);
            let is_new = l.slot != *slot && same_bits(&l.record.calibration, new);
            assert!(is_old || is_new, "{what}: loaded {l:?}");
            // The slot with the old record was not touched at all.
            assert_eq!(flash.page(*slot), s.flash.page(*slot), "{what}");
            assert_eq!(
                flash.erase_count(*slot),
                s.flash.erase_count(*slot),
                "{what}"
            );
        }
        (Some(_), Err(e)) => panic!("{what}: old calibration lost: {e:?}"),
        (None, Ok(l)) => assert!(same_bits(&l.record.calibration, new), "{what}: {l:?}"),
        (None, Err(_)) => {}
    }
}

#[test]
fn power_loss_at_every_step_of_a_store_keeps_old_or_new() {
    let new = calib(0.5);
    let newer = calib(0.25);
    for s in scenarios() {
        // Operations of an uninterrupted store.
        let mut probe = s.flash.clone();
        let start = probe.operations();
        store(&mut probe, &new, HASH).unwrap();
        let total = probe.operations() - start;
        assert_eq!(total as usize, 1 + RECORD_BYTES / DOUBLE_WORD_BYTES);

        for k in 0..=total {
            for torn in [false, true] {
                let what = format!("{}: cut after {k} of {total} ops, torn {torn}", s.name);
                let mut f = s.flash.clone();
                f.cut_power_after(k, torn);
                let r = store(&mut f, &new, HASH);
                if k < total {
                    assert_eq!(
                        r,
                        Err(StoreError::Flash(RamFlashError::PowerLost)),
                        "{what}"
                    );
                    assert!(!f.is_powered());
                } else {
                    assert!(r.is_ok(), "{what}: {r:?}");
                }
                f.power_on();
                check_after_power_loss(&s, &f, &new, &what);
                if k == total {
                    assert!(same_bits(&loaded(&f).record.calibration, &new), "{what}");
                }
                // After the reboot the next store completes and wins.
                let slot = store(&mut f, &newer, HASH).unwrap();
                let l = loaded(&f);
                assert_eq!(l.slot, slot, "{what}");
                assert!(same_bits(&l.record.calibration, &newer), "{what}");
            }
        }
    }
}

/// A pseudo-random walk of stores, most of them interrupted, against a model of the
/// last calibration that must survive.
#[test]
fn random_walk_of_interrupted_stores() {
    let mut rng: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = move |n: u32| {
        rng = rng.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        ((rng >> 33) as u32) % n
    };
    let ops = 1 + (RECORD_BYTES / DOUBLE_WORD_BYTES) as u32;
    let mut flash = RamFlash::new();
    let mut good: Option<Calibration> = None;
    for step in 0..3000 {
        let c = calib(step as f32);
        let cut = next(ops + 4);
        if cut < ops {
            flash.cut_power_after(cut, next(2) == 1);
        }
        let r = store(&mut flash, &c, HASH);
        flash.power_on();
        assert_eq!(r.is_ok(), cut >= ops, "step {step}");
        match (load(&flash, HASH), good) {
            (Ok(l), Some(g)) => {
                let c_new = same_bits(&l.record.calibration, &c);
                assert!(c_new || same_bits(&l.record.calibration, &g), "step {step}");
                assert!(r.is_err() || c_new, "step {step}");
                good = Some(l.record.calibration);
            }
            (Ok(l), None) => {
                assert!(same_bits(&l.record.calibration, &c), "step {step}");
                good = Some(l.record.calibration);
            }
            (Err(e), Some(_)) => panic!("step {step}: lost the calibration: {e:?}"),
            (Err(_), None) => assert!(r.is_err()),
        }
    }
    assert!(good.is_some());
}

// ---- RamFlash enforces the chip's rules ----

#[test]
fn ram_flash_rules() {
    let mut f = RamFlash::new();
    let dw = [0x12u8; 8];
    assert_eq!(f.program(Slot::A, 4, &dw), Err(RamFlashError::Misaligned));
    assert_eq!(
        f.program(Slot::A, 0, &dw[..5]),
        Err(RamFlashError::Misaligned)
    );
    assert_eq!(
        f.program(Slot::A, PAGE_BYTES, &dw),
        Err(RamFlashError::OutOfBounds)
    );
    assert_eq!(
        f.program(Slot::A, usize::MAX - 7, &dw),
        Err(RamFlashError::OutOfBounds)
    );
    let mut big = [0u8; PAGE_BYTES + 1];
    assert_eq!(f.read(Slot::A, &mut big), Err(RamFlashError::OutOfBounds));

    f.program(Slot::A, 8, &dw).unwrap();
    // Once per erase, even with the same or all-ones data.
    assert_eq!(f.program(Slot::A, 8, &dw), Err(RamFlashError::NotErased));
    f.program(Slot::A, 16, &[0xFF; 8]).unwrap();
    assert_eq!(
        f.program(Slot::A, 16, &[0xFF; 8]),
        Err(RamFlashError::NotErased)
    );
    // Content planted behind the rules' back is not erased either.
    f.page_mut(Slot::B)[100] = 0;
    assert_eq!(f.program(Slot::B, 96, &dw), Err(RamFlashError::NotErased));
    // Slots are independent; erase restores 0xFF.
    assert!(f.page(Slot::B)[..96].iter().all(|&b| b == 0xFF));
    f.erase(Slot::A).unwrap();
    assert!(f.page(Slot::A).iter().all(|&b| b == 0xFF));
    f.program(Slot::A, 8, &dw).unwrap();
    assert_eq!(f.page(Slot::A)[8..16], dw);
    assert_eq!(f.page(Slot::B)[100], 0);
}

#[test]
fn ram_flash_power_cut() {
    let mut f = RamFlash::new();
    f.cut_power_after(2, true);
    assert_eq!(
        f.program(Slot::A, 0, &[0u8; 32]),
        Err(RamFlashError::PowerLost)
    );
    // Two double words done, the third torn (first half), the fourth untouched.
    assert_eq!(f.page(Slot::A)[..20], [0u8; 20]);
    assert_eq!(f.page(Slot::A)[20..32], [0xFF; 12]);
    let mut buf = [0u8; 8];
    assert_eq!(f.read(Slot::A, &mut buf), Err(RamFlashError::PowerLost));
    assert_eq!(f.erase(Slot::B), Err(RamFlashError::PowerLost));
    f.power_on();
    f.read(Slot::A, &mut buf).unwrap();

    // A torn erase leaves the even double words as they were.
    f.cut_power_after(0, true);
    assert_eq!(f.erase(Slot::A), Err(RamFlashError::PowerLost));
    f.power_on();
    assert_eq!(f.page(Slot::A)[..8], [0u8; 8]);
    assert_eq!(f.page(Slot::A)[8..16], [0xFF; 8]);
    assert_eq!(f.page(Slot::A)[16..20], [0u8; 4]);
    // A clean cut changes nothing.
    f.cut_power_after(0, false);
    assert_eq!(f.erase(Slot::A), Err(RamFlashError::PowerLost));
    f.power_on();
    assert_eq!(f.page(Slot::A)[..8], [0u8; 8]);
    assert_eq!(f.erase_count(Slot::A), 0);
}

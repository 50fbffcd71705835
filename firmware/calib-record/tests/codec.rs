//! The record codec against corrupted, truncated, erased, stale and foreign records.

mod common;

use calib_record::layout::{COMMIT_OFFSET, DOUBLE_WORD_BYTES, FORMAT_VERSION, HEADER_BYTES};
use calib_record::{
    config_hash, decode, encode, load, Alignment, Calibration, FlashSlots, RamFlash, Record,
    RecordError, Slot, PAGE_BYTES, RECORD_BYTES,
};
use common::{
    cal, coefs, encoded, encoded_cal, reseal, same_bits, ALIGN, DEFAULT_PATHS, HASH, OTHER_HASH,
};
use mras::{Coefficients, Config, Cplx, PathKind, MAX_PATHS};

/// Byte offsets of header fields (see `layout`).
const VERSION_AT: usize = 4;
const COUNT_AT: usize = 6;
const FLAGS_AT: usize = 7;
const OFFSET_AT: usize = 16;
const PATH0_AT: usize = HEADER_BYTES;

const _: () = {
    assert!(RECORD_BYTES == 128);
    assert!(RECORD_BYTES % DOUBLE_WORD_BYTES == 0);
    assert!(COMMIT_OFFSET == RECORD_BYTES - DOUBLE_WORD_BYTES);
};

#[test]
fn round_trip() {
    let c = coefs(0.01);
    let buf = encoded(&c, 7, HASH);
    let rec = decode(&buf, HASH).unwrap();
    assert_eq!(
        rec,
        Record {
            calibration: cal(&c),
            sequence: 7,
            config_hash: HASH
        }
    );
    assert!(same_bits(&rec.calibration.coefficients, &c));
}

#[test]
fn round_trip_from_a_whole_page() {
    let mut page = [0xFFu8; PAGE_BYTES];
    page[..RECORD_BYTES].copy_from_slice(&encoded(&coefs(0.5), 3, HASH));
    assert_eq!(decode(&page, HASH).unwrap().sequence, 3);
}

#[test]
fn round_trip_no_paths_and_max_paths() {
    let none = Coefficients::zeros(&[]);
    assert_eq!(
        decode(&encoded(&none, 1, HASH), HASH)
            .unwrap()
            .calibration
            .coefficients,
        none
    );

    let kinds = [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(4),
        PathKind::Harmonic(-4),
        PathKind::Harmonic(7),
        PathKind::Harmonic(-15),
        PathKind::Harmonic(15),
        PathKind::Harmonic(-6),
    ];
    assert_eq!(kinds.len(), MAX_PATHS);
    let mut full = Coefficients::zeros(&kinds);
    for (n, k) in kinds.iter().enumerate() {
        full.set(
            *k,
            Cplx::new(n as f32 * 0.01, -(n as f32) * f32::MIN_POSITIVE),
        );
    }
    let back = decode(&encoded(&full, 1, HASH), HASH)
        .unwrap()
        .calibration
        .coefficients;
    assert!(same_bits(&back, &full));
}

/// The format is persisted in the field: pin it byte for byte (format 2, the fixtures'
/// alignment: offset -1.25 rad, reversed). The expected bytes, CRC included, were
/// computed independently with Python's `struct` and `zlib.crc32`.
#[test]
fn golden_bytes() {
    let mut c = Coefficients::zeros(&DEFAULT_PATHS);
    c.set(PathKind::Offset, Cplx::new(0.1, -0.08));
    c.set(PathKind::AmplitudeQuadrature, Cplx::new(0.25, -0.5));
    c.set(PathKind::Harmonic(4), Cplx::new(1.5e-3, -2.0));
    c.set(PathKind::Harmonic(5), Cplx::new(0.0, -0.0));
    #[rustfmt::skip]
    let expected: [u8; RECORD_BYTES] = [
        0x53, 0x41, 0x52, 0x4D, 0x02, 0x00, 0x04, 0x01,
        0x04, 0x03, 0x02, 0x01, 0xD4, 0xC3, 0xB2, 0xA1,
        0x00, 0x00, 0xA0, 0xBF, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0xCD, 0xCC, 0xCC, 0x3D,
        0x0A, 0xD7, 0xA3, 0xBD, 0x01, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x80, 0x3E, 0x00, 0x00, 0x00, 0xBF,
        0x02, 0x04, 0x00, 0x00, 0xA6, 0x9B, 0xC4, 0x3A,
        0x00, 0x00, 0x00, 0xC0, 0x02, 0x05, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        0xCA, 0x03, 0x3A, 0x71, 0xAC, 0xBE, 0xAD, 0xB2,
    ];
    assert_eq!(encoded(&c, 0x0102_0304, 0xA1B2_C3D4), expected);
}

#[test]
fn every_single_bit_flip_is_detected() {
    let good = encoded(&coefs(0.02), 42, HASH);
    for bit in 0..RECORD_BYTES * 8 {
        let mut buf = good;
        buf[bit / 8] ^= 1 << (bit % 8);
        let err = decode(&buf, HASH).expect_err("flip accepted");
        let expected = match bit / 8 {
            0..4 => matches!(err, RecordError::BadMagic),
            4..6 => matches!(err, RecordError::UnsupportedVersion { .. }),
            _ => err == RecordError::BadCrc,
        };
        assert!(expected, "bit {bit}: {err:?}");
    }
}

#[test]
fn every_double_bit_flip_is_detected() {
    let good = encoded(&coefs(0.03), 43, HASH);
    let bits = RECORD_BYTES * 8;
    for i in 0..bits {
        let mut once = good;
        once[i / 8] ^= 1 << (i % 8);
        for j in i + 1..bits {
            let mut buf = once;
            buf[j / 8] ^= 1 << (j % 8);
            assert!(decode(&buf, HASH).is_err(), "bits {i} and {j}");
        }
    }
}

#[test]
fn truncation_at_every_length() {
    let good = encoded(&coefs(0.04), 44, HASH);
    for len in 0..RECORD_BYTES {
        assert_eq!(
            decode(&good[..len], HASH),
            Err(RecordError::Truncated),
            "len {len}"
        );
    }
    assert!(decode(&good, HASH).is_ok());
}

#[test]
fn erased_page() {
    assert_eq!(decode(&[0xFF; PAGE_BYTES], HASH), Err(RecordError::Erased));
    assert_eq!(
        decode(&[0xFF; RECORD_BYTES], HASH),
        Err(RecordError::Erased)
    );
}

/// Every prefix of the programming order (double word by double word, commit last)
/// on an erased page is refused until the last double word is in.
#[test]
fn interrupted_write_images_are_refused() {
    let good = encoded(&coefs(0.05), 45, HASH);
    for dws in 0..RECORD_BYTES / DOUBLE_WORD_BYTES {
        let mut img = [0xFFu8; RECORD_BYTES];
        img[..dws * DOUBLE_WORD_BYTES].copy_from_slice(&good[..dws * DOUBLE_WORD_BYTES]);
        let err = decode(&img, HASH).expect_err("partial record accepted");
        let expected = match dws {
            0 => RecordError::Erased,
            16 => unreachable!(),
            _ => RecordError::Incomplete,
        };
        assert_eq!(err, expected, "{dws} double words");
        // Torn: half of the next double word as well.
        let half = dws * DOUBLE_WORD_BYTES + DOUBLE_WORD_BYTES / 2;
        img[..half].copy_from_slice(&good[..half]);
        assert!(decode(&img, HASH).is_err(), "{dws} double words + half");
    }
}

#[test]
fn commit_mark_and_crc_both_checked() {
    let good = encoded(&coefs(0.06), 46, HASH);
    let mut no_mark = good;
    no_mark[COMMIT_OFFSET + 4..].fill(0xFF);
    assert_eq!(decode(&no_mark, HASH), Err(RecordError::BadCrc));
    let mut no_crc = good;
    no_crc[COMMIT_OFFSET..COMMIT_OFFSET + 4].fill(0xFF);
    assert_eq!(decode(&no_crc, HASH), Err(RecordError::BadCrc));
}

#[test]
fn bad_magic() {
    let mut buf = encoded(&coefs(0.0), 1, HASH);
    buf[..4].copy_from_slice(&0x4D52_4154u32.to_le_bytes());
    reseal(&mut buf);
    assert_eq!(decode(&buf, HASH), Err(RecordError::BadMagic));
    assert_eq!(
        decode(&[0u8; RECORD_BYTES], HASH),
        Err(RecordError::BadMagic)
    );
}

#[test]
fn stale_and_future_versions() {
    for found in [0, FORMAT_VERSION - 1, FORMAT_VERSION + 1, u16::MAX] {
        let mut buf = encoded(&coefs(0.0), 1, HASH);
        buf[VERSION_AT..VERSION_AT + 2].copy_from_slice(&found.to_le_bytes());
        reseal(&mut buf);
        assert_eq!(
            decode(&buf, HASH),
            Err(RecordError::UnsupportedVersion {
                found,
                expected: FORMAT_VERSION
            })
        );
    }
}

/// A well-formed record of format 1 (120 bytes, no alignment) as the previous firmware
/// wrote it: refused by its version, by name, so the drive commissions again.
#[test]
fn a_format_1_record_is_refused_by_name() {
    let mut v1 = [0u8; 120];
    v1[..4].copy_from_slice(&0x4D52_4153u32.to_le_bytes());
    v1[4..6].copy_from_slice(&1u16.to_le_bytes());
    v1[6] = 1; // one path: offset (0.1, -0.08)
    v1[8..12].copy_from_slice(&5u32.to_le_bytes());
    v1[12..16].copy_from_slice(&HASH.to_le_bytes());
    v1[16..20].copy_from_slice(&[0, 0, 0, 0]);
    v1[20..24].copy_from_slice(&0.1f32.to_bits().to_le_bytes());
    v1[24..28].copy_from_slice(&(-0.08f32).to_bits().to_le_bytes());
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&v1[..112]);
    v1[112..116].copy_from_slice(&crc.to_le_bytes());
    v1[116..120].copy_from_slice(&(!0x4D52_4153u32).to_le_bytes());
    // As read from its page: the 120 bytes and the erased bytes after them.
    let mut page = [0xFFu8; PAGE_BYTES];
    page[..120].copy_from_slice(&v1);
    let err = decode(&page, HASH).unwrap_err();
    assert_eq!(
        err,
        RecordError::UnsupportedVersion {
            found: 1,
            expected: 2
        }
    );
    assert_eq!(err.name(), "UnsupportedVersion");

    let mut flash = RamFlash::new();
    for slot in Slot::BOTH {
        flash.erase(slot).unwrap();
        let mut page = [0xFFu8; 128];
        page[..120].copy_from_slice(&v1);
        flash.program(slot, 0, &page).unwrap();
    }
    let e = load(&flash, HASH).unwrap_err();
    assert_eq!(e.name(), "UnsupportedVersion");
}

#[test]
fn the_alignment_round_trips_exactly_and_is_checked() {
    let pi = core::f32::consts::PI;
    for (offset_e_rad, reversed) in [(0.0, false), (pi, true), (-pi, false), (1e-7, true)] {
        let c = Calibration {
            coefficients: coefs(0.1),
            alignment: Alignment {
                offset_e_rad,
                reversed,
            },
        };
        let back = decode(&encoded_cal(&c, 3, HASH), HASH).unwrap().calibration;
        assert_eq!(back.alignment.reversed, reversed);
        assert_eq!(
            back.alignment.offset_e_rad.to_bits(),
            offset_e_rad.to_bits()
        );
    }
    for bad in [f32::NAN, f32::INFINITY, 3.2, -3.2] {
        let c = Calibration {
            coefficients: coefs(0.1),
            alignment: Alignment {
                offset_e_rad: bad,
                reversed: false,
            },
        };
        assert_eq!(
            decode(&encoded_cal(&c, 3, HASH), HASH),
            Err(RecordError::BadAlignment),
            "{bad}"
        );
    }
    let mut buf = encoded(&coefs(0.0), 1, HASH);
    buf[FLAGS_AT] = 2;
    reseal(&mut buf);
    assert_eq!(decode(&buf, HASH), Err(RecordError::BadAlignment));
    let mut buf = encoded(&coefs(0.0), 1, HASH);
    buf[OFFSET_AT..OFFSET_AT + 4].copy_from_slice(&f32::NAN.to_bits().to_le_bytes());
    reseal(&mut buf);
    assert_eq!(decode(&buf, HASH), Err(RecordError::BadAlignment));
    assert_eq!(RecordError::BadAlignment.name(), "BadAlignment");
    let _ = ALIGN;
}

#[test]
fn config_mismatch() {
    let buf = encoded(&coefs(0.0), 1, HASH);
    assert_eq!(
        decode(&buf, OTHER_HASH),
        Err(RecordError::ConfigMismatch {
            stored: HASH,
            expected: OTHER_HASH
        })
    );
}

#[test]
fn non_finite_values_are_rejected() {
    for bad in [f32::NAN, -f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        for (n, &kind) in DEFAULT_PATHS.iter().enumerate() {
            for part in 0..2 {
                let mut c = coefs(0.0);
                let v = c.get(kind).unwrap();
                let v = if part == 0 {
                    Cplx::new(bad, v.im)
                } else {
                    Cplx::new(v.re, bad)
                };
                c.set(kind, v);
                let buf = encoded(&c, 1, HASH);
                assert_eq!(
                    decode(&buf, HASH),
                    Err(RecordError::NonFiniteValue),
                    "path {n}, part {part}, {bad}"
                );
            }
        }
    }
}

/// Patch the (tag, h) of path entry `n` and re-seal.
fn with_kind_bytes(n: usize, tag: u8, h: u8) -> [u8; RECORD_BYTES] {
    let mut buf = encoded(&coefs(0.0), 1, HASH);
    let at = PATH0_AT + 12 * n;
    buf[at] = tag;
    buf[at + 1] = h;
    reseal(&mut buf);
    buf
}

#[test]
fn bad_path_lists_are_rejected() {
    let bad = RecordError::BadPathList;
    // Path 3 is Harmonic(5).
    for (tag, h) in [
        (3, 0), // unknown tag
        (0, 1), // offset with a harmonic number
        (1, 4), // C/D with a harmonic number
        (2, 0), // h = 0..3 are refused by the core
        (2, 1),
        (2, 2),
        (2, 3),
        (2, 16), // |h| > 15
        (2, (-16i8) as u8),
        (2, 0x80),         // h = -128
        (2, 4),            // duplicate of path 2
        (2, (-2i8) as u8), // m = 3: same error harmonic as h = 4 (path 2)
        (0, 0),            // second offset
    ] {
        assert_eq!(
            decode(&with_kind_bytes(3, tag, h), HASH),
            Err(bad),
            "tag {tag} h {h}"
        );
    }
    // A valid replacement decodes.
    let ok = decode(&with_kind_bytes(3, 2, (-7i8) as u8), HASH).unwrap();
    assert_eq!(
        ok.calibration.coefficients.iter().nth(3).unwrap().0,
        PathKind::Harmonic(-7)
    );

    for count in [MAX_PATHS as u8 + 1, 0x80, u8::MAX] {
        let mut buf = encoded(&coefs(0.0), 1, HASH);
        buf[COUNT_AT] = count;
        reseal(&mut buf);
        assert_eq!(decode(&buf, HASH), Err(bad), "count {count}");
    }
}

/// A count that is smaller than the number of written paths is a different (valid)
/// record only if the CRC matches: here it is re-sealed, so the shorter list decodes.
#[test]
fn path_count_is_authoritative_once_sealed() {
    let mut buf = encoded(&coefs(0.0), 1, HASH);
    buf[COUNT_AT] = 2;
    reseal(&mut buf);
    assert_eq!(
        decode(&buf, HASH).unwrap().calibration.coefficients.len(),
        2
    );
}

#[test]
fn encode_returns_record_length_and_overwrites_buffer() {
    let mut buf = [0xA5u8; RECORD_BYTES];
    assert_eq!(
        encode(
            &Calibration {
                coefficients: Coefficients::zeros(&[]),
                alignment: Alignment::IDENTITY
            },
            9,
            HASH,
            &mut buf
        ),
        RECORD_BYTES
    );
    assert!(buf[7..8]
        .iter()
        .chain(&buf[16..COMMIT_OFFSET])
        .all(|&b| b == 0));
    assert_eq!(decode(&buf, HASH).unwrap().sequence, 9);
}

#[test]
fn config_hash_covers_the_meaning_of_the_coefficients_only() {
    let base = Config::default();
    let h = config_hash(&base, 4);
    // Independently computed with zlib.crc32 over the documented serialisation.
    assert_eq!(h, 0xFF94_483C);
    // Another motor: another pole count, another hash.
    assert_ne!(config_hash(&base, 6), h);

    let mut tuned = base;
    tuned.sample_period_s = 100.0e-6;
    tuned.observer.eigenvalues_hz = [200.0, 20.0, 2.0];
    tuned.observer.inertia_kg_m2 = 3.0e-4;
    tuned.law = mras::AdaptationLaw::PAPER_FIG8;
    tuned.gates.min_speed_rad_s = 5.0;
    tuned.health.coefficient_limit = 0.3;
    tuned.convergence.min_revs = 9;
    tuned.input.raw_limit = 4095.0;
    assert_eq!(
        config_hash(&tuned, 4),
        h,
        "tuning must not invalidate a calibration"
    );

    let mut neg_zero = base;
    neg_zero.input.offset_x = -0.0;
    assert_eq!(config_hash(&neg_zero, 4), h);

    let mut variants = Vec::new();
    let mut c = base;
    c.sensor_periods = 3;
    variants.push(c);
    for field in 0..4 {
        let mut c = base;
        let f = match field {
            0 => &mut c.input.offset_x,
            1 => &mut c.input.offset_y,
            2 => &mut c.input.gain_x,
            _ => &mut c.input.gain_y,
        };
        *f += 1.0e-3;
        variants.push(c);
    }
    for paths in [
        &DEFAULT_PATHS[..3],
        &[
            PathKind::AmplitudeQuadrature,
            PathKind::Offset,
            PathKind::Harmonic(4),
            PathKind::Harmonic(5),
        ][..],
        &[
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(-2),
            PathKind::Harmonic(5),
        ][..],
    ] {
        let mut c = base;
        c.set_paths(paths).unwrap();
        variants.push(c);
    }
    let mut seen = vec![h];
    for v in &variants {
        let hv = config_hash(v, 4);
        assert!(!seen.contains(&hv), "{v:?}");
        seen.push(hv);
    }
}

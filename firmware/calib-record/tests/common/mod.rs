//! Shared test fixtures.
#![allow(dead_code)]

use core::f32::consts::{PI, TAU};

use calib_record::layout::{CRC_OFFSET, DOUBLE_WORD_BYTES};
use calib_record::{encode, Alignment, Calibration, MotorConstants, RECORD_BYTES};
use mras::{Coefficients, Cplx, PathKind};

pub const HASH: u32 = 0xA1B2_C3D4;
pub const OTHER_HASH: u32 = 0x0BAD_C0DE;

pub const DEFAULT_PATHS: [PathKind; 4] = [
    PathKind::Offset,
    PathKind::AmplitudeQuadrature,
    PathKind::Harmonic(4),
    PathKind::Harmonic(5),
];

/// Coefficients for the default path list, with a distinguishing tag in every value.
pub fn coefs(tag: f32) -> Coefficients {
    let mut c = Coefficients::zeros(&DEFAULT_PATHS);
    c.set(PathKind::Offset, Cplx::new(0.1 + tag, -0.08));
    c.set(PathKind::AmplitudeQuadrature, Cplx::new(0.25, -0.5 + tag));
    c.set(PathKind::Harmonic(4), Cplx::new(1.5e-3, -tag));
    c.set(PathKind::Harmonic(5), Cplx::new(tag * 1e-3, -0.0));
    c
}

/// A valid alignment derived from the tag: the offset walks around [-π, π) (tag 0 is
/// exactly -π), the direction is the parity of the tag's bits, the pole pairs 1-64.
pub fn alignment(tag: f32) -> Alignment {
    Alignment {
        offset_e_rad: (tag * 0.731).rem_euclid(TAU) - PI,
        reversed: tag.to_bits().count_ones() % 2 == 1,
        pole_pairs: 1 + (tag.to_bits() % 64) as u16,
    }
}

/// Valid motor constants derived from the tag (tag 0: zero inverter error and
/// viscous friction, both allowed; the constant friction is positive below tag 2 and
/// negative above it, which is allowed too).
pub fn motor(tag: f32) -> MotorConstants {
    let t = tag.abs();
    MotorConstants {
        r_ohm: 0.1 + t * 1e-3,
        ld_h: 2e-4 + t * 1e-6,
        lq_h: 3e-4 + t * 1e-6,
        v_inverter_v: t * 1e-2,
        flux_wb: 0.01 + t * 1e-4,
        inertia_kg_m2: 1e-4 + t * 1e-7,
        viscous_nm_s_rad: t * 1e-6,
        coulomb_nm: 2e-3 - t * 1e-3,
    }
}

/// Plain motor constants for records whose motor does not matter.
pub const MOTOR: MotorConstants = MotorConstants {
    r_ohm: 0.3,
    ld_h: 5e-4,
    lq_h: 6e-4,
    v_inverter_v: 0.5,
    flux_wb: 0.02,
    inertia_kg_m2: 2e-4,
    viscous_nm_s_rad: 1e-5,
    coulomb_nm: 3e-3,
};

/// A calibration with a distinguishing tag in every coefficient, in the alignment and
/// in the motor constants.
pub fn calib(tag: f32) -> Calibration {
    Calibration {
        coefficients: coefs(tag),
        alignment: alignment(tag),
        motor: motor(tag),
    }
}

/// `c` with the identity alignment (4 pole pairs: a stored alignment has a count) and
/// [`MOTOR`].
pub fn with_identity(c: Coefficients) -> Calibration {
    Calibration {
        coefficients: c,
        alignment: Alignment {
            pole_pairs: 4,
            ..Alignment::IDENTITY
        },
        motor: MOTOR,
    }
}

pub fn encoded(c: &Calibration, seq: u32, hash: u32) -> [u8; RECORD_BYTES] {
    let mut buf = [0u8; RECORD_BYTES];
    assert_eq!(encode(c, seq, hash, &mut buf), RECORD_BYTES);
    buf
}

/// Recompute the CRC after patching fields, to test the checks behind it.
pub fn reseal(buf: &mut [u8; RECORD_BYTES]) {
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&buf[..CRC_OFFSET]);
    buf[CRC_OFFSET..CRC_OFFSET + 4].copy_from_slice(&crc.to_le_bytes());
}

/// Bit-exact comparison (f32 `==` equates 0.0 and -0.0 and never matches NaN).
pub fn same_coef_bits(a: &Coefficients, b: &Coefficients) -> bool {
    a.len() == b.len()
        && a.iter().zip(b.iter()).all(|((ka, va), (kb, vb))| {
            ka == kb && va.re.to_bits() == vb.re.to_bits() && va.im.to_bits() == vb.im.to_bits()
        })
}

/// The motor constants in record order.
pub fn motor_fields(m: &MotorConstants) -> [f32; 8] {
    [
        m.r_ohm,
        m.ld_h,
        m.lq_h,
        m.v_inverter_v,
        m.flux_wb,
        m.inertia_kg_m2,
        m.viscous_nm_s_rad,
        m.coulomb_nm,
    ]
}

/// Bit-exact comparison of motor constants.
pub fn same_motor_bits(a: &MotorConstants, b: &MotorConstants) -> bool {
    motor_fields(a)
        .iter()
        .zip(motor_fields(b).iter())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Bit-exact comparison of whole calibrations.
pub fn same_bits(a: &Calibration, b: &Calibration) -> bool {
    same_coef_bits(&a.coefficients, &b.coefficients)
        && a.alignment.offset_e_rad.to_bits() == b.alignment.offset_e_rad.to_bits()
        && a.alignment.reversed == b.alignment.reversed
        && same_motor_bits(&a.motor, &b.motor)
}

/// Size of a format-version-1 record.
pub const V1_RECORD_BYTES: usize = 120;
/// Size of a format-version-2 record.
pub const V2_RECORD_BYTES: usize = 128;
/// Size of a format-version-3 record (sixteen paths, no motor block).
pub const V3_RECORD_BYTES: usize = 224;
/// Path entries in a version 1 or 2 record (the core then ran at most 8 paths).
pub const LEGACY_PATHS: usize = 8;

/// A correctly formed format-version-1 record, built by hand from the version-1
/// layout (independently of the crate's encoder): magic, version 1, path count,
/// reserved 0, sequence, hash, eight 12-byte path entries, CRC-32/ISO-HDLC over bytes
/// 0..112, commit mark.
pub fn v1_record(c: &Coefficients, seq: u32, hash: u32) -> [u8; V1_RECORD_BYTES] {
    let mut b = [0u8; V1_RECORD_BYTES];
    legacy_header(&mut b, 1, c, seq, hash);
    legacy_paths_and_seal(&mut b, 16, c);
    b
}

/// A correctly formed format-version-2 record, built by hand from the version-2
/// layout: magic, version 2, path count, direction flags, sequence, hash, alignment
/// offset, reserved 0, eight 12-byte path entries from byte 24, CRC-32/ISO-HDLC over
/// bytes 0..120, commit mark.
pub fn v2_record(cal: &Calibration, seq: u32, hash: u32) -> [u8; V2_RECORD_BYTES] {
    let mut b = [0u8; V2_RECORD_BYTES];
    legacy_header(&mut b, 2, &cal.coefficients, seq, hash);
    b[7] = cal.alignment.reversed as u8;
    let offset = cal.alignment.offset_e_rad.to_bits();
    b[16..20].copy_from_slice(&offset.to_le_bytes());
    legacy_paths_and_seal(&mut b, 24, &cal.coefficients);
    b
}

/// A correctly formed format-version-3 record, built by hand from the version-3
/// layout: the version-2 header with version 3, sixteen 12-byte path entries from byte
/// 24, CRC-32/ISO-HDLC over bytes 0..216, commit mark (no motor block).
pub fn v3_record(cal: &Calibration, seq: u32, hash: u32) -> [u8; V3_RECORD_BYTES] {
    let mut b = [0u8; V3_RECORD_BYTES];
    legacy_header(&mut b, 3, &cal.coefficients, seq, hash);
    b[7] = cal.alignment.reversed as u8;
    let offset = cal.alignment.offset_e_rad.to_bits();
    b[16..20].copy_from_slice(&offset.to_le_bytes());
    write_paths_and_seal(&mut b, 24, 16, &cal.coefficients);
    b
}

/// A correctly formed format-version-4 record, built by hand from the version-4
/// layout: the version-3 header and paths with version 4, the eight motor constants
/// from byte 216, CRC-32/ISO-HDLC over bytes 0..248, commit mark (bytes 20..24 zero:
/// no pole-pair count).
pub fn v4_record(cal: &Calibration, seq: u32, hash: u32) -> [u8; 256] {
    let mut b = [0u8; 256];
    let paths = v3_record(cal, seq, hash);
    b[..216].copy_from_slice(&paths[..216]);
    b[4..6].copy_from_slice(&4u16.to_le_bytes());
    for (n, v) in motor_fields(&cal.motor).into_iter().enumerate() {
        b[216 + 4 * n..220 + 4 * n].copy_from_slice(&v.to_bits().to_le_bytes());
    }
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&b[..248]);
    b[248..252].copy_from_slice(&crc.to_le_bytes());
    b[252..256].copy_from_slice(&(!0x4D52_4153u32).to_le_bytes());
    b
}

/// Bytes 0..16 of a version 1, 2, 3 or 4 record: magic, version, count, sequence, hash.
fn legacy_header(b: &mut [u8], version: u16, c: &Coefficients, seq: u32, hash: u32) {
    b[0..4].copy_from_slice(&0x4D52_4153u32.to_le_bytes()); // "MRAS"
    b[4..6].copy_from_slice(&version.to_le_bytes());
    b[6] = c.len() as u8;
    b[8..12].copy_from_slice(&seq.to_le_bytes());
    b[12..16].copy_from_slice(&hash.to_le_bytes());
}

/// Eight path entries from `first`, then the CRC and the commit mark, which end `b`.
fn legacy_paths_and_seal(b: &mut [u8], first: usize, c: &Coefficients) {
    write_paths_and_seal(b, first, LEGACY_PATHS, c);
}

/// `entries` path entries from `first`, then the CRC and the commit mark, which end `b`.
fn write_paths_and_seal(b: &mut [u8], first: usize, entries: usize, c: &Coefficients) {
    for (n, (kind, v)) in c.iter().enumerate() {
        let at = first + 12 * n;
        let (tag, h) = match kind {
            PathKind::Offset => (0, 0),
            PathKind::AmplitudeQuadrature => (1, 0),
            PathKind::Harmonic(h) => (2, h as u8),
        };
        b[at] = tag;
        b[at + 1] = h;
        b[at + 4..at + 8].copy_from_slice(&v.re.to_bits().to_le_bytes());
        b[at + 8..at + 12].copy_from_slice(&v.im.to_bits().to_le_bytes());
    }
    let crc_at = first + 12 * entries;
    assert_eq!(crc_at + DOUBLE_WORD_BYTES, b.len());
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&b[..crc_at]);
    b[crc_at..crc_at + 4].copy_from_slice(&crc.to_le_bytes());
    b[crc_at + 4..].copy_from_slice(&0xB2AD_BEACu32.to_le_bytes()); // !magic
}

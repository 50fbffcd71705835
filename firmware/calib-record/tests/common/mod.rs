//! Shared test fixtures.
#![allow(dead_code)]

use calib_record::layout::CRC_OFFSET;
use calib_record::{encode, Alignment, Calibration, RECORD_BYTES};
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

/// The alignment stored with the fixtures' coefficients.
pub const ALIGN: Alignment = Alignment {
    offset_e_rad: -1.25,
    reversed: true,
};

/// A calibration of `c` with [`ALIGN`].
pub fn cal(c: &Coefficients) -> Calibration {
    Calibration {
        coefficients: *c,
        alignment: ALIGN,
    }
}

pub fn encoded(c: &Coefficients, seq: u32, hash: u32) -> [u8; RECORD_BYTES] {
    encoded_cal(&cal(c), seq, hash)
}

pub fn encoded_cal(c: &Calibration, seq: u32, hash: u32) -> [u8; RECORD_BYTES] {
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
pub fn same_bits(a: &Coefficients, b: &Coefficients) -> bool {
    a.len() == b.len()
        && a.iter().zip(b.iter()).all(|((ka, va), (kb, vb))| {
            ka == kb && va.re.to_bits() == vb.re.to_bits() && va.im.to_bits() == vb.im.to_bits()
        })
}

//! Property tests: exact round trips and no panics on arbitrary flash content.

mod common;

use core::f32::consts::PI;

use calib_record::layout::MOTOR_OFFSET;
use calib_record::{
    decode, load, store, Alignment, Calibration, MotorConstants, RamFlash, RecordError, Slot,
    RECORD_BYTES,
};
use common::{calib, encoded, motor_fields, reseal, same_bits, same_motor_bits, HASH};
use mras::{Coefficients, Cplx, PathKind, MAX_PATHS};
use proptest::prelude::*;

/// A valid path list: distinct error harmonics m in 1..=16, each realised by one of
/// the kinds that null it, in random order.
fn path_list() -> impl Strategy<Value = Vec<PathKind>> {
    let kind = (1u8..=16, any::<bool>()).prop_filter_map("no kind for this m", |(m, up)| {
        let m8 = m as i8;
        let options: Vec<PathKind> = match m {
            1 => vec![PathKind::Offset],
            2 => vec![PathKind::AmplitudeQuadrature],
            _ => [1 + m8, 1 - m8]
                .into_iter()
                .filter(|h| h.abs() <= 15 && !(0..=3).contains(h))
                .map(PathKind::Harmonic)
                .collect(),
        };
        match options.len() {
            0 => None,
            1 => Some(options[0]),
            _ => Some(options[usize::from(up)]),
        }
    });
    proptest::collection::vec(kind, 0..=MAX_PATHS).prop_map(|mut v| {
        let mut seen = Vec::new();
        v.retain(|k| {
            let fresh = !seen.contains(&k.error_harmonic());
            seen.push(k.error_harmonic());
            fresh
        });
        v
    })
}

/// Any finite f32, subnormals and -0.0 included.
fn finite() -> impl Strategy<Value = f32> {
    any::<u32>()
        .prop_map(f32::from_bits)
        .prop_filter("finite", |v| v.is_finite())
}

fn coefficients() -> impl Strategy<Value = Coefficients> {
    path_list().prop_flat_map(|paths| {
        let n = paths.len();
        proptest::collection::vec((finite(), finite()), n).prop_map(move |vals| {
            let mut c = Coefficients::zeros(&paths);
            for (k, (re, im)) in paths.iter().zip(vals) {
                assert!(c.set(*k, Cplx::new(re, im)));
            }
            c
        })
    })
}

/// Any valid alignment offset: every f32 in [-π, π], ±0, subnormals and both ends
/// included.
fn offset() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => any::<u32>()
            .prop_map(f32::from_bits)
            .prop_filter("within [-π, π]", |v| (-PI..=PI).contains(v)),
        1 => prop_oneof![Just(PI), Just(-PI), Just(0.0), Just(-0.0)],
    ]
}

fn alignment() -> impl Strategy<Value = Alignment> {
    (offset(), any::<bool>(), 1..=u16::MAX).prop_map(|(offset_e_rad, reversed, pole_pairs)| {
        Alignment {
            offset_e_rad,
            reversed,
            pole_pairs,
        }
    })
}

/// Any finite f32 > 0, subnormals and f32::MAX included.
fn positive() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => finite().prop_map(f32::abs).prop_filter("> 0", |v| *v > 0.0),
        1 => prop_oneof![Just(f32::from_bits(1)), Just(f32::MIN_POSITIVE), Just(f32::MAX)],
    ]
}

/// Any finite f32 ≥ 0, ±0 included.
fn non_negative() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => finite().prop_map(f32::abs),
        1 => prop_oneof![Just(0.0), Just(-0.0)],
    ]
}

/// Any valid motor constants (the friction terms: any finite value, either sign).
fn motor() -> impl Strategy<Value = MotorConstants> {
    (
        (positive(), positive(), positive(), non_negative()),
        (positive(), positive(), finite(), finite()),
    )
        .prop_map(
            |(
                (r_ohm, ld_h, lq_h, v_inverter_v),
                (flux_wb, inertia_kg_m2, viscous_nm_s_rad, coulomb_nm),
            )| {
                MotorConstants {
                    r_ohm,
                    ld_h,
                    lq_h,
                    v_inverter_v,
                    flux_wb,
                    inertia_kg_m2,
                    viscous_nm_s_rad,
                    coulomb_nm,
                }
            },
        )
}

fn calibration() -> impl Strategy<Value = Calibration> {
    (coefficients(), alignment(), motor()).prop_map(|(coefficients, alignment, motor)| {
        Calibration {
            coefficients,
            alignment,
            motor,
        }
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_calibrations_round_trip_bit_exact(
        c in calibration(), seq in any::<u32>(), hash in any::<u32>()
    ) {
        let rec = decode(&encoded(&c, seq, hash), hash).unwrap();
        prop_assert!(same_bits(&rec.calibration, &c));
        prop_assert!(same_motor_bits(&rec.calibration.motor, &c.motor));
        prop_assert_eq!(rec.sequence, seq);
        prop_assert_eq!(rec.config_hash, hash);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = decode(&bytes, HASH);
    }

    /// Whatever the (sealed) alignment bytes hold, the record decodes with exactly
    /// that alignment if the offset is finite and within [-π, π] and the direction
    /// byte is 0 or 1, and is refused as `BadAlignment` otherwise.
    #[test]
    fn any_alignment_bytes_decode_exactly_or_bad_alignment(
        bits in any::<u32>(), direction in any::<u8>(), tag in 0.0f32..10.0,
    ) {
        let mut buf = encoded(&calib(tag), 1, HASH);
        buf[7] = direction;
        buf[16..20].copy_from_slice(&bits.to_le_bytes());
        reseal(&mut buf);
        let offset = f32::from_bits(bits);
        let valid = offset.is_finite() && offset.abs() <= PI && direction <= 1;
        match decode(&buf, HASH) {
            Ok(rec) => {
                prop_assert!(valid);
                let a = rec.calibration.alignment;
                prop_assert_eq!(a.offset_e_rad.to_bits(), bits);
                prop_assert_eq!(a.reversed, direction == 1);
            }
            Err(e) => {
                prop_assert!(!valid);
                prop_assert_eq!(e, RecordError::BadAlignment);
            }
        }
    }

    /// Whatever the (sealed) motor block holds, the record decodes with exactly those
    /// constants if they are valid (finite; r, Ld, Lq, flux, inertia > 0; inverter
    /// error ≥ 0; viscous and constant friction of any sign) and is refused as
    /// `BadMotor` otherwise.
    #[test]
    fn any_motor_bytes_decode_exactly_or_bad_motor(
        // Mostly valid fields (finite, ≥ 0), so that both outcomes are common.
        mut fields in proptest::array::uniform8(prop_oneof![
            12 => any::<u32>().prop_map(|b| b & 0x7F7F_FFFF), // finite, ≥ 0
            1 => any::<u32>(),
            1 => Just(0u32),
            1 => Just(0x8000_0000u32), // -0.0
            1 => Just(0x7F80_0000u32), // +∞
            1 => Just(0x7FC0_0000u32), // NaN
        ]),
        // Sign flips of the friction terms, so that negative ones are common too.
        negate_friction in any::<[bool; 2]>(),
        tag in 0.0f32..10.0,
    ) {
        for (bits, negate) in fields[6..].iter_mut().zip(negate_friction) {
            if negate {
                *bits ^= 0x8000_0000;
            }
        }
        let mut buf = encoded(&calib(tag), 1, HASH);
        for (n, bits) in fields.iter().enumerate() {
            let at = MOTOR_OFFSET + 4 * n;
            buf[at..at + 4].copy_from_slice(&bits.to_le_bytes());
        }
        reseal(&mut buf);
        let v = fields.map(f32::from_bits);
        let positive = |x: f32| x.is_finite() && x > 0.0;
        let non_negative = |x: f32| x.is_finite() && x >= 0.0;
        let valid = [v[0], v[1], v[2], v[4], v[5]].into_iter().all(positive)
            && non_negative(v[3])
            && [v[6], v[7]].into_iter().all(f32::is_finite);
        match decode(&buf, HASH) {
            Ok(rec) => {
                prop_assert!(valid);
                let got = motor_fields(&rec.calibration.motor).map(f32::to_bits);
                prop_assert_eq!(got, fields);
            }
            Err(e) => {
                prop_assert!(!valid);
                prop_assert_eq!(e, RecordError::BadMotor);
            }
        }
    }

    /// Random byte corruption of a valid record is either detected or no change.
    #[test]
    fn random_corruption_is_detected(
        c in calibration(),
        hits in proptest::collection::vec((0..RECORD_BYTES, 1u8..=255), 1..6),
    ) {
        let good = encoded(&c, 1, HASH);
        let mut bad = good;
        for (at, x) in hits {
            bad[at] ^= x;
        }
        prop_assert!(bad == good || decode(&bad, HASH).is_err());
    }

    /// Whatever the pages hold, load and store never panic, and after a store load
    /// returns what was stored.
    #[test]
    fn store_over_arbitrary_pages(
        a in proptest::collection::vec(any::<u8>(), RECORD_BYTES),
        b in proptest::collection::vec(any::<u8>(), RECORD_BYTES),
        c in calibration(),
    ) {
        let mut flash = RamFlash::new();
        flash.page_mut(Slot::A)[..RECORD_BYTES].copy_from_slice(&a);
        flash.page_mut(Slot::B)[..RECORD_BYTES].copy_from_slice(&b);
        let _ = load(&flash, HASH);
        let slot = store(&mut flash, &c, HASH).unwrap();
        let l = load(&flash, HASH).unwrap();
        prop_assert_eq!(l.slot, slot);
        prop_assert!(same_bits(&l.record.calibration, &c));
    }
}

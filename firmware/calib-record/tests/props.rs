//! Property tests: exact round trips and no panics on arbitrary flash content.

mod common;

use calib_record::{decode, load, store, RamFlash, Slot, RECORD_BYTES};
use common::{cal, encoded, same_bits, HASH};
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_coefficients_round_trip_bit_exact(
        c in coefficients(), seq in any::<u32>(), hash in any::<u32>()
    ) {
        let rec = decode(&encoded(&c, seq, hash), hash).unwrap();
        prop_assert!(same_bits(&rec.calibration.coefficients, &c));
        prop_assert_eq!(rec.sequence, seq);
        prop_assert_eq!(rec.config_hash, hash);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = decode(&bytes, HASH);
    }

    /// Random byte corruption of a valid record is either detected or no change.
    #[test]
    fn random_corruption_is_detected(
        c in coefficients(),
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
        c in coefficients(),
    ) {
        let mut flash = RamFlash::new();
        flash.page_mut(Slot::A)[..RECORD_BYTES].copy_from_slice(&a);
        flash.page_mut(Slot::B)[..RECORD_BYTES].copy_from_slice(&b);
        let _ = load(&flash, HASH);
        let slot = store(&mut flash, &cal(&c), HASH).unwrap();
        let l = load(&flash, HASH).unwrap();
        prop_assert_eq!(l.slot, slot);
        prop_assert!(same_bits(&l.record.calibration.coefficients, &c));
    }
}

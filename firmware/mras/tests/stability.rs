//! The documented stable range of the adaptation gain (docs/theory.md §5) holds at every
//! speed and direction of the comparison table, each cell within 2x of the revolutions
//! published in docs/figures/gain-sweep.md (`hil-sim figures laws`, the same runs).

mod common;
use common::*;

const SPEEDS_REV_S: [f64; 10] = [
    2.0, -2.0, 5.0, -5.0, 20.0, -20.0, 50.0, -50.0, 100.0, -100.0,
];

/// Revolutions to 10x published for each end of the range, in [`SPEEDS_REV_S`] order.
const PUBLISHED: [(f32, [usize; 10]); 2] = [
    (0.05, [12, 10, 6, 5, 4, 4, 4, 4, 3, 3]),
    (0.2, [5, 3, 5, 3, 3, 3, 3, 3, 2, 2]),
];

#[test]
fn both_ends_of_the_stable_gain_range_converge_everywhere() {
    for (gain, published) in PUBLISHED {
        for (v, p) in SPEEDS_REV_S.into_iter().zip(published) {
            let r = revs_to_10x(with_gain(gain, 0.0), v);
            println!("gain {gain}: {v:+} rev/s -> {r:?} (published {p})");
            assert!(
                r.is_some_and(|r| r <= 2 * p),
                "gain {gain} at {v} rev/s: {r:?}, published {p}"
            );
        }
    }
}

#[test]
fn proportional_term_keeps_convergence() {
    for v in [5.0, -20.0, 100.0] {
        let r = revs_to_10x(with_gain(0.15, 0.05), v);
        assert!(r.is_some_and(|r| r <= 6), "{v}: {r:?}");
    }
}

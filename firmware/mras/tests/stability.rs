//! The documented stable range of the adaptation gain (docs/theory.md §5) holds at every
//! speed and direction of the comparison table.

mod common;
use common::*;

const SPEEDS_REV_S: [f64; 10] = [
    2.0, -2.0, 5.0, -5.0, 20.0, -20.0, 50.0, -50.0, 100.0, -100.0,
];

#[test]
fn both_ends_of_the_stable_gain_range_converge_everywhere() {
    for gain in [0.05, 0.2] {
        for v in SPEEDS_REV_S {
            let r = revs_to_10x(with_gain(gain, 0.0), v);
            println!("gain {gain}: {v:+} rev/s -> {r:?}");
            assert!(
                r.is_some_and(|r| r <= 15),
                "gain {gain} at {v} rev/s: {r:?}"
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

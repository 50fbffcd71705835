//! The firmware runs the core split: [`Front`] in the control interrupt, [`Adapter`] in a
//! lower-priority task that may run any time before the update latency is up. Whatever
//! that delay, the result is bit for bit the inline [`Tracker`]'s.

mod common;
use common::*;
use mras::{AdaptSample, Adapter, Config, Front, InjectionUpdate, Tracker, UPDATE_LATENCY_PERIODS};
use proptest::prelude::*;
use std::collections::VecDeque;

/// Front and adapter as the firmware drives them: the task gets to run only every
/// `task_every` periods (then drains every queued sample), updates are applied when due.
fn split_run(
    cfg: Config,
    samples: &[(f32, f32)],
    task_every: usize,
) -> Vec<(Result<mras::Estimate, mras::Fault>, u32)> {
    let mut front = Front::new(cfg).unwrap();
    let mut adapter = Adapter::new(&cfg).unwrap();
    let mut to_task: VecDeque<AdaptSample> = VecDeque::new();
    let mut to_front = heapless::Deque::<InjectionUpdate, { 2 * mras::MAX_PATHS }>::new();
    let mut out = Vec::new();
    for (k, &(x, y)) in samples.iter().enumerate() {
        front.apply_due(&mut to_front);
        let r = front.step(x, y, 0.0).map(|e| mras::Estimate {
            adapting: false,
            ..e
        });
        to_task.extend(front.handoff().copied());
        if k % task_every == task_every - 1 {
            for s in to_task.drain(..) {
                let (_, update) = adapter.step(&s);
                if let Some(u) = update {
                    to_front.push_back(u).expect("one update per stride fits");
                }
            }
        }
        out.push((r, adapter.convergence().revs_adapted));
    }
    out
}

fn inline_run(cfg: Config, samples: &[(f32, f32)]) -> Vec<Result<mras::Estimate, mras::Fault>> {
    let mut t = Tracker::new(cfg).unwrap();
    samples
        .iter()
        .map(|&(x, y)| {
            t.step(x, y, 0.0).map(|e| mras::Estimate {
                adapting: false,
                ..e
            })
        })
        .collect()
}

/// The extreme sensor at constant speed, as raw samples.
fn samples(speed_rev_s: f64, n: usize) -> Vec<(f32, f32)> {
    let s = extreme_sensor().compile();
    (0..n)
        .map(|k| {
            let th = std::f64::consts::TAU * speed_rev_s * k as f64 * T_S;
            let (x, y) = s.vector(th);
            (x as f32, y as f32)
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]
    #[test]
    fn a_task_late_within_the_latency_changes_no_bit(
        task_every in 1usize..=UPDATE_LATENCY_PERIODS as usize,
        speed_rev_s in 5.0f64..40.0,
    ) {
        let xs = samples(speed_rev_s, 40_000);
        let inline = inline_run(Config::default(), &xs);
        let split = split_run(Config::default(), &xs, task_every);
        for (k, (a, (b, _))) in inline.iter().zip(&split).enumerate() {
            prop_assert_eq!(a, b, "period {}", k);
        }
        // And the adaptation did run: revolutions were adapted over.
        prop_assert!(split.last().unwrap().1 > 2);
    }
}

/// The spatial error (pk-pk, 360 bins, rad mechanical) of the estimates of the last
/// `n` periods of a constant-speed run of [`samples`] at `speed_rev_s`.
fn spatial_error_of_last(
    estimates: impl Iterator<Item = Result<mras::Estimate, mras::Fault>>,
    speed_rev_s: f64,
    total: usize,
    n: usize,
) -> f64 {
    let mut e = mras_sim::SpatialError::<360>::new();
    for (k, r) in estimates.enumerate().skip(total - n) {
        let est = r.expect("no fault at the end of the run");
        let th = std::f64::consts::TAU * speed_rev_s * k as f64 * T_S;
        e.add(
            th.rem_euclid(std::f64::consts::TAU),
            mras_sim::wrap_pi(est.theta_unwrapped_rad() - th),
        );
    }
    e.pk_pk_rad()
}

/// A task later than the latency is no longer bit-exact, but the updates still land (late)
/// and the adaptation still converges, to within 2x of the inline tracker's residual
/// (docs/performance.md): the deadline matters for reproducibility, not accuracy.
#[test]
fn a_task_past_its_deadline_still_converges() {
    const N: usize = 60_000;
    let xs = samples(20.0, N);
    let late = split_run(Config::default(), &xs, 3 * UPDATE_LATENCY_PERIODS as usize);
    let inline = inline_run(Config::default(), &xs);
    assert_ne!(
        late.iter().map(|x| x.0).collect::<Vec<_>>(),
        inline,
        "a late task should differ (else this test checks nothing)"
    );
    // The last 20 revolutions (1 s at 20 rev/s), well after convergence.
    let last = 20_000;
    let e_late = spatial_error_of_last(late.iter().map(|x| x.0), 20.0, N, last);
    let e_inline = spatial_error_of_last(inline.iter().copied(), 20.0, N, last);
    let raw = mras_sim::SensorModel::extreme().raw_error_pk_pk_rad();
    println!(
        "raw {:.2} mrad, inline {:.5} mrad, task 3x past its deadline {:.5} mrad pk-pk",
        raw * 1e3,
        e_inline * 1e3,
        e_late * 1e3
    );
    assert!(e_inline < raw / 1000.0, "inline: {e_inline} of {raw}");
    assert!(
        e_late <= 2.0 * e_inline,
        "late task {e_late} rad against inline {e_inline} rad"
    );
}

/// A bank from the data reaches the front through the update queue like a path's term:
/// split or inline, the rounds, the grown bank and every estimate are the same bits.
#[test]
fn a_bank_grown_from_the_data_changes_no_bit_when_split() {
    let mut cfg = Config::default();
    cfg.set_paths(&mras::survey::FIRST_STAGE).unwrap();
    cfg.paths_from_data = true;
    let xs = samples(20.0, 60_000);
    let inline = inline_run(cfg, &xs);
    let split = split_run(cfg, &xs, UPDATE_LATENCY_PERIODS as usize);
    for (k, (a, (b, _))) in inline.iter().zip(&split).enumerate() {
        assert_eq!(a, b, "period {k}");
    }
    let mut t = Tracker::new(cfg).unwrap();
    for &(x, y) in &xs {
        let _ = t.step(x, y, 0.0);
    }
    let o = t.adapter().survey().expect("a survey ran");
    assert!(o.bank.as_slice().len() > 2, "the bank grew: {:?}", o.bank);
    assert!(!t.adapter().surveying(), "and is complete");
}

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

/// A task later than the latency is no longer bit-exact, but the updates still land (late)
/// and the adaptation still converges: the deadline matters for reproducibility only.
#[test]
fn a_task_past_its_deadline_still_converges() {
    let xs = samples(20.0, 60_000);
    let late = split_run(Config::default(), &xs, 3 * UPDATE_LATENCY_PERIODS as usize);
    let inline = inline_run(Config::default(), &xs);
    assert_ne!(
        late.iter().map(|x| x.0).collect::<Vec<_>>(),
        inline,
        "a late task should differ (else this test checks nothing)"
    );
    assert!(late.last().unwrap().1 > 5);
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

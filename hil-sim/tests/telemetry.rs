//! What the stream says against what happened, on the `commissioning` scenario's rig:
//! the losses the firmware's hand-over code counts reach every record when the
//! adaptation task runs late or its queue is too small (the same code and queue types as
//! the firmware, so the same drops), and θ̂ in the records is the rotor's angle at the
//! record's sample instant (`t_ms / 1000 - 1 / f_pwm`), in the motor's frame.

use calib_record::RamFlash;
use drive::commissioning::State;
use drive::telemetry::{Line, Record};
use hil_sim::power_up::{self, Boot};
use hil_sim::rig::{Rig, SimFlash, Step};
use hil_sim::scenario::Scenario;
use mras::F32Trig;
use std::f64::consts::TAU;

fn scenario() -> Scenario {
    Scenario::load("commissioning").unwrap()
}

/// A power-up of `seconds` on a rig set up by `setup`, checking at every record that it
/// carries the counters of the control period and the adaptation task as they were when
/// its snapshot was taken (the same period: the rig takes no step in between).
fn boot_with<const H: usize, const U: usize>(
    mut rig: Rig<F32Trig, H, U>,
    seconds: f64,
    setup: impl FnOnce(&mut Rig<F32Trig, H, U>),
) -> (Boot, u64) {
    setup(&mut rig);
    let sc = scenario();
    let mut seen = 0;
    let mut records = 0u64;
    let mut hook = |rig: &mut Rig<F32Trig, H, U>, _: &Step| {
        for s in &rig.streamed()[seen..] {
            if let Line::Record(r) = &s.line {
                records += 1;
                assert_eq!(r.handoffs_dropped, rig.period.handoffs_dropped());
                assert_eq!(r.updates_late, rig.period.updates_late());
                assert_eq!(r.updates_dropped, rig.adaptation().updates_dropped());
                assert_eq!(r.events_dropped, 0);
            }
        }
        seen = rig.streamed().len();
    };
    let boot = power_up::run_boot(&mut rig, &sc, seconds, Some(&mut hook));
    (boot, records)
}

fn rig() -> Rig {
    power_up::rig(&scenario(), SimFlash::new(RamFlash::default()), 1).unwrap()
}

fn last_record(b: &Boot) -> Record {
    *b.records().last().expect("records")
}

/// The adaptation task held off: every 6 periods, the updates of the samples it reaches
/// 4 or 5 periods late (a third of them, one update every 2 samples with 7 paths) are
/// applied at once and counted late; every 20 periods, 5 of the 20 samples find the
/// 15-sample queue full. On time, nothing. The stream's losses say so.
#[test]
fn a_late_adaptation_task_is_counted_and_streamed() {
    let seconds = 1.0;
    let periods = (seconds / scenario().sample_period_s()).round();
    let (on_time, records) = boot_with(rig(), seconds, |_| {});
    assert!(records >= 90, "{records} records");
    assert!(on_time.losses().is_none(), "{:?}", on_time.losses());

    let (every_6, _) = boot_with(rig(), seconds, |r| r.set_adaptation_every(6));
    let last = last_record(&every_6);
    let late = every_6.losses().updates_late as f64;
    // Up to the last record's snapshot, 1/6 of the periods' samples made a late update.
    let expected = f64::from(last.t_ms) * 1e-3 / scenario().sample_period_s() / 6.0;
    assert!(
        (late - expected).abs() < 0.03 * expected,
        "{late} updates late, {expected:.0} expected"
    );
    let l = every_6.losses();
    assert_eq!(
        (
            l.handoffs_dropped,
            l.updates_dropped,
            l.events_dropped,
            l.frames_lost
        ),
        (0, 0, 0, 0),
        "{l:?}"
    );

    let (every_20, _) = boot_with(rig(), seconds, |r| r.set_adaptation_every(20));
    let dropped = every_20.losses().handoffs_dropped as f64;
    let expected = f64::from(last_record(&every_20).t_ms) * 1e-3 * 20_000.0 / 4.0;
    assert!(
        (dropped - expected).abs() < 0.01 * expected && dropped < periods / 4.0,
        "{dropped} samples dropped, {expected:.0} expected"
    );
    assert!(every_20.losses().updates_late > 0);
}

/// An update queue with room for one: every update the adaptation makes while the one
/// before waits out its latency (one every 2 samples with 7 paths, in force 4 periods
/// after its sample) finds it full, and is counted and streamed. Owed, each still goes
/// before its period (the slot frees 2 periods after it was made): none is late. The
/// report says so.
#[test]
fn an_update_queue_too_small_is_counted_and_streamed() {
    let (b, _) = boot_with(rig().with_queue_depths::<16, 2>(), 1.0, |_| {});
    let l = b.losses();
    let updates = f64::from(last_record(&b).t_ms) * 1e-3 * 20_000.0 / 2.0;
    assert!(
        (l.updates_dropped as f64) > 0.95 * updates && (l.updates_dropped as f64) <= updates,
        "{l:?}, {updates} updates made"
    );
    assert_eq!(
        (l.updates_late, l.handoffs_dropped, l.frames_lost),
        (0, 0, 0),
        "{l:?}"
    );
    let report = power_up::report(&scenario(), &[("small queue", &b)]);
    let line = format!("losses: {} updates dropped", l.updates_dropped);
    assert!(report.contains(&line), "{report}");
}

/// θ̂ streamed, against what the control period had and the rotor: each record's θ̂ is
/// the estimate of the period whose sample was taken at `t_ms / 1000 - 1/f_pwm` (the
/// period its snapshot was taken in), in the motor's frame (the sensor's direction as
/// the alignment in force has it), in [0, 2π); in Run it follows the rotor at that
/// instant to within the estimate's error, modulo one sensor period, mounted either way.
/// (What stays between them besides the mounting is a constant of the sensor's frame,
/// the same either way round; pk-pk, as the emulator scores it, does not see it.)
#[test]
fn streamed_theta_is_the_estimate_at_the_records_instant_in_the_motor_frame() {
    for reversed in [false, true] {
        let mut sc = scenario();
        sc.file.sensor.mount_offset_deg = 70.0;
        sc.file.sensor.mount_reversed = reversed;
        let t_s = sc.sample_period_s();
        let mut rig = power_up::rig(&sc, SimFlash::new(RamFlash::default()), 1).unwrap();
        let n = f64::from(rig.plant.sensor.params.model.sensor_periods);
        let offset = rig.plant.sensor.params.mount.offset_rad;
        // Each period's sample instant, rotor angle, estimate (sensor's frame) and the
        // direction of the alignment in force (forward until the sweep measured it).
        let mut steps = Vec::new();
        let mut hook = |rig: &mut Rig, s: &Step| {
            let dir = if rig.command.alignment.reversed {
                -1.0
            } else {
                1.0
            };
            steps.push((s.truth.t_s, s.truth.theta_rad, s.estimate.theta_rad, dir))
        };
        let b = power_up::run_boot(&mut rig, &sc, 4.0, Some(&mut hook));
        assert_eq!(b.final_state, State::Run, "{:?}", b.transitions);
        // The magnet at `offset ± θ`: in the motor's frame, `θ ± offset`.
        let mount = if reversed { -offset } else { offset };
        let within_period = |e: f64| (n * e - TAU * (n * e / TAU).round()) / n;
        let mut errors = Vec::new();
        for r in b.records() {
            assert!((0.0..std::f32::consts::TAU).contains(&r.theta_rad), "{r:?}");
            // The period number t_ms·f/1000, the k-th step; its sample one period
            // before t_ms.
            let k = (f64::from(r.t_ms) * 1e-3 / t_s).round() as usize - 1;
            let (t, rotor, estimate, dir) = steps[k];
            assert!(
                (t - (f64::from(r.t_ms) * 1e-3 - t_s)).abs() < 1e-9,
                "{t} {r:?}"
            );
            let motor = (dir * f64::from(estimate)).rem_euclid(TAU);
            let d = (f64::from(r.theta_rad) - motor + 0.5 * TAU).rem_euclid(TAU) - 0.5 * TAU;
            assert!(d.abs() < 1e-6, "{d} at {r:?}");
            if r.state == State::Run {
                assert_eq!(dir, if reversed { -1.0 } else { 1.0 });
                errors.push(within_period(f64::from(r.theta_rad) - rotor - mount));
            }
        }
        assert!(errors.len() >= 50, "{}", errors.len());
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let spread = errors.iter().map(|e| (e - mean).abs()).fold(0.0, f64::max);
        eprintln!(
            "reversed {reversed}: {} records in Run, θ̂ - rotor {:.2} mrad ± {:.3} mrad",
            errors.len(),
            mean * 1e3,
            spread * 1e3
        );
        // A wrong frame (direction not undone) would spread over the whole period.
        assert!(spread < 0.5e-3, "{spread} rad");
    }
}

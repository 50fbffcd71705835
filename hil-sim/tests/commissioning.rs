//! The firmware's control period and supervisor commissioning the simulated drive:
//! alignment at any sensor mounting, a wire break in Run (ridden through, or the safe
//! state when it lasts), a store in Run. Every power-up that runs its tasks on time
//! streams no loss of any kind.

use calib_record::RamFlash;
use drive::commissioning::{Cause, State};
use drive::telemetry::{Event, Line};
use hil_sim::power_up::{self, Boot};
use hil_sim::rig::SimFlash;
use hil_sim::scenario::Scenario;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::f64::consts::TAU;

fn scenario(offset_deg: f64, reversed: bool) -> Scenario {
    let mut sc = Scenario::load("commissioning").unwrap();
    sc.file.sensor.mount_offset_deg = offset_deg;
    sc.file.sensor.mount_reversed = reversed;
    sc
}

/// The stream says nothing was lost, and it has records to say it with.
fn assert_no_loss(b: &Boot, what: &str) {
    assert!(b.records().count() > 10, "{what}: no records");
    let losses = b.losses();
    assert!(losses.is_none(), "{what}: {losses:?}");
}

/// One power-up on an erased flash, long enough for a Run window.
fn first_boot(sc: &Scenario, seconds: f64) -> Boot {
    let flash = SimFlash::new(RamFlash::default());
    power_up::boot(sc, flash, sc.file.seed, seconds, None)
        .unwrap()
        .0
}

/// ≥ 20 random mountings, each both ways: every run aligns, commissions, reaches Run and
/// holds the application's speed, with the torque per amp within 2 % of the run with
/// the sensor mounted at the rotor's zero.
#[test]
fn any_mounting_either_direction_commissions_with_full_torque_per_amp() {
    let aligned = first_boot(&scenario(0.0, false), 4.0);
    let reference = aligned.run_torque_per_amp.expect("aligned run reaches Run");
    assert!(reference > 0.97, "aligned torque per amp {reference}");
    let mut rng = ChaCha8Rng::seed_from_u64(2015);
    let mounts: Vec<(f64, bool)> = (0..20)
        .map(|_| rng.random_range(0.0..360.0))
        .flat_map(|deg| [(deg, false), (deg, true)])
        .collect();
    let results: Vec<(f64, bool, Boot)> = mounts
        .par_iter()
        .map(|&(deg, rev)| (deg, rev, first_boot(&scenario(deg, rev), 4.0)))
        .collect();
    let (mut worst, mut worst_angle): (f64, f64) = (1.0, 0.0);
    for (deg, rev, b) in &results {
        let what = format!("mount {deg:.1}° reversed {rev}: {:?}", b.transitions);
        assert_eq!(b.final_state, State::Run, "{what} cause {:?}", b.cause);
        assert_eq!(b.alignment.reversed, *rev, "{what}");
        let err = b.run_angle_error_e_rad.unwrap();
        worst_angle = worst_angle.max(err.abs());
        assert!(err.abs() < 0.02, "{what}: electrical angle error {err} rad");
        let speed = b.run_speed_rad_s.unwrap() / TAU;
        assert!((speed - 20.0).abs() < 0.2, "{what}: {speed} rev/s");
        let k = b.run_torque_per_amp.unwrap() / reference;
        worst = worst.min(k);
        assert!(k > 0.98, "{what}: torque per amp {k:.4} of the aligned run");
        assert_eq!(b.faulted_samples, 0, "{what}");
        assert_no_loss(b, &what);
    }
    eprintln!(
        "{} mountings: worst torque per amp {worst:.4} of the aligned run, worst electrical angle error {:.1} mrad",
        results.len(),
        worst_angle * 1e3
    );
}

/// Without the motor's identification, the controller told 4 pole pairs on a
/// 6-pole-pair motor: the sweep sees the sensor travel 4/6 of a period and refuses, by
/// name, before anything spins (with it, the count is found:
/// `tests/identification.rs`).
#[test]
fn a_wrong_pole_pair_count_is_refused_by_the_sweep_without_identification() {
    let mut sc = scenario(40.0, false);
    sc.file.motor.pole_pairs = 6;
    if let Some(c) = sc.file.commissioning.as_mut() {
        c.identify_motor = Some(false);
    }
    let flash = SimFlash::new(RamFlash::default());
    let mut rig = power_up::rig_with(&sc, flash, 1, |d| d.motor.pole_pairs = 4).unwrap();
    let b = power_up::run_boot(&mut rig, &sc, 2.0, None);
    assert_eq!(b.cause, Some(Cause::PolePairs), "{:?}", b.transitions);
    assert!(b.entered(State::SpinUp).is_none());
    let ratio = b.streamed.iter().find_map(|s| match s.line {
        Line::Event(Event::Aligned { ratio, .. }) => Some(ratio),
        _ => None,
    });
    // Refused before it is accepted: no alignment event.
    assert_eq!(ratio, None);
    assert_no_loss(&b, "wrong pole pairs");
}

/// Wire break in Run for 20 ms: the bridge is off from the faulted period on, the
/// core re-acquires by itself when the sensor comes back, the bridge re-arms and the
/// adaptation resumes; no safe state. A break that lasts beyond the supervisor's
/// `reacquire_timeout_s` ends in the safe state (`LossOfLock`: the lock was not
/// regained), and a restart clears it.
#[test]
fn a_wire_break_in_run_is_ridden_through_unless_it_lasts() {
    let timeout_s = drive::commissioning::Params::default().reacquire_timeout_s as f64;
    for break_s in [0.02, 0.3] {
        let sc = scenario(120.0, true);
        let flash = SimFlash::new(RamFlash::default());
        let healthy = sc.file.sensor.to_params().unwrap();
        // Both wires of the sensor's bridge open: X and Y at the amplifier's zero.
        let mut broken = healthy.clone();
        broken.model = mras_sim::SensorModel::ideal(2);
        broken.model.bx1 = 0.0;
        broken.model.by1 = 0.0;
        let (mut t_break, mut first_fault, mut back) = (None, None, None);
        let (mut rearmed, mut relocked) = (None, None);
        let mut revs_at_back = 0;
        let mut revs_later = None;
        let mut enabled_while_broken = 0u32;
        let mut restarted_at = None;
        let mut enabled_after_restart = 0u32;
        let mut run_from = None;
        let mut hook = |rig: &mut hil_sim::rig::Rig, s: &hil_sim::rig::Step| {
            let t = s.truth.t_s;
            let state = rig.supervisor().unwrap().state();
            if state == State::Run {
                run_from.get_or_insert(t);
            }
            // Well into Run: the slow tracking adapts (steady for its settling time).
            if t_break.is_none() && run_from.is_some_and(|r| t > r + 0.6) {
                t_break = Some(t);
                rig.plant.sensor = hil_sim::sensor::SensorSim::new(broken.clone(), 7).unwrap();
            }
            let Some(tb) = t_break else { return };
            if s.fault.is_some() && first_fault.is_none() {
                first_fault = Some(t);
                assert!(!s.output.enable, "the faulted period itself is off");
            }
            if back.is_none() && t > tb {
                enabled_while_broken += s.output.enable as u32;
            }
            if back.is_none() && t > tb + break_s {
                back = Some(t);
                revs_at_back = rig.adaptation().adapter().convergence().revs_adapted;
                rig.plant.sensor = hil_sim::sensor::SensorSim::new(healthy.clone(), 8).unwrap();
            }
            if let Some(tr) = back {
                if relocked.is_none() && rig.period.tracker().is_locked() {
                    relocked = Some(t - tr);
                }
                if rearmed.is_none() && s.output.enable {
                    rearmed = Some(t - tr);
                }
                if revs_later.is_none() && t > tr + 0.25 {
                    revs_later = Some(rig.adaptation().adapter().convergence().revs_adapted);
                }
            }
            if break_s > timeout_s && t > tb + break_s + 0.1 && restarted_at.is_none() {
                assert_eq!(rig.supervisor().unwrap().state(), State::Safe);
                restarted_at = Some(t);
                rig.supervisor_mut().unwrap().restart();
            }
            if restarted_at.is_some() {
                enabled_after_restart += s.output.enable as u32;
            }
        };
        let (b, _) = power_up::boot(&sc, flash, 3, 5.0, Some(&mut hook)).unwrap();
        let tb = t_break.expect("reached Run");
        let tf = first_fault.expect("the break faulted");
        assert!(
            tf - tb < 1e-4,
            "fault {tf} vs break {tb}: in the first period"
        );
        assert_eq!(enabled_while_broken, 0, "bridge on without a sensor");
        let fault = b.streamed.iter().find_map(|s| match s.line {
            Line::Event(Event::Fault { cause, state, .. }) => Some((s.t_s, cause, state)),
            _ => None,
        });
        assert_no_loss(&b, &format!("wire break {break_s} s"));
        if break_s < timeout_s {
            // Ridden through: locked again within a few ms of the sensor's return, the
            // bridge on again, the adaptation running again.
            assert_eq!(fault, None, "{:?}", b.transitions);
            assert_eq!(b.final_state, State::Run);
            let relocked = relocked.expect("locked again");
            let rearmed = rearmed.expect("bridge on again");
            eprintln!(
                "20 ms wire break at 20 rev/s in Run: locked {:.1} ms and the bridge on {:.1} ms \
                 after the sensor's return",
                relocked * 1e3,
                rearmed * 1e3
            );
            assert!(relocked < 5e-3 && rearmed < 5e-3, "{relocked} {rearmed}");
            let revs = revs_later.unwrap() - revs_at_back;
            assert!(revs >= 3, "{revs} revolutions adapted in the 0.25 s after");
            let run = b.run.as_ref().unwrap();
            assert!(
                run.raw_pk_pk_mrad / run.estimate_pk_pk_mrad > 100.0,
                "{run:?}"
            );
        } else {
            let (tf, cause, state) = fault.expect("safe state");
            assert_eq!(
                (cause, state),
                (Cause::Sensor(mras::Fault::LossOfLock), State::Run)
            );
            // The supervisor steps at 1 kHz: the timeout plus a step or two.
            assert!(
                tf - tb >= timeout_s && tf - tb < timeout_s + 3e-3,
                "safe {:.1} ms after the break",
                (tf - tb) * 1e3
            );
            assert!(
                enabled_after_restart > 1000,
                "{:?} {:?}",
                b.transitions,
                b.cause
            );
            assert_eq!(b.final_state, State::Run);
            assert!(b.loaded_from_flash);
        }
    }
}

/// The operator stores the tracked calibration in Run at 20 rev/s: the erase takes its
/// time, the control period runs through it, lock holds, the current stays the load's.
/// With the pages in the bank the code runs from, the same store stalls the CPU: the
/// timer keeps the last duties, a standing voltage vector on a spinning motor drives
/// the current past the drive's limit, and the drive trips or loses lock, or rides
/// through on the inverter's losses (its dead time takes about 1 V off the vector).
#[test]
fn a_store_in_run_at_speed_keeps_lock_unless_the_flash_stalls_the_cpu() {
    for stall in [false, true] {
        let sc = scenario(200.0, false);
        let i_max_a = sc.file.motor.i_max_a;
        let mut flash = SimFlash::new(RamFlash::default());
        flash.stall_cpu = false;
        let mut requested = None;
        // The largest phase current from the request on.
        let mut peak_a = 0f64;
        let mut hook = |rig: &mut hil_sim::rig::Rig, s: &hil_sim::rig::Step| {
            let t = s.truth.t_s;
            if requested.is_none() && rig.supervisor().unwrap().state() == State::Run && t > 3.0 {
                requested = Some(t);
                rig.flash_mut().unwrap().stall_cpu = stall;
                rig.supervisor_mut().unwrap().request_store();
            }
            if requested.is_some() {
                let i = rig.plant.phase_currents_a();
                peak_a = i.iter().fold(peak_a, |m, x| m.max(x.abs()));
            }
        };
        let (b, _) = power_up::boot(&sc, flash, 5, 4.0, Some(&mut hook)).unwrap();
        let t_req = requested.expect("reached Run");
        let stored: Vec<f64> = b
            .streamed
            .iter()
            .filter_map(|s| matches!(s.line, Line::Event(Event::Stored { .. })).then_some(s.t_s))
            .collect();
        if stall {
            // The timer keeps the last duties while the CPU stalls: a standing voltage
            // vector on a spinning motor, the over-current break, then lock lost.
            assert!(b.missed_periods > 500, "{}", b.missed_periods);
            eprintln!(
                "stalled store: {} missed periods, peak current {peak_a:.1} A, {:?}",
                b.missed_periods, b.cause
            );
            assert!(peak_a > i_max_a, "peak {peak_a:.1} A");
            assert!(
                matches!(
                    b.cause,
                    None | Some(Cause::OverCurrent | Cause::Sensor(mras::Fault::LossOfLock))
                ),
                "{:?}",
                b.cause
            );
        } else {
            assert!(peak_a < 0.5 * i_max_a, "peak {peak_a:.1} A");
            assert_eq!(b.missed_periods, 0);
            assert_eq!(b.final_state, State::Run, "{:?}", b.transitions);
            assert_eq!(b.faulted_samples, 0);
            assert_no_loss(&b, "store in Run");
            // Commissioning's store and the operator's; the latter took the erase time.
            assert_eq!(stored.len(), 2, "{stored:?}");
            let took = stored[1] - t_req;
            assert!(took >= hil_sim::rig::ERASE_S, "store took {took} s");
            let speed = b.run_speed_rad_s.unwrap() / TAU;
            assert!((speed - 20.0).abs() < 0.2, "{speed}");
        }
    }
}

/// A flash error during the commissioning's store: the safe state with its cause, the
/// flash error named in the stream, and the next power-up commissions again.
#[test]
fn a_store_that_hits_a_flash_error_ends_safe_with_its_cause() {
    let sc = scenario(10.0, false);
    let mut flash = SimFlash::new(RamFlash::default());
    flash.fail_next_program = true;
    let (b, flash) = power_up::boot(&sc, flash, 1, 3.5, None).unwrap();
    assert_eq!(b.final_state, State::Safe, "{:?}", b.transitions);
    assert_eq!(b.cause, Some(Cause::StoreFailed));
    assert!(b.streamed.iter().any(|s| matches!(
        s.line,
        Line::Event(Event::StoreFailed {
            reason: "ProgErr",
            ..
        })
    )));
    assert_no_loss(&b, "store failed");
    let (again, _) = power_up::boot(&sc, flash, 2, 0.5, None).unwrap();
    assert!(
        again.entered(State::Align).is_some(),
        "{:?}",
        again.transitions
    );
}

/// A bank from the data through the firmware's power-up: commissioning grows the bank
/// from the configured first stage (the stream names each new bank), verifies and stores
/// it; the next power-up installs the stored bank and runs on it.
#[test]
fn a_bank_from_the_data_is_commissioned_stored_and_loaded_again() {
    let mut sc = scenario(0.0, false);
    sc.file.core.set_paths(&mras::survey::FIRST_STAGE).unwrap();
    sc.file.core.paths_from_data = true;
    let flash = SimFlash::new(RamFlash::default());
    let (first, flash) = power_up::boot(&sc, flash, sc.file.seed, 6.0, None).unwrap();
    let what = format!("{:?} cause {:?}", first.transitions, first.cause);
    assert_eq!(first.final_state, State::Run, "{what}");
    assert!(!first.loaded_from_flash);
    assert_no_loss(&first, "bank from the data");
    let banks = |b: &Boot| -> Vec<mras::Bank> {
        b.streamed
            .iter()
            .filter_map(|s| match s.line {
                Line::Paths(bank) => Some(bank),
                _ => None,
            })
            .collect()
    };
    let grown = banks(&first);
    let bank = *grown.last().expect("the stream names the grown bank");
    assert!(bank.as_slice().len() > 2, "{bank:?}");
    assert!(bank.as_slice().starts_with(&mras::survey::FIRST_STAGE));
    let named: Vec<String> = first.coefficients.iter().map(|c| c.0.clone()).collect();
    let want: Vec<String> = drive::telemetry::bank_names(bank.as_slice())
        .split(',')
        .map(String::from)
        .collect();
    assert_eq!(named, want, "the stored coefficients are the grown bank's");
    let first_run = first
        .run
        .as_ref()
        .expect("a Run window")
        .estimate_pk_pk_mrad;

    let (second, _) = power_up::boot(&sc, flash, sc.file.seed + 1, 2.0, None).unwrap();
    let what = format!("{:?} cause {:?}", second.transitions, second.cause);
    assert_eq!(second.final_state, State::Run, "{what}");
    assert!(second.loaded_from_flash, "{what}");
    assert_no_loss(&second, "stored bank loaded");
    assert_eq!(
        banks(&second),
        vec![bank],
        "the install names the stored bank once"
    );
    let second_run = second
        .run
        .as_ref()
        .expect("a Run window")
        .estimate_pk_pk_mrad;
    let raw = second.run.as_ref().unwrap().raw_pk_pk_mrad;
    eprintln!(
        "bank {:?}: Run {first_run:.3} mrad pk-pk after commissioning, {second_run:.3} after \
         loading it (raw {raw:.1})",
        bank.as_slice()
    );
    assert!(second_run < raw / 20.0, "{second_run} of raw {raw}");
}

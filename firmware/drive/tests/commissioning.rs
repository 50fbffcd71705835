//! Every transition and every fault path of the power-up sequence.

use calib_record::Alignment;
use drive::commissioning::*;
use std::cell::Cell;

mod common;
use common::{Drive, Rotor, AMPS_PER_ACCEL, AMPS_PER_SPEED, FLUX_WB};
use drive::ident::{IdentError, IdentStatus, Identified};
use drive::telemetry::{Fault, SweepResult};

const DT: f32 = 1e-3;

fn params() -> Params {
    Params::default()
}

/// Inputs of a healthy drive at the commissioning speed.
fn healthy() -> Inputs {
    Inputs {
        dt_s: DT,
        omega_rad_s: params().speed_rad_s,
        residual_max_rad: 1e-4,
        ..Inputs::default()
    }
}

/// Step until `state` is reached (at most `max_s`), with inputs from `f`.
fn run_until(
    c: &mut Commissioning,
    state: State,
    max_s: f32,
    mut f: impl FnMut(&Commissioning) -> Inputs,
) {
    let mut t = 0.0;
    while c.state() != state {
        let i = f(c);
        c.step(&i);
        t += i.dt_s;
        assert!(
            t <= max_s,
            "{state:?} not reached in {max_s} s, stuck in {:?}",
            c.state()
        );
    }
}

/// A sweep with 4 pole pairs in force on N = 2 in which the sensor travelled `ratio`
/// of a period.
fn swept(ratio: f32) -> Option<SweepResult> {
    swept_at(4.0, ratio)
}

/// A sweep with `in_force` pole pairs in force on N = 2, as `drive::align` reports it.
fn swept_at(in_force: f32, ratio: f32) -> Option<SweepResult> {
    let pole_pairs = in_force / ratio.max(1e-6);
    let whole = ((pole_pairs / 2.0).round().max(1.0) * 2.0).min(u16::MAX as f32);
    Some(SweepResult {
        ratio,
        pole_pairs,
        whole_pole_pairs: whole as u16,
        sensor_periods: 2,
        alignment: Alignment {
            offset_e_rad: 0.4,
            reversed: true,
            pole_pairs: in_force as u16,
        },
    })
}

/// What an identification found.
const IDENTIFIED: Identified = Identified {
    r_ohm: 0.3,
    ld_h: 0.5e-3,
    lq_h: 0.5e-3,
    v_inverter_v: 0.4,
};

thread_local! {
    /// The rotor behind [`hardware`] ([`common::Rotor`]): at rest until the spin-up.
    static ROTOR: Cell<Rotor> = Cell::new(Rotor::default());
}

/// `i` with the rotor's motion of the step `c` is about to take.
fn with_rotor(c: &Commissioning, mut i: Inputs) -> Inputs {
    let mut r = ROTOR.get();
    match (c.state(), c.outputs().setpoint) {
        (State::CheckSensor, _) => r = Rotor::default(),
        (_, Setpoint::Speed { omega_rad_s }) => r.step(i.dt_s, Drive::Speed(omega_rad_s)),
        (_, Setpoint::Torque { iq_a }) => r.step(i.dt_s, Drive::Torque(iq_a)),
        (_, Setpoint::Coast { .. }) => r.step(i.dt_s, Drive::Coast),
        _ => r.step(i.dt_s, Drive::Hold),
    }
    ROTOR.set(r);
    i.theta_rad = r.theta_rad;
    i.omega_rad_s = r.omega_rad_s;
    i.iq_integral_a_s = r.iq_integral_a_s;
    i.flux_angle_wb_rad = r.flux_angle_wb_rad;
    i
}

/// A responsive hardware layer: no calibration in flash, the identification and the
/// sweep done at once, store succeeds, converges as soon as adaptation runs; the rotor
/// as [`ROTOR`] says.
fn hardware(c: &Commissioning) -> Inputs {
    let mut i = with_rotor(c, healthy());
    if c.state() == State::Identify {
        i.ident = IdentStatus::Done(IDENTIFIED);
    }
    i.load = LoadStatus::Unavailable;
    i.store = StoreStatus::Done;
    i.converged = c.state() == State::Adapt;
    i.sweep = (c.state() == State::Sweep).then_some(swept(1.02)).flatten();
    i
}

fn drive_to(state: State) -> Commissioning {
    let mut c = Commissioning::new(params());
    run_until(&mut c, state, 10.0, hardware);
    c
}

#[test]
fn full_sequence_without_calibration() {
    let mut c = Commissioning::new(params());
    let mut seen = vec![c.state()];
    let mut t = 0.0;
    while c.state() != State::Run {
        let o = c.step(&hardware(&c));
        t += DT;
        if *seen.last().unwrap() != c.state() {
            seen.push(c.state());
        }
        // PWM is never on before the sensor was checked and the flash asked.
        if matches!(c.state(), State::CheckSensor | State::LoadCalibration) {
            assert!(!o.pwm_enabled());
        }
        assert!(t < 10.0);
    }
    use State::*;
    assert_eq!(
        seen,
        [
            CheckSensor,
            LoadCalibration,
            Identify,
            Align,
            Sweep,
            SpinUp,
            Adapt,
            Verify,
            Motion,
            Store,
            Run
        ]
    );
    assert!(!c.calibration_loaded());
    assert_eq!(c.cause(), None);
}

/// A stored calibration: the identification on the rotor's d axis (nothing moves), then
/// Run, with no alignment, sweep or adaptation.
#[test]
fn stored_calibration_skips_commissioning() {
    let mut c = Commissioning::new(params());
    run_until(&mut c, State::LoadCalibration, 1.0, |_| healthy());
    // Pending: stays, asking.
    for _ in 0..10 {
        let o = c.step(&healthy());
        assert_eq!(o.request, Request::LoadCalibration);
        assert_eq!(c.state(), State::LoadCalibration);
    }
    let o = c.step(&Inputs {
        load: LoadStatus::Loaded,
        ..healthy()
    });
    assert_eq!(c.state(), State::Identify);
    assert_eq!(
        o.setpoint,
        Setpoint::Identify {
            current_a: params().identify_current_a,
            on_rotor: true
        }
    );
    assert_eq!(o.adaptation, Adaptation::Frozen);
    let o = c.step(&Inputs {
        ident: IdentStatus::Done(IDENTIFIED),
        ..healthy()
    });
    assert_eq!(c.state(), State::Run);
    assert!(c.calibration_loaded());
    assert_eq!(o.setpoint, Setpoint::Application);
    // Tracking once ω̂'s low-pass, started at rest, has caught up with it.
    assert_eq!(o.adaptation, Adaptation::Frozen);
    for _ in 0..(0.5 / DT) as usize {
        c.step(&healthy());
    }
    assert_eq!(c.outputs().adaptation, Adaptation::Tracking);
}

/// A hard speed change in Run (the application's first setpoint after commissioning)
/// moves ε by more than the transient gate lets pass unseen: Run tracks once the speed
/// has been steady for `speed_settle_s` after its entry, and then pauses while ω̂ is
/// more than `speed_tolerance` from its low-pass, judged on locked steps only (a
/// dropout ridden through resumes tracking with the lock).
#[test]
fn run_tracks_only_at_a_steady_speed() {
    let mut c = drive_to(State::Run);
    let w = params().speed_rad_s;
    let step_at = |c: &mut Commissioning, omega_rad_s: f32, s: f32| {
        for _ in 0..(s / DT).round() as usize {
            c.step(&Inputs {
                omega_rad_s,
                ..healthy()
            });
        }
        c.outputs().adaptation
    };
    assert_eq!(step_at(&mut c, w, 0.5), Adaptation::Tracking);
    // A 30 % drop: frozen at once, until the 50 ms low-pass is within 10 % of it.
    assert_eq!(step_at(&mut c, 0.7 * w, 0.001), Adaptation::Frozen);
    assert_eq!(step_at(&mut c, 0.7 * w, 0.03), Adaptation::Frozen);
    assert_eq!(step_at(&mut c, 0.7 * w, 0.2), Adaptation::Tracking);
    // Unlocked steps (a dropout) with a wild ω̂ neither stop nor start the tracking.
    for _ in 0..10 {
        c.step(&Inputs {
            omega_rad_s: 0.0,
            locked: false,
            ..healthy()
        });
    }
    assert_eq!(c.state(), State::Run);
    assert_eq!(c.outputs().adaptation, Adaptation::Tracking);
}

/// Below half the commissioning speed a torque ripple moves the rotor 4x or more than
/// while commissioning: Run holds the coefficients there, and tracks again above.
#[test]
fn run_tracks_only_at_half_the_commissioning_speed_or_more() {
    let mut c = drive_to(State::Run);
    let at = |c: &mut Commissioning, share: f32| {
        // 0.5 s: ten times the speed filter's time constant.
        for _ in 0..(0.5 / DT) as usize {
            c.step(&Inputs {
                omega_rad_s: share * params().speed_rad_s,
                ..healthy()
            });
        }
        c.outputs().adaptation
    };
    assert_eq!(at(&mut c, 1.0), Adaptation::Tracking);
    assert_eq!(at(&mut c, -0.6), Adaptation::Tracking, "either direction");
    assert_eq!(at(&mut c, 0.4), Adaptation::Frozen);
    assert_eq!(at(&mut c, 0.05), Adaptation::Frozen);
    assert_eq!(at(&mut c, 0.55), Adaptation::Tracking);
    assert_eq!(c.state(), State::Run);
}

/// The torque ripple is learned in Run where the coefficients are held (below half the
/// commissioning speed) and the speed is steady, and only when asked for.
#[test]
fn run_learns_the_torque_ripple_where_it_holds_the_coefficients() {
    let at = |c: &mut Commissioning, share: f32, s: f32| {
        for _ in 0..(s / DT).round() as usize {
            c.step(&Inputs {
                omega_rad_s: share * params().speed_rad_s,
                ..healthy()
            });
        }
        c.outputs().learn_ripple
    };
    let mut c = Commissioning::new(Params {
        learn_torque_ripple: true,
        ..params()
    });
    assert!(!c.outputs().learn_ripple);
    run_until(&mut c, State::Run, 10.0, hardware);
    assert!(!at(&mut c, 1.0, 0.5), "tracking at the commissioning speed");
    // Braked to 5 %: not while the speed settles, then learning.
    assert!(!at(&mut c, 0.05, 0.01));
    assert!(at(&mut c, 0.05, 0.5));
    assert_eq!(c.outputs().adaptation, Adaptation::Frozen);
    // A step of the speed pauses it.
    assert!(!at(&mut c, 0.08, 0.001));
    assert!(at(&mut c, 0.08, 0.5));
    // Off by default.
    let mut d = drive_to(State::Run);
    assert!(!at(&mut d, 0.05, 0.5));
}

#[test]
fn slow_tracking_can_be_disabled() {
    let mut c = Commissioning::new(Params {
        slow_tracking: false,
        ..params()
    });
    run_until(&mut c, State::Run, 10.0, hardware);
    assert_eq!(c.outputs().adaptation, Adaptation::Frozen);
}

#[test]
fn outputs_per_state() {
    use State::*;
    for (state, pwm, adaptation, request) in [
        (
            LoadCalibration,
            false,
            Adaptation::Frozen,
            Request::LoadCalibration,
        ),
        (Identify, true, Adaptation::Frozen, Request::None),
        (Align, true, Adaptation::Frozen, Request::None),
        (Sweep, true, Adaptation::Frozen, Request::None),
        (SpinUp, true, Adaptation::Frozen, Request::None),
        (Adapt, true, Adaptation::Commissioning, Request::None),
        (Verify, true, Adaptation::Frozen, Request::None),
        // The control period runs through the flash erase: the drive holds its speed.
        (Store, true, Adaptation::Frozen, Request::StoreCalibration),
        // Frozen on entry: Run tracks once the speed has been steady
        // (`run_tracks_only_at_a_steady_speed`).
        (Run, true, Adaptation::Frozen, Request::None),
    ] {
        let o = drive_to(state).outputs();
        assert_eq!(o.pwm_enabled(), pwm, "{state:?}");
        assert_eq!(o.adaptation, adaptation, "{state:?}");
        assert_eq!(o.request, request, "{state:?}");
    }
    assert!(
        matches!(drive_to(Identify).outputs().setpoint, Setpoint::Identify { current_a, on_rotor: false } if current_a > 0.0)
    );
    assert!(
        matches!(drive_to(Align).outputs().setpoint, Setpoint::Align { current_a } if current_a > 0.0)
    );
    assert!(
        matches!(drive_to(Sweep).outputs().setpoint, Setpoint::Sweep { current_a, duration_s } if current_a > 0.0 && duration_s > 0.0)
    );
    // The spin-up starts with its torque probe at a quarter of the alignment's current
    // (the rotor travels half a radian), then its speed setpoint ramps from zero.
    let mut c = drive_to(SpinUp);
    let probe = Setpoint::Torque {
        iq_a: PROBE_SHARE * params().align_current_a,
    };
    let mut probe_s = 0.0;
    while c.outputs().setpoint == probe {
        c.step(&hardware(&c));
        probe_s += DT;
        assert!(probe_s <= drive::spin::PROBE_TIMEOUT_S + DT);
    }
    let w = params().speed_rad_s;
    assert!(
        matches!(c.outputs().setpoint, Setpoint::Speed { omega_rad_s } if omega_rad_s > 0.0 && omega_rad_s < 0.01 * w),
        "{:?} after the probe",
        c.outputs().setpoint
    );
    // Only the sensor check measures the current sensors' zero (bridge off).
    assert!(Commissioning::new(params()).outputs().calibrate_currents);
    assert!(!drive_to(Align).outputs().calibrate_currents);
}

#[test]
fn the_sensor_check_waits_for_the_current_zero_and_refuses_a_broken_one() {
    let mut c = Commissioning::new(params());
    let waiting = Inputs {
        currents_ready: false,
        ..healthy()
    };
    for _ in 0..(3.0 * params().check_s / DT) as usize {
        c.step(&waiting);
    }
    assert_eq!(c.state(), State::CheckSensor);
    run_until(&mut c, State::Safe, 1.0, |_| waiting);
    assert_eq!(c.cause(), Some(Cause::Timeout(State::CheckSensor)));

    let mut c = Commissioning::new(params());
    c.step(&Inputs {
        currents_implausible: true,
        ..healthy()
    });
    assert_eq!(c.cause(), Some(Cause::CurrentSensor));
}

#[test]
fn the_sweep_checks_rotation_and_pole_pairs() {
    // 4 pole pairs in force on N = 2: the travel gives 4/ratio, within 0.7 of 4 on.
    for (ratio, cause) in [
        (0.0, Some(Cause::NoRotation)),
        // 23.5 pole pairs: beyond `max_pole_pairs` (16) and its tolerance.
        (0.17, Some(Cause::NoRotation)),
        // 3 and 5: half-way to a count N divides, once the one in force was swept
        // again... and again.
        (4.0 / 3.0, Some(Cause::PolePairs)),
        // 4 and a rotor that rings: on.
        (0.87, None),
        (1.2, None),
    ] {
        let mut c = drive_to(State::Sweep);
        for _ in 0..MAX_SWEEPS {
            c.step(&Inputs {
                sweep: swept(ratio),
                ..healthy()
            });
            if c.state() == State::Align {
                run_until(&mut c, State::Sweep, 1.0, |_| healthy());
            }
        }
        assert_eq!(c.cause(), cause, "ratio {ratio}");
        if cause.is_none() {
            assert_eq!(c.state(), State::SpinUp);
        }
    }
    // No result: waits, then times out.
    let mut c = drive_to(State::Sweep);
    let p = params();
    run_until(&mut c, State::Safe, 3.0 * p.sweep_s + 1.1, |_| healthy());
    assert_eq!(c.cause(), Some(Cause::Timeout(State::Sweep)));
}

/// Another pole-pair count than the one in force (2, 6, 8 or 16 on a drive configured
/// for 4): aligned and swept again with it in force, then on once a sweep confirms the
/// count in force; at most `MAX_SWEEPS`, and never the same count twice. Without the
/// motor's identification the configured count is a requirement.
#[test]
fn another_pole_pair_count_is_aligned_and_swept_again() {
    let sweep = |c: &mut Commissioning, r: Option<SweepResult>| {
        c.step(&Inputs {
            sweep: r,
            ..healthy()
        });
        if c.state() == State::Align {
            run_until(c, State::Sweep, 1.0, |_| healthy());
        }
    };
    for p_true in [2.0f32, 6.0, 8.0, 16.0] {
        // Found at once.
        let mut c = drive_to(State::Sweep);
        sweep(&mut c, swept(4.0 / p_true));
        assert_eq!(c.state(), State::Sweep, "p {p_true}");
        sweep(&mut c, swept_at(p_true, 0.98));
        assert_eq!(c.state(), State::SpinUp, "p {p_true}");
        // The first sweep's estimate one count off (not the one in force): found by
        // the third.
        let off = if p_true < 16.0 {
            p_true + 2.0
        } else {
            p_true - 2.0
        };
        if off == 4.0 {
            continue;
        }
        let mut c = drive_to(State::Sweep);
        sweep(&mut c, swept(4.0 / off));
        sweep(&mut c, swept_at(off, off / p_true));
        assert_eq!(c.state(), State::Sweep, "p {p_true}");
        sweep(&mut c, swept_at(p_true, 1.0));
        assert_eq!(c.state(), State::SpinUp, "p {p_true}");
    }
    // Three sweeps that each find another count: refused.
    let mut c = drive_to(State::Sweep);
    for in_force in [4.0, 6.0, 8.0] {
        sweep(&mut c, swept_at(in_force, in_force / (in_force + 2.0)));
    }
    assert_eq!(c.cause(), Some(Cause::PolePairs));
    // The count in force found again, or the one swept before: refused at once.
    let mut c = drive_to(State::Sweep);
    sweep(&mut c, swept(4.0 / 6.0));
    sweep(&mut c, swept_at(6.0, 1.2));
    assert_eq!(c.cause(), Some(Cause::PolePairs));
    let mut c = drive_to(State::Sweep);
    sweep(&mut c, swept(4.0 / 2.9));
    assert_eq!(c.state(), State::Sweep);
    sweep(&mut c, swept_at(2.0, 2.0 / 3.1));
    assert_eq!(c.cause(), Some(Cause::PolePairs));
    let mut c = Commissioning::new(Params {
        identify_motor: false,
        ..params()
    });
    run_until(&mut c, State::Sweep, 10.0, hardware);
    c.step(&Inputs {
        sweep: swept(4.0 / 6.0),
        ..healthy()
    });
    assert_eq!(c.cause(), Some(Cause::PolePairs));
}

#[test]
fn a_refused_load_ends_safe() {
    let mut c = Commissioning::new(params());
    run_until(&mut c, State::LoadCalibration, 1.0, |_| healthy());
    c.step(&Inputs {
        load: LoadStatus::Refused,
        ..healthy()
    });
    assert_eq!(c.cause(), Some(Cause::LoadRefused));
}

#[test]
fn sensor_check_waits_its_time() {
    let mut c = Commissioning::new(params());
    let steps = (params().check_s / DT) as usize - 2;
    for _ in 0..steps {
        c.step(&healthy());
    }
    assert_eq!(c.state(), State::CheckSensor);
}

#[test]
fn every_fault_in_every_state_ends_safe_with_its_cause() {
    use State::*;
    let faults = [
        Fault::Sensor(mras::Fault::NonFiniteInput),
        Fault::Sensor(mras::Fault::SensorLost),
        Fault::Sensor(mras::Fault::SensorSaturated),
        Fault::Sensor(mras::Fault::LossOfLock),
        Fault::Sensor(mras::Fault::NumericalOverflow),
        Fault::AdcOutOfRange,
        Fault::OverCurrent,
    ];
    for state in [
        CheckSensor,
        LoadCalibration,
        Identify,
        Align,
        Sweep,
        SpinUp,
        Adapt,
        Verify,
        Motion,
        Store,
        Run,
    ] {
        for f in faults {
            let mut c = drive_to(state);
            let o = c.step(&Inputs {
                fault: Some(f),
                ..hardware(&c)
            });
            assert_eq!(c.state(), Safe, "{state:?} {f:?}");
            assert_eq!(c.cause(), Some(Cause::from(f)));
            assert_eq!(o.setpoint, Setpoint::Off);
        }
        for dt in [f32::NAN, f32::INFINITY, -1e-3] {
            let mut c = drive_to(state);
            c.step(&Inputs {
                dt_s: dt,
                ..hardware(&c)
            });
            assert_eq!(c.cause(), Some(Cause::BadInput), "{state:?} dt {dt}");
        }
    }
}

#[test]
fn spin_up_timeout_and_settling() {
    let p = params();
    let mut c = drive_to(State::SpinUp);
    // In the band, out of it, in again: settling restarts.
    let mut i = hardware(&c);
    for _ in 0..((p.speed_settle_s / DT) as usize - 30) {
        c.step(&i);
    }
    // Out of the band for 0.1 s (twice the speed filter's time constant).
    i.omega_rad_s = 0.5 * p.speed_rad_s;
    for _ in 0..100 {
        c.step(&i);
    }
    i.omega_rad_s = p.speed_rad_s;
    for _ in 0..10 {
        c.step(&i);
    }
    assert_eq!(
        c.state(),
        State::SpinUp,
        "settling must restart after leaving the band"
    );
    // Never reaching speed: timeout, counted from the torque probe's end (a rotor that
    // does not turn holds the probe to its own limit).
    let mut c = drive_to(State::SpinUp);
    let slow = Inputs {
        omega_rad_s: 0.2 * p.speed_rad_s,
        ..hardware(&c)
    };
    let limit_s = drive::spin::PROBE_TIMEOUT_S + p.spin_up_timeout_s;
    for _ in 0..((limit_s - 0.02) / DT) as usize {
        c.step(&slow);
    }
    assert_eq!(c.state(), State::SpinUp);
    run_until(&mut c, State::Safe, 0.03, |_| slow);
    assert_eq!(c.cause(), Some(Cause::Timeout(State::SpinUp)));
}

#[test]
fn speed_ripple_of_the_uncorrected_sensor_does_not_block_spin_up() {
    // ω̂ on an uncorrected sensor: ±35 % ripple at 40 Hz around the target.
    let p = params();
    let mut c = drive_to(State::SpinUp);
    let mut t = 0.0f32;
    while c.state() == State::SpinUp {
        let w = p.speed_rad_s * (1.0 + 0.35 * libm::sinf(core::f32::consts::TAU * 40.0 * t));
        c.step(&Inputs {
            omega_rad_s: w,
            ..with_rotor(&c, healthy())
        });
        t += DT;
        assert!(t < 1.0, "spin-up never settled");
    }
    assert_eq!(c.state(), State::Adapt);
}

#[test]
fn adapt_timeout() {
    let p = params();
    let mut c = drive_to(State::Adapt);
    run_until(&mut c, State::Safe, p.adapt_timeout_s + 0.1, |_| healthy());
    assert_eq!(c.cause(), Some(Cause::Timeout(State::Adapt)));
}

/// Verify judges the residual's mean over `verify_s`: spikes to 1.5x the limit with a
/// mean of 0.8x pass, a mean of 1.1x fails at the end, a gross residual (3x) or NaN at
/// once.
#[test]
fn verify_judges_the_residuals_mean_and_fails_at_once_on_a_gross_one() {
    let p = params();
    let limit = p.verify_residual_rad;
    let spiky = |k: u32| if k % 2 == 0 { 1.5 } else { 0.1 } * limit;
    for (what, residual, passes) in [
        ("spikes, mean 0.8x", &spiky as &dyn Fn(u32) -> f32, true),
        ("mean 1.1x", &|_| 1.1 * limit, false),
    ] {
        let mut c = drive_to(State::Verify);
        let mut k = 0;
        while c.state() == State::Verify {
            c.step(&Inputs {
                residual_max_rad: residual(k),
                ..hardware(&c)
            });
            k += 1;
        }
        let verified = c.state() == State::Motion;
        assert_eq!(verified, passes, "{what}: {:?}", c.cause());
        if !passes {
            assert_eq!(c.cause(), Some(Cause::VerifyFailed), "{what}");
            assert!(k as f32 * DT >= p.verify_s, "{what}: judged at the end");
        }
    }
    for r in [VERIFY_GROSS * limit, f32::NAN] {
        let mut c = drive_to(State::Verify);
        c.step(&Inputs {
            residual_max_rad: r,
            ..hardware(&c)
        });
        assert_eq!(c.cause(), Some(Cause::VerifyFailed), "{r}");
    }
}

#[test]
fn store_waits_then_fails_or_succeeds() {
    let mut c = drive_to(State::Store);
    for _ in 0..100 {
        c.step(&healthy()); // store Pending
    }
    assert_eq!(c.state(), State::Store);
    c.step(&Inputs {
        store: StoreStatus::Failed,
        ..healthy()
    });
    assert_eq!(c.cause(), Some(Cause::StoreFailed));
}

#[test]
fn safe_is_sticky_until_restart_and_boot_faults_force_it() {
    let mut c = drive_to(State::Adapt);
    c.step(&Inputs {
        fault: Some(Fault::OverCurrent),
        ..healthy()
    });
    for _ in 0..100 {
        let o = c.step(&hardware(&c));
        assert_eq!(o.setpoint, Setpoint::Off);
    }
    assert_eq!(c.state(), State::Safe);
    c.restart();
    assert_eq!((c.state(), c.cause()), (State::CheckSensor, None));

    for cause in [Cause::Watchdog, Cause::HardFault, Cause::Panic] {
        let mut c = Commissioning::new(params());
        c.force_safe(cause);
        assert_eq!(c.state(), State::Safe);
        c.step(&healthy());
        assert_eq!((c.state(), c.cause()), (State::Safe, Some(cause)));
    }
}

/// In Run the control period rides through sensor faults; the sequence goes to the safe
/// state only when the estimate stays unlocked for `reacquire_timeout_s`, and a lock
/// regained before that resets the clock. Outside Run nothing rides through.
#[test]
fn run_rides_through_an_unlocked_estimate_for_the_timeout_only() {
    let mut c = Commissioning::new(params());
    assert!(!c.outputs().reacquire);
    run_until(&mut c, State::Run, 10.0, hardware);
    assert!(c.outputs().reacquire);
    let unlocked = |c: &Commissioning| Inputs {
        locked: false,
        ..hardware(c)
    };
    let timeout_steps = (params().reacquire_timeout_s / DT).round() as u32;
    // Unlocked for all but the last step of the timeout, then locked again: no fault.
    for _ in 0..timeout_steps - 1 {
        c.step(&unlocked(&c));
    }
    c.step(&hardware(&c));
    assert_eq!(c.state(), State::Run);
    // Unlocked from then on: safe at the timeout (within a step: the time is summed in
    // f32), with the lock loss as cause.
    for k in 0..timeout_steps - 1 {
        c.step(&unlocked(&c));
        assert_eq!(c.state(), State::Run, "step {k}");
    }
    c.step(&unlocked(&c));
    c.step(&unlocked(&c));
    assert_eq!(c.state(), State::Safe);
    assert_eq!(c.cause(), Some(Cause::Sensor(mras::Fault::LossOfLock)));
    assert!(!c.outputs().reacquire);
}

/// Hardware for a refined commissioning: ω̂ follows the setpoint, the bank converges
/// whenever adaptation runs, and the refined coefficients' install answers `refine`.
fn refining(refine: RefineStatus) -> impl Fn(&Commissioning) -> Inputs {
    move |c| {
        let o = c.outputs();
        let mut i = hardware(c);
        if let Setpoint::Speed { omega_rad_s } = o.setpoint {
            i.omega_rad_s = omega_rad_s;
        }
        i.converged = o.adaptation == Adaptation::Commissioning;
        i.refine = refine;
        i
    }
}

#[test]
fn a_refinement_adapts_on_then_verifies_the_installed_mean() {
    let p = Params {
        refine_s: 0.5,
        ..params()
    };
    let mut c = Commissioning::new(p);
    run_until(&mut c, State::Refine, 10.0, refining(RefineStatus::Pending));
    let o = c.outputs();
    assert_eq!(o.adaptation, Adaptation::Commissioning, "adapting on");
    assert_eq!(c.refine_index(), 0);
    // The whole refinement, then Verify asking for the install.
    let mut t = 0.0;
    while c.state() == State::Refine {
        c.step(&refining(RefineStatus::Pending)(&c));
        t += DT;
    }
    assert!((t - p.refine_s).abs() < 2.0 * DT, "refined for {t} s");
    assert_eq!(c.state(), State::Verify);
    // Until the refined coefficients are in force: frozen, asking, not measuring the
    // offset shift and not counting the verification time.
    for _ in 0..(2.0 * p.verify_s / DT) as usize {
        let o = c.step(&refining(RefineStatus::Pending)(&c));
        assert_eq!(o.request, Request::InstallRefined);
        assert_eq!(o.adaptation, Adaptation::Frozen);
        assert!(!o.measure_shift);
    }
    assert_eq!(c.state(), State::Verify);
    let o = c.step(&refining(RefineStatus::Installed)(&c));
    assert_eq!(o.request, Request::None);
    assert!(o.measure_shift);
    run_until(&mut c, State::Run, 10.0, refining(RefineStatus::Installed));
}

#[test]
fn a_second_speed_is_reached_converged_and_refined_before_the_install() {
    let p = Params {
        refine_s: 0.3,
        second_speed_ratio: 2.0,
        ..params()
    };
    let mut c = Commissioning::new(p);
    let mut seen = vec![];
    while c.state() != State::Verify {
        let o = c.step(&refining(RefineStatus::Pending)(&c));
        if seen.last().map(|&(s, _, _)| s) != Some(c.state()) {
            seen.push((c.state(), c.refine_index(), o.setpoint));
        }
        assert!(seen.len() < 20);
    }
    let speed = |omega_rad_s| Setpoint::Speed { omega_rad_s };
    let w = p.speed_rad_s;
    assert_eq!(
        seen[seen.len() - 5..],
        [
            (State::Adapt, 0, speed(w)),
            (State::Refine, 0, speed(w)),
            (State::SecondSpeed, 1, speed(2.0 * w)),
            (State::Refine, 1, speed(2.0 * w)),
            (State::Verify, 2, speed(2.0 * w)),
        ]
    );
    run_until(&mut c, State::Run, 10.0, refining(RefineStatus::Installed));
}

#[test]
fn a_second_speed_never_reached_times_out() {
    let p = Params {
        refine_s: 0.3,
        second_speed_ratio: 2.0,
        ..params()
    };
    let mut c = Commissioning::new(p);
    run_until(
        &mut c,
        State::SecondSpeed,
        10.0,
        refining(RefineStatus::Pending),
    );
    // The drive stays at the first speed (voltage limit): never settled there.
    run_until(&mut c, State::Safe, 10.0, |c| Inputs {
        converged: true,
        omega_rad_s: p.speed_rad_s,
        ..hardware(c)
    });
    assert_eq!(c.cause(), Some(Cause::Timeout(State::SecondSpeed)));
}

#[test]
fn a_refinement_that_fails_ends_in_the_safe_state() {
    let p = Params {
        refine_s: 0.2,
        ..params()
    };
    let mut c = Commissioning::new(p);
    run_until(&mut c, State::Safe, 10.0, refining(RefineStatus::Failed));
    assert_eq!(c.cause(), Some(Cause::RefineFailed));
    assert!(!c.outputs().pwm_enabled());
}

#[test]
fn refinement_settings_are_validated() {
    assert_eq!(params().validate(), Ok(()));
    let bad = [
        Params {
            refine_s: -1.0,
            ..params()
        },
        Params {
            refine_s: f32::NAN,
            ..params()
        },
        Params {
            refine_s: 1.0,
            second_speed_ratio: 1.2,
            ..params()
        },
        Params {
            second_speed_ratio: 2.0,
            ..params()
        },
    ];
    for (p, field) in bad.iter().zip([
        "refine_s",
        "refine_s",
        "second_speed_ratio",
        "second_speed_ratio",
    ]) {
        assert_eq!(p.validate().map_err(|(f, _)| f), Err(field), "{p:?}");
    }
    let ok = Params {
        refine_s: 1.0,
        second_speed_ratio: 2.0,
        ..params()
    };
    assert_eq!(ok.validate(), Ok(()));
}

/// A failed identification ends safe with its own name; one that never ends, with a
/// timeout; neither stores anything (nothing past Identify runs).
#[test]
fn a_failed_or_stalled_identification_ends_safe_by_name() {
    for e in [
        IdentError::CurrentSign,
        IdentError::CurrentNotReached,
        IdentError::OverCurrent,
        IdentError::Unsettled,
        IdentError::OutOfRange,
    ] {
        let mut c = drive_to(State::Identify);
        let o = c.step(&Inputs {
            ident: IdentStatus::Failed(e),
            ..healthy()
        });
        assert_eq!(c.state(), State::Safe);
        assert_eq!(c.cause(), Some(Cause::Identify(e)));
        assert_eq!(o.setpoint, Setpoint::Off);
        assert_eq!(o.request, Request::None);
    }
    let mut c = drive_to(State::Identify);
    run_until(&mut c, State::Safe, IDENTIFY_TIMEOUT_S + 0.01, |_| {
        healthy()
    });
    assert_eq!(c.cause(), Some(Cause::Timeout(State::Identify)));
}

/// The spin-up's least squares find the rotor's J/kt and friction roughly (on the
/// uncorrected sensor), Motion's coast its flux linkage and the fit over the dip the same
/// again on the corrected one; all stays in force to Run.
#[test]
fn spin_up_and_motion_fit_inertia_and_friction_and_the_coast_measures_the_flux() {
    let p = params();
    let rel = |found: f32, truth: f32| (found / truth - 1.0).abs();
    let mut c = drive_to(State::Adapt);
    // Friction as the current it takes at the commissioning speed: one speed region
    // separates viscous from constant friction only weakly, their sum well.
    let friction =
        |f: &drive::spin::MotionFit| f.amps_per_speed_a_s * p.speed_rad_s + f.amps_constant_a;
    let true_friction = AMPS_PER_SPEED * p.speed_rad_s;
    let f = c.spin_up_fit().expect("a fit");
    assert!(rel(f.amps_per_accel_a_s2, AMPS_PER_ACCEL) < 0.02, "{f:?}");
    assert!(rel(friction(&f), true_friction) < 0.02, "{f:?}");
    assert!(f.omega0_rad_s.abs() < 0.5, "{f:?}");
    assert_eq!((c.motion_fit(), c.flux_wb()), (None, None));
    run_until(&mut c, State::Verify, 10.0, hardware);
    // The coast: +I for the first half, -I for the second; then the dip and back.
    let (mut ids, mut lowest) = (vec![], f32::INFINITY);
    while matches!(c.state(), State::Verify | State::Motion) {
        match c.step(&hardware(&c)).setpoint {
            Setpoint::Coast { id_a } => ids.push(id_a),
            Setpoint::Speed { omega_rad_s } if c.state() == State::Motion => {
                lowest = lowest.min(omega_rad_s)
            }
            _ => {}
        }
    }
    assert_eq!(c.state(), State::Store);
    let n = ids.len();
    assert!(
        (n as f32 * DT - p.coast_s).abs() < 1.5 * DT,
        "coasted {n} steps"
    );
    let plus = ids.iter().take_while(|&&i| i == p.coast_current_a).count();
    assert!(
        ids[plus..].iter().all(|&i| i == -p.coast_current_a),
        "{ids:?}"
    );
    assert!((2 * plus).abs_diff(n) <= 1, "{ids:?}");
    assert!(
        (lowest / p.speed_rad_s - (1.0 - MOTION_DIP)).abs() < 0.01,
        "{lowest}"
    );
    let psi = c.flux_wb().expect("flux");
    assert!(rel(psi, FLUX_WB) < 1e-3, "flux {psi}");
    let m = c.motion_fit().expect("a fit");
    assert!(rel(m.amps_per_accel_a_s2, AMPS_PER_ACCEL) < 0.01, "{m:?}");
    assert!(rel(friction(&m), true_friction) < 0.05, "{m:?}");
    run_until(&mut c, State::Run, 1.0, hardware);
    assert_eq!(c.spin_up_fit(), Some(f));
    assert_eq!(c.motion_fit(), Some(m));
    assert_eq!(c.flux_wb(), Some(psi));
}

/// A rotor that turns at the speed from the start, with no acceleration to fit J on:
/// the spin-up keeps the loops' J (no fit), Motion refuses it by name. So is a coast
/// whose back-EMF integrates to nothing.
#[test]
fn no_acceleration_or_no_back_emf_ends_safe_by_name() {
    let p = params();
    let (mut theta, mut iq) = (0.0f32, 0.0f32);
    let mut turning = |c: &Commissioning| {
        theta = (theta + p.speed_rad_s * DT).rem_euclid(std::f32::consts::TAU);
        iq += 0.2 * DT;
        Inputs {
            theta_rad: theta,
            iq_integral_a_s: iq,
            ..hardware(c)
        }
    };
    let mut c = drive_to(State::SpinUp);
    run_until(&mut c, State::Adapt, 1.0, &mut turning);
    assert_eq!(c.spin_up_fit(), None);
    run_until(&mut c, State::Motion, 10.0, &mut turning);
    run_until(&mut c, State::Safe, 2.0, &mut turning);
    assert_eq!(
        c.cause(),
        Some(Cause::Identify(IdentError::InertiaOutOfRange))
    );
    assert!(c.flux_wb().is_some(), "the coast measured");

    let mut c = drive_to(State::Motion);
    run_until(&mut c, State::Safe, 1.0, |c| Inputs {
        flux_angle_wb_rad: [0.0; 2],
        ..hardware(c)
    });
    assert_eq!(c.cause(), Some(Cause::Identify(IdentError::FluxOutOfRange)));
    assert_eq!(c.flux_wb(), None);
}

/// Without the motor's identification (`identify_motor` off, what the firmware did before
/// it identified its motor): no Identify, no Motion, no fit; a loaded calibration goes
/// straight to Run.
#[test]
fn without_the_motors_identification_the_sequence_skips_identify_and_motion() {
    let p = Params {
        identify_motor: false,
        ..params()
    };
    let mut c = Commissioning::new(p);
    let mut seen = vec![c.state()];
    while c.state() != State::Run {
        let o = c.step(&hardware(&c));
        assert!(!matches!(
            o.setpoint,
            Setpoint::Identify { .. } | Setpoint::Coast { .. }
        ));
        if *seen.last().unwrap() != c.state() {
            seen.push(c.state());
        }
        assert!(seen.len() < 20);
    }
    use State::*;
    assert_eq!(
        seen,
        [
            CheckSensor,
            LoadCalibration,
            Align,
            Sweep,
            SpinUp,
            Adapt,
            Verify,
            Store,
            Run
        ]
    );
    assert_eq!(
        (c.spin_up_fit(), c.motion_fit(), c.flux_wb()),
        (None, None, None)
    );

    let mut c = Commissioning::new(p);
    run_until(&mut c, State::LoadCalibration, 1.0, |_| healthy());
    c.step(&Inputs {
        load: LoadStatus::Loaded,
        ..healthy()
    });
    assert_eq!(c.state(), State::Run);
}

#[test]
fn spin_up_probes_the_acceleration_per_amp_and_measures_a_rough_flux() {
    let rel = |found: f32, truth: f32| (found / truth - 1.0).abs();
    let mut c = drive_to(State::SpinUp);
    // The probe: J/kt from the travel under its current, reported on one step only.
    let mut probed = vec![];
    while matches!(c.outputs().setpoint, Setpoint::Torque { .. }) {
        c.step(&hardware(&c));
        probed.extend(c.probe_ended());
    }
    assert_eq!(probed.len(), 1, "{probed:?}");
    // The rotor's friction takes a small share of the probe's current from rest.
    assert!(rel(probed[0], AMPS_PER_ACCEL) < 0.02, "{probed:?}");
    c.step(&hardware(&c));
    assert_eq!(c.probe_ended(), None);
    assert_eq!(c.spin_up_flux_wb(), None, "no travel at speed yet");
    run_until(&mut c, State::Adapt, 3.0, hardware);
    // The back-EMF over the rest of SpinUp: the scripted rotor has no R·i or inverter
    // error in it.
    let psi = c.spin_up_flux_wb().expect("a rough flux");
    assert!(rel(psi, FLUX_WB) < 1e-3, "{psi}");
}

#[test]
fn a_coast_that_would_stop_the_rotor_is_cut_and_the_flux_is_measured_at_held_speed() {
    let p = params();
    let rel = |found: f32, truth: f32| (found / truth - 1.0).abs();
    let mut c = drive_to(State::Motion);
    // The first step of the coast, then a rotor slowed below `COAST_CUT` of its speed (a
    // fan on a light rotor) on the second; a coast that keeps its speed runs its whole
    // length (`spin_up_and_motion_fit_inertia_and_friction_and_the_coast_measures_the_flux`).
    let mut coasted = 0;
    let mut first = true;
    while c.state() == State::Motion {
        let mut i = hardware(&c);
        if matches!(c.outputs().setpoint, Setpoint::Coast { .. }) {
            coasted += 1;
            if !first {
                i.omega_rad_s = 0.9 * COAST_CUT * p.speed_rad_s;
            }
            first = false;
        }
        c.step(&i);
    }
    assert_eq!(
        coasted, 2,
        "the coast ends on the step that finds the speed halved"
    );
    assert_eq!(c.state(), State::Store, "{:?}", c.cause());
    let psi = c.flux_wb().expect("flux at held speed");
    assert!(rel(psi, FLUX_WB) < 1e-3, "flux {psi}");
    assert!(c.motion_fit().is_some());
}

//! The supervisor against scripted telemetry and a RAM flash: loads are reported only
//! once the control period accepted them, stores carry the alignment, failures are named.

use calib_record::{
    config_hash, Alignment, Calibration, FlashSlots, InputScaling, RamFlash, RamFlashError, Slot,
};
use drive::commissioning::{Cause, Params, Setpoint, State};
use drive::supervisor::{NamedError, Supervisor, MAX_EVENTS, RECORD_DIVIDER};
use drive::telemetry::{
    Command, CycleStats, Event, Fault, InstallAck, Snapshot, SweepResult, Telemetry,
};
use mras::{Coefficients, Config, Cplx, PathKind};

mod common;
use common::{Drive, Rotor, AMPS_PER_ACCEL, AMPS_PER_SPEED, FLUX_WB};

/// RAM flash whose programming can be made to fail.
#[derive(Default)]
struct Flash {
    ram: RamFlash,
    fail_program: bool,
}

#[derive(Debug)]
struct FlashError(&'static str);

impl NamedError for FlashError {
    fn name(&self) -> &'static str {
        self.0
    }
}

impl FlashSlots for Flash {
    type Error = FlashError;
    fn read(&self, slot: Slot, buf: &mut [u8]) -> Result<(), FlashError> {
        self.ram.read(slot, buf).map_err(ram)
    }
    fn erase(&mut self, slot: Slot) -> Result<(), FlashError> {
        self.ram.erase(slot).map_err(ram)
    }
    fn program(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), FlashError> {
        if self.fail_program {
            return Err(FlashError("ProgErr"));
        }
        self.ram.program(slot, offset, data).map_err(ram)
    }
}

fn ram(e: RamFlashError) -> FlashError {
    FlashError(match e {
        RamFlashError::PowerLost => "PowerLost",
        _ => "Ram",
    })
}

const POLE_PAIRS: u16 = 4;

/// The control period's configured motor.
const MOTOR: drive::control::MotorConfig = drive::control::MotorConfig {
    pole_pairs: POLE_PAIRS,
    r_ohm: 0.3,
    l_h: 0.5e-3,
    flux_wb: 0.02,
    inertia_kg_m2: 2e-4,
    vdc_v: 24.0,
    i_max_a: 10.0,
};

fn hash() -> u32 {
    config_hash(&Config::default(), POLE_PAIRS, &InputScaling::IDENTITY)
}

fn supervisor() -> Supervisor {
    Supervisor::new(Params::default(), hash(), 20_000, 20, &MOTOR, 2)
}

fn coefficients() -> Coefficients {
    let mut c = Coefficients::zeros(Config::default().paths());
    c.set(PathKind::Offset, Cplx::new(0.1, -0.08));
    c.set(PathKind::Harmonic(5), Cplx::new(0.01, 0.02));
    c
}

const IDENTIFIED: drive::ident::Identified = drive::ident::Identified {
    r_ohm: 0.3,
    ld_h: 0.5e-3,
    lq_h: 0.5e-3,
    v_inverter_v: 0.4,
};

/// A healthy control period at the commissioning speed.
fn telemetry(ticks: u32) -> Telemetry {
    Telemetry {
        snapshot: Snapshot {
            ticks,
            fault: None,
            release: 0,
            core_faults: 0,
            unlocked: false,
            theta_rad: 1.0,
            epsilon_rad: 0.0,
            omega_rad_s: Params::default().speed_rad_s,
            amplitude: 1.0,
            sweep: None,
            sweep_fit: None,
            // Done at once: the identification's own tests are `ident.rs`.
            ident: drive::ident::IdentStatus::Done(IDENTIFIED),
            shift: None,
            iq_integral_a_s: 0.0,
            flux_angle_wb_rad: [0.0; 2],
            currents_ready: true,
            currents_implausible: false,
            cycles: CycleStats::EMPTY,
            handoffs_dropped: 0,
            updates_late: 0,
        },
        converged: false,
        revs: 0,
        residual_max_rad: 1e-4,
        coefficients: coefficients(),
        install: None,
        updates_dropped: 0,
    }
}

/// The rotor ([`common::Rotor`]) a step on under `cmd` in `state`, into the snapshot.
fn turn(rotor: &mut Rotor, state: State, cmd: &Command, tm: &mut Telemetry) {
    let _ = state;
    let drive = match cmd.setpoint {
        Setpoint::Speed { omega_rad_s } => Drive::Speed(omega_rad_s),
        Setpoint::Torque { iq_a } => Drive::Torque(iq_a),
        Setpoint::Coast { .. } => Drive::Coast,
        _ => Drive::Hold,
    };
    rotor.step(1e-3, drive);
    let sn = &mut tm.snapshot;
    sn.theta_rad = rotor.theta_rad;
    sn.omega_rad_s = rotor.omega_rad_s;
    sn.iq_integral_a_s = rotor.iq_integral_a_s;
    sn.flux_angle_wb_rad = rotor.flux_angle_wb_rad;
}

/// Step with `f` shaping each snapshot of the rotor under the last command ([`turn`]),
/// collecting events, until `until` holds or `max` steps.
fn run<const E: usize>(
    s: &mut Supervisor<E>,
    flash: &mut Flash,
    ticks: &mut u32,
    max: usize,
    mut f: impl FnMut(&Supervisor<E>, &mut Telemetry),
    until: impl Fn(&Supervisor<E>) -> bool,
) -> (Vec<Event>, Command) {
    let mut events = Vec::new();
    let mut cmd = Command::OFF;
    let mut rotor = Rotor::default();
    for _ in 0..max {
        *ticks += 20;
        let mut tm = telemetry(*ticks);
        turn(&mut rotor, s.state(), &cmd, &mut tm);
        f(s, &mut tm);
        let out = s.step(&tm, flash);
        events.extend(out.events.iter().copied());
        cmd = out.command;
        if until(s) {
            break;
        }
    }
    (events, cmd)
}

fn sweep_result() -> SweepResult {
    SweepResult {
        ratio: 1.01,
        pole_pairs: POLE_PAIRS as f32 / 1.01,
        whole_pole_pairs: POLE_PAIRS,
        sensor_periods: 2,
        alignment: Alignment {
            offset_e_rad: -1.25,
            reversed: true,
            pole_pairs: POLE_PAIRS,
        },
    }
}

/// A control period that sweeps and converges at once, until `until`.
fn commission<const E: usize>(
    s: &mut Supervisor<E>,
    flash: &mut Flash,
    ticks: &mut u32,
    until: State,
) -> (Vec<Event>, Command) {
    run(
        s,
        flash,
        ticks,
        20_000,
        |s, tm| {
            tm.snapshot.sweep = (s.state() == State::Sweep).then(sweep_result);
            tm.converged = s.state() == State::Adapt;
        },
        |s| s.state() == until,
    )
}

/// The whole first power-up on a blank flash: named events in order, the alignment
/// measured by the sweep goes into the command and into the record.
#[test]
fn first_power_up_commissions_and_stores_the_alignment() {
    let mut s = supervisor();
    let mut flash = Flash::default();
    let mut ticks = 0;
    let (events, cmd) = commission(&mut s, &mut flash, &mut ticks, State::Run);
    assert_eq!(s.state(), State::Run, "{events:?}");
    assert!(
        events.iter().any(|e| matches!(
            e,
            Event::NotLoaded {
                reason: "Erased",
                ..
            }
        )),
        "{events:?}"
    );
    let states: Vec<State> = events
        .iter()
        .filter_map(|e| match e {
            Event::State { state, .. } => Some(*state),
            _ => None,
        })
        .collect();
    use State::*;
    assert_eq!(
        states,
        [
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
    assert!(events
        .iter()
        .any(|e| matches!(e, Event::Aligned { reversed: true, .. })));
    assert!(events.iter().any(|e| matches!(
        e,
        Event::Identified { r_ohm, ld_h, .. } if *r_ohm == IDENTIFIED.r_ohm && *ld_h == IDENTIFIED.ld_h
    )));
    assert!(events.iter().any(|e| matches!(e, Event::Stored { .. })));
    assert_eq!(cmd.alignment, sweep_result().alignment);
    assert_eq!(cmd.setpoint, Setpoint::Application);

    let loaded = calib_record::load(&flash, hash())
        .unwrap()
        .record
        .calibration;
    assert_eq!(loaded.coefficients, coefficients());
    assert_eq!(loaded.alignment, sweep_result().alignment);
    // The motor as identified: R and L as streamed, ψ from the coast, J and B from the
    // spin-up's fit at the torque constant 1.5·p·ψ; the same in force and streamed.
    let m = loaded.motor;
    let kt = 1.5 * POLE_PAIRS as f32 * FLUX_WB;
    assert_eq!(
        (m.r_ohm, m.ld_h, m.lq_h, m.v_inverter_v),
        (
            IDENTIFIED.r_ohm,
            IDENTIFIED.ld_h,
            IDENTIFIED.lq_h,
            IDENTIFIED.v_inverter_v
        )
    );
    let rel = |found: f32, truth: f32| (found / truth - 1.0).abs();
    assert!(rel(m.flux_wb, FLUX_WB) < 1e-3, "{m:?}");
    assert!(rel(m.inertia_kg_m2, AMPS_PER_ACCEL * kt) < 0.02, "{m:?}");
    // Friction as the torque at the commissioning speed (viscous and constant parts).
    let w = Params::default().speed_rad_s;
    let friction = m.viscous_nm_s_rad * w + m.coulomb_nm;
    assert!(rel(friction, AMPS_PER_SPEED * kt * w) < 0.05, "{m:?}");
    assert_eq!(s.motor(), m);
    assert!(rel(cmd.motion.amps_per_accel_a_s2, AMPS_PER_ACCEL) < 0.02);
    assert_eq!(cmd.motion.flux_wb, m.flux_wb);
    assert!(events.iter().any(|e| matches!(
        e,
        Event::Motion { flux_wb, inertia_kg_m2, .. }
            if *flux_wb == m.flux_wb && *inertia_kg_m2 == m.inertia_kg_m2
    )));
}

/// A motor of 6 pole pairs on the drive configured for 4: the first sweep's travel
/// (4/6 of a sensor period) puts 6 in force with a second alignment, the second sweep
/// confirms it; the command, the events, the torque constant of J and the record all
/// carry 6. A record whose count N does not divide is not loaded (commissions again).
#[test]
fn another_pole_pair_count_is_put_in_force_swept_again_and_stored() {
    let mut s = supervisor();
    let mut flash = Flash::default();
    let mut ticks = 0;
    let mut sweeps = Vec::new();
    let (events, cmd) = run(
        &mut s,
        &mut flash,
        &mut ticks,
        20_000,
        |s, tm| {
            let in_force = s.pole_pairs();
            tm.snapshot.sweep = (s.state() == State::Sweep).then(|| SweepResult {
                ratio: in_force as f32 / 6.0,
                pole_pairs: 6.0,
                whole_pole_pairs: 6,
                sensor_periods: 2,
                alignment: Alignment {
                    offset_e_rad: 0.5 * in_force as f32 - 2.5,
                    reversed: false,
                    pole_pairs: in_force,
                },
            });
            if s.state() == State::Sweep && sweeps.last() != Some(&in_force) {
                sweeps.push(in_force);
            }
            tm.converged = s.state() == State::Adapt;
        },
        |s| s.state() == State::Run,
    );
    assert_eq!(s.state(), State::Run, "{events:?}");
    assert_eq!(sweeps, [4, 6]);
    let aligned: Vec<(u16, f32)> = events
        .iter()
        .filter_map(|e| match e {
            Event::Aligned {
                pole_pairs, ratio, ..
            } => Some((*pole_pairs, *ratio)),
            _ => None,
        })
        .collect();
    assert_eq!(aligned, [(6, 4.0 / 6.0), (6, 1.0)]);
    // The second sweep's offset, for its count.
    let expected = Alignment {
        offset_e_rad: 0.5,
        reversed: false,
        pole_pairs: 6,
    };
    assert_eq!(cmd.alignment, expected);
    assert_eq!(s.pole_pairs(), 6);
    let stored = calib_record::load(&flash, hash())
        .unwrap()
        .record
        .calibration;
    assert_eq!(stored.alignment, expected);
    let kt = 1.5 * 6.0 * FLUX_WB;
    let rel = |found: f32, truth: f32| (found / truth - 1.0).abs();
    assert!(
        rel(stored.motor.inertia_kg_m2, AMPS_PER_ACCEL * kt) < 0.02,
        "{stored:?}"
    );

    // The same record with 3 pole pairs (N = 2 does not divide 3): not loaded.
    let mut bad = stored;
    bad.alignment.pole_pairs = 3;
    let mut flash = Flash::default();
    calib_record::store(&mut flash, &bad, hash()).unwrap();
    let mut s = supervisor();
    let mut ticks = 0;
    let (events, _) = run(
        &mut s,
        &mut flash,
        &mut ticks,
        200,
        |_, _| {},
        |s| s.state() == State::Identify,
    );
    assert!(
        events.iter().any(|e| matches!(
            e,
            Event::NotLoaded {
                reason: "PolePairs",
                ..
            }
        )),
        "{events:?}"
    );
    assert!(!s.calibration_loaded());
}

/// The motor a record carries: what a load puts in force.
const STORED_MOTOR: calib_record::MotorConstants = calib_record::MotorConstants {
    r_ohm: 0.25,
    ld_h: 4e-4,
    lq_h: 5e-4,
    v_inverter_v: 0.3,
    flux_wb: 0.015,
    inertia_kg_m2: 3e-4,
    viscous_nm_s_rad: 1e-4,
    coulomb_nm: 2e-3,
};

/// Second power-up: the coefficients go to the control period, and Loaded (and Run)
/// come only with its acceptance; a refusal is the safe state.
#[test]
fn a_load_is_reported_only_once_the_control_period_accepted_it() {
    for accepted in [true, false] {
        let mut flash = Flash::default();
        let cal = Calibration {
            coefficients: coefficients(),
            alignment: sweep_result().alignment,
            motor: STORED_MOTOR,
        };
        calib_record::store(&mut flash, &cal, hash()).unwrap();
        let mut s = supervisor();
        let mut ticks = 0;
        let mut install = None;
        // Until the install comes out, the control period has nothing to acknowledge.
        for _ in 0..200 {
            ticks += 20;
            let out = s.step(&telemetry(ticks), &mut flash);
            if let Some(i) = out.install {
                install = Some(i);
                assert!(!out.events.iter().any(|e| matches!(e, Event::Loaded { .. })));
                assert_eq!(out.command.alignment, cal.alignment);
                break;
            }
        }
        let install = install.expect("the stored coefficients are sent to the control period");
        assert_eq!(install.coefficients, cal.coefficients);
        // No acknowledgement yet: still loading.
        for _ in 0..20 {
            ticks += 20;
            s.step(&telemetry(ticks), &mut flash);
            assert_eq!(s.state(), State::LoadCalibration);
        }
        ticks += 20;
        let mut tm = telemetry(ticks);
        tm.install = Some(InstallAck {
            generation: install.generation,
            accepted,
        });
        let out = s.step(&tm, &mut flash);
        if accepted {
            // The identification on the rotor's d axis, then Run.
            assert_eq!(s.state(), State::Identify);
            assert!(s.calibration_loaded());
            assert!(out
                .events
                .iter()
                .any(|e| matches!(e, Event::Loaded { sequence: 1, .. })));
            // The stored motor in force: ψ, and J/kt at kt = 1.5·p·ψ.
            let m = STORED_MOTOR;
            assert!(out.events.iter().any(|e| matches!(
                *e,
                Event::Motion { flux_wb, inertia_kg_m2, viscous_nm_s_rad, coulomb_nm, .. }
                    if (flux_wb, inertia_kg_m2, viscous_nm_s_rad, coulomb_nm)
                        == (m.flux_wb, m.inertia_kg_m2, m.viscous_nm_s_rad, m.coulomb_nm)
            )));
            let kt = 1.5 * POLE_PAIRS as f32 * m.flux_wb;
            assert_eq!(out.command.motion.flux_wb, m.flux_wb);
            assert_eq!(out.command.motion.amps_per_accel_a_s2, m.inertia_kg_m2 / kt);
            ticks += 20;
            let out = s.step(&telemetry(ticks), &mut flash);
            assert_eq!(s.state(), State::Run);
            assert!(out
                .events
                .iter()
                .any(|e| matches!(e, Event::Identified { .. })));
        } else {
            assert_eq!(s.cause(), Some(Cause::LoadRefused));
            assert_eq!(out.command.motion, Default::default(), "nothing loaded");
            assert!(out.events.iter().any(|e| matches!(
                e,
                Event::Fault {
                    cause: Cause::LoadRefused,
                    ..
                }
            )));
        }
    }
}

#[test]
fn a_failed_store_is_the_safe_state_with_the_flash_error_named() {
    let mut s = supervisor();
    let mut flash = Flash {
        fail_program: true,
        ..Flash::default()
    };
    let mut ticks = 0;
    let (events, cmd) = commission(&mut s, &mut flash, &mut ticks, State::Safe);
    assert_eq!(s.cause(), Some(Cause::StoreFailed));
    assert!(events.iter().any(|e| matches!(
        e,
        Event::StoreFailed {
            reason: "ProgErr",
            ..
        }
    )));
    assert_eq!(cmd.setpoint, Setpoint::Off);
}

#[test]
fn a_store_in_run_keeps_running_and_a_failed_one_too() {
    let mut s = supervisor();
    let mut flash = Flash::default();
    let mut ticks = 0;
    commission(&mut s, &mut flash, &mut ticks, State::Run);
    let mut drifted = coefficients();
    drifted.set(PathKind::Offset, Cplx::new(0.11, -0.07));
    s.request_store();
    let mut tm = telemetry(ticks + 20);
    tm.coefficients = drifted;
    let out = s.step(&tm, &mut flash);
    assert_eq!(s.state(), State::Run);
    assert!(out.events.iter().any(|e| matches!(e, Event::Stored { .. })));
    let l = calib_record::load(&flash, hash()).unwrap();
    assert_eq!(l.record.calibration.coefficients, drifted);
    assert_eq!(l.record.sequence, 2);

    flash.fail_program = true;
    s.request_store();
    let out = s.step(&telemetry(ticks + 40), &mut flash);
    assert_eq!(s.state(), State::Run);
    assert!(out.events.iter().any(|e| matches!(
        e,
        Event::StoreFailed {
            reason: "ProgErr",
            ..
        }
    )));
    // The previous record is intact.
    assert_eq!(
        calib_record::load(&flash, hash())
            .unwrap()
            .record
            .calibration
            .coefficients,
        drifted
    );
}

#[test]
fn a_latched_fault_ends_safe_and_a_restart_releases_the_latch() {
    let mut s = supervisor();
    let mut flash = Flash::default();
    let mut ticks = 0;
    let (_, before) = run(
        &mut s,
        &mut flash,
        &mut ticks,
        2000,
        |_, _| {},
        |s| s.state() == State::Align,
    );
    let mut tm = telemetry(ticks + 20);
    tm.snapshot.fault = Some(Fault::Sensor(mras::Fault::SensorLost));
    let out = s.step(&tm, &mut flash);
    assert_eq!(s.state(), State::Safe);
    assert_eq!(out.command.setpoint, Setpoint::Off);
    assert!(out.events.iter().any(|e| matches!(
        e,
        Event::Fault {
            cause: Cause::Sensor(mras::Fault::SensorLost),
            state: State::Align,
            ..
        }
    )));
    assert_eq!(out.command.release, before.release);
    s.restart();
    let out = s.step(&telemetry(ticks + 40), &mut flash);
    assert_ne!(out.command.release, before.release);
    assert_eq!(s.state(), State::CheckSensor);
    // A snapshot taken before the control period saw the release still shows the
    // latched fault: not a new one.
    let mut stale = telemetry(ticks + 60);
    stale.snapshot.fault = Some(Fault::Sensor(mras::Fault::SensorLost));
    s.step(&stale, &mut flash);
    assert_eq!(s.state(), State::CheckSensor);
    let mut fresh = stale;
    fresh.snapshot.release = out.command.release;
    s.step(&fresh, &mut flash);
    assert_eq!(s.state(), State::Safe);
}

#[test]
fn boot_faults_are_reported_and_records_come_every_divider_steps() {
    let mut s = supervisor();
    s.boot_fault(Cause::Watchdog);
    let mut flash = Flash::default();
    let mut records = 0;
    for k in 0..100 {
        let out = s.step(&telemetry(20 * (k + 1)), &mut flash);
        if k == 0 {
            assert_eq!(out.events.len(), 1);
            assert!(matches!(
                out.events.iter().next().unwrap(),
                Event::Fault {
                    cause: Cause::Watchdog,
                    ..
                }
            ));
        }
        if let Some(r) = out.record {
            records += 1;
            assert_eq!(r.state, State::Safe);
            assert_eq!(r.t_ms, k + 1);
            assert_eq!(r.coef[0], 0.1);
            assert_eq!(r.coef[1], -0.08);
        }
    }
    // Steps 0, D, 2D, ... of the hundred.
    assert_eq!(records, 100_u32.div_ceil(RECORD_DIVIDER));
}

/// A two-speed commissioning on a scripted control period whose coefficients are what
/// the MRAS learns with a motion ripple: `e + M/ω²` at the speed commanded. The
/// supervisor installs `e` (the two refinements' separation) before verifying, reports
/// the verification only once the control period accepted it, and stores it; a refusal
/// is the safe state.
#[test]
fn a_two_speed_commissioning_installs_and_stores_the_sensor_error_alone() {
    let params = Params {
        refine_s: 0.2,
        second_speed_ratio: 2.0,
        ..Params::default()
    };
    let e = coefficients();
    let motion = Cplx::new(30.0, -40.0); // 3.2 mrad at 125.7 rad/s on the offset path
    let learnt = |omega_rad_s: f32| {
        let mut c = e;
        let v = e.get(PathKind::Offset).unwrap();
        c.set(
            PathKind::Offset,
            v + motion.scale(1.0 / (omega_rad_s * omega_rad_s)),
        );
        c
    };
    for accepted in [true, false] {
        let mut s = Supervisor::new(params, hash(), 20_000, 20, &MOTOR, 2);
        let mut flash = Flash::default();
        let mut ticks = 0;
        let mut omega_rad_s: f32 = 0.0;
        let mut rotor = Rotor::default();
        let mut cmd = Command::OFF;
        let mut installed: Option<(u8, Coefficients)> = None;
        let mut acked = false;
        let mut states = vec![];
        for _ in 0..20_000 {
            ticks += 20;
            let mut tm = telemetry(ticks);
            turn(&mut rotor, s.state(), &cmd, &mut tm);
            tm.snapshot.sweep = (s.state() == State::Sweep).then(sweep_result);
            tm.converged = matches!(s.state(), State::Adapt | State::SecondSpeed);
            tm.coefficients = match installed {
                Some((generation, c)) => {
                    if !acked {
                        tm.install = Some(InstallAck {
                            generation,
                            accepted,
                        });
                        acked = true;
                    }
                    c
                }
                None => learnt(omega_rad_s.max(1.0)),
            };
            let out = s.step(&tm, &mut flash);
            cmd = out.command;
            if let Setpoint::Speed { omega_rad_s: w } = out.command.setpoint {
                omega_rad_s = w;
            }
            if let Some(i) = out.install {
                assert_eq!(s.state(), State::Verify);
                installed = Some((i.generation, i.coefficients));
            }
            for ev in &out.events {
                if let Event::State { state, .. } = ev {
                    states.push(*state);
                }
            }
            if matches!(s.state(), State::Run | State::Safe) {
                break;
            }
        }
        let (_, sent) = installed.expect("the refined coefficients were installed");
        let err = (sent.get(PathKind::Offset).unwrap() - e.get(PathKind::Offset).unwrap()).abs();
        let one_speed = motion.abs() / (params.speed_rad_s * params.speed_rad_s);
        assert!(err < 1e-6, "{err} (the motion at one speed: {one_speed})");
        assert_eq!(sent.kinds(), e.kinds());
        let [first, second] = s.refinements().map(Option::unwrap);
        assert!((first.speed_rad_s - params.speed_rad_s).abs() < 1e-3);
        assert!((second.speed_rad_s - 2.0 * params.speed_rad_s).abs() < 1e-3);
        use State::*;
        if accepted {
            assert_eq!(s.state(), Run);
            assert_eq!(
                states[4..],
                [
                    SpinUp,
                    Adapt,
                    Refine,
                    SecondSpeed,
                    Refine,
                    Verify,
                    Motion,
                    Store,
                    Run
                ]
            );
            let stored = calib_record::load(&flash, hash()).unwrap();
            assert_eq!(stored.record.calibration.coefficients, sent);
        } else {
            assert_eq!(s.cause(), Some(Cause::RefineFailed));
            assert_eq!(s.refine_error(), None, "formed, then refused by the core");
            assert!(
                calib_record::load(&flash, hash()).is_err(),
                "nothing stored"
            );
        }
    }
}

/// Steps that produce more events than fit, on a supervisor that holds one event a step
/// besides a boot fault, against one with the default room on the same telemetry: the
/// end of the sweep (its measurement and the state change) keeps the first and counts
/// the second; a fault in the step of a failed store in Run takes the store event's
/// place (counted); a boot fault and a step's fault right after a restart are both
/// kept (the restart's state change gives way). Every event dropped
/// is counted and none is a fault, the records carry the count, and the default room
/// drops nothing.
#[test]
fn a_fault_is_never_dropped_and_events_that_do_not_fit_are_counted() {
    fn drive<const E: usize>() -> (Vec<Event>, Supervisor<E>, u32) {
        let mut s =
            Supervisor::<E>::with_event_room(Params::default(), hash(), 20_000, 20, &MOTOR, 2);
        let mut flash = Flash::default();
        let mut ticks = 0;
        let (mut events, _) = commission(&mut s, &mut flash, &mut ticks, State::Run);
        // A store in Run that fails, and a sensor fault in the same step.
        flash.fail_program = true;
        s.request_store();
        ticks += 20;
        let mut tm = telemetry(ticks);
        tm.snapshot.fault = Some(Fault::Sensor(mras::Fault::SensorLost));
        let out = s.step(&tm, &mut flash);
        assert_eq!(s.state(), State::Safe);
        events.extend(out.events.iter().copied());
        // Steps until a record: it carries the count.
        let record = loop {
            ticks += 20;
            if let Some(r) = s.step(&telemetry(ticks), &mut flash).record {
                break r;
            }
        };
        assert_eq!(record.events_dropped, s.events_dropped());
        (events, s, ticks)
    }
    let (all, full, _) = drive::<MAX_EVENTS>();
    assert_eq!(full.events_dropped(), 0);
    let (kept, one, ticks) = drive::<1>();
    // What one event a step kept is what the default room kept, less what was counted.
    assert_eq!(
        (all.len() - kept.len()) as u32,
        one.events_dropped(),
        "{all:?}\n{kept:?}"
    );
    assert!(one.events_dropped() >= 2);
    // What was kept is what the default room kept, in order, less what was dropped.
    let mut rest = kept.iter().peekable();
    let dropped: Vec<&Event> = all
        .iter()
        .filter(|e| match rest.peek() == Some(e) {
            true => rest.next().is_none(),
            false => true,
        })
        .collect();
    assert!(rest.next().is_none(), "{kept:?} is not a part of {all:?}");
    assert_eq!(dropped.len() as u32, one.events_dropped());
    assert!(dropped.iter().all(|e| !e.is_fault()), "{dropped:?}");
    assert!(all
        .iter()
        .filter(|e| e.is_fault())
        .eq(kept.iter().filter(|e| e.is_fault())));
    // The sweep's measurement stayed, its state change went.
    assert!(kept.iter().any(|e| matches!(e, Event::Aligned { .. })));
    assert!(!kept.iter().any(|e| matches!(
        e,
        Event::State {
            state: State::SpinUp,
            ..
        }
    )));
    // The fault took the failed store's place.
    assert!(all.iter().any(|e| matches!(e, Event::StoreFailed { .. })));
    assert!(!kept.iter().any(|e| matches!(e, Event::StoreFailed { .. })));
    assert!(matches!(
        kept.last(),
        Some(Event::Fault {
            cause: Cause::Sensor(mras::Fault::SensorLost),
            state: State::Run,
            ..
        })
    ));

    // A boot fault and the step's own fault: both kept with room for one event.
    let mut one = one;
    let released = one.step(&telemetry(ticks + 20), &mut Flash::default());
    one.boot_fault(Cause::Watchdog);
    one.restart();
    let mut tm = telemetry(ticks + 40);
    tm.snapshot.fault = Some(Fault::Sensor(mras::Fault::SensorLost));
    // A fault seen after the restart's release reached the control period.
    tm.snapshot.release = released.command.release.wrapping_add(1);
    let before = one.events_dropped();
    let out = one.step(&tm, &mut Flash::default());
    let faults: Vec<&Event> = out.events.iter().collect();
    assert_eq!(faults.len(), 2, "{faults:?}");
    assert!(faults.iter().all(|e| e.is_fault()));
    // The restart's state change gave way to the fault.
    assert_eq!(one.events_dropped(), before + 1);
}

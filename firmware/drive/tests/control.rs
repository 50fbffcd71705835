//! The control period on its own: the latched safe state, the current sensors' zero,
//! scaling faults, the supervisor's divider, installs.

use calib_record::Alignment;
use drive::adaptation::AdaptationTask;
use drive::adc::ChannelScaling;
use drive::commissioning::{Adaptation, Setpoint};
use drive::control::{ControlPeriod, CurrentSensing, DriveConfig, MotorConfig, Sample};
use drive::motion::LoopMode;
use drive::telemetry::{Command, Fault, Install};
use mras::{Bank, Change, Coefficients, Config, Cplx, Front, PathKind};

const T: f32 = 50e-6;
const AMPLITUDE: f32 = 1600.0;

fn config() -> DriveConfig {
    let sensor = ChannelScaling::from_amplitude(2048, AMPLITUDE as u16).unwrap();
    DriveConfig {
        control_period_s: T,
        motor: MotorConfig {
            pole_pairs: 4,
            r_ohm: 0.3,
            l_h: 0.5e-3,
            flux_wb: 0.02,
            inertia_kg_m2: 2e-4,
            vdc_v: 24.0,
            i_max_a: 10.0,
        },
        sensor_x: sensor,
        sensor_y: sensor,
        current: CurrentSensing {
            amps_per_count: 0.0161,
            zero_counts: 2048,
            max_counts: 4095,
            zero_tolerance_counts: 200,
        },
        current_bandwidth_hz: 1000.0,
        speed_bandwidth_hz: 10.0,
        application_loop: LoopMode::Velocity,
        application_bandwidth_hz: 10.0,
        supervisor_divider: 20,
    }
}

fn period() -> ControlPeriod<mras::F32Trig> {
    let core = Config {
        sample_period_s: T,
        ..Config::default()
    };
    ControlPeriod::new(config(), Front::new(core).unwrap()).unwrap()
}

/// The sensor at `theta_s_rad` (sensor electrical), currents at zero.
fn sample(theta_s_rad: f32) -> Sample {
    let c = |v: f32| (2048.0 + AMPLITUDE * v).round() as u16;
    Sample {
        x: c(libm::cosf(theta_s_rad)),
        y: c(libm::sinf(theta_s_rad)),
        ia: 2048,
        ib: 2048,
        overcurrent: false,
        cycles: 0,
    }
}

fn running() -> Command {
    Command {
        setpoint: Setpoint::Speed { omega_rad_s: 10.0 },
        adaptation: Adaptation::Frozen,
        ..Command::OFF
    }
}

#[test]
fn off_means_bridge_off_and_running_means_on() {
    let mut p = period();
    let o = p.step(&sample(0.1), &Command::OFF);
    assert!(!o.enable);
    assert_eq!(o.duties, [0.5; 3]);
    let o = p.step(&sample(0.1), &running());
    assert!(o.enable);
    assert!(o.duties.iter().all(|d| (0.0..=1.0).contains(d)));
}

/// A wire break: the bridge goes off in the faulted period and stays off on good
/// samples, whatever the command, until the supervisor releases it.
#[test]
fn a_fault_latches_the_safe_state_until_released() {
    let mut p = period();
    let cmd = running();
    for k in 0..200 {
        assert!(p.step(&sample(0.001 * k as f32), &cmd).enable);
    }
    // Both channels at mid-scale: |Z| = 0, the sensor is gone.
    let broken = Sample {
        x: 2048,
        y: 2048,
        ..sample(0.0)
    };
    let o = p.step(&broken, &cmd);
    assert!(!o.enable);
    assert_eq!(p.latched(), Some(Fault::Sensor(mras::Fault::SensorLost)));
    for k in 0..1000 {
        assert!(!p.step(&sample(0.2 + 0.001 * k as f32), &cmd).enable, "{k}");
    }
    assert_eq!(
        p.snapshot().fault,
        Some(Fault::Sensor(mras::Fault::SensorLost))
    );
    let released = Command {
        release: cmd.release.wrapping_add(1),
        ..cmd
    };
    assert!(p.step(&sample(1.3), &released).enable);
    assert_eq!(p.latched(), None);
    assert_eq!(p.snapshot().fault, None);
}

/// Riding through (Run): a refused sample or a lost lock switches the bridge off for
/// the periods without a locked estimate only, latches nothing, and shows in the
/// snapshot; the bridge is on again once the core has re-acquired. A fault that is not
/// the sensor's still latches.
#[test]
fn riding_through_keeps_the_bridge_off_only_while_unlocked() {
    let mut p = period();
    let cmd = Command {
        setpoint: Setpoint::Application,
        reacquire: true,
        ..running()
    };
    // Off until the core's first window has held the lock.
    let mut th = 0.0;
    for k in 0..200 {
        th += 0.001;
        assert_eq!(p.step(&sample(th), &cmd).enable, k >= 32, "{k}");
    }
    p.snapshot();
    p.step(&sample(th), &cmd);
    assert!(!p.snapshot().unlocked);
    let broken = Sample {
        x: 2048,
        y: 2048,
        ..sample(0.0)
    };
    assert!(!p.step(&broken, &cmd).enable);
    assert_eq!(p.latched(), None);
    assert!(p.snapshot().unlocked);
    // A railed channel is refused before the core, which still counts the period and
    // holds its estimate (its drift check needs the time that passed).
    let index = p.tracker().index();
    assert!(!p.step(&Sample { y: 0, ..sample(th) }, &cmd).enable);
    assert_eq!(p.tracker().index(), index + 1);
    assert!(p.tracker().faults().contains(mras::Fault::SensorSaturated));
    assert_eq!(p.latched(), None);
    // Back, but half a sensor period away: the lock is lost and re-acquired.
    th += std::f32::consts::PI;
    let mut off = 0;
    for k in 0..200 {
        th += 0.001;
        let o = p.step(&sample(th), &cmd);
        if !o.enable {
            off = k + 1;
        }
    }
    assert_eq!(p.latched(), None);
    assert!(p.tracker().is_locked());
    // Two windows of 32 periods (measure and restart, then hold the lock).
    assert!((32..=80).contains(&off), "bridge off for {off} periods");
    assert!(p.snapshot().unlocked, "since the previous snapshot");
    assert!(p.step(&sample(th), &cmd).enable);
    assert!(!p.snapshot().unlocked);
    let railed = Sample {
        x: 4096,
        ..sample(th)
    };
    assert!(!p.step(&railed, &cmd).enable);
    assert_eq!(p.latched(), Some(Fault::AdcOutOfRange));
}

#[test]
fn adc_range_rails_and_break_input_are_faults_by_name() {
    let cmd = running();
    let cases = [
        (
            Sample {
                x: 4096,
                ..sample(0.0)
            },
            Fault::AdcOutOfRange,
        ),
        (
            Sample {
                y: 0,
                ..sample(0.0)
            },
            Fault::Sensor(mras::Fault::SensorSaturated),
        ),
        (
            Sample {
                ia: 4095,
                ..sample(0.0)
            },
            Fault::OverCurrent,
        ),
        (
            Sample {
                ib: 5000,
                ..sample(0.0)
            },
            Fault::AdcOutOfRange,
        ),
        (
            Sample {
                overcurrent: true,
                ..sample(0.0)
            },
            Fault::OverCurrent,
        ),
    ];
    for (s, f) in cases {
        let mut p = period();
        p.step(&sample(0.0), &cmd);
        assert!(!p.step(&s, &cmd).enable, "{f:?}");
        assert_eq!(p.latched(), Some(f));
    }
}

#[test]
fn current_zero_is_measured_with_the_bridge_off_and_checked() {
    let cmd = Command {
        calibrate_currents: true,
        ..Command::OFF
    };
    let mut p = period();
    let offset = Sample {
        ia: 2100,
        ib: 1990,
        ..sample(0.0)
    };
    for _ in 0..255 {
        p.step(&offset, &cmd);
    }
    assert!(!p.snapshot().currents_ready);
    p.step(&offset, &cmd);
    let t = p.snapshot();
    assert!(t.currents_ready && !t.currents_implausible);
    assert_eq!(p.current_zero_counts(), [2100.0, 1990.0]);
    // Now those counts read as zero current.
    p.step(&offset, &running());
    assert_eq!(p.last_currents_a(), (0.0, 0.0));

    let mut p = period();
    let broken = Sample {
        ia: 2600,
        ..sample(0.0)
    };
    for _ in 0..256 {
        p.step(&broken, &cmd);
    }
    assert!(p.snapshot().currents_implausible);
}

#[test]
fn the_supervisor_is_due_every_divider_periods() {
    let mut p = period();
    let due: Vec<usize> = (1..=100)
        .filter(|_| p.step(&sample(0.0), &Command::OFF).supervisor_due)
        .collect();
    assert_eq!(due.len(), 5);
    let t = p.snapshot();
    assert_eq!(t.ticks, 100);
}

#[test]
fn installs_are_acknowledged_with_their_generation() {
    let paths = Config::default();
    let mut task = AdaptationTask::new(&paths).unwrap();
    let mut good = Coefficients::zeros(paths.paths());
    good.set(PathKind::Offset, Cplx::new(0.05, -0.02));
    let mut sent = Vec::new();
    task.install(
        &Install {
            generation: 7,
            coefficients: good,
        },
        |u| sent.push(u),
    );
    let ack = task.report().install.unwrap();
    assert_eq!((ack.generation, ack.accepted), (7, true));
    assert_eq!(task.report().coefficients, good);
    // Every path's term goes to the control period, due at once (the bank is the one
    // in use: no new bank).
    assert_eq!(sent.len(), good.len());
    assert_eq!(
        sent[0].change,
        Change::Term {
            path: 0,
            value: Cplx::new(0.05, -0.02)
        }
    );
    let mut p = period();
    assert!(sent.iter().all(|u| p.apply(u)));
    // Another path list: refused, the coefficients stay, nothing is sent.
    let other = Coefficients::zeros(&[PathKind::Offset]);
    sent.clear();
    task.install(
        &Install {
            generation: 8,
            coefficients: other,
        },
        |u| sent.push(u),
    );
    let ack = task.report().install.unwrap();
    assert_eq!((ack.generation, ack.accepted), (8, false));
    assert_eq!(task.adapter().coefficients(), good);
    assert!(sent.is_empty());
    // The report reaches the supervisor's snapshot.
    let t = p.snapshot().merged(task.report());
    assert_eq!(t.install.map(|a| a.generation), Some(8));
}

/// A record of a bank from the data, installed into a core that starts from the first
/// stage: the bank goes to the control period first, then the terms of the new bank.
#[test]
fn an_installed_bank_from_the_data_goes_to_the_control_period_first() {
    let mut core = Config {
        sample_period_s: T,
        ..Config::default()
    };
    core.set_paths(&mras::survey::FIRST_STAGE).unwrap();
    core.paths_from_data = true;
    let mut task = AdaptationTask::new(&core).unwrap();
    let bank = [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(10),
    ];
    let mut record = Coefficients::zeros(&bank);
    record.set(PathKind::Harmonic(10), Cplx::new(0.01, 0.002));
    let mut sent = Vec::new();
    task.install(
        &Install {
            generation: 1,
            coefficients: record,
        },
        |u| sent.push(u),
    );
    assert!(task.report().install.unwrap().accepted);
    assert_eq!(sent.len(), 1 + bank.len());
    assert_eq!(sent[0].change, Change::Bank(Bank::new(&bank).into()));
    assert_eq!(
        sent[3].change,
        Change::Term {
            path: 2,
            value: Cplx::new(0.01, 0.002)
        }
    );
    let mut p = ControlPeriod::new(config(), Front::new(core).unwrap()).unwrap();
    assert!(sent.iter().all(|u| p.apply(u)));
    assert_eq!(task.report().coefficients, record);
}

#[test]
fn a_reversed_sensor_reports_speed_in_the_motor_frame() {
    let mut p = period();
    let cmd = Command {
        alignment: Alignment {
            offset_e_rad: 0.0,
            reversed: true,
        },
        ..Command::OFF
    };
    // The sensor turns forward at 100 rad/s electrical: the motor turns backwards.
    for k in 0..4000 {
        p.step(&sample(100.0 * T * k as f32), &cmd);
    }
    let w = p.snapshot().omega_rad_s;
    // N = 2: 100 rad/s sensor electrical is 50 rad/s mechanical.
    assert!((w + 50.0).abs() < 1.0, "{w}");
}

#[test]
fn configurations_are_checked_by_field() {
    let core = Config {
        sample_period_s: T,
        ..Config::default()
    };
    let mut c = config();
    c.motor.pole_pairs = 3; // N = 2 does not divide 3
    let e = ControlPeriod::new(c, Front::new(core).unwrap()).unwrap_err();
    assert_eq!(e.field, "motor.pole_pairs");
    let mut c = config();
    c.control_period_s = 25e-6;
    let e = ControlPeriod::new(c, Front::new(core).unwrap()).unwrap_err();
    assert_eq!(e.field, "drive.control_period_s");
    let mut c = config();
    c.current.amps_per_count = f32::NAN;
    assert!(ControlPeriod::new(c, Front::new(core).unwrap()).is_err());
    let mut c = config();
    c.supervisor_divider = 0;
    assert!(ControlPeriod::new(c, Front::new(core).unwrap()).is_err());
}

//! The control period on its own: the latched safe state, the current sensors' zero,
//! scaling faults, the supervisor's divider, installs; and the hand-over to the
//! adaptation task (`drive::handoff`): what each side drops and counts, late updates,
//! and a bank change the queue cannot take.

use calib_record::Alignment;
use drive::adaptation::AdaptationTask;
use drive::adc::ChannelScaling;
use drive::commissioning::{Adaptation, Setpoint};
use drive::control::{ControlPeriod, CurrentSensing, DriveConfig, MotorConfig, Sample};
use drive::handoff::{
    BankQueue, Prepared, Queue, Receiver, SpareQueue, HANDOFF_DEPTH, UPDATE_DEPTH,
};
use drive::motion::LoopMode;
use drive::telemetry::{Command, Fault, Install};
use mras::{
    AdaptSample, Bank, Change, Coefficients, Config, Cplx, Front, Injection, InjectionUpdate,
    PackedBank, PathKind,
};

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
        max_modulation: 1.0,
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
        ic: 2048,
        overcurrent: false,
        cycles: 0,
    }
}

/// Step `p` until `updates` (all due at one period) are due: not before, then all, none
/// late.
fn due_in_time(p: &mut ControlPeriod<mras::F32Trig>, updates: &[InjectionUpdate]) {
    let due = updates[0].apply_at;
    while p.tracker().index() + 1 < due {
        assert!(!p.apply(&updates[0]));
        p.step(&sample(0.0), &Command::OFF);
    }
    assert!(updates.iter().all(|u| p.apply(u)));
    assert_eq!(p.snapshot().updates_late, 0);
}

fn drain<const N: usize>(q: &mut Queue<InjectionUpdate, N>) -> Vec<InjectionUpdate> {
    std::iter::from_fn(|| q.dequeue()).collect()
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
            // A rail on the shunts read (here all three, whichever two are read).
            Sample {
                ia: 4095,
                ib: 4095,
                ic: 4095,
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
        ic: 2020,
        ..sample(0.0)
    };
    for _ in 0..255 {
        p.step(&offset, &cmd);
    }
    assert!(!p.snapshot().currents_ready);
    p.step(&offset, &cmd);
    let t = p.snapshot();
    assert!(t.currents_ready && !t.currents_implausible);
    assert_eq!(p.current_zero_counts(), [2100.0, 1990.0, 2020.0]);
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
    let mut queue = Queue::<InjectionUpdate, UPDATE_DEPTH>::new();
    task.install(
        &Install {
            generation: 7,
            coefficients: good,
        },
        &mut queue,
        &mut BankQueue::new(),
    );
    let sent = drain(&mut queue);
    let ack = task.report().install.unwrap();
    assert_eq!((ack.generation, ack.accepted), (7, true));
    assert_eq!(task.report().coefficients, good);
    // Every path's term goes to the control period (the bank is the one in use: no new
    // bank), due with the update of the last sample adapted on (none yet: period 0).
    assert_eq!(sent.len(), good.len());
    assert_eq!(
        sent[0].change,
        Change::Term {
            path: 0,
            value: Cplx::new(0.05, -0.02)
        }
    );
    let mut p = period();
    assert!(sent
        .iter()
        .all(|u| u.apply_at == mras::UPDATE_LATENCY_PERIODS));
    due_in_time(&mut p, &sent);
    // Another path list: refused, the coefficients stay, nothing is sent.
    let other = Coefficients::zeros(&[PathKind::Offset]);
    task.install(
        &Install {
            generation: 8,
            coefficients: other,
        },
        &mut queue,
        &mut BankQueue::new(),
    );
    let sent = drain(&mut queue);
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
    let mut queue = Queue::<InjectionUpdate, UPDATE_DEPTH>::new();
    task.install(
        &Install {
            generation: 1,
            coefficients: record,
        },
        &mut queue,
        &mut BankQueue::new(),
    );
    let sent = drain(&mut queue);
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
    due_in_time(&mut p, &sent);
    assert_eq!(task.report().coefficients, record);
}

/// The alignment's pole pairs are the ones the commutation uses (0: the configured
/// 4); a count the sensor's periods (N = 2) do not divide keeps the bridge off.
#[test]
fn the_alignments_pole_pairs_are_in_force_and_one_n_does_not_divide_keeps_the_bridge_off() {
    let at = |pole_pairs: u16| {
        let mut p = period();
        let cmd = Command {
            alignment: Alignment {
                pole_pairs,
                ..Alignment::IDENTITY
            },
            ..running()
        };
        let mut o = p.step(&sample(0.7), &cmd);
        for _ in 0..10 {
            o = p.step(&sample(0.7), &cmd);
        }
        o
    };
    let (configured, four, six, three) = (at(0), at(4), at(6), at(3));
    assert!(configured.enable && four.enable && six.enable);
    assert_eq!(configured.duties, four.duties);
    // θe = (p/N)·θs: 1.4 rad at 4 pole pairs, 2.1 rad at 6.
    assert_ne!(six.duties, four.duties);
    assert!(!three.enable);
    assert_eq!(three.duties, [0.5; 3]);
}

#[test]
fn a_reversed_sensor_reports_speed_in_the_motor_frame() {
    let mut p = period();
    let cmd = Command {
        alignment: Alignment {
            reversed: true,
            ..Alignment::IDENTITY
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

/// A receiving end that keeps what it hands out (the updates the control period took).
struct Counted<'a, Q, T> {
    inner: &'a mut Q,
    taken: Vec<T>,
}

impl<T: Copy, Q: Receiver<T>> Receiver<T> for Counted<'_, Q, T> {
    fn peek(&self) -> Option<&T> {
        self.inner.peek()
    }
    fn receive(&mut self) -> Option<T> {
        let u = self.inner.receive();
        self.taken.extend(u);
        u
    }
}

/// A hand-over queue the adaptation task does not drain: the samples beyond its room
/// are dropped and counted, the oldest kept.
#[test]
fn a_full_handoff_queue_drops_the_sample_and_counts_it() {
    let mut p = period();
    let mut handoff = Queue::<AdaptSample, 4>::new();
    let mut handed = 0;
    for k in 0..10 {
        p.step(&sample(0.05 * k as f32), &Command::OFF);
        handed += p.hand_over(&mut handoff) as u32;
    }
    assert_eq!(handed, 10, "every sample accepted");
    assert_eq!(p.snapshot().handoffs_dropped, 7);
    let kept: Vec<u32> = std::iter::from_fn(|| handoff.dequeue())
        .map(|s| s.index)
        .collect();
    assert_eq!(kept, [1, 2, 3]);
}

/// The adaptation task run only every `every` periods, over the firmware's queues: late
/// by up to the latency (4 periods) nothing is late; later, the updates of the samples
/// it reached after their deadline are applied at once and counted late (a third of
/// them at 6 periods, where samples 4 and 5 periods old miss it); beyond the hand-over
/// queue's room (15 samples), samples are dropped and counted.
#[test]
fn a_late_adaptation_task_shows_as_late_updates_and_dropped_samples() {
    let core = Config {
        sample_period_s: T,
        ..Config::default()
    };
    for every in [1u32, 4, 6, 20] {
        let mut p = period();
        let mut task = AdaptationTask::new(&core).unwrap();
        let mut handoff = Queue::<AdaptSample, HANDOFF_DEPTH>::new();
        let mut updates = Queue::<InjectionUpdate, UPDATE_DEPTH>::new();
        let (mut banks, mut spares) = (BankQueue::new(), SpareQueue::new());
        let mut taken = 0usize;
        let periods = 4000u32;
        for k in 1..=periods {
            let mut counted = Counted {
                inner: &mut updates,
                taken: Vec::new(),
            };
            p.apply_due(&mut counted, &mut banks, &mut spares);
            taken += counted.taken.len();
            p.step(&sample(0.05 * k as f32), &running());
            p.hand_over(&mut handoff);
            if k % every == 0 {
                task.run(
                    &mut handoff,
                    &mut updates,
                    &mut banks,
                    &mut spares,
                    None,
                    |_| {},
                );
            }
        }
        let s = p.snapshot();
        let what = format!("every {every}: {taken} updates, {s:?}");
        assert!(taken > 1000, "{what}");
        assert_eq!(task.updates_dropped(), 0, "{what}");
        match every {
            1 | 4 => assert_eq!((s.updates_late, s.handoffs_dropped), (0, 0), "{what}"),
            6 => {
                assert_eq!(s.handoffs_dropped, 0, "{what}");
                let third = taken as f64 / 3.0;
                assert!(
                    (s.updates_late as f64 - third).abs() < 0.02 * third,
                    "{what}"
                );
            }
            _ => assert_eq!(s.handoffs_dropped, periods / every * (every - 15), "{what}"),
        }
    }
}

/// A bank change (a record's bank from the data) while the update queue is full: it is
/// counted and owed, and nothing overtakes it. Once there is room the bank goes first,
/// then every path's term: the control period ends on the adapter's bank and
/// coefficients, bit for bit as a front that loaded them directly. (Silently dropped,
/// as the firmware's queue used to, the front stays on the first stage's bank.)
#[test]
fn a_bank_change_the_queue_cannot_take_goes_first_once_there_is_room() {
    let mut core = Config {
        sample_period_s: T,
        ..Config::default()
    };
    core.set_paths(&mras::survey::FIRST_STAGE).unwrap();
    core.paths_from_data = true;
    let bank = [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(10),
    ];
    let mut record = Coefficients::zeros(&bank);
    record.set(PathKind::Offset, Cplx::new(0.03, -0.01));
    record.set(PathKind::AmplitudeQuadrature, Cplx::new(-0.02, 0.004));
    record.set(PathKind::Harmonic(10), Cplx::new(0.01, 0.002));
    let install = Install {
        generation: 1,
        coefficients: record,
    };
    let mut p = ControlPeriod::new(config(), Front::new(core).unwrap()).unwrap();
    let mut task = AdaptationTask::new(&core).unwrap();
    let mut handoff = Queue::<AdaptSample, HANDOFF_DEPTH>::new();
    // Room for one update, and the task run every 10 periods: the adapter's own
    // updates (one per stride, 8 samples with this bank) come late, and at times two at
    // once, which the queue cannot take.
    let mut updates = Queue::<InjectionUpdate, 2>::new();
    let (mut banks, mut spares) = (BankQueue::new(), SpareQueue::new());
    let mut taken = Vec::new();
    let (mut installed_at, mut owing) = (None, false);
    for k in 1..=600u32 {
        let mut counted = Counted {
            inner: &mut updates,
            taken: Vec::new(),
        };
        p.apply_due(&mut counted, &mut banks, &mut spares);
        taken.extend(counted.taken.iter().map(|u| (k, *u)));
        p.step(&sample(0.05 * k as f32), &Command::OFF);
        p.hand_over(&mut handoff);
        if k % 10 == 0 {
            // Install when the task owes a term of the first stage's bank: it takes the
            // queue's one slot first, the bank finds it full.
            let now = (installed_at.is_none() && owing).then_some(install);
            if now.is_some() {
                installed_at = Some(k);
            }
            let before = task.updates_dropped();
            task.run(
                &mut handoff,
                &mut updates,
                &mut banks,
                &mut spares,
                now,
                |_| {},
            );
            owing = task.updates_dropped() > before;
        }
    }
    let k0 = installed_at.expect("the queue was full with a term owed");
    assert!(task.report().install.unwrap().accepted);
    // The bank and the three terms could not be queued (besides the term owed before).
    assert!(task.updates_dropped() > 4, "{}", task.updates_dropped());
    let after: Vec<InjectionUpdate> = taken
        .iter()
        .filter(|(k, _)| *k > k0)
        .map(|(_, u)| *u)
        .collect();
    // The one queued before the install, then the bank: nothing overtook it.
    assert!(matches!(after[0].change, Change::Term { .. }), "{after:?}");
    assert_eq!(after[1].change, Change::Bank(Bank::new(&bank).into()));
    // After the bank, only the new bank's terms, at the record's values (frozen: the
    // adapter's terms are its coefficients).
    for u in &after[2..] {
        let Change::Term { path, value } = u.change else {
            panic!("a second bank: {after:?}");
        };
        assert_eq!(Some(value), record.get(bank[path as usize]), "{u:?}");
    }
    let paths: std::collections::BTreeSet<u8> = after[2..]
        .iter()
        .filter_map(|u| match u.change {
            Change::Term { path, .. } => Some(path),
            _ => None,
        })
        .collect();
    assert_eq!(paths.len(), bank.len(), "every path's term went");
    // What the control period applied, replayed on a fresh front, is the record loaded
    // directly; the owed updates went after their period, and were counted late.
    let mut replayed = Front::new(core).unwrap();
    let mut loaded = Front::new(core).unwrap();
    loaded.load_injection(&record);
    for (_, u) in &taken {
        assert!(replayed.apply(&InjectionUpdate { apply_at: 0, ..*u }));
    }
    for k in 0..50 {
        let th = 0.05 * k as f32;
        let a = replayed.step(libm::cosf(th), libm::sinf(th), 0.0).unwrap();
        let b = loaded.step(libm::cosf(th), libm::sinf(th), 0.0).unwrap();
        assert_eq!(a.decoupled, b.decoupled, "sample {k}");
    }
    assert!(p.snapshot().updates_late > 0);
}

/// The shunts read are the two whose low sides conduct longest around the peak: over the
/// whole linear range of SVPWM (every angle, up to |v| = Vdc/√3, the vector turning
/// 31 mrad per period as at 100 Hz electrical and 20 kHz) their duties stay below 0.94
/// (1/2 + √3/4 = 0.933 for a still vector) before and after the peak, while the unread
/// phase reaches 1.
#[test]
fn the_two_shunts_read_conduct_at_least_6_percent_of_the_period_over_the_linear_range() {
    use drive::control::phases_to_read;
    use drive::foc::svpwm;
    let vdc = 24.0_f32;
    let mut worst_read = 0.0_f32;
    let mut worst_unread = 0.0_f32;
    for k in 0..3600 {
        let a = k as f32 * core::f32::consts::TAU / 3600.0;
        let b = a + core::f32::consts::TAU * 100.0 / 20_000.0;
        let m = vdc / 3.0_f32.sqrt();
        let (before, _) = svpwm(m * libm::cosf(a), m * libm::sinf(a), vdc);
        let (after, _) = svpwm(m * libm::cosf(b), m * libm::sinf(b), vdc);
        let skip = phases_to_read(&before, &after);
        for ph in 0..3 {
            let d = before[ph].max(after[ph]);
            if ph == skip {
                worst_unread = worst_unread.max(d);
            } else {
                worst_read = worst_read.max(d);
            }
        }
    }
    assert!(worst_read < 0.94, "{worst_read}");
    assert!(worst_unread > 0.999, "{worst_unread}");
}

/// With the bridge running at a high duty on phase a, the current comes from shunts b
/// and c: a shunt a that shows no current (its low side never conducted) does not move
/// the measured currents.
#[test]
fn a_phase_at_high_duty_is_reconstructed_from_the_other_two() {
    let mut p = period();
    let cmd = running();
    // Commissioned zero at mid-scale; any Run output sets the duties of the next read.
    let out = p.step(&sample(0.0), &cmd);
    assert!(out.enable, "{out:?}");
    // i_a = 2 A, i_b = -1.5 A, i_c = -0.5 A in counts (amps_per_count of `config`).
    let k = config().current.amps_per_count;
    let counts = |i: f32| (2048.0 + i / k).round() as u16;
    let read = Sample {
        ia: counts(2.0),
        ib: counts(-1.5),
        ic: counts(-0.5),
        ..sample(0.0)
    };
    let skip = drive::control::phases_to_read(&[0.5; 3], &out.duties);
    let blind = Sample {
        ia: if skip == 0 { 2048 } else { read.ia },
        ib: if skip == 1 { 2048 } else { read.ib },
        ic: if skip == 2 { 2048 } else { read.ic },
        ..read
    };
    p.step(&blind, &cmd);
    let (ia, ib) = p.last_currents_a();
    let tol = 1.01 * k.abs();
    assert!(
        (ia - 2.0).abs() < tol && (ib + 1.5).abs() < tol,
        "{ia} {ib} (phase {skip} unread)"
    );
}

/// The banks' decoupling vectors the control period took (each one's bank).
struct BanksTaken<'a> {
    inner: &'a mut BankQueue,
    taken: Vec<PackedBank>,
}

impl Receiver<Prepared<Injection>> for BanksTaken<'_> {
    fn peek(&self) -> Option<&Prepared<Injection>> {
        self.inner.peek()
    }
    fn receive(&mut self) -> Option<Prepared<Injection>> {
        let p = self.inner.receive();
        self.taken.extend(p.as_ref().map(|p| *p.injection.bank()));
        p
    }
}

/// A bank from the data, over the firmware's queues: every bank a survey round puts in
/// force, and then a record's bank, reach the control period built whole by the task and
/// are swapped in (the second in the vector the first replaced); none is left over, none
/// is late, and at every
/// period the decoupling vector in force is bit for bit that of a control period given
/// the same updates alone, which builds each bank in place.
#[test]
fn every_survey_bank_comes_built_and_equals_the_bank_built_in_place() {
    let mut core = Config {
        sample_period_s: T,
        paths_from_data: true,
        ..Config::default()
    };
    core.set_paths(&mras::survey::FIRST_STAGE).unwrap();
    let mut p = ControlPeriod::new(config(), Front::new(core).unwrap()).unwrap();
    let mut in_place = ControlPeriod::new(config(), Front::new(core).unwrap()).unwrap();
    let mut task = AdaptationTask::new(&core).unwrap();
    let mut handoff = Queue::<AdaptSample, HANDOFF_DEPTH>::new();
    let mut updates = Queue::<InjectionUpdate, UPDATE_DEPTH>::new();
    let mut bank_queue = BankQueue::new();
    let mut built = BanksTaken {
        inner: &mut bank_queue,
        taken: Vec::new(),
    };
    let mut spares = SpareQueue::new();
    let cmd = Command {
        adaptation: Adaptation::Commissioning,
        ..running()
    };
    let mut banks = Vec::new();
    let bank = [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(-5),
    ];
    let mut record = Coefficients::zeros(&bank);
    record.set(PathKind::Offset, Cplx::new(0.03, -0.01));
    record.set(PathKind::Harmonic(-5), Cplx::new(0.01, 0.002));
    let mut installed_at = None;
    // A sensor with an offset and a third harmonic, for the survey to find.
    let x = |th: f32| (th + 0.02 * libm::sinf(3.0 * th), 0.03);
    for k in 1..=40_000u32 {
        let mut counted = Counted {
            inner: &mut updates,
            taken: Vec::new(),
        };
        p.apply_due(&mut counted, &mut built, &mut spares);
        for u in &counted.taken {
            assert!(
                in_place.apply(u),
                "period {k}: {u:?} taken before it was due"
            );
        }
        assert_eq!(
            p.tracker().injection(),
            in_place.tracker().injection(),
            "period {k}"
        );
        banks.extend(counted.taken.iter().filter_map(|u| match u.change {
            Change::Bank(b) => Some(b),
            _ => None,
        }));
        let (th, off) = x(0.05 * k as f32);
        let mut s = sample(th);
        s.x = (s.x as f32 + off * AMPLITUDE).round() as u16;
        p.step(&s, &cmd);
        in_place.step(&s, &cmd);
        p.hand_over(&mut handoff);
        // Once the survey's bank is in force, a record of another bank (from flash):
        // built in the vector the survey's bank replaced.
        let surveyed = !task.adapter().surveying() && !banks.is_empty() && updates.is_empty();
        let install = (surveyed && installed_at.is_none()).then(|| {
            installed_at = Some(k);
            Install {
                generation: 1,
                coefficients: record,
            }
        });
        task.run(
            &mut handoff,
            &mut updates,
            built.inner,
            &mut spares,
            install,
            |_| {},
        );
        if installed_at.is_some_and(|i| k > i + 10) {
            break;
        }
    }
    assert!(task.report().install.unwrap().accepted);
    assert_eq!(banks.len(), 2, "{:?}", p.snapshot());
    assert!(!task.adapter().surveying());
    assert_eq!(built.taken, banks);
    assert!(built.inner.is_empty());
    assert_eq!(p.snapshot().updates_late, 0);
    assert_eq!(banks[1], Bank::new(&bank).into());
}

/// A bank's update whose vector was not built (no spare was at hand) is built in place,
/// and a vector queued for a later update is not taken for it: the later update swaps
/// it in, and the vector it replaced goes back. A vector of another bank for the same
/// period is not taken either.
#[test]
fn a_bank_without_its_vector_is_built_in_place_and_a_later_ones_vector_waits() {
    let core = Config {
        sample_period_s: T,
        ..Config::default()
    };
    let first = [
        PathKind::Offset,
        PathKind::AmplitudeQuadrature,
        PathKind::Harmonic(5),
    ];
    let second = [PathKind::Offset, PathKind::Harmonic(-4)];
    let bank = |paths: &[PathKind], at: u32| InjectionUpdate {
        apply_at: at,
        change: Change::Bank(Bank::new(paths).into()),
    };
    let term = |at: u32| InjectionUpdate {
        apply_at: at,
        change: Change::Term {
            path: 1,
            value: Cplx::new(0.01, -0.02),
        },
    };
    let mut updates = Queue::<InjectionUpdate, UPDATE_DEPTH>::new();
    let mut banks = BankQueue::new();
    let mut spares = SpareQueue::new();

    // Another bank's vector at the first's period: refused by its bank.
    let mut p = period();
    p.step(&sample(0.0), &Command::OFF);
    let now = p.tracker().index();
    let mut other = Injection::new(core.paths());
    other.apply(&bank(&second, now + 1).change, None);
    let other = Prepared {
        apply_at: now + 1,
        injection: other,
    };
    banks.enqueue(other).unwrap();
    updates.enqueue(bank(&first, now + 1)).unwrap();
    p.apply_due(&mut updates, &mut banks, &mut spares);
    assert_eq!(p.tracker().injection().kinds(), &first[..]);
    assert_eq!(banks.len(), 1);
    assert!(spares.is_empty());

    // A later update's vector (the same bank again, with a term) queued ahead of the
    // first bank's update: the first is built in place, the later one swapped in at
    // its own period.
    let mut p = period();
    p.step(&sample(0.0), &Command::OFF);
    let now = p.tracker().index();
    let mut built = Injection::new(core.paths());
    for u in [bank(&first, now + 1), bank(&first, now + 2), term(now + 2)] {
        built.apply(&u.change, None);
    }
    let mut banks = BankQueue::new();
    banks
        .enqueue(Prepared {
            apply_at: now + 2,
            injection: built,
        })
        .unwrap();
    for u in [bank(&first, now + 1), bank(&first, now + 2), term(now + 2)] {
        updates.enqueue(u).unwrap();
    }
    p.apply_due(&mut updates, &mut banks, &mut spares);
    let mut in_place = Injection::new(core.paths());
    in_place.apply(&bank(&first, now + 1).change, None);
    assert_eq!(p.tracker().injection(), &in_place);
    assert_eq!((banks.len(), updates.len()), (1, 2));
    p.step(&sample(0.05), &Command::OFF);
    p.apply_due(&mut updates, &mut banks, &mut spares);
    assert_eq!(p.tracker().injection(), &built);
    assert!(banks.is_empty() && updates.is_empty());
    // The vector the swap replaced is the first bank's, built in place.
    assert_eq!(spares.dequeue().unwrap().kinds(), &first[..]);
    assert_eq!(p.snapshot().updates_late, 0);
}

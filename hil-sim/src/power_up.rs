//! The `commissioning` scenario: the firmware's own power-up state machine
//! (`drive::commissioning`) and flash record (`calib_record`, on a simulated flash)
//! driving the simulated drive, for two power-ups: the first with an erased flash
//! (self-commissioning, then store), the second with the stored calibration.

use crate::drive::{Drive, Mode};
use crate::scenario::{NamedCoefficient, Scenario, Window, WindowStats};
use crate::sensor::SensorSim;
use calib_record::{config_hash, RamFlash};
use drive::commissioning::{
    Adaptation, Cause, Commissioning, Inputs, LoadStatus, Request, Setpoint, State, StoreStatus,
};
use mras::Tracker;
use std::f64::consts::TAU;

/// The supervisor runs every this many control periods (1 kHz at 20 kHz, as on the MCU).
pub const SUPERVISOR_DIVIDER: u64 = 20;

/// What one power-up did.
#[derive(Clone, Debug)]
pub struct Boot {
    /// (time, state entered).
    pub transitions: Vec<(f64, State)>,
    pub final_state: State,
    pub cause: Option<Cause>,
    pub loaded_from_flash: bool,
    /// Spatial error over the last 0.1 s of spin-up (uncorrected sensor), if reached.
    pub spin_up: Option<WindowStats>,
    /// Spatial error over the last 20 % of the run, if in Run by then.
    pub run: Option<WindowStats>,
    /// Time adapting (Adapt state) and revolutions over it.
    pub adapt_s: Option<f64>,
    pub adapt_revs: Option<f64>,
    pub faulted_samples: u32,
    pub coefficients: Vec<NamedCoefficient>,
}

impl Boot {
    pub fn entered(&self, s: State) -> Option<f64> {
        self.transitions
            .iter()
            .find(|(_, x)| *x == s)
            .map(|(t, _)| *t)
    }
}

/// Run one power-up for `duration_s` on `flash`.
pub fn boot(
    sc: &Scenario,
    flash: &mut RamFlash,
    seed: u64,
    duration_s: f64,
) -> Result<Boot, String> {
    let f = &sc.file;
    let c = f
        .commissioning
        .ok_or_else(|| format!("{}: no [commissioning] table", sc.origin))?;
    let cfg = sc.core_config(None)?;
    let hash = config_hash(&cfg);
    let mut tracker = Tracker::new(cfg).map_err(|e| e.to_string())?;
    let t_s = sc.sample_period_s();
    let motor = f.motor.to_params()?;
    let j_hat = motor.j_kg_m2 * f.inertia_estimate_ratio;
    let sensor = SensorSim::new(f.sensor.to_params()?, seed)?;
    let mut drive = Drive::new(motor, f.control.to_params()?, sensor, t_s, j_hat)?;
    let mut sm = Commissioning::new(c.params());
    let n = f.sensor.sensor_periods as f64;

    let steps = (duration_s / t_s).round() as u64;
    let mut transitions = vec![(0.0, sm.state())];
    let (mut load, mut store) = (LoadStatus::Pending, StoreStatus::Pending);
    let (mut fault, mut faulted) = (None, 0u32);
    // Spin-up error: the last complete 0.1 s slice before adaptation starts.
    const SLICE_S: f64 = 0.1;
    let (mut spin_slice, mut spin_up): (Option<(f64, Window)>, Option<Window>) = (None, None);
    let mut run = Window::new(0.8 * duration_s, duration_s + t_s);
    let mut adapt_start: Option<(f64, f64)> = None;
    let (mut adapt_s, mut adapt_revs) = (None, None);
    let apply = |sm: &Commissioning, drive: &mut Drive, tracker: &mut Tracker| {
        let o = sm.outputs();
        drive.mode = match o.setpoint {
            Setpoint::Off => Mode::Off,
            Setpoint::Align { current_a } => Mode::Align {
                current_a: current_a as f64,
            },
            Setpoint::Speed { omega_rad_s } => Mode::Speed {
                omega_rad_s: omega_rad_s as f64,
            },
            Setpoint::Application => Mode::Reference,
        };
        tracker.set_frozen(o.adaptation == Adaptation::Frozen);
    };
    apply(&sm, &mut drive, &mut tracker);
    for k in 0..steps {
        let s = drive.step(&mut tracker);
        if let Err(e) = s.result {
            faulted += 1;
            fault.get_or_insert(e);
        }
        match sm.state() {
            State::SpinUp => {
                let (t0, w) =
                    spin_slice.get_or_insert_with(|| (s.t_s, Window::new(0.0, f64::INFINITY)));
                if s.t_s - *t0 >= SLICE_S {
                    spin_up = spin_slice.take().map(|(_, w)| w);
                } else {
                    w.add(&s, n);
                }
            }
            State::Run => run.add(&s, n),
            _ => {}
        }
        if (k + 1) % SUPERVISOR_DIVIDER != 0 {
            continue;
        }
        let o = sm.outputs();
        match o.request {
            Request::LoadCalibration if load == LoadStatus::Pending => {
                load = match calib_record::load(flash, hash) {
                    Ok(l) if tracker.set_coefficients(&l.record.coefficients).is_ok() => {
                        LoadStatus::Loaded
                    }
                    _ => LoadStatus::Unavailable,
                }
            }
            Request::StoreCalibration if store == StoreStatus::Pending => {
                store = match calib_record::store(flash, &tracker.coefficients(), hash) {
                    Ok(_) => StoreStatus::Done,
                    Err(_) => StoreStatus::Failed,
                }
            }
            _ => {}
        }
        let conv = tracker.convergence();
        let before = sm.state();
        sm.step(&Inputs {
            dt_s: (SUPERVISOR_DIVIDER as f64 * t_s) as f32,
            fault: fault.take(),
            overcurrent: false,
            omega_rad_s: s.estimate.omega_rad_s,
            converged: conv.converged,
            residual_max_rad: conv.residual_rad[..conv.len as usize]
                .iter()
                .fold(0.0, |a, b| a.max(*b)),
            load,
            store,
        });
        if sm.state() != before {
            transitions.push((s.t_s, sm.state()));
            if sm.state() == State::Adapt {
                adapt_start = Some((s.t_s, s.theta_rad));
            }
            if before == State::Adapt {
                if let Some((t0, th0)) = adapt_start {
                    adapt_s = Some(s.t_s - t0);
                    adapt_revs = Some((s.theta_rad - th0).abs() / TAU);
                }
            }
            apply(&sm, &mut drive, &mut tracker);
        }
    }
    let in_run = sm.state() == State::Run;
    Ok(Boot {
        final_state: sm.state(),
        cause: sm.cause(),
        loaded_from_flash: sm.calibration_loaded(),
        spin_up: spin_up.map(|w| w.stats()),
        run: in_run.then(|| run.stats()),
        adapt_s,
        adapt_revs,
        faulted_samples: faulted,
        coefficients: tracker
            .coefficients()
            .iter()
            .map(|(k, v)| (crate::scenario::path_name(k), v.re, v.im))
            .collect(),
        transitions,
    })
}

/// Both power-ups: erased flash, then the flash the first one left.
pub fn run(sc: &Scenario, duration_s: f64) -> Result<(Boot, Boot), String> {
    let mut flash = RamFlash::default();
    let first = boot(sc, &mut flash, sc.file.seed, duration_s)?;
    let second = boot(sc, &mut flash, sc.file.seed + 1, duration_s)?;
    Ok((first, second))
}

/// The printed report.
pub fn report(sc: &Scenario, boots: &[(&str, &Boot)]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "scenario {}: {}", sc.file.name, sc.file.description);
    for (title, b) in boots {
        let _ = writeln!(s, "  power-up {title}:");
        for (t, st) in &b.transitions {
            let _ = writeln!(s, "    {t:8.3} s  {}", st.name());
        }
        match b.cause {
            Some(c) => {
                let _ = writeln!(s, "    SAFE STATE: {c:?}");
            }
            None => {
                let _ = writeln!(
                    s,
                    "    calibration {}",
                    if b.loaded_from_flash {
                        "loaded from flash"
                    } else {
                        "commissioned and stored"
                    }
                );
            }
        }
        if let (Some(t), Some(r)) = (b.adapt_s, b.adapt_revs) {
            let _ = writeln!(
                s,
                "    adaptation converged in {t:.2} s / {r:.1} revolutions"
            );
        }
        if let Some(w) = &b.spin_up {
            let _ = writeln!(
                s,
                "    spatial error at the end of spin-up (uncorrected): raw {:.2}, θ̂ {:.2} mrad pk-pk",
                w.raw_pk_pk_mrad, w.estimate_pk_pk_mrad
            );
        }
        if let Some(w) = &b.run {
            let _ = writeln!(
                s,
                "    spatial error in Run (last 20 %): raw {:.2}, θ̂ {:.4} mrad pk-pk ({:.0}x), RMS {:.4} mrad",
                w.raw_pk_pk_mrad,
                w.estimate_pk_pk_mrad,
                w.raw_pk_pk_mrad / w.estimate_pk_pk_mrad,
                w.estimate_rms_mrad
            );
        }
        let _ = writeln!(s, "    faulted samples: {}", b.faulted_samples);
        let coefs: Vec<String> = b
            .coefficients
            .iter()
            .map(|(n, re, im)| format!("{n} {re:+.4}{im:+.4}j"))
            .collect();
        let _ = writeln!(s, "    coefficients: {}", coefs.join(", "));
    }
    s
}

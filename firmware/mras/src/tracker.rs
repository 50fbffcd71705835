//! The core per control period: [`Front::step`] (observer, decoupling vector, health)
//! in the control interrupt, [`Adapter::step`] (the MRAS adaptation) on the samples it
//! hands over, and [`Tracker`], both run inline for the host.

use crate::adapter::Adapter;
use crate::coefficients::{CoefficientsError, Convergence};
use crate::complex::Cplx;
use crate::config::{Config, ConfigError};
use crate::decoupler::{AdaptSample, Change, Injection, InjectionUpdate};
use crate::health::{Fault, Faults};
use crate::observer::{DiscreteGains, ObserverGains, ObserverState};
use crate::trig::{inv_sqrt_f32, sin_cos_f32, F32Trig, Trig};
use crate::Coefficients;
use core::borrow::BorrowMut;
use core::f32::consts::{PI, TAU};

/// What the observer knows after one sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Estimate {
    /// θ̂rm, mechanical angle in [0, 2π), at the instant of this sample.
    pub theta_rad: f32,
    /// Whole mechanical turns (θ̂ continuous = turns·2π + theta_rad).
    pub turns: i32,
    /// θ̂s, sensor electrical angle in [0, 2π).
    pub theta_e_rad: f32,
    /// ω̂rm (rad/s).
    pub omega_rad_s: f32,
    /// Disturbance torque estimate K_iso∫ε (N·m).
    pub disturbance_nm: f32,
    /// |Zd| of the decoupled vector at this sample (scaled units).
    pub amplitude: f32,
    /// ε: angle between the decoupled vector and the reference (rad, sensor electrical).
    pub epsilon_rad: f32,
    /// Whether any path adapted on this sample ([`Tracker`] only: the [`Front`] does
    /// not know, its adaptation runs elsewhere).
    pub adapting: bool,
    /// The decoupled vector Zd = Z + D(θ̂s) (scaled units), for plots of the corrected
    /// sensor image (paper Fig. 8a).
    pub decoupled: Cplx,
}

impl Estimate {
    /// Continuous mechanical angle (f64: exact for any realistic turn count).
    pub fn theta_unwrapped_rad(&self) -> f64 {
        self.turns as f64 * core::f64::consts::TAU + self.theta_rad as f64
    }
}

/// The part of the core that runs on every sample: observer, decoupling vector and health
/// monitor. Every accepted sample leaves an [`AdaptSample`] for the [`Adapter`], whose
/// [`InjectionUpdate`]s come back through [`Front::apply`].
///
/// `S` holds the decoupling vector: by value, or a pointer the control period swaps for
/// another when a new bank comes in force ([`Self::swap_injection`]; the firmware's
/// `&'static mut Injection`).
#[derive(Clone, Debug)]
pub struct Front<T: Trig = F32Trig, S: BorrowMut<Injection> = Injection> {
    cfg: Config,
    trig: T,
    gains: ObserverGains,
    discrete: DiscreteGains,
    obs: ObserverState,
    /// `obs.periods` split into (sensor period within the turn, turns); refreshed only
    /// when the period count changes, to keep integer division out of most samples.
    mech: (i32, i32),
    /// The decoupling vector's terms (eq. 9, 16), as the adaptation last updated them.
    inject: S,
    /// Periods stepped (wrapping): the clock of [`InjectionUpdate::apply_at`].
    index: u32,
    /// The last accepted sample for the adaptation, and whether it is this period's.
    handoff: AdaptSample,
    handed: bool,
    /// |Z| of an acquisition, handed over with the first sample after it (flag set).
    restart: bool,
    restart_amplitude: f32,
    acquired: bool,
    /// Accepted samples left in the acquisition window under way; 0: locked. See
    /// [`Acquisition`].
    acq_left: u16,
    acq: Acquisition,
    /// The period of the last accepted sample (how long a run of refused ones lasts).
    accepted_index: u32,
    frozen: bool,
    faults: Faults,
    last: Estimate,
    cos_lock: f32,
    /// cos of half the lock threshold: a sample further from the reference is a slip
    /// under way or a sensor reading garbage, and is not adapted on.
    cos_adapt: f32,
    inv_n: f32,
    /// |Z|² limits of the health band (min², max²).
    amplitude2_band: [f32; 2],
    /// ε low-passed over [`LAG_TAU_S`]: the observer's lag (sensor-electrical rad).
    lag_rad: f32,
    lag_alpha: f32,
}

/// Lock acquisition (docs/theory.md §6): the observer is (re)started at the sensor's
/// angle and at the speed measured from the sensor's own phase advance over a window
/// of samples, and declared locked only after a whole window in which its angle error
/// stayed below the lock threshold.
#[derive(Clone, Copy, Debug)]
struct Acquisition {
    /// Phase advances per window: one time constant of the fastest eigenvalue, so that
    /// what the sensor's error adds to the measured speed (at most its pk-pk angle error
    /// over that time) is pulled in by the observer well within the lock threshold.
    window: u16,
    /// Σ of the phase advance from each accepted sample to the next (sensor-electrical
    /// rad, unwrapped: valid up to ~1 rad per sample), and how many.
    advance_rad: f32,
    count: u16,
    /// The previous accepted sample of the window (`ZERO`: none, after a refused one:
    /// the measurement starts again there).
    prev: Cplx,
    /// At the measurement's first sample, the decoupled vector's angle less the raw
    /// one. The measured advance is that of the raw vector; moving both ends onto the
    /// decoupled vector removes the sensor error the coefficients already know.
    start_corr_rad: f32,
    /// The last phase advance: a sensor turning at any plausible speed changes it by far
    /// less than [`MAX_ADVANCE_CHANGE_RAD`] from one sample to the next.
    last_advance_rad: f32,
    /// Restart the observer at the window's end (the lock was lost in it, or the
    /// estimate was held too long to be trusted).
    reseed: bool,
    /// First window after a start at rest: restart it also when the measured speed is
    /// further from ω̂ than `speed_tol_rad_s` (a flying start the observer would not
    /// pull in from rest without slipping).
    speed_check: bool,
    /// A quarter of the fastest eigenvalue over N (rad/s mechanical): an observer off by
    /// this much in speed stays well inside the lock threshold while it settles.
    speed_tol_rad_s: f32,
    /// 1/(N·T·window): a window's phase advance (sensor-electrical rad) to ω (rad/s
    /// mechanical), worked out once: the window's end is a control period's, and its
    /// other work (the decoupled angle at both ends) makes it the longest.
    per_window_to_rad_s: f32,
}

/// Largest change of the phase advance from one sample to the next that a sensor
/// reading its rotor can show (sensor-electrical rad). Its error changes the advance by
/// the error's second derivative times the advance squared: ~0.01 rad at 100 rev/s,
/// 20 kHz, N = 2 on the extreme test sensor; noise adds ~1e-3. A sensor reading garbage
/// changes it by a radian.
const MAX_ADVANCE_CHANGE_RAD: f32 = 0.1;

/// A run of refused samples after which the held estimate may be this far from the
/// rotor (sensor-electrical rad): re-acquire rather than trust it. Half the default lock
/// threshold, so that a slip by a whole period (which the lock test cannot see) is
/// never taken for lock.
const HELD_DRIFT_LIMIT_RAD: f32 = 0.5;

/// The lag estimate's time constant: short against the disturbance estimate's settling
/// (the slowest eigenvalue, ~0.1 s), long against the sample period, so that noise on ε
/// averages out.
const LAG_TAU_S: f32 = 2.0e-3;
/// Beyond this the first-order placement is not trusted (acquisition, loss of lock).
const MAX_LAG_RAD: f32 = 0.2;

impl Front<F32Trig> {
    /// A front with the portable trigonometry.
    pub fn new(cfg: Config) -> Result<Self, ConfigError> {
        Self::with_trig(cfg, F32Trig)
    }
}

impl<T: Trig> Front<T> {
    /// A front with a given trigonometry implementation (e.g. the CORDIC).
    pub fn with_trig(cfg: Config, trig: T) -> Result<Self, ConfigError> {
        Front::with_store(cfg, trig, Injection::EMPTY)
    }
}

impl<T: Trig, S: BorrowMut<Injection>> Front<T, S> {
    /// [`Front::with_trig`], its decoupling vector kept in `store` (given the
    /// configured bank, every term zero).
    pub fn with_store(cfg: Config, trig: T, mut store: S) -> Result<Self, ConfigError> {
        cfg.validate()?;
        *store.borrow_mut() = Injection::new(cfg.paths());
        let gains = ObserverGains::from_eigenvalues(
            cfg.observer.eigenvalues_hz,
            cfg.observer.inertia_kg_m2,
        );
        let n = cfg.sensor_periods as f32;
        let [l1, l2, l3] = gains.lambda_rad_s;
        let fastest_rad_s = l1.max(l2).max(l3);
        // ≥ 8 samples, so that a window spans several phase advances even with a
        // fast observer; ≤ 1000, so that it stays short on a slow one.
        let window = ((1.0 / (fastest_rad_s * cfg.sample_period_s)) as u16)
            .saturating_add(1)
            .clamp(8, 1000);
        let acq = Acquisition {
            window,
            advance_rad: 0.0,
            count: 0,
            prev: Cplx::ZERO,
            start_corr_rad: 0.0,
            last_advance_rad: 0.0,
            reseed: false,
            speed_check: false,
            speed_tol_rad_s: 0.25 * fastest_rad_s / n,
            per_window_to_rad_s: 1.0 / (n * cfg.sample_period_s * window as f32),
        };
        Ok(Self {
            acq_left: 1,
            acq,
            accepted_index: 0,
            inject: store,
            index: 0,
            handoff: AdaptSample::default(),
            handed: false,
            restart: false,
            restart_amplitude: 0.0,
            discrete: DiscreteGains::new(&gains, cfg.sample_period_s, cfg.sensor_periods),
            gains,
            obs: ObserverState::default(),
            mech: (0, 0),
            acquired: false,
            frozen: false,
            faults: Faults::default(),
            last: Estimate::default(),
            cos_lock: sin_cos_f32(cfg.health.lock_threshold_rad).1,
            cos_adapt: sin_cos_f32(0.5 * cfg.health.lock_threshold_rad).1,
            inv_n: 1.0 / cfg.sensor_periods as f32,
            lag_rad: 0.0,
            lag_alpha: (cfg.sample_period_s / LAG_TAU_S).min(1.0),
            amplitude2_band: [
                cfg.health.amplitude_min * cfg.health.amplitude_min,
                cfg.health.amplitude_max * cfg.health.amplitude_max,
            ],
            cfg,
            trig,
        })
    }

    pub fn config(&self) -> &Config {
        &self.cfg
    }

    pub fn gains(&self) -> &ObserverGains {
        &self.gains
    }

    /// The trigonometry the core uses, for callers that must use the same (FOC).
    pub fn trig(&self) -> &T {
        &self.trig
    }

    /// One control period: the sensor vector in scaled units (the front end's
    /// `(raw - offset) · gain`, nominal |Z| = 1) and the torque feedforward T* (N·m).
    ///
    /// On `Err` for bad input (non-finite, |Z| out of band) nothing but the latched
    /// fault set changes. `Err(LossOfLock)` comes once, on the sample where a locked
    /// observer lost its lock: the observer has still advanced, re-acquires by itself,
    /// and adaptation pauses until [`Self::is_locked`] again.
    ///
    /// An accepted sample (`Ok`, or `Err(LossOfLock)`) leaves its [`AdaptSample`] for
    /// [`Self::handoff`]. Updates due by this period must have been applied first.
    pub fn step(&mut self, x: f32, y: f32, torque_ff_nm: f32) -> Result<Estimate, Fault> {
        self.index = self.index.wrapping_add(1);
        self.handed = false;
        // One comparison each rejects NaN and ±inf.
        if !(libm::fabsf(x) < f32::INFINITY
            && libm::fabsf(y) < f32::INFINITY
            && libm::fabsf(torque_ff_nm) < f32::INFINITY)
        {
            return self.reject(Fault::NonFiniteInput);
        }
        let z = Cplx::new(x, y);
        let z2 = z.norm_sqr();
        // Written so that a NaN also lands on the rejecting side.
        let below_max = z2 <= self.amplitude2_band[1];
        if !below_max {
            return self.reject(Fault::SensorSaturated);
        }
        if z2 < self.amplitude2_band[0] {
            return self.reject(Fault::SensorLost);
        }
        if self.acq_left != 0 {
            // Not locked: start at the measured angle, or measure the sensor's speed and
            // restart there; then run this sample as any other.
            self.acquiring(z);
        }

        // Reference unit vector at the prior estimate θ̂s.
        let (s, c) = self.trig.sin_cos(self.obs.theta_e_rad);
        let u = Cplx::new(c, s);
        // The decoupling vector is evaluated at the sensor's angle, θ̂s + lag: at u turned
        // by e^{j·lag} ≈ 1 - lag²/2 + j·lag (|lag| ≤ 0.2 rad).
        let lag = self.lag_rad;
        let u_sensor = u * Cplx::new(1.0 - 0.5 * lag * lag, lag);

        // Decoupled vector and the cross-product error, normalised by |Zd|.
        let zd = z + self.inject.borrow().vector(u_sensor);
        let zd2 = zd.norm_sqr();
        if zd2 < 0.25 * self.amplitude2_band[0] {
            // Coefficients plus input cancel the vector: nothing to track on.
            return self.reject(Fault::SensorLost);
        }
        let inv_zd = inv_sqrt_f32(zd2);
        let zd_abs = zd2 * inv_zd;
        let eps_e_rad = (zd.im * c - zd.re * s) * inv_zd;
        // The slow part of ε is the observer's lag behind the sensor angle (ε's harmonics
        // are the residual sensor error): low-passed and bounded, it places the next
        // decoupling vector (`Injection::vector`).
        self.lag_rad = (self.lag_rad + (eps_e_rad - self.lag_rad) * self.lag_alpha)
            .clamp(-MAX_LAG_RAD, MAX_LAG_RAD);
        let cos_err = (zd.re * c + zd.im * s) * inv_zd;
        let lock_lost = cos_err < self.cos_lock && self.lock_lost(z);

        let n = self.cfg.sensor_periods;
        let next = self
            .obs
            .advanced(&self.discrete, eps_e_rad * self.inv_n, torque_ff_nm);
        if !next.is_finite() {
            return self.reject(Fault::NumericalOverflow);
        }
        let amplitude = zd_abs;
        let o = &self.obs;
        let flags = if self.acq_left != 0 || cos_err < self.cos_adapt {
            0
        } else {
            AdaptSample::LOCKED
        } | if self.frozen { AdaptSample::FROZEN } else { 0 }
            | if self.restart {
                AdaptSample::RESTART
            } else {
                0
            };
        self.restart = false;
        self.handed = true;
        self.handoff = AdaptSample {
            index: self.index,
            eps_e_rad,
            u: Cplx::new(c, s),
            omega_rad_s: o.omega_rad_s,
            amplitude,
            disturbance_nm: o.disturbance_nm,
            torque_ff_nm,
            restart_amplitude: self.restart_amplitude,
            flags,
        };

        let mut est = self.estimate_of(&self.obs, amplitude, eps_e_rad, false);
        est.decoupled = zd;
        if next.periods != self.obs.periods {
            self.mech = Self::step_split(self.mech, self.obs.periods, next.periods, n);
        }
        self.obs = next;
        self.last = est;
        self.accepted_index = self.index;
        if lock_lost {
            Err(Fault::LossOfLock)
        } else {
            Ok(est)
        }
    }

    /// A control period whose sample the front end refused (a railed ADC channel:
    /// `SensorSaturated`; an open input: `SensorLost`): counted, the estimate held and
    /// `f` latched, as when the core refuses a sample itself. Without it the held-drift
    /// check would not see the time that passed.
    pub fn refuse(&mut self, f: Fault) -> Fault {
        self.index = self.index.wrapping_add(1);
        self.handed = false;
        let _ = self.reject(f);
        f
    }

    fn reject(&mut self, f: Fault) -> Result<Estimate, Fault> {
        self.faults.insert(f);
        self.held();
        Err(f)
    }

    /// A refused sample: the window's phase advance must restart after it, and once the
    /// held estimate may have drifted past [`HELD_DRIFT_LIMIT_RAD`] the lock is void.
    #[cold]
    #[inline(never)]
    fn held(&mut self) {
        self.acq.prev = Cplx::ZERO;
        if self.acq_left == 0 {
            let periods = self.index.wrapping_sub(self.accepted_index) as f32;
            let drift_rad = periods * libm::fabsf(self.obs.omega_rad_s) * self.discrete.n_t_s;
            if drift_rad > HELD_DRIFT_LIMIT_RAD {
                self.start_window(Cplx::ZERO, true);
            }
        }
    }

    /// The angle error passed the lock threshold on this sample: when locked, lock is
    /// lost (latched, reported once) and re-acquisition starts; during a window, the
    /// observer is restarted at its end. True when lock was lost on this sample.
    #[cold]
    #[inline(never)]
    fn lock_lost(&mut self, z: Cplx) -> bool {
        if self.acq_left != 0 {
            self.acq.reseed = true;
            return false;
        }
        self.faults.insert(Fault::LossOfLock);
        self.start_window(z, true);
        true
    }

    /// Begin a window of [`Acquisition::window`] phase advances after the accepted
    /// sample `z` (`ZERO`: from the next accepted one); `reseed` forces a restart of the
    /// observer at its end.
    fn start_window(&mut self, z: Cplx, reseed: bool) {
        self.open_window(reseed);
        if z != Cplx::ZERO {
            self.measure_from(z);
        }
    }

    /// [`Self::start_window`] without a first sample.
    fn open_window(&mut self, reseed: bool) {
        self.acq_left = 1;
        self.acq.prev = Cplx::ZERO;
        self.acq.reseed = reseed;
        self.acq.speed_check = false;
    }

    /// The speed measurement starts at `z`.
    fn measure_from(&mut self, z: Cplx) {
        let c = self.decoupled_correction(z, angle_of(z));
        self.measure_from_corrected(z, c);
    }

    /// The speed measurement starts at `z`, whose decoupled angle less its raw one is
    /// `corr_rad`.
    fn measure_from_corrected(&mut self, z: Cplx, corr_rad: f32) {
        self.acq.advance_rad = 0.0;
        self.acq.count = 0;
        self.acq.prev = z;
        self.acq.start_corr_rad = corr_rad;
    }

    /// The angle of the decoupled vector `z + D(θ)` at its own angle, less the raw angle
    /// `raw` of `z` (two fixed-point steps from `raw`): where θ̂ would be, locked, with
    /// the coefficients in force. 0 while they are zero.
    fn decoupled_correction(&self, z: Cplx, raw: f32) -> f32 {
        self.decoupled_step(z, raw, self.decoupled_step(z, raw, 0.0))
    }

    /// One fixed-point step from the correction `c`: the angle of `z + D(raw + c)` less
    /// `raw`, by the small angle it is turned from `raw + c` (no atan2: it is small).
    /// Out of line: code size; D by the control path's Horner form (a power series took
    /// a third of the first control interrupt).
    #[inline(never)]
    fn decoupled_step(&self, z: Cplx, raw: f32, c: f32) -> f32 {
        let (s, co) = self.trig.sin_cos(raw + c);
        let u = Cplx::new(co, s);
        let w = (z + self.inject.borrow().vector(u)) * u.conj();
        c + atan_series(w.im / w.re)
    }

    /// A sample while not locked: the first good one starts the observer at rest at the
    /// measured angle (at rest no sample of it changes); every other one adds its phase
    /// advance, and at the window's end the observer is either declared locked or
    /// restarted at the measured angle and speed, followed by a window that must hold
    /// the lock.
    #[cold]
    #[inline(never)]
    fn acquiring(&mut self, z: Cplx) {
        if !self.acquired {
            self.acquire(z);
            return;
        }
        let a = &mut self.acq;
        if a.prev == Cplx::ZERO {
            self.measure_from(z);
            return;
        }
        // The advance from the previous sample (0.5 rad per sample is 800 rev/s at
        // 20 kHz, N = 2).
        let p = z * a.prev.conj();
        let advance_rad = atan_series(p.im / p.re);
        // Written so that a NaN also counts as a jump.
        let smooth = libm::fabsf(advance_rad - a.last_advance_rad) <= MAX_ADVANCE_CHANGE_RAD;
        if a.count > 0 && !smooth {
            // Not a sensor turning smoothly: measure again from here, and restart the
            // observer at the end whatever it does meanwhile.
            a.reseed = true;
            self.measure_from(z);
            return;
        }
        a.last_advance_rad = advance_rad;
        a.advance_rad += advance_rad;
        a.count += 1;
        a.prev = z;
        if a.count < a.window {
            return;
        }
        let raw = angle_of(z);
        let corr_rad = self.decoupled_correction(z, raw);
        let a = &self.acq;
        let advance_rad = a.advance_rad + corr_rad - a.start_corr_rad;
        // `count` is `window` here: the mean advance per sample, without a division.
        let omega_rad_s = advance_rad * a.per_window_to_rad_s;
        // Written so that a NaN speed also restarts.
        let pulled_in = libm::fabsf(omega_rad_s - self.obs.omega_rad_s) <= a.speed_tol_rad_s;
        let restart = a.reseed || (a.speed_check && !pulled_in);
        if restart {
            self.reseed(z, angle_of_rad(raw + corr_rad), omega_rad_s);
            self.start_window(Cplx::ZERO, false);
            self.measure_from_corrected(z, corr_rad);
        } else {
            self.acq_left = 0;
        }
    }

    /// First good sample: start at the measured angle, at rest, and open the first
    /// window (which also checks the speed).
    #[cold]
    #[inline(never)]
    fn acquire(&mut self, z: Cplx) {
        let raw = angle_of(z);
        self.obs = ObserverState {
            theta_e_rad: raw,
            ..Default::default()
        };
        self.mech = (0, 0);
        self.lag_rad = 0.0;
        self.restart = true;
        self.restart_amplitude = z.abs();
        self.acquired = true;
        // `start_window(z, false)`, the raw angle measured once.
        self.open_window(false);
        self.measure_from_corrected(z, self.decoupled_correction(z, raw));
        self.acq.speed_check = true;
    }

    /// Restart the observer at the (decoupled) angle `th` and the measured speed,
    /// keeping the period count continuous (the nearest period to the estimate it
    /// replaces); the adaptation restarts its smoothing there.
    fn reseed(&mut self, z: Cplx, th: f32, omega_rad_s: f32) {
        let d = self.obs.theta_e_rad - th;
        let periods = if d > PI {
            self.obs.periods.wrapping_add(1)
        } else if d < -PI {
            self.obs.periods.wrapping_sub(1)
        } else {
            self.obs.periods
        };
        // A non-finite speed (a sample exactly on the imaginary axis of the previous
        // one) is kept out of the state.
        let omega_rad_s = if omega_rad_s.is_finite() {
            omega_rad_s
        } else {
            0.0
        };
        self.obs = ObserverState {
            theta_e_rad: th,
            periods,
            omega_int_rad_s: omega_rad_s,
            omega_rad_s,
            ..Default::default()
        };
        self.mech = Self::split_periods(periods, self.cfg.sensor_periods);
        self.lag_rad = 0.0;
        self.restart = true;
        self.restart_amplitude = z.abs();
    }

    /// [`Self::split_periods`] of `to` from `mech`, that of `from`: a step of one
    /// period (the observer's usual wrap) without the division, which made the period
    /// of a wrap one of the control interrupt's longest.
    #[inline(always)]
    fn step_split(mech: (i32, i32), from: i32, to: i32, n: u16) -> (i32, i32) {
        let (p, turns) = mech;
        let n_i = (n as i32).max(1);
        match to.checked_sub(from) {
            Some(1) if p + 1 < n_i => (p + 1, turns),
            Some(1) => (0, turns + 1),
            Some(-1) if p > 0 => (p - 1, turns),
            Some(-1) => (n_i - 1, turns - 1),
            _ => Self::split_periods(to, n),
        }
    }

    fn split_periods(periods: i32, n: u16) -> (i32, i32) {
        let n = n as i32;
        // N ≥ 1 is validated; `max` keeps a division by zero out of the control path.
        let n = n.max(1);
        (periods.rem_euclid(n), periods.div_euclid(n))
    }

    /// The estimate for the state `o`, whose period split is `self.mech`.
    #[inline(always)]
    fn estimate_of(&self, o: &ObserverState, amplitude: f32, eps: f32, adapting: bool) -> Estimate {
        let (p, turns) = self.mech;
        Estimate {
            theta_rad: (p as f32 * TAU + o.theta_e_rad) * self.inv_n,
            turns,
            theta_e_rad: o.theta_e_rad,
            omega_rad_s: o.omega_rad_s,
            disturbance_nm: o.disturbance_nm,
            amplitude,
            epsilon_rad: eps,
            adapting,
            decoupled: Cplx::ZERO,
        }
    }

    /// The estimate of the last accepted sample.
    pub fn last_estimate(&self) -> Estimate {
        self.last
    }

    /// [`Estimate::decoupled`] of the last sample, read where it lies (the whole estimate
    /// copied cost the control period 20 cycles for the one field).
    #[inline(always)]
    pub fn last_decoupled(&self) -> Cplx {
        self.last.decoupled
    }

    /// The observer's internal state (for logging and state-held checks).
    pub fn observer_state(&self) -> ObserverState {
        self.obs
    }

    /// Whether the observer is locked: acquired, and no loss of lock (or long run of
    /// refused samples) since a window that held the lock. Adaptation runs only then.
    #[inline(always)]
    pub fn is_locked(&self) -> bool {
        self.acq_left == 0
    }

    /// Scale the observer's disturbance estimate by `k` where the torque fed forward is
    /// scaled by `k` (a torque constant or inertia put in force at speed): at a steady
    /// speed the estimate holds the feed-forward's mean, so θ̂ does not jump. Its
    /// low-frequency estimate, not the torque of the moment, which may ring.
    pub fn scale_disturbance(&mut self, k: f32) {
        self.obs.disturbance_nm *= k;
    }

    /// Forget the observer state; the next good sample re-acquires. Coefficients stay.
    pub fn reset_observer(&mut self) {
        self.acquired = false;
        self.acq_left = 1;
        self.obs = ObserverState::default();
        self.mech = (0, 0);
        self.lag_rad = 0.0;
    }

    /// Stop (true) or resume (false) adaptation; residuals are still measured.
    pub fn set_frozen(&mut self, frozen: bool) {
        self.frozen = frozen;
    }

    pub fn is_frozen(&self) -> bool {
        self.frozen
    }

    pub fn faults(&self) -> Faults {
        self.faults
    }

    pub fn clear_faults(&mut self) {
        self.faults = Faults::default();
    }

    /// This period's sample for the adaptation (`None` if it was rejected); read in
    /// place, the caller copies it where it goes.
    #[inline(always)]
    pub fn handoff(&self) -> Option<&AdaptSample> {
        self.handed.then_some(&self.handoff)
    }

    /// Add a flag (e.g. [`AdaptSample::REPORT`]) to this period's sample, if any.
    #[inline(always)]
    pub fn mark_handoff(&mut self, flag: u8) {
        self.handoff.flags |= flag;
    }

    /// The period count of the last [`Self::step`].
    pub fn index(&self) -> u32 {
        self.index
    }

    /// Put an update in force if it is due at the coming period (`false`: not yet, keep
    /// it). A late one (its task missed the deadline) is applied at once. A new bank is
    /// worked out here (the firmware swaps in one built by its task instead:
    /// [`Self::swap_injection`]).
    #[inline(always)]
    pub fn apply(&mut self, u: &InjectionUpdate) -> bool {
        let due = self.is_due(u);
        if due {
            match u.change {
                Change::Term { path, value } => self.inject.borrow_mut().set(path as usize, value),
                Change::Bank(b) => self.inject.borrow_mut().put_bank(&b, None),
            }
        }
        due
    }

    /// Whether `u` is in force from the coming period (or was due earlier: late).
    #[inline(always)]
    pub fn is_due(&self, u: &InjectionUpdate) -> bool {
        u.due_in(self.index.wrapping_add(1)) <= 0
    }

    /// Put in force, in order, the updates at the front of `pending` that are due at the
    /// coming period ([`Self::apply`]); the rest stay queued.
    #[inline(always)]
    pub fn apply_due<const N: usize>(&mut self, pending: &mut heapless::Deque<InjectionUpdate, N>) {
        while let Some(u) = pending.front() {
            if !self.apply(u) {
                break;
            }
            pending.pop_front();
        }
    }

    /// Every path's decoupling-vector term at once (coefficients loaded from flash, which
    /// the [`Adapter`] has validated).
    pub fn load_injection(&mut self, c: &Coefficients) {
        let kinds = c.kinds();
        let inject = self.inject.borrow_mut();
        if kinds != inject.kinds() {
            inject.rebank(kinds);
        }
        for (i, (_, v)) in c.iter().enumerate() {
            inject.set(i, v);
        }
    }

    /// The decoupling vector in force.
    pub fn injection(&self) -> &Injection {
        self.inject.borrow()
    }

    /// `next` in force in place of the decoupling vector, which is returned: a new bank
    /// built whole where there is time (the caller checks it is the bank due).
    #[inline(always)]
    pub fn swap_injection(&mut self, next: S) -> S {
        core::mem::replace(&mut self.inject, next)
    }
}

/// [`Front`] and [`Adapter`] run inline, in the order the firmware runs them: the
/// adaptation of a sample right after it, its update in force
/// [`crate::UPDATE_LATENCY_PERIODS`] later. Bit for bit what the firmware's control
/// interrupt and adaptation task compute, with one call per period.
#[derive(Clone, Debug)]
pub struct Tracker<T: Trig = F32Trig> {
    front: Front<T>,
    adapter: Adapter,
    /// Updates not yet due, in order (at most one per stride, within the latency).
    pending: heapless::Deque<InjectionUpdate, { crate::MAX_PATHS }>,
    adapting: bool,
}

impl Tracker<F32Trig> {
    /// A tracker with the portable trigonometry.
    pub fn new(cfg: Config) -> Result<Self, ConfigError> {
        Self::with_trig(cfg, F32Trig)
    }
}

impl<T: Trig> Tracker<T> {
    /// A tracker with a given trigonometry implementation (e.g. the CORDIC).
    pub fn with_trig(cfg: Config, trig: T) -> Result<Self, ConfigError> {
        Ok(Self {
            adapter: Adapter::new(&cfg)?,
            front: Front::with_trig(cfg, trig)?,
            pending: heapless::Deque::new(),
            adapting: false,
        })
    }

    /// One control period: the scaled sensor vector and the torque feedforward T* (N·m);
    /// see [`Front::step`].
    pub fn step(&mut self, x: f32, y: f32, torque_ff_nm: f32) -> Result<Estimate, Fault> {
        self.front.apply_due(&mut self.pending);
        let result = self.front.step(x, y, torque_ff_nm);
        // `adapting` stays that of the last accepted sample, as the estimate does.
        if let Some(&s) = self.front.handoff() {
            let (adapting, update) = self.adapter.step(&s);
            self.adapting = adapting;
            if let Some(u) = update {
                if let Err(u) = self.pending.push_back(u) {
                    // Cannot happen (one update per stride, latency < capacity strides);
                    // apply rather than lose it.
                    self.front.apply(&InjectionUpdate {
                        apply_at: self.front.index(),
                        ..u
                    });
                }
            }
        }
        result.map(|e| Estimate {
            adapting: self.adapting,
            ..e
        })
    }

    /// A period whose sample the front end refused; see [`Front::refuse`].
    pub fn refuse(&mut self, f: Fault) -> Fault {
        self.front.apply_due(&mut self.pending);
        self.front.refuse(f)
    }

    pub fn front(&self) -> &Front<T> {
        &self.front
    }

    pub fn adapter(&self) -> &Adapter {
        &self.adapter
    }

    pub fn config(&self) -> &Config {
        self.front.config()
    }

    pub fn gains(&self) -> &ObserverGains {
        self.front.gains()
    }

    pub fn trig(&self) -> &T {
        self.front.trig()
    }

    pub fn last_estimate(&self) -> Estimate {
        Estimate {
            adapting: self.adapting,
            ..self.front.last_estimate()
        }
    }

    pub fn observer_state(&self) -> ObserverState {
        self.front.observer_state()
    }

    pub fn reset_observer(&mut self) {
        self.front.reset_observer();
    }

    /// See [`Front::is_locked`].
    pub fn is_locked(&self) -> bool {
        self.front.is_locked()
    }

    pub fn set_frozen(&mut self, frozen: bool) {
        self.front.set_frozen(frozen);
    }

    pub fn is_frozen(&self) -> bool {
        self.front.is_frozen()
    }

    pub fn faults(&self) -> Faults {
        self.front.faults()
    }

    pub fn clear_faults(&mut self) {
        self.front.clear_faults();
    }

    /// Snapshot of the persistent coefficients (proportional parts excluded).
    pub fn coefficients(&self) -> Coefficients {
        self.adapter.coefficients()
    }

    /// Load coefficients (e.g. from flash), validated by [`Adapter::set_coefficients`];
    /// the updates still pending are dropped.
    pub fn set_coefficients(&mut self, c: &Coefficients) -> Result<(), CoefficientsError> {
        self.adapter.set_coefficients(c)?;
        self.pending.clear();
        self.front.load_injection(c);
        Ok(())
    }

    /// Convergence measures and the `converged` judgement.
    pub fn convergence(&self) -> Convergence {
        self.adapter.convergence()
    }
}

/// The angle of `z` in [0, 2π).
#[inline(never)]
fn angle_of(z: Cplx) -> f32 {
    angle_of_rad(libm::atan2f(z.im, z.re))
}

/// `x` (within a turn of [0, 2π)) wrapped into [0, 2π).
fn angle_of_rad(x: f32) -> f32 {
    let x = if x < 0.0 { x + TAU } else { x };
    if x >= TAU {
        x - TAU
    } else {
        x
    }
}

/// arctan(t) by its series to t⁵: error < 1e-4 rad for |t| ≤ 0.5 (and far less for the
/// small angles it is used on).
#[inline(always)]
fn atan_series(t: f32) -> f32 {
    let t2 = t * t;
    t * (1.0 - t2 * (1.0 / 3.0 - t2 * 0.2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_of_one_period_splits_as_the_division_does() {
        type F = Front<crate::F32Trig>;
        for n in [1u16, 2, 3, 7] {
            let mut mech = F::split_periods(-40, n);
            for to in -39..40 {
                mech = F::step_split(mech, to - 1, to, n);
                assert_eq!(mech, F::split_periods(to, n), "n {n}, up to {to}");
            }
            for to in (-40..39).rev() {
                mech = F::step_split(mech, to + 1, to, n);
                assert_eq!(mech, F::split_periods(to, n), "n {n}, down to {to}");
            }
            // Any other jump: the division.
            assert_eq!(F::step_split(mech, -40, -37, n), F::split_periods(-37, n));
        }
    }
}

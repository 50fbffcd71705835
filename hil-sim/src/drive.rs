//! A simulated SPMSM drive that closes its loops through the core's estimate, so that
//! sensor error becomes real torque ripple and real motion, as on a bench.
//!
//! Per control period T (the core's sample period):
//! 1. sample the sensor (X and Y, Y possibly skewed in time) and the phase currents;
//! 2. `Tracker::step` with the torque command in force (the observer's feedforward);
//! 3. motion controller (position or velocity, bandwidth configurable) → torque command;
//! 4. dq current PI regulators in the frame of the *estimated* electrical angle
//!    → αβ voltage command, applied during the *next* period (average-value inverter,
//!    one PWM period of delay, limited to the linear SVPWM range Vdc/√3);
//! 5. the plant integrates over T in `SUBSTEPS` substeps.
//!
//! The electrical state is integrated in the stationary αβ frame (one sin/cos per
//! substep, for the back-EMF and torque), semi-implicitly in R; with 4 substeps per 50 µs
//! period the substep is 12.5 µs against L/R = 1.7 ms and ωe·h ≤ 0.03 rad at 100 rev/s.

use crate::sensor::SensorSim;
use mras::{Estimate, Fault, Tracker};
use std::f64::consts::TAU;

/// Electrical substeps per control period.
pub const SUBSTEPS: u32 = 4;
const SQRT3: f64 = 1.732_050_807_568_877_2;

/// One spatial harmonic of the cogging torque: `amplitude·sin(harmonic·θrm + phase)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cogging {
    pub harmonic: u32,
    pub amplitude_nm: f64,
    pub phase_rad: f64,
}

/// A load torque that starts at `t_s` (and lasts to the next step).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadStep {
    pub t_s: f64,
    pub torque_nm: f64,
}

/// Motor, inverter and mechanics.
#[derive(Clone, Debug, PartialEq)]
pub struct MotorParams {
    pub pole_pairs: u32,
    pub r_ohm: f64,
    pub l_h: f64,
    /// Permanent-magnet flux linkage λ (V·s); torque constant Kt = 1.5·p·λ.
    pub flux_wb: f64,
    /// Physical inertia J of rotor and load.
    pub j_kg_m2: f64,
    pub vdc_v: f64,
    /// Current limit (peak phase current).
    pub i_max_a: f64,
    pub coulomb_nm: f64,
    pub viscous_nm_s_rad: f64,
    pub cogging: Vec<Cogging>,
    pub load_steps: Vec<LoadStep>,
    /// Phase a and b current-sensor offsets (A) and relative gain errors (§V.C).
    pub current_offset_a: [f64; 2],
    pub current_gain_error: [f64; 2],
}

impl Default for MotorParams {
    /// A 48 V servo of the ElectroCraft RP34 class (the paper's bench motor).
    fn default() -> Self {
        Self {
            pole_pairs: 4,
            r_ohm: 0.3,
            l_h: 0.5e-3,
            flux_wb: 0.02,
            j_kg_m2: 2.0e-4,
            vdc_v: 48.0,
            i_max_a: 20.0,
            coulomb_nm: 0.0,
            viscous_nm_s_rad: 1.0e-5,
            cogging: Vec::new(),
            load_steps: Vec::new(),
            current_offset_a: [0.0; 2],
            current_gain_error: [0.0; 2],
        }
    }
}

impl MotorParams {
    pub fn torque_constant_nm_a(&self) -> f64 {
        1.5 * self.pole_pairs as f64 * self.flux_wb
    }

    /// Rated torque: the torque at the current limit.
    pub fn rated_torque_nm(&self) -> f64 {
        self.torque_constant_nm_a() * self.i_max_a
    }

    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("motor.pole_pairs", self.pole_pairs as f64),
            ("motor.r_ohm", self.r_ohm),
            ("motor.l_h", self.l_h),
            ("motor.flux_wb", self.flux_wb),
            ("motor.j_kg_m2", self.j_kg_m2),
            ("motor.vdc_v", self.vdc_v),
            ("motor.i_max_a", self.i_max_a),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("`{name}` = {v}: must be finite and > 0"));
            }
        }
        for (name, v) in [
            ("motor.coulomb_nm", self.coulomb_nm),
            ("motor.viscous_nm_s_rad", self.viscous_nm_s_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("`{name}` = {v}: must be finite and >= 0"));
            }
        }
        Ok(())
    }
}

/// The motion profile the controller is asked to follow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reference {
    /// From rest, accelerate at `accel_rad_s2` to `speed_rev_s` and hold.
    Ramp { speed_rev_s: f64, accel_rad_s2: f64 },
    /// ω* = A·sin(2π f t) (the paper's Fig. 8 profile).
    Sine { amplitude_rad_s: f64, freq_hz: f64 },
}

impl Reference {
    fn trajectory(&self) -> mras::sim::Trajectory {
        match *self {
            Reference::Ramp {
                speed_rev_s,
                accel_rad_s2,
            } => mras::sim::Trajectory::Ramp {
                omega_rad_s: speed_rev_s * TAU,
                accel_rad_s2,
            },
            Reference::Sine {
                amplitude_rad_s,
                freq_hz,
            } => mras::sim::Trajectory::Sine {
                amplitude_rad_s,
                freq_hz,
            },
        }
    }

    /// (θ*, ω*, α*) at t.
    pub fn state(&self, t_s: f64) -> (f64, f64, f64) {
        self.trajectory().state(t_s)
    }
}

/// Whether the motion loop closes on position (PID) or on velocity (PI).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoopMode {
    Position,
    Velocity,
}

/// Control loops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlParams {
    pub mode: LoopMode,
    /// Motion loop bandwidth (Hz): triple pole (position) or double pole (velocity).
    pub bandwidth_hz: f64,
    /// Current loop bandwidth (Hz), PI zero on the electrical pole.
    pub current_bandwidth_hz: f64,
    pub reference: Reference,
}

/// The motion controller's estimate of J, which is also the observer's Ĵ.
#[derive(Clone, Copy, Debug)]
struct MotionController {
    j_hat: f64,
    kp: f64,
    ki: f64,
    kd: f64,
    integral: f64,
    mode: LoopMode,
}

impl MotionController {
    fn new(c: &ControlParams, j_hat: f64) -> Self {
        let w = TAU * c.bandwidth_hz;
        let (kd, kp, ki) = match c.mode {
            // (s + w)³: α = 3w·ė + 3w²·e + w³∫e
            LoopMode::Position => (3.0 * w, 3.0 * w * w, w * w * w),
            // (s + w)²: α = 2w·ė + w²∫ė
            LoopMode::Velocity => (2.0 * w, w * w, 0.0),
        };
        Self {
            j_hat,
            kp,
            ki,
            kd,
            integral: 0.0,
            mode: c.mode,
        }
    }

    /// Torque command from the reference and the estimate.
    fn torque(&mut self, r: (f64, f64, f64), theta_hat: f64, omega_hat: f64, t: f64) -> f64 {
        let (th_ref, w_ref, a_ref) = r;
        let e_th = th_ref - theta_hat;
        let e_w = w_ref - omega_hat;
        let a = match self.mode {
            LoopMode::Position => {
                self.integral += e_th * t;
                a_ref + self.kd * e_w + self.kp * e_th + self.ki * self.integral
            }
            LoopMode::Velocity => {
                self.integral += e_w * t;
                a_ref + self.kd * e_w + self.kp * self.integral
            }
        };
        self.j_hat * a
    }
}

/// Everything the drive knows and does in one control period, for recording.
#[derive(Clone, Copy, Debug)]
pub struct DriveSample {
    pub t_s: f64,
    /// True mechanical angle (continuous) and speed.
    pub theta_rad: f64,
    pub omega_rad_s: f64,
    /// Reference position (continuous).
    pub theta_ref_rad: f64,
    /// What the ADC delivered.
    pub x: f32,
    pub y: f32,
    /// Torque command (also the observer's feedforward) and electrical torque produced.
    pub torque_cmd_nm: f64,
    pub torque_nm: f64,
    pub result: Result<Estimate, Fault>,
    /// The estimate used by the loops (last good one on a fault).
    pub estimate: Estimate,
}

impl DriveSample {
    /// θ̂ - θ (rad, mechanical).
    pub fn estimation_error_rad(&self) -> f64 {
        self.estimate.theta_unwrapped_rad() - self.theta_rad
    }

    /// θ* - θ̂: the position loop's command tracking error (paper Fig. 9b, 10a).
    pub fn tracking_error_rad(&self) -> f64 {
        self.theta_ref_rad - self.estimate.theta_unwrapped_rad()
    }
}

/// The simulated drive: plant, inverter, current and motion control, sensor, core.
pub struct Drive {
    pub motor: MotorParams,
    pub control: ControlParams,
    pub sensor: SensorSim,
    t_s: f64,
    k: u64,
    // Plant state.
    theta_rm: f64,
    omega_rm: f64,
    i_ab: [f64; 2],
    // Inverter: αβ voltage applied during this period (commanded one period ago).
    v_ab_applied: [f64; 2],
    // Control state.
    motion: MotionController,
    id_int: f64,
    iq_int: f64,
    torque_cmd_nm: f64,
    last_torque_nm: f64,
}

impl Drive {
    /// A drive at rest at θ = 0. `j_hat_kg_m2` is the controller's (and should be the
    /// observer's) inertia estimate.
    pub fn new(
        motor: MotorParams,
        control: ControlParams,
        sensor: SensorSim,
        sample_period_s: f64,
        j_hat_kg_m2: f64,
    ) -> Result<Self, String> {
        motor.validate()?;
        if !(control.bandwidth_hz > 0.0 && control.current_bandwidth_hz > 0.0) {
            return Err(
                "`control.bandwidth_hz` and `control.current_bandwidth_hz` must be > 0".into(),
            );
        }
        if control.current_bandwidth_hz * sample_period_s > 0.1 {
            return Err(format!(
                "`control.current_bandwidth_hz` = {}: at most a tenth of the control rate",
                control.current_bandwidth_hz
            ));
        }
        Ok(Self {
            motion: MotionController::new(&control, j_hat_kg_m2),
            motor,
            control,
            sensor,
            t_s: sample_period_s,
            k: 0,
            theta_rm: 0.0,
            omega_rm: 0.0,
            i_ab: [0.0; 2],
            v_ab_applied: [0.0; 2],
            id_int: 0.0,
            iq_int: 0.0,
            torque_cmd_nm: 0.0,
            last_torque_nm: 0.0,
        })
    }

    pub fn time_s(&self) -> f64 {
        self.k as f64 * self.t_s
    }

    /// Measured phase currents a, b → αβ, with the current sensors' offset and gain errors.
    fn measured_currents(&self) -> [f64; 2] {
        let m = &self.motor;
        let ia = self.i_ab[0];
        let ib = -0.5 * self.i_ab[0] + 0.5 * SQRT3 * self.i_ab[1];
        let ia_m = (1.0 + m.current_gain_error[0]) * ia + m.current_offset_a[0];
        let ib_m = (1.0 + m.current_gain_error[1]) * ib + m.current_offset_a[1];
        [ia_m, (ia_m + 2.0 * ib_m) / SQRT3]
    }

    fn load_torque_nm(&self, t: f64) -> f64 {
        self.motor
            .load_steps
            .iter()
            .filter(|s| s.t_s <= t)
            .max_by(|a, b| a.t_s.total_cmp(&b.t_s))
            .map_or(0.0, |s| s.torque_nm)
    }

    /// One control period; returns what happened in it.
    pub fn step<T: mras::Trig>(&mut self, tracker: &mut Tracker<T>) -> DriveSample {
        let t = self.time_s();
        let m = &self.motor;
        let p = m.pole_pairs as f64;

        // 1. Sample.
        let (theta_sampled, omega_sampled) = (self.theta_rm, self.omega_rm);
        let (x, y) = self.sensor.sample(t, self.theta_rm, self.omega_rm);
        let i_meas = self.measured_currents();

        // 2. Observer + MRAS, fed the torque command in force.
        let result = tracker.step(x, y, self.torque_cmd_nm as f32);
        let est = match result {
            Ok(e) => e,
            Err(_) => tracker.last_estimate(),
        };
        let theta_hat = est.theta_unwrapped_rad();
        let omega_hat = est.omega_rad_s as f64;

        // 3. Motion control (torque limited by the current limit).
        let r = self.control.reference.state(t);
        let t_max = m.rated_torque_nm();
        let torque_cmd = self
            .motion
            .torque(r, theta_hat, omega_hat, self.t_s)
            .clamp(-t_max, t_max);
        let iq_ref = torque_cmd / m.torque_constant_nm_a();

        // 4. Current control in the estimated frame; the voltage acts during the next
        //    period, so rotate it by the angle travelled until the middle of that period.
        let th_e = p * est.theta_rad as f64;
        let (s, c) = th_e.sin_cos();
        let id = c * i_meas[0] + s * i_meas[1];
        let iq = -s * i_meas[0] + c * i_meas[1];
        let wc = TAU * self.control.current_bandwidth_hz;
        let (kp, ki) = (m.l_h * wc, m.r_ohm * wc);
        let we_hat = p * omega_hat;
        let (ed, eq) = (0.0 - id, iq_ref - iq);
        self.id_int += ki * ed * self.t_s;
        self.iq_int += ki * eq * self.t_s;
        let mut vd = kp * ed + self.id_int - we_hat * m.l_h * iq;
        let mut vq = kp * eq + self.iq_int + we_hat * (m.l_h * id + m.flux_wb);
        let v_max = m.vdc_v / SQRT3;
        let v = (vd * vd + vq * vq).sqrt();
        if v > v_max {
            // Saturate and stop integrating (anti-windup by back-calculation).
            vd *= v_max / v;
            vq *= v_max / v;
            self.id_int -= ki * ed * self.t_s;
            self.iq_int -= ki * eq * self.t_s;
        }
        let (s2, c2) = (th_e + 1.5 * we_hat * self.t_s).sin_cos();
        let v_cmd = [c2 * vd - s2 * vq, s2 * vd + c2 * vq];

        // 5. Plant over one period with the voltage commanded one period ago.
        let h = self.t_s / SUBSTEPS as f64;
        let load = self.load_torque_nm(t);
        let mut torque = 0.0;
        for _ in 0..SUBSTEPS {
            let th_mid = self.theta_rm + 0.5 * h * self.omega_rm;
            let (se, ce) = (p * th_mid).sin_cos();
            let we = p * self.omega_rm;
            // Back-EMF e_αβ = ωe·λ·(-sin θe, cos θe).
            let e = [-we * m.flux_wb * se, we * m.flux_wb * ce];
            let k_r = 1.0 / (1.0 + h * m.r_ohm / m.l_h);
            for j in 0..2 {
                self.i_ab[j] = (self.i_ab[j] + h / m.l_h * (self.v_ab_applied[j] - e[j])) * k_r;
            }
            // T = 1.5·p·λ·(iβ cos θe - iα sin θe).
            let te = m.torque_constant_nm_a() * (self.i_ab[1] * ce - self.i_ab[0] * se);
            let mut cog = 0.0;
            for cg in &m.cogging {
                cog += cg.amplitude_nm * (cg.harmonic as f64 * th_mid + cg.phase_rad).sin();
            }
            // Coulomb friction, smoothed over ±1 mrad/s to keep the ODE well posed.
            let fric =
                m.coulomb_nm * (self.omega_rm / 1.0e-3).tanh() + m.viscous_nm_s_rad * self.omega_rm;
            let accel = (te - fric - load - cog) / m.j_kg_m2;
            self.omega_rm += accel * h;
            self.theta_rm += self.omega_rm * h;
            torque += te;
        }
        self.v_ab_applied = v_cmd;
        self.torque_cmd_nm = torque_cmd;
        self.last_torque_nm = torque / SUBSTEPS as f64;
        self.k += 1;

        DriveSample {
            t_s: t,
            theta_rad: theta_sampled,
            omega_rad_s: omega_sampled,
            theta_ref_rad: r.0,
            x,
            y,
            torque_cmd_nm: torque_cmd,
            torque_nm: self.last_torque_nm,
            result,
            estimate: est,
        }
    }
}

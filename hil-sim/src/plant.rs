//! The plant: motor, inverter, sensor front end and mechanics. Everything that is
//! control lives in the firmware's `drive` crate and runs unchanged in [`crate::rig`].
//!
//! Per control period T:
//! 1. [`Plant::sample`]: the ADC conversions at the period's start, in counts: the sensor's
//!    X and Y (Y possibly skewed in time) and the phase currents a, b (with the current
//!    sensors' offset and gain errors);
//! 2. [`Plant::advance`]: the inverter applies the duties the control period computed in
//!    the *previous* period (average-value inverter: the duties' line-to-line voltages,
//!    one PWM period of delay), or opens the windings while the bridge is off, and the
//!    motor and mechanics integrate over T in `SUBSTEPS` substeps (more where a short
//!    L/R or the inverter's error needs them, [`substeps_for`]). Each phase's voltage
//!    falls short by `Vdc·dead_time/T + device_drop` against its current's sign
//!    ([`MotorParams::dead_time_s`]): the average error of the dead time and of the
//!    conducting devices. It ramps linearly across the band in which the PWM ripple
//!    takes the phase current through zero within a period (`|v|·T/(2L)` for the
//!    applied voltage v), or across what keeps the substeps stable if that is wider
//!    (at most [`INVERTER_BAND_A`] with the substeps [`substeps_for`] picks).
//!
//! The electrical state is integrated in the stationary αβ frame, semi-implicitly in R,
//! with the back-EMF and torque evaluated at each substep's mid angle (one sin/cos per
//! period, then exact small-angle rotations). The default, 2 substeps per 50 µs period
//! (h = 25 µs against L/R = 1.7 ms, ωe·h ≤ 0.063 rad at 100 rev/s), agrees with 16
//! substeps to within 0.5 % in current and 1e-5 of the angle travelled after 0.3 s of an
//! open-loop run-up with a load step (`tests::substeps_converge`; closed loop, the
//! controller corrects even that).

use crate::input_error::InvalidParam;
use crate::sensor::SensorSim;

/// Electrical substeps per control period (see the module doc for the accuracy).
pub const SUBSTEPS: u32 = 2;
const SQRT3: f64 = 1.732_050_807_568_877_2;

/// The smallest band the inverter's error may be spread over for the substeps to
/// resolve it (A): narrower than the PWM ripple of any identification level.
pub const INVERTER_BAND_A: f64 = 0.2;

/// [`SUBSTEPS`], or more where the motor needs them: a substep within a tenth of L/R
/// (the semi-implicit step's decay rate then within 0.5 %), and the inverter's error,
/// whose slope across [`INVERTER_BAND_A`] acts as a resistance the explicit substep must
/// resolve (`h·(4/3)·v_err/(band·L)` ≤ 1/3); at most 256.
pub fn substeps_for(m: &MotorParams, t_s: f64) -> u32 {
    let v_err = m.vdc_v * m.dead_time_s / t_s + m.device_drop_v;
    let n = (4.0 * t_s * v_err / (m.l_h * INVERTER_BAND_A))
        .max(10.0 * t_s * m.r_ohm / m.l_h)
        .ceil();
    if n.is_finite() {
        (n as u32).clamp(SUBSTEPS, 256)
    } else {
        SUBSTEPS
    }
}

/// (sin δ, cos δ), by Taylor series for the small angles a substep or a PWM period
/// turns through (error < 2e-12 for |δ| ≤ 0.3), else the library call. Saves most of the
/// model's transcendental functions.
pub(crate) fn sin_cos_small(d: f64) -> (f64, f64) {
    if d.abs() > 0.3 {
        return d.sin_cos();
    }
    // Reciprocal constants: multiplications, not divisions, in the inner loop.
    const S: [f64; 4] = [1.0 / 6.0, 1.0 / 20.0, 1.0 / 42.0, 1.0 / 72.0];
    const C: [f64; 4] = [1.0 / 2.0, 1.0 / 12.0, 1.0 / 30.0, 1.0 / 56.0];
    let d2 = d * d;
    let s = d * (1.0 - d2 * S[0] * (1.0 - d2 * S[1] * (1.0 - d2 * S[2] * (1.0 - d2 * S[3]))));
    let c = 1.0 - d2 * C[0] * (1.0 - d2 * C[1] * (1.0 - d2 * C[2] * (1.0 - d2 * C[3])));
    (s, c)
}

/// Rotate the unit vector (sin a, cos a) by (sin d, cos d).
pub(crate) fn rotate((s, c): (f64, f64), (sd, cd): (f64, f64)) -> (f64, f64) {
    (s * cd + c * sd, c * cd - s * sd)
}

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
    /// Continuous rated torque: the base of per-unit loads.
    pub rated_torque_nm: f64,
    pub coulomb_nm: f64,
    pub viscous_nm_s_rad: f64,
    pub cogging: Vec<Cogging>,
    pub load_steps: Vec<LoadStep>,
    /// Phase a and b current-sensor offsets (A) and relative gain errors (§V.C).
    pub current_offset_a: [f64; 3],
    pub current_gain_error: [f64; 3],
    /// The inverter's dead time (s) and each conducting device's voltage drop (V): a
    /// phase's voltage falls short by `Vdc·dead_time/T + drop` against its current's
    /// sign ([`Plant`]'s module doc). 0 and 0: the ideal inverter.
    pub dead_time_s: f64,
    pub device_drop_v: f64,
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
            rated_torque_nm: 0.6,
            coulomb_nm: 0.0,
            viscous_nm_s_rad: 1.0e-5,
            cogging: Vec::new(),
            load_steps: Vec::new(),
            current_offset_a: [0.0; 3],
            current_gain_error: [0.0; 3],
            dead_time_s: 0.0,
            device_drop_v: 0.0,
        }
    }
}

impl MotorParams {
    pub fn torque_constant_nm_a(&self) -> f64 {
        1.5 * self.pole_pairs as f64 * self.flux_wb
    }

    /// Peak torque: the torque at the current limit.
    pub fn peak_torque_nm(&self) -> f64 {
        self.torque_constant_nm_a() * self.i_max_a
    }

    pub fn validate(&self) -> Result<(), InvalidParam> {
        let positive = [
            ("motor.pole_pairs", self.pole_pairs as f64),
            ("motor.r_ohm", self.r_ohm),
            ("motor.l_h", self.l_h),
            ("motor.flux_wb", self.flux_wb),
            ("motor.j_kg_m2", self.j_kg_m2),
            ("motor.vdc_v", self.vdc_v),
            ("motor.i_max_a", self.i_max_a),
            ("motor.rated_torque_nm", self.rated_torque_nm),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(InvalidParam::OutOfRange {
                    name,
                    value: v,
                    rule: "must be finite and > 0",
                });
            }
        }
        for (name, v) in [
            ("motor.coulomb_nm", self.coulomb_nm),
            ("motor.viscous_nm_s_rad", self.viscous_nm_s_rad),
            ("motor.dead_time_s", self.dead_time_s),
            ("motor.device_drop_v", self.device_drop_v),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(InvalidParam::OutOfRange {
                    name,
                    value: v,
                    rule: "must be finite and >= 0",
                });
            }
        }
        Ok(())
    }
}

/// The inverter's voltage error in αβ for the current (αβ, A): each phase's voltage
/// falls short by `v_err` against its current, linearly across `band_a` either side of
/// zero (the current's PWM ripple crosses zero there, and the dead time's error with it).
fn inverter_error_ab(v_err: f64, band_a: f64, ia: f64, ib: f64) -> (f64, f64) {
    if v_err == 0.0 {
        return (0.0, 0.0);
    }
    let [a, b, c] = ab_to_phases([ia, ib]).map(|i| -v_err * (i / band_a).clamp(-1.0, 1.0));
    // The common mode drops out: amplitude-invariant Clarke.
    (2.0 / 3.0 * (a - 0.5 * (b + c)), (b - c) / SQRT3)
}

/// The phase-current sensing front end: what a count means.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentAdc {
    /// A per count (signed, as the board's amplifier reads the current).
    pub amps_per_count: f64,
    pub zero_counts: u16,
    pub max_counts: u16,
}

impl CurrentAdc {
    /// 12 bits spanning ±2·`i_max_a`, zero at mid-scale.
    pub fn for_motor(m: &MotorParams) -> Self {
        Self {
            amps_per_count: 4.0 * m.i_max_a / 4096.0,
            zero_counts: 2048,
            max_counts: 4095,
        }
    }

    fn counts(&self, amps: f64) -> u16 {
        if amps.is_nan() {
            return 0;
        }
        let c = crate::exact::round_i64(amps / self.amps_per_count)
            .saturating_add(self.zero_counts as i64);
        c.clamp(0, self.max_counts as i64) as u16
    }
}

/// What really happened in a period, for measuring the controller against.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    pub t_s: f64,
    /// Rotor mechanical angle (continuous) and speed at the sampling instant.
    pub theta_rad: f64,
    pub omega_rad_s: f64,
    /// The sensor's X and Y as converted (scaled units; the ADC's count size times the
    /// counts).
    pub x: f32,
    pub y: f32,
}

/// The plant: motor, inverter, sensor, mechanics.
pub struct Plant {
    pub motor: MotorParams,
    pub sensor: SensorSim,
    pub current_adc: CurrentAdc,
    /// Size of one sensor count (scaled units) and the converter's bits.
    sensor_count_size: f64,
    sensor_bits: u8,
    t_s: f64,
    k: u64,
    theta_rm: f64,
    omega_rm: f64,
    i_ab: [f64; 2],
    /// αβ voltage applied during the period under way (duties of the previous one).
    v_ab_applied: [f64; 2],
    /// The duties of the bridge output last given (None: bridge off).
    duties_applied: Option<[f32; 3]>,
    /// Bridge on during the period under way.
    enabled: bool,
    /// The over-current comparator's level on any phase current (A) and whether it has
    /// tripped: the break input clears MOE in hardware and stays latched (BIF).
    pub break_level_a: f64,
    tripped: bool,
    /// The comparator's break acts on the bridge here (hil-sim's drive). Off when a
    /// modelled timer owns the break path (the emulator: BKIN → TIM1 → MOE).
    pub break_opens_bridge: bool,
    /// With `break_opens_bridge` off: the break path a modelled timer has armed for the
    /// coming period, as its latency from the comparator's crossing to the bridge off
    /// (its input filter), or None when nothing would open the bridge (break disabled,
    /// not routed, or MOE already off). The bridge opens from the first substep that
    /// starts that long after the crossing (in this period or the next); no latch here
    /// (the timer owns it).
    pub break_path_delay_s: Option<f64>,
    /// The comparator over its level at the end of the last period (its output now, a
    /// level: it falls back when the current does).
    comparator_over: bool,
    /// In the last period: when the comparator first crossed its level (s from the
    /// period's start, interpolated between substeps), and when the armed break path
    /// opened the bridge (s from the period's start).
    crossing_s: Option<f64>,
    break_opened_s: Option<f64>,
    /// The armed break path's opening still to come, from the next period's start (a
    /// crossing near a period's end).
    break_due_s: Option<f64>,
    last_torque_nm: f64,
    consts: PlantConsts,
}

/// Substep constants, computed once (divisions are slow in the inner loop).
#[derive(Clone, Copy, Debug)]
struct PlantConsts {
    substeps: u32,
    h_s: f64,
    /// 1/(1 + h·R/L): the resistive term taken implicitly.
    k_r: f64,
    h_over_l: f64,
    h_over_j: f64,
    kt: f64,
    /// The inverter's voltage error per phase at full conduction (V), and the smallest
    /// band it is spread over (A): one that keeps the substeps stable
    /// (`h·(4/3)·v_err/(band·L)` ≤ 1/3).
    v_err: f64,
    band_floor_a: f64,
    /// T/(2L): times the applied voltage, the PWM ripple's half-amplitude (A).
    ripple_per_v: f64,
}

impl PlantConsts {
    fn new(m: &MotorParams, t_s: f64, substeps: u32) -> Self {
        let h_s = t_s / substeps as f64;
        Self {
            substeps,
            h_s,
            k_r: 1.0 / (1.0 + h_s * m.r_ohm / m.l_h),
            h_over_l: h_s / m.l_h,
            h_over_j: h_s / m.j_kg_m2,
            kt: m.torque_constant_nm_a(),
            v_err: m.vdc_v * m.dead_time_s / t_s + m.device_drop_v,
            band_floor_a: (4.0 * h_s * (m.vdc_v * m.dead_time_s / t_s + m.device_drop_v) / m.l_h)
                .max(1e-3),
            ripple_per_v: t_s / (2.0 * m.l_h),
        }
    }
}

impl Plant {
    /// A plant at rest at θ = `theta0_rad`, sampled every `sample_period_s`. The sensor
    /// must have an ADC: the controller reads counts.
    pub fn new(
        motor: MotorParams,
        sensor: SensorSim,
        sample_period_s: f64,
        theta0_rad: f64,
    ) -> Result<Self, InvalidParam> {
        motor.validate()?;
        let adc = sensor.params.adc.ok_or(InvalidParam::OutOfRange {
            name: "sensor.adc_bits",
            value: 0.0,
            rule: "the drive reads ADC counts, give the converter's bits (1..=16)",
        })?;
        if !(1..=16).contains(&adc.bits) {
            return Err(InvalidParam::OutOfRange {
                name: "sensor.adc_bits",
                value: adc.bits.into(),
                rule: "the drive's converter has 1..=16 bits",
            });
        }
        if !(theta0_rad.is_finite()) {
            return Err(InvalidParam::Rule("initial rotor angle must be finite"));
        }
        Ok(Self {
            consts: PlantConsts::new(
                &motor,
                sample_period_s,
                substeps_for(&motor, sample_period_s),
            ),
            motor: motor.clone(),
            current_adc: CurrentAdc::for_motor(&motor),
            sensor_count_size: 2.0 * adc.full_scale / (1u64 << adc.bits) as f64,
            sensor_bits: adc.bits,
            sensor,
            t_s: sample_period_s,
            k: 0,
            theta_rm: theta0_rad,
            omega_rm: 0.0,
            i_ab: [0.0; 2],
            v_ab_applied: [0.0; 2],
            duties_applied: None,
            enabled: false,
            break_level_a: 2.0 * motor.i_max_a,
            tripped: false,
            break_opens_bridge: true,
            break_path_delay_s: None,
            comparator_over: false,
            crossing_s: None,
            break_opened_s: None,
            break_due_s: None,
            last_torque_nm: 0.0,
        })
    }

    /// Integrate the plant in `n` substeps per period instead of [`SUBSTEPS`].
    pub fn with_substeps(mut self, n: u32) -> Self {
        self.consts = PlantConsts::new(&self.motor, self.t_s, n.max(1));
        self
    }

    /// Size of one sensor count in scaled units, and the converter's bits: the
    /// controller's scaling of the sensor channels.
    pub fn sensor_adc(&self) -> (f64, u8) {
        (self.sensor_count_size, self.sensor_bits)
    }

    pub fn time_s(&self) -> f64 {
        self.k as f64 * self.t_s
    }

    pub fn theta_rad(&self) -> f64 {
        self.theta_rm
    }

    pub fn omega_rad_s(&self) -> f64 {
        self.omega_rm
    }

    /// Phase currents (αβ, A) and the mean electrical torque of the last period.
    pub fn currents_ab(&self) -> [f64; 2] {
        self.i_ab
    }

    /// The duties of the bridge output last given (None: bridge off): with
    /// [`Self::advance_applied`], those of the period just integrated.
    pub fn duties_applied(&self) -> Option<[f32; 3]> {
        self.duties_applied
    }

    pub fn torque_nm(&self) -> f64 {
        self.last_torque_nm
    }

    /// Measured phase currents a, b → counts, with the current sensors' offset and gain
    /// errors.
    fn current_counts(&self) -> [u16; 3] {
        let m = &self.motor;
        let i = self.phase_currents_a();
        [0, 1, 2].map(|k| {
            self.current_adc
                .counts((1.0 + m.current_gain_error[k]) * i[k] + m.current_offset_a[k])
        })
    }

    /// Phase currents a, b, c (A) at the end of the last period.
    pub fn phase_currents_a(&self) -> [f64; 3] {
        ab_to_phases(self.i_ab)
    }

    fn load_torque_nm(&self, t: f64) -> f64 {
        self.motor
            .load_steps
            .iter()
            .filter(|s| s.t_s <= t)
            .max_by(|a, b| a.t_s.total_cmp(&b.t_s))
            .map_or(0.0, |s| s.torque_nm)
    }

    /// The ADC conversions at the start of the period, and the truth at that instant.
    pub fn sample(&mut self) -> (drive::control::Sample, Truth) {
        let t = self.time_s();
        // The sensor's converter codes: the counts less mid-scale (same count size).
        let (qx, qy) = self.sensor.sample_codes(t, self.theta_rm, self.omega_rm);
        let mid = 1i32 << (self.sensor_bits - 1);
        let [ia, ib, ic] = self.current_counts();
        let sample = drive::control::Sample {
            x: (qx + mid) as u16,
            y: (qy + mid) as u16,
            ia,
            ib,
            ic,
            overcurrent: self.tripped,
            cycles: 0,
        };
        let truth = Truth {
            t_s: t,
            theta_rad: self.theta_rm,
            omega_rad_s: self.omega_rm,
            x: (qx as f64 * self.sensor_count_size) as f32,
            y: (qy as f64 * self.sensor_count_size) as f32,
        };
        (sample, truth)
    }

    /// One period: the voltage of the previous period's duties (or open windings), then
    /// the controller's new output takes over for the next period.
    pub fn advance(&mut self, out: &drive::control::Output) {
        // MOE clears at once; a new enable acts with the next period's duties.
        let open = !out.enable || !self.enabled;
        self.integrate_period(open);
        self.enabled = out.enable;
        self.duties_applied = out.enable.then_some(out.duties);
        self.v_ab_applied = if out.enable {
            duties_to_ab(&out.duties, self.motor.vdc_v)
        } else {
            [0.0; 2]
        };
        self.k += 1;
    }

    /// One period with the bridge output that is applied during it (duties and
    /// enable as the timer really drove them): for a modelled timer that owns the delay.
    pub fn advance_applied(&mut self, applied: &drive::control::Output) {
        self.enabled = applied.enable;
        self.duties_applied = applied.enable.then_some(applied.duties);
        self.v_ab_applied = if applied.enable {
            duties_to_ab(&applied.duties, self.motor.vdc_v)
        } else {
            [0.0; 2]
        };
        self.integrate_period(!applied.enable);
        self.k += 1;
    }

    /// The over-current comparator has tripped since the plant was built (latched, the
    /// way hil-sim's drive reads it: the timer's break flag).
    pub fn comparator_tripped(&self) -> bool {
        self.tripped
    }

    /// The comparator's output now: a phase current over its level at the end of the
    /// last period (not latched).
    pub fn comparator_over(&self) -> bool {
        self.comparator_over
    }

    /// In the last period: when the comparator first crossed its level, in seconds
    /// from the period's start (interpolated between substeps), if it did.
    pub fn crossing_s(&self) -> Option<f64> {
        self.crossing_s
    }

    /// In the last period: when the armed break path ([`Plant::break_path_delay_s`])
    /// opened the bridge, in seconds from the period's start, if it did.
    pub fn break_opened_s(&self) -> Option<f64> {
        self.break_opened_s
    }

    /// The largest phase current magnitude of an αβ current (the comparator watches all
    /// three phases; a NaN phase is passed over by `max`, an all-NaN current gives NaN,
    /// which trips nothing).
    fn phase_peak_a(ia: f64, ib: f64) -> f64 {
        ia.abs()
            .max((0.5 * ia - 0.5 * SQRT3 * ib).abs())
            .max((0.5 * ia + 0.5 * SQRT3 * ib).abs())
    }

    fn integrate_period(&mut self, open: bool) {
        let m = &self.motor;
        let p = m.pole_pairs as f64;
        let mut open = open || (self.tripped && self.break_opens_bridge);
        let c = self.consts;
        let h = c.h_s;
        let load = if m.load_steps.is_empty() {
            0.0
        } else {
            self.load_torque_nm(self.time_s())
        };
        // The state in locals for the substeps (same operations in the same order).
        let (mut omega, mut theta) = (self.omega_rm, self.theta_rm);
        let [mut ia, mut ib] = self.i_ab;
        let [va, vb] = self.v_ab_applied;
        // The band a phase current's inverter error ramps over: where the PWM ripple
        // takes it through zero within a period.
        let band_a = (va.hypot(vb) * c.ripple_per_v).max(c.band_floor_a);
        let mut torque = 0.0;
        // The comparator's timing (read by a modelled timer; nothing below depends on it
        // except the armed break path's opening).
        let (mut crossing, mut opened, mut over) = (None, None, self.comparator_over);
        // When the armed break path opens the bridge (s from this period's start).
        let mut open_at = if self.break_opens_bridge {
            None
        } else {
            self.break_due_s.take()
        };
        // One exact sin/cos per period, then rotation by the substep's electrical angle at
        // the period's starting speed (the speed change within 50 µs moves the angle by
        // less than 1e-6 rad).
        let mut th_mid = theta + 0.5 * h * omega;
        let (mut se, mut ce) = (p * th_mid).sin_cos();
        let turn = sin_cos_small(p * omega * h);
        for n in 0..c.substeps {
            if n > 0 {
                (se, ce) = rotate((se, ce), turn);
                th_mid += omega * h;
            }
            // Back-EMF e_αβ = ωe·λ·(-sin θe, cos θe).
            let we_flux = p * omega * m.flux_wb;
            let (ea, eb) = (-we_flux * se, we_flux * ce);
            if open_at.is_some_and(|t| n as f64 * h >= t) {
                open_at = None;
                if !open {
                    open = true;
                    opened = Some(n as f64 * h);
                }
            }
            let before = (ia, ib);
            if open {
                // Bridge off: open windings (the freewheel transient is not modelled).
                (ia, ib) = (0.0, 0.0);
            } else {
                let (da, db) = inverter_error_ab(c.v_err, band_a, ia, ib);
                ia = (ia + c.h_over_l * (va + da - ea)) * c.k_r;
                ib = (ib + c.h_over_l * (vb + db - eb)) * c.k_r;
            }
            // The over-current comparator on any phase (a NaN current does not trip it).
            let level = self.break_level_a;
            let peak = Self::phase_peak_a(ia, ib);
            if peak > level {
                self.tripped = true;
                open |= self.break_opens_bridge;
                if !over && crossing.is_none() {
                    // A rising edge: linear between the substep's ends (at its start
                    // when the level moved below a current that was already there).
                    let peak_before = Self::phase_peak_a(before.0, before.1);
                    let f = ((level - peak_before) / (peak - peak_before)).clamp(0.0, 1.0);
                    let tc = (n as f64 + if f.is_finite() { f } else { 0.0 }) * h;
                    crossing = Some(tc);
                    if let (Some(d), false) = (self.break_path_delay_s, self.break_opens_bridge) {
                        open_at = open_at.or(Some(tc + d));
                    }
                }
                over = true;
            } else {
                over = false;
            }
            // T = 1.5·p·λ·(iβ cos θe - iα sin θe).
            let te = c.kt * (ib * ce - ia * se);
            let mut cog = 0.0;
            for cg in &m.cogging {
                cog += cg.amplitude_nm * (cg.harmonic as f64 * th_mid + cg.phase_rad).sin();
            }
            // Coulomb friction, smoothed over ±1 mrad/s to keep the ODE well posed.
            let coulomb = if m.coulomb_nm > 0.0 {
                m.coulomb_nm * (omega / 1.0e-3).tanh()
            } else {
                0.0
            };
            let fric = coulomb + m.viscous_nm_s_rad * omega;
            omega += (te - fric - load - cog) * c.h_over_j;
            theta += omega * h;
            torque += te;
        }
        (self.omega_rm, self.theta_rm, self.i_ab) = (omega, theta, [ia, ib]);
        self.last_torque_nm = torque / c.substeps as f64;
        (self.comparator_over, self.crossing_s, self.break_opened_s) = (over, crossing, opened);
        self.break_due_s = open_at.map(|t| t - c.substeps as f64 * h);
    }
}

/// Phase quantities a, b, c of an αβ vector (amplitude-invariant inverse Clarke).
pub fn ab_to_phases([al, be]: [f64; 2]) -> [f64; 3] {
    let b = -0.5 * al + 0.5 * SQRT3 * be;
    [al, b, -al - b]
}

/// Average-value inverter: the αβ voltage of three duty cycles on a DC link (the
/// common mode does not reach a star-connected motor).
pub fn duties_to_ab(d: &[f32; 3], vdc_v: f64) -> [f64; 2] {
    let [a, b, c] = d.map(|x| x as f64 * vdc_v);
    let mean = (a + b + c) / 3.0;
    let (an, bn, cn) = (a - mean, b - mean, c - mean);
    [an, (bn - cn) / SQRT3]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{self, ControlParams, Reference, Rig, Step};
    use crate::sensor::SensorParams;
    use drive::commissioning::{Adaptation, Setpoint};
    use drive::control::ControlPeriod;
    use drive::motion::LoopMode;
    use drive::telemetry::Command;
    use mras::Config;
    use mras_sim::{Adc, SensorModel, SpatialError};
    use std::f64::consts::TAU;

    const T_S: f64 = 50e-6;

    fn sensor(model: SensorModel) -> SensorSim {
        let mut p = SensorParams::exact(model);
        p.adc = Some(Adc {
            bits: 12,
            full_scale: 1.5,
        });
        SensorSim::new(p, 1).unwrap()
    }

    /// The plant under the firmware's control period, velocity loop, adaptation frozen.
    fn drive(motor: MotorParams, model: SensorModel, speed_rev_s: f64, substeps: u32) -> Rig {
        let control = ControlParams {
            mode: LoopMode::Velocity,
            bandwidth_hz: 20.0,
            current_bandwidth_hz: 1000.0,
            reference: Reference::Ramp {
                speed_rev_s,
                accel_rad_s2: 500.0,
            },
        };
        let cfg = Config {
            sample_period_s: T_S as f32,
            observer: mras::ObserverConfig {
                eigenvalues_hz: [200.0, 20.0, 2.0],
                inertia_kg_m2: motor.j_kg_m2 as f32,
            },
            ..Config::default()
        };
        let j = motor.j_kg_m2;
        let plant = Plant::new(motor, sensor(model), T_S, 0.0)
            .unwrap()
            .with_substeps(substeps);
        let d = rig::drive_config(&plant, &control, j, T_S).unwrap();
        let period = ControlPeriod::new(d, mras::Front::new(cfg).unwrap()).unwrap();
        let mut r = Rig::new(plant, period, Some(control.reference));
        r.command = Command {
            setpoint: Setpoint::Application,
            adaptation: Adaptation::Frozen,
            ..Command::OFF
        };
        r
    }

    fn run(d: &mut Rig, seconds: f64) -> Vec<Step> {
        (0..(seconds / T_S) as usize).map(|_| d.step()).collect()
    }

    /// 2 substeps against 16 on the plant alone: 6 V on the rotor's q axis from rest
    /// (it runs up to its no-load speed) and a load step; angle and currents agree.
    #[test]
    fn substeps_converge() {
        let mut out = Vec::new();
        for n in [2, 16] {
            let m = MotorParams {
                load_steps: vec![LoadStep {
                    t_s: 0.15,
                    torque_nm: 0.3,
                }],
                ..MotorParams::default()
            };
            let mut p = Plant::new(m, sensor(SensorModel::ideal(2)), T_S, 0.0)
                .unwrap()
                .with_substeps(n);
            let vdc = p.motor.vdc_v;
            for _ in 0..(0.3 / T_S) as usize {
                // One period ahead, at the middle of the next period.
                let th = 4.0 * (p.theta_rad() + 1.5 * T_S * p.omega_rad_s());
                let (va, vb) = (-6.0 * th.sin(), 6.0 * th.cos());
                let (duties, _) = drive::foc::svpwm(va as f32, vb as f32, vdc as f32);
                p.advance(&drive::control::Output {
                    duties,
                    enable: true,
                    supervisor_due: false,
                });
            }
            out.push((p.theta_rad(), p.i_ab));
        }
        let (a, b) = (out[0], out[1]);
        // 20 rad travelled open loop: 1e-5 of it.
        assert!((a.0 - b.0).abs() < 2e-4, "angle {} vs {}", a.0, b.0);
        let i_scale = b.1[0].hypot(b.1[1]);
        assert!(i_scale > 1.0, "{b:?}");
        for k in 0..2 {
            assert!(
                (a.1[k] - b.1[k]).abs() < 5e-3 * i_scale,
                "current {a:?} vs {b:?}"
            );
        }
    }

    /// The comparator as a modelled timer reads it: a level with the time it crossed,
    /// and the armed break path opening the bridge that long after the crossing.
    #[test]
    fn the_comparator_reports_its_crossing_and_an_armed_break_opens_the_bridge() {
        let run = |delay_s: Option<f64>| {
            let mut p = Plant::new(
                MotorParams::default(),
                sensor(SensorModel::ideal(2)),
                T_S,
                0.0,
            )
            .unwrap()
            .with_substeps(16);
            p.break_opens_bridge = false;
            p.break_path_delay_s = delay_s;
            p.break_level_a = 1.0;
            let vdc = p.motor.vdc_v;
            // 6 V on the q axis at rest: the current rises with L/R = 1.7 ms.
            let (duties, _) = drive::foc::svpwm(0.0, 6.0, vdc as f32);
            let out = drive::control::Output {
                duties,
                enable: true,
                supervisor_due: false,
            };
            let mut seen = Vec::new();
            for _ in 0..200 {
                p.advance_applied(&out);
                seen.push((p.crossing_s(), p.break_opened_s(), p.comparator_over()));
            }
            seen
        };
        let h = T_S / 16.0;
        // Not armed: one crossing, then a level that stays up.
        let free = run(None);
        let k = free.iter().position(|s| s.0.is_some()).unwrap();
        let tc = free[k].0.unwrap();
        assert!(tc > 0.0 && tc < T_S, "{tc}");
        assert!(free[k + 1..]
            .iter()
            .all(|s| s.0.is_none() && s.1.is_none() && s.2));
        // Armed with a latency of 2.5 substeps: the first substep starting that long
        // after the same crossing opens the bridge; the level falls with the current.
        let armed = run(Some(2.5 * h));
        assert_eq!(armed[k].0, Some(tc));
        let opened = armed[k].1.or(armed[k + 1].1.map(|o| o + T_S)).unwrap();
        assert!(
            opened >= tc + 2.5 * h && opened < tc + 3.5 * h,
            "{opened} vs {tc}"
        );
        assert!(!armed[k + 2].2, "the comparator is a level, not a latch");
    }

    #[test]
    fn duties_become_the_commanded_voltage() {
        // SVPWM duties of a vector reproduce it through the average-value inverter.
        for k in 0..12 {
            let th = k as f32 * 0.5;
            let (va, vb) = (10.0 * th.cos(), 10.0 * th.sin());
            let (d, _) = drive::foc::svpwm(va, vb, 48.0);
            let v = duties_to_ab(&d, 48.0);
            assert!((v[0] - va as f64).abs() < 1e-4 && (v[1] - vb as f64).abs() < 1e-4);
        }
    }

    #[test]
    fn holds_speed_against_a_load_step_with_matching_torque() {
        let m = MotorParams {
            load_steps: vec![LoadStep {
                t_s: 0.3,
                torque_nm: 0.5,
            }],
            ..MotorParams::default()
        };
        let mut d = drive(m, SensorModel::ideal(2), 10.0, SUBSTEPS);
        let s = run(&mut d, 1.0);
        let last = s.last().unwrap();
        let w = last.truth.omega_rad_s;
        assert!((w - 10.0 * TAU).abs() < 0.5, "{w}");
        // Steady state: electrical torque = load + viscous friction.
        let expect = 0.5 + 1e-5 * w;
        assert!(
            (last.torque_nm - expect).abs() < 0.02,
            "{} vs {expect}",
            last.torque_nm
        );
        assert!(s.iter().all(|x| x.fault.is_none()));
    }

    /// Torque ripple spectrum vs θrm at constant speed: harmonic `k` amplitude (N·m).
    fn torque_ripple(m: MotorParams, model: SensorModel, k: u32) -> f64 {
        let mut d = drive(m, model, 10.0, SUBSTEPS);
        let s = run(&mut d, 1.5);
        let mut e = SpatialError::<360>::new();
        for x in s.iter().filter(|x| x.truth.t_s > 0.5) {
            e.add(x.truth.theta_rad, x.torque_nm);
        }
        e.harmonic_amplitude_rad(k)
    }

    #[test]
    fn sensor_error_becomes_torque_ripple_at_its_harmonic() {
        let mut offset = SensorModel::ideal(2);
        offset.ax = 0.05;
        // The 5 Hz sensor error at 2θrm passes the 20 Hz velocity loop into real torque.
        let with = torque_ripple(MotorParams::default(), offset, 2);
        let without = torque_ripple(MotorParams::default(), SensorModel::ideal(2), 2);
        assert!(with > 20.0 * without.max(1e-6), "{with} vs {without}");
    }

    #[test]
    fn current_sensor_offset_and_gain_ripple_at_p_and_2p() {
        // Paper §V.C: offset → pole-pair harmonic, gain error → twice that.
        let p = MotorParams::default().pole_pairs;
        let m = MotorParams {
            load_steps: vec![LoadStep {
                t_s: 0.0,
                torque_nm: 0.5,
            }],
            ..MotorParams::default()
        };
        let mut off = m.clone();
        off.current_offset_a = [0.2, 0.0, 0.0];
        let r_off = torque_ripple(off, SensorModel::ideal(2), p);
        let r_off_2p = torque_ripple(m.clone(), SensorModel::ideal(2), p);
        assert!(r_off > 10.0 * r_off_2p.max(1e-6), "{r_off} vs {r_off_2p}");
        // A gain imbalance: twice the pole-pair harmonic, as the paper finds for two
        // fixed sensors. The drive reads the two shunts of the lowest duties, so the pair
        // (and the error's pattern) changes with the sector: a pole-pair component
        // appears beside it, of the same order.
        let mut gain = m.clone();
        gain.current_gain_error = [0.05, -0.05, 0.0];
        let r_gain = torque_ripple(gain.clone(), SensorModel::ideal(2), 2 * p);
        let r_none = torque_ripple(m.clone(), SensorModel::ideal(2), 2 * p);
        assert!(r_gain > 10.0 * r_none.max(1e-6), "{r_gain} vs {r_none}");
    }

    #[test]
    fn voltage_limit_caps_speed_without_blowing_up() {
        // Back-EMF at 48 V / √3 limits this motor to ~ 27.7 / (4·0.02) = 346 rad/s.
        let mut d = drive(
            MotorParams::default(),
            SensorModel::ideal(2),
            100.0,
            SUBSTEPS,
        );
        let s = run(&mut d, 1.5);
        let w = s.last().unwrap().truth.omega_rad_s;
        assert!(w.is_finite() && w < 360.0, "{w}");
        assert!(w > 250.0, "{w}");
    }
}

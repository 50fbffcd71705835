//! The board around the MCU: the NUCLEO-G474RE with the X-NUCLEO-IHM08M1 three-shunt
//! inverter shield and an analog sin/cos sensor, wired from `board_map` (the table the
//! firmware configures itself from): which signal each (ADC, channel) converts, the
//! comparator's pin on TIM1_BKIN and who pulls it up, the shunt amplifier's scaling and
//! offset, the bus divider; driving hil-sim's plant.
//!
//! The shunt inputs: the amplifier of phase p shows the phase current only while p's
//! low side conducts (dead time included) over the whole sampling window, and has
//! settled (`current_sense::SETTLE_NS` after the low side turned on); otherwise the
//! amplifier's zero plus the ringing of the last switching edge. Every input carries a
//! small deterministic noise.

use crate::periph::tim1::{OutRegs, Tim1};
use crate::periph::{flash, ticks, TICK_HZ};
use crate::regfile::RegFile;
use board_map::{Function, Signal, Tim1Signal};
use drive::control::{Output, Sample};
use hil_sim::plant::{CurrentAdc, MotorParams, Plant, Truth};
use hil_sim::plant_truth::PeriodTruth;
use hil_sim::scenario::Scenario;

/// The shield's current amplifier: A per count (signed: low-side shunts read inverted)
/// and its zero, from `board_map::current_sense`.
pub const CURRENT_A_PER_COUNT: f64 = board_map::current_sense::AMPS_PER_COUNT as f64;
pub const CURRENT_ZERO_COUNTS: u16 = board_map::current_sense::ZERO_COUNTS;

/// The ringing of a shunt amplifier's output after a switching edge: its amplitude
/// (counts), decay time and frequency. Not from a datasheet: an oscillation of some tens
/// of counts that has died out by `SETTLE_NS` (5 time constants ≈ 1 µs), the order of
/// what ST's Motor Control SDK budgets as T_noise for this board.
const RING_COUNTS: f64 = 40.0;
const RING_TAU_S: f64 = 200.0e-9;
const RING_HZ: f64 = 4.0e6;
/// The converted inputs' noise: ±2 counts, deterministic (a hash of the instant).
const NOISE_COUNTS: i64 = 2;

/// The NUCLEO-G474RE's HSE: the 24 MHz crystal X3 (UM2505, the STM32G4 Nucleo-64 user
/// manual; ST's own board support uses HSE_VALUE = 24 MHz). The firmware clocks from
/// HSI16 and never starts it; a firmware that does gets this frequency.
pub const NUCLEO_G474RE_HSE_HZ: f64 = 24.0e6;

/// The DC bus the emulated bench supplies to the shield (V).
pub const BENCH_SUPPLY_V: f64 = 24.0;

pub struct Board {
    pub plant: Plant,
    /// The PWM period the plant integrates per step (ticks): the timer's, once the
    /// firmware has started TIM1 (`advance_to`).
    period_ticks: u64,
    /// The time the plant's state belongs to.
    plant_at: u64,
    last: (Sample, Truth),
    /// Bank-2 pages write-protected in the option bytes (FLASH_WRP2AR), if any.
    pub wrp2a_pages: Option<(u32, u32)>,
    /// The crystal on OSC_IN/OSC_OUT (Hz).
    pub hse_hz: f64,
    /// DBGMCU_IDCODE.DEV_ID the chip reports (0x469: STM32G47x; another for a
    /// wrong-chip test).
    pub dev_id: u16,
    /// The plant's αβ current at the start of the last step and when (ticks): with the
    /// state at `plant_at`, the slope the shunts interpolate on.
    i_before: ([f64; 2], u64),
    /// The instant the plant's state belongs to: the trigger it was advanced to (the
    /// plant's own clock `plant_at` counts whole periods from its start).
    state_at: u64,
}

/// What an analog input shows of the plant: one phase current, the bus, the sensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Input {
    Phase(usize),
    Bus,
    SensorX,
    SensorY,
}

/// The TIM1 channel (0 = CH1) that drives the high side of a phase, from the board map.
fn tim1_channel_of(high: Signal) -> Option<usize> {
    match board_map::pin_use(high).function {
        Function::Tim1 { signal, .. } => match signal {
            Tim1Signal::Ch1 => Some(0),
            Tim1Signal::Ch2 => Some(1),
            Tim1Signal::Ch3 => Some(2),
            _ => None,
        },
        Function::Analog { .. } => None,
    }
}

/// The input ADC `adc` (0 = ADC1) converts on `channel`, from the board map.
fn input_of(adc: usize, channel: u32) -> Option<Input> {
    let pu = board_map::PINS.iter().find(|p| {
        matches!(p.function, Function::Analog { adc: a, channel: c }
            if a.index() == adc && c as u32 == channel)
    })?;
    Some(match pu.signal {
        Signal::CurrentU => Input::Phase(tim1_channel_of(Signal::HighU)?),
        Signal::CurrentV => Input::Phase(tim1_channel_of(Signal::HighV)?),
        Signal::CurrentW => Input::Phase(tim1_channel_of(Signal::HighW)?),
        Signal::BusVoltage => Input::Bus,
        Signal::SensorX => Input::SensorX,
        Signal::SensorY => Input::SensorY,
        _ => return None,
    })
}

/// The comparator's pin (TIM1_BKIN): its GPIO port base, pin number, alternate function.
pub fn bkin_pin() -> (u32, u32, u32) {
    let pu = board_map::pin_use(Signal::OverCurrent);
    let af = match pu.function {
        Function::Tim1 { af, .. } => af as u32,
        Function::Analog { .. } => 0,
    };
    let base = 0x4800_0000 + 0x400 * pu.pin.port_index() as u32;
    (base, pu.pin.number as u32, af)
}

/// The BKIN pin's level as the GPIO and the timer see it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BkinPin {
    /// The pin reads low: the comparator pulls it low, or nothing pulls it up (a
    /// released open-drain line with no pull-up floats: taken as low).
    pub low: bool,
    /// Released and nothing pulls it up.
    pub floating: bool,
    /// The pin is in its TIM1_BKIN alternate function (MODER = 10, AFR = the map's).
    pub routed: bool,
}

/// A deterministic noise in [-NOISE_COUNTS, NOISE_COUNTS] for an instant and input.
fn noise(t: u64, adc: usize, channel: u32) -> i64 {
    let mut h = t ^ (adc as u64) << 56 ^ (channel as u64) << 48;
    h = h.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h % (2 * NOISE_COUNTS as u64 + 1)) as i64 - NOISE_COUNTS
}

impl Board {
    /// The `commissioning` scenario's motor and distorted, arbitrarily mounted sensor on
    /// this board's amplifiers.
    pub fn commissioning(seed: u64) -> anyhow::Result<Self> {
        Self::with_sensor_of("commissioning", seed)
    }

    /// The same motor with an N = 1 sensor: `ripple-1rev`'s (error harmonics m = 1..16
    /// of a few mrad falling with m), for the firmware built with `sensor-n1`.
    pub fn commissioning_n1(seed: u64) -> anyhow::Result<Self> {
        Self::with_sensor_of("ripple-1rev", seed)
    }

    /// `ripple-1rev`'s rig and sensor: its load (J 5x the firmware's nominal, bearing
    /// friction, the once- and twice-per-revolution torque ripple fixed to the shaft) on
    /// the `commissioning` motor's windings and this board's inverter, and its N = 1
    /// sensor, for the firmware built with `sensor-n1` (`ripple_elf`).
    pub fn ripple_n1(seed: u64) -> anyhow::Result<Self> {
        let load = Scenario::load("ripple-1rev")?.file.motor.to_params()?;
        Self::build("ripple-1rev", seed, |m| {
            m.j_kg_m2 = load.j_kg_m2;
            m.coulomb_nm = load.coulomb_nm;
            m.viscous_nm_s_rad = load.viscous_nm_s_rad;
            m.cogging = load.cogging;
        })
    }

    /// The `commissioning` scenario's sensor on another motor: the firmware's constants
    /// stay the nominal ones (`board_map::motor`), the plant is `adjust`'s.
    pub fn commissioning_with_motor(
        seed: u64,
        adjust: impl FnOnce(&mut MotorParams),
    ) -> anyhow::Result<Self> {
        Self::build("commissioning", seed, adjust)
    }

    /// The `commissioning` scenario's motor with the sensor of scenario `sensor_of`.
    fn with_sensor_of(sensor_of: &str, seed: u64) -> anyhow::Result<Self> {
        Self::build(sensor_of, seed, |_| {})
    }

    fn build(
        sensor_of: &str,
        seed: u64,
        adjust: impl FnOnce(&mut MotorParams),
    ) -> anyhow::Result<Self> {
        let sc = Scenario::load("commissioning")?;
        let mut motor = sc.file.motor.to_params()?;
        adjust(&mut motor);
        // The bench supply of docs/hardware.md (the shield takes 10-48 V).
        motor.vdc_v = BENCH_SUPPLY_V;
        // The sensor amplifier: the scenario's converter (12 bits over ±1.5 units), so
        // that its worst sensor (amplitude 1.2, offsets 0.1, harmonics) stays in range.
        let sp = Scenario::load(sensor_of)?.file.sensor.to_params()?;
        let sensor = hil_sim::sensor::SensorSim::new(sp, seed)?;
        // Until the firmware starts TIM1 the plant only coasts at rest; its step is then
        // the period the firmware programmed (`advance_to`), so any PWM rate runs.
        let pwm_hz = 20_000.0;
        let mut plant = Plant::new(motor, sensor, 1.0 / pwm_hz, 0.3)?;
        plant.current_adc = CurrentAdc {
            amps_per_count: CURRENT_A_PER_COUNT,
            zero_counts: CURRENT_ZERO_COUNTS,
            max_counts: board_map::current_sense::FULL_SCALE_COUNTS,
        };
        // The comparator drives BKIN; the timer model owns what the break does.
        plant.break_opens_bridge = false;
        Ok(Self::new(plant, pwm_hz))
    }

    pub fn new(plant: Plant, pwm_hz: f64) -> Self {
        let period_ticks = (TICK_HZ / pwm_hz).round() as u64;
        let mut p = plant;
        let last = p.sample();
        Self {
            plant: p,
            period_ticks,
            plant_at: 0,
            last,
            wrp2a_pages: None,
            hse_hz: NUCLEO_G474RE_HSE_HZ,
            dev_id: crate::debug::DEV_ID_G474,
            i_before: ([0.0; 2], 0),
            state_at: 0,
        }
    }

    /// Option bytes loaded at reset (§3.4): write protection of bank 2.
    pub fn reset_option_bytes(&self, regs: &mut RegFile) {
        let v = match self.wrp2a_pages {
            Some((a, b)) => (b & 0x7F) << 16 | (a & 0x7F),
            None => 0x0000_00FF,
        };
        regs.set(flash::WRP2AR, v);
    }

    fn idle() -> Output {
        Output {
            duties: [0.0; 3],
            enable: false,
            supervisor_due: false,
        }
    }

    /// The PWM period the plant steps by (s).
    pub fn period_s(&self) -> f64 {
        self.period_ticks as f64 / TICK_HZ
    }

    pub fn period_ticks(&self) -> u64 {
        self.period_ticks
    }

    /// Step the plant by `period_ticks` from now on: the same motor, sensor (with its
    /// noise state) and settings at the same angle, its clock carried over. Done at the
    /// first trigger, before the bridge ever switched, so nothing else of the state
    /// matters (the motor is at rest).
    fn set_period(&mut self, period_ticks: u64) {
        if period_ticks == 0 || period_ticks == self.period_ticks {
            return;
        }
        let dt_s = period_ticks as f64 / TICK_HZ;
        let old = &self.plant;
        let Ok(mut p) = Plant::new(old.motor.clone(), old.sensor.clone(), dt_s, old.theta_rad())
        else {
            // The same motor and sensor were accepted at construction.
            unreachable!("the plant's parameters were validated when the board was built");
        };
        p.current_adc = old.current_adc;
        p.break_level_a = old.break_level_a;
        p.break_opens_bridge = old.break_opens_bridge;
        p.break_path_delay_s = old.break_path_delay_s;
        let steps = (old.time_s() / dt_s).round() as u64;
        for _ in 0..steps {
            p.advance_applied(&Self::idle());
        }
        self.plant = p;
        self.period_ticks = period_ticks;
    }

    /// The plant up to the sampling instant `t`, the last period driven with `duties`
    /// (bridge on if `on`), any periods before it coasting. `period_ticks` is the PWM
    /// period the timer runs (2·ARR·(PSC + 1) timer clocks, centre-aligned).
    pub fn advance_to(&mut self, t: u64, duties: [f32; 3], on: bool, period_ticks: u64) {
        self.set_period(period_ticks);
        let n =
            ((t.saturating_sub(self.plant_at)) as f64 / self.period_ticks as f64).round() as u64;
        if n == 0 {
            return;
        }
        self.i_before = (self.plant.currents_ab(), self.state_at);
        for _ in 1..n {
            self.plant.advance_applied(&Self::idle());
        }
        self.plant.advance_applied(&Output {
            duties,
            enable: on,
            supervisor_due: false,
        });
        self.plant_at += n * self.period_ticks;
        self.state_at = t;
        self.last = self.plant.sample();
    }

    /// When the period the plant integrated last began (ticks).
    pub fn last_period_start(&self) -> u64 {
        self.plant_at.saturating_sub(self.period_ticks)
    }

    pub fn next_coast(&self, _now: u64) -> u64 {
        self.plant_at + 2 * self.period_ticks
    }

    /// No sampling for two periods: the motor coasts with the bridge off. Returns
    /// whether the plant moved.
    pub fn coast(&mut self, now: u64) -> bool {
        let mut moved = false;
        while now >= self.plant_at + 2 * self.period_ticks {
            self.i_before = (self.plant.currents_ab(), self.state_at);
            self.plant.advance_applied(&Self::idle());
            self.plant_at += self.period_ticks;
            self.state_at += self.period_ticks;
            moved = true;
        }
        if moved {
            self.last = self.plant.sample();
        }
        moved
    }

    pub fn sample(&self) -> Sample {
        self.last.0
    }

    pub fn truth(&self) -> Truth {
        self.last.1
    }

    /// The plant at the last sampling instant: the truth, the phase currents and the
    /// torque of the period that ended there.
    pub fn period_truth(&self) -> PeriodTruth {
        PeriodTruth {
            truth: self.last.1,
            i_ab: self.plant.currents_ab(),
            torque_nm: self.plant.torque_nm(),
            duties: self.plant.duties_applied(),
        }
    }

    /// Phase currents a, b, c (A) at `t`: the plant's state at the trigger it was last
    /// advanced to, moved on by the slope over that step (the plant is average-valued, a
    /// PWM period a step).
    pub fn phase_currents_at(&self, t: u64) -> [f64; 3] {
        let (i0, t0) = self.i_before;
        let i1 = self.plant.currents_ab();
        let span = self.state_at.saturating_sub(t0).max(1) as f64;
        let f = (t as f64 - self.state_at as f64) / span;
        hil_sim::plant::ab_to_phases([0, 1].map(|k| i1[k] + (i1[k] - i0[k]) * f.clamp(-1.0, 1.0)))
    }

    /// The analog front end: what ADC `adc` (0 = ADC1) converts on `channel` over the
    /// sampling window [`from`, `to`] (ticks), in counts, with the timer's outputs as
    /// they are then.
    pub fn input(
        &self,
        tim: &Tim1,
        out: &OutRegs,
        adc: usize,
        channel: u32,
        from: u64,
        to: u64,
    ) -> u16 {
        use board_map::{bus_voltage, current_sense as cs};
        let full = cs::FULL_SCALE_COUNTS as f64 + 1.0;
        let n = noise(to, adc, channel);
        let v = match input_of(adc, channel) {
            None => return 0,
            Some(Input::SensorX) => return self.last.0.x,
            Some(Input::SensorY) => return self.last.0.y,
            Some(Input::Bus) => {
                let v_adc = self.plant.motor.vdc_v / bus_voltage::RATIO as f64;
                (v_adc / cs::VREF_V as f64 * full).round() as i64 + n
            }
            Some(Input::Phase(p)) => {
                let settle = ticks(cs::SETTLE_NS as f64 * 1e-9);
                let low = tim.low_side(out, p, from, to, settle);
                let zero = CURRENT_ZERO_COUNTS as i64;
                if low.conducts {
                    let i = self.phase_currents_at(to)[p];
                    zero + (i / CURRENT_A_PER_COUNT).round() as i64 + n
                } else {
                    let ring = low.last_edge.map_or(0.0, |e| {
                        let dt = to.saturating_sub(e) as f64 / TICK_HZ;
                        RING_COUNTS
                            * (-dt / RING_TAU_S).exp()
                            * (2.0 * std::f64::consts::PI * RING_HZ * dt).sin()
                    });
                    zero + ring.round() as i64 + n
                }
            }
        };
        v.clamp(0, cs::FULL_SCALE_COUNTS as i64) as u16
    }

    /// The comparator's pin: the open-drain output (low while over its level, or
    /// `glitch`) with the board's pull-up (`over_current::BOARD_PULL_UP`) or the pin's
    /// own (GPIOx_PUPDR = 01); a pull-down or nothing leaves the released line low.
    pub fn bkin(&self, regs: &RegFile, glitch: bool) -> BkinPin {
        let (port, pin, af) = bkin_pin();
        let moder = (regs.get(port) >> (2 * pin)) & 0b11;
        let afr = (regs.get(port + 0x20 + 4 * (pin / 8)) >> (4 * (pin % 8))) & 0xF;
        let pupdr = (regs.get(port + 0x0C) >> (2 * pin)) & 0b11;
        let pulled_up = board_map::over_current::BOARD_PULL_UP || pupdr == 0b01;
        let driven_low = self.plant.comparator_over() || glitch;
        BkinPin {
            low: driven_low || !pulled_up,
            floating: !driven_low && !pulled_up && pupdr != 0b10,
            routed: moder == 0b10 && afr == af,
        }
    }
}

//! The board around the MCU: the NUCLEO-G474RE with a three-phase inverter shield and
//! an analog sin/cos sensor, wired as the firmware's `board.rs` says (PA0 = ADC1_IN1
//! sensor X, PA1 = ADC2_IN2 sensor Y, PC0 = ADC1_IN6 current a, PC1 = ADC2_IN7 current
//! b, PA6 = the over-current comparator on TIM1_BKIN), driving hil-sim's plant. The
//! scaling constants are the board's hardware (amplifier gains), which the firmware's
//! board constants describe: they are repeated here as the physical side.

use crate::periph::{flash, TICK_HZ};
use crate::regfile::RegFile;
use drive::control::{Output, Sample};
use hil_sim::plant::{CurrentAdc, Plant, Truth};
use hil_sim::plant_truth::PeriodTruth;
use hil_sim::scenario::Scenario;

/// The shield's current amplifier: A per count, zero at mid-scale, low-side shunts read
/// inverted (ST's three-shunt boards).
pub const CURRENT_A_PER_COUNT: f64 = -0.0161;

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

    /// The `commissioning` scenario's motor with the sensor of scenario `sensor_of`.
    fn with_sensor_of(sensor_of: &str, seed: u64) -> anyhow::Result<Self> {
        let sc = Scenario::load("commissioning")?;
        let mut motor = sc.file.motor.to_params()?;
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
            zero_counts: 2048,
            max_counts: 4095,
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
        for _ in 1..n {
            self.plant.advance_applied(&Self::idle());
        }
        self.plant.advance_applied(&Output {
            duties,
            enable: on,
            supervisor_due: false,
        });
        self.plant_at += n * self.period_ticks;
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
            self.plant.advance_applied(&Self::idle());
            self.plant_at += self.period_ticks;
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

    /// The analog front end: what ADC `adc` (0 = ADC1) converts on `channel`.
    pub fn channel(s: &Sample, adc: usize, channel: u32) -> u16 {
        match (adc, channel) {
            (0, 1) => s.ia,
            (0, 6) => s.ic,
            (0, 11) => s.x,
            (1, 7) => s.ib,
            (1, 2) => 1500,
            (1, 13) => s.y,
            // Unwired inputs read near zero.
            _ => 0,
        }
    }
}

//! The board: NUCLEO-G474RE with an X-NUCLEO-IHM08M1-class three-phase inverter shield
//! and a KMZ41/KMZ60-class analog sin/cos sensor. The one owner of the clock tree, the
//! pin map and the electrical ratings. Verify the pin map against your shield's
//! schematic before the first power-up (docs/hardware.md).

/// SYSCLK from HSI16 through the PLL: 16 MHz / M 4 × N 85 / R 2 = 170 MHz, range 1 boost
/// (RM0440 §7.2.4, §6.1.5).
pub const SYSCLK_HZ: u32 = 170_000_000;

/// PWM carrier and control rate: TIM1 centre-aligned, one control period per carrier
/// period (the ADCs are triggered once per period, at the counter's peak). Everything
/// rate-dependent below derives from it; feature `pwm-40khz` doubles it.
#[cfg(not(feature = "pwm-40khz"))]
pub const PWM_HZ: u32 = 20_000;
#[cfg(feature = "pwm-40khz")]
pub const PWM_HZ: u32 = 40_000;
/// TIM1 ARR for centre-aligned mode: f_pwm = f_tim / (2·ARR).
pub const PWM_ARR: u16 = (SYSCLK_HZ / (2 * PWM_HZ)) as u16;
/// Control period T seen by the core.
pub const CONTROL_PERIOD_S: f32 = 1.0 / PWM_HZ as f32;
/// Dead time: 500 ns at 170 MHz is 85 ticks (DTG[7:5] = 0xx: DT = DTG·t_DTS, RM0440
/// §28.6.20). Check against the gate driver and MOSFETs of the shield.
pub const DEAD_TIME_TICKS: u8 = 85;

/// Pins (all AF6 for TIM1 on the STM32G474, DS12288 table 13):
/// TIM1_CH1 PA8, CH2 PA9, CH3 PA10; CH1N PA7, CH2N PB0, CH3N PB1; BKIN PA6 (active low,
/// over-current comparator of the shield).
/// Sensor X: PA0 = ADC1_IN1; sensor Y: PA1 = ADC2_IN2 (sampled simultaneously).
/// Phase current a: PC0 = ADC1_IN6; phase current b: PC1 = ADC2_IN7.
pub mod pins {
    pub const SENSOR_X_ADC1_CHANNEL: u8 = 1;
    pub const SENSOR_Y_ADC2_CHANNEL: u8 = 2;
    pub const CURRENT_A_ADC1_CHANNEL: u8 = 6;
    pub const CURRENT_B_ADC2_CHANNEL: u8 = 7;
}

/// Sensor front end: counts at zero and at the nominal amplitude (KMZ41 bridge through
/// the shield's amplifier, biased at mid-supply). Measure yours: docs/hardware.md step 3.
pub const SENSOR_OFFSET_COUNTS: u16 = 2048;
pub const SENSOR_AMPLITUDE_COUNTS: u16 = 1600;
/// Sensor periods per mechanical revolution (KMZ41 over a diametral magnet: 2).
pub const SENSOR_PERIODS: u16 = 2;

/// Current sensing: shunt amplifier gain in A per count, nominal zero at mid-scale (the
/// zero is measured at start-up with the bridge off). The sign is the board's: ST's
/// three-shunt boards read `i = zero - counts` (low-side shunts); confirm with a known
/// DC current at bring-up (docs/hardware.md, step 4) before closing the current loop.
pub const CURRENT_ZERO_COUNTS: u16 = 2048;
pub const CURRENT_A_PER_COUNT: f32 = -0.0161;
/// A measured zero further than this from the nominal means broken current sensing.
pub const CURRENT_ZERO_TOLERANCE_COUNTS: u16 = 200;

/// Motor (ElectroCraft RP34 class, the paper's) and supply.
pub const POLE_PAIRS: u16 = 4;
pub const R_OHM: f32 = 0.3;
pub const L_H: f32 = 0.5e-3;
pub const FLUX_WB: f32 = 0.02;
pub const INERTIA_KG_M2: f32 = 2.0e-4;
pub const VDC_V: f32 = 24.0;
pub const I_MAX_A: f32 = 10.0;
pub const CURRENT_BANDWIDTH_HZ: f32 = 1000.0;
/// Speed held in Run by this firmware's placeholder application (mechanical rad/s).
pub const APPLICATION_SPEED_RAD_S: f32 = 10.0 * core::f32::consts::TAU;
/// Speed loop used during commissioning (PI, double pole).
pub const SPEED_BANDWIDTH_HZ: f32 = 10.0;

/// Supervisor rate as a divisor of the control rate (1 kHz); the stream is every
/// `drive::supervisor::RECORD_DIVIDER`-th supervisor step (100 Hz).
pub const SUPERVISOR_DIVIDER: u32 = PWM_HZ / 1000;
// The supervisor runs at exactly 1 kHz, and ARR fits TIM1's 16 bits, at any PWM_HZ.
const _: () = assert!(PWM_HZ.is_multiple_of(1000) && SYSCLK_HZ / (2 * PWM_HZ) <= u16::MAX as u32);
/// Independent watchdog timeout, fed by the supervisor (1 kHz). Longer than a flash
/// page erase plus the record's programming (≤ 40 ms + 2 ms), during which the
/// supervisor does not run.
pub const WATCHDOG_TIMEOUT_US: u32 = 100_000;

/// The core's configuration on this board.
pub fn core_config() -> mras::Config {
    mras::Config {
        sample_period_s: CONTROL_PERIOD_S,
        sensor_periods: SENSOR_PERIODS,
        observer: mras::ObserverConfig {
            eigenvalues_hz: [200.0, 20.0, 2.0],
            inertia_kg_m2: INERTIA_KG_M2,
        },
        ..mras::Config::default()
    }
}

/// The control period's configuration on this board.
pub fn drive_config() -> Option<drive::control::DriveConfig> {
    let sensor =
        drive::adc::ChannelScaling::from_amplitude(SENSOR_OFFSET_COUNTS, SENSOR_AMPLITUDE_COUNTS)?;
    Some(drive::control::DriveConfig {
        control_period_s: CONTROL_PERIOD_S,
        motor: drive::control::MotorConfig {
            pole_pairs: POLE_PAIRS,
            r_ohm: R_OHM,
            l_h: L_H,
            flux_wb: FLUX_WB,
            inertia_kg_m2: INERTIA_KG_M2,
            vdc_v: VDC_V,
            i_max_a: I_MAX_A,
        },
        sensor_x: sensor,
        sensor_y: sensor,
        current: drive::control::CurrentSensing {
            amps_per_count: CURRENT_A_PER_COUNT,
            zero_counts: CURRENT_ZERO_COUNTS,
            max_counts: drive::adc::ADC_MAX_COUNTS,
            zero_tolerance_counts: CURRENT_ZERO_TOLERANCE_COUNTS,
        },
        current_bandwidth_hz: CURRENT_BANDWIDTH_HZ,
        speed_bandwidth_hz: SPEED_BANDWIDTH_HZ,
        // The placeholder application holds a speed; replace with your motion loop.
        application_loop: drive::motion::LoopMode::Velocity,
        application_bandwidth_hz: SPEED_BANDWIDTH_HZ,
        supervisor_divider: SUPERVISOR_DIVIDER,
    })
}

/// Commissioning parameters on this board.
pub fn commissioning_params() -> drive::commissioning::Params {
    drive::commissioning::Params {
        align_current_a: 0.2 * I_MAX_A,
        ..drive::commissioning::Params::default()
    }
}

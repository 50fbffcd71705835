//! The board: NUCLEO-G474RE with an X-NUCLEO-IHM08M1-class three-phase inverter shield
//! and a KMZ41/KMZ60-class analog sin/cos sensor. The one owner of the clock tree, the
//! pin map and the electrical ratings: [`setup`] brings them up and hands the app its
//! peripherals. Verify the pin map against your shield's schematic before the first
//! power-up (docs/hardware.md).

use crate::calibration::Flash;
use crate::pwm::Pwm;
use stm32g4xx_hal::gpio::GpioExt;
use stm32g4xx_hal::independent_watchdog::IndependentWatchdog;
use stm32g4xx_hal::pwr::{PwrExt, VoltageScale};
use stm32g4xx_hal::rcc::{
    Config as RccConfig, PllConfig, PllMDiv, PllNMul, PllRDiv, PllSrc, RccExt,
};
use stm32g4xx_hal::stm32::{Peripherals, ADC1, ADC12_COMMON, ADC2, RCC};

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

/// The ADCs' clock in timer ticks: synchronous HCLK/4 (adc.rs, CKMODE = 11).
pub const ADC_CLOCK_TICKS: u32 = 4;
/// From TRGO2 to the start of the first sampling window (RM0440 §21.4.x latency of
/// the injected trigger in synchronous clock mode), in ticks.
pub const ADC_TRIGGER_LATENCY_TICKS: u32 = 3 * ADC_CLOCK_TICKS;
/// Ticks from the first current slot's sampling start to the second's sampling end:
/// slot 1's sampling + 12.5-cycle conversion, then slot 2's sampling.
const CURRENT_SPAN_TICKS: u32 = ((board_map::SLOT_SAMPLING_HALF_CYCLES[0] as u32 + 25)
    + board_map::SLOT_SAMPLING_HALF_CYCLES[1] as u32)
    * ADC_CLOCK_TICKS
    / 2;
/// Ticks a shunt needs after its low side turns on: dead time, then the shield's
/// settling (board_map::current_sense::SETTLE_NS).
const SHUNT_SETTLE_TICKS: u32 =
    DEAD_TIME_TICKS as u32 + board_map::current_sense::SETTLE_NS * (SYSCLK_HZ / 1_000_000) / 1000;
/// Around the peak a phase's low side conducts from `-(ARR - CCR_before) + settle` to
/// `ARR - CCR_after` (ticks from the peak). The current conversions start `k + latency`
/// after the peak and span `CURRENT_SPAN_TICKS`; centring them in the window gives
/// the shortest half-window that still lets both slots read: SHUNT_HALF_WINDOW_MIN_TICKS.
pub const ADC_TRIGGER_AFTER_PEAK_TICKS: u32 =
    (SHUNT_SETTLE_TICKS - CURRENT_SPAN_TICKS) / 2 - ADC_TRIGGER_LATENCY_TICKS;
/// A phase is read only if `ARR - CCR` is at least this before and after the peak:
/// at 20 kHz a duty up to 1 - this/ARR; the two lowest duties of SVPWM stay below
/// 0.94 over the linear range (drive::control::phases_to_read).
pub const SHUNT_HALF_WINDOW_MIN_TICKS: u32 =
    ADC_TRIGGER_AFTER_PEAK_TICKS + ADC_TRIGGER_LATENCY_TICKS + CURRENT_SPAN_TICKS;
/// The voltage limit as a fraction of Vdc/√3 that keeps the two shunts read inside
/// their windows: SVPWM's lower two duties reach 1/2 + m·√3/4 (plus 0.007 for the
/// vector turning between the halves of the window at 100 Hz electrical), and must stay
/// at or below 1 - SHUNT_HALF_WINDOW_MIN_TICKS/ARR. 1 at 20 kHz; 0.94 at 40 kHz.
pub const MAX_MODULATION: f32 = {
    let d_max = 1.0 - SHUNT_HALF_WINDOW_MIN_TICKS as f32 / PWM_ARR as f32;
    let m = (d_max - 0.5 - 0.007) / (0.25 * 1.732_050_8);
    if m > 1.0 {
        1.0
    } else {
        m
    }
};

// Pins, ADC channels and the shield's analog front ends: `board_map` (one table,
// checked against ST's pin data, that the emulator wires its board from too).

/// Sensor front end: counts at zero and at the nominal amplitude (KMZ41 bridge through
/// the shield's amplifier, biased at mid-supply). Measure yours: docs/hardware.md step 3.
pub const SENSOR_OFFSET_COUNTS: u16 = 2048;
pub const SENSOR_AMPLITUDE_COUNTS: u16 = 1600;
/// Sensor periods per mechanical revolution (KMZ41 over a diametral magnet: 2; with the
/// feature `sensor-n1`, an on-axis magnet or Hall array: 1).
#[cfg(not(feature = "sensor-n1"))]
pub const SENSOR_PERIODS: u16 = 2;
#[cfg(feature = "sensor-n1")]
pub const SENSOR_PERIODS: u16 = 1;

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
/// With the feature `fast-run`, 24 rev/s: a back-EMF of 12.1 V, with the load's current
/// about 91 % of the linear voltage limit Vdc/√3 at 24 V (the emulator's
/// high-modulation test).
#[cfg(not(feature = "fast-run"))]
pub const APPLICATION_SPEED_RAD_S: f32 = 10.0 * core::f32::consts::TAU;
#[cfg(feature = "fast-run")]
pub const APPLICATION_SPEED_RAD_S: f32 = 24.0 * core::f32::consts::TAU;
/// Speed loop used during commissioning (PI, double pole).
pub const SPEED_BANDWIDTH_HZ: f32 = 10.0;

/// Supervisor rate as a divisor of the control rate (1 kHz); the stream is every
/// `drive::supervisor::RECORD_DIVIDER`-th supervisor step (every 11 ms).
pub const SUPERVISOR_DIVIDER: u32 = PWM_HZ / 1000;
// The supervisor runs at exactly 1 kHz, and ARR fits TIM1's 16 bits, at any PWM_HZ.
const _: () = assert!(PWM_HZ.is_multiple_of(1000) && SYSCLK_HZ / (2 * PWM_HZ) <= u16::MAX as u32);
/// Independent watchdog timeout, fed by the supervisor (1 kHz). Longer than a flash
/// page erase plus the record's programming (≤ 40 ms + 2 ms), during which the
/// supervisor does not run.
pub const WATCHDOG_TIMEOUT_US: u32 = 100_000;

/// The core's configuration on this board.
pub fn core_config() -> mras::Config {
    #[allow(unused_mut)]
    let mut cfg = mras::Config {
        sample_period_s: CONTROL_PERIOD_S,
        sensor_periods: SENSOR_PERIODS,
        observer: mras::ObserverConfig {
            eigenvalues_hz: [200.0, 20.0, 2.0],
            inertia_kg_m2: INERTIA_KG_M2,
        },
        ..mras::Config::default()
    };
    // An N = 1 sensor's error harmonics land anywhere up to m = 16: the bank grows from
    // the offset and C/D paths to the harmonics the commissioning measures. The first
    // stage is two valid paths, so this cannot fail; were it to, the default bank stays.
    #[cfg(feature = "sensor-n1")]
    if cfg.set_paths(&mras::survey::FIRST_STAGE).is_ok() {
        cfg.paths_from_data = true;
    }
    cfg
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
        max_modulation: MAX_MODULATION,
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

/// The core's sine/cosine: the CORDIC, or the portable `F32Trig` (feature `cordic`).
#[cfg(feature = "cordic")]
pub type CoreTrig = crate::cordic::Trig;
#[cfg(not(feature = "cordic"))]
pub type CoreTrig = mras::F32Trig;

/// What [`setup`] hands the app: the peripherals its tasks own, and why the last run
/// ended.
pub struct Board {
    /// TIM1 with the bridge off (MOE = 0), its pins on AF6.
    pub pwm: Pwm,
    pub trig: CoreTrig,
    pub flash: Flash,
    /// Not started: the app starts it once init's work is done.
    pub watchdog: IndependentWatchdog,
    /// Not started: from the moment they are, TRGO2 starts a conversion every period,
    /// so the app brings them up last ([`crate::adc::Adcs::new`]).
    pub adc: (ADC1, ADC2, ADC12_COMMON),
    /// The last reset was the independent watchdog's (RCC_CSR.IWDGRSTF, now cleared).
    pub watchdog_reset: bool,
}

/// Clocks, pins and peripherals, in the order the safe state needs: the bridge's
/// outputs are at their off level before their pins leave reset.
pub fn setup(dp: Peripherals, cp: &mut cortex_m::Peripherals) -> Board {
    // The cycle counter first: the ADC bring-up's timeouts (adc.rs) count its cycles.
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();

    // A debugger halt stops TIM1 (RM0440 DBGMCU_APB2FZR.DBG_TIM1_STOP); with the
    // counter stopped the timer disables its outputs as if MOE were reset (TIM1
    // "debug mode", OSSI = 1: off level), so a halted current loop never leaves the
    // bridge switching on its last duties.
    dp.DBGMCU
        .apb2_fz()
        .modify(|_, w| w.dbg_tim1_stop().set_bit());
    // Debug builds only (DBGMCU_APB1FZR1.DBG_IWDG_STOP): the watchdog pauses while
    // halted, so breakpoints do not reset the board. Release builds keep it counting.
    #[cfg(debug_assertions)]
    dp.DBGMCU
        .apb1l_fz()
        .modify(|_, w| w.dbg_iwdg_stop().set_bit());

    {
        // SAFETY: init-time clock enables through the PAC, before `dp.RCC` is
        // constrained; nothing else runs.
        let rcc = unsafe { &*RCC::ptr() };
        // §7.4 (RCC_APB1ENR1): the PWR clock, which the HAL's `freeze` does not enable
        // although it reads PWR_CR1.VOS and writes PWR_CR5.R1MODE (boost). Read back
        // before the first PWR access (ST's "delay after an RCC peripheral clock
        // enabling").
        rcc.apb1enr1().modify(|_, w| w.pwren().set_bit());
        let _ = rcc.apb1enr1().read();
        // §7.4 (RCC_APB2ENR): the SYSCFG clock, read back before the CFGR2 write.
        rcc.apb2enr().modify(|_, w| w.syscfgen().set_bit());
        let _ = rcc.apb2enr().read();
    }
    // §10.2.8 SYSCFG_CFGR2.CLL: a core lockup (a fault in the HardFault handler, a
    // bad stack) reaches TIM1's break input and clears MOE in hardware, where no
    // software runs any more. Set once; only a reset clears it.
    dp.SYSCFG.cfgr2().modify(|_, w| w.cll().set_bit());

    // Clock tree (SYSCLK_HZ): HSI16 / 4 × 85 / 2, range 1 boost.
    let pwr = dp
        .PWR
        .constrain()
        .vos(VoltageScale::Range1 { enable_boost: true })
        .freeze();
    let pll = PllConfig {
        mux: PllSrc::HSI,
        m: PllMDiv::DIV_4,
        n: PllNMul::MUL_85,
        r: Some(PllRDiv::DIV_2),
        q: None,
        p: None,
    };
    let mut rcc = dp
        .RCC
        .constrain()
        .freeze(RccConfig::pll().pll_cfg(pll).boost(true), pwr);

    // TIM1 before its pins: outputs driven to their off level (OSSI = 1, MOE = 0)
    // from the moment the pins become AF6, never floating (pwm.rs).
    let pwm = Pwm::new(dp.TIM1);

    // Pin map (`pins`): TIM1 outputs and break on AF6, sensor and currents analog.
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);
    let break_pin = gpioa.pa6.into_alternate::<6>();
    let _pwm_pins = (
        gpioa.pa8.into_alternate::<6>(),
        gpioa.pa9.into_alternate::<6>(),
        gpioa.pa10.into_alternate::<6>(),
        gpioa.pa7.into_alternate::<6>(),
        gpiob.pb0.into_alternate::<6>(),
        gpiob.pb1.into_alternate::<6>(),
    );
    let _analog = (
        gpioa.pa0.into_analog(),
        gpioa.pa1.into_analog(),
        gpioc.pc0.into_analog(),
        gpioc.pc1.into_analog(),
    );
    // A break may have latched while BKIN's pin was not yet on AF6 (a low input is
    // active). 1 µs covers the break filter (8 timer clocks) after the pin switch;
    // then clear it, unless the comparator holds the input active.
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000);
    pwm.clear_boot_break(break_pin.is_low());

    #[cfg(feature = "cordic")]
    let trig = crate::cordic::Cordic::new(dp.CORDIC);
    #[cfg(not(feature = "cordic"))]
    let trig = mras::F32Trig;

    // Why did the last run end? (RM0440 §7.4.29 RCC_CSR.) Read, then clear the flags.
    // SAFETY: read and clear of the reset flags during init.
    let csr = unsafe { &*RCC::ptr() }.csr();
    let watchdog_reset = csr.read().iwdgrstf().bit_is_set();
    csr.modify(|_, w| w.rmvf().set_bit());

    Board {
        pwm,
        trig,
        flash: Flash::new(dp.FLASH),
        watchdog: IndependentWatchdog::new(dp.IWDG),
        adc: (dp.ADC1, dp.ADC2, dp.ADC12_COMMON),
        watchdog_reset,
    }
}

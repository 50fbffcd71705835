//! The board: NUCLEO-G474RE with an X-NUCLEO-IHM08M1 three-phase inverter shield and a
//! KMZ41/KMZ60-class analog sin/cos sensor. The one owner of the clock tree and the
//! electrical ratings; the pin map and the analog front ends are data in `board_map`,
//! which [`setup`] applies: it brings them up and hands the app its peripherals. Set the
//! shield's jumpers before the first power-up (docs/hardware.md).

use crate::calibration::Flash;
use crate::pwm::Pwm;
use board_map::{Function, PinUse, Pull, Tim1Signal};
use stm32g4xx_hal::independent_watchdog::IndependentWatchdog;
use stm32g4xx_hal::pwr::{PwrExt, VoltageScale};
use stm32g4xx_hal::rcc::{
    Config as RccConfig, PllConfig, PllMDiv, PllNMul, PllRDiv, PllSrc, RccExt,
};
use stm32g4xx_hal::stm32::{Peripherals, ADC1, ADC12_COMMON, ADC2, GPIOA, GPIOB, GPIOC, RCC};

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
/// From TRGO2 to the start of the first sampling window: the injected trigger's latency
/// in synchronous clock mode, taken as 3 ADC clocks (RM0440's latency table was not
/// found to check it against; the emulator assumes 2.625). A clock either way moves the
/// current slots by 4 ticks in a window of at least 178.
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
/// an amplifier biased at mid-supply). Measure yours: docs/hardware.md step 3.
pub const SENSOR_OFFSET_COUNTS: u16 = board_map::sensor::OFFSET_COUNTS;
pub const SENSOR_AMPLITUDE_COUNTS: u16 = board_map::sensor::AMPLITUDE_COUNTS;
/// Sensor periods per mechanical revolution (KMZ41 over a diametral magnet: 2; with the
/// feature `sensor-n1`, an on-axis magnet or Hall array: 1).
#[cfg(not(feature = "sensor-n1"))]
pub const SENSOR_PERIODS: u16 = 2;
#[cfg(feature = "sensor-n1")]
pub const SENSOR_PERIODS: u16 = 1;

/// Current sensing: A per count with the board's sign, and the nominal zero (the zero
/// is measured at start-up with the bridge off): the IHM08M1's 10 mΩ shunts and ×5.18
/// amplifiers, `i = (zero - counts) · 15.55 mA` (board_map::current_sense). Confirm the
/// sign with a known DC current at bring-up (docs/hardware.md, step 4) before closing
/// the current loop.
pub const CURRENT_ZERO_COUNTS: u16 = board_map::current_sense::ZERO_COUNTS;
pub const CURRENT_A_PER_COUNT: f32 = board_map::current_sense::AMPS_PER_COUNT;
/// A measured zero further than this from the nominal means broken current sensing.
pub const CURRENT_ZERO_TOLERANCE_COUNTS: u16 = 200;

/// Motor (ElectroCraft RP34 class, the paper's) and supply: R and L are starting
/// points, identified at every power-up (`drive::ident`).
pub const POLE_PAIRS: u16 = board_map::motor::POLE_PAIRS;
pub const R_OHM: f32 = board_map::motor::R_OHM;
pub const L_H: f32 = board_map::motor::L_H;
pub const FLUX_WB: f32 = board_map::motor::FLUX_WB;
pub const INERTIA_KG_M2: f32 = board_map::motor::INERTIA_KG_M2;
pub const VDC_V: f32 = board_map::motor::VDC_V;
pub const I_MAX_A: f32 = board_map::motor::I_MAX_A;
pub const CURRENT_BANDWIDTH_HZ: f32 = 1000.0;
/// Speed held in Run by this firmware's placeholder application (mechanical rad/s).
/// With the feature `fast-run`, 24 rev/s: a back-EMF of 12.1 V, with the load's current
/// about 91 % of the linear voltage limit Vdc/√3 at 24 V (the emulator's
/// high-modulation test).
/// With the feature `slow-run`, 1 rev/s: below half the commissioning speed, where the
/// drive holds its coefficients and the torque-ripple learner (feature `learn-ripple`)
/// may run while the speed is steady (`cargo xtask ripple-elf`); with `run-5rev`,
/// 5 rev/s: the same, where the observer shows the learner's harmonics above its floor.
#[cfg(not(any(feature = "fast-run", feature = "slow-run", feature = "run-5rev")))]
pub const APPLICATION_SPEED_RAD_S: f32 = 10.0 * core::f32::consts::TAU;
#[cfg(all(
    feature = "fast-run",
    not(any(feature = "slow-run", feature = "run-5rev"))
))]
pub const APPLICATION_SPEED_RAD_S: f32 = 24.0 * core::f32::consts::TAU;
#[cfg(all(
    feature = "slow-run",
    not(any(feature = "fast-run", feature = "run-5rev"))
))]
pub const APPLICATION_SPEED_RAD_S: f32 = core::f32::consts::TAU;
#[cfg(all(
    feature = "run-5rev",
    not(any(feature = "fast-run", feature = "slow-run"))
))]
pub const APPLICATION_SPEED_RAD_S: f32 = 5.0 * core::f32::consts::TAU;
#[cfg(any(
    all(feature = "fast-run", feature = "slow-run"),
    all(feature = "fast-run", feature = "run-5rev"),
    all(feature = "slow-run", feature = "run-5rev")
))]
compile_error!("features `fast-run`, `slow-run` and `run-5rev` each set the Run speed: choose one");
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
        // The feature turns the learner on; without it the drive's default stands.
        learn_torque_ripple: cfg!(feature = "learn-ripple")
            || drive::commissioning::Params::default().learn_torque_ripple,
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
    // The watchdog pauses while the core is halted too (DBGMCU_APB1FZR1.DBG_IWDG_STOP,
    // §46.16.3): a halted core cannot feed it and the bridge is already off, so all a
    // counting watchdog would add is a reset, a latched Watchdog fault and a new
    // power-up after a probe's attach held the core for 100 ms. A running core is
    // guarded as before: the freeze applies only in Debug state.
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
    // The clock tree only: the GPIO clocks are enabled with the pins (`setup_pins`).
    let _rcc = dp
        .RCC
        .constrain()
        .freeze(RccConfig::pll().pll_cfg(pll).boost(true), pwr);

    // TIM1 before its pins: outputs driven to their off level (OSSI = 1, MOE = 0)
    // from the moment the pins become AF6, never floating (pwm.rs).
    let pwm = Pwm::new(dp.TIM1);

    // Pin map (`board_map::PINS`): TIM1 outputs and break on AF6, currents, bus voltage
    // and sensor analog.
    let bkin_low = setup_pins(&dp.GPIOA, &dp.GPIOB, &dp.GPIOC);
    pwm.clear_boot_break(bkin_low);

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

/// One pin's configuration from its line of `board_map::PINS`, written mode last: the
/// pull, speed and alternate function are in place while the pin is still analog (its
/// reset state: high impedance, pulls disconnected) and all take effect with the MODER
/// write, so the pin is never seen half configured (a BKIN without its pull-up).
#[derive(Clone, Copy)]
struct PinConfig {
    number: u32,
    /// GPIOx_MODER: 10 alternate function, 11 analog (RM0440 §9.4.1).
    mode: u32,
    /// GPIOx_PUPDR: 00 none, 01 pull-up, 10 pull-down (§9.4.4).
    pull: u32,
    /// GPIOx_OSPEEDR: 10 high speed for the gate-driver outputs (§9.4.3).
    speed: Option<u32>,
    /// GPIOx_AFRL/AFRH: the alternate function number (§9.4.9, §9.4.10).
    af: Option<u32>,
}

impl PinConfig {
    const fn of(u: &PinUse) -> Self {
        let number = u.pin.number as u32;
        match u.function {
            Function::Tim1 { signal, af, pull } => Self {
                number,
                mode: 0b10,
                pull: match pull {
                    Pull::None => 0b00,
                    Pull::Up => 0b01,
                    Pull::Down => 0b10,
                },
                speed: if signal.is_output() { Some(0b10) } else { None },
                af: Some(af as u32),
            },
            Function::Analog { .. } => Self {
                number,
                mode: 0b11,
                pull: 0b00,
                speed: None,
                af: None,
            },
        }
    }
}

/// Writes one pin's registers on a port: pull, speed, alternate function, then mode.
/// The three ports are distinct register-block types in the PAC, one expansion each.
macro_rules! configure_pin {
    ($port:expr, $c:expr) => {{
        let (port, c) = ($port, $c);
        let shift2 = 2 * c.number;
        // SAFETY (all writes): read-modify-write of this pin's own field, every value a
        // defined encoding (PinConfig), during init with nothing else running.
        port.pupdr()
            .modify(|r, w| unsafe { w.bits((r.bits() & !(0b11 << shift2)) | (c.pull << shift2)) });
        if let Some(speed) = c.speed {
            port.ospeedr().modify(|r, w| unsafe {
                w.bits((r.bits() & !(0b11 << shift2)) | (speed << shift2))
            });
        }
        if let Some(af) = c.af {
            let shift4 = 4 * (c.number % 8);
            if c.number < 8 {
                port.afrl().modify(|r, w| unsafe {
                    w.bits((r.bits() & !(0xF << shift4)) | (af << shift4))
                });
            } else {
                port.afrh().modify(|r, w| unsafe {
                    w.bits((r.bits() & !(0xF << shift4)) | (af << shift4))
                });
            }
        }
        port.moder()
            .modify(|r, w| unsafe { w.bits((r.bits() & !(0b11 << shift2)) | (c.mode << shift2)) });
    }};
}

/// Configures every pin of `board_map::PINS` (after TIM1: its outputs hold their off
/// level from the moment they become AF). The break input first, its pull-up set while
/// the pin is still analog, so BKIN never floats once it is TIM1's; then the gate
/// outputs and the analog inputs. Returns whether BKIN reads low (active) after the
/// break filter has seen the pin.
fn setup_pins(gpioa: &GPIOA, gpiob: &GPIOB, gpioc: &GPIOC) -> bool {
    // SAFETY: init-time clock enables through the PAC; nothing else runs.
    let rcc = unsafe { &*RCC::ptr() };
    // RM0440 §7.4 (RCC_AHB2ENR): the ports' clocks, read back before the first GPIO
    // access (ST's "delay after an RCC peripheral clock enabling").
    rcc.ahb2enr().modify(|_, w| {
        w.gpioaen()
            .set_bit()
            .gpioben()
            .set_bit()
            .gpiocen()
            .set_bit()
    });
    let _ = rcc.ahb2enr().read();

    let is_break = |u: &PinUse| {
        matches!(
            u.function,
            Function::Tim1 {
                signal: Tim1Signal::Bkin,
                ..
            }
        )
    };
    let configure = |u: &PinUse| {
        let c = PinConfig::of(u);
        match u.pin.port {
            b'A' => configure_pin!(gpioa, c),
            b'B' => configure_pin!(gpiob, c),
            b'C' => configure_pin!(gpioc, c),
            // board-map's pins are on ports A-C (tests/st_pin_database.rs).
            _ => panic!("a pin outside ports A-C"),
        }
    };
    board_map::PINS
        .iter()
        .filter(|u| is_break(u))
        .for_each(configure);
    board_map::PINS
        .iter()
        .filter(|u| !is_break(u))
        .for_each(configure);

    // A break may have latched while BKIN's pin was not yet on AF6 (a low input is
    // active). 1 µs covers the break filter (8 timer clocks) after the pin switch;
    // then the pin's level (GPIOx_IDR, §9.4.5) says whether the comparator holds it.
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000);
    let bkin = board_map::pin_use(board_map::Signal::OverCurrent).pin;
    let idr = match bkin.port {
        b'A' => gpioa.idr().read().bits(),
        b'B' => gpiob.idr().read().bits(),
        b'C' => gpioc.idr().read().bits(),
        _ => panic!("a pin outside ports A-C"),
    };
    idr & (1 << bkin.number) == 0
}

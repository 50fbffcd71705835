//! The drive firmware: the thin hardware layer around the portable core (`mras`) and the
//! portable drive logic (`drive`).
//!
//! Priorities (RTIC 2):
//! 3. `control`, bound to ADC1_2 (end of the injected sequence triggered by TIM1 TRGO2):
//!    read X, Y and the phase currents, scale, `Tracker::step`, current control with the
//!    corrected θ̂, SVPWM, compare registers (preloaded). Its cycle count is measured.
//! 2. `supervisor` (1 kHz, spawned by `control`): the power-up commissioning state
//!    machine, calibration in flash, watchdog feed, fault events.
//! 1. `stream` (100 Hz, spawned by `control`): the RTT coefficient stream.
#![no_std]
#![no_main]

mod adc;
mod board;
mod calibration;
#[cfg(feature = "cordic")]
mod cordic;
mod fault_record;
mod pwm;

use defmt_rtt as _;
use panic_probe as _;

/// Names of the core's paths, in configuration order, as streamed in `mras-paths`.
const PATH_NAMES: &str = "offset,amplitude_quadrature,h4,h5,h6,h7,h8";

/// min/mean/max of the control task's cycle count (DWT CYCCNT) since the last report.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub struct CycleStats {
    pub min: u32,
    pub max: u32,
    pub sum: u64,
    pub count: u32,
}

impl CycleStats {
    const EMPTY: Self = Self {
        min: u32::MAX,
        max: 0,
        sum: 0,
        count: 0,
    };

    fn add(&mut self, c: u32) {
        self.min = self.min.min(c);
        self.max = self.max.max(c);
        self.sum += c as u64;
        self.count += 1;
    }

    fn mean(&self) -> u32 {
        if self.count == 0 {
            0
        } else {
            (self.sum / self.count as u64) as u32
        }
    }
}

#[rtic::app(device = stm32g4xx_hal::stm32, dispatchers = [USART1, USART2])]
mod app {
    use crate::adc::Adcs;
    use crate::pwm::Pwm;
    use crate::{board, calibration, fault_record, CycleStats, PATH_NAMES};
    use cortex_m::peripheral::DWT;
    use drive::adc::{scale_pair, ChannelScaling};
    use drive::commissioning::{
        Adaptation, Cause, Commissioning, Inputs, LoadStatus, Outputs, Params, Request, Setpoint,
        State, StoreStatus,
    };
    use drive::foc::{self, Pi};
    use mras::{Coefficients, Config, Fault, Tracker};
    use stm32g4xx_hal::gpio::GpioExt;
    use stm32g4xx_hal::independent_watchdog::IndependentWatchdog;
    use stm32g4xx_hal::pwr::{PwrExt, VoltageScale};
    use stm32g4xx_hal::rcc::{
        Config as RccConfig, PllConfig, PllMDiv, PllNMul, PllRDiv, PllSrc, RccExt,
    };

    /// What `control` publishes for the slower tasks.
    #[derive(Clone, Copy)]
    pub struct Telemetry {
        pub ticks: u32,
        /// Commissioning state, set by the supervisor.
        pub state: State,
        /// First fault since the supervisor last looked.
        pub fault: Option<Fault>,
        pub faults_latched: u8,
        pub overcurrent: bool,
        pub omega_rad_s: f32,
        pub amplitude: f32,
        pub converged: bool,
        pub revs: u32,
        pub residual_max_rad: f32,
        pub cycles: CycleStats,
        /// The core's `Tracker::step` alone (with the ADC scaling).
        pub step_cycles: CycleStats,
        pub coefficients: Coefficients,
    }

    #[shared]
    struct Shared {
        telemetry: Telemetry,
        command: Outputs,
        /// Coefficients loaded from flash, for `control` to install.
        pending_load: Option<Coefficients>,
    }

    #[local]
    struct Local {
        adcs: Adcs,
        pwm: Pwm,
        tracker: Tracker<CoreTrig>,
        scaling: (ChannelScaling, ChannelScaling),
        id_pi: Pi,
        iq_pi: Pi,
        speed_pi: Pi,
        torque_cmd_nm: f32,
        ticks: u32,
        commissioning: Commissioning,
        watchdog: IndependentWatchdog,
        last_state: State,
        load: LoadStatus,
        store: StoreStatus,
    }

    /// The core's sine/cosine: the CORDIC, or the portable `F32Trig` (feature `cordic`).
    #[cfg(feature = "cordic")]
    type CoreTrig = crate::cordic::Trig;
    #[cfg(not(feature = "cordic"))]
    type CoreTrig = mras::F32Trig;

    fn core_config() -> Config {
        Config {
            sample_period_s: board::CONTROL_PERIOD_S,
            sensor_periods: board::SENSOR_PERIODS,
            observer: mras::ObserverConfig {
                eigenvalues_hz: [200.0, 20.0, 2.0],
                inertia_kg_m2: board::INERTIA_KG_M2,
            },
            ..Config::default()
        }
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut cp = cx.core;

        // Clock tree (board::SYSCLK_HZ): HSI16 / 4 × 85 / 2, range 1 boost.
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

        // Pin map (board::pins): TIM1 outputs and break on AF6, sensor and currents analog.
        let gpioa = dp.GPIOA.split(&mut rcc);
        let gpiob = dp.GPIOB.split(&mut rcc);
        let gpioc = dp.GPIOC.split(&mut rcc);
        let _pwm_pins = (
            gpioa.pa8.into_alternate::<6>(),
            gpioa.pa9.into_alternate::<6>(),
            gpioa.pa10.into_alternate::<6>(),
            gpioa.pa7.into_alternate::<6>(),
            gpiob.pb0.into_alternate::<6>(),
            gpiob.pb1.into_alternate::<6>(),
            gpioa.pa6.into_alternate::<6>(),
        );
        let _analog = (
            gpioa.pa0.into_analog(),
            gpioa.pa1.into_analog(),
            gpioc.pc0.into_analog(),
            gpioc.pc1.into_analog(),
        );

        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();

        let mut commissioning = Commissioning::new(Params {
            align_current_a: 0.2 * board::I_MAX_A,
            ..Params::default()
        });
        // Why did the last run end? (RM0440 §7.4.29 RCC_CSR; the fault record in RAM.)
        // SAFETY: read and clear of the reset flags during init.
        let csr = unsafe { (*stm32g4xx_hal::stm32::RCC::ptr()).csr().read() };
        if csr.iwdgrstf().bit_is_set() {
            defmt::error!("mras-fault cause=Watchdog state=Boot t_ms=0");
            commissioning.force_safe(Cause::Watchdog);
        }
        unsafe {
            (*stm32g4xx_hal::stm32::RCC::ptr())
                .csr()
                .modify(|_, w| w.rmvf().set_bit())
        };
        if let Some(pc) = fault_record::take() {
            defmt::error!(
                "mras-fault cause=HardFault state=Boot t_ms=0 pc={=u32:#x}",
                pc
            );
            commissioning.force_safe(Cause::HardFault);
        }

        let mut watchdog = IndependentWatchdog::new(dp.IWDG);
        watchdog.start(stm32g4xx_hal::time::MicroSecond::from_ticks(
            board::WATCHDOG_TIMEOUT_US,
        ));

        #[cfg(feature = "cordic")]
        let trig = crate::cordic::Cordic::new(dp.CORDIC);
        #[cfg(not(feature = "cordic"))]
        let trig = mras::F32Trig;
        let tracker = match Tracker::with_trig(core_config(), trig) {
            Ok(t) => t,
            Err(e) => defmt::panic!("core configuration: {=str}: {=str}", e.field, e.problem),
        };
        let scaling = match (
            ChannelScaling::from_amplitude(
                board::SENSOR_OFFSET_COUNTS,
                board::SENSOR_AMPLITUDE_COUNTS,
            ),
            ChannelScaling::from_amplitude(
                board::SENSOR_OFFSET_COUNTS,
                board::SENSOR_AMPLITUDE_COUNTS,
            ),
        ) {
            (Some(x), Some(y)) => (x, y),
            _ => defmt::panic!("board sensor scaling out of range"),
        };
        let coefficients = tracker.coefficients();

        let pwm = Pwm::new(dp.TIM1);
        let adcs = Adcs::new(dp.ADC1, dp.ADC2, dp.ADC12_COMMON);
        calibration::init(dp.FLASH);

        defmt::info!("mras-paths {=str}", PATH_NAMES);
        defmt::info!(
            "drive-fw: {=u32} Hz PWM, SYSCLK {=u32} Hz, N = {=u16}",
            board::PWM_HZ,
            board::SYSCLK_HZ,
            board::SENSOR_PERIODS
        );
        let command = commissioning.outputs();
        (
            Shared {
                telemetry: Telemetry {
                    ticks: 0,
                    state: State::CheckSensor,
                    fault: None,
                    faults_latched: 0,
                    overcurrent: false,
                    omega_rad_s: 0.0,
                    amplitude: 0.0,
                    converged: false,
                    revs: 0,
                    residual_max_rad: f32::INFINITY,
                    cycles: CycleStats::EMPTY,
                    step_cycles: CycleStats::EMPTY,
                    coefficients,
                },
                command,
                pending_load: None,
            },
            Local {
                adcs,
                pwm,
                tracker,
                scaling,
                id_pi: Pi::current_loop(board::R_OHM, board::L_H, board::CURRENT_BANDWIDTH_HZ),
                iq_pi: Pi::current_loop(board::R_OHM, board::L_H, board::CURRENT_BANDWIDTH_HZ),
                speed_pi: {
                    // Double pole at the speed bandwidth on J: kp = 2ωJ, ki = ω²J.
                    let w = core::f32::consts::TAU * board::SPEED_BANDWIDTH_HZ;
                    Pi {
                        kp: 2.0 * w * board::INERTIA_KG_M2,
                        ki: w * w * board::INERTIA_KG_M2,
                        integral: 0.0,
                    }
                },
                torque_cmd_nm: 0.0,
                ticks: 0,
                commissioning,
                watchdog,
                last_state: State::CheckSensor,
                load: LoadStatus::Pending,
                store: StoreStatus::Pending,
            },
        )
    }

    /// The control period: highest priority, bound to the end of the injected sequence.
    #[task(binds = ADC1_2, priority = 3,
           local = [adcs, pwm, tracker, scaling, id_pi, iq_pi, speed_pi, torque_cmd_nm, ticks],
           shared = [telemetry, command, pending_load])]
    fn control(mut cx: control::Context) {
        let t0 = DWT::cycle_count();
        let l = cx.local;
        let s = l.adcs.read();
        let cmd = cx.shared.command.lock(|c| *c);
        if let Some(c) = cx.shared.pending_load.lock(|p| p.take()) {
            if l.tracker.set_coefficients(&c).is_err() {
                defmt::warn!("stored coefficients refused by the core");
            }
        }
        l.tracker.set_frozen(cmd.adaptation == Adaptation::Frozen);

        // Sensor → core. A railed ADC is the core's SensorSaturated. The core's step is
        // timed on its own too: the figure docs/performance.md estimates on the emulator.
        let t_step = DWT::cycle_count();
        let result = match scale_pair(s.x, s.y, &l.scaling.0, &l.scaling.1) {
            Ok((x, y)) => l.tracker.step(x, y, *l.torque_cmd_nm),
            Err(_) => Err(Fault::SensorSaturated),
        };
        let step_cycles = DWT::cycle_count().wrapping_sub(t_step);
        let est = l.tracker.last_estimate();

        // Currents (shunts at mid-scale), torque and voltage.
        let amps =
            |c: u16| (c as f32 - board::CURRENT_OFFSET_COUNTS as f32) * board::CURRENT_A_PER_COUNT;
        let (i_alpha, i_beta) = foc::clarke(amps(s.ia), amps(s.ib));
        let p = board::POLE_PAIRS as f32;
        let kt = 1.5 * p * board::FLUX_WB;
        let t = board::CONTROL_PERIOD_S;
        let (angle, id_ref, iq_ref) = match cmd.setpoint {
            Setpoint::Off => (0.0, 0.0, 0.0),
            Setpoint::Align { current_a } => (0.0, current_a, 0.0),
            Setpoint::Speed { .. } | Setpoint::Application => {
                // Application: hold the commissioning speed; replace with your motion loop.
                let omega_rad_s = match cmd.setpoint {
                    Setpoint::Speed { omega_rad_s } => omega_rad_s,
                    _ => board::APPLICATION_SPEED_RAD_S,
                };
                let torque = l
                    .speed_pi
                    .step(omega_rad_s - est.omega_rad_s, t, false)
                    .clamp(-kt * board::I_MAX_A, kt * board::I_MAX_A);
                (p * est.theta_rad, 0.0, torque / kt)
            }
        };
        if cmd.setpoint == Setpoint::Off || result.is_err() {
            l.pwm.disarm();
            l.id_pi.reset();
            l.iq_pi.reset();
            l.speed_pi.reset();
            *l.torque_cmd_nm = 0.0;
        } else {
            let sc = libm::sincosf(angle);
            let (id, iq) = foc::park(i_alpha, i_beta, sc);
            let vd = l.id_pi.step(id_ref - id, t, false);
            let vq = l.iq_pi.step(iq_ref - iq, t, false);
            // Rotate by the angle travelled until the middle of the next period.
            let lead = 1.5 * p * est.omega_rad_s * t;
            let (va, vb) = foc::inverse_park(vd, vq, libm::sincosf(angle + lead));
            let (duty, _limited) = foc::svpwm(va, vb, board::VDC_V);
            l.pwm.set_duties(duty);
            if !l.pwm.armed() {
                l.pwm.arm();
            }
            *l.torque_cmd_nm = kt * iq_ref;
        }

        *l.ticks = l.ticks.wrapping_add(1);
        let cycles = DWT::cycle_count().wrapping_sub(t0);
        let conv = l.tracker.convergence();
        let snapshot = cmd.request == Request::StoreCalibration;
        let coefs = l.tracker.coefficients();
        let overcurrent = l.pwm.break_active();
        let ticks = *l.ticks;
        cx.shared.telemetry.lock(|tm| {
            tm.ticks = ticks;
            if tm.fault.is_none() {
                tm.fault = result.err();
            }
            tm.faults_latched = l.tracker.faults().bits();
            tm.overcurrent |= overcurrent;
            tm.omega_rad_s = est.omega_rad_s;
            tm.amplitude = est.amplitude;
            tm.converged = conv.converged;
            tm.revs = conv.revs_adapted;
            tm.residual_max_rad = conv.residual_rad[..conv.len as usize]
                .iter()
                .fold(0.0, |a, b| a.max(*b));
            tm.cycles.add(cycles);
            tm.step_cycles.add(step_cycles);
            if snapshot {
                tm.coefficients = coefs;
            }
        });
        if ticks.is_multiple_of(board::SUPERVISOR_DIVIDER) {
            supervisor::spawn().ok();
        }
        if ticks.is_multiple_of(board::STREAM_DIVIDER) {
            stream::spawn().ok();
        }
    }

    /// The commissioning state machine, flash, watchdog (1 kHz).
    #[task(priority = 2, local = [commissioning, watchdog, last_state, load, store],
           shared = [telemetry, command, pending_load])]
    async fn supervisor(mut cx: supervisor::Context) {
        let l = cx.local;
        let (fault, overcurrent, omega, converged, residual, coefs, ticks) =
            cx.shared.telemetry.lock(|tm| {
                let f = tm.fault.take();
                let oc = core::mem::take(&mut tm.overcurrent);
                (
                    f,
                    oc,
                    tm.omega_rad_s,
                    tm.converged,
                    tm.residual_max_rad,
                    tm.coefficients,
                    tm.ticks,
                )
            });
        let request = cx.shared.command.lock(|c| c.request);
        match request {
            Request::LoadCalibration if *l.load == LoadStatus::Pending => {
                *l.load = match calibration::load(&core_config()) {
                    Some(c) => {
                        cx.shared.pending_load.lock(|p| *p = Some(c));
                        LoadStatus::Loaded
                    }
                    None => LoadStatus::Unavailable,
                };
            }
            Request::StoreCalibration if *l.store == StoreStatus::Pending => {
                l.watchdog.feed();
                *l.store = if calibration::store(&coefs, &core_config()) {
                    StoreStatus::Done
                } else {
                    StoreStatus::Failed
                };
            }
            _ => {}
        }
        let out = l.commissioning.step(&Inputs {
            dt_s: board::SUPERVISOR_DIVIDER as f32 * board::CONTROL_PERIOD_S,
            fault,
            overcurrent,
            omega_rad_s: omega,
            converged,
            residual_max_rad: residual,
            load: *l.load,
            store: *l.store,
        });
        cx.shared.command.lock(|c| *c = out);
        let state = l.commissioning.state();
        cx.shared.telemetry.lock(|tm| tm.state = state);
        if state != *l.last_state {
            let t_ms = ticks / (board::PWM_HZ / 1000);
            match l.commissioning.cause() {
                Some(cause) => defmt::error!(
                    "mras-fault cause={=str} state={=str} t_ms={=u32}",
                    cause_name(cause),
                    l.last_state.name(),
                    t_ms
                ),
                None => defmt::info!("mras-state {=str} t_ms={=u32}", state.name(), t_ms),
            }
            *l.last_state = state;
        }
        l.watchdog.feed();
    }

    fn cause_name(c: Cause) -> &'static str {
        match c {
            Cause::Sensor(Fault::NonFiniteInput) => "NonFiniteInput",
            Cause::Sensor(Fault::SensorLost) => "SensorLost",
            Cause::Sensor(Fault::SensorSaturated) => "SensorSaturated",
            Cause::Sensor(Fault::LossOfLock) => "LossOfLock",
            Cause::Sensor(Fault::NumericalOverflow) => "NumericalOverflow",
            Cause::OverCurrent => "OverCurrent",
            Cause::BadInput => "BadInput",
            Cause::Timeout(_) => "Timeout",
            Cause::VerifyFailed => "VerifyFailed",
            Cause::StoreFailed => "StoreFailed",
            Cause::Watchdog => "Watchdog",
            Cause::HardFault => "HardFault",
        }
    }

    /// The RTT coefficient stream (100 Hz); the grammar `hil-sim rtt-log` parses.
    #[task(priority = 1, shared = [telemetry])]
    async fn stream(mut cx: stream::Context) {
        let (tm, cycles, step) = cx.shared.telemetry.lock(|tm| {
            let c = (tm.cycles, tm.step_cycles);
            tm.cycles = CycleStats::EMPTY;
            tm.step_cycles = CycleStats::EMPTY;
            (*tm, c.0, c.1)
        });
        let mut coef = [0.0f32; 2 * mras::MAX_PATHS];
        let mut n = 0;
        for (_, v) in tm.coefficients.iter() {
            coef[n] = v.re;
            coef[n + 1] = v.im;
            n += 2;
        }
        defmt::info!(
            "mras t_ms={=u32} state={=str} faults={=u8} omega_rad_s={=f32} amplitude={=f32} converged={=bool} revs={=u32} residual_max_rad={=f32} cycles_max={=u32} cycles_mean={=u32} cycles_min={=u32} step_cycles_max={=u32} step_cycles_mean={=u32} coef={=[?]}",
            tm.ticks / (board::PWM_HZ / 1000),
            tm.state.name(),
            tm.faults_latched,
            tm.omega_rad_s,
            tm.amplitude,
            tm.converged,
            tm.revs,
            tm.residual_max_rad,
            cycles.max,
            cycles.mean(),
            if cycles.count == 0 { 0 } else { cycles.min },
            step.max,
            step.mean(),
            &coef[..n]
        );
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    // Safe state first, then leave a record for the next boot and reset.
    pwm::disarm_from_anywhere();
    fault_record::store(ef.pc());
    cortex_m::peripheral::SCB::sys_reset();
}

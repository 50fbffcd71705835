//! The drive firmware: the thin hardware layer around the portable drive logic.
//!
//! Priorities (RTIC 2):
//! 3. `control`, bound to ADC1_2 (end of the injected sequence triggered by TIM1 TRGO2):
//!    read the ADCs → `drive::control::ControlPeriod::step` → compare registers and MOE.
//!    It hands the accepted sample to `adapt` and, at the supervisor's divider ticks,
//!    publishes a telemetry snapshot.
//! 2. `adapt` (every period, pended by `control`): the MRAS adaptation
//!    (`drive::adaptation::AdaptationTask`) on the handed-over samples; its updates go
//!    back to `control`, in force a fixed latency later (`mras::UPDATE_LATENCY_PERIODS`),
//!    so the result does not depend on when in between it ran. Both directions are
//!    lock-free queues: neither side ever masks the other.
//! 1. `supervisor` (1 kHz, spawned by `control`): `drive::supervisor::Supervisor::step`
//!    on the snapshot and the adaptation's report, the calibration flash, the watchdog,
//!    and the RTT stream. It is the only runtime context that logs; defmt-rtt neither
//!    blocks nor masks interrupts (firmware/app/Cargo.toml), so the control interrupt is
//!    never held up by RTT.
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

/// A panic: bridge off first, the cause for the next boot, reset. Interrupts are masked
/// before the MOE clear so that `control` cannot re-arm the bridge in between. No
/// logging: a frame may be half written by the interrupted task.
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    pwm::disarm_from_anywhere();
    fault_record::store_panic();
    cortex_m::peripheral::SCB::sys_reset();
}

#[rtic::app(device = stm32g4xx_hal::stm32, dispatchers = [USART1, USART2])]
mod app {
    use crate::adc::Adcs;
    use crate::pwm::Pwm;
    use crate::{board, calibration, fault_record};
    use calib_record::config_hash;
    use cortex_m::peripheral::DWT;
    use drive::adaptation::{AdaptReport, AdaptationTask};
    use drive::commissioning::Cause;
    use drive::control::ControlPeriod;
    use drive::motion::MotionRef;
    use drive::supervisor::Supervisor;
    use drive::telemetry::{self, Command, Install, TelemetrySlot};
    use heapless::spsc::{Consumer, Producer, Queue};
    use mras::{AdaptSample, Front, InjectionUpdate};
    use stm32g4xx_hal::gpio::GpioExt;
    use stm32g4xx_hal::independent_watchdog::IndependentWatchdog;
    use stm32g4xx_hal::pwr::{PwrExt, VoltageScale};
    use stm32g4xx_hal::rcc::{
        Config as RccConfig, PllConfig, PllMDiv, PllNMul, PllRDiv, PllSrc, RccExt,
    };
    use stm32g4xx_hal::stm32::Interrupt;

    /// The core's sine/cosine: the CORDIC, or the portable `F32Trig` (feature `cordic`).
    #[cfg(feature = "cordic")]
    type CoreTrig = crate::cordic::Trig;
    #[cfg(not(feature = "cordic"))]
    type CoreTrig = mras::F32Trig;

    #[shared]
    struct Shared {
        /// Supervisor → control, read every period.
        command: Command,
        /// Control → supervisor, at the divider ticks.
        telemetry: TelemetrySlot,
        /// Coefficients loaded from flash, for `adapt` to install.
        mailbox: Option<Install>,
        /// Adaptation → supervisor, after each snapshot period.
        report: AdaptReport,
    }

    #[local]
    struct Local {
        adcs: Adcs,
        pwm: Pwm,
        period: ControlPeriod<CoreTrig>,
        /// Accepted samples to `adapt`, and its updates back.
        handoff_tx: Producer<'static, AdaptSample, HANDOFF_DEPTH>,
        updates_rx: Consumer<'static, InjectionUpdate, UPDATE_DEPTH>,
        adaptation: AdaptationTask,
        handoff_rx: Consumer<'static, AdaptSample, HANDOFF_DEPTH>,
        updates_tx: Producer<'static, InjectionUpdate, UPDATE_DEPTH>,
        /// The previous control interrupt's cycle count (DWT CYCCNT).
        last_cycles: u32,
        supervisor: Supervisor,
        flash: calibration::Flash,
        watchdog: IndependentWatchdog,
    }

    /// Queue sizes (one slot is kept free): samples `adapt` may lag behind by, and the
    /// updates in flight (one per stride, and a whole install at once).
    const HANDOFF_DEPTH: usize = 16;
    const UPDATE_DEPTH: usize = 2 * mras::MAX_PATHS;

    #[init(local = [
        handoff: Queue<AdaptSample, HANDOFF_DEPTH> = Queue::new(),
        updates: Queue<InjectionUpdate, UPDATE_DEPTH> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut cp = cx.core;

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
            let rcc = unsafe { &*stm32g4xx_hal::stm32::RCC::ptr() };
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

        // TIM1 before its pins: outputs driven to their off level (OSSI = 1, MOE = 0)
        // from the moment the pins become AF6, never floating (pwm.rs).
        let pwm = Pwm::new(dp.TIM1);

        // Pin map (board::pins): TIM1 outputs and break on AF6, sensor and currents analog.
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
        cortex_m::asm::delay(board::SYSCLK_HZ / 1_000_000);
        pwm.clear_boot_break(break_pin.is_low());

        #[cfg(feature = "cordic")]
        let trig = crate::cordic::Cordic::new(dp.CORDIC);
        #[cfg(not(feature = "cordic"))]
        let trig = mras::F32Trig;
        let cfg = board::core_config();
        let tracker = match Front::with_trig(cfg, trig) {
            Ok(t) => t,
            Err(e) => defmt::panic!("core configuration: {=str}: {=str}", e.field, e.problem),
        };
        // Validated by `Front::with_trig` just above: cannot fail.
        let Ok(adaptation) = AdaptationTask::new(&cfg) else {
            defmt::panic!("core configuration")
        };
        let (handoff_tx, handoff_rx) = cx.local.handoff.split();
        let (updates_tx, updates_rx) = cx.local.updates.split();
        let Some(drive_cfg) = board::drive_config() else {
            defmt::panic!("board sensor scaling out of range (board.rs)")
        };
        let mut period = match ControlPeriod::new(drive_cfg, tracker) {
            Ok(p) => p,
            Err(e) => defmt::panic!("drive configuration: {=str}: {=str}", e.field, e.problem),
        };
        // The placeholder application: hold a speed (replace with your motion loop).
        period.set_reference(MotionRef {
            omega_rad_s: board::APPLICATION_SPEED_RAD_S,
            ..MotionRef::default()
        });
        let mut supervisor = Supervisor::new(
            board::commissioning_params(),
            config_hash(&cfg, board::POLE_PAIRS),
            board::PWM_HZ,
            board::SUPERVISOR_DIVIDER,
        );

        // Why did the last run end? (RM0440 §7.4.29 RCC_CSR; the fault record in RAM.)
        // SAFETY: read and clear of the reset flags during init.
        let csr = unsafe { (*stm32g4xx_hal::stm32::RCC::ptr()).csr().read() };
        let watchdog_reset = csr.iwdgrstf().bit_is_set();
        unsafe {
            (*stm32g4xx_hal::stm32::RCC::ptr())
                .csr()
                .modify(|_, w| w.rmvf().set_bit())
        };
        match fault_record::take() {
            Some(fault_record::Ended::HardFault { pc }) => {
                defmt::error!("previous run ended in a HardFault at pc={=u32:#x}", pc);
                supervisor.boot_fault(Cause::HardFault);
            }
            Some(fault_record::Ended::Panic) => supervisor.boot_fault(Cause::Panic),
            None if watchdog_reset => supervisor.boot_fault(Cause::Watchdog),
            None => {}
        }

        let mut watchdog = IndependentWatchdog::new(dp.IWDG);
        watchdog.start(stm32g4xx_hal::time::MicroSecond::from_ticks(
            board::WATCHDOG_TIMEOUT_US,
        ));

        let flash = calibration::Flash::new(dp.FLASH);

        telemetry::log_paths(&telemetry::path_names(&cfg));
        defmt::info!(
            "drive-fw: {=u32} Hz PWM, SYSCLK {=u32} Hz, N = {=u16}, p = {=u16}",
            board::PWM_HZ,
            board::SYSCLK_HZ,
            board::SENSOR_PERIODS,
            board::POLE_PAIRS
        );
        // Last: from here TRGO2 starts a conversion every period, and init runs masked;
        // the logging above takes longer than a 40 kHz period.
        let adcs = Adcs::new(dp.ADC1, dp.ADC2, dp.ADC12_COMMON);
        (
            Shared {
                command: Command::OFF,
                telemetry: TelemetrySlot::EMPTY,
                mailbox: None,
                report: AdaptReport::EMPTY,
            },
            Local {
                adcs,
                pwm,
                period,
                handoff_tx,
                updates_rx,
                adaptation,
                handoff_rx,
                updates_tx,
                last_cycles: 0,
                supervisor,
                flash,
                watchdog,
            },
        )
    }

    /// The control period: highest priority, bound to the end of the injected sequence.
    #[task(binds = ADC1_2, priority = 3,
           local = [adcs, pwm, period, last_cycles, handoff_tx, updates_rx],
           shared = [command, telemetry])]
    fn control(mut cx: control::Context) {
        let t0 = DWT::cycle_count();
        let l = cx.local;
        let mut sample = l.adcs.read();
        sample.overcurrent = l.pwm.break_active();
        sample.cycles = *l.last_cycles;
        let command = cx.shared.command.lock(|c| *c);
        // The adaptation's updates due by this period.
        while let Some(u) = l.updates_rx.peek() {
            if !l.period.apply(u) {
                break;
            }
            l.updates_rx.dequeue();
        }
        let out = l.period.step(&sample, &command);
        l.pwm.apply(&out);
        if let Some(&h) = l.period.handoff() {
            if l.handoff_tx.enqueue(h).is_err() {
                l.period.note_handoff_dropped();
            }
            rtic::pend(Interrupt::USART3);
        }
        if out.supervisor_due {
            let snapshot = l.period.snapshot();
            cx.shared.telemetry.lock(|t| t.publish(snapshot));
            // Still running (a flash operation): this tick is skipped, the snapshot waits.
            supervisor::spawn().ok();
        }
        *l.last_cycles = DWT::cycle_count().wrapping_sub(t0);
    }

    /// The MRAS adaptation on every sample `control` handed over (USART3's vector, which
    /// no peripheral raises here, pended by `control`).
    #[task(binds = USART3, priority = 2, local = [adaptation, handoff_rx, updates_tx],
           shared = [mailbox, report])]
    fn adapt(mut cx: adapt::Context) {
        let l = cx.local;
        if let Some(i) = cx.shared.mailbox.lock(Option::take) {
            // The queue holds a whole install beside the updates in flight.
            l.adaptation.install(&i, |u| {
                l.updates_tx.enqueue(u).ok();
            });
            cx.shared.report.lock(|r| *r = *l.adaptation.report());
        }
        while let Some(s) = l.handoff_rx.dequeue() {
            if let Some(u) = l.adaptation.step(&s) {
                l.updates_tx.enqueue(u).ok();
            }
            if s.has(AdaptSample::REPORT) {
                cx.shared.report.lock(|r| *r = *l.adaptation.report());
            }
        }
    }

    /// Commissioning, calibration flash, watchdog and the stream (1 kHz).
    #[task(priority = 1, local = [supervisor, flash, watchdog],
           shared = [command, telemetry, mailbox, report])]
    async fn supervisor(mut cx: supervisor::Context) {
        let l = cx.local;
        let Some(mut tm) = cx.shared.telemetry.lock(TelemetrySlot::take) else {
            return;
        };
        tm.merge(&cx.shared.report.lock(|r| *r));
        let out = l.supervisor.step(&tm, l.flash);
        cx.shared.command.lock(|c| *c = out.command);
        if out.install.is_some() {
            cx.shared.mailbox.lock(|m| *m = out.install);
        }
        l.watchdog.feed();
        for e in &out.events {
            telemetry::log_event(e);
        }
        if let Some(r) = &out.record {
            telemetry::log_record(r);
        }
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    // Safe state first, then leave a record for the next boot and reset.
    pwm::disarm_from_anywhere();
    fault_record::store_hard_fault(ef.pc());
    cortex_m::peripheral::SCB::sys_reset();
}

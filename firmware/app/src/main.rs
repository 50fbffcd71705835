//! The drive firmware: the thin hardware layer around the portable drive logic.
//!
//! Priorities (RTIC 2):
//! 3. `control`, bound to ADC1_2 (end of the injected sequence triggered by TIM1 TRGO2):
//!    read the ADCs → `drive::control::ControlPeriod::step` → compare registers and MOE.
//!    It hands the accepted sample to `adapt` and, at the supervisor's divider ticks,
//!    owes the supervisor a telemetry snapshot of its state (`TelemetrySlot`).
//! 2. `adapt` (every period, pended by `control`): the MRAS adaptation
//!    (`drive::adaptation::AdaptationTask::run`) on the handed-over samples; its updates
//!    go back to `control`, in force a fixed latency later (`mras::UPDATE_LATENCY_PERIODS`),
//!    so the result does not depend on when in between it ran. Both directions are
//!    lock-free queues (`drive::handoff`, with their drop rules): neither side ever masks
//!    the other.
//! 1. `supervisor` (1 kHz, pended by `control`): `drive::supervisor::Supervisor::step`
//!    on the snapshot and the adaptation's report, the calibration flash, the watchdog,
//!    and the RTT stream. It copies the snapshot it is owed from the control period's
//!    state, masking `control` for the copy. It is the only runtime context that logs;
//!    defmt-rtt neither blocks nor masks interrupts (firmware/app/Cargo.toml), so the
//!    control interrupt is never held up by RTT.
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

#[rtic::app(device = stm32g4xx_hal::stm32)]
mod app {
    use crate::adc::{self, Adcs};
    use crate::pwm::Pwm;
    use crate::{board, calibration, fault_record};
    use core::sync::atomic::{AtomicBool, Ordering};
    use cortex_m::peripheral::DWT;
    use drive::adaptation::{AdaptReport, AdaptationTask};
    use drive::commissioning::Cause;
    use drive::control::ControlPeriod;
    use drive::handoff::{
        BankQueue, HandoffQueue, Prepared, SpareQueue, BANK_DEPTH, HANDOFF_DEPTH,
    };
    use drive::motion::MotionRef;
    use drive::supervisor::Supervisor;
    use drive::telemetry::{self, Command, Install, TelemetrySlot};
    use heapless::spsc::{Consumer, Producer, Queue};
    use mras::{AdaptSample, Front, Injection, InjectionUpdate};
    use stm32g4xx_hal::independent_watchdog::IndependentWatchdog;
    use stm32g4xx_hal::stm32::Interrupt;

    use crate::board::CoreTrig;

    #[shared]
    struct Shared {
        /// Supervisor → control, read every period.
        command: Command,
        /// Control → supervisor, at the divider ticks.
        telemetry: TelemetrySlot,
        /// The control period: `control`'s, read by `supervisor` for the snapshot a
        /// supervisor's period owes (a copy, with `control` masked).
        period: ControlPeriod<CoreTrig, &'static mut Injection>,
        /// Coefficients loaded from flash, for `adapt` to install.
        mailbox: Option<Install>,
        /// Adaptation → supervisor, after each snapshot period.
        report: AdaptReport,
    }

    #[local]
    struct Local {
        adcs: Adcs,
        pwm: Pwm,
        /// Accepted samples to `adapt`, and its updates and new banks' decoupling
        /// vectors back; the vectors they replaced to `adapt` again.
        handoff_tx: Producer<'static, AdaptSample, HANDOFF_DEPTH>,
        updates_rx: Consumer<'static, InjectionUpdate, UPDATES>,
        banks_rx: Consumer<'static, Prepared<&'static mut Injection>, BANK_DEPTH>,
        spares_tx: Producer<'static, &'static mut Injection, BANK_DEPTH>,
        adaptation: AdaptationTask<&'static mut Injection>,
        handoff_rx: Consumer<'static, AdaptSample, HANDOFF_DEPTH>,
        updates_tx: Producer<'static, InjectionUpdate, UPDATES>,
        banks_tx: Producer<'static, Prepared<&'static mut Injection>, BANK_DEPTH>,
        spares_rx: Consumer<'static, &'static mut Injection, BANK_DEPTH>,
        /// The previous control interrupt's cycle count (DWT CYCCNT).
        last_cycles: u32,
        supervisor: Supervisor,
        flash: calibration::Flash,
        watchdog: IndependentWatchdog,
        adc_start: adc::Start,
    }

    /// The update queue's depth: `drive::handoff`'s, or room for one update in the
    /// deliberately broken `mutant-starve-updates` build (firmware/app/Cargo.toml).
    const UPDATES: usize = if cfg!(feature = "mutant-starve-updates") {
        2
    } else {
        drive::handoff::UPDATE_DEPTH
    };

    #[init(local = [
        handoff: HandoffQueue = Queue::new(),
        updates: Queue<InjectionUpdate, UPDATES> = Queue::new(),
        banks: BankQueue<&'static mut Injection> = Queue::new(),
        spares: SpareQueue<&'static mut Injection> = Queue::new(),
        // The decoupling vector in force and the one a new bank is built in.
        injections: [Injection; 2] = [Injection::EMPTY; 2],
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut cp = cx.core;
        let hw = board::setup(cx.device, &mut cp);
        let (pwm, trig) = (hw.pwm, hw.trig);

        let cfg = board::core_config();
        let [in_force, spare] = cx.local.injections;
        let tracker = match Front::with_store(cfg, trig, in_force) {
            Ok(t) => t,
            Err(e) => defmt::panic!("core configuration: {=str}: {=str}", e.field, e.problem),
        };
        // Validated by `Front::with_trig` just above: cannot fail.
        let Ok(adaptation) = AdaptationTask::with_spare(&cfg, spare) else {
            defmt::panic!("core configuration")
        };
        let (handoff_tx, handoff_rx) = cx.local.handoff.split();
        let (updates_tx, updates_rx) = cx.local.updates.split();
        let (banks_tx, banks_rx) = cx.local.banks.split();
        let (spares_tx, spares_rx) = cx.local.spares.split();
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
            period.calibration_hash(),
            board::PWM_HZ,
            board::SUPERVISOR_DIVIDER,
            &period.config().motor,
            period.tracker().config().sensor_periods,
        );

        // Why did the last run end? (The fault record in RAM, then the reset flags.)
        match fault_record::take() {
            Some(fault_record::Ended::HardFault { pc }) => {
                defmt::error!("previous run ended in a HardFault at pc={=u32:#x}", pc);
                supervisor.boot_fault(Cause::HardFault);
            }
            Some(fault_record::Ended::Panic) => supervisor.boot_fault(Cause::Panic),
            None if hw.watchdog_reset => supervisor.boot_fault(Cause::Watchdog),
            None => {}
        }

        let mut watchdog = hw.watchdog;
        watchdog.start(stm32g4xx_hal::time::MicroSecond::from_ticks(
            board::WATCHDOG_TIMEOUT_US,
        ));

        // The banner starts a boot in the stream; the path names are its first line of
        // ours (telemetry::INIT_SEQ), the supervisor's lines follow numbered from 1.
        defmt::info!(
            "drive-fw: {=u32} Hz PWM, SYSCLK {=u32} Hz, N = {=u16}, p = {=u16}",
            board::PWM_HZ,
            board::SYSCLK_HZ,
            board::SENSOR_PERIODS,
            board::POLE_PAIRS
        );
        telemetry::log_paths(telemetry::INIT_SEQ, &telemetry::path_names(&cfg));
        // The conversions start in `idle`, after init: it runs masked, and the logging
        // above takes longer than a 40 kHz period.
        let (adc1, adc2, adc12) = hw.adc;
        let (adcs, adc_start) = Adcs::new(adc1, adc2, adc12);
        (
            Shared {
                command: Command::OFF,
                telemetry: TelemetrySlot::EMPTY,
                period,
                mailbox: None,
                report: AdaptReport::EMPTY,
            },
            Local {
                adcs,
                pwm,
                handoff_tx,
                updates_rx,
                banks_rx,
                spares_tx,
                adaptation,
                handoff_rx,
                updates_tx,
                banks_tx,
                spares_rx,
                last_cycles: 0,
                supervisor,
                flash: hw.flash,
                watchdog,
                adc_start,
            },
        )
    }

    /// Arms the ADC trigger: the first control interrupt follows the next TRGO2.
    #[idle(local = [adc_start])]
    fn idle(cx: idle::Context) -> ! {
        cx.local.adc_start.conversions();
        // RTIC's own idle when there is none: a branch to itself (`b .`), which the
        // emulator also takes for idle.
        #[allow(clippy::empty_loop)]
        loop {}
    }

    /// The control period: highest priority, bound to the end of the injected sequence.
    #[task(binds = ADC1_2, priority = 3,
           local = [adcs, pwm, last_cycles, handoff_tx, updates_rx, banks_rx, spares_tx],
           shared = [command, telemetry, period])]
    fn control(cx: control::Context) {
        let t0 = DWT::cycle_count();
        let l = cx.local;
        let mut sample = l.adcs.read();
        sample.overcurrent = l.pwm.break_active();
        sample.cycles = *l.last_cycles;
        let (mut command, mut telemetry) = (cx.shared.command, cx.shared.telemetry);
        // At the ceiling of `period`: no other task takes it while this one runs.
        let mut period = cx.shared.period;
        period.lock(|period| {
            // The snapshot of a supervisor's period the supervisor did not take (busy,
            // or preempted past it): written before anything changes that state.
            telemetry.lock(|t| t.settle_with(|s| period.write_snapshot(s)));
            period.apply_due(l.updates_rx, l.banks_rx, l.spares_tx);
            // Read where it lies (a copy cost about 30 cycles): at its ceiling here.
            let out = command.lock(|command| period.step(&sample, command));
            l.pwm.apply(&out);
            if period.hand_over(l.handoff_tx) {
                rtic::pend(Interrupt::USART3);
            }
            // The supervisor copies the snapshot (TelemetrySlot::take_into). Still
            // pended or running (a flash operation): this tick is skipped, and what its
            // snapshot would have restarted (the cycle statistics, the loss of lock)
            // runs on into the next.
            if out.supervisor_due && !SUPERVISOR_BUSY.load(Ordering::Relaxed) {
                SUPERVISOR_BUSY.store(true, Ordering::Relaxed);
                telemetry.lock(TelemetrySlot::owe);
                rtic::pend(Interrupt::USART1);
            }
        });
        if cfg!(feature = "mutant-slow-control") {
            // The deliberately broken build: busy until 1.5 control periods after entry.
            let busy = 3 * (board::SYSCLK_HZ / board::PWM_HZ) / 2;
            while DWT::cycle_count().wrapping_sub(t0) < busy {}
        }
        *l.last_cycles = DWT::cycle_count().wrapping_sub(t0);
    }

    /// The MRAS adaptation on every sample `control` handed over (USART3's vector, which
    /// no peripheral raises here, pended by `control`).
    #[task(binds = USART3, priority = 2, local = [adaptation, handoff_rx, updates_tx, banks_tx, spares_rx],
           shared = [mailbox, report])]
    fn adapt(mut cx: adapt::Context) {
        let l = cx.local;
        // Taken only when there is one: taking an empty mailbox copied the whole of it
        // (168 bytes, misaligned) on every run.
        let install = cx
            .shared
            .mailbox
            .lock(|m| if m.is_some() { m.take() } else { None });
        let mut report = cx.shared.report;
        l.adaptation.run(
            l.handoff_rx,
            l.updates_tx,
            l.banks_tx,
            l.spares_rx,
            install,
            |r| report.lock(|x| *x = *r),
        );
    }

    /// From `control`'s supervisor tick to the supervisor's return: a tick meanwhile is
    /// skipped. Set only by `control`, cleared only by `supervisor`.
    static SUPERVISOR_BUSY: AtomicBool = AtomicBool::new(false);

    /// Commissioning, calibration flash, watchdog and the stream (1 kHz; USART1's
    /// vector, which no peripheral raises here, pended by `control`: a pend where a
    /// spawn of a software task cost the control interrupt about 35 cycles more).
    #[task(binds = USART1, priority = 1, local = [supervisor, flash, watchdog],
           shared = [command, telemetry, mailbox, report, period])]
    fn supervisor(cx: supervisor::Context) {
        supervise(cx);
        SUPERVISOR_BUSY.store(false, Ordering::Relaxed);
    }

    fn supervise(mut cx: supervisor::Context) {
        use rtic::Mutex as _;
        let l = cx.local;
        // The snapshot copied with `control` masked: its period's state, which only
        // the next control period changes.
        let telemetry = &mut cx.shared.telemetry;
        let mut snapshot = telemetry::Snapshot::EMPTY;
        let fresh = cx
            .shared
            .period
            .lock(|p| telemetry.lock(|t| t.take_into(&mut snapshot, |s| p.write_snapshot(s))));
        if !fresh {
            return;
        }
        let tm = snapshot.merged(&cx.shared.report.lock(|r| *r));
        let out = l.supervisor.step(&tm, l.flash);
        // New motion constants in force here, in the hold that writes the command that
        // carries them (about 130 cycles with `control` held off): in the control
        // interrupt they took its period past half a 40 kHz one.
        let command = &mut cx.shared.command;
        cx.shared.period.lock(|p| {
            command.lock(|c| {
                p.put_motion(&out.command.motion);
                *c = out.command;
            })
        });
        if out.install.is_some() {
            cx.shared.mailbox.lock(|m| *m = out.install);
        }
        l.watchdog.feed();
        for (seq, line) in out.lines() {
            telemetry::log_line(seq, &line);
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

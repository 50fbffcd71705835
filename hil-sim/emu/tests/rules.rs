//! Each rule-based peripheral model against a register sequence that keeps the rule and
//! one that breaks it, as a firmware would write them (no CPU: the bus accesses only).
//! The scenarios (tests/scenarios.rs) then require the release firmware to break none.

use drive_emu::board::Board;
use drive_emu::machine::Machine;
use drive_emu::periph::flash::{CR as FLASH_CR, KEYR, SR as FLASH_SR};
use drive_emu::periph::rcc::{AHB1ENR, AHB2ENR, APB2ENR};
use drive_emu::periph::ticks;
use drive_emu::periph::tim1::{self, Tim1};
use drive_emu::rtt::Rtt;

fn machine() -> Machine {
    Machine::new(
        vec![0xFF; 512 * 1024],
        Board::commissioning(1).unwrap(),
        Rtt::new(None),
    )
}

/// Let `s` seconds pass with the CPU doing nothing.
fn wait(m: &mut Machine, s: f64) {
    m.now += ticks(s);
    m.service_events();
}

const ADC1_CR: u32 = 0x5000_0008;
const ADC1_ISR: u32 = 0x5000_0000;
const ADC_CCR: u32 = 0x5000_0308;

/// Clocked, regulator on and settled, calibrated: returns with ADCAL just cleared.
fn calibrated_adc(m: &mut Machine) {
    m.mmio_write(AHB2ENR, 4, 1 << 13);
    m.mmio_write(ADC_CCR, 4, 3 << 16);
    m.mmio_write(ADC1_CR, 4, 0); // DEEPPWD = 0
    m.mmio_write(ADC1_CR, 4, 1 << 28); // ADVREGEN
    wait(m, 25e-6);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 << 31); // ADCAL
    while m.mmio_read(ADC1_CR, 4) & (1 << 31) != 0 {
        m.now += 1;
    }
}

#[test]
fn aden_right_after_calibration_is_ignored_and_a_retry_enables() {
    let mut m = machine();
    calibrated_adc(&mut m);
    // Within 4 ADC clocks (16 ticks at HCLK/4) of ADCAL clearing: reset by the logic.
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1);
    assert_eq!(m.mmio_read(ADC1_CR, 4) & 1, 0, "ADEN must not stick");
    assert_eq!(m.adcs.violations.aden_ignored, 1);
    wait(&mut m, 1e-6);
    assert_eq!(m.mmio_read(ADC1_ISR, 4) & 1, 0, "never ready without ADEN");
    // The retry a correct firmware does: ADEN again, ADRDY follows.
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1);
    wait(&mut m, 1e-6);
    assert_eq!(m.mmio_read(ADC1_ISR, 4) & 1, 1);
}

#[test]
fn calibration_without_the_regulator_settled_is_reported() {
    let mut m = machine();
    m.mmio_write(AHB2ENR, 4, 1 << 13);
    m.mmio_write(ADC_CCR, 4, 3 << 16);
    m.mmio_write(ADC1_CR, 4, 0);
    m.mmio_write(ADC1_CR, 4, 1 << 28);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 << 31);
    assert_eq!(m.adcs.violations.cal_without_regulator, 1);
}

#[test]
fn an_unclocked_peripheral_ignores_writes_and_reads_zero() {
    let mut m = machine();
    m.mmio_write(tim1::ARR, 4, 4250);
    assert_eq!(m.mmio_read(tim1::ARR, 4), 0);
    assert_eq!(m.unmodelled.gated.get("TIM1"), Some(&2));
    m.mmio_write(APB2ENR, 4, 1 << 11);
    m.mmio_write(tim1::ARR, 4, 4250);
    assert_eq!(m.mmio_read(tim1::ARR, 4), 4250);
}

/// Unlocked flash with PER and a page of `bank2` selected, STRT written.
fn erase(m: &mut Machine, bank2: bool, page: u32) {
    m.mmio_write(KEYR, 4, 0x4567_0123);
    m.mmio_write(KEYR, 4, 0xCDEF_89AB);
    let bker = if bank2 { 1 << 11 } else { 0 };
    m.mmio_write(FLASH_CR, 4, 1 << 1 | page << 3 | bker);
    m.mmio_write(FLASH_CR, 4, 1 << 1 | page << 3 | bker | 1 << 16);
}

#[test]
fn erasing_the_code_bank_stalls_the_cpu_and_bank_2_does_not() {
    let mut m = machine();
    erase(&mut m, true, 126);
    assert_eq!(m.stall_until, 0, "bank 2 reads while writing");
    assert_eq!(m.flash_ctl.code_bank_erases, 0);
    wait(&mut m, 0.03);
    erase(&mut m, false, 100);
    assert_eq!(m.flash_ctl.code_bank_erases, 1);
    assert!(
        m.stall_until >= m.now + ticks(0.02),
        "the CPU waits for the erase"
    );
}

#[test]
fn a_stale_error_flag_refuses_the_next_operation_until_cleared() {
    let mut m = machine();
    // A stray write to flash: PGSERR, sticky.
    m.flash_write(0x7F000, 4, 0);
    assert_ne!(m.mmio_read(FLASH_SR, 4) & (1 << 7), 0);
    erase(&mut m, true, 126);
    assert_eq!(m.flash_ctl.stale_flag_refusals, 1);
    assert_eq!(m.flash_ctl.erases, 0);
    // Cleared by writing 1 (RM0440; the SVD says plain), then the erase runs.
    m.mmio_write(FLASH_SR, 4, 0xC3FB);
    assert_eq!(m.mmio_read(FLASH_SR, 4) & 0xC3FB, 0);
    erase(&mut m, true, 126);
    assert_eq!(m.flash_ctl.erases, 1);
}

/// TIM1 as the firmware sets it up (centre-aligned, ARR 4250, CCR4 = ARR - 1 on
/// TRGO2), with `rcr`, break enabled active low, MOE on.
fn pwm(m: &mut Machine, rcr: u32, bkine: bool) {
    m.mmio_write(APB2ENR, 4, 1 << 11);
    m.mmio_write(tim1::CR1, 4, 1 << 5 | 1 << 7);
    m.mmio_write(tim1::ARR, 4, 4250);
    m.mmio_write(tim1::CCMR1, 4, 0x6868);
    m.mmio_write(tim1::CCMR2, 4, 0x7868);
    m.mmio_write(tim1::CCR1 + 12, 4, 4249);
    m.mmio_write(tim1::CR2, 4, 0b0111 << 20);
    m.mmio_write(tim1::RCR, 4, rcr);
    m.mmio_write(tim1::AF1, 4, bkine as u32);
    m.mmio_write(tim1::BDTR, 4, 85 | 1 << 12 | 1 << 10 | 1 << 11);
    m.mmio_write(tim1::EGR, 4, 1);
    m.mmio_write(tim1::CR1, 4, 1 << 5 | 1 << 7 | 1);
    m.mmio_write(tim1::BDTR, 4, 85 | 1 << 12 | 1 << 10 | 1 << 11 | 1 << 15);
}

fn updates_per_period(rcr: u32) -> f64 {
    let mut m = machine();
    pwm(&mut m, rcr, true);
    let u0 = m.tim1.updates;
    let p0 = m.tim1.peaks;
    for _ in 0..200 {
        wait(&mut m, 10e-6);
    }
    (m.tim1.updates - u0) as f64 / (m.tim1.peaks - p0) as f64
}

#[test]
fn rcr_0_updates_at_peak_and_valley_rcr_1_once_per_period() {
    assert_eq!(updates_per_period(0), 2.0);
    assert_eq!(updates_per_period(1), 1.0);
}

/// The comparator's pin (board_map: PA6) on AF6 (TIM1_BKIN), with the internal
/// pull-up when `pull_up` (the IHM08M1 has none of its own).
fn bkin_pin(m: &mut Machine, pull_up: bool) {
    let en = m.mmio_read(AHB2ENR, 4);
    m.mmio_write(AHB2ENR, 4, en | 1);
    // The pull first, then the function: routed before its pull-up, the line floats.
    m.mmio_write(0x4800_000C, 4, u32::from(pull_up) << 12);
    m.mmio_write(0x4800_0020, 4, 6 << 24);
    let moder = m.mmio_read(0x4800_0000, 4) & !(0b11 << 12);
    m.mmio_write(0x4800_0000, 4, moder | 0b10 << 12);
}

fn break_clears_moe(bkine: bool) -> bool {
    let mut m = machine();
    bkin_pin(&mut m, true);
    pwm(&mut m, 1, bkine);
    assert!(Tim1::moe(&m.regs));
    m.board.plant.break_level_a = -1.0; // any current trips the comparator
    for _ in 0..10 {
        wait(&mut m, 50e-6);
    }
    !Tim1::moe(&m.regs)
}

#[test]
fn bkin_clears_moe_only_when_routed_by_af1() {
    assert!(break_clears_moe(true));
    assert!(
        !break_clears_moe(false),
        "AF1.BKINE = 0: the pin does not reach the break"
    );
}

// ---- missed control periods, as the hardware sees them ----

use drive_emu::machine::{ADC1_2_IRQ, USART3_IRQ};
use drive_emu::nvic::irq;
use drive_emu::scenarios::violations_of;
use drive_emu::stats::MissCause;

const ADC1_IER: u32 = 0x5000_0004;
const ADC1_JSQR: u32 = 0x5000_004C;
const ISR_JEOS: u32 = 1 << 6;
/// One PWM period of `pwm()`: centre-aligned, ARR 4250 at 170 MHz.
const PERIOD_S: f64 = 50e-6;

/// The firmware's acquisition: ADC1 calibrated and enabled, the injected pair on
/// TIM1 TRGO2 (JEXTSEL 8, rising edge), JEOS raising ADC1_2, TIM1 running.
fn acquisition(m: &mut Machine) {
    calibrated_adc(m);
    wait(m, 1e-6);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1); // ADEN
    wait(m, 1e-6);
    m.mmio_write(ADC1_JSQR, 4, 1 | 8 << 2 | 1 << 7 | 1 << 9 | 6 << 15);
    m.mmio_write(ADC1_IER, 4, ISR_JEOS);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 | 1 << 3); // JADSTART
    pwm(m, 1, true);
}

/// Wait (in 1 µs steps) until the control interrupt is requested.
fn until_requested(m: &mut Machine) {
    for _ in 0..200 {
        if m.nvic.irq_pending(ADC1_2_IRQ) {
            return;
        }
        wait(m, 1e-6);
    }
    panic!("no control interrupt requested within 200 µs");
}

/// Control interrupts that clear JEOS at entry (as the firmware's `Adcs::read` does)
/// and last `periods` PWM periods each, `n` times back to back.
fn control_interrupts(m: &mut Machine, periods: f64, n: usize) {
    for _ in 0..n {
        until_requested(m);
        m.exception_entered(irq(ADC1_2_IRQ), 0);
        m.mmio_write(ADC1_ISR, 4, ISR_JEOS);
        wait(m, periods * PERIOD_S);
        m.exception_returned(0);
    }
}

#[test]
fn a_control_interrupt_of_one_and_a_half_periods_misses_periods_though_jeos_is_read() {
    let mut m = machine();
    acquisition(&mut m);
    control_interrupts(&mut m, 0.4, 10);
    assert!(m.stats.missed.is_empty(), "{:?}", m.stats.missed);
    control_interrupts(&mut m, 1.5, 20);
    let missed = &m.stats.missed;
    // Every trigger lands in an interrupt that runs back to back with the next: the
    // whole stretch (about 30 periods) is missed, and never by an unread sequence,
    // which is all a JEOS-only count would have seen.
    assert!(missed.len() >= 25, "{} missed: {missed:?}", missed.len());
    assert!(missed
        .iter()
        .all(|x| x.cause == MissCause::ControlRunning && !x.before_control));
    assert!(missed.iter().all(|x| x.in_isr_instrs.is_some()));
}

#[test]
fn a_sequence_left_unread_or_an_adc_disarmed_after_the_control_ran_is_a_missed_period() {
    let mut m = machine();
    acquisition(&mut m);
    // Before the control interrupt ever ran (init): counted apart.
    until_requested(&mut m);
    wait(&mut m, PERIOD_S);
    assert!(m.stats.missed.iter().all(|x| x.before_control));
    assert_eq!(m.stats.missed_control(), 0);
    // The interrupt runs but leaves JEOS set: the next trigger finds it unread.
    m.exception_entered(irq(ADC1_2_IRQ), 0);
    m.exception_returned(0);
    m.mmio_write(ADC1_IER, 4, 0); // no more requests: nothing reads the sequence
    wait(&mut m, 2.0 * PERIOD_S);
    assert!(m
        .stats
        .missed
        .iter()
        .any(|x| x.cause == MissCause::SequenceUnread && !x.before_control));
    // The ADC disabled (ADDIS) once the control interrupt has run: triggers are lost.
    m.mmio_write(ADC1_ISR, 4, ISR_JEOS);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 << 1);
    let before = m.stats.missed.len();
    wait(&mut m, 3.0 * PERIOD_S);
    let lost: Vec<_> = m.stats.missed[before..].iter().map(|x| x.cause).collect();
    assert!(
        lost.len() >= 2 && lost.iter().all(|c| *c == MissCause::AdcNotArmed),
        "{lost:?}"
    );
}

#[test]
fn the_adaptation_task_returning_after_its_update_is_due_misses_its_deadline() {
    let mut m = machine();
    let ispr1 = 0xE000_E204;
    // Sample handed over in control interrupt k: USART3 pended from it.
    m.exception_entered(irq(ADC1_2_IRQ), 0);
    m.ppb_write(ispr1, 4, 1 << (USART3_IRQ - 32));
    m.exception_returned(0);
    m.exception_entered(irq(USART3_IRQ), 0);
    // Three control interrupts preempt it: the update is still in time.
    for _ in 0..3 {
        m.exception_entered(irq(ADC1_2_IRQ), 0);
        m.exception_returned(0);
    }
    m.exception_returned(0);
    assert_eq!(
        (m.stats.task_from_pend_max, m.stats.task_deadline_misses),
        (3, 0)
    );
    // Four: the fourth applies updates due by then, and this one is not in the queue.
    m.exception_entered(irq(ADC1_2_IRQ), 0);
    m.ppb_write(0xE000_EF00, 4, USART3_IRQ as u32); // STIR
    m.exception_returned(0);
    m.exception_entered(irq(USART3_IRQ), 0);
    for _ in 0..4 {
        m.exception_entered(irq(ADC1_2_IRQ), 0);
        m.exception_returned(0);
    }
    m.exception_returned(0);
    assert_eq!(
        (m.stats.task_from_pend_max, m.stats.task_deadline_misses),
        (4, 1)
    );
}

// ---- over-current: the comparator as a level through the break filter ----

/// PA6 on AF6 (TIM1_BKIN), TIM1 running with MOE on, BKF as given, the comparator's
/// level just above the standing current.
fn overcurrent_bench(bkf: u32) -> Machine {
    let mut m = machine();
    bkin_pin(&mut m, true);
    pwm(&mut m, 1, true);
    let bdtr = 85 | 1 << 12 | 1 << 10 | 1 << 11 | bkf << 16;
    m.mmio_write(tim1::BDTR, 4, bdtr);
    m.mmio_write(tim1::BDTR, 4, bdtr | 1 << 15);
    // Phase a high a little longer than b and c: a few amperes through the windings.
    m.mmio_write(tim1::CCR1, 4, 2200);
    m.mmio_write(tim1::CCR1 + 4, 4, 2125);
    m.mmio_write(tim1::CCR1 + 8, 4, 2125);
    for _ in 0..40 {
        wait(&mut m, PERIOD_S);
    }
    assert!(Tim1::moe(&m.regs));
    m
}

fn trip(m: &mut Machine) {
    m.board.plant.break_level_a = 1e-3;
    for _ in 0..4 {
        wait(m, PERIOD_S);
    }
}

#[test]
fn the_break_clears_moe_its_filter_after_the_comparator_crosses() {
    for (bkf, latency_s) in [(0, 0.0), (3, 8.0 / 170e6), (15, 8.0 * 32.0 / 170e6)] {
        let mut m = overcurrent_bench(bkf);
        trip(&mut m);
        assert!(!Tim1::moe(&m.regs), "BKF {bkf}");
        let b = m.stats.breaks[0];
        let dt = (b.moe_cleared - b.crossing) as f64 / 170e6;
        assert!((dt - latency_s).abs() < 1.5 / 170e6, "BKF {bkf}: {dt} s");
        // The bridge opened: the current fell, and the comparator (a level) with it.
        assert!(!m.board.plant.comparator_over(), "BKF {bkf}");
    }
}

#[test]
fn moe_written_during_an_active_break_is_refused_and_reported() {
    let mut m = overcurrent_bench(3);
    // Any current, none included, is over a negative level: the break stays active.
    m.board.plant.break_level_a = -1.0;
    wait(&mut m, 2.0 * PERIOD_S);
    assert!(!Tim1::moe(&m.regs));
    let bdtr = m.mmio_read(tim1::BDTR, 4);
    m.mmio_write(tim1::BDTR, 4, bdtr | 1 << 15);
    assert!(!Tim1::moe(&m.regs));
    assert_eq!(m.tim1.moe_refused, 1);
    assert!(violations_of(&m)
        .iter()
        .any(|v| v.contains("MOE written 1 while the break input was active")));
    // Once the level is back under, the hardware takes MOE again: whether the firmware
    // does is its supervisor's business (the overcurrent scenario checks that it
    // does not).
    m.board.plant.break_level_a = 100.0;
    wait(&mut m, 2.0 * PERIOD_S);
    let sets = m.tim1.moe_sets;
    m.mmio_write(tim1::BDTR, 4, bdtr | 1 << 15);
    assert!(Tim1::moe(&m.regs));
    assert_eq!(m.tim1.moe_sets, sets + 1);
}

#[test]
fn the_comparator_pin_reads_low_only_while_over_its_level() {
    let mut m = overcurrent_bench(3);
    let idr = 0x4800_0010;
    assert_ne!(m.mmio_read(idr, 4) & 1 << 6, 0, "pulled up");
    m.board.plant.break_level_a = -1.0;
    wait(&mut m, PERIOD_S);
    assert_eq!(m.mmio_read(idr, 4) & 1 << 6, 0);
}

// ---- flash: errors, BSY, a torn double word ----

/// Unlocked with PG set.
fn programming(m: &mut Machine) {
    m.mmio_write(KEYR, 4, 0x4567_0123);
    m.mmio_write(KEYR, 4, 0xCDEF_89AB);
    m.mmio_write(FLASH_CR, 4, 1);
}

const CALIB: u32 = 0x7F000;

#[test]
fn flash_programming_errors_are_reported_by_flag() {
    type Case = fn(&mut Machine);
    let cases: [(&str, Case); 6] = [
        ("PROGERR", |m| {
            m.flash_write(CALIB, 4, 1);
            m.flash_write(CALIB + 4, 4, 2);
            wait(m, 1e-3);
            m.flash_write(CALIB, 4, 3);
            m.flash_write(CALIB + 4, 4, 4);
        }),
        ("PGAERR", |m| m.flash_write(CALIB + 4, 4, 1)),
        ("SIZERR", |m| m.flash_write(CALIB, 2, 1)),
        ("PGSERR", |m| {
            m.mmio_write(FLASH_CR, 4, 0);
            m.flash_write(CALIB, 4, 1);
        }),
        ("while BSY", |m| {
            m.flash_write(CALIB, 4, 1);
            m.flash_write(CALIB + 4, 4, 2);
            m.flash_write(CALIB + 8, 4, 1);
            m.flash_write(CALIB + 12, 4, 2);
        }),
        ("stale", |m| {
            m.flash_write(CALIB, 2, 1);
            m.flash_write(CALIB, 4, 1);
            m.flash_write(CALIB + 4, 4, 2);
        }),
    ];
    for (flag, f) in cases {
        let mut m = machine();
        programming(&mut m);
        f(&mut m);
        let v = violations_of(&m);
        let key = match flag {
            "while BSY" => "while BSY",
            "stale" => "error flags of an earlier one still set",
            k => k,
        };
        assert!(v.iter().any(|s| s.contains(key)), "{flag}: {v:#?}");
    }
    // A sequence that keeps every rule breaks none.
    let mut m = machine();
    programming(&mut m);
    m.flash_write(CALIB, 4, 1);
    m.flash_write(CALIB + 4, 4, 2);
    wait(&mut m, 1e-3);
    m.flash_write(CALIB + 8, 4, 1);
    m.flash_write(CALIB + 12, 4, 2);
    assert!(violations_of(&m).is_empty(), "{:#?}", violations_of(&m));
}

#[test]
fn a_power_cut_while_programming_tears_the_double_word_and_its_read_raises_the_nmi() {
    let mut m = machine();
    programming(&mut m);
    m.flash_write(CALIB, 4, 0x1111_1111);
    m.flash_write(CALIB + 4, 4, 0x2222_2222);
    assert_eq!(m.power_cut(), Some(CALIB));
    assert_eq!(m.flash_read(CALIB + 4, 4), 0xFFFF_FFFF, "half programmed");
    assert!(m.nvic.nmi_pending);
    let eccr = 0x4002_2018;
    assert_ne!(m.mmio_read(eccr, 4) & 1 << 31, 0, "ECCD");
    // ECCD is cleared by writing 1 (what the firmware's NMI handler does).
    m.mmio_write(eccr, 4, 1 << 31);
    assert_eq!(m.mmio_read(eccr, 4) & 1 << 31, 0);
    // A word elsewhere reads without error; erasing the page removes the torn word.
    m.nvic.nmi_pending = false;
    m.flash_read(CALIB + 8, 4);
    assert!(!m.nvic.nmi_pending);
    wait(&mut m, 1e-3);
    m.mmio_write(FLASH_CR, 4, 0);
    erase(&mut m, true, 126);
    assert!(m.flash_ctl.torn.is_empty());
    // Nothing torn without a programming under way.
    assert_eq!(m.power_cut(), None);
}

#[test]
fn the_code_bank_follows_the_bank_swap_which_is_reported() {
    let mut m = machine();
    m.mmio_write(APB2ENR, 4, 1); // SYSCFG
    m.mmio_write(0x4001_0000, 4, 1 << 8); // FB_MODE
    erase(&mut m, true, 126);
    assert_eq!(m.flash_ctl.code_bank_erases, 1, "bank 2 holds the code now");
    assert!(violations_of(&m).iter().any(|v| v.contains("FB_MODE")));
}

// ---- the other counters ----

#[test]
fn cordic_functions_the_model_does_not_compute_are_reported() {
    let mut m = machine();
    m.mmio_write(AHB1ENR, 4, 1 << 3); // CORDICEN
    m.mmio_write(drive_emu::periph::misc::CORDIC_CSR, 4, 0);
    m.mmio_write(drive_emu::periph::misc::CORDIC_WDATA, 4, 0x2000_0000);
    assert!(violations_of(&m).is_empty());
    m.mmio_write(drive_emu::periph::misc::CORDIC_CSR, 4, 3); // arctangent
    m.mmio_write(drive_emu::periph::misc::CORDIC_WDATA, 4, 0x2000_0000);
    assert!(violations_of(&m).iter().any(|v| v.contains("CORDIC")));
}

#[test]
fn iwdg_prescaler_writes_without_the_key_are_ignored_and_reported() {
    let mut m = machine();
    use drive_emu::periph::misc::{IWDG_KR, IWDG_PR};
    m.mmio_write(IWDG_PR, 4, 3);
    assert_eq!(m.mmio_read(IWDG_PR, 4), 0);
    assert!(violations_of(&m).iter().any(|v| v.contains("IWDG")));
    let mut m = machine();
    m.mmio_write(IWDG_KR, 4, 0x5555);
    m.mmio_write(IWDG_PR, 4, 3);
    assert_eq!(m.mmio_read(IWDG_PR, 4), 3);
    assert!(violations_of(&m).is_empty());
}

#[test]
fn unknown_registers_on_either_bus_and_aoe_are_reported() {
    let mut m = machine();
    m.ppb_write(0xE000_E010, 4, 0); // SysTick CSR: known, plain
    assert!(violations_of(&m).is_empty());
    m.ppb_write(0xE000_EF50, 4, 0); // ICIALLU: a Cortex-M7 cache register
    assert!(violations_of(&m)
        .iter()
        .any(|v| v.contains("private peripheral bus") && v.contains("0xe000ef50")));
    let mut m = machine();
    m.mmio_read(0x4000_2C00, 4); // no register there in the models
    assert!(violations_of(&m).iter().any(|v| v.contains("0x40002c00")));
    let mut m = machine();
    m.mmio_write(APB2ENR, 4, 1 << 11);
    m.mmio_write(tim1::BDTR, 4, 1 << 14); // AOE
    assert!(violations_of(&m).iter().any(|v| v.contains("AOE")));
}

#[test]
fn the_pll_locks_after_its_start_up_and_a_switch_waits_for_it() {
    use drive_emu::periph::rcc::{CFGR, CR, PLLCFGR};
    let mut m = machine();
    // HSI16 / 4 · 85 / 2 = 170 MHz.
    m.mmio_write(PLLCFGR, 4, 2 | 3 << 4 | 85 << 8 | 1 << 24);
    m.mmio_write(CR, 4, 1 << 8 | 1 << 24);
    assert_eq!(
        m.mmio_read(CR, 4) & 1 << 25,
        0,
        "PLLRDY only after it locks"
    );
    m.mmio_write(CFGR, 4, 3);
    assert_eq!(
        m.mmio_read(CFGR, 4) >> 2 & 3,
        1,
        "the switch waits, on HSI16"
    );
    wait(&mut m, 50e-6);
    assert_ne!(m.mmio_read(CR, 4) & 1 << 25, 0);
    assert_eq!(m.mmio_read(CFGR, 4) >> 2 & 3, 3);
    assert_eq!(m.rcc.sysclk_hz, 170_000_000);
    // HSE: the NUCLEO-G474RE's 24 MHz crystal, 2 ms to start.
    m.mmio_write(CR, 4, 1 << 8 | 1 << 24 | 1 << 16);
    wait(&mut m, 1e-3);
    assert_eq!(m.mmio_read(CR, 4) & 1 << 17, 0);
    wait(&mut m, 1.5e-3);
    assert_ne!(m.mmio_read(CR, 4) & 1 << 17, 0);
    m.mmio_write(CFGR, 4, 2);
    assert_eq!(m.rcc.sysclk_hz, 24_000_000);
}

// ---- the three-shunt board: conversion windows, shunt visibility, the ADC rules ----

use board_map::{channel, current_sense, Signal};
use drive_emu::periph::tim1::DBGMCU_APB2FZR;

fn adc_base(i: u32) -> u32 {
    0x5000_0000 + 0x100 * i
}

/// Both ADCs as the firmware sets them up: HCLK/4, dual injected simultaneous (`dual`),
/// regulators settled, calibrated, enabled and ready; sampling 6.5 cycles for the
/// currents and the bus, 24.5 for the sensor (board_map's slots).
fn adcs_enabled(m: &mut Machine, dual: u32) {
    m.mmio_write(AHB2ENR, 4, 1 << 13 | 1);
    m.mmio_write(ADC_CCR, 4, 3 << 16 | dual);
    for i in 0..2 {
        let cr = adc_base(i) + 8;
        m.mmio_write(cr, 4, 0);
        m.mmio_write(cr, 4, 1 << 28);
    }
    wait(m, 25e-6);
    for i in 0..2 {
        m.mmio_write(adc_base(i) + 8, 4, 1 << 28 | 1 << 31);
    }
    wait(m, 5e-6);
    for i in 0..2 {
        m.mmio_write(adc_base(i) + 8, 4, 1 << 28 | 1);
    }
    wait(m, 2e-6);
    let smp = |m: &mut Machine, i: u32, ch: u8, code: u32| {
        let (reg, sh) = if ch < 10 {
            (adc_base(i) + 0x14, 3 * ch as u32)
        } else {
            (adc_base(i) + 0x18, 3 * (ch as u32 - 10))
        };
        let v = m.mmio_read(reg, 4);
        m.mmio_write(reg, 4, v | code << sh);
    };
    for (s, i, code) in [
        (Signal::CurrentU, 0, 1),
        (Signal::CurrentW, 0, 1),
        (Signal::SensorX, 0, 3),
        (Signal::CurrentV, 1, 1),
        (Signal::BusVoltage, 1, 1),
        (Signal::SensorY, 1, 3),
    ] {
        smp(m, i, channel(s), code);
    }
}

/// The JSQR of board_map's three slots on ADC `i`, JEXTEN as given (TRGO2).
fn jsqr(i: usize, jexten: u32) -> u32 {
    let ch: Vec<u32> = board_map::INJECTED_SEQUENCE
        .iter()
        .map(|p| channel(if i == 0 { p.0 } else { p.1 }) as u32)
        .collect();
    2 | 8 << 2 | jexten << 7 | ch[0] << 9 | ch[1] << 15 | ch[2] << 21
}

/// A dummy injected conversion by software (ES0430), its result not read, then the
/// sequence armed on TRGO2 with `jexten`.
fn arm_injected(m: &mut Machine, dummy: bool, jexten: u32) {
    for i in 0..2 {
        m.mmio_write(adc_base(i as u32) + 0x4C, 4, jsqr(i, 0) & !(0x1F << 2));
    }
    if dummy {
        m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 | 1 << 3);
        wait(m, 5e-6);
        assert_eq!(
            m.mmio_read(ADC1_CR, 4) & 1 << 3,
            0,
            "JADSTART cleared at the end"
        );
        m.mmio_write(ADC1_ISR, 4, 0x7FF);
        m.mmio_write(adc_base(1), 4, 0x7FF);
    }
    for i in 0..2 {
        m.mmio_write(adc_base(i as u32) + 0x4C, 4, jsqr(i, jexten));
    }
    m.mmio_write(ADC1_IER, 4, ISR_JEOS);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 | 1 << 3);
}

const ARR: u32 = 4250;

/// TIM1 as the three-shunt firmware runs it: PWM mode 1 on CH1-3 with their
/// complementary outputs (dead time 85 ticks), CCR1-3 preloaded, updated at the peak
/// (RCR = 1), TRGO2 = OC4REF in PWM mode 1 with CCR4 = ARR - k: `k` ticks after the peak.
fn three_shunt_pwm(m: &mut Machine, ccr: [u32; 3], k: u32) {
    bkin_pin(m, true);
    pwm(m, 1, true);
    m.mmio_write(tim1::CCMR2, 4, 0x6868);
    m.mmio_write(tim1::CCR1 + 12, 4, ARR - k);
    // The L6398's active-low low-side inputs: CHxN inverted and idling high.
    m.mmio_write(tim1::CR2, 4, 0b0111 << 20 | 1 << 9 | 1 << 11 | 1 << 13);
    m.mmio_write(tim1::CCER, 4, 0xDDD);
    for (j, c) in ccr.iter().enumerate() {
        m.mmio_write(tim1::CCR1 + 4 * j as u32, 4, *c);
    }
    assert!(Tim1::moe(&m.regs));
}

/// The shunt reading of phase `p` (0 = U) in the last sequence, and what the phase
/// current would read at its hold instant.
fn shunt(m: &mut Machine, p: usize) -> (i64, i64) {
    let (adc, slot) = [(0, 0), (1, 0), (0, 1)][p];
    let v = m.mmio_read(adc_base(adc) + 0x80 + 4 * slot, 4) as i64;
    // Latency 2.625 + 6.5 sampling cycles (+ 19 for the second slot) at 4 ticks each.
    let hold = m.stats.last_trigger + 36 + 76 * slot as u64;
    let i = m.board.phase_currents_at(hold)[p];
    let zero = current_sense::ZERO_COUNTS as i64;
    (
        v,
        zero + (i / current_sense::AMPS_PER_COUNT as f64).round() as i64,
    )
}

fn three_shunt_bench(ccr: [u32; 3]) -> Machine {
    let mut m = machine();
    adcs_enabled(&mut m, 0b00101);
    arm_injected(&mut m, true, 1);
    // Phase U 2.1 V above the others (24 V bus), a current of about 2 A through the
    // motor and the board's 820 ns of dead time.
    three_shunt_pwm(&mut m, [2500, 2125, 2125], 20);
    for _ in 0..40 {
        wait(&mut m, PERIOD_S);
    }
    for (j, c) in ccr.iter().enumerate() {
        m.mmio_write(tim1::CCR1 + 4 * j as u32, 4, *c);
    }
    for _ in 0..3 {
        wait(&mut m, PERIOD_S);
    }
    m
}

#[test]
fn a_shunt_reads_its_phase_current_only_while_its_low_side_conducts() {
    let mut m = three_shunt_bench([2500, 2125, 2125]);
    for p in 0..3 {
        let (v, expected) = shunt(&mut m, p);
        assert!((v - expected).abs() <= 3, "phase {p}: {v} vs {expected}");
    }
    let (_, u) = shunt(&mut m, 0);
    assert!(
        (u - current_sense::ZERO_COUNTS as i64).abs() > 60,
        "a current to see: {u}"
    );
    // U's high side on almost the whole period: its low side never conducts around the
    // peak (CCR1 = ARR - 10 is within the dead time), the amplifier shows no current.
    let mut m = three_shunt_bench([ARR - 10, 2125, 2125]);
    let (v, expected) = shunt(&mut m, 0);
    let zero = current_sense::ZERO_COUNTS as i64;
    assert!((v - zero).abs() <= 45, "U at zero and ringing: {v}");
    assert!(
        (expected - zero).abs() > 60,
        "though a current flows: {expected}"
    );
    // V's low side turned on just before the window (CCR2 = ARR - 100: on 15 ticks
    // before the peak, less than SETTLE_NS before sampling): not settled, no current.
    let mut m = three_shunt_bench([2200, ARR - 100, 2125]);
    let (v, expected) = shunt(&mut m, 1);
    assert!(
        (v - zero).abs() <= 45,
        "V not settled: {v} (current {expected})"
    );
    assert!(violations_of(&m).is_empty(), "{:#?}", violations_of(&m));
}

#[test]
fn a_conversion_late_after_calibration_reads_wrong_unless_a_dummy_conversion_went_first() {
    for dummy in [false, true] {
        let mut m = machine();
        adcs_enabled(&mut m, 0b00101);
        wait(&mut m, 2e-3);
        arm_injected(&mut m, dummy, 1);
        three_shunt_pwm(&mut m, [2125; 3], 20);
        // The first sequence's end (JEOS), read before the next trigger.
        while m.mmio_read(ADC1_ISR, 4) & ISR_JEOS == 0 {
            wait(&mut m, 1e-6);
        }
        assert_eq!(m.adcs.triggers, 1);
        shunt(&mut m, 0);
        let a = m.adcs.violations;
        assert!(a.late_conversions >= 2, "{a:?}");
        assert_eq!(a.late_results_read, u32::from(!dummy), "dummy {dummy}");
        let flagged = violations_of(&m).iter().any(|v| v.contains("ES0430"));
        assert_eq!(flagged, !dummy);
    }
}

#[test]
fn only_a_rising_trigger_edge_is_the_firmwares() {
    for (jexten, bad) in [(1, false), (2, true), (3, true)] {
        let mut m = machine();
        adcs_enabled(&mut m, 0b00101);
        arm_injected(&mut m, true, jexten);
        three_shunt_pwm(&mut m, [2125; 3], 20);
        wait(&mut m, 3.0 * PERIOD_S);
        assert_eq!(
            m.adcs.violations.jexten_not_rising > 0,
            bad,
            "JEXTEN {jexten}"
        );
        assert_eq!(m.adcs.triggers > 0, jexten != 2, "JEXTEN {jexten}");
    }
}

#[test]
fn jadstart_is_gated_on_aden_not_adrdy() {
    let mut m = machine();
    calibrated_adc(&mut m);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 << 3); // no ADEN: refused
    assert_eq!(m.mmio_read(ADC1_CR, 4) & 1 << 3, 0);
    wait(&mut m, 1e-6);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1);
    m.mmio_write(ADC1_JSQR, 4, 8 << 2 | 1 << 7);
    // ADEN set, ADRDY not yet: accepted.
    assert_eq!(m.mmio_read(ADC1_ISR, 4) & 1, 0);
    m.mmio_write(ADC1_CR, 4, 1 << 28 | 1 | 1 << 3);
    assert_ne!(m.mmio_read(ADC1_CR, 4) & 1 << 3, 0);
}

#[test]
fn ckmode_and_dual_are_refused_with_an_adc_enabled() {
    let mut m = machine();
    adcs_enabled(&mut m, 0b00101);
    m.mmio_write(ADC_CCR, 4, 1 << 16);
    assert_eq!(m.mmio_read(ADC_CCR, 4), 3 << 16 | 0b00101);
    assert_eq!(m.adcs.violations.common_write_refused, 1);
    assert!(violations_of(&m).iter().any(|v| v.contains("CKMODE")));
    // Before ADEN it is the way to set them.
    let mut m = machine();
    m.mmio_write(AHB2ENR, 4, 1 << 13);
    m.mmio_write(ADC_CCR, 4, 3 << 16 | 0b00101);
    m.mmio_write(ADC_CCR, 4, 1 << 16);
    assert_eq!(m.adcs.violations.common_write_refused, 0);
}

#[test]
fn dual_simultaneous_sequences_must_match_in_length_and_sampling_times() {
    for case in 0..3 {
        let mut m = machine();
        adcs_enabled(&mut m, 0b00101);
        arm_injected(&mut m, true, 1);
        match case {
            1 => m.mmio_write(adc_base(1) + 0x4C, 4, jsqr(1, 1) & !3 | 1), // JL = 1
            2 => {
                // The sensor pair's Y at 6.5 cycles, X at 24.5.
                let (reg, sh) = (adc_base(1) + 0x14, 3 * channel(Signal::SensorY) as u32);
                let v = m.mmio_read(reg, 4) & !(7 << sh);
                m.mmio_write(reg, 4, v | 1 << sh);
            }
            _ => {}
        }
        three_shunt_pwm(&mut m, [2125; 3], 20);
        wait(&mut m, 2.0 * PERIOD_S);
        assert_eq!(
            m.adcs.violations.dual_mismatch > 0,
            case != 0,
            "case {case}"
        );
    }
}

// ---- BKIN: the pin, the boot break, glitches ----

#[test]
fn a_floating_bkin_line_breaks_and_is_reported() {
    for pull_up in [true, false] {
        let mut m = machine();
        bkin_pin(&mut m, pull_up);
        m.mmio_write(APB2ENR, 4, 1 << 11);
        m.mmio_write(tim1::AF1, 4, 1); // BKINE
        m.mmio_write(tim1::BDTR, 4, 1 << 12);
        m.mmio_write(tim1::SR, 4, 0);
        m.mmio_write(tim1::BDTR, 4, 1 << 12 | 1 << 15);
        assert_eq!(Tim1::moe(&m.regs), pull_up, "pull-up {pull_up}");
        assert_eq!(m.tim1.bkin_floating > 0, !pull_up);
        assert_eq!(
            violations_of(&m)
                .iter()
                .any(|v| v.contains("BKIN floating")),
            !pull_up
        );
    }
}

#[test]
fn the_break_latches_at_boot_before_the_pin_is_routed_and_the_firmware_clears_it() {
    let mut m = machine();
    m.mmio_write(APB2ENR, 4, 1 << 11);
    m.mmio_write(tim1::AF1, 4, 1); // BKINE
                                   // BKE before PA6 is on AF6: the timer's BKIN input is not the pin yet, read low.
    m.mmio_write(tim1::BDTR, 4, 1 << 12);
    assert_ne!(
        m.mmio_read(tim1::SR, 4) & tim1::SR_BIF,
        0,
        "latched at boot"
    );
    assert_eq!(m.tim1.bif_sets, 1);
    bkin_pin(&mut m, true);
    // clear_boot_break: BIF written 0 (rc_w0).
    m.mmio_write(tim1::SR, 4, !tim1::SR_BIF);
    assert_eq!(m.mmio_read(tim1::SR, 4) & tim1::SR_BIF, 0);
    assert_eq!(m.tim1.bif_clears, 1);
    m.mmio_write(tim1::BDTR, 4, 1 << 12 | 1 << 15);
    assert!(Tim1::moe(&m.regs));
    assert!(violations_of(&m).is_empty(), "{:#?}", violations_of(&m));
}

#[test]
fn comparator_glitches_near_the_level_break_only_through_a_short_filter() {
    for (bkf, breaks) in [(0, true), (3, true), (15, false)] {
        let mut m = overcurrent_bench(bkf);
        let i = m.board.plant.currents_ab();
        let peak = m.board.phase_currents_at(m.now).map(f64::abs);
        let peak = peak.iter().cloned().fold(0.0, f64::max).max(i[0].abs());
        m.board.plant.break_level_a = peak * 1.05;
        for _ in 0..4 {
            wait(&mut m, PERIOD_S);
        }
        assert!(m.stats.comparator_glitches > 0, "BKF {bkf}");
        assert!(
            !m.board.plant.comparator_over(),
            "BKF {bkf}: under its level"
        );
        assert_eq!(m.stats.glitch_breaks > 0, breaks, "BKF {bkf}");
        assert_eq!(Tim1::moe(&m.regs), !breaks, "BKF {bkf}");
    }
}

// ---- the debug halt ----

#[test]
fn a_debug_halt_freezes_tim1_with_the_bridge_off_only_with_dbg_tim1_stop() {
    for stop in [true, false] {
        for halt_s in [1e-3, 100e-3] {
            let mut m = three_shunt_bench([2300, 2125, 2125]);
            if stop {
                m.mmio_write(DBGMCU_APB2FZR, 4, tim1::DBG_TIM1_STOP);
            }
            let peaks = m.tim1.peaks;
            m.halt_core(ticks(halt_s));
            let mut steps = 0;
            while m.halted() {
                assert_eq!(m.bridge_on(), !stop, "stop {stop}, {halt_s} s");
                wait(&mut m, 100e-6);
                steps += 1;
            }
            assert!(steps >= 10);
            let ran = m.tim1.peaks - peaks;
            if stop {
                assert!(ran <= 1, "the counter stopped: {ran} peaks");
                // Coasting with the bridge open: no current.
                assert_eq!(m.board.plant.currents_ab(), [0.0; 2]);
            } else {
                assert!(ran as f64 >= 0.9 * halt_s / PERIOD_S, "{ran} peaks");
            }
            // Resumed: the timer runs on with MOE as it was.
            let p = m.tim1.peaks;
            wait(&mut m, 3.0 * PERIOD_S);
            assert!(m.tim1.peaks >= p + 2 && m.bridge_on());
        }
    }
}

/// The IHM08M1's L6398 takes its low-side input active low (board_map::gate_driver): a
/// complementary output enabled active high, or idling low (MOE = 0 would hold the low
/// side on), is reported; inverted and idling high, as the firmware sets it, is not.
#[test]
fn a_low_side_output_the_gate_driver_does_not_take_is_reported() {
    let mut m = machine();
    m.mmio_write(APB2ENR, 4, 1 << 11);
    // CC1E and CC1NE, CC1NP = 0, OIS1N = 0: with the outputs disabled (MOE = OSSI = 0)
    // the timer drives nothing yet; with OSSI = 1 it drives the idle levels.
    m.mmio_write(tim1::CCER, 4, 0b0101);
    assert_eq!(m.tim1.gate_polarity_wrong, 0);
    m.mmio_write(tim1::BDTR, 4, tim1::BDTR_OSSI);
    assert_eq!(m.tim1.gate_polarity_wrong, 1);
    assert!(violations_of(&m).iter().any(|v| v.contains("gate driver")));
    // Inverted, but idling low: still wrong, the same stretch.
    m.mmio_write(tim1::CCER, 4, 0b1101);
    assert_eq!(m.tim1.gate_polarity_wrong, 1);

    let mut m = machine();
    m.mmio_write(APB2ENR, 4, 1 << 11);
    m.mmio_write(tim1::BDTR, 4, tim1::BDTR_OSSI);
    m.mmio_write(tim1::CR2, 4, 1 << 9 | 1 << 11 | 1 << 13);
    m.mmio_write(tim1::CCER, 4, 0b1101 | 0b1101 << 4 | 0b1101 << 8);
    assert_eq!(m.tim1.gate_polarity_wrong, 0);
    assert!(violations_of(&m).is_empty(), "{:?}", violations_of(&m));
}

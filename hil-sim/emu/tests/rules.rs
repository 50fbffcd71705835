//! Each rule-based peripheral model against a register sequence that keeps the rule and
//! one that breaks it, as a firmware would write them (no CPU: the bus accesses only).
//! The scenarios (tests/scenarios.rs) then require the release firmware to break none.

use drive_emu::board::Board;
use drive_emu::machine::Machine;
use drive_emu::periph::flash::{CR as FLASH_CR, KEYR, SR as FLASH_SR};
use drive_emu::periph::rcc::{AHB2ENR, APB2ENR};
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

fn break_clears_moe(bkine: bool) -> bool {
    let mut m = machine();
    // PA6 on AF6 (TIM1_BKIN).
    m.mmio_write(AHB2ENR, 4, 1);
    m.mmio_write(0x4800_0000, 4, 0b10 << 12);
    m.mmio_write(0x4800_0020, 4, 6 << 24);
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

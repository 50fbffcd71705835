//! The debug core as a probe drives it: only through `DebugPort` (bus reads and writes,
//! the reset pin, time).

use drive_emu::board::Board;
use drive_emu::debug::*;
use drive_emu::periph::ticks;
use drive_emu::Emu;

fn elf() -> Vec<u8> {
    let path = std::env::var_os("DRIVE_EMU_ELF")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(hil_sim::stream::release_elf);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn emu() -> Emu {
    Emu::new(&elf(), Board::commissioning(1).unwrap(), None).unwrap()
}

fn rd(e: &mut Emu, a: u32) -> u32 {
    let mut b = [0u8; 4];
    e.read(a, 4, &mut b).unwrap();
    u32::from_le_bytes(b)
}

fn wr(e: &mut Emu, a: u32, v: u32) {
    e.write(a, 4, &v.to_le_bytes()).unwrap();
}

fn halt(e: &mut Emu) {
    wr(e, DHCSR, DBGKEY << 16 | C_DEBUGEN | C_HALT);
    e.advance(100).unwrap();
    assert!(rd(e, DHCSR) & S_HALT != 0);
}

fn reg(e: &mut Emu, sel: u32) -> u32 {
    wr(e, DCRSR, sel);
    rd(e, DCRDR)
}

fn set_reg(e: &mut Emu, sel: u32, v: u32) {
    wr(e, DCRDR, v);
    wr(e, DCRSR, 1 << 16 | sel);
}

/// Thumb halfwords into RAM at `at`.
fn code(e: &mut Emu, at: u32, hw: &[u16]) {
    let b: Vec<u8> = hw.iter().flat_map(|h| h.to_le_bytes()).collect();
    e.write(at, 2, &b).unwrap();
}

const RAM_CODE: u32 = 0x2001_0000;

#[test]
fn a_halt_stops_the_core_and_freezes_tim1_then_it_resumes() {
    let mut e = emu();
    e.advance(ticks(0.2)).unwrap();
    wr(
        &mut e,
        drive_emu::periph::tim1::DBGMCU_APB2FZR,
        drive_emu::periph::tim1::DBG_TIM1_STOP,
    );
    assert_eq!(rd(&mut e, DBGMCU_IDCODE) & 0xFFF, 0x469);
    halt(&mut e);
    assert!(rd(&mut e, DFSR) & DFSR_HALTED != 0);
    let pc = reg(&mut e, 15);
    let dt = e.advance(ticks(0.01)).unwrap();
    assert!(dt >= ticks(0.01));
    assert_eq!(reg(&mut e, 15), pc);
    assert!(!e.m().bridge_on());
    assert!(e.m().tim1.frozen());
    wr(&mut e, DHCSR, DBGKEY << 16 | C_DEBUGEN);
    e.advance(ticks(0.01)).unwrap();
    assert_eq!(rd(&mut e, DHCSR) & S_HALT, 0);
    assert!(!e.m().tim1.frozen());
}

#[test]
fn core_registers_round_trip_and_a_step_executes_one_instruction() {
    let mut e = emu();
    e.advance(ticks(0.05)).unwrap();
    halt(&mut e);
    for (sel, v) in [
        (3, 0x1234_5678),
        (69, 0x4049_0FDB),
        (33, 0x0340_0000),
        (12, 7),
    ] {
        set_reg(&mut e, sel, v);
        assert_eq!(reg(&mut e, sel), v, "REGSEL {sel}");
    }
    // movs r0, #1; mov.w r1, #5; adds r0, #1
    code(&mut e, RAM_CODE, &[0x2001, 0xF04F, 0x0105, 0x3001]);
    set_reg(&mut e, 15, RAM_CODE);
    set_reg(&mut e, 0, 0);
    let step = DBGKEY << 16 | C_DEBUGEN | C_STEP | C_MASKINTS;
    wr(&mut e, DHCSR, step);
    e.advance(1000).unwrap();
    assert!(rd(&mut e, DHCSR) & S_HALT != 0);
    assert_eq!(reg(&mut e, 15), RAM_CODE + 2);
    assert_eq!(reg(&mut e, 0), 1);
    wr(&mut e, DHCSR, step);
    e.advance(1000).unwrap();
    assert_eq!(reg(&mut e, 15), RAM_CODE + 6);
    assert_eq!(reg(&mut e, 1), 5);
    assert_eq!(reg(&mut e, 0), 1);
}

#[test]
fn bkpt_halts_at_the_breakpoint_with_dfsr_bkpt() {
    let mut e = emu();
    e.advance(ticks(0.05)).unwrap();
    halt(&mut e);
    wr(&mut e, DFSR, 0x1F);
    // movs r0, #7; bkpt #0
    code(&mut e, RAM_CODE, &[0x2007, 0xBE00]);
    set_reg(&mut e, 15, RAM_CODE);
    // Interrupts masked: the routine runs without the firmware's.
    set_reg(&mut e, 20, 1);
    wr(&mut e, DHCSR, DBGKEY << 16 | C_DEBUGEN);
    e.advance(ticks(0.001)).unwrap();
    assert!(rd(&mut e, DHCSR) & S_HALT != 0);
    assert!(rd(&mut e, DFSR) & DFSR_BKPT != 0);
    assert_eq!(reg(&mut e, 15), RAM_CODE + 2);
    assert_eq!(reg(&mut e, 0), 7);
}

#[test]
fn a_reset_with_vc_corereset_halts_at_the_reset_vector() {
    let mut e = emu();
    e.advance(ticks(0.02)).unwrap();
    wr(&mut e, DHCSR, DBGKEY << 16 | C_DEBUGEN);
    wr(&mut e, DEMCR, VC_CORERESET);
    let _ = rd(&mut e, DHCSR);
    wr(&mut e, 0xE000_ED0C, 0x05FA_0004);
    e.advance(1000).unwrap();
    let dhcsr = rd(&mut e, DHCSR);
    assert!(dhcsr & S_HALT != 0 && dhcsr & S_RESET_ST != 0, "{dhcsr:#x}");
    assert_eq!(rd(&mut e, DHCSR) & S_RESET_ST, 0, "sticky until read");
    assert!(rd(&mut e, DFSR) & DFSR_VCATCH != 0);
    let reset_vector = rd(&mut e, 0x0800_0004) & !1;
    assert_eq!(reg(&mut e, 15), reset_vector);
    // The pin too, with its flag in RCC_CSR.
    e.pin_reset();
    e.advance(100).unwrap();
    assert!(rd(&mut e, DHCSR) & S_HALT != 0);
    assert!(rd(&mut e, 0x4002_1094) & 1 << 26 != 0);
}

const KEYR: u32 = 0x4002_2008;
const SR: u32 = 0x4002_2010;
const CR: u32 = 0x4002_2014;
/// The last page of bank 1 (the firmware is far smaller).
const PAGE: u32 = 127;
const PAGE_ADDR: u32 = 0x0800_0000 + PAGE * 2048;

fn unlock_erase(e: &mut Emu) {
    wr(e, KEYR, 0x4567_0123);
    wr(e, KEYR, 0xCDEF_89AB);
    assert_eq!(rd(e, CR) >> 31, 0, "unlocked");
    wr(e, CR, 1 << 1 | PAGE << 3);
    wr(e, CR, 1 << 1 | PAGE << 3 | 1 << 16);
    e.advance(ticks(0.03)).unwrap();
    assert_eq!(rd(e, SR) & (1 << 16 | 0xC3FA), 0);
    assert_eq!(rd(e, PAGE_ADDR), 0xFFFF_FFFF);
    wr(e, CR, 1);
}

#[test]
fn bank_1_erases_and_programs_through_the_port() {
    let mut e = emu();
    e.advance(ticks(0.02)).unwrap();
    halt(&mut e);
    wr(&mut e, PAGE_ADDR, 0xDEAD_BEEF);
    assert_ne!(rd(&mut e, PAGE_ADDR), 0xDEAD_BEEF, "locked: PGSERR");
    wr(&mut e, SR, 0xC3FB);
    unlock_erase(&mut e);
    wr(&mut e, PAGE_ADDR + 8, 0xDEAD_BEEF);
    wr(&mut e, PAGE_ADDR + 12, 0x0123_4567);
    e.advance(ticks(0.001)).unwrap();
    assert_eq!(rd(&mut e, SR) & 0xC3FA, 0);
    assert_eq!(rd(&mut e, PAGE_ADDR + 8), 0xDEAD_BEEF);
    assert_eq!(rd(&mut e, PAGE_ADDR + 12), 0x0123_4567);
    // Unicorn's copy (what the CPU fetches) follows.
    let mut b = [0u8; 8];
    e.uc.mem_read((PAGE_ADDR + 8) as u64, &mut b).unwrap();
    assert_eq!(b, [0xEF, 0xBE, 0xAD, 0xDE, 0x67, 0x45, 0x23, 0x01]);
}

/// A routine in RAM programs a double word of bank 1 with `str` (as a flash algorithm
/// does) and ends in BKPT; the CPU then runs the code it wrote, twice with different
/// code at the same address (the translation cache follows).
#[test]
fn code_in_ram_programs_bank_1_and_the_cpu_executes_the_new_code() {
    let mut e = emu();
    e.advance(ticks(0.02)).unwrap();
    halt(&mut e);
    for k in [1u32, 2] {
        unlock_erase(&mut e);
        // str r1, [r0]; str r2, [r0, #4]; bkpt #0
        code(&mut e, RAM_CODE, &[0x6001, 0x6042, 0xBE00]);
        set_reg(&mut e, 0, PAGE_ADDR);
        // movs r0, #k; bkpt #0; nop; nop
        set_reg(&mut e, 1, 0xBE00 << 16 | 0x2000 | k);
        set_reg(&mut e, 2, 0xBF00_BF00);
        set_reg(&mut e, 15, RAM_CODE);
        set_reg(&mut e, 20, 1);
        wr(&mut e, DHCSR, DBGKEY << 16 | C_DEBUGEN);
        e.advance(ticks(0.001)).unwrap();
        assert!(rd(&mut e, DFSR) & DFSR_BKPT != 0);
        assert_eq!(reg(&mut e, 15), RAM_CODE + 4);
        assert_eq!(rd(&mut e, SR) & 0xC3FA, 0, "k {k}");
        assert_eq!(rd(&mut e, PAGE_ADDR), 0xBE00 << 16 | 0x2000 | k);
        wr(&mut e, DFSR, 0x1F);
        set_reg(&mut e, 15, PAGE_ADDR);
        wr(&mut e, DHCSR, DBGKEY << 16 | C_DEBUGEN);
        e.advance(ticks(0.001)).unwrap();
        assert!(rd(&mut e, DFSR) & DFSR_BKPT != 0);
        assert_eq!(reg(&mut e, 15), PAGE_ADDR + 2);
        assert_eq!(reg(&mut e, 0), k, "the new code ran");
        wr(&mut e, DFSR, 0x1F);
    }
}

#[test]
fn an_unmapped_address_faults() {
    let mut e = emu();
    let mut b = [0u8; 4];
    assert_eq!(
        e.read(0x3000_0000, 4, &mut b),
        Err(ApFault { addr: 0x3000_0000 })
    );
    assert_eq!(rd(&mut e, 0x1FFF_75E0) & 0xFFFF, 512);
    assert_eq!(rd(&mut e, 0x4002_2020) >> 22 & 1, 1, "OPTR.DBANK");
}

/// IWDG (RM0440 §42) keeps counting while the core is halted unless
/// DBGMCU_APB1FZR1.DBG_IWDG_STOP is set: the release firmware sets it; with the bit
/// cleared behind its back, a halt of 150 ms resets it through its watchdog.
#[test]
fn a_long_halt_resets_by_watchdog_only_without_dbg_iwdg_stop() {
    for stop in [false, true] {
        let mut e = emu();
        e.advance(ticks(0.3)).unwrap();
        assert_ne!(
            rd(&mut e, DBGMCU_APB1FZR1) & DBG_IWDG_STOP,
            0,
            "set by the firmware"
        );
        if !stop {
            wr(&mut e, DBGMCU_APB1FZR1, 0);
        }
        let before = e.m().iwdg.expiries;
        halt(&mut e);
        e.advance(ticks(0.15)).unwrap();
        assert_eq!(e.m().iwdg.expiries > before, !stop, "DBG_IWDG_STOP {stop}");
    }
}

#[test]
fn the_wrong_flash_models_misbehave() {
    use drive_emu::periph::flash::FlashMutation;
    let mut e = emu();
    halt(&mut e);
    e.m_mut().flash_ctl.mutation = Some(FlashMutation::KeysAnyOrder);
    wr(&mut e, KEYR, 0x4567_0123);
    wr(&mut e, KEYR, 0xCDEF_89AB);
    assert_eq!(rd(&mut e, CR) >> 31, 1, "the right order no longer unlocks");
}

#[test]
fn observe_mode_rtt_sees_what_consume_mode_reads() {
    let run = |mode| {
        let mut e = emu();
        e.m_mut().rtt.mode = mode;
        let cb = e.m().rtt.block.unwrap();
        for _ in 0..300 {
            e.advance(ticks(0.001)).unwrap();
            if mode == drive_emu::rtt::RttMode::Observe && rd(&mut e, cb) == 0x4747_4553 {
                // The probe's RTT client consumes: RdOff := WrOff.
                let wr_off = rd(&mut e, cb + 24 + 12);
                wr(&mut e, cb + 24 + 16, wr_off);
            }
        }
        e.m().rtt.bytes.clone()
    };
    let consumed = run(drive_emu::rtt::RttMode::Consume);
    let observed = run(drive_emu::rtt::RttMode::Observe);
    assert!(!consumed.is_empty());
    assert_eq!(observed, consumed);
}

#[test]
fn a_blank_chip_locks_up_without_panicking_and_resets_sanely() {
    let mut e = Emu::blank(Board::commissioning(1).unwrap()).unwrap();
    e.advance(ticks(0.001)).unwrap();
    assert_eq!(rd(&mut e, 0x0800_0000), 0xFFFF_FFFF);
    e.pin_reset();
    e.advance(ticks(0.001)).unwrap();
    halt(&mut e);
    e.set_firmware(&elf()).unwrap();
}

/// DEMCR.VC_HARDERR (C1.6.5): a HardFault halts the core on its handler's first
/// instruction with DFSR.VCATCH, the frame already stacked; without the catch the
/// handler runs.
#[test]
fn the_hardfault_vector_catch_halts_on_the_handler() {
    for catch in [true, false] {
        let mut e = emu();
        e.advance(ticks(0.05)).unwrap();
        halt(&mut e);
        wr(&mut e, DFSR, 0x1F);
        wr(&mut e, DEMCR, if catch { VC_HARDERR } else { 0 });
        // A load from nowhere (LDR r0, [r1], r1 in a reserved region) in RAM, run
        // from there: a precise bus fault, escalated to HardFault.
        code(&mut e, RAM_CODE, &[0x6808]);
        set_reg(&mut e, 1, 0x3000_0000);
        set_reg(&mut e, 15, RAM_CODE);
        wr(&mut e, DHCSR, DBGKEY << 16 | C_DEBUGEN);
        e.advance(ticks(1e-6)).unwrap();
        let handler = rd(&mut e, 0x0800_000C) & !1;
        let halted = rd(&mut e, DHCSR) & S_HALT != 0;
        assert_eq!(halted, catch, "VC_HARDERR {catch}");
        assert_eq!(e.m().stats.hard_faults.len(), 1);
        if catch {
            assert_ne!(rd(&mut e, DFSR) & DFSR_VCATCH, 0);
            assert_eq!(reg(&mut e, 15), handler);
            // The stacked PC is the faulting instruction's.
            let sp = reg(&mut e, 13);
            assert_eq!(rd(&mut e, sp + 24), RAM_CODE);
        }
    }
}

//! Why the previous run ended, in RAM that the reset does not clear (`.uninit`): a
//! HardFault (with its program counter) or a panic. The next boot reports it over RTT
//! and starts in the safe state.

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

const MAGIC: u32 = 0xFA17_C0DE;
const HARD_FAULT: u32 = 1;
const PANIC: u32 = 2;

#[link_section = ".uninit.fault_record"]
static mut RECORD: MaybeUninit<[u32; 3]> = MaybeUninit::uninit();

/// How the previous run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    HardFault { pc: u32 },
    Panic,
}

fn store(kind: u32, pc: u32) {
    // SAFETY: single writer (the HardFault or panic handler, which does not return).
    unsafe { addr_of_mut!(RECORD).write(MaybeUninit::new([MAGIC, kind, pc])) };
}

/// Called from the HardFault handler only.
pub fn store_hard_fault(pc: u32) {
    store(HARD_FAULT, pc);
}

/// Called from the panic handler only.
pub fn store_panic() {
    store(PANIC, 0);
}

/// How the previous run ended, if it ended in a fault; clears the record.
pub fn take() -> Option<Ended> {
    // SAFETY: read during init before interrupts are enabled; any bit pattern is a
    // valid [u32; 3] (uninitialised RAM after power-on just fails the magic check).
    let [magic, kind, pc] = unsafe { addr_of!(RECORD).read().assume_init() };
    unsafe { addr_of_mut!(RECORD).write(MaybeUninit::new([0, 0, 0])) };
    match (magic, kind) {
        (MAGIC, HARD_FAULT) => Some(Ended::HardFault { pc }),
        (MAGIC, PANIC) => Some(Ended::Panic),
        _ => None,
    }
}

//! A HardFault leaves its program counter in RAM that the reset does not clear
//! (`.uninit`), so that the next boot reports it over RTT and starts in the safe state.

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

const MAGIC: u32 = 0xFA17_C0DE;

#[link_section = ".uninit.fault_record"]
static mut RECORD: MaybeUninit<[u32; 2]> = MaybeUninit::uninit();

/// Called from the HardFault handler only.
pub fn store(pc: u32) {
    // SAFETY: single writer (the HardFault handler, which does not return).
    unsafe { addr_of_mut!(RECORD).write(MaybeUninit::new([MAGIC, pc])) };
}

/// The faulting PC of the previous run, if it ended in a HardFault; clears the record.
pub fn take() -> Option<u32> {
    // SAFETY: read during init before interrupts are enabled; any bit pattern is a
    // valid [u32; 2] (uninitialised RAM after power-on just fails the magic check).
    let [magic, pc] = unsafe { addr_of!(RECORD).read().assume_init() };
    unsafe { addr_of_mut!(RECORD).write(MaybeUninit::new([0, 0])) };
    (magic == MAGIC).then_some(pc)
}

//! What a debug probe reaches on the emulated board: the debug access port's view of
//! the bus (ARM ADIv5 MEM-AP: RAM, flash, peripherals, the private peripheral bus with
//! the core's debug registers) and the reset pin. Time passes only through
//! [`DebugPort::advance`]; the probe's side (`vprobe`) decides how much.

/// An access the bus did not answer (the MEM-AP reports a fault: CSW/DRW error).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ApFault {
    pub addr: u32,
}

impl std::fmt::Display for ApFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "no answer from the bus at {:#010x}", self.addr)
    }
}

impl std::error::Error for ApFault {}

pub trait DebugPort {
    /// `out.len()` bytes from `addr` as consecutive accesses of `width` bytes each
    /// (1, 2 or 4; `addr` aligned to `width`, `out.len()` a multiple of it), as the
    /// MEM-AP's auto-incrementing transfers do. Reads have the side effects a bus read
    /// has (a status register's read-to-clear, the flash's ECC check).
    fn read(&mut self, addr: u32, width: u8, out: &mut [u8]) -> Result<(), ApFault>;
    /// `data` to `addr` as consecutive accesses of `width` bytes each.
    fn write(&mut self, addr: u32, width: u8, data: &[u8]) -> Result<(), ApFault>;
    /// NRST pulsed: a system reset with the pin's reset flag (RM0440 §7.1.2).
    fn pin_reset(&mut self);
    /// Let up to `max_ticks` of emulated time (170 MHz ticks) pass: the CPU runs unless
    /// halted, the peripherals and the plant always. Returns the ticks that passed.
    fn advance(&mut self, max_ticks: u64) -> anyhow::Result<u64>;
    /// Emulated time (170 MHz ticks since power-on).
    fn now_ticks(&self) -> u64;
}

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

/// DHCSR (ARMv7-M ARM C1.6.2) control bits and the debug key writes need.
pub const DHCSR: u32 = 0xE000_EDF0;
pub const DCRSR: u32 = 0xE000_EDF4;
pub const DCRDR: u32 = 0xE000_EDF8;
pub const DEMCR: u32 = 0xE000_EDFC;
/// DFSR (C1.6.1): why the core halted, write 1 to clear.
pub const DFSR: u32 = 0xE000_ED30;
pub const DBGKEY: u32 = 0xA05F;
pub const C_DEBUGEN: u32 = 1 << 0;
pub const C_HALT: u32 = 1 << 1;
pub const C_STEP: u32 = 1 << 2;
pub const C_MASKINTS: u32 = 1 << 3;
pub const S_REGRDY: u32 = 1 << 16;
pub const S_HALT: u32 = 1 << 17;
pub const S_SLEEP: u32 = 1 << 18;
pub const S_LOCKUP: u32 = 1 << 19;
pub const S_RETIRE_ST: u32 = 1 << 24;
pub const S_RESET_ST: u32 = 1 << 25;
pub const DFSR_HALTED: u32 = 1 << 0;
pub const DFSR_BKPT: u32 = 1 << 1;
pub const DFSR_VCATCH: u32 = 1 << 3;
/// DEMCR.VC_CORERESET (C1.6.5): halt on the reset vector.
pub const VC_CORERESET: u32 = 1 << 0;
/// DBGMCU IDCODE (RM0440 §46.6.1), CR and APB1FZR1 with DBG_IWDG_STOP (§46.16.3).
pub const DBGMCU_IDCODE: u32 = 0xE004_2000;
pub const DBGMCU_APB1FZR1: u32 = 0xE004_2008;
pub const DBG_IWDG_STOP: u32 = 1 << 12;
/// DEV_ID of the STM32G47x/48x (RM0440 §46.6.1) and the REV_ID reported with it.
pub const DEV_ID_G474: u16 = 0x469;
pub const REV_ID_G474: u16 = 0x2000;

/// The core's halting-debug state (ARMv7-M ARM C1.6). It lives in the debug power
/// domain: a system reset leaves it alone, only a power-on reset clears it (C1.6.2,
/// "DHCSR ... not reset by a Local reset").
#[derive(Clone, Debug, Default)]
pub struct DebugState {
    /// DHCSR control bits C_DEBUGEN, C_HALT, C_STEP, C_MASKINTS.
    pub ctrl: u32,
    /// The core is in Debug state: no instruction, no exception.
    pub halted: bool,
    /// One instruction to execute, then halt again (C_STEP written with C_HALT clear).
    pub step_pending: bool,
    pub dfsr: u32,
    pub dcrdr: u32,
    /// S_RESET_ST / S_RETIRE_ST: sticky, cleared by a DHCSR read.
    pub reset_st: bool,
    pub retire_st: bool,
}

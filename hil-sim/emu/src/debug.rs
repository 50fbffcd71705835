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
/// DEMCR.VC_HARDERR (C1.6.5): halt on a HardFault's entry.
pub const VC_HARDERR: u32 = 1 << 10;
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

/// The Flash Patch and Breakpoint unit as the Cortex-M4 has it (ARMv7-M ARM C1.11,
/// FPB version 1: six instruction comparators and two literal ones): breakpoints on
/// instruction fetches from the code region; no remapping (FP_REMAP.RMPSPT = 0), the
/// literal comparators are storage. Like the other debug registers it keeps its state
/// over a system reset.
#[derive(Clone, Debug, Default)]
pub struct Fpb {
    /// FP_CTRL.ENABLE.
    pub enable: bool,
    /// FP_COMP0..7 as written (FPBv1 fields: REPLACE[31:30], COMP[28:2], ENABLE[0]).
    pub comp: [u32; 8],
    /// Something changed since the CPU last installed its breakpoints.
    pub changed: bool,
}

pub const FP_CTRL: u32 = 0xE000_2000;
pub const FP_REMAP: u32 = 0xE000_2004;
pub const FP_COMP0: u32 = 0xE000_2008;
/// The end of the unit's registers (FP_COMP7 is the last).
pub const FP_END: u32 = FP_COMP0 + 32;
const FP_NUM_CODE: u32 = 6;
const FP_NUM_LIT: u32 = 2;

impl Fpb {
    /// A read of an FPB register; None outside the unit.
    pub fn read(&self, a: u32) -> Option<u32> {
        match a {
            // KEY reads 0; REV 0 (FPBv1); NUM_CODE[3:0] and NUM_LIT.
            FP_CTRL => Some(FP_NUM_LIT << 8 | FP_NUM_CODE << 4 | self.enable as u32),
            FP_REMAP => Some(0),
            a if (FP_COMP0..FP_END).contains(&a) => Some(self.comp[((a - FP_COMP0) / 4) as usize]),
            _ => None,
        }
    }

    /// A write of an FPB register; false outside the unit. FP_CTRL takes ENABLE only
    /// with KEY (bit 1) set.
    pub fn write(&mut self, a: u32, v: u32) -> bool {
        match a {
            FP_CTRL => {
                if v & 2 != 0 {
                    self.enable = v & 1 != 0;
                    self.changed = true;
                }
            }
            FP_REMAP => {}
            a if (FP_COMP0..FP_END).contains(&a) => {
                self.comp[((a - FP_COMP0) / 4) as usize] = v & 0xDFFF_FFFD;
                self.changed = true;
            }
            _ => return false,
        }
        true
    }

    /// The halfword addresses whose instruction fetch is a breakpoint now: an enabled
    /// instruction comparator's word address, its lower halfword (REPLACE = 01), upper
    /// (10) or both (11); REPLACE = 00 would remap, which this unit does not.
    pub fn breakpoints(&self) -> Vec<u32> {
        if !self.enable {
            return Vec::new();
        }
        let mut out = Vec::new();
        for &c in &self.comp[..FP_NUM_CODE as usize] {
            if c & 1 == 0 {
                continue;
            }
            let word = c & 0x1FFF_FFFC;
            let replace = c >> 30;
            if replace & 1 != 0 {
                out.push(word);
            }
            if replace & 2 != 0 {
                out.push(word + 2);
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }
}

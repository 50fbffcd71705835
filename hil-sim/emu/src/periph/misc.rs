//! The small ones: CORDIC (RM0440 §17), IWDG (§42), the GPIO alternate-function
//! routing of the break pin (§9), SYSCFG_CFGR2 (§10).

use crate::regfile::RegFile;

pub const CORDIC: u32 = 0x4002_0C00;
pub const CORDIC_CSR: u32 = CORDIC;
pub const CORDIC_WDATA: u32 = CORDIC + 0x04;
pub const CORDIC_RDATA: u32 = CORDIC + 0x08;

#[derive(Debug, Default, Clone)]
pub struct Cordic {
    results: [u32; 2],
    next: usize,
    /// Functions the model does not compute, asked for anyway.
    pub unsupported: u32,
}

impl Cordic {
    /// A WDATA write: one q1.31 argument (NARGS = 0; ARG2, the modulus, stays 1) →
    /// RES1, RES2 (§17.3.2 table 108: cosine gives m·cos, m·sin).
    pub fn write_arg(&mut self, regs: &mut RegFile, v: u32) {
        let csr = regs.get(CORDIC_CSR);
        let x = (v as i32) as f64 / 2f64.powi(31) * std::f64::consts::PI;
        let q31 = |r: f64| {
            ((r * 2f64.powi(31))
                .round()
                .clamp(-(2f64.powi(31)), 2f64.powi(31) - 1.0) as i32) as u32
        };
        let (r1, r2) = match csr & 0xF {
            0 => (x.cos(), x.sin()),
            1 => (x.sin(), x.cos()),
            _ => {
                self.unsupported += 1;
                (0.0, 0.0)
            }
        };
        self.results = [q31(r1), q31(r2)];
        self.next = 0;
        regs.set_bits(CORDIC_CSR, 1 << 31, true);
    }

    pub fn read_result(&mut self, regs: &mut RegFile) -> u32 {
        let nres = if regs.bit(CORDIC_CSR, 1 << 19) { 2 } else { 1 };
        let r = self.results[self.next.min(1)];
        self.next += 1;
        if self.next >= nres {
            regs.set_bits(CORDIC_CSR, 1 << 31, false);
            self.next = 0;
        }
        r
    }
}

pub const IWDG: u32 = 0x4000_3000;
pub const IWDG_KR: u32 = IWDG;
pub const IWDG_PR: u32 = IWDG + 0x04;
pub const IWDG_RLR: u32 = IWDG + 0x08;
pub const IWDG_SR: u32 = IWDG + 0x0C;
/// LSI: 32 kHz (§7.2.6).
const LSI_HZ: f64 = 32_000.0;

#[derive(Debug, Default, Clone)]
pub struct Iwdg {
    running: bool,
    write_access: bool,
    reloaded_at: u64,
    /// PR/RLR updates in flight (SR.PVU/RVU) until this time.
    sr_busy_until: u64,
    pub expiries: u32,
    /// PR/RLR writes without the 0x5555 key first: ignored by the hardware (§42.3.5).
    pub protected_writes: u32,
}

impl Iwdg {
    pub fn reset(&mut self) {
        *self = Self {
            expiries: self.expiries,
            protected_writes: self.protected_writes,
            ..Self::default()
        };
    }

    /// Timeout in ticks: (RLR + 1) · 4·2^PR LSI periods (§42.3.3).
    fn timeout_ticks(regs: &RegFile) -> u64 {
        let pr = (regs.get(IWDG_PR) & 0b111).min(6);
        let rlr = regs.get(IWDG_RLR) & 0xFFF;
        let lsi = (rlr as f64 + 1.0) * (4u32 << pr) as f64;
        super::ticks(lsi / LSI_HZ)
    }

    /// A write: keys (§42.3.2) and the write-protected PR/RLR.
    pub fn on_write(&mut self, regs: &mut RegFile, addr: u32, old: u32, now: u64) {
        match addr {
            IWDG_KR => match regs.get(IWDG_KR) & 0xFFFF {
                0xCCCC => {
                    self.running = true;
                    self.reloaded_at = now;
                }
                0xAAAA => self.reloaded_at = now,
                0x5555 => self.write_access = true,
                _ => self.write_access = false,
            },
            IWDG_PR | IWDG_RLR => {
                if !self.write_access {
                    regs.set(addr, old);
                    self.protected_writes += 1;
                } else {
                    self.sr_busy_until = now + super::ticks(5.0 / LSI_HZ);
                    let bit = if addr == IWDG_PR { 1 } else { 2 };
                    regs.set_bits(IWDG_SR, bit, true);
                }
            }
            _ => {}
        }
    }

    pub fn update(&mut self, regs: &mut RegFile, now: u64) {
        if now >= self.sr_busy_until {
            regs.set(IWDG_SR, 0);
        }
    }

    /// The counter stopped for `d` ticks (DBG_IWDG_STOP with the core halted).
    pub fn hold(&mut self, d: u64) {
        self.reloaded_at += d;
    }

    pub fn expiry(&self, regs: &RegFile) -> Option<u64> {
        self.running
            .then(|| self.reloaded_at + Self::timeout_ticks(regs))
    }
}

pub const GPIOA: u32 = 0x4800_0000;
pub const SYSCFG_MEMRMP: u32 = 0x4001_0000;
pub const SYSCFG_CFGR2: u32 = 0x4001_001C;

/// SYSCFG_MEMRMP.FB_MODE (§10.2.1): bank 2 mapped at 0x0800_0000 and bank 1 at
/// 0x0804_0000, so that code linked for 0x0800_0000 runs from bank 2.
pub fn banks_swapped(regs: &RegFile) -> bool {
    regs.bit(SYSCFG_MEMRMP, 1 << 8)
}

/// SYSCFG_CFGR2.CLL: the core's lockup output is a TIM1 break source (§10.2.8).
pub fn lockup_to_break(regs: &RegFile) -> bool {
    regs.bit(SYSCFG_CFGR2, 1)
}

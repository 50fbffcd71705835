//! The memory-mapped register file: every register of the modelled peripherals with the
//! reset value and write semantics the PAC (generated from ST's SVD) gives it
//! (`regs_g474.rs`, by `cargo xtask regs`). Behaviour lives in the peripheral models,
//! which read and set bits here; this file only applies what a bus write does.

use std::collections::HashMap;

/// One register as the PAC describes it.
#[derive(Clone, Debug)]
pub struct RegDef {
    pub addr: u32,
    pub periph: &'static str,
    pub name: &'static str,
    pub reset: u32,
    pub readable: bool,
    pub writable: bool,
    /// Fields written 1 to set (`rs`), 1 to clear (`rc_w1`), 0 to clear (`rc_w0`), 1 to
    /// toggle; the rest of the writable bits are plain.
    pub w1s: u32,
    pub w1c: u32,
    pub w0c: u32,
    pub w1t: u32,
    /// Bits of read-only fields in a writable register (hardware status).
    pub read_only_bits: u32,
}

/// A peripheral's address range.
#[derive(Debug)]
pub struct PeriphDef {
    pub name: &'static str,
    pub base: u32,
    pub size: u32,
}

/// The value a bus write of `v` leaves in a register that held `old`.
pub fn written(def: &RegDef, old: u32, v: u32) -> u32 {
    if !def.writable {
        return old;
    }
    let special = def.w1s | def.w1c | def.w0c | def.w1t | def.read_only_bits;
    let plain = !special;
    let mut new = (old & !plain) | (v & plain);
    new |= v & def.w1s;
    new &= !(v & def.w1c);
    new &= !(!v & def.w0c);
    new ^= v & def.w1t;
    new
}

/// Where ST's SVD (and so the PAC) gets a register's write semantics wrong, the rule
/// from RM0440: (address, w1c bits). FLASH_SR's EOP and error flags are "cleared by
/// writing 1" (§3.7.5), and so are FLASH_ECCR's ECCD and ECCC (§3.7.6); the SVD gives
/// them plain writers.
const W1C_OVERRIDES: &[(u32, u32)] = &[(0x4002_2010, 0x0000_C3FB), (0x4002_2018, 0xC000_0000)];

/// Registers the G474 has and the SVD leaves out, from RM0440: the bank-2 write
/// protection areas FLASH_WRP2AR/WRP2BR (§3.7.14-15), loaded from the option bytes.
const MISSING: &[RegDef] = &[
    option_byte_register(0x4002_204C, "WRP2AR"),
    option_byte_register(0x4002_2050, "WRP2BR"),
];

/// A FLASH register loaded from the option bytes: read-only, 0x0000_00FF (area empty).
const fn option_byte_register(addr: u32, name: &'static str) -> RegDef {
    RegDef {
        addr,
        periph: "FLASH",
        name,
        reset: 0x0000_00FF,
        readable: true,
        writable: false,
        w1s: 0,
        w1c: 0,
        w0c: 0,
        w1t: 0,
        read_only_bits: 0,
    }
}

/// Register values, by address.
pub struct RegFile {
    defs: Vec<RegDef>,
    values: Vec<u32>,
    index: HashMap<u32, usize>,
}

impl RegFile {
    pub fn new(defs: &'static [RegDef]) -> Self {
        let mut defs = defs.to_vec();
        defs.extend(MISSING.iter().cloned());
        let index = defs.iter().enumerate().map(|(i, d)| (d.addr, i)).collect();
        for &(addr, w1c) in W1C_OVERRIDES {
            if let Some(d) = defs.iter_mut().find(|d| d.addr == addr) {
                d.w1c |= w1c;
            }
        }
        Self {
            values: defs.iter().map(|d| d.reset).collect(),
            index,
            defs,
        }
    }

    /// Every register back to its reset value (a system reset).
    pub fn reset(&mut self) {
        for (v, d) in self.values.iter_mut().zip(&self.defs) {
            *v = d.reset;
        }
    }

    pub fn def(&self, addr: u32) -> Option<&RegDef> {
        self.index.get(&addr).map(|&i| &self.defs[i])
    }

    /// The value (models' view: no read side effects).
    pub fn get(&self, addr: u32) -> u32 {
        self.index.get(&addr).map_or(0, |&i| self.values[i])
    }

    /// Set by the hardware (models), bypassing the write semantics.
    pub fn set(&mut self, addr: u32, v: u32) {
        if let Some(&i) = self.index.get(&addr) {
            self.values[i] = v;
        }
    }

    pub fn set_bits(&mut self, addr: u32, mask: u32, on: bool) {
        let v = self.get(addr);
        self.set(addr, if on { v | mask } else { v & !mask });
    }

    pub fn bit(&self, addr: u32, mask: u32) -> bool {
        self.get(addr) & mask != 0
    }

    /// A bus write: the register's write semantics. Returns (old, new), None if no
    /// register is there.
    pub fn bus_write(&mut self, addr: u32, v: u32) -> Option<(u32, u32)> {
        let &i = self.index.get(&addr)?;
        let old = self.values[i];
        let new = written(&self.defs[i], old, v);
        self.values[i] = new;
        Some((old, new))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn def(w1s: u32, w1c: u32, w0c: u32, ro: u32) -> RegDef {
        RegDef {
            addr: 0,
            periph: "T",
            name: "R",
            reset: 0,
            readable: true,
            writable: true,
            w1s,
            w1c,
            w0c,
            w1t: 0,
            read_only_bits: ro,
        }
    }

    #[test]
    fn write_semantics_follow_the_field_kinds() {
        // ADC_CR-like: bit 0 rs, bit 28 plain. A modify that writes 0 to bit 0 keeps it.
        let d = def(1, 0, 0, 0);
        assert_eq!(written(&d, 1, 1 << 28), 1 | 1 << 28);
        assert_eq!(written(&d, 0, 1), 1);
        // rc_w1 (ADC_ISR): 1 clears, 0 keeps.
        let d = def(0, 0b11, 0, 0);
        assert_eq!(written(&d, 0b11, 0b01), 0b10);
        // rc_w0 (TIM_SR): 0 clears, 1 keeps.
        let d = def(0, 0, 0b11, 0);
        assert_eq!(written(&d, 0b11, 0b01), 0b01);
        // Read-only status bit (FLASH_SR.BSY) is not written by ones.
        let d = def(0, 0, 0, 1 << 16);
        assert_eq!(written(&d, 0, 0xFFFF_FFFF), 0xFFFE_FFFF);
        assert_eq!(written(&d, 1 << 16, 0), 1 << 16);
    }
}

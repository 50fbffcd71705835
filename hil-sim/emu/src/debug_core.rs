//! The emulated chip's side of the debug port: the core halted, stepped and resumed
//! (ARMv7-M ARM C1), its registers through DCRSR/DCRDR (C1.6.3-4), and the bus as the
//! MEM-AP sees it.

use crate::cpu::Emu;
use crate::debug::*;
use crate::elf::FLASH_BASE;
use crate::machine::{PERIPHERALS, SRAM, SRAM_BYTES, SYSMEM, SYSMEM_BYTES};
use crate::periph::flash;
use crate::periph::rcc::ResetKind;
use anyhow::Result;
use unicorn_engine::RegisterARM;

const BANK_BYTES: u32 = flash::BANK_BYTES;

fn within(a: u32, base: u32, len: u32) -> bool {
    a.wrapping_sub(base) < len
}

impl Emu {
    /// The slice of a halted core (C1.5): no instruction, no exception; the
    /// peripherals and the plant go on to the next event. IWDG stops with
    /// DBGMCU_APB1FZR1.DBG_IWDG_STOP (RM0440 §46.16.3), else it counts and may reset
    /// the chip. A pending single step executes exactly one instruction first.
    pub(crate) fn step_halted(&mut self, deadline: u64) -> Result<()> {
        if std::mem::take(&mut self.m_mut().dbg.step_pending) {
            return self.single_step();
        }
        let m = self.m_mut();
        let until = deadline.max(m.now + 1);
        if m.regs.bit(DBGMCU_APB1FZR1, DBG_IWDG_STOP) {
            m.iwdg.hold(until - m.now);
        }
        m.now = until;
        Ok(())
    }

    /// C_STEP (C1.6.2): one instruction, then Debug state again with DFSR.HALTED. A
    /// pending exception is taken first unless C_MASKINTS is set.
    fn single_step(&mut self) -> Result<()> {
        if self.m().lockup {
            return Ok(());
        }
        if self.m().dbg.ctrl & C_MASKINTS == 0 {
            self.take_pending()?;
        }
        let m = self.m_mut();
        m.dbg.halted = false;
        // A step of the idle loop `b .` must not skip time to a deadline: none here.
        m.deadline = m.now;
        m.stop = false;
        m.idle = false;
        m.first_block = true;
        let pc = self.pc();
        // Unicorn counts instructions only in blocks translated while counting: a block
        // cached from a normal run would run whole. Drop the translations around the PC
        // before the step, and after it, so that normal runs do not keep the counting
        // ones.
        let around = (pc as u64 & !0xFFF, (pc as u64 & !0xFFF) + 0x2000);
        let _ = self.uc.ctl_remove_cache(around.0, around.1);
        let r = self.uc.emu_start((pc | 1) as u64, 0, 0, 1);
        let _ = self.uc.ctl_remove_cache(around.0, around.1);
        self.after_run(r)?;
        let m = self.m_mut();
        m.dbg.retire_st = true;
        m.debug_halt(DFSR_HALTED);
        Ok(())
    }

    fn core_reg_id(sel: u32) -> Option<i32> {
        use RegisterARM as R;
        Some(match sel {
            0..=12 => R::R0 as i32 + sel as i32,
            13 => R::SP as i32,
            14 => R::LR as i32,
            15 => R::PC as i32,
            16 => R::XPSR as i32,
            17 => R::MSP as i32,
            18 => R::PSP as i32,
            33 => R::FPSCR as i32,
            64..=95 => R::S0 as i32 + (sel - 64) as i32,
            _ => return None,
        })
    }

    /// A core register by DCRSR.REGSEL (C1.6.3).
    pub fn core_reg_read(&self, sel: u32) -> u32 {
        let r = |id: i32| self.uc.reg_read(id).unwrap_or(0) as u32;
        match sel {
            15 => self.pc() & !1,
            20 => {
                use RegisterARM as R;
                r(R::CONTROL as i32) << 24
                    | r(R::FAULTMASK as i32) << 16
                    | r(R::BASEPRI as i32) << 8
                    | r(R::PRIMASK as i32)
            }
            s => Self::core_reg_id(s).map_or(0, r),
        }
    }

    pub fn core_reg_write(&mut self, sel: u32, v: u32) -> Result<()> {
        use RegisterARM as R;
        let w = |uc: &mut unicorn_engine::Unicorn<'static, crate::machine::Machine>,
                 id: i32,
                 v: u32| {
            uc.reg_write(id, v as u64)
                .map_err(|e| anyhow::anyhow!("{e:?}"))
        };
        match sel {
            15 => w(&mut self.uc, R::PC as i32, v & !1)?,
            20 => {
                w(&mut self.uc, R::PRIMASK as i32, v & 1)?;
                w(&mut self.uc, R::BASEPRI as i32, (v >> 8) & 0xFF)?;
                w(&mut self.uc, R::FAULTMASK as i32, (v >> 16) & 1)?;
                w(&mut self.uc, R::CONTROL as i32, (v >> 24) & 7)?;
            }
            16 => {
                w(&mut self.uc, R::XPSR as i32, v)?;
                // Thread/handler mode follows IPSR: QEMU re-reads it from the flags.
                let nzcv = self.uc.reg_read(R::APSR_NZCV).unwrap_or(0);
                let _ = self.uc.reg_write(R::APSR_NZCV, nzcv);
            }
            s => {
                if let Some(id) = Self::core_reg_id(s) {
                    w(&mut self.uc, id, v)?;
                }
            }
        }
        Ok(())
    }

    /// DCRSR written (C1.6.3): REGWnR (bit 16) moves DCRDR into the register, else the
    /// register into DCRDR. Only in Debug state; S_REGRDY is always set here (the
    /// transfer completes at once).
    fn dcrsr_write(&mut self, v: u32) {
        if !self.m().dbg.halted {
            return;
        }
        let sel = v & 0x7F;
        if v & (1 << 16) != 0 {
            let d = self.m().dbg.dcrdr;
            let _ = self.core_reg_write(sel, d);
        } else {
            self.m_mut().dbg.dcrdr = self.core_reg_read(sel);
        }
    }

    fn bus_read1(&mut self, a: u32, width: u8) -> Result<u32, ApFault> {
        let w = width as usize;
        let fault = ApFault { addr: a };
        if within(a, SRAM, SRAM_BYTES) || within(a, SYSMEM, SYSMEM_BYTES) {
            let mut b = [0u8; 4];
            self.uc.mem_read(a as u64, &mut b[..w]).map_err(|_| fault)?;
            return Ok(u32::from_le_bytes(b));
        }
        if within(a, FLASH_BASE, 2 * BANK_BYTES) {
            let off = a - FLASH_BASE;
            return Ok(self.m_mut().flash_read(off, w));
        }
        if PERIPHERALS.iter().any(|&(b, l)| within(a, b, l)) {
            return Ok(self.m_mut().mmio_read(a, w));
        }
        if (0xE000_0000..0xE010_0000).contains(&a) {
            let v = self.m_mut().ppb_read(a & !3);
            let mask = if w == 4 { u32::MAX } else { (1 << (8 * w)) - 1 };
            return Ok(v >> ((a & 3) * 8) & mask);
        }
        Err(fault)
    }

    fn bus_write1(&mut self, a: u32, width: u8, v: u32) -> Result<(), ApFault> {
        let w = width as usize;
        let fault = ApFault { addr: a };
        if within(a, SRAM, SRAM_BYTES) {
            self.uc
                .mem_write(a as u64, &v.to_le_bytes()[..w])
                .map_err(|_| fault)?;
            return Ok(());
        }
        if within(a, FLASH_BASE, 2 * BANK_BYTES) {
            self.m_mut().flash_write(a - FLASH_BASE, w, v);
            self.sync_bank1();
            return Ok(());
        }
        if PERIPHERALS.iter().any(|&(b, l)| within(a, b, l)) {
            self.m_mut().mmio_write(a, w, v);
            self.sync_bank1();
            return Ok(());
        }
        if (0xE000_0000..0xE010_0000).contains(&a) {
            if a == DCRSR {
                self.dcrsr_write(v);
            } else {
                self.m_mut().ppb_write(a, w, v);
                // C_STEP completes before the probe's next access, as on silicon,
                // where one instruction takes nanoseconds: a probe that reads S_HALT
                // straight after the write must see the step done, never the old PC
                // (probe-rs would take an unmoved PC for a BKPT and skip two bytes).
                if std::mem::take(&mut self.m_mut().dbg.step_pending) {
                    self.single_step().map_err(|_| fault)?;
                }
                // AIRCR.SYSRESETREQ likewise: the reset is over (S_RESET_ST set, the
                // vector catch taken or not) before the probe's next access. Left to
                // the next slice, a probe polling DHCSR straight after would see the
                // old halt and take it for the reset's vector catch.
                if let Some(kind) = self.m_mut().reset_request.take() {
                    self.system_reset(kind).map_err(|_| fault)?;
                }
            }
            return Ok(());
        }
        Err(fault)
    }

    /// Unicorn's copy of bank 1 follows the flash model where an erase or a program
    /// changed it, and the translations of changed code are dropped.
    pub(crate) fn sync_bank1(&mut self) {
        let Some((lo, hi)) = self.m_mut().bank1_dirty.take() else {
            return;
        };
        let bytes = self.m().flash[lo as usize..hi as usize].to_vec();
        let base = (FLASH_BASE + lo) as u64;
        let _ = self.uc.mem_write(base, &bytes);
        let _ = self.uc.ctl_remove_cache(base, (FLASH_BASE + hi) as u64);
    }
}

impl DebugPort for Emu {
    fn read(&mut self, addr: u32, width: u8, out: &mut [u8]) -> Result<(), ApFault> {
        if !matches!(width, 1 | 2 | 4) || !addr.is_multiple_of(width as u32) {
            return Err(ApFault { addr });
        }
        for (k, chunk) in out.chunks_mut(width as usize).enumerate() {
            let a = addr.wrapping_add((k * width as usize) as u32);
            let v = self.bus_read1(a, width)?;
            let n = chunk.len();
            chunk.copy_from_slice(&v.to_le_bytes()[..n]);
        }
        Ok(())
    }

    fn write(&mut self, addr: u32, width: u8, data: &[u8]) -> Result<(), ApFault> {
        if !matches!(width, 1 | 2 | 4) || !addr.is_multiple_of(width as u32) {
            return Err(ApFault { addr });
        }
        for (k, chunk) in data.chunks(width as usize).enumerate() {
            let a = addr.wrapping_add((k * width as usize) as u32);
            let mut b = [0u8; 4];
            b[..chunk.len()].copy_from_slice(chunk);
            self.bus_write1(a, width, u32::from_le_bytes(b))?;
        }
        Ok(())
    }

    fn pin_reset(&mut self) {
        let _ = self.system_reset(ResetKind::Pin);
    }

    fn advance(&mut self, max_ticks: u64) -> Result<u64> {
        let t0 = self.m().now;
        let t_end = t0.saturating_add(max_ticks);
        while self.m().now < t_end && !self.m().powered_off {
            self.step(t_end)?;
        }
        Ok(self.m().now - t0)
    }

    fn now_ticks(&self) -> u64 {
        self.m().now
    }
}

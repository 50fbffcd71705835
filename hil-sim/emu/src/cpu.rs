//! The CPU: Unicorn as a Cortex-M4F running the image, and the core's behaviour Unicorn
//! lacks, done here between translated blocks: exception entry and return with the
//! 8- or 26-word frame (ARMv7-M ARM B1.5.6-8), tail-chaining and nesting by priority,
//! faults, lockup and resets.

use crate::board::Board;
use crate::elf::{self, Image, FLASH_BASE};
use crate::machine::{
    Fault, Machine, ADC1_2_IRQ, PERIPHERALS, SRAM, SRAM_BYTES, SYSMEM, SYSMEM_BYTES,
};
use crate::nvic;
use crate::periph::rcc::ResetKind;
use crate::periph::ticks;
use crate::profile::{Profile, Stage, ENTRY_CYCLES, EXIT_CYCLES, LAZY_FP_WORDS};
use crate::rtt::{Rtt, UP0};
use anyhow::{anyhow, bail, Result};
use unicorn_engine::{Arch, ArmCpuModel, HookType, MemType, Mode, Prot, RegisterARM, Unicorn};

const BANK2: u64 = 0x0804_0000;
const BANK_BYTES: u64 = 256 * 1024;
/// FLASH_SIZE data register (RM0440 §48.2): KiB of flash.
const FLASH_SIZE_REG: u64 = 0x1FFF_75E0;

/// Exception return values (B1.5.8).
const EXC_RETURN_FP: u32 = 0xFFFF_FFE1;
const EXC_RETURN_BASIC: u32 = 0xFFFF_FFF1;
const EXC_RETURN_THREAD: u32 = 0x8;

/// The core registers of a basic frame, in stack order (PC and xPSR follow; B1.5.6).
const FRAME_REGS: [RegisterARM; 6] = [
    RegisterARM::R0,
    RegisterARM::R1,
    RegisterARM::R2,
    RegisterARM::R3,
    RegisterARM::R12,
    RegisterARM::LR,
];

/// What the flash keeps over a power cycle: its bytes and the double words torn by a
/// power cut during programming (their data and ECC disagree).
#[derive(Clone, Debug)]
pub struct KeptFlash {
    pub bytes: Vec<u8>,
    pub torn: Vec<u32>,
}

/// The emulated board running a firmware image.
pub struct Emu {
    pub uc: Unicorn<'static, Machine>,
    pub elf: Vec<u8>,
    /// The FPB's breakpoints as Unicorn code hooks (address, hook).
    fpb_hooks: Vec<(u32, unicorn_engine::UcHookId)>,
}

fn uc_err(e: unicorn_engine::uc_error) -> anyhow::Error {
    anyhow!("unicorn: {e:?}")
}

impl Emu {
    /// Power the board on with `elf` in flash; `flash` is the flash of an earlier run
    /// (the calibration pages kept), or None for a freshly programmed part (the
    /// calibration pages erased).
    pub fn new(elf: &[u8], board: Board, flash: Option<KeptFlash>) -> Result<Self> {
        let Image {
            flash: image,
            rtt_block,
            ..
        } = elf::load(elf)?;
        let (flash, torn) = match flash {
            // Reflash the code, keep bank 2 (where the calibration lives).
            Some(KeptFlash { mut bytes, torn }) => {
                bytes[..BANK_BYTES as usize].copy_from_slice(&image[..BANK_BYTES as usize]);
                let bank2 = torn
                    .into_iter()
                    .filter(|&t| t >= BANK_BYTES as u32)
                    .collect();
                (bytes, bank2)
            }
            None => (image, Vec::new()),
        };
        let mut m = Machine::new(flash, board, Rtt::new(rtt_block));
        m.flash_ctl.torn = torn;
        m.profile = Some(Profile::for_elf(elf)?);
        Self::power_on(m, elf.to_vec())
    }

    /// A blank chip: flash erased (0xFF), no firmware known. Out of reset the core
    /// reads SP and PC 0xFFFF_FFFF from the erased vector table; the fetch from there
    /// faults and the HardFault vector (erased too) faults again: lockup (B1.5.15).
    pub fn blank(board: Board) -> Result<Self> {
        let m = Machine::new(vec![0xFF; 2 * BANK_BYTES as usize], board, Rtt::new(None));
        Self::power_on(m, Vec::new())
    }

    /// The core around `m`, its RAM at power-on content, out of reset.
    fn power_on(m: Machine, elf: Vec<u8>) -> Result<Self> {
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB, m).map_err(uc_err)?;
        // Not UC_MODE_MCLASS, which makes a Cortex-M33: a Cortex-M4 with our own
        // exception model.
        uc.ctl_set_cpu_model(ArmCpuModel::CORTEX_M4 as i32)
            .map_err(uc_err)?;
        Self::map(&mut uc)?;
        let mut emu = Self {
            uc,
            elf,
            fpb_hooks: Vec::new(),
        };
        // Power-on RAM content is not zero: a fixed pattern, so `.uninit` records are
        // garbage at the first boot.
        let pattern: Vec<u8> = (0..SRAM_BYTES)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        emu.uc.mem_write(SRAM as u64, &pattern).map_err(uc_err)?;
        emu.cpu_reset()?;
        Ok(emu)
    }

    /// The firmware a probe flashed: its cycle profile and RTT control block for the
    /// measurements. The flash is not touched.
    pub fn set_firmware(&mut self, elf: &[u8]) -> Result<()> {
        let image = elf::load(elf)?;
        let profile = Profile::for_elf(elf)?;
        let m = self.m_mut();
        m.rtt.block = image.rtt_block;
        m.profile = Some(profile);
        m.block_costs.clear();
        self.elf = elf.to_vec();
        Ok(())
    }

    fn map(uc: &mut Unicorn<'static, Machine>) -> Result<()> {
        // Bank 1 (code) as memory; bank 2 through callbacks (programming, ECC).
        uc.mem_map(FLASH_BASE as u64, BANK_BYTES, Prot::READ | Prot::EXEC)
            .map_err(uc_err)?;
        let code = uc.get_data().flash[..BANK_BYTES as usize].to_vec();
        uc.mem_write(FLASH_BASE as u64, &code).map_err(uc_err)?;
        uc.mmio_map(
            BANK2,
            BANK_BYTES,
            Some(|uc: &mut Unicorn<'_, Machine>, off: u64, size: usize| {
                uc.get_data_mut()
                    .flash_read((BANK_BYTES + off) as u32, size) as u64
            }),
            Some(
                |uc: &mut Unicorn<'_, Machine>, off: u64, size: usize, v: u64| {
                    uc.get_data_mut()
                        .flash_write((BANK_BYTES + off) as u32, size, v as u32)
                },
            ),
        )
        .map_err(uc_err)?;
        uc.mem_map(SYSMEM as u64, SYSMEM_BYTES as u64, Prot::READ)
            .map_err(uc_err)?;
        uc.mem_write(FLASH_SIZE_REG, &512u16.to_le_bytes())
            .map_err(uc_err)?;
        uc.mem_map(SRAM as u64, SRAM_BYTES as u64, Prot::ALL)
            .map_err(uc_err)?;
        for (base, size) in PERIPHERALS.map(|(b, n)| (b as u64, n as u64)) {
            uc.mmio_map(
                base,
                size,
                Some(move |uc: &mut Unicorn<'_, Machine>, off: u64, sz: usize| {
                    uc.get_data_mut().mmio_read((base + off) as u32, sz) as u64
                }),
                Some(
                    move |uc: &mut Unicorn<'_, Machine>, off: u64, sz: usize, v: u64| {
                        uc.get_data_mut()
                            .mmio_write((base + off) as u32, sz, v as u32)
                    },
                ),
            )
            .map_err(uc_err)?;
        }
        // The peripheral bit-band alias (PM0214 §2.2.5): one word per bit of
        // 0x4000_0000..0x400F_FFFF.
        uc.mmio_map(
            0x4200_0000,
            0x0200_0000,
            Some(|uc: &mut Unicorn<'_, Machine>, off: u64, _sz: usize| {
                let (addr, bit) = bitband(off);
                (uc.get_data_mut().mmio_read(addr, 4) >> bit & 1) as u64
            }),
            Some(
                |uc: &mut Unicorn<'_, Machine>, off: u64, _sz: usize, v: u64| {
                    let (addr, bit) = bitband(off);
                    let m = uc.get_data_mut();
                    let old = m.regs.get(addr);
                    let new = if v & 1 != 0 {
                        old | 1 << bit
                    } else {
                        old & !(1 << bit)
                    };
                    m.mmio_write(addr, 4, new);
                },
            ),
        )
        .map_err(uc_err)?;
        uc.mmio_map(
            0xE000_0000,
            0x0010_0000,
            Some(|uc: &mut Unicorn<'_, Machine>, off: u64, sz: usize| {
                let a = 0xE000_0000 + off as u32;
                let v = uc.get_data_mut().ppb_read(a & !3);
                (v >> ((a & 3) * 8)
                    & if sz == 4 {
                        u32::MAX
                    } else {
                        (1 << (8 * sz)) - 1
                    }) as u64
            }),
            Some(
                |uc: &mut Unicorn<'_, Machine>, off: u64, sz: usize, v: u64| {
                    let a = 0xE000_0000 + off as u32;
                    uc.get_data_mut().ppb_write(a, sz, v as u32)
                },
            ),
        )
        .map_err(uc_err)?;

        uc.add_block_hook(
            1,
            0,
            |uc: &mut Unicorn<'_, Machine>, addr: u64, size: u32| on_block(uc, addr as u32, size),
        )
        .map_err(uc_err)?;
        uc.add_intr_hook(|uc: &mut Unicorn<'_, Machine>, intno: u32| {
            let pc = uc.reg_read(RegisterARM::PC).unwrap_or(0) as u32;
            let m = uc.get_data_mut();
            match intno {
                // EXCP_EXCEPTION_EXIT: a branch to an EXC_RETURN value.
                8 => m.exc_return = Some(pc),
                // EXCP_NOCP: Unicorn's own coprocessor check.
                17 => m.fault = Some(Fault::NoCoprocessor(pc)),
                // EXCP_BKPT: with halting debug enabled the core enters Debug state at
                // the BKPT (ARMv7-M ARM C1.5.1: DFSR.BKPT, the PC left at it);
                // without, a HardFault (the DebugMonitor is not enabled).
                7 if m.dbg.ctrl & crate::debug::C_DEBUGEN != 0 => {
                    m.debug_halt(crate::debug::DFSR_BKPT);
                    m.bkpt_at = Some(pc);
                }
                _ => m.fault = Some(Fault::Undefined(pc)),
            }
            let _ = uc.emu_stop();
        })
        .map_err(uc_err)?;
        uc.add_mem_hook(
            HookType::MEM_UNMAPPED | HookType::MEM_PROT,
            1,
            0,
            |uc: &mut Unicorn<'_, Machine>, t: MemType, addr: u64, size: usize, v: i64| {
                // A store into bank 1 (mapped read-only for Unicorn) is a write to the
                // flash array: the controller decides (programming, or PGSERR etc.,
                // RM0440 §3.3.8); the CPU loop then copies the model's bank 1 back.
                let a = addr as u32;
                if t == MemType::WRITE_PROT
                    && (FLASH_BASE..FLASH_BASE + BANK_BYTES as u32).contains(&a)
                {
                    uc.get_data_mut()
                        .flash_write(a - FLASH_BASE, size, v as u32);
                    uc.get_data_mut().stop = true;
                    return true;
                }
                uc.get_data_mut().fault = Some(Fault::Bus(a));
                false
            },
        )
        .map_err(uc_err)?;
        Ok(())
    }

    pub fn m(&self) -> &Machine {
        self.uc.get_data()
    }

    pub fn m_mut(&mut self) -> &mut Machine {
        self.uc.get_data_mut()
    }

    fn reg(&self, r: RegisterARM) -> u32 {
        self.uc.reg_read(r).unwrap_or(0) as u32
    }

    fn set_reg(&mut self, r: RegisterARM, v: u32) -> Result<()> {
        self.uc.reg_write(r, v as u64).map_err(uc_err)
    }

    fn read_u32(&self, a: u32) -> Result<u32> {
        let mut b = [0u8; 4];
        self.uc.mem_read(a as u64, &mut b).map_err(uc_err)?;
        Ok(u32::from_le_bytes(b))
    }

    fn write_u32(&mut self, a: u32, v: u32) -> Result<()> {
        self.uc
            .mem_write(a as u64, &v.to_le_bytes())
            .map_err(uc_err)
    }

    /// The core out of reset: SP and PC from the vector table (B1.5.5).
    fn cpu_reset(&mut self) -> Result<()> {
        let sp = self.m().vector(0);
        let pc = self.m().vector(1);
        for r in [
            RegisterARM::R0,
            RegisterARM::R1,
            RegisterARM::R2,
            RegisterARM::R3,
            RegisterARM::R12,
        ] {
            self.set_reg(r, 0)?;
        }
        self.set_reg(RegisterARM::PRIMASK, 0)?;
        self.set_reg(RegisterARM::BASEPRI, 0)?;
        self.set_reg(RegisterARM::CONTROL, 0)?;
        self.set_reg(RegisterARM::XPSR, 1 << 24)?;
        self.set_reg(RegisterARM::MSP, sp)?;
        self.set_reg(RegisterARM::SP, sp)?;
        self.set_reg(RegisterARM::LR, 0xFFFF_FFFF)?;
        self.set_reg(RegisterARM::PC, pc & !1)?;
        self.flush_mode()?;
        Ok(())
    }

    /// A system reset: peripherals, core registers; RAM and flash kept. With
    /// DEMCR.VC_CORERESET and halting debug enabled the core halts on the reset vector's
    /// first instruction (ARMv7-M ARM C1.6.5, DFSR.VCATCH).
    pub(crate) fn system_reset(&mut self, kind: ResetKind) -> Result<()> {
        self.m_mut().reset_peripherals(kind);
        self.cpu_reset()?;
        let m = self.m_mut();
        if m.dbg.ctrl & crate::debug::C_DEBUGEN != 0 && m.demcr & crate::debug::VC_CORERESET != 0 {
            m.debug_halt(crate::debug::DFSR_VCATCH);
        } else {
            // Without the vector catch the core leaves Debug state and runs from the
            // reset vector (what a probe's plain reset, probe-rs `reset`, relies on).
            m.debug_resume();
        }
        Ok(())
    }

    /// QEMU caches thread/handler mode in its translation flags: rewriting the flags
    /// register makes it re-read IPSR.
    fn flush_mode(&mut self) -> Result<()> {
        let nzcv = self.reg(RegisterARM::APSR_NZCV);
        self.set_reg(RegisterARM::APSR_NZCV, nzcv)
    }

    /// Exception entry (B1.5.6): push the frame on the main stack, EXC_RETURN in LR,
    /// IPSR, the handler.
    fn enter(&mut self, n: u16) -> Result<()> {
        let fp = self.m().fpu_enabled();
        let sp = self.reg(RegisterARM::SP);
        let size = if fp { 0x68 } else { 0x20 };
        let align = sp & 4 != 0;
        let frame = (sp - size) & !7;
        let xpsr = self.reg(RegisterARM::XPSR);
        for (i, r) in FRAME_REGS.iter().enumerate() {
            let v = self.reg(*r);
            self.write_u32(frame + 4 * i as u32, v)?;
        }
        let pc = self.reg(RegisterARM::PC);
        self.write_u32(frame + 24, pc)?;
        self.write_u32(frame + 28, (xpsr & !(1 << 9)) | (align as u32) << 9)?;
        if fp {
            for k in 0..16 {
                let s = self.uc.reg_read(RegisterARM::S0 as i32 + k).unwrap_or(0) as u32;
                self.write_u32(frame + 32 + 4 * k as u32, s)?;
            }
            let fpscr = self.reg(RegisterARM::FPSCR);
            self.write_u32(frame + 96, fpscr)?;
        }
        let thread = self.m().nvic.active.is_empty();
        let exc_return = if fp { EXC_RETURN_FP } else { EXC_RETURN_BASIC }
            | if thread { EXC_RETURN_THREAD } else { 0 };
        let handler = self.m().vector(n);
        // The frame push is in the entry's cost; no branch refill follows it.
        let cost = ENTRY_CYCLES + if fp { LAZY_FP_WORDS } else { 0 };
        self.m_mut().exception_entered(n, cost);
        self.set_reg(RegisterARM::SP, frame)?;
        self.set_reg(RegisterARM::LR, exc_return)?;
        // IPSR = n, T = 1, IT/ICI cleared.
        self.set_reg(RegisterARM::XPSR, (xpsr & 0xF800_0000) | 1 << 24 | n as u32)?;
        self.set_reg(RegisterARM::PC, handler & !1)?;
        self.flush_mode()
    }

    /// Exception return (B1.5.8): pop the frame the EXC_RETURN value describes.
    fn exit(&mut self, exc_return: u32) -> Result<()> {
        let fp = exc_return & 0x10 == 0;
        let frame = self.reg(RegisterARM::SP);
        for (i, r) in FRAME_REGS.iter().enumerate() {
            let v = self.read_u32(frame + 4 * i as u32)?;
            self.set_reg(*r, v)?;
        }
        let pc = self.read_u32(frame + 24)?;
        let xpsr = self.read_u32(frame + 28)?;
        if fp {
            for k in 0..16 {
                let v = self.read_u32(frame + 32 + 4 * k as u32)?;
                self.uc
                    .reg_write(RegisterARM::S0 as i32 + k, v as u64)
                    .map_err(uc_err)?;
            }
            let fpscr = self.read_u32(frame + 96)?;
            self.set_reg(RegisterARM::FPSCR, fpscr)?;
        }
        let size = if fp { 0x68 } else { 0x20 };
        let sp = frame + size + if xpsr & (1 << 9) != 0 { 4 } else { 0 };
        let cost = EXIT_CYCLES + if fp { LAZY_FP_WORDS } else { 0 };
        self.m_mut().exception_returned(cost);
        self.set_reg(RegisterARM::SP, sp)?;
        self.set_reg(RegisterARM::XPSR, xpsr & !(1 << 9))?;
        self.set_reg(RegisterARM::PC, pc & !1)?;
        self.flush_mode()
    }

    /// A fault: HardFault (the configurable faults are not enabled by the firmware, so
    /// they escalate), or lockup when it happens in HardFault or NMI (B1.5.15).
    fn fault(&mut self, f: Fault) -> Result<()> {
        if std::env::var_os("DRIVE_EMU_TRACE").is_some() {
            eprintln!(
                "fault {f:x?} pc={:#x} sp={:#x} lr={:#x} t={:.6}",
                self.reg(RegisterARM::PC),
                self.reg(RegisterARM::SP),
                self.reg(RegisterARM::LR),
                self.m().time_s()
            );
        }
        let in_fault_handler = self
            .m()
            .nvic
            .active
            .iter()
            .any(|&n| n == nvic::HARD_FAULT || n == nvic::NMI);
        let m = self.m_mut();
        match f {
            Fault::NoCoprocessor(_) => m.cfsr |= 1 << 19,
            Fault::Undefined(_) => m.cfsr |= 1 << 16,
            Fault::Bus(_) => m.cfsr |= 1 << 10,
        }
        m.hfsr |= 1 << 30;
        if in_fault_handler {
            m.lockup = true;
            m.stats.lockups += 1;
            m.check_break();
            return Ok(());
        }
        let pc = match f {
            Fault::NoCoprocessor(pc) | Fault::Undefined(pc) => pc,
            Fault::Bus(_) => self.reg(RegisterARM::PC),
        };
        let now = self.m().now;
        self.m_mut().stats.hard_faults.push((now, pc));
        self.set_reg(RegisterARM::PC, pc)?;
        if self.enter(nvic::HARD_FAULT).is_err() {
            // The frame could not be pushed (SP outside memory, as from an erased
            // vector table): a fault while entering HardFault, lockup (B1.5.15).
            let m = self.m_mut();
            m.lockup = true;
            m.stats.lockups += 1;
            return Ok(());
        }
        // DEMCR.VC_HARDERR (C1.6.5): with halting debug enabled the core halts on the
        // HardFault handler's first instruction, the frame stacked, DFSR.VCATCH set.
        let m = self.m_mut();
        if m.dbg.ctrl & crate::debug::C_DEBUGEN != 0 && m.demcr & crate::debug::VC_HARDERR != 0 {
            m.debug_halt(crate::debug::DFSR_VCATCH);
        }
        Ok(())
    }

    /// Take the most urgent pending exception if it preempts what runs (with
    /// tail-chaining, this is called again after each return).
    pub(crate) fn take_pending(&mut self) -> Result<bool> {
        let Some((n, prio)) = self.m().nvic.most_urgent_pending() else {
            return Ok(false);
        };
        let primask = self.reg(RegisterARM::PRIMASK) & 1 != 0;
        let basepri = self.reg(RegisterARM::BASEPRI) as u8;
        if prio < self.m().nvic.execution_priority(primask, basepri) {
            self.enter(n)?;
            Ok(true)
        } else {
            Ok(false)
        }
    }

    /// RTT: read what the firmware wrote since the last poll (the host side).
    fn poll_rtt(&mut self) -> Result<()> {
        let now = self.m().now;
        self.m_mut().rtt.schedule(now);
        let (Some(cb), true) = (self.m().rtt.block, self.m().rtt.reading) else {
            return Ok(());
        };
        // Until the firmware's start-up code has written the control block, RAM holds
        // anything: a host finds the block by its ID, as probe-rs does.
        let mut id = [0u8; 10];
        self.uc.mem_read(cb as u64, &mut id).map_err(uc_err)?;
        if &id != b"SEGGER RTT" {
            return Ok(());
        }
        let up = cb + UP0;
        let buf = self.read_u32(up + 4)?;
        let size = self.read_u32(up + 8)?;
        let wr = self.read_u32(up + 12)?;
        let observe = self.m().rtt.mode == crate::rtt::RttMode::Observe;
        // Observing: from the write offset seen last (the buffer starts empty at
        // offset 0), whatever a probe did to RdOff.
        let rd = if observe {
            self.m().rtt.seen_wr.unwrap_or(0)
        } else {
            self.read_u32(up + 16)?
        };
        let in_ram = |a: u32| (SRAM..SRAM + SRAM_BYTES).contains(&a);
        if size == 0
            || wr >= size
            || rd >= size
            || wr == rd
            || !in_ram(buf)
            || !in_ram(buf + size - 1)
        {
            return Ok(());
        }
        let mut out = Vec::new();
        let copy = |from: u32, to: u32, out: &mut Vec<u8>| -> Result<()> {
            let mut b = vec![0u8; (to - from) as usize];
            self.uc
                .mem_read((buf + from) as u64, &mut b)
                .map_err(uc_err)?;
            out.extend(b);
            Ok(())
        };
        if wr > rd {
            copy(rd, wr, &mut out)?;
        } else {
            copy(rd, size, &mut out)?;
            copy(0, wr, &mut out)?;
        }
        if observe {
            self.m_mut().rtt.seen_wr = Some(wr);
        } else {
            self.write_u32(up + 16, wr)?;
        }
        let m = self.m_mut();
        m.rtt.bytes.extend(out);
        m.rtt.reads += 1;
        Ok(())
    }

    /// Run until `t_end_s` of emulated time (or the power is cut).
    pub fn run_until(&mut self, t_end_s: f64) -> Result<()> {
        let t_end = ticks(t_end_s);
        while self.m().now < t_end && !self.m().powered_off {
            self.step(t_end)?;
        }
        Ok(())
    }

    pub fn run_for(&mut self, dt_s: f64) -> Result<()> {
        let t = self.m().time_s() + dt_s;
        self.run_until(t)
    }

    /// One slice: events, exceptions, then the CPU up to the next event.
    pub(crate) fn step(&mut self, t_end: u64) -> Result<()> {
        self.sync_bank1();
        self.m_mut().service_events();
        if self.m().rtt.next_poll <= self.m().now {
            self.poll_rtt()?;
        }
        if let Some(kind) = self.m_mut().reset_request.take() {
            return self.system_reset(kind);
        }
        let deadline = self.m().next_event().min(t_end);
        if self.m().dbg.halted {
            return self.step_halted(deadline);
        }
        // An injected busy-wait at the end of the control interrupt: time passes as
        // executed instructions of the handler, then it returns.
        if let Some((exc_return, until)) = self.m().busy_exit {
            if self.m().now >= until {
                self.m_mut().busy_exit = None;
                return self.exit(exc_return);
            }
            let m = self.m_mut();
            let to = until.min(deadline).max(m.now + 1);
            let n = (to - m.now) / m.rcc.ticks_per_instr.max(1);
            m.now = to;
            m.instrs += n;
            m.cycles += n;
            m.stats.charge(Stage::Rest, n, n);
            return Ok(());
        }
        // A stalled or locked-up core executes nothing: time passes to the next event.
        let (stall, lockup) = (self.m().stall_until, self.m().lockup);
        if lockup || stall > self.m().now {
            let until = if lockup {
                deadline
            } else {
                stall.min(deadline)
            };
            let m = self.m_mut();
            m.now = until.max(m.now + 1);
            return Ok(());
        }
        while self.take_pending()? {}
        let m = self.m_mut();
        m.deadline = deadline;
        m.stop = false;
        m.idle = false;
        m.first_block = true;
        self.sync_breakpoints()?;
        let pc = self.reg(RegisterARM::PC);
        self.m_mut().fetching_from_flash =
            (FLASH_BASE..FLASH_BASE + 2 * BANK_BYTES as u32).contains(&pc);
        let r = self.uc.emu_start((pc | 1) as u64, 0, 0, 0);
        self.after_run(r)
    }

    /// The FPB's breakpoints as code hooks on their addresses: a fetch from one enters
    /// Debug state before the instruction executes (DFSR.BKPT; the PC stays on it),
    /// when halting debug is enabled (without it the event is ignored here). Each
    /// address's translations are dropped so that the hook takes effect.
    fn sync_breakpoints(&mut self) -> Result<()> {
        if !std::mem::take(&mut self.m_mut().fpb.changed) {
            return Ok(());
        }
        for (a, id) in std::mem::take(&mut self.fpb_hooks) {
            self.uc.remove_hook(id).map_err(uc_err)?;
            self.uc
                .ctl_remove_cache(a as u64, a as u64 + 4)
                .map_err(uc_err)?;
        }
        for a in self.m().fpb.breakpoints() {
            let id = self
                .uc
                .add_code_hook(a as u64, a as u64, |uc, addr, _size| {
                    let m = uc.get_data_mut();
                    // The unit as it is now: a probe disables it to step over the
                    // breakpoint before the hooks are brought up to date.
                    let live = m.fpb.breakpoints().contains(&(addr as u32));
                    if live && m.dbg.ctrl & crate::debug::C_DEBUGEN != 0 {
                        m.debug_halt(crate::debug::DFSR_BKPT);
                        m.bkpt_at = Some(addr as u32);
                        let _ = uc.emu_stop();
                    }
                })
                .map_err(uc_err)?;
            self.uc
                .ctl_remove_cache(a as u64, a as u64 + 4)
                .map_err(uc_err)?;
            self.fpb_hooks.push((a, id));
        }
        Ok(())
    }

    /// What a run of Unicorn left to do: an exception return, a fault, a BKPT halt.
    pub(crate) fn after_run(
        &mut self,
        r: std::result::Result<(), unicorn_engine::uc_error>,
    ) -> Result<()> {
        if let Some(pc) = self.m_mut().bkpt_at.take() {
            // Unicorn stopped past the BKPT's exception: the PC back on it.
            self.set_reg(RegisterARM::PC, pc)?;
            return Ok(());
        }
        let m = self.m_mut();
        if let Some(e) = m.exc_return.take() {
            if e >> 28 == 0xF {
                let control = m.nvic.active.last() == Some(&nvic::irq(ADC1_2_IRQ));
                if control && m.control_busy_ticks > 0 {
                    m.busy_exit = Some((e, m.now + m.control_busy_ticks));
                    return Ok(());
                }
                return self.exit(e);
            }
        }
        if let Some(f) = m.fault.take() {
            return self.fault(f);
        }
        if let Err(e) = r {
            bail!(
                "the CPU stopped at pc={:#010x}: {e:?}",
                self.reg(RegisterARM::PC)
            );
        }
        let m = self.m_mut();
        if m.idle && !m.nvic.any_pending() {
            // The idle loop: nothing runs until the next event.
            m.now = m.now.max(m.deadline);
        }
        Ok(())
    }

    /// The flash as it stays over a power cycle (to power the board up again with it).
    pub fn flash(&self) -> KeptFlash {
        let m = self.m();
        KeptFlash {
            bytes: m.flash.clone(),
            torn: m.flash_ctl.torn.clone(),
        }
    }

    /// The CPU is in the idle loop and no exception is active.
    pub fn pc(&self) -> u32 {
        self.reg(RegisterARM::PC)
    }
}

/// Bit-band alias offset → (peripheral word address, bit).
fn bitband(off: u64) -> (u32, u32) {
    let byte = (off / 32) as u32;
    let bit = ((off % 32) / 4) as u32 + (byte & 3) * 8;
    (0x4000_0000 + (byte & !3), bit)
}

/// The block hook: whether to leave Unicorn before this block, and if not its time,
/// the FPU check and idle detection. Unicorn emits the hook ahead of the block's
/// exit-request check, so a stop asked for here leaves *before* the block runs: the
/// block is counted only when it runs, and the first block of a slice always runs (a
/// slice shorter than a block still makes progress).
fn on_block(uc: &mut Unicorn<'_, Machine>, addr: u32, size: u32) {
    let m = uc.get_data_mut();
    let first = std::mem::take(&mut m.first_block);
    let pending = m.nvic.any_pending();
    let track = m.stats.armed && m.stats.isr_entered_at.is_none();
    let mut preempt = false;
    if pending || track {
        let primask = uc.reg_read(RegisterARM::PRIMASK).unwrap_or(0) & 1 != 0;
        let basepri = uc.reg_read(RegisterARM::BASEPRI).unwrap_or(0) as u8;
        let m = uc.get_data_mut();
        let exec = m.nvic.execution_priority(primask, basepri);
        if pending {
            preempt = m
                .nvic
                .most_urgent_pending()
                .is_some_and(|(_, prio)| prio < exec);
        }
        // The control interrupt masked by PRIMASK/BASEPRI (not by running itself, nor by
        // its own locks), once the window is open: init runs masked by design. As of
        // this block's start.
        let masked = m.stats.armed
            && m.stats.isr_entered_at.is_none()
            && (primask || (basepri != 0 && (basepri as i16 & 0xF0) <= m.control_priority()));
        match (masked, m.stats.masked_since) {
            (true, None) => m.stats.masked_since = Some(m.instrs),
            (false, Some(t0)) => {
                let (len, at) = (m.instrs - t0, m.now);
                m.stats.masked_ended(len, at);
                m.stats.masked_since = None;
            }
            _ => {}
        }
    }
    let m = uc.get_data_mut();
    if !first && (m.stop || preempt || m.now >= m.deadline) {
        let _ = uc.emu_stop();
        return;
    }
    let (n, vfp) = m.count_instrs(addr, size);
    m.instrs += n;
    m.now += n * m.rcc.ticks_per_instr;
    m.account_cycles(addr, size, n);
    if vfp && !m.fpu_enabled() {
        // The block's FP instruction would raise NOCP on silicon (CPACR CP10/11 off).
        m.fault = Some(Fault::NoCoprocessor(addr));
        let _ = uc.emu_stop();
        return;
    }
    if m.is_idle_branch(addr, size) {
        // `b .`: nothing runs until the next event (step skips the time).
        m.idle = true;
        let _ = uc.emu_stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bitband_alias_maps_to_word_and_bit() {
        // RCC_AHB2ENR (0x4002_104C) bit 0: 0x4200_0000 + 0x2104C·32 + 0·4.
        assert_eq!(bitband(0x2104C * 32), (0x4002_104C, 0));
        assert_eq!(bitband(0x2104C * 32 + 2 * 4), (0x4002_104C, 2));
        assert_eq!(bitband(0x2104D * 32 + 4), (0x4002_104C, 9));
    }
}

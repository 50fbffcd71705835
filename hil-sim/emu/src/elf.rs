//! The firmware image: loaded by physical address (LMA, where `.data`'s initial values
//! sit in flash) exactly as a probe would flash it, and its symbols.

use anyhow::{bail, Context, Result};
use object::{Object, ObjectSegment, ObjectSymbol};

/// Flash of the STM32G474RE: 512 KiB at 0x0800_0000 (RM0440 §3.3.1), two banks in
/// dual-bank mode.
pub const FLASH_BASE: u32 = 0x0800_0000;
pub const FLASH_BYTES: u32 = 512 * 1024;

pub struct Image {
    /// The whole flash as programmed: erased (0xFF) where the ELF puts nothing.
    pub flash: Vec<u8>,
    /// `_SEGGER_RTT`, the RTT control block.
    pub rtt_block: Option<u32>,
    /// Address of `_calib_start` (the calibration pages), if the ELF has it.
    pub calib_start: Option<u32>,
}

pub fn load(elf: &[u8]) -> Result<Image> {
    let file = object::File::parse(elf).context("not an ELF file")?;
    let mut flash = vec![0xFF; FLASH_BYTES as usize];
    let mut loaded = 0;
    for seg in file.segments() {
        let data = seg.data().context("segment data")?;
        if data.is_empty() {
            continue;
        }
        // The load address: object's `address()` is p_vaddr; the image goes where the
        // probe writes it, p_paddr.
        let paddr = match &file {
            object::File::Elf32(f) => {
                use object::read::elf::ProgramHeader;
                let e = f.endian();
                let i = f
                    .elf_program_headers()
                    .iter()
                    .find(|h| {
                        h.p_vaddr(e) as u64 == seg.address() && h.p_filesz(e) as usize == data.len()
                    })
                    .context("program header of a segment")?;
                i.p_paddr(e)
            }
            _ => bail!("not a 32-bit ELF: the firmware is built for thumbv7em"),
        };
        let start = paddr
            .checked_sub(FLASH_BASE)
            .filter(|o| (*o as usize + data.len()) <= flash.len())
            .with_context(|| format!("segment at {paddr:#010x} is outside the 512 KiB flash"))?;
        flash[start as usize..start as usize + data.len()].copy_from_slice(data);
        loaded += data.len();
    }
    if loaded == 0 {
        bail!("the ELF has nothing to flash");
    }
    let sym = |name: &str| {
        file.symbols()
            .find(|s| s.name() == Ok(name))
            .map(|s| s.address() as u32)
    };
    Ok(Image {
        flash,
        rtt_block: sym("_SEGGER_RTT"),
        calib_start: sym("_calib_start"),
    })
}

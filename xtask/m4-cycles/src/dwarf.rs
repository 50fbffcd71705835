//! Inlined call chains from the ELF's DWARF (gimli's addr2line).

use crate::disasm::demangle;
use crate::{Error, Frame};
use addr2line::gimli;
use object::{Object, ObjectSection, ObjectSymbol};
use std::borrow::Cow;
use std::collections::HashMap;

/// The DWARF of one ELF, ready for look-ups, and its function symbols for the code the
/// DWARF does not describe (assembly, padding).
pub struct Chains<'a> {
    context: addr2line::Context<gimli::EndianSlice<'a, gimli::LittleEndian>>,
    /// (start, end, name) by start.
    symbols: Vec<(u32, u32, String)>,
}

/// The function symbols of `file` by start (Thumb bit cleared).
fn function_symbols(file: &object::File<'_>) -> Vec<(u32, u32, String)> {
    let mut symbols: Vec<_> = file
        .symbols()
        .filter(|s| s.kind() == object::SymbolKind::Text)
        .filter_map(|s| {
            let start = s.address() as u32 & !1;
            Some((start, start + s.size() as u32, demangle(s.name().ok()?)))
        })
        .filter(|s| !s.2.starts_with('$'))
        .collect();
    symbols.sort();
    symbols
}

/// The DWARF sections of an ELF, owned where they had to be decompressed.
fn sections(elf: &[u8]) -> Result<gimli::DwarfSections<Cow<'_, [u8]>>, Error> {
    let file = object::File::parse(elf)?;
    let dwarf = gimli::DwarfSections::load(|id| -> Result<Cow<'_, [u8]>, Error> {
        Ok(match file.section_by_name(id.name()) {
            Some(s) => s.uncompressed_data()?,
            None => Cow::Borrowed(&[]),
        })
    })?;
    Ok(dwarf)
}

/// The symbol binutils names code without DWARF after: the function that holds `pc`,
/// else the nearest one below it. `symbols`: (start, end, name) by start.
fn nearest_symbol(symbols: &[(u32, u32, String)], pc: u32) -> Option<&str> {
    let candidates = &symbols[..symbols.partition_point(|s| s.0 <= pc)];
    candidates
        .iter()
        .rev()
        .find(|s| pc < s.1)
        .or(candidates.last())
        .map(|s| s.2.as_str())
}

impl<'a> Chains<'a> {
    /// Over `dwarf`, which the caller keeps, and the symbols of `elf`.
    fn new(dwarf: &'a gimli::DwarfSections<Cow<'a, [u8]>>, elf: &[u8]) -> Result<Self, Error> {
        let borrowed = dwarf.borrow(|s| gimli::EndianSlice::new(s, gimli::LittleEndian));
        Ok(Self {
            context: addr2line::Context::from_dwarf(borrowed)?,
            symbols: function_symbols(&object::File::parse(elf)?),
        })
    }

    /// The inlined call chain of `pc`, innermost frame first: what binutils'
    /// `addr2line -f -i -C` prints: where the DWARF names no function, the symbol's name
    /// (`??` without one), and `??:?` where it has no line.
    pub fn chain(&self, pc: u32) -> Result<Vec<Frame>, Error> {
        let mut frames = self.context.find_frames(u64::from(pc)).skip_all_loads()?;
        let mut chain = Vec::new();
        while let Some(f) = frames.next()? {
            let function = match &f.function {
                Some(name) => demangle(&name.raw_name()?),
                None => nearest_symbol(&self.symbols, pc)
                    .unwrap_or("??")
                    .to_string(),
            };
            let location = match &f.location {
                Some(l) => format!(
                    "{}:{}",
                    l.file.unwrap_or("??"),
                    l.line.map_or("?".to_string(), |n| n.to_string())
                ),
                None => "??:0".to_string(),
            };
            chain.push(Frame { function, location });
        }
        if chain.is_empty() {
            chain.push(Frame {
                function: nearest_symbol(&self.symbols, pc)
                    .unwrap_or("??")
                    .to_string(),
                location: "??:?".into(),
            });
        }
        Ok(chain)
    }
}

/// The inlined call chain of each of `pcs` from the DWARF of `elf`, innermost first.
pub fn chains_of_elf(elf: &[u8], pcs: &[u32]) -> Result<HashMap<u32, Vec<Frame>>, Error> {
    let dwarf = sections(elf)?;
    let chains = Chains::new(&dwarf, elf)?;
    pcs.iter().map(|&pc| Ok((pc, chains.chain(pc)?))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Not inlined, so that it has a frame of its own in this test binary's DWARF.
    #[inline(never)]
    fn a_function_with_a_frame(x: u32) -> u32 {
        std::hint::black_box(x).wrapping_mul(3)
    }

    /// The DWARF path on a real ELF: this test binary's own (host code, with the debug
    /// info every profile here keeps), at the link address of a function of this file.
    #[test]
    fn chains_name_the_function_and_its_file_from_the_dwarf() {
        assert_eq!(a_function_with_a_frame(2), 6);
        let exe = std::fs::read(std::env::current_exe().unwrap()).unwrap();
        let file = object::File::parse(&*exe).unwrap();
        let symbol = file
            .symbols()
            .find(|s| {
                s.name()
                    .is_ok_and(|n| demangle(n).ends_with("dwarf::tests::a_function_with_a_frame"))
            })
            .expect("the function's symbol");
        let pc = u32::try_from(symbol.address()).expect("a link address below 4 GiB");
        let chains = chains_of_elf(&exe, &[pc]).unwrap();
        // Outermost last: an optimised build may have inlined `black_box` at the entry.
        // Its name is the linkage name's path where the DWARF has one (full debug info),
        // the bare name in line tables only (the host profile's).
        let outer = chains[&pc].last().expect("a frame");
        assert!(
            [
                "m4_cycles::dwarf::tests::a_function_with_a_frame",
                "a_function_with_a_frame"
            ]
            .contains(&outer.function.as_str()),
            "{:?}",
            chains[&pc]
        );
        assert!(
            outer.location.contains("m4-cycles/src/dwarf.rs:"),
            "{:?}",
            chains[&pc]
        );
    }

    #[test]
    fn code_without_dwarf_takes_the_symbol_that_holds_it_or_the_one_below() {
        let symbols = [
            (0x100, 0x106, "mras_vsqrt_f32".to_string()),
            (0x108, 0x200, "ADC1_2".to_string()),
            (0x108, 0x108, "alias".to_string()),
        ];
        assert_eq!(nearest_symbol(&symbols, 0x104), Some("mras_vsqrt_f32"));
        // Padding after a function: the one below.
        assert_eq!(nearest_symbol(&symbols, 0x106), Some("mras_vsqrt_f32"));
        assert_eq!(nearest_symbol(&symbols, 0x108), Some("ADC1_2"));
        assert_eq!(nearest_symbol(&symbols, 0xfe), None);
    }
}

//! `cargo xtask regs [--check]`: the STM32G474 register table of the emulator
//! (`hil-sim/emu/src/regs_g474.rs`), generated from the sources of the stm32g4 0.16.0 PAC
//! (svd2rust's output for ST's SVD): each register's address, reset value, and write
//! semantics (which bits are write-1-to-set, write-1-to-clear, write-0-to-clear, toggle or
//! read-only).
//!
//! The PAC's sources are read as text, in the shapes svd2rust 0.3x writes them:
//! `mod.rs` names each peripheral's module and base address; a module's `RegisterBlock`
//! struct gives the layout (offsets from the field sizes, cross-checked against the offsets
//! in the accessors' doc comments); each register's file gives its width, reset value,
//! readability and writability, and its fields: readers (offset and mask from the reader
//! method's expression) and writers (offset from the writer method, kind and width from the
//! writer's type, followed through `pub use` aliases). Whatever this parser does not know
//! either fails loudly (a layout it cannot place) or is named in the generated file (a
//! field it cannot place, treated as plain writable).
//!
//! `--check` regenerates in memory and fails if the committed file differs.

use anyhow::{anyhow, bail, Context, Result};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::{cargo, root};

const PAC: &str = "stm32g4";
const PAC_VERSION: &str = "0.16.0";
/// The device's directory in the PAC's `src/`.
const DEVICE: &str = "stm32g474";
/// The generated file, relative to the workspace root.
pub(crate) const OUTPUT: &str = "hil-sim/emu/src/regs_g474.rs";
/// The peripherals of the table, as `mod.rs` names them.
const PERIPHERALS: &[&str] = &[
    "RCC",
    "PWR",
    "FLASH",
    "ADC1",
    "ADC2",
    "ADC12_COMMON",
    "TIM1",
    "CORDIC",
    "IWDG",
    "GPIOA",
    "GPIOB",
    "GPIOC",
    "SYSCFG",
    "DBGMCU",
    "USART1",
    "USART2",
    "EXTI",
    "CRC",
];

/// `cargo xtask regs [--check]`.
pub(crate) fn main(args: &[String]) -> Result<()> {
    let check = match args {
        [] => false,
        [a] if a == "--check" => true,
        _ => {
            bail!("usage: cargo xtask regs [--check] (unexpected arguments {args:?})")
        }
    };
    let dir = pac_dir()?;
    eprintln!("xtask regs: reading {}", dir.display());
    let table = generate(&Dir(dir))?;
    for w in &table.warnings {
        eprintln!("xtask regs: warning: {w}");
    }
    let path = root().join(OUTPUT);
    let summary = format!(
        "{} peripherals, {} registers, {} warnings",
        table.periphs,
        table.regs,
        table.warnings.len()
    );
    if check {
        let committed = std::fs::read_to_string(&path).map_err(|e| {
            anyhow!(
                "{}: {e}; run `cargo xtask regs` and commit the file",
                path.display()
            )
        })?;
        if committed != table.text {
            let line = committed
                .lines()
                .zip(table.text.lines())
                .position(|(a, b)| a != b)
                .unwrap_or(committed.lines().count().min(table.text.lines().count()))
                + 1;
            bail!(
                "{OUTPUT} differs from what the {PAC} {PAC_VERSION} PAC generates (first at line {line}): \
                 it was edited by hand or the generator changed; run `cargo xtask regs` and commit the result"
            );
        }
        eprintln!("xtask regs: {OUTPUT} is up to date ({summary})");
        return Ok(());
    }
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).with_context(|| parent.display().to_string())?;
    }
    std::fs::write(&path, &table.text).with_context(|| path.display().to_string())?;
    eprintln!("xtask regs: wrote {OUTPUT} ({summary})");
    // The generator emits rustfmt's layout itself (so `--check` needs no rustfmt); confirm it.
    match Command::new("rustfmt")
        .args(["--edition", "2021", "--check"])
        .arg(&path)
        .output()
    {
        Ok(out) if out.status.success() => Ok(()),
        Ok(out) => Err(anyhow!(
            "the generator's layout is not rustfmt's (a bug in xtask/src/regs.rs):\n{}",
            String::from_utf8_lossy(&out.stdout)
        )),
        Err(e) => {
            eprintln!("xtask regs: warning: cannot run rustfmt to confirm the layout: {e}");
            Ok(())
        }
    }
}

/// `<stm32g4 0.16.0>/src/stm32g474`, from `cargo metadata`.
fn pac_dir() -> Result<PathBuf> {
    let mut c = cargo();
    c.args(["metadata", "--format-version", "1", "--locked"]);
    let out = c.output().context("cannot start cargo metadata")?;
    if !out.status.success() {
        bail!(
            "cargo metadata failed ({}):\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let meta: serde_json::Value =
        serde_json::from_slice(&out.stdout).context("cargo metadata: invalid JSON")?;
    let packages = meta
        .get("packages")
        .and_then(|p| p.as_array())
        .ok_or_else(|| anyhow!("cargo metadata: no \"packages\" array"))?;
    let manifest = packages
        .iter()
        .find(|p| {
            p.get("name").and_then(|n| n.as_str()) == Some(PAC)
                && p.get("version").and_then(|v| v.as_str()) == Some(PAC_VERSION)
        })
        .and_then(|p| p.get("manifest_path"))
        .and_then(|m| m.as_str())
        .ok_or_else(|| {
            anyhow!("cargo metadata: no package {PAC} {PAC_VERSION} in the dependency graph")
        })?;
    let dir = Path::new(manifest)
        .parent()
        .ok_or_else(|| anyhow!("{manifest}: no parent directory"))?
        .join("src")
        .join(DEVICE);
    if !dir.join("mod.rs").is_file() {
        bail!("{}: no mod.rs", dir.display());
    }
    Ok(dir)
}

/// The PAC's device directory, by path relative to it (a directory, or inline in tests).
trait Files {
    fn read(&self, rel: &str) -> Result<String>;
}

struct Dir(PathBuf);

impl Files for Dir {
    fn read(&self, rel: &str) -> Result<String> {
        let path = self.0.join(rel);
        std::fs::read_to_string(&path).with_context(|| path.display().to_string())
    }
}

/// The generated file and what it holds.
struct Table {
    text: String,
    periphs: usize,
    regs: usize,
    warnings: Vec<String>,
}

struct PeriphOut {
    name: String,
    base: u32,
    size: u32,
}

struct RegOut {
    addr: u32,
    periph: String,
    name: String,
    bits: RegBits,
}

fn generate(files: &dyn Files) -> Result<Table> {
    let decls = parse_periph_decls(&files.read("mod.rs")?)?;
    let mut warnings = Vec::new();
    let mut periphs = Vec::new();
    let mut regs = Vec::new();
    let mut reg_files: HashMap<(String, String), RegFile> = HashMap::new();
    for &name in PERIPHERALS {
        let (module, base) = decls
            .get(name)
            .ok_or_else(|| anyhow!("mod.rs: no `pub type {name} = crate::Periph<..>`"))?;
        let ctx = || format!("{name} ({module}.rs)");
        let mut block =
            parse_block(&files.read(&format!("{module}.rs"))?, module).with_context(ctx)?;
        resolve_foreign(files, &mut block).with_context(ctx)?;
        // Parse every register file of the block once; the layout needs their widths.
        for r in block.reg_types.values() {
            let key = (r.module.clone(), r.file.clone());
            if let std::collections::hash_map::Entry::Vacant(slot) = reg_files.entry(key) {
                let rel = format!("{}/{}.rs", r.module, r.file);
                let text = files.read(&rel)?;
                let parsed = parse_reg_file(&text, &r.spec).with_context(|| rel.clone())?;
                slot.insert(parsed);
            }
        }
        let reg_file = |ty: &str| -> Result<(&RegRef, &RegFile)> {
            let r = block
                .reg_types
                .get(ty)
                .ok_or_else(|| anyhow!("no `pub type {ty} = crate::Reg<..>`"))?;
            let rf = reg_files
                .get(&(r.module.clone(), r.file.clone()))
                .ok_or_else(|| anyhow!("{}/{}.rs not read", r.module, r.file))?;
            Ok((r, rf))
        };
        let size_of = |ty: &str| reg_file(ty).map(|(_, rf)| rf.ux_bits / 8);
        let slots = layout(&block, &size_of).with_context(ctx)?;
        let mut end = 0u32;
        for slot in &slots {
            let mut views = Vec::new();
            for ty in &slot.views {
                let (r, rf) = reg_file(ty).with_context(ctx)?;
                let what = format!("{name}.{}", ty);
                let bits = reg_bits(files, &r.module, &r.file, rf, &what, &mut warnings)?;
                views.push((ty.clone(), bits));
            }
            let what = format!("{name}.{}", slot.name);
            let bits = merge_views(&what, views, &mut warnings)?;
            end = end.max(slot.offset.saturating_add(bits.ux_bits / 8));
            let addr = base
                .checked_add(slot.offset)
                .ok_or_else(|| anyhow!("{what}: address overflows"))?;
            regs.push(RegOut {
                addr,
                periph: name.to_string(),
                name: slot.name.clone(),
                bits,
            });
        }
        periphs.push(PeriphOut {
            name: name.to_string(),
            base: *base,
            size: end
                .checked_next_multiple_of(4)
                .ok_or_else(|| anyhow!("{name}: size overflows"))?,
        });
    }
    periphs.sort_by_key(|p| p.base);
    for w in periphs.windows(2) {
        if u64::from(w[0].base) + u64::from(w[0].size) > u64::from(w[1].base) {
            bail!("{} and {} overlap", w[0].name, w[1].name);
        }
    }
    regs.sort_by_key(|r| r.addr);
    for w in regs.windows(2) {
        if w[0].addr == w[1].addr {
            bail!(
                "{}.{} and {}.{} share the address {:#010x}",
                w[0].periph,
                w[0].name,
                w[1].periph,
                w[1].name,
                w[0].addr
            );
        }
    }
    Ok(Table {
        text: render(&periphs, &regs),
        periphs: periphs.len(),
        regs: regs.len(),
        warnings,
    })
}

fn hex(v: u32) -> String {
    format!("0x{:04x}_{:04x}", v >> 16, v & 0xffff)
}

/// The generated file, in rustfmt's layout.
fn render(periphs: &[PeriphOut], regs: &[RegOut]) -> String {
    let mut s = String::new();
    s.push_str(
        "//! The STM32G474's registers as the stm32g4 0.16.0 PAC (svd2rust, from ST's SVD)\n\
         //! describes them: address, reset value, write semantics. Generated by\n\
         //! `cargo xtask regs`; do not edit.\n\
         use crate::regfile::{PeriphDef, RegDef};\n\
         \n\
         pub static PERIPHS: &[PeriphDef] = &[\n",
    );
    for p in periphs {
        s.push_str(&format!(
            "    PeriphDef {{\n        name: \"{}\",\n        base: {},\n        size: {},\n    }},\n",
            p.name,
            hex(p.base),
            hex(p.size)
        ));
    }
    s.push_str("];\n\npub static REGS: &[RegDef] = &[\n");
    for r in regs {
        let b = &r.bits;
        for note in &b.notes {
            s.push_str(&format!("    // {}.{}: {note}\n", r.periph, r.name));
        }
        s.push_str(&format!(
            "    RegDef {{\n        addr: {},\n        periph: \"{}\",\n        name: \"{}\",\n        \
             reset: {},\n        readable: {},\n        writable: {},\n        w1s: {},\n        \
             w1c: {},\n        w0c: {},\n        w1t: {},\n        read_only_bits: {},\n    }},\n",
            hex(r.addr),
            r.periph,
            r.name,
            hex(b.reset),
            b.readable,
            b.writable,
            hex(b.w1s),
            hex(b.w1c),
            hex(b.w0c),
            hex(b.w1t),
            hex(b.read_only_bits()),
        ));
    }
    s.push_str("];\n");
    s
}

// ---------------------------------------------------------------------------------------
// Text helpers

/// An integer literal: `0x2000_0000`, `16`.
/// An integer literal the generator cannot use.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum IntError {
    #[error("not an integer literal: `{0}`")]
    NotInteger(String),
    #[error("`{0}` does not fit 32 bits")]
    TooWide(String),
}

fn parse_int(s: &str) -> Result<u64, IntError> {
    let t = s.trim().replace('_', "");
    let r = match t.strip_prefix("0x") {
        Some(h) => u64::from_str_radix(h, 16),
        None => t.parse::<u64>(),
    };
    r.map_err(|_| IntError::NotInteger(s.to_string()))
}

fn parse_u32(s: &str) -> Result<u32, IntError> {
    u32::try_from(parse_int(s)?).map_err(|_| IntError::TooWide(s.to_string()))
}

/// Top-level statements starting with `prefix` (`pub type `, `pub use `), each on one line
/// with its whitespace collapsed.
fn statements(text: &str, prefix: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur: Option<String> = None;
    for line in text.lines() {
        if cur.is_none() && line.starts_with(prefix) {
            cur = Some(String::new());
        }
        if let Some(c) = cur.as_mut() {
            c.push(' ');
            c.push_str(line.trim());
            if line.trim_end().ends_with(';') {
                out.push(c.split_whitespace().collect::<Vec<_>>().join(" "));
                cur = None;
            }
        }
    }
    out
}

/// The lines inside the top-level block opened by the line `header` (e.g. `impl R {`),
/// up to its closing `}` at column 0; `Some(empty)` for `header}` on one line.
fn block<'a>(text: &'a str, header: &str) -> Option<Vec<&'a str>> {
    let mut lines = text.lines();
    loop {
        let line = lines.next()?.trim_end();
        if line == header {
            break;
        }
        if line.strip_suffix('}') == Some(header) {
            return Some(Vec::new());
        }
    }
    let mut body = Vec::new();
    for line in lines {
        if line.trim_end() == "}" {
            return Some(body);
        }
        body.push(line);
    }
    None
}

/// A method in an impl block: its doc lines and its text on one line.
#[derive(Debug)]
struct Item {
    docs: Vec<String>,
    text: String,
}

fn items(lines: &[&str]) -> Vec<Item> {
    let mut out = Vec::new();
    let mut docs = Vec::new();
    let mut cur: Option<(String, i64)> = None;
    for line in lines {
        let t = line.trim();
        if let Some((text, depth)) = cur.as_mut() {
            text.push(' ');
            text.push_str(t);
            *depth += t.matches('{').count() as i64 - t.matches('}').count() as i64;
            if *depth <= 0 {
                let (text, _) = cur.take().unwrap_or_default();
                out.push(Item {
                    docs: std::mem::take(&mut docs),
                    text,
                });
            }
        } else if let Some(d) = t.strip_prefix("///") {
            docs.push(d.to_string());
        } else if t.starts_with("pub ") {
            let depth = t.matches('{').count() as i64 - t.matches('}').count() as i64;
            if depth <= 0 && t.ends_with('}') {
                out.push(Item {
                    docs: std::mem::take(&mut docs),
                    text: t.to_string(),
                });
            } else {
                cur = Some((t.to_string(), depth));
            }
        }
    }
    out
}

/// The text between the `(` at `open` and its matching `)`.
fn balanced(s: &str, open: usize) -> Option<&str> {
    let mut depth = 0;
    for (i, c) in s[open..].char_indices() {
        match c {
            '(' => depth += 1,
            ')' => {
                depth -= 1;
                if depth == 0 {
                    return Some(&s[open + 1..open + i]);
                }
            }
            _ => {}
        }
    }
    None
}

// ---------------------------------------------------------------------------------------
// mod.rs and the register blocks

/// `pub type ADC1 = crate::Periph<adc1::RegisterBlock, 0x5000_0000>;` → ADC1 → (adc1, base).
fn parse_periph_decls(mod_rs: &str) -> Result<BTreeMap<String, (String, u32)>> {
    let mut out = BTreeMap::new();
    for st in statements(mod_rs, "pub type ") {
        let Some((lhs, rhs)) = st.split_once(" = ") else {
            continue;
        };
        let Some(inner) = rhs
            .strip_prefix("crate::Periph<")
            .and_then(|r| r.strip_suffix(">;"))
        else {
            continue;
        };
        let name = lhs.trim_start_matches("pub type ").trim();
        let (path, base) = inner
            .split_once(',')
            .ok_or_else(|| anyhow!("mod.rs: cannot read `{st}`"))?;
        let module = path
            .trim()
            .strip_suffix("::RegisterBlock")
            .filter(|m| !m.contains("::"))
            .ok_or_else(|| anyhow!("mod.rs: cannot read the module of `{st}`"))?;
        let base = parse_u32(base).with_context(|| format!("mod.rs: `{st}`"))?;
        out.insert(name.to_string(), (module.to_string(), base));
    }
    Ok(out)
}

#[derive(Debug, Clone, PartialEq)]
enum FieldTy {
    /// A register (its type name, e.g. `CR`).
    Reg(String),
    /// `[OFR; 4]`.
    Array(String, u32),
    /// `[u8; 0x04]`: reserved bytes, or an alias slot (`_reserved_6_ccmr1`).
    Bytes(u32),
}

#[derive(Debug, Clone, PartialEq)]
enum AccBody {
    /// `&self.cr`
    Field(String),
    /// `&self.ofr[n]`
    Indexed(String),
    /// `self.ofr(2)`
    Element(String, u32),
    /// `unsafe { &*core::ptr::from_ref(self).cast::<u8>().add(24).cast() }`: an alternate
    /// view of the bytes at that offset.
    Cast(u32),
    /// `self.ofr.iter()`
    Iter,
}

#[derive(Debug)]
struct Accessor {
    name: String,
    /// The doc comment's `0x08` or `0x60..0x70`.
    doc: Option<(u32, Option<u32>)>,
    ret: String,
    body: AccBody,
}

#[derive(Debug)]
struct Block {
    fields: Vec<(String, FieldTy)>,
    /// `pub type CR = crate::Reg<cr::CRrs>;` → CR → (this module, cr, CRrs); also
    /// `pub use CCR as CCR6;`.
    reg_types: HashMap<String, RegRef>,
    /// `pub use crate::stm32g474::gpioa::OTYPER;`: (name here, module, name there), for
    /// [`resolve_foreign`] to add to `reg_types`.
    foreign: Vec<(String, String, String)>,
    accessors: Vec<Accessor>,
}

/// Where a register type is defined: `<module>/<file>.rs`, `pub struct <spec>;`.
#[derive(Debug, Clone, PartialEq)]
struct RegRef {
    module: String,
    file: String,
    spec: String,
}

/// A module file's `pub type CR = crate::Reg<cr::CRrs>;` statements.
fn parse_reg_types(text: &str, module: &str) -> Result<HashMap<String, RegRef>> {
    let mut reg_types = HashMap::new();
    for st in statements(text, "pub type ") {
        let Some((lhs, rhs)) = st.split_once(" = ") else {
            continue;
        };
        let Some(inner) = rhs
            .strip_prefix("crate::Reg<")
            .and_then(|r| r.strip_suffix(">;"))
        else {
            continue;
        };
        let (file, spec) = inner
            .split_once("::")
            .filter(|(_, s)| !s.contains("::"))
            .ok_or_else(|| anyhow!("cannot read `{st}`"))?;
        let name = lhs.trim_start_matches("pub type ").trim();
        let r = RegRef {
            module: module.to_string(),
            file: file.to_string(),
            spec: spec.to_string(),
        };
        reg_types.insert(name.to_string(), r);
    }
    Ok(reg_types)
}

/// Add the register types a block takes from other modules to its `reg_types`.
fn resolve_foreign(files: &dyn Files, block: &mut Block) -> Result<()> {
    for (here, module, there) in std::mem::take(&mut block.foreign) {
        let other = parse_reg_types(&files.read(&format!("{module}.rs"))?, &module)
            .with_context(|| format!("{module}.rs"))?;
        let r = other.get(&there).ok_or_else(|| {
            anyhow!(
            "`pub use crate::{DEVICE}::{module}::{there}`: {module}.rs defines no register {there}"
        )
        })?;
        block.reg_types.insert(here, r.clone());
    }
    Ok(())
}

/// A register of the table: its offset in the block, name and type(s) (more than one for
/// alternate views of the same bytes).
#[derive(Debug, PartialEq)]
struct Slot {
    offset: u32,
    name: String,
    views: Vec<String>,
}

fn parse_block(text: &str, module: &str) -> Result<Block> {
    let struct_lines = block(text, "pub struct RegisterBlock {")
        .ok_or_else(|| anyhow!("no `pub struct RegisterBlock {{`"))?;
    let mut fields = Vec::new();
    for line in struct_lines {
        let t = line.trim();
        if t.is_empty() || t.starts_with("//") || t.starts_with("#[") {
            continue;
        }
        let (name, ty) = t
            .trim_end_matches(',')
            .split_once(':')
            .ok_or_else(|| anyhow!("RegisterBlock: cannot read the field `{t}`"))?;
        let ty = ty.trim();
        let fty = if let Some(arr) = ty.strip_prefix('[').and_then(|a| a.strip_suffix(']')) {
            let (elem, n) = arr
                .split_once(';')
                .ok_or_else(|| anyhow!("RegisterBlock: cannot read the type `{ty}`"))?;
            let n = parse_u32(n).with_context(|| format!("RegisterBlock: `{t}`"))?;
            match elem.trim() {
                "u8" => FieldTy::Bytes(n),
                e => FieldTy::Array(e.to_string(), n),
            }
        } else {
            FieldTy::Reg(ty.to_string())
        };
        fields.push((name.trim().to_string(), fty));
    }
    let mut reg_types = parse_reg_types(text, module)?;
    let mut foreign = Vec::new();
    for st in statements(text, "pub use ") {
        let body = st.trim_start_matches("pub use ").trim_end_matches(';');
        let (path, alias) = match body.split_once(" as ") {
            Some((p, a)) => (p.trim(), Some(a.trim())),
            None => (body.trim(), None),
        };
        let segs: Vec<&str> = path.split("::").collect();
        let Some(name) = segs.last().copied() else {
            continue;
        };
        // Lower-case names are the register modules that come with the types.
        if !name.starts_with(|c: char| c.is_ascii_uppercase()) {
            continue;
        }
        let here = alias.unwrap_or(name).to_string();
        match segs.as_slice() {
            [n] => {
                let r = reg_types
                    .get(*n)
                    .cloned()
                    .ok_or_else(|| anyhow!("`{st}`: no register type {n} here"))?;
                reg_types.insert(here, r);
            }
            ["crate", d, m, n] if *d == DEVICE => {
                foreign.push((here, m.to_string(), n.to_string()));
            }
            _ => bail!("cannot follow `{st}`"),
        }
    }
    let impl_lines =
        block(text, "impl RegisterBlock {").ok_or_else(|| anyhow!("no `impl RegisterBlock {{`"))?;
    let mut accessors = Vec::new();
    for item in items(&impl_lines) {
        accessors.push(parse_accessor(&item)?);
    }
    Ok(Block {
        fields,
        reg_types,
        foreign,
        accessors,
    })
}

fn parse_accessor(item: &Item) -> Result<Accessor> {
    let t = &item.text;
    let bad = || format!("RegisterBlock: cannot read the accessor `{t}`");
    let sig = t
        .strip_prefix("pub const fn ")
        .or_else(|| t.strip_prefix("pub fn "))
        .with_context(bad)?;
    let name = sig.split('(').next().with_context(bad)?.trim().to_string();
    let (head, body) = sig.split_once('{').with_context(bad)?;
    let ret = head
        .split_once("->")
        .with_context(bad)?
        .1
        .trim()
        .trim_start_matches('&')
        .to_string();
    let body = body.trim().strip_suffix('}').with_context(bad)?.trim();
    let body = if ret.starts_with("impl ") || body.contains(".iter()") {
        AccBody::Iter
    } else if let Some(f) = body.strip_prefix("&self.") {
        match f.strip_suffix("[n]") {
            Some(a) => AccBody::Indexed(a.to_string()),
            None => AccBody::Field(f.to_string()),
        }
    } else if body.starts_with("unsafe {") && body.contains("core::ptr::from_ref(self)") {
        match body.find(".add(") {
            Some(i) => {
                let n = balanced(body, i + 4).with_context(bad)?;
                AccBody::Cast(parse_u32(n).with_context(bad)?)
            }
            None if body.contains(".cast::<u8>().cast()") => AccBody::Cast(0),
            None => bail!(bad()),
        }
    } else if let Some(call) = body.strip_prefix("self.") {
        let (arr, rest) = call.split_once('(').with_context(bad)?;
        let idx = rest.strip_suffix(')').with_context(bad)?;
        AccBody::Element(arr.to_string(), parse_u32(idx).with_context(bad)?)
    } else {
        bail!(
            "{} (a cluster or an accessor shape this generator does not know)",
            bad()
        );
    };
    let mut doc = None;
    if let Some(d) = item
        .docs
        .iter()
        .map(|d| d.trim())
        .find(|d| d.starts_with("0x"))
    {
        let range = d.split(" - ").next().unwrap_or(d).trim();
        doc = Some(match range.split_once("..") {
            Some((a, b)) => (parse_u32(a)?, Some(parse_u32(b)?)),
            None => (parse_u32(range)?, None),
        });
    }
    Ok(Accessor {
        name,
        doc,
        ret,
        body,
    })
}

/// `_reserved_6_ccmr1` → `ccmr1`: the slot of svd2rust's alternate register views.
fn alias_slot_name(field: &str) -> Option<&str> {
    let rest = field.strip_prefix("_reserved_")?;
    let (idx, name) = rest.split_once('_')?;
    (!idx.is_empty() && idx.bytes().all(|b| b.is_ascii_digit()) && !name.is_empty()).then_some(name)
}

/// The block's registers at their offsets: fields laid out in order (repr(C)), arrays
/// expanded, alternate views grouped; every offset checked against the accessors' docs.
fn layout(block: &Block, size_of: &dyn Fn(&str) -> Result<u32>) -> Result<Vec<Slot>> {
    // field → (offset, element size, count, type)
    let mut placed: HashMap<&str, (u32, u32, u32, &str)> = HashMap::new();
    let mut alias_slots: Vec<(u32, u32, &str)> = Vec::new();
    let mut slots = Vec::new();
    let mut off = 0u32;
    for (name, ty) in &block.fields {
        let (ty, count) = match ty {
            FieldTy::Bytes(n) => {
                if let Some(alias) = alias_slot_name(name) {
                    alias_slots.push((off, *n, alias));
                }
                off = off
                    .checked_add(*n)
                    .ok_or_else(|| anyhow!("RegisterBlock: offset overflows"))?;
                continue;
            }
            FieldTy::Reg(t) => (t.as_str(), None),
            FieldTy::Array(t, n) => (t.as_str(), Some(*n)),
        };
        if !block.reg_types.contains_key(ty) {
            bail!(
                "RegisterBlock: the field `{name}: {ty}` is not a register (`pub type {ty} = \
                 crate::Reg<..>`): a cluster, which this generator does not handle"
            );
        }
        let size = size_of(ty)?.max(1);
        let n = count.unwrap_or(1);
        let end = off
            .div_ceil(size)
            .checked_mul(size)
            .and_then(|o| Some((o, o.checked_add(n.checked_mul(size)?)?)));
        let Some((start, end)) = end else {
            bail!("RegisterBlock: offset overflows");
        };
        off = start;
        placed.insert(name, (off, size, n, ty));
        for i in 0..n {
            let name = match count {
                None => name.to_uppercase(),
                Some(_) => format!("{}{i}", name.to_uppercase()),
            };
            slots.push(Slot {
                offset: off + i * size,
                name,
                views: vec![ty.to_string()],
            });
        }
        off = end;
    }
    let mut reached: Vec<&str> = Vec::new();
    let mut views: BTreeMap<u32, Vec<String>> = BTreeMap::new();
    for acc in &block.accessors {
        let doc = || {
            acc.doc.ok_or_else(|| {
                anyhow!(
                    "the accessor `{}` has no `///0x..` offset in its doc comment",
                    acc.name
                )
            })
        };
        let mismatch = |doc: u32, code: u32| {
            anyhow!(
                "the accessor `{}`: its doc comment says offset {doc:#x}, the layout gives {code:#x}",
                acc.name
            )
        };
        let find = |f: &str| {
            placed
                .get(f)
                .copied()
                .ok_or_else(|| anyhow!("the accessor `{}` names no register field `{f}`", acc.name))
        };
        match &acc.body {
            AccBody::Iter => {}
            AccBody::Field(f) => {
                let (o, _, _, ty) = find(f)?;
                let (d, _) = doc()?;
                if d != o {
                    return Err(mismatch(d, o));
                }
                if acc.ret != ty {
                    bail!(
                        "the accessor `{}` returns {} but `{f}` is {ty}",
                        acc.name,
                        acc.ret
                    );
                }
                reached.push(f);
            }
            AccBody::Indexed(f) => {
                let (o, size, n, _) = find(f)?;
                let (d, end) = doc()?;
                if d != o {
                    return Err(mismatch(d, o));
                }
                if end != Some(o + n * size) {
                    bail!(
                        "the accessor `{}`: its doc comment's range ends at {end:x?}, the layout at {:#x}",
                        acc.name,
                        o + n * size
                    );
                }
                reached.push(f);
            }
            AccBody::Element(f, i) => {
                let (o, size, n, _) = find(f)?;
                if *i >= n {
                    bail!("the accessor `{}`: index {i} of {n}", acc.name);
                }
                let (d, _) = doc()?;
                if d != o + i * size {
                    return Err(mismatch(d, o + i * size));
                }
                // The PAC's own name of the element (`ofr1` for index 0, as the manual).
                if let Some(s) = slots.iter_mut().find(|s| s.offset == d) {
                    s.name = acc.name.to_uppercase();
                }
            }
            AccBody::Cast(at) => {
                let (d, _) = doc()?;
                if d != *at {
                    return Err(mismatch(d, *at));
                }
                if !block.reg_types.contains_key(&acc.ret) {
                    bail!(
                        "the accessor `{}` returns {}, not a register",
                        acc.name,
                        acc.ret
                    );
                }
                let size = size_of(&acc.ret)?;
                if !alias_slots.iter().any(|&(o, n, _)| o == *at && size <= n) {
                    bail!(
                        "the accessor `{}` views offset {at:#x}, where no `_reserved_N_name` slot of its size is",
                        acc.name
                    );
                }
                views.entry(*at).or_default().push(acc.ret.clone());
            }
        }
    }
    for (name, _) in &block.fields {
        if placed.contains_key(name.as_str()) && !reached.contains(&name.as_str()) {
            bail!("the register field `{name}` has no accessor");
        }
    }
    for (o, _, name) in alias_slots {
        let v = views
            .remove(&o)
            .ok_or_else(|| anyhow!("the slot of `{name}` at {o:#x} has no accessor"))?;
        slots.push(Slot {
            offset: o,
            name: name.to_uppercase(),
            views: v,
        });
    }
    slots.sort_by_key(|s| s.offset);
    Ok(slots)
}

// ---------------------------------------------------------------------------------------
// Register files

/// A writer type as the PAC defines it: one this generator knows, or the name of one it
/// does not (kept for the table's note).
#[derive(Debug, Clone, PartialEq)]
enum WriterType {
    Known(WriterKind),
    Unknown(String),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum WriterKind {
    Plain,
    W1S,
    W1C,
    W0C,
    W1T,
}

#[derive(Debug, Clone, PartialEq)]
enum TypeDef {
    /// `pub type ADEN_W<'a, REG> = crate::BitWriter1S<'a, REG, ADENW>;`: kind (or the
    /// unknown writer's name) and width.
    Writer(WriterType, u32),
    /// `pub use X as Y;`, `pub use super::file::X;`, `pub use crate::<device>::m::file::X;`
    /// (module and file `None` for the same one).
    Use {
        module: Option<String>,
        file: Option<String>,
        name: String,
    },
    /// Anything else (readers, enums, a path this generator does not follow).
    Other(String),
}

/// The `pub type` and `pub use` statements of a register file, by the name they define.
fn parse_types(text: &str) -> HashMap<String, TypeDef> {
    let mut out = HashMap::new();
    for st in statements(text, "pub type ") {
        let Some((lhs, rhs)) = st.split_once(" = ") else {
            continue;
        };
        let name = lhs
            .trim_start_matches("pub type ")
            .split('<')
            .next()
            .unwrap_or("")
            .trim()
            .to_string();
        let rhs = rhs.trim_end_matches(';');
        let head = rhs.split('<').next().unwrap_or(rhs);
        let def = match head.strip_prefix("crate::") {
            Some("FieldWriter") => {
                let args = rhs
                    .split_once('<')
                    .map(|(_, a)| a.trim_end_matches('>'))
                    .unwrap_or("");
                match args.split(',').nth(2).map(parse_u32) {
                    Some(Ok(w)) => TypeDef::Writer(WriterType::Known(WriterKind::Plain), w),
                    _ => TypeDef::Other(rhs.to_string()),
                }
            }
            Some(k) if k.starts_with("BitWriter") => {
                let kind = match k {
                    "BitWriter" => WriterType::Known(WriterKind::Plain),
                    "BitWriter1S" => WriterType::Known(WriterKind::W1S),
                    "BitWriter1C" => WriterType::Known(WriterKind::W1C),
                    "BitWriter0C" => WriterType::Known(WriterKind::W0C),
                    "BitWriter1T" => WriterType::Known(WriterKind::W1T),
                    other => WriterType::Unknown(other.to_string()),
                };
                TypeDef::Writer(kind, 1)
            }
            _ => TypeDef::Other(rhs.to_string()),
        };
        out.insert(name, def);
    }
    for st in statements(text, "pub use ") {
        let body = st.trim_start_matches("pub use ").trim_end_matches(';');
        let (path, alias) = match body.split_once(" as ") {
            Some((p, a)) => (p.trim(), Some(a.trim())),
            None => (body.trim(), None),
        };
        let segs: Vec<&str> = path.split("::").collect();
        let def = match segs.as_slice() {
            [n] => TypeDef::Use {
                module: None,
                file: None,
                name: n.to_string(),
            },
            ["super", f, n] => TypeDef::Use {
                module: None,
                file: Some(f.to_string()),
                name: n.to_string(),
            },
            ["crate", d, m, f, n] if *d == DEVICE => TypeDef::Use {
                module: Some(m.to_string()),
                file: Some(f.to_string()),
                name: n.to_string(),
            },
            _ => TypeDef::Other(path.to_string()),
        };
        let key = alias.or(segs.last().copied()).unwrap_or(path);
        out.insert(key.to_string(), def);
    }
    out
}

/// Bits a reader or writer covers: the register's field methods.
#[derive(Debug, Clone, PartialEq)]
struct Method {
    name: String,
    /// The reader's or writer's type (`ADEN_W`).
    ty: String,
    /// `None`: a single field; `Some(count)` (or an error): a field array taking `n`.
    array: Option<Result<u32, ArrayBoundError>>,
    /// The argument of `TY::new(..)` (for writers without the leading `self, `).
    arg: String,
}

/// A field array whose element count cannot be read: reported when the array is placed
/// (a note in the table), not when the file is parsed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum ArrayBoundError {
    #[error("the field array `{0}` has no `[(); N][n as usize]` bound")]
    Missing(String),
    #[error(transparent)]
    Count(#[from] IntError),
}

fn parse_method(item: &Item, writer: bool) -> Result<Option<Method>> {
    let t = &item.text;
    let bad = || format!("cannot read the method `{t}`");
    let Some(sig) = t.strip_prefix("pub fn ") else {
        return Ok(None);
    };
    let name = sig.split('(').next().unwrap_or("").trim().to_string();
    let params = balanced(sig, sig.find('(').with_context(bad)?).with_context(bad)?;
    let (head, body) = sig.split_once('{').with_context(bad)?;
    let ret = head.split_once("->").with_context(bad)?.1.trim();
    if ret.starts_with("impl ") {
        return Ok(None); // the iterator over a field array
    }
    let ty = ret.split('<').next().unwrap_or(ret).trim().to_string();
    let call = format!("{ty}::new(");
    let Some(at) = body.find(&call) else {
        return Ok(None); // not a field accessor
    };
    let mut arg = balanced(body, at + call.len() - 1)
        .with_context(bad)?
        .trim()
        .to_string();
    if writer {
        arg = arg
            .strip_prefix("self,")
            .with_context(bad)?
            .trim()
            .to_string();
    }
    let array = if params.contains("n:") {
        Some(
            body.split_once("[(); ")
                .and_then(|(_, r)| r.split_once(']'))
                .ok_or_else(|| ArrayBoundError::Missing(name.clone()))
                .and_then(|(n, _)| Ok(parse_u32(n)?)),
        )
    } else {
        None
    };
    Ok(Some(Method {
        name,
        ty,
        array,
        arg,
    }))
}

/// What a register file says about the register.
#[derive(Debug, Clone, PartialEq)]
struct RegFile {
    ux_bits: u32,
    readable: bool,
    writable: bool,
    reset: u32,
    one_to_modify: u32,
    zero_to_modify: u32,
    readers: Vec<Method>,
    writers: Vec<Method>,
    types: HashMap<String, TypeDef>,
}

/// `const NAME: uN = LIT;` among the lines.
fn const_in(lines: &[&str], name: &str) -> Result<Option<u32>> {
    for l in lines {
        let t = l.trim();
        if let Some(rest) = t.strip_prefix(&format!("const {name}:")) {
            let v = rest
                .split_once('=')
                .map(|(_, v)| v.trim().trim_end_matches(';'))
                .ok_or_else(|| anyhow!("cannot read `{t}`"))?;
            return Ok(Some(parse_u32(v)?));
        }
    }
    Ok(None)
}

fn parse_reg_file(text: &str, spec: &str) -> Result<RegFile> {
    if !text
        .lines()
        .any(|l| l.trim() == format!("pub struct {spec};"))
    {
        bail!("no `pub struct {spec};`");
    }
    let spec_lines = block(text, &format!("impl crate::RegisterSpec for {spec} {{"))
        .ok_or_else(|| anyhow!("no `impl crate::RegisterSpec for {spec}`"))?;
    let ux = spec_lines
        .iter()
        .find_map(|l| l.trim().strip_prefix("type Ux = "))
        .ok_or_else(|| anyhow!("{spec}: no `type Ux`"))?;
    let ux_bits = match ux.trim_end_matches(';') {
        "u8" => 8,
        "u16" => 16,
        "u32" => 32,
        other => {
            bail!("{spec}: register width `{other}` (expected u8, u16 or u32)")
        }
    };
    let readable = text.lines().any(|l| {
        l.trim_start()
            .starts_with(&format!("impl crate::Readable for {spec} "))
    });
    let wr = block(text, &format!("impl crate::Writable for {spec} {{"));
    let writable = wr.is_some();
    let wr = wr.unwrap_or_default();
    let one_to_modify = const_in(&wr, "ONE_TO_MODIFY_FIELDS_BITMAP")?.unwrap_or(0);
    let zero_to_modify = const_in(&wr, "ZERO_TO_MODIFY_FIELDS_BITMAP")?.unwrap_or(0);
    let reset = match block(text, &format!("impl crate::Resettable for {spec} {{")) {
        Some(lines) => const_in(&lines, "RESET_VALUE")?.unwrap_or(0),
        None => 0,
    };
    let mut readers = Vec::new();
    if let Some(lines) = block(text, "impl R {") {
        for item in items(&lines) {
            readers.extend(parse_method(&item, false)?);
        }
    }
    let mut writers = Vec::new();
    if let Some(lines) = block(text, "impl W {") {
        for item in items(&lines) {
            writers.extend(parse_method(&item, true)?);
        }
    }
    Ok(RegFile {
        ux_bits,
        readable,
        writable,
        reset,
        one_to_modify,
        zero_to_modify,
        readers,
        writers,
        types: parse_types(text),
    })
}

// ---------------------------------------------------------------------------------------
// The field expressions: `((self.bits >> (n * 2 + 1)) & 3) as u8`, `n * 2 + 1`

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Num(u64),
    Ident(String),
    Sym(&'static str),
}

fn tokenize(s: &str) -> Result<Vec<Tok>> {
    let mut out = Vec::new();
    let b = s.as_bytes();
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c.is_ascii_whitespace() {
            i += 1;
        } else if c.is_ascii_alphanumeric() || c == b'_' {
            let start = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            let w = &s[start..i];
            out.push(if c.is_ascii_digit() {
                Tok::Num(parse_int(w)?)
            } else {
                Tok::Ident(w.to_string())
            });
        } else {
            let sym = ["(", ")", ">>", "&", "*", "+", "!=", "."]
                .into_iter()
                .find(|p| s[i..].starts_with(p))
                .ok_or_else(|| anyhow!("unexpected `{}` in `{s}`", &s[i..]))?;
            out.push(Tok::Sym(sym));
            i += sym.len();
        }
    }
    Ok(out)
}

/// A value of a field expression: an integer, or bits `(self.bits >> shift) & mask`.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Val {
    Int(u64),
    Bits { shift: u32, mask: u64 },
}

struct Eval<'a> {
    toks: &'a [Tok],
    pos: usize,
    n: Option<u64>,
    ux_bits: u32,
}

impl Eval<'_> {
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos)
    }

    fn next(&mut self) -> Option<Tok> {
        let t = self.toks.get(self.pos).cloned();
        self.pos += 1;
        t
    }

    fn primary(&mut self) -> Result<Val> {
        match self.next() {
            Some(Tok::Num(v)) => Ok(Val::Int(v)),
            Some(Tok::Sym("(")) => {
                let v = self.expr(0)?;
                match self.next() {
                    Some(Tok::Sym(")")) => Ok(v),
                    _ => Err(anyhow!("unbalanced parentheses")),
                }
            }
            Some(Tok::Ident(i)) if i == "n" => self
                .n
                .map(Val::Int)
                .ok_or_else(|| anyhow!("`n` outside a field array")),
            Some(Tok::Ident(i)) if i == "self" => match (self.next(), self.next()) {
                (Some(Tok::Sym(".")), Some(Tok::Ident(b))) if b == "bits" => Ok(Val::Bits {
                    shift: 0,
                    mask: (1u64 << self.ux_bits) - 1,
                }),
                _ => Err(anyhow!("`self` not followed by `.bits`")),
            },
            t => Err(anyhow!("unexpected {t:?}")),
        }
    }

    fn expr(&mut self, min: u8) -> Result<Val> {
        let mut lhs = self.primary()?;
        loop {
            match self.peek() {
                Some(Tok::Ident(a)) if a == "as" => {
                    self.pos += 1;
                    let ty = match self.next() {
                        Some(Tok::Ident(t)) => t,
                        t => bail!("`as` followed by {t:?}"),
                    };
                    lhs = match (lhs, ty.as_str()) {
                        (Val::Int(v), _) => Val::Int(v),
                        (Val::Bits { shift, mask }, "u8" | "u16" | "u32" | "u64") => {
                            let w: u32 = ty[1..].parse().unwrap_or(64);
                            let m = if w >= 64 { u64::MAX } else { (1u64 << w) - 1 };
                            Val::Bits {
                                shift,
                                mask: mask & m,
                            }
                        }
                        _ => bail!("`as {ty}` of the register's bits"),
                    };
                }
                Some(Tok::Sym(op)) if *op != "(" && *op != ")" && *op != "." => {
                    let op = *op;
                    let prec = match op {
                        "*" => 5,
                        "+" => 4,
                        ">>" => 3,
                        "&" => 2,
                        _ => 1, // !=
                    };
                    if prec < min {
                        break;
                    }
                    self.pos += 1;
                    let rhs = self.expr(prec + 1)?;
                    lhs = apply(op, lhs, rhs)?;
                }
                _ => break,
            }
        }
        Ok(lhs)
    }
}

fn apply(op: &str, a: Val, b: Val) -> Result<Val> {
    let overflow = || anyhow!("overflow in `{a:?} {op} {b:?}`");
    Ok(match (op, a, b) {
        ("*", Val::Int(x), Val::Int(y)) => Val::Int(x.checked_mul(y).ok_or_else(overflow)?),
        ("+", Val::Int(x), Val::Int(y)) => Val::Int(x.checked_add(y).ok_or_else(overflow)?),
        ("&", Val::Int(x), Val::Int(y)) => Val::Int(x & y),
        (">>", Val::Bits { shift, mask }, Val::Int(s)) if s < 64 => Val::Bits {
            shift: shift + s as u32,
            mask: mask >> s,
        },
        ("&", Val::Bits { shift, mask }, Val::Int(m)) => Val::Bits {
            shift,
            mask: mask & m,
        },
        ("!=", bits @ Val::Bits { .. }, Val::Int(0)) => bits,
        _ => bail!("unsupported `{a:?} {op} {b:?}`"),
    })
}

fn eval(expr: &str, n: Option<u64>, ux_bits: u32) -> Result<Val> {
    let toks = tokenize(expr)?;
    let mut e = Eval {
        toks: &toks,
        pos: 0,
        n,
        ux_bits,
    };
    let v = e.expr(0)?;
    if e.pos != toks.len() {
        bail!("trailing tokens in `{expr}`");
    }
    Ok(v)
}

/// The register bits a reader expression reads.
fn reader_mask(expr: &str, n: Option<u64>, ux_bits: u32) -> Result<u32> {
    match eval(expr, n, ux_bits)? {
        Val::Bits { shift, mask } if shift < 64 => Ok(((mask << shift) & 0xffff_ffff) as u32),
        v => Err(anyhow!("`{expr}` is {v:?}, not the register's bits")),
    }
}

/// The bit offset a writer expression gives.
fn writer_offset(expr: &str, n: Option<u64>) -> Result<u32> {
    match eval(expr, n, 32)? {
        Val::Int(v) if v < 32 => Ok(v as u32),
        v => Err(anyhow!("`{expr}` is {v:?}, not a bit offset")),
    }
}

/// Every element index of a method (`[None]` for a single field).
fn indices(m: &Method) -> Result<Vec<Option<u64>>> {
    match &m.array {
        None => Ok(vec![None]),
        Some(Ok(count)) => Ok((0..u64::from(*count)).map(Some).collect()),
        Some(Err(e)) => Err(e.clone().into()),
    }
}

// ---------------------------------------------------------------------------------------
// Write semantics

/// A register's bits by semantics.
#[derive(Debug, Clone, Default, PartialEq)]
struct RegBits {
    ux_bits: u32,
    readable: bool,
    writable: bool,
    reset: u32,
    read: u32,
    plain: u32,
    w1s: u32,
    w1c: u32,
    w0c: u32,
    w1t: u32,
    /// A writer this generator could not place: no bit is called read-only.
    unplaced_writer: bool,
    /// What the generated file says about the register.
    notes: Vec<String>,
}

impl RegBits {
    fn written(&self) -> u32 {
        self.plain | self.w1s | self.w1c | self.w0c | self.w1t
    }

    /// Bits readers cover and no writer does, in a writable register.
    fn read_only_bits(&self) -> u32 {
        if self.writable && !self.unplaced_writer {
            self.read & !self.written()
        } else {
            0
        }
    }
}

/// Follow a writer type through `pub use` to its `pub type` (at most a few hops).
fn resolve_writer(
    files: &dyn Files,
    module: &str,
    file: &str,
    types: &HashMap<String, TypeDef>,
    name: &str,
) -> Result<(WriterType, u32)> {
    let (mut module, mut file, mut name) = (module.to_string(), file.to_string(), name.to_string());
    let mut other: Option<HashMap<String, TypeDef>> = None;
    for _ in 0..8 {
        let tys = other.as_ref().unwrap_or(types);
        let def = tys.get(&name).cloned().ok_or_else(|| {
            anyhow!("the writer type `{name}` is not defined in {module}/{file}.rs")
        })?;
        match def {
            TypeDef::Writer(kind, width) => return Ok((kind, width)),
            TypeDef::Use {
                module: m,
                file: f,
                name: n,
            } => {
                let (m, f) = (m.unwrap_or(module.clone()), f.unwrap_or(file.clone()));
                name = n;
                if (&m, &f) != (&module, &file) {
                    other = Some(parse_types(&files.read(&format!("{m}/{f}.rs"))?));
                    (module, file) = (m, f);
                }
            }
            TypeDef::Other(rhs) => {
                bail!("the writer type `{name}` is `{rhs}`, not a known writer")
            }
        }
    }
    Err(anyhow!("the writer type `{name}`: too many `pub use` hops"))
}

/// One register file's bits; the ONE/ZERO_TO_MODIFY cross-check warns as `what`.
fn reg_bits(
    files: &dyn Files,
    module: &str,
    file: &str,
    rf: &RegFile,
    what: &str,
    warnings: &mut Vec<String>,
) -> Result<RegBits> {
    let mut b = RegBits {
        ux_bits: rf.ux_bits,
        readable: rf.readable,
        writable: rf.writable,
        reset: rf.reset,
        ..RegBits::default()
    };
    let mut note = |b: &mut RegBits, text: String| {
        warnings.push(format!("{what}: {text}"));
        b.notes.push(text);
    };
    for r in &rf.readers {
        let masks = indices(r).and_then(|ix| {
            ix.into_iter()
                .map(|n| reader_mask(&r.arg, n, rf.ux_bits))
                .collect::<Result<Vec<_>, _>>()
        });
        match masks {
            Ok(ms) => b.read |= ms.into_iter().fold(0, |a, m| a | m),
            Err(e) => note(
                &mut b,
                format!(
                    "reader `{}` not placed ({e:#}); its bits are not called read-only",
                    r.name
                ),
            ),
        }
    }
    for w in &rf.writers {
        let placed =
            resolve_writer(files, module, file, &rf.types, &w.ty).and_then(|(kind, width)| {
                let masks = indices(w)?
                    .into_iter()
                    .map(|n| {
                        let off = writer_offset(&w.arg, n)?;
                        if width == 0 || u64::from(off) + u64::from(width) > u64::from(rf.ux_bits) {
                            bail!("{width} bits at {off}: beyond the register");
                        }
                        Ok((((1u64 << width) - 1) << off) as u32)
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                Ok((kind, masks.into_iter().fold(0, |a, m| a | m)))
            });
        match placed {
            Ok((WriterType::Known(kind), m)) => {
                let slot = match kind {
                    WriterKind::Plain => &mut b.plain,
                    WriterKind::W1S => &mut b.w1s,
                    WriterKind::W1C => &mut b.w1c,
                    WriterKind::W0C => &mut b.w0c,
                    WriterKind::W1T => &mut b.w1t,
                };
                *slot |= m;
            }
            Ok((WriterType::Unknown(unknown), m)) => {
                b.plain |= m;
                note(
                    &mut b,
                    format!(
                        "writer `{}` is a crate::{unknown}, which the table cannot express: treated as plain writable",
                        w.name
                    ),
                );
            }
            Err(e) => {
                b.unplaced_writer = true;
                note(
                    &mut b,
                    format!(
                        "writer `{}` not placed ({e:#}): treated as plain writable, no bit called read-only",
                        w.name
                    ),
                );
            }
        }
    }
    if rf.writable && !b.unplaced_writer {
        let one = b.w1s | b.w1c | b.w1t;
        if one != rf.one_to_modify || b.w0c != rf.zero_to_modify {
            warnings.push(format!(
                "{what}: the fields' w1s|w1c|w1t = {} and w0c = {} but the PAC's ONE_TO_MODIFY = {} and ZERO_TO_MODIFY = {}",
                hex(one),
                hex(b.w0c),
                hex(rf.one_to_modify),
                hex(rf.zero_to_modify)
            ));
        }
    }
    Ok(b)
}

/// One register seen through one or more types (svd2rust's alternate registers, e.g.
/// TIM1's CCMR1 as CCMR1_INPUT and CCMR1_OUTPUT, CRC's DR as DR, DR16 and DR8).
fn merge_views(
    what: &str,
    views: Vec<(String, RegBits)>,
    warnings: &mut Vec<String>,
) -> Result<RegBits> {
    if views.len() == 1 {
        return views
            .into_iter()
            .next()
            .map(|(_, b)| b)
            .ok_or_else(|| anyhow!("{what}: no view"));
    }
    let widest = views
        .iter()
        .map(|(_, b)| b.ux_bits)
        .max()
        .ok_or_else(|| anyhow!("{what}: no view"))?;
    let (_, wide) = views
        .iter()
        .find(|(_, b)| b.ux_bits == widest)
        .ok_or_else(|| anyhow!("{what}: no view"))?;
    let mut m = RegBits {
        ux_bits: widest,
        reset: wide.reset,
        ..RegBits::default()
    };
    let names: Vec<&str> = views.iter().map(|(n, _)| n.as_str()).collect();
    m.notes.push(format!(
        "one register seen as {} (alternate views in the PAC), merged",
        names.join(", ")
    ));
    for (name, b) in &views {
        let low = if b.ux_bits >= 32 {
            u32::MAX
        } else {
            (1u32 << b.ux_bits) - 1
        };
        if b.reset != wide.reset & low {
            bail!(
                "{what}: the view {name} resets to {} but the widest view to {}",
                hex(b.reset),
                hex(wide.reset)
            );
        }
        m.readable |= b.readable;
        m.writable |= b.writable;
        m.read |= b.read;
        m.plain |= b.plain;
        m.w1s |= b.w1s;
        m.w1c |= b.w1c;
        m.w0c |= b.w0c;
        m.w1t |= b.w1t;
        m.unplaced_writer |= b.unplaced_writer;
        m.notes
            .extend(b.notes.iter().map(|n| format!("{name}: {n}")));
    }
    let kinds = [m.plain, m.w1s, m.w1c, m.w0c, m.w1t];
    let mut seen = 0u32;
    let mut conflict = 0u32;
    for k in kinds {
        conflict |= seen & k;
        seen |= k;
    }
    if conflict != 0 {
        let text = format!(
            "the views disagree on the write semantics of bits {}",
            hex(conflict)
        );
        warnings.push(format!("{what}: {text}"));
        m.notes.push(text);
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    impl Files for HashMap<&str, &str> {
        fn read(&self, rel: &str) -> Result<String> {
            self.get(rel)
                .map(|s| s.to_string())
                .ok_or_else(|| anyhow!("{rel}: not found"))
        }
    }

    const BLOCK: &str = r#"#[repr(C)]
#[derive(Debug)]
///Register block
pub struct RegisterBlock {
    isr: ISR,
    cr: CR,
    _reserved2: [u8; 0x08],
    ofr: [OFR; 2],
    _reserved_4_ccmr: [u8; 0x04],
    half: HALF,
}
impl RegisterBlock {
    ///0x00 - interrupt and status register
    #[inline(always)]
    pub const fn isr(&self) -> &ISR {
        &self.isr
    }
    ///0x04 - control register
    #[inline(always)]
    pub const fn cr(&self) -> &CR {
        &self.cr
    }
    ///0x10..0x18 - offset register %s
    ///
    ///<div class="warning">`n` is the index of register in the array. `n == 0` corresponds to `OFR1` register.</div>
    #[inline(always)]
    pub const fn ofr(&self, n: usize) -> &OFR {
        &self.ofr[n]
    }
    ///Iterator for array of:
    ///0x10..0x18 - offset register %s
    #[inline(always)]
    pub fn ofr_iter(&self) -> impl Iterator<Item = &OFR> {
        self.ofr.iter()
    }
    ///0x10 - offset register 1
    #[inline(always)]
    pub const fn ofr1(&self) -> &OFR {
        self.ofr(0)
    }
    ///0x14 - offset register 2
    #[inline(always)]
    pub const fn ofr2(&self) -> &OFR {
        self.ofr(1)
    }
    ///0x18 - mode register (input)
    #[inline(always)]
    pub const fn ccmr_input(&self) -> &CCMR_INPUT {
        unsafe { &*core::ptr::from_ref(self).cast::<u8>().add(24).cast() }
    }
    ///0x18 - mode register (output)
    #[inline(always)]
    pub const fn ccmr_output(&self) -> &CCMR_OUTPUT {
        unsafe { &*core::ptr::from_ref(self).cast::<u8>().add(24).cast() }
    }
    ///0x1c - a half-word register
    #[inline(always)]
    pub const fn half(&self) -> &HALF {
        &self.half
    }
}
///ISR (rw) register accessor
pub type ISR = crate::Reg<isr::ISRrs>;
pub mod isr;
pub type CR = crate::Reg<cr::CRrs>;
pub type OFR = crate::Reg<ofr::OFRrs>;
pub type CCMR_INPUT = crate::Reg<ccmr_input::CCMR_INPUTrs>;
pub type CCMR_OUTPUT = crate::Reg<ccmr_output::CCMR_OUTPUTrs>;
pub type HALF = crate::Reg<half::HALFrs>;
pub use CR as CR2;
pub use cr as cr2;
pub use crate::stm32g474::n::OTHER;
pub use crate::stm32g474::n::other;
"#;

    fn sizes(ty: &str) -> Result<u32> {
        Ok(if ty == "HALF" { 2 } else { 4 })
    }

    #[test]
    fn layout_with_a_gap_an_array_and_alternate_views() {
        let b = parse_block(BLOCK, "m").unwrap();
        assert_eq!(
            b.reg_types["CR"],
            RegRef {
                module: "m".into(),
                file: "cr".into(),
                spec: "CRrs".into()
            }
        );
        assert_eq!(b.reg_types["CR2"], b.reg_types["CR"]);
        assert_eq!(
            b.foreign,
            vec![("OTHER".to_string(), "n".to_string(), "OTHER".to_string())]
        );
        assert_eq!(b.fields[2], ("_reserved2".to_string(), FieldTy::Bytes(8)));
        assert_eq!(
            b.fields[3],
            ("ofr".to_string(), FieldTy::Array("OFR".into(), 2))
        );
        let slots = layout(&b, &sizes).unwrap();
        let got: Vec<(u32, &str, Vec<&str>)> = slots
            .iter()
            .map(|s| {
                (
                    s.offset,
                    s.name.as_str(),
                    s.views.iter().map(String::as_str).collect(),
                )
            })
            .collect();
        assert_eq!(
            got,
            vec![
                (0x00, "ISR", vec!["ISR"]),
                (0x04, "CR", vec!["CR"]),
                (0x10, "OFR1", vec!["OFR"]),
                (0x14, "OFR2", vec!["OFR"]),
                (0x18, "CCMR", vec!["CCMR_INPUT", "CCMR_OUTPUT"]),
                (0x1c, "HALF", vec!["HALF"]),
            ]
        );
    }

    #[test]
    fn layout_fails_when_a_doc_offset_disagrees() {
        let wrong = BLOCK.replace("///0x04 - control register", "///0x08 - control register");
        let e = layout(&parse_block(&wrong, "m").unwrap(), &sizes)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`cr`") && e.contains("0x8") && e.contains("0x4"),
            "{e}"
        );
        let gap = BLOCK.replace("[u8; 0x08]", "[u8; 0x04]");
        assert!(layout(&parse_block(&gap, "m").unwrap(), &sizes).is_err());
    }

    #[test]
    fn a_cluster_fails_loudly() {
        let cluster = BLOCK.replace("    cr: CR,\n", "    cr: CR,\n    ch: CH,\n");
        let e = layout(&parse_block(&cluster, "m").unwrap(), &sizes)
            .unwrap_err()
            .to_string();
        assert!(e.contains("cluster"), "{e}");
    }

    #[test]
    fn periph_decls() {
        let m = "///ADC1\npub type ADC1 = crate::Periph<adc1::RegisterBlock, 0x5000_0000>;\n\
                 pub type ADC2 = crate::Periph<adc1::RegisterBlock, 0x5000_0100>;\n\
                 pub type X = u32;\n";
        let d = parse_periph_decls(m).unwrap();
        assert_eq!(d["ADC1"], ("adc1".to_string(), 0x5000_0000));
        assert_eq!(d["ADC2"], ("adc1".to_string(), 0x5000_0100));
        assert_eq!(d.len(), 2);
    }

    const REG: &str = r#"///Register `SR` reader
pub type R = crate::R<SRrs>;
///Register `SR` writer
pub type W = crate::W<SRrs>;
///Field `EN` reader - enable
pub type EN_R = crate::BitReader;
///Field `EN` writer - enable
pub type EN_W<'a, REG> = crate::BitWriter1S<'a, REG>;
pub type CLR_R = crate::BitReader<CLRR>;
pub type CLR_W<'a, REG> = crate::BitWriter1C<'a, REG, CLRW>;
pub use CLR_R as CLR2_R;
pub use CLR_W as CLR2_W;
pub type UIF_W<'a, REG> = crate::BitWriter0C<'a, REG>;
pub type MODE_R = crate::FieldReader<MODE>;
pub type MODE_W<'a, REG> =
    crate::FieldWriter<'a, REG, 2, MODE, crate::Safe>;
pub type BSY_R = crate::BitReader;
pub type ODR_W<'a, REG> = crate::BitWriter<'a, REG>;
pub type ODR_R = crate::BitReader;
impl R {
    ///Bit 0 - enable
    #[inline(always)]
    pub fn en(&self) -> EN_R {
        EN_R::new((self.bits & 1) != 0)
    }
    ///Bit 1 - clear
    #[inline(always)]
    pub fn clr(&self) -> CLR_R {
        CLR_R::new(((self.bits >> 1) & 1) != 0)
    }
    #[inline(always)]
    pub fn clr2(&self) -> CLR2_R {
        CLR2_R::new(((self.bits >> 2) & 1) != 0)
    }
    ///Bits 4:5 - mode
    #[inline(always)]
    pub fn mode(&self) -> MODE_R {
        MODE_R::new(((self.bits >> 4) & 3) as u8)
    }
    ///Bit 16 - busy
    #[inline(always)]
    pub fn bsy(&self) -> BSY_R {
        BSY_R::new(((self.bits >> 16) & 1) != 0)
    }
    ///Output data (0-3)
    #[inline(always)]
    pub fn odr(&self, n: u8) -> ODR_R {
        #[allow(clippy::no_effect)]
        [(); 4][n as usize];
        ODR_R::new(((self.bits >> (n * 2 + 20)) & 1) != 0)
    }
    ///Iterator for array of:
    #[inline(always)]
    pub fn odr_iter(&self) -> impl Iterator<Item = ODR_R> + '_ {
        (0..4).map(move |n| ODR_R::new(((self.bits >> (n * 2 + 20)) & 1) != 0))
    }
}
impl W {
    ///Bit 0 - enable
    #[inline(always)]
    pub fn en(&mut self) -> EN_W<SRrs> {
        EN_W::new(self, 0)
    }
    #[inline(always)]
    pub fn clr(&mut self) -> CLR_W<SRrs> {
        CLR_W::new(self, 1)
    }
    #[inline(always)]
    pub fn clr2(&mut self) -> CLR2_W<SRrs> {
        CLR2_W::new(self, 2)
    }
    #[inline(always)]
    pub fn uif(&mut self) -> UIF_W<SRrs> {
        UIF_W::new(self, 8)
    }
    #[inline(always)]
    pub fn mode(&mut self) -> MODE_W<SRrs> {
        MODE_W::new(self, 4)
    }
    #[inline(always)]
    pub fn odr(&mut self, n: u8) -> ODR_W<SRrs> {
        #[allow(clippy::no_effect)]
        [(); 4][n as usize];
        ODR_W::new(self, n * 2 + 20)
    }
}
///status register
pub struct SRrs;
impl crate::RegisterSpec for SRrs {
    type Ux = u32;
}
impl crate::Readable for SRrs {}
impl crate::Writable for SRrs {
    type Safety = crate::Unsafe;
    const ONE_TO_MODIFY_FIELDS_BITMAP: u32 = 0x07;
    const ZERO_TO_MODIFY_FIELDS_BITMAP: u32 = 0x0100;
}
///`reset()` method sets SR to value 0x2000_0000
impl crate::Resettable for SRrs {
    const RESET_VALUE: u32 = 0x2000_0000;
}
"#;

    #[test]
    fn register_file_with_1s_1c_0c_plain_and_read_only_fields() {
        let rf = parse_reg_file(REG, "SRrs").unwrap();
        assert_eq!(rf.ux_bits, 32);
        assert!(rf.readable && rf.writable);
        assert_eq!(rf.reset, 0x2000_0000);
        assert_eq!((rf.one_to_modify, rf.zero_to_modify), (0x07, 0x100));
        assert_eq!(rf.readers.len(), 6);
        assert_eq!(rf.writers.len(), 6);
        assert_eq!(rf.writers[5].array, Some(Ok(4)));
        assert_eq!(rf.writers[5].arg, "n * 2 + 20");
        let files: HashMap<&str, &str> = HashMap::new();
        let mut warnings = Vec::new();
        let b = reg_bits(&files, "m", "sr", &rf, "M.SR", &mut warnings).unwrap();
        assert_eq!(b.w1s, 0b1);
        assert_eq!(b.w1c, 0b110);
        assert_eq!(b.w0c, 0x100);
        assert_eq!(b.w1t, 0);
        assert_eq!(b.plain, 0x30 | 0x0550_0000);
        assert_eq!(b.read, 0b111 | 0x30 | 0x1_0000 | 0x0550_0000);
        assert_eq!(b.read_only_bits(), 0x1_0000);
        assert!(warnings.is_empty(), "{warnings:?}");
        assert!(b.notes.is_empty());
    }

    #[test]
    fn bitmap_mismatch_warns_and_an_unknown_writer_falls_back() {
        let odd = REG
            .replace("= 0x07;", "= 0x03;")
            .replace("ODR_W::new(self, n * 2 + 20)", "ODR_W::new(self, n << 1)");
        let rf = parse_reg_file(&odd, "SRrs").unwrap();
        let files: HashMap<&str, &str> = HashMap::new();
        let mut warnings = Vec::new();
        let b = reg_bits(&files, "m", "sr", &rf, "M.SR", &mut warnings).unwrap();
        assert_eq!(
            b.read_only_bits(),
            0,
            "an unplaced writer: nothing read-only"
        );
        assert_eq!(b.notes.len(), 1, "{:?}", b.notes);
        assert!(b.notes[0].contains("`odr`"), "{:?}", b.notes);
        // The unplaced writer skips the bitmap cross-check; without it, it warns.
        let rf = parse_reg_file(&REG.replace("= 0x07;", "= 0x03;"), "SRrs").unwrap();
        let mut warnings = Vec::new();
        reg_bits(&files, "m", "sr", &rf, "M.SR", &mut warnings).unwrap();
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].starts_with("M.SR:"), "{warnings:?}");
    }

    #[test]
    fn read_only_and_write_only_registers() {
        let ro = REG.replace(
            "impl crate::Writable for SRrs {\n    type Safety = crate::Unsafe;\n    const ONE_TO_MODIFY_FIELDS_BITMAP: u32 = 0x07;\n    const ZERO_TO_MODIFY_FIELDS_BITMAP: u32 = 0x0100;\n}\n",
            "",
        );
        let rf = parse_reg_file(&ro, "SRrs").unwrap();
        assert!(rf.readable && !rf.writable);
        let wo = REG
            .replace("impl crate::Readable for SRrs {}\n", "")
            .replace(
                "impl crate::Resettable for SRrs {\n    const RESET_VALUE: u32 = 0x2000_0000;\n}",
                "impl crate::Resettable for SRrs {}",
            );
        let rf = parse_reg_file(&wo, "SRrs").unwrap();
        assert!(!rf.readable && rf.writable);
        assert_eq!(rf.reset, 0);
        assert!(parse_reg_file(REG, "CRrs").is_err());
    }

    #[test]
    fn writer_types_through_pub_use_across_files() {
        let other =
            "pub type MODER_W<'a, REG> = crate::FieldWriter<'a, REG, 2, MODE, crate::Safe>;\n";
        let here = "pub use crate::stm32g474::gpioa::moder::MODER_W;\npub use super::afrl::AFR_W as AFRH_W;\n";
        let afrl = "pub type AFR_W<'a, REG> = crate::FieldWriter<'a, REG, 4, AF, crate::Safe>;\n";
        let files: HashMap<&str, &str> =
            HashMap::from([("gpioa/moder.rs", other), ("gpiob/afrl.rs", afrl)]);
        let types = parse_types(here);
        assert_eq!(
            resolve_writer(&files, "gpiob", "moder", &types, "MODER_W").unwrap(),
            (WriterType::Known(WriterKind::Plain), 2)
        );
        assert_eq!(
            resolve_writer(&files, "gpiob", "afrh", &types, "AFRH_W").unwrap(),
            (WriterType::Known(WriterKind::Plain), 4)
        );
        assert!(resolve_writer(&files, "gpiob", "x", &types, "NOPE_W").is_err());
    }

    #[test]
    fn field_expressions() {
        assert_eq!(reader_mask("(self.bits & 1) != 0", None, 32).ok(), Some(1));
        assert_eq!(
            reader_mask("((self.bits >> 16) & 1) != 0", None, 32).ok(),
            Some(0x1_0000)
        );
        assert_eq!(
            reader_mask("((self.bits >> 8) & 0x0f) as u8", None, 32).ok(),
            Some(0xf00)
        );
        assert_eq!(
            reader_mask("self.bits & 0x0fff", None, 16).ok(),
            Some(0xfff)
        );
        assert_eq!(reader_mask("self.bits", None, 16).ok(), Some(0xffff));
        assert_eq!(reader_mask("self.bits", None, 32).ok(), Some(0xffff_ffff));
        assert_eq!(
            reader_mask("((self.bits >> 28) & 0xff) as u8", None, 32).ok(),
            Some(0xf000_0000)
        );
        assert_eq!(
            reader_mask("((self.bits >> (n * 4 + 1)) & 3) as u8", Some(2), 32).ok(),
            Some(0b11 << 9)
        );
        assert_eq!(
            reader_mask("((self.bits >> n) & 1) != 0", Some(5), 32).ok(),
            Some(1 << 5)
        );
        assert!(reader_mask("((self.bits >> n) & 1) != 0", None, 32).is_err());
        assert!(reader_mask("self.other", None, 32).is_err());
        assert!(reader_mask("(self.bits & 1", None, 32).is_err());
        assert_eq!(writer_offset("n * 2 + 1", Some(3)).ok(), Some(7));
        assert_eq!(writer_offset("n + 8", Some(3)).ok(), Some(11));
        assert_eq!(writer_offset("31", None).ok(), Some(31));
        assert!(writer_offset("32", None).is_err());
        assert!(writer_offset("n << 1", Some(1)).is_err());
    }

    #[test]
    fn alternate_views_merge() {
        let a = RegBits {
            ux_bits: 32,
            readable: true,
            writable: true,
            reset: 0xffff_ffff,
            read: 0xffff_ffff,
            plain: 0xffff_ffff,
            ..RegBits::default()
        };
        let narrow = RegBits {
            ux_bits: 8,
            reset: 0xff,
            read: 0xff,
            plain: 0xff,
            ..a.clone()
        };
        let mut w = Vec::new();
        let m = merge_views(
            "CRC.DR",
            vec![("DR".into(), a.clone()), ("DR8".into(), narrow.clone())],
            &mut w,
        )
        .unwrap();
        assert_eq!(
            (m.reset, m.ux_bits, m.read_only_bits()),
            (0xffff_ffff, 32, 0)
        );
        assert!(w.is_empty());
        let bad = RegBits {
            reset: 0x12,
            ..narrow
        };
        assert!(merge_views(
            "CRC.DR",
            vec![("DR".into(), a), ("DR8".into(), bad)],
            &mut w
        )
        .is_err());
    }
}

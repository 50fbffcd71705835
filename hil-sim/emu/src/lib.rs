//! The release `drive-fw` ELF on an emulated STM32G474 driving hil-sim's simulated
//! motor: the binary users flash, executed. See docs/emulator.md.
//!
//! GPL-2.0-only: this crate links the Unicorn engine. No MIT crate depends on it.

pub mod bench;
pub mod board;
pub mod budget;
pub mod cpu;
pub mod debug;
pub mod debug_core;
pub mod elf;
pub mod machine;
pub mod nvic;
pub mod perf_report;
pub mod periph;
pub mod profile;
pub mod regfile;
pub mod regs_g474;
pub mod ripple_elf;
pub mod rtt;
pub mod scenarios;
pub mod stats;
pub mod vprobe;

pub use cpu::Emu;

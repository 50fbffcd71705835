//! Behaviour models of the STM32G474's peripherals the drive uses, written from RM0440
//! (Rev 8 section numbers). Each model keeps its state here and its registers in the
//! [`RegFile`](crate::regfile::RegFile); the machine calls them on bus accesses and at
//! their events. Time is in ticks of the 170 MHz system clock ([`TICK_HZ`]).

pub mod adc;
pub mod flash;
pub mod misc;
pub mod rcc;
pub mod tim1;

/// The time base: one tick of the 170 MHz system clock the firmware configures.
pub const TICK_HZ: f64 = 170.0e6;

/// Ticks in `s` seconds.
pub fn ticks(s: f64) -> u64 {
    (s * TICK_HZ).round() as u64
}

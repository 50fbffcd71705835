//! Portable drive logic of the firmware (`no_std`, no HAL types): everything that is not
//! register access, so that it is tested on the host and reused by hil-sim.
#![no_std]
#![deny(unsafe_code)]

pub mod adc;
pub mod commissioning;
pub mod cordic;
pub mod foc;

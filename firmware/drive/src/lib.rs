//! Portable drive logic of the firmware (`no_std`, no HAL types): everything that is not
//! register access, so that it is tested on the host and run unchanged by hil-sim.
//!
//! - [`control::ControlPeriod`]: the control period (ADC counts → duties), the
//!   firmware's control interrupt body;
//! - [`supervisor::Supervisor`]: the commissioning state machine, the calibration in
//!   flash and the stream, the firmware's supervisor task body;
//! - [`adaptation::AdaptationTask`] and [`handoff`]: the MRAS adaptation's task and the
//!   bounded queues between it and the control period, with their drop rules;
//! - [`telemetry`]: what they exchange, and the stream's schema.
#![no_std]
#![deny(unsafe_code)]

pub mod adaptation;
pub mod adc;
pub mod align;
pub mod commissioning;
pub mod control;
pub mod cordic;
pub mod foc;
pub mod handoff;
pub mod ident;
pub mod motion;
mod mutant;
pub mod refine;
pub mod ripple;
pub mod spin;
pub mod supervisor;
pub mod telemetry;

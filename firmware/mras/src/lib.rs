//! Decoupling vector-tracking motion observer with MRAS self-commissioning of a
//! vector-based angle sensor (Secrest et al., IEEE TIA 2015), as a portable core.
//!
//! `no_std`, no allocation, no panics in [`Tracker::step`], `f32` arithmetic.
//! The theory as implemented, with the paper's equation numbers, is in `docs/theory.md`.
//!
//! ```
//! use mras::{Config, Tracker};
//! let mut t = Tracker::new(Config::default()).unwrap();
//! let est = t.step(1.0, 0.0, 0.0).unwrap();
//! assert!(est.theta_rad.abs() < 1e-6);
//! ```
#![no_std]
#![deny(unsafe_code)]

mod adapter;
pub mod closed_form;
mod coefficients;
mod complex;
pub mod config;
mod decoupler;
mod health;
pub mod observer;
pub mod survey;
mod tracker;
mod transient;
mod trig;

pub use adapter::Adapter;
pub use coefficients::{Coefficients, CoefficientsError, Convergence, PaperForm};
pub use complex::Cplx;
pub use config::{
    AdaptationLaw, Bank, Config, ConfigError, ConvergenceConfig, Gates, HealthConfig,
    ObserverConfig, PathKind, MAX_PATHS,
};
pub use decoupler::{
    AdaptSample, BankPlan, Change, Injection, InjectionUpdate, PackedBank, UPDATE_LATENCY_PERIODS,
};
pub use health::{Fault, Faults};
pub use tracker::{Estimate, Front, Tracker};
pub use trig::{
    clamp_01_f32, clamp_unit_f32, inv_sqrt_f32, inv_sqrt_steps_f32, max_f32, min_f32,
    round_f32_fast, sin_cos_f32, sqrt_f32, F32Trig, LibmTrig, Trig,
};

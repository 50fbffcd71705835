//! `hil-sim qemu-vector`: an input vector for the emulated Cortex-M4F (a distorted sensor
//! through commissioning) and the host's trace of the same core over it.

use crate::commission::{noise, ADC, INERTIA_KG_M2, SAMPLE_PERIOD_S};
use anyhow::{bail, Context, Result};
use mras::{Config, Tracker};
use mras_sim::{encode_vector_record, write_trace_line, Kinematic, SensorModel, Trajectory};
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Input vector to write (x, y, torque as little-endian f32 per step).
    #[arg(long)]
    pub vector: PathBuf,
    /// The host core's trace over that vector (`mras_sim::write_trace_line`).
    #[arg(long)]
    pub trace: PathBuf,
    /// Steps (20 kHz): 8000 covers the spin-up to 20 rev/s and convergence.
    #[arg(long, default_value_t = 8000)]
    pub steps: u64,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(a: &Args) -> Result<()> {
    if a.steps == 0 || a.steps > 20_000 {
        bail!("--steps must be in 1..=20000 (the image embeds the vector)");
    }
    let kin = Kinematic {
        sensor: SensorModel::extreme(),
        trajectory: Trajectory::Ramp {
            omega_rad_s: 20.0 * std::f64::consts::TAU,
            accel_rad_s2: 2000.0,
        },
        sample_period_s: SAMPLE_PERIOD_S,
        inertia_kg_m2: INERTIA_KG_M2,
        adc: Some(ADC),
    };
    let mut vector = Vec::with_capacity(a.steps as usize * 12);
    let mut trace = String::new();
    let mut tracker = Tracker::new(Config::default())?;
    // The driver feeds the live tracker; the trace is written from what it fed, so the
    // host trace is the core over exactly the recorded f32 values.
    kin.run(
        &mut tracker,
        0,
        a.steps,
        noise(a.seed, 3.0e-4)?,
        |t, rec| {
            vector.extend_from_slice(&encode_vector_record(rec.x, rec.y, rec.torque_nm));
            let _ = write_trace_line(&mut trace, rec.k as usize, &rec.result, t);
        },
    );
    let conv = tracker.convergence();
    for (p, d) in [(&a.vector, vector.as_slice()), (&a.trace, trace.as_bytes())] {
        if let Some(dir) = p.parent() {
            std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
        }
        std::fs::write(p, d).with_context(|| p.display().to_string())?;
    }
    println!(
        "qemu-vector: {} steps ({} bytes) to {}, host trace to {}; converged: {} after {} revolutions",
        a.steps,
        vector.len(),
        a.vector.display(),
        a.trace.display(),
        conv.converged,
        conv.revs_adapted
    );
    Ok(())
}

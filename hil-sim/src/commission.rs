//! Constant-speed self-commissioning with a summary a drive engineer can check.

use crate::Law;
use anyhow::{bail, Context, Result};
use mras::{PaperForm, Tracker};
use mras_sim::{revs_to_reduction, wrap_pi, Adc, CommissioningRun, SensorModel, SpatialError};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

pub const SAMPLE_PERIOD_S: f64 = 50.0e-6;
pub const INERTIA_KG_M2: f64 = 1.0e-4;
/// 12-bit ADC over ±1.5 (nominal amplitude 1).
pub const ADC: Adc = Adc {
    bits: 12,
    full_scale: 1.5,
};

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Commissioning speed, rev/s (negative: reverse).
    #[arg(long, default_value_t = 20.0, allow_negative_numbers = true)]
    pub speed_rev_s: f64,
    /// Revolutions of adaptation.
    #[arg(long, default_value_t = 10)]
    pub revs: u32,
    #[arg(long, value_enum, default_value_t = Law::Ours)]
    pub law: Law,
    /// Gaussian noise on X and Y (scaled units, nominal amplitude 1).
    #[arg(long, default_value_t = 3.0e-4, allow_negative_numbers = true)]
    pub noise_std: f64,
    /// Noise seed (runs are deterministic).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            speed_rev_s: 20.0,
            revs: 10,
            law: Law::Ours,
            noise_std: 3.0e-4,
            seed: 1,
        }
    }
}

pub fn noise(seed: u64, std: f64) -> Result<impl FnMut() -> (f64, f64)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, std).with_context(|| format!("--noise-std {std}"))?;
    Ok(move || (n.sample(&mut rng), n.sample(&mut rng)))
}

pub fn run(a: &Args) -> Result<()> {
    if !(a.speed_rev_s.abs() >= 0.5 && a.speed_rev_s.abs() <= 200.0) {
        bail!(
            "--speed-rev-s {} out of range: |speed| must be in [0.5, 200] rev/s",
            a.speed_rev_s
        );
    }
    if !(a.noise_std.is_finite() && (0.0..=0.05).contains(&a.noise_std)) {
        bail!(
            "--noise-std {} out of range: must be in [0, 0.05] (nominal amplitude 1)",
            a.noise_std
        );
    }
    if a.revs == 0 {
        bail!("--revs must be at least 1");
    }
    let sensor = SensorModel::extreme();
    let cfg = a.law.config();
    let mut t = Tracker::new(cfg)?;
    let ev = cfg.observer.eigenvalues_hz;
    println!(
        "hil-sim commission: kinematic drive, extreme sensor, N = {}",
        sensor.sensor_periods
    );
    println!(
        "  offsets {:+.0}/{:+.0} %, amplitude imbalance {:.0} %, quadrature {:.0}°, h = 2..5",
        sensor.ax * 100.0,
        sensor.ay * 100.0,
        (sensor.bx1 / sensor.by1 - 1.0) * 100.0,
        sensor.phi_x1_rad.to_degrees()
    );
    println!(
        "  {:.0} kHz, 12-bit ADC, noise σ = {:.1e}; observer {}/{}/{} Hz; law {:?}",
        1e-3 / SAMPLE_PERIOD_S,
        a.noise_std,
        ev[0],
        ev[1],
        ev[2],
        cfg.law
    );
    println!(
        "  spin-up to {:+} rev/s on the uncorrected sensor, then adapt:",
        a.speed_rev_s
    );

    let r = CommissioningRun {
        sensor,
        speed_rev_s: a.speed_rev_s,
        sample_period_s: SAMPLE_PERIOD_S,
        inertia_kg_m2: INERTIA_KG_M2,
        adc: Some(ADC),
    };
    let mut per_rev = Vec::new();
    let mut raw_pk_pk = 0.0;
    let mut converged_at = None;
    let mut faults = r.run(&mut t, a.revs, noise(a.seed, a.noise_std)?, |t, rep| {
        let c = t.convergence();
        if c.converged && converged_at.is_none() {
            converged_at = Some(rep.rev);
        }
        println!(
            "  rev {:3}: error {:8.3} mrad pk-pk (raw {:.1}) {:8.1}x{}",
            rep.rev,
            rep.error_pk_pk_rad * 1e3,
            rep.raw_pk_pk_rad * 1e3,
            rep.raw_pk_pk_rad / rep.error_pk_pk_rad,
            if c.converged { "  converged" } else { "" }
        );
        per_rev.push(rep.error_pk_pk_rad);
        raw_pk_pk = rep.raw_pk_pk_rad;
    });

    // Verification: two more revolutions, adaptation frozen, 360 bins.
    t.set_frozen(true);
    let (kin, k0) = (r.kinematic(), r.step_after(a.revs));
    let steps_per_rev = r.steps_per_rev();
    let (mut est, mut raw) = (SpatialError::<360>::new(), SpatialError::<360>::new());
    let n = sensor.sensor_periods as f64;
    kin.run(
        &mut t,
        k0,
        2 * steps_per_rev,
        noise(a.seed ^ 0x5eed, a.noise_std)?,
        |_, rec| {
            faults += rec.result.is_err() as u32;
            est.add(rec.theta_rad, rec.error_rad);
            let raw_err = wrap_pi((rec.y as f64).atan2(rec.x as f64) - n * rec.theta_rad) / n;
            raw.add(rec.theta_rad, raw_err);
        },
    );

    let secs_per_rev = 1.0 / a.speed_rev_s.abs();
    let fmt_revs = |r: Option<usize>| match r {
        Some(r) => format!("{r} rev ({:.2} s)", r as f64 * secs_per_rev),
        None => format!("not within {} rev", a.revs),
    };
    println!("summary (verification: 2 revolutions frozen, 360 bins):");
    println!(
        "  spatial error, raw sensor : {:8.3} mrad pk-pk, {:8.3} mrad RMS",
        raw.pk_pk_rad() * 1e3,
        raw.rms_rad() * 1e3
    );
    println!(
        "  spatial error, corrected  : {:8.3} mrad pk-pk, {:8.3} mrad RMS  ({:.0}x lower pk-pk)",
        est.pk_pk_rad() * 1e3,
        est.rms_rad() * 1e3,
        raw.pk_pk_rad() / est.pk_pk_rad()
    );
    println!(
        "  10x reduction: {}; 100x: {}; converged flag: {}",
        fmt_revs(revs_to_reduction(&per_rev, raw_pk_pk, 10.0)),
        fmt_revs(revs_to_reduction(&per_rev, raw_pk_pk, 100.0)),
        converged_at.map_or("not yet".into(), |r| format!("rev {r}"))
    );
    println!("  faults: {faults}");
    println!("coefficients (scaled sensor units):");
    let coefs = t.coefficients();
    for (kind, _) in coefs.iter() {
        match coefs.paper_form(kind) {
            Some(PaperForm::Offset { xo, yo }) => {
                println!("  offset      Xo = {xo:+.5}, Yo = {yo:+.5}")
            }
            Some(PaperForm::AmplitudeQuadrature { c, d }) => {
                println!("  ampl/quad   C  = {c:+.5}, D  = {d:+.5}")
            }
            Some(PaperForm::Harmonic { h, e, f }) => {
                println!("  h = {h:<3}     E  = {e:+.5}, F  = {f:+.5}")
            }
            None => {}
        }
    }
    if faults > 0 {
        bail!("{faults} samples faulted");
    }
    Ok(())
}

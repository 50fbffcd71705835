//! Parameter studies whose tables go into docs/theory.md.

use crate::commission::{INERTIA_KG_M2, SAMPLE_PERIOD_S};
use crate::Law;
use anyhow::Result;
use mras::{AdaptationLaw, Config, Tracker};
use mras_sim::{revs_to_reduction, CommissioningRun, SensorModel};

#[derive(clap::Args, Clone, Debug)]
pub struct CompareArgs {
    /// Revolutions of adaptation per run.
    #[arg(long, default_value_t = 30)]
    pub revs: u32,
}

#[derive(clap::Args, Clone, Debug)]
pub struct SweepArgs {
    /// Revolutions of adaptation per run.
    #[arg(long, default_value_t = 30)]
    pub revs: u32,
}

/// Revolutions to a 10x reduction of the extreme sensor's error (noiseless, no ADC, so
/// that the figure measures the adaptation and nothing else); `None` if not reached.
/// A loss of lock counts as not reached.
pub fn revs_to_10x(cfg: Config, speed_rev_s: f64, revs: u32) -> Result<Option<usize>> {
    let r = CommissioningRun {
        sensor: SensorModel::extreme(),
        speed_rev_s,
        sample_period_s: SAMPLE_PERIOD_S,
        inertia_kg_m2: INERTIA_KG_M2,
        adc: None,
    };
    let mut t = Tracker::new(cfg)?;
    let (mut per_rev, mut raw) = (Vec::new(), 0.0);
    r.run(
        &mut t,
        revs,
        || (0.0, 0.0),
        |_, rep| {
            per_rev.push(rep.error_pk_pk_rad);
            raw = rep.raw_pk_pk_rad;
        },
    );
    if !t.faults().is_empty() {
        return Ok(None);
    }
    Ok(revs_to_reduction(&per_rev, raw, 10.0))
}

fn cell(r: Option<usize>, revs: u32) -> String {
    r.map_or(format!("> {revs}"), |r| r.to_string())
}

pub const SPEEDS_REV_S: [f64; 5] = [2.0, 5.0, 20.0, 50.0, 100.0];

pub fn compare_laws(a: &CompareArgs) -> Result<()> {
    println!("Revolutions to a 10x reduction of the extreme sensor's spatial error");
    println!(
        "(observer 100/10/1 Hz, 20 kHz, noiseless; `> {}`: not reached)\n",
        a.revs
    );
    println!("| speed (rev/s) | ours, forward | ours, reverse | paper, forward | paper, reverse |");
    println!("|---:|---:|---:|---:|---:|");
    for v in SPEEDS_REV_S {
        let mut row = format!("| {v} |");
        for law in [Law::Ours, Law::Paper] {
            for dir in [1.0, -1.0] {
                let r = revs_to_10x(law.config(), v * dir, a.revs)?;
                row += &format!(" {} |", cell(r, a.revs));
            }
        }
        println!("{row}");
    }
    Ok(())
}

pub fn gain_sweep(a: &SweepArgs) -> Result<()> {
    let gains = [0.05, 0.1, 0.15, 0.2];
    println!(
        "Revolutions to 10x vs gain_per_rad (forward / reverse; `> {}`: not reached)\n",
        a.revs
    );
    let mut head = "| gain (1/rad) |".to_string();
    for v in SPEEDS_REV_S {
        head += &format!(" {v} rev/s |");
    }
    println!("{head}");
    println!("|---:|{}", "---:|".repeat(SPEEDS_REV_S.len()));
    for g in gains {
        let mut cfg = Config::default();
        if let AdaptationLaw::Compensated {
            gain_per_rad,
            offset_gain_per_mech_rad,
            ..
        } = &mut cfg.law
        {
            // Every path at the swept gain, the offset included.
            *gain_per_rad = g;
            *offset_gain_per_mech_rad = 0.0;
        }
        let mut row = format!("| {g} |");
        for v in SPEEDS_REV_S {
            let f = revs_to_10x(cfg, v, a.revs)?;
            let r = revs_to_10x(cfg, -v, a.revs)?;
            row += &format!(" {} / {} |", cell(f, a.revs), cell(r, a.revs));
        }
        println!("{row}");
    }
    Ok(())
}

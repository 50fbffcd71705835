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

pub fn cell(r: Option<usize>, revs: u32) -> String {
    r.map_or(format!("> {revs}"), |r| r.to_string())
}

pub const SPEEDS_REV_S: [f64; 5] = [2.0, 5.0, 20.0, 50.0, 100.0];

pub fn compare_laws(a: &CompareArgs) -> Result<()> {
    print!("{}", compare_laws_table(a.revs)?);
    Ok(())
}

pub fn gain_sweep(a: &SweepArgs) -> Result<()> {
    print!("{}", gain_sweep_table(a.revs)?);
    Ok(())
}

/// Per speed of [`SPEEDS_REV_S`]: revolutions to 10x with ours forward, reverse, then
/// the paper's law forward, reverse.
pub type LawGrid = Vec<(f64, [Option<usize>; 4])>;

/// [`LawGrid`] over `revs` revolutions per run.
pub fn compare_laws_grid(revs: u32) -> Result<LawGrid> {
    let mut grid = Vec::new();
    for v in SPEEDS_REV_S {
        let mut row = [None; 4];
        let runs = [Law::Ours, Law::Paper]
            .into_iter()
            .flat_map(|law| [1.0, -1.0].map(|dir| (law, dir)));
        for (k, (law, dir)) in runs.enumerate() {
            row[k] = revs_to_10x(law.config(), v * dir, revs)?;
        }
        grid.push((v, row));
    }
    Ok(grid)
}

/// Revolutions to 10x per speed and direction, ours and the paper's law (markdown).
pub fn compare_laws_table(revs: u32) -> Result<String> {
    Ok(laws_table(&compare_laws_grid(revs)?, revs))
}

/// The markdown table of a [`LawGrid`].
pub fn laws_table(grid: &LawGrid, revs: u32) -> String {
    let mut s = format!("Revolutions to 10x (`> {revs}`: not reached):\n\n");
    s += "| speed (rev/s) | ours, forward | ours, reverse | paper, forward | paper, reverse |\n";
    s += "|---:|---:|---:|---:|---:|\n";
    for (v, row) in grid {
        s += &format!("| {v} |");
        for r in row {
            s += &format!(" {} |", cell(*r, revs));
        }
        s.push('\n');
    }
    s
}

/// The adaptation gains of [`gain_sweep_table`]: the configuration's valid range.
pub const SWEPT_GAINS: [f32; 4] = [0.05, 0.1, 0.15, 0.2];

/// The default configuration with every path, the offset included, at `gain`.
pub fn with_gain(gain: f32) -> Config {
    let mut cfg = Config::default();
    if let AdaptationLaw::Compensated {
        gain_per_rad,
        offset_gain_per_mech_rad,
        ..
    } = &mut cfg.law
    {
        *gain_per_rad = gain;
        *offset_gain_per_mech_rad = 0.0;
    }
    cfg
}

/// Revolutions to 10x over gain, speed and direction (markdown).
pub fn gain_sweep_table(revs: u32) -> Result<String> {
    let mut s = format!("Revolutions to 10x, forward / reverse (`> {revs}`: not reached):\n\n");
    let mut head = "| gain (1/rad) |".to_string();
    for v in SPEEDS_REV_S {
        head += &format!(" {v} rev/s |");
    }
    s += &head;
    s += &format!("\n|---:|{}\n", "---:|".repeat(SPEEDS_REV_S.len()));
    for g in SWEPT_GAINS {
        let cfg = with_gain(g);
        let mut row = format!("| {g} |");
        for v in SPEEDS_REV_S {
            let f = revs_to_10x(cfg, v, revs)?;
            let r = revs_to_10x(cfg, -v, revs)?;
            row += &format!(" {} / {} |", cell(f, revs), cell(r, revs));
        }
        s += &row;
        s.push('\n');
    }
    Ok(s)
}

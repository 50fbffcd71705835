//! docs/performance.md's `cargo xtask perf` section: every build side by side, the
//! control interrupt by stage and the gate's verdicts, so that a reader compares the
//! builds in one table instead of three. `drive-emu perf` prints each build's full
//! table ([`crate::scenarios::perf_table`]) on the terminal as it runs.

use crate::budget::{self, Status};
use crate::scenarios::Perf;
use std::fmt::Write as _;

/// One measured build: its label and what `perf_run` measured.
pub struct Built<'a> {
    pub label: &'a str,
    pub perf: &'a Perf,
    /// Where the firmware was at its first missed periods (one line each), if any.
    pub missed_at: Vec<String>,
}

fn row(s: &mut String, cells: &[String]) {
    let _ = writeln!(s, "| {} |", cells.join(" | "));
}

/// The section: the budgets, the stages in Run, the gate, and what each build did.
pub fn report(builds: &[Built]) -> String {
    let mut s = budget::budgets_text();
    s.push('\n');
    let heads: Vec<String> = builds
        .iter()
        .map(|b| format!("{} ({} cycles a period)", b.label, b.perf.period_cycles))
        .collect();
    let rule = |n: usize| {
        let mut r = vec!["---".to_string()];
        r.extend(std::iter::repeat_n("---:".to_string(), n));
        r
    };
    // The stages: estimated Cortex-M4 cycles, mean / max over the window in Run.
    let mut head = vec!["stage: est. cycles in Run, mean / max".to_string()];
    head.extend(heads.iter().cloned());
    row(&mut s, &head);
    row(&mut s, &rule(builds.len()));
    let stages = builds.first().map_or(0, |b| b.perf.stages.len());
    for k in 0..stages {
        let mut cells = vec![builds[0].perf.stages[k].0.to_string()];
        cells.extend(builds.iter().map(|b| {
            let (_, _, _, mean, max) = b.perf.stages[k];
            format!("{mean:.0} / {max}")
        }));
        row(&mut s, &cells);
    }
    let mut whole = vec!["**whole interrupt**".to_string()];
    whole.extend(builds.iter().map(|b| {
        format!(
            "**{:.0} / {}**",
            b.perf.isr_cycles_mean, b.perf.isr_cycles_max
        )
    }));
    row(&mut s, &whole);
    let mut share = vec!["share of the period, mean / max".to_string()];
    share.extend(builds.iter().map(|b| {
        let pc = b.perf.period_cycles.max(1) as f64;
        format!(
            "{:.1} % / {:.1} %",
            100.0 * b.perf.isr_cycles_mean / pc,
            100.0 * b.perf.isr_cycles_max as f64 / pc
        )
    }));
    row(&mut s, &share);
    let mut instrs = vec!["executed instructions, mean / max".to_string()];
    instrs.extend(
        builds
            .iter()
            .map(|b| format!("{:.0} / {}", b.perf.isr_instrs_mean, b.perf.isr_instrs_max)),
    );
    row(&mut s, &instrs);
    if let Some(b) = builds.first() {
        let _ = writeln!(
            s,
            "\nThe stages over {:.1} s of Run from the stream's `Run`; the gate below counts the power-up before it too.\n",
            b.perf.window_s
        );
    }
    // The gate: each check's figure and verdict per build.
    let verdicts: Vec<Vec<budget::Verdict>> = builds
        .iter()
        .map(|b| budget::evaluate(&b.perf.budget_measures()))
        .collect();
    let mut head = vec!["the gate: check (budget)".to_string()];
    head.extend(heads.iter().cloned());
    row(&mut s, &head);
    row(&mut s, &rule(builds.len()));
    let checks: Vec<(budget::Check, String)> =
        verdicts.iter().flatten().fold(Vec::new(), |mut acc, v| {
            if !acc.iter().any(|(c, _)| *c == v.check) {
                // A period's cycles differ by build: the label names it.
                let limit = match v.check {
                    budget::Check::TaskRunSpan => "each build's".to_string(),
                    _ => v.limit_text(),
                };
                acc.push((v.check, limit));
            }
            acc
        });
    for (check, limit) in &checks {
        let mut cells = vec![format!("{} ({limit})", check.label())];
        cells.extend(
            verdicts
                .iter()
                .map(|vs| match vs.iter().find(|v| v.check == *check) {
                    None => "—".to_string(),
                    Some(v) => {
                        let mark = match v.status {
                            Status::Pass => "pass",
                            Status::Known { .. } => "known failure",
                            _ => "**FAIL**",
                        };
                        format!("{} {mark}", v.measured_text())
                    }
                }),
        );
        row(&mut s, &cells);
    }
    s.push('\n');
    for (b, vs) in builds.iter().zip(&verdicts) {
        for v in vs.iter().filter(|v| v.status != Status::Pass) {
            let _ = writeln!(s, "- {}: {}", b.label, v.describe());
            if let Some(why) = v.why {
                let _ = writeln!(s, "  ({why})");
            }
        }
    }
    // What each build did on its way to Run.
    for b in builds {
        let p = b.perf;
        let states: Vec<String> = p
            .states
            .iter()
            .map(|(n, t)| format!("{n} {t} ms"))
            .collect();
        let _ = writeln!(s, "- {}: {}", b.label, states.join(" → "));
        let (at_ms, stage, c) = p.powerup_isr_max_at;
        let _ = writeln!(
            s,
            "  - longest control interrupt before Run: {} est. cycles, ending at {at_ms:.1} ms, {c} of them in {stage}; adaptation task's longest run {} est. cycles before Run, {} in Run (preemptions included)",
            p.powerup_isr_max.1, p.powerup_task_max.0, p.task_max.0
        );
        if p.banks.len() > 1 {
            let banks: Vec<String> = p
                .banks
                .iter()
                .map(|b| format!("`{}`", b.join(", ")))
                .collect();
            let _ = writeln!(s, "  - path banks streamed: {}", banks.join(" → "));
        }
        for l in &b.missed_at {
            let _ = writeln!(s, "  - {l}");
        }
    }
    s
}

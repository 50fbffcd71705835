//! The results page's tables (docs/results.md), filled into the template by `page.rs`:
//! methods by conditions, each figure in mrad or as a ratio.

use super::stats::{Condition, Dist, Summary};
use super::{Distribution, Method, Plan, SPECTRUM_HARMONICS_OF_THETA_S};
use std::fmt::Write as _;

/// Three significant digits (no exponent); a dash for no value.
pub(crate) fn sig3(v: f64) -> String {
    match v {
        v if !v.is_finite() => "—".into(),
        v if v >= 100.0 => format!("{v:.0}"),
        v if v >= 10.0 => format!("{v:.1}"),
        v if v >= 1.0 => format!("{v:.2}"),
        v => format!("{v:.3}"),
    }
}

pub(crate) fn mrad(rad: f64) -> String {
    sig3(rad * 1e3)
}

pub(crate) fn ratio(r: f64) -> String {
    if r.is_finite() {
        format!("{}x", sig3(r))
    } else {
        "—".into()
    }
}

fn label(m: Method) -> String {
    match m.is_extra() {
        true => format!("*{}*", m.label()),
        false => m.label().to_string(),
    }
}

fn revs(d: &Dist) -> String {
    match d.count {
        0 => "—".into(),
        _ => format!("{:.1} / {:.1} / {:.1}", d.median, d.p95, d.worst),
    }
}

/// "N.Nx less" or "N.Nx more": the error `a` leaves against `b`.
pub(crate) fn versus(a: f64, b: f64) -> String {
    match (a, b) {
        (a, b) if !(a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite()) => "—".into(),
        (a, b) if a <= b => format!("{} less", ratio(b / a)),
        (a, b) => format!("{} more", ratio(a / b)),
    }
}

/// A markdown table: `head` is its header row and alignment row.
pub(crate) fn table(head: &str, rows: impl IntoIterator<Item = Vec<String>>) -> String {
    let mut t = format!("{head}\n");
    for r in rows {
        let _ = writeln!(t, "| {} |", r.join(" | "));
    }
    t
}

/// Each method's row of `cells`, labelled.
fn by_method(cells: impl Fn(Method) -> Vec<String>) -> impl Iterator<Item = Vec<String>> {
    Method::ALL
        .into_iter()
        .map(move |m| [vec![label(m)], cells(m)].concat())
}

const RESIDUAL_HEAD: &str = "| method | pk-pk median | pk-pk p95 | pk-pk worst | RMS median \
    | RMS p95 | RMS worst | median ÷ oracle | raw p95 ÷ p95 |";

/// pk-pk and RMS (median, p95, worst), ÷ oracle and the p95 reduction of `m` in `c`.
fn residual_cells(c: &Condition, m: Method) -> Vec<String> {
    let st = c.get(m);
    let dists = [st.pk_pk, st.rms];
    let mut r: Vec<String> = dists
        .iter()
        .flat_map(|d| [d.median, d.p95, d.worst].map(mrad))
        .collect();
    r.extend([ratio(c.ratio_to_oracle(m)), ratio(c.p95_reduction(m))]);
    r
}

/// The main table: each sensor's worst evaluated phase (also printed by the command).
pub(crate) fn main_table(s: &Summary, plan: &Plan) -> String {
    let head = format!(
        "{RESIDUAL_HEAD} revolutions to converge (median / p95 / worst) | loss of lock |\n|---|{}",
        "---:|".repeat(10)
    );
    table(
        &head,
        by_method(|m| {
            let t = s.trackers.iter().find(|t| t.method == m);
            let conv = match (m, t) {
                (Method::Raw | Method::Oracle, _) => "—".into(),
                (_, Some(t)) if t.never_converged > 0 => {
                    format!("{} (never: {})", revs(&t.converged_revs), t.never_converged)
                }
                (_, Some(t)) => revs(&t.converged_revs),
                (_, None) => format!("{} (calibration spin)", plan.calibration_revs),
            };
            let lock = t.map_or("—".into(), |t| {
                let pct = 100.0 * t.lost_lock as f64 / s.sensors.max(1) as f64;
                format!("{} of {} ({pct:.1} %)", t.lost_lock, s.sensors)
            });
            [residual_cells(&s.worst_phase, m), vec![conv, lock]].concat()
        }),
    )
}

/// Methods × conditions (phases, then each sensor's worst), one figure per cell.
fn overview(s: &Summary, cell: impl Fn(&Condition, Method) -> String) -> String {
    let names: Vec<&str> = s.phases.iter().map(|c| c.name.as_str()).collect();
    let n = names.len() + 1;
    let head = format!(
        "| method | {} | worst phase |\n|---|{}",
        names.join(" | "),
        "---:|".repeat(n)
    );
    table(
        &head,
        by_method(|m| {
            s.phases
                .iter()
                .chain([&s.worst_phase])
                .map(|c| cell(c, m))
                .collect()
        }),
    )
}

/// Every table the template may name.
pub(crate) fn tables(s: &Summary, plan: &Plan, d: &Distribution) -> [(&'static str, String); 7] {
    let details = s.phases.iter().map(|c| {
        let t = table(
            &format!("{RESIDUAL_HEAD}\n|---|{}", "---:|".repeat(8)),
            by_method(|m| residual_cells(c, m)),
        );
        format!(
            "<details><summary>{}: all statistics</summary>\n\n{t}\n</details>",
            c.name
        )
    });
    let orders: Vec<String> = (1..=SPECTRUM_HARMONICS_OF_THETA_S)
        .map(|k| format!("m = {k}"))
        .collect();
    let spectrum_head = format!(
        "| method | {} |\n|---|{}",
        orders.join(" | "),
        "---:|".repeat(orders.len())
    );
    let spectrum = by_method(|m| {
        s.spectrum_median_rad[m.index()]
            .iter()
            .map(|a| mrad(*a))
            .collect()
    });
    [
        ("table.main", main_table(s, plan)),
        (
            "table.medians",
            overview(s, |c, m| {
                format!(
                    "{} ({})",
                    mrad(c.get(m).pk_pk.median),
                    mrad(c.get(m).pk_pk.p95)
                )
            }),
        ),
        (
            "table.ratios",
            overview(s, |c, m| ratio(c.ratio_to_oracle(m))),
        ),
        ("table.details", details.collect::<Vec<_>>().join("\n\n")),
        ("table.spectrum", table(&spectrum_head, spectrum)),
        ("table.phases", plan.table()),
        ("table.distribution", d.table()),
    ]
}

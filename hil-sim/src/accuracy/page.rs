//! The results page (docs/results.md): the hand-written `results.template.md` beside
//! this file, its `{{name}}` placeholders filled from the run's [`Summary`]. The prose
//! lives in the template; this file only names the run's figures and builds the tables.

use super::report::RunInfo;
use super::stats::{Condition, Dist, Summary};
use super::{
    Method, Plan, BINS, DISTRIBUTION, SAMPLE_PERIOD_S, SENSOR_PERIODS,
    SPECTRUM_HARMONICS_OF_THETA_S, SPECTRUM_PHASE,
};
use crate::plant::MotorParams;
use anyhow::{anyhow, Result};
use std::collections::BTreeMap;
use std::fmt::Write as _;

pub const TEMPLATE: &str = include_str!("results.template.md");

/// Three significant digits (no exponent); a dash for no value.
fn sig3(v: f64) -> String {
    match v {
        v if !v.is_finite() => "—".into(),
        v if v >= 100.0 => format!("{v:.0}"),
        v if v >= 10.0 => format!("{v:.1}"),
        v if v >= 1.0 => format!("{v:.2}"),
        v => format!("{v:.3}"),
    }
}

fn mrad(rad: f64) -> String {
    sig3(rad * 1e3)
}

fn ratio(r: f64) -> String {
    if r.is_finite() {
        format!("{}x", sig3(r))
    } else {
        "—".into()
    }
}

/// "N.Nx less" or "N.Nx more": the error `a` leaves against `b`.
fn versus(a: f64, b: f64) -> String {
    match (a, b) {
        (a, b) if !(a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite()) => "—".into(),
        (a, b) if a <= b => format!("{} less", ratio(b / a)),
        (a, b) => format!("{} more", ratio(a / b)),
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

fn tables(s: &Summary, plan: &Plan) -> [(&'static str, String); 7] {
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
        ("table.distribution", DISTRIBUTION.table()),
    ]
}

/// Every figure the template may name.
fn values(s: &Summary, plan: &Plan, info: &RunInfo) -> BTreeMap<String, String> {
    let mut v = BTreeMap::new();
    let mut put = |k: String, x: String| v.insert(k, x);
    let eval = plan.evaluation();
    let conditions = eval
        .iter()
        .map(|p| p.key)
        .zip(&s.phases)
        .chain([("worst", &s.worst_phase)]);
    for (c, cond) in conditions {
        for m in Method::ALL {
            let (k, st) = (m.key(), cond.get(m));
            put(format!("{k}.{c}"), mrad(st.pk_pk.median));
            put(format!("{k}.{c}.p95"), mrad(st.pk_pk.p95));
            put(format!("{k}.{c}.x"), ratio(cond.ratio_to_oracle(m)));
            put(format!("{k}.{c}.red"), ratio(cond.p95_reduction(m)));
            put(
                format!("{k}.{c}.vs"),
                versus(cond.get(Method::Ours).pk_pk.median, st.pk_pk.median),
            );
        }
    }
    for m in Method::ALL {
        let (k, w) = (m.key(), &s.worst_phase);
        let per_phase = s
            .phases
            .iter()
            .map(|c| (c.ratio_to_oracle(m), c.name.as_str()));
        let (worst, name) = per_phase.fold((0.0, ""), |a, b| if b.0 > a.0 { b } else { a });
        put(format!("{k}.phase_max.x"), ratio(worst));
        put(format!("{k}.phase_max"), name.to_string());
        let yes = |met: bool| if met { "yes" } else { "**no**" }.to_string();
        put(
            format!("{k}.met.median"),
            yes(w.ratio_to_oracle(m) <= 1.5 && worst <= 1.5),
        );
        put(format!("{k}.met.p95"), yes(w.p95_reduction(m) >= 100.0));
        let spec = &s.spectrum_median_rad[m.index()];
        for (h, a) in spec.iter().enumerate() {
            put(format!("{k}.m{}", h + 1), mrad(*a));
        }
        let power = |r: std::ops::Range<usize>| spec[r].iter().map(|a| a * a).sum::<f64>();
        // Rounded down ("at least"), so that a near-total does not read 100 %.
        let share = (1e3 * power(4..7) / power(0..SPECTRUM_HARMONICS_OF_THETA_S))
            .floor()
            .min(999.0)
            / 10.0;
        put(format!("{k}.share_m5_7"), format!("{share:.1} %"));
        let Some(t) = s.trackers.iter().find(|t| t.method == m) else {
            continue;
        };
        let d = t.converged_revs;
        put(format!("{k}.conv"), format!("{:.1}", d.median));
        put(
            format!("{k}.conv.all"),
            format!(
                "median {:.2}, p95 {:.2}, worst {:.2}",
                d.median, d.p95, d.worst
            ),
        );
        put(
            format!("{k}.met.conv"),
            yes(t.never_converged == 0 && d.worst <= 5.0),
        );
        put(format!("{k}.met.lock"), yes(t.lost_lock == 0));
        for (n, x) in [
            ("never", t.never_converged),
            ("late", t.not_converged_in_commissioning),
            ("lost", t.lost_lock),
            ("faults", t.any_fault),
        ] {
            put(format!("{k}.{n}"), x.to_string());
        }
        put(format!("{k}.late.mrad"), mrad(t.late_pk_pk_median_rad));
        put(format!("{k}.all.mrad"), mrad(t.all_pk_pk_median_rad));
    }
    for (k, t) in tables(s, plan) {
        put(k.into(), t);
    }
    // The observer's angle lag under an unmodelled torque step: ΔT/K_so, with
    // K_so = Ĵ(λ1λ2 + λ1λ3 + λ2λ3) of the default observer and this motor's J.
    let motor = MotorParams::default();
    let step = eval
        .iter()
        .flat_map(|p| &p.load_steps)
        .map(|(_, pu)| pu.abs())
        .fold(0.0, f64::max);
    let step_nm = step * motor.rated_torque_nm;
    let [l1, l2, l3] = mras::Config::default()
        .observer
        .eigenvalues_hz
        .map(|f| std::f64::consts::TAU * f as f64);
    let k_so = motor.j_kg_m2 * (l1 * l2 + l1 * l3 + l2 * l3);
    let cogging = plan
        .cogging
        .iter()
        .map(|(h, pu)| format!("{:.0} % at harmonic {h}", pu * 100.0));
    let mut note = String::new();
    if info.reduced {
        note += " **Reduced variant** (CI size): the published page has 500 sensors.";
    }
    if let Some(n) = s.fit_failures.iter().max().filter(|n| **n > 0) {
        let _ = write!(
            note,
            " Offline fits failed on up to {n} sensors per method (no value there)."
        );
    }
    for (k, x) in [
        ("run.command", info.command()),
        ("run.sensors", info.sensors.to_string()),
        ("run.seed", info.seed.to_string()),
        ("run.duration_s", format!("{:.2}", plan.duration_s())),
        ("run.rate_khz", format!("{:.0}", 1e-3 / SAMPLE_PERIOD_S)),
        ("run.wall_s", format!("{:.0}", info.wall_s)),
        ("run.threads", info.threads.to_string()),
        ("run.note", note),
        ("plan.n", SENSOR_PERIODS.to_string()),
        ("plan.bins", BINS.to_string()),
        (
            "plan.bin_deg",
            format!("{}", 360 / (BINS * SENSOR_PERIODS as usize)),
        ),
        ("plan.cal_revs", plan.calibration_revs.to_string()),
        ("plan.speed_loop_hz", plan.speed_loop_hz.to_string()),
        ("plan.cogging", cogging.collect::<Vec<_>>().join(", ")),
        ("plan.step_nm", format!("{step_nm:.2}")),
        ("plan.k_so", format!("{k_so:.1}")),
        ("plan.lag_mrad", format!("{:.0}", 1e3 * step_nm / k_so)),
        ("spectrum.phase", eval[SPECTRUM_PHASE].name.into()),
    ] {
        put(k.into(), x);
    }
    v
}

/// The page: [`TEMPLATE`] filled, plots linked from `plots`.
pub(crate) fn markdown(s: &Summary, plan: &Plan, info: &RunInfo, plots: &str) -> Result<String> {
    let page = render(TEMPLATE, &values(s, plan, info))?;
    Ok(page.replace("](results/", &format!("]({plots}/")))
}

/// `template` with each `{{name}}` replaced by its value; an unknown name is an error
/// that gives the template's line.
pub fn render(template: &str, values: &BTreeMap<String, String>) -> Result<String> {
    let mut out = String::with_capacity(2 * template.len());
    let mut rest = template;
    while let Some(at) = rest.find("{{") {
        let line = template[..template.len() - rest.len() + at]
            .matches('\n')
            .count()
            + 1;
        let end = rest[at..]
            .find("}}")
            .ok_or_else(|| anyhow!("results template line {line}: `{{{{` without `}}}}`"))?;
        let name = &rest[at + 2..at + end];
        let value = values
            .get(name)
            .ok_or_else(|| anyhow!("results template line {line}: no figure named `{name}`"))?;
        out += &rest[..at];
        out += value;
        rest = &rest[at + end + 2..];
    }
    Ok(out + rest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_fills_and_names_the_line_of_an_unknown_figure() {
        let v = BTreeMap::from([("a.b".to_string(), "1.5x".to_string())]);
        assert_eq!(render("x {{a.b}} y", &v).unwrap(), "x 1.5x y");
        let e = render("one\ntwo {{a.c}}", &v).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("`a.c`"), "{e}");
        assert!(render("{{a.b", &v)
            .unwrap_err()
            .to_string()
            .contains("line 1"));
    }
}

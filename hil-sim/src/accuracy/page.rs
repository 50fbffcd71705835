//! The results page (docs/results.md): the hand-written `results.template.md` beside
//! this file, its `{{name}}` placeholders filled from the run's [`Summary`]. The prose
//! lives in the template; this file names the run's figures, `tables.rs` builds the
//! tables, and the plan and the run name their own (`Plan::figures`, `RunInfo::figures`).
//! A sentence that compares figures is a figure here too (`versus`, `within`), so the
//! template states no verdict a new run could contradict.
//!
//! The figures are also written as JSON (`docs/figures/accuracy.json`, and the reduced
//! variant's `accuracy-reduced.json`, prefixed `reduced.`): `cargo xtask docs --check`
//! renders the page from them with the same [`docgen::render`] and compares.

use super::report::{RunInfo, Suite};
use super::tables::{mrad, ratio, tables, versus};
use super::{Method, SPECTRUM_HARMONICS_OF_THETA_S};
use anyhow::{anyhow, Result};
use std::collections::BTreeMap;

pub const TEMPLATE: &str = include_str!("results.template.md");
/// The README's paragraph on the benchmark (`docs/figures/accuracy-summary.md`).
pub const SUMMARY_TEMPLATE: &str = include_str!("summary.template.md");
/// The prefix of the reduced variant's figures on the page.
pub const REDUCED_PREFIX: &str = "reduced.";

/// Every figure the template may name: the first suite's by name, the others' with the
/// prefix `n<N>.` (`n1.ours_data.load.x`).
pub fn values(suites: &[&Suite], info: &RunInfo) -> BTreeMap<String, String> {
    let mut v = BTreeMap::new();
    for (i, suite) in suites.iter().enumerate() {
        let prefix = match i {
            0 => String::new(),
            _ => format!("n{}.", suite.population.sensor_periods),
        };
        for (k, x) in suite_values(suite, info) {
            v.insert(format!("{prefix}{k}"), x);
        }
    }
    v
}

/// One suite's figures.
fn suite_values(suite: &Suite, info: &RunInfo) -> BTreeMap<String, String> {
    let (s, plan) = (&suite.summary, &suite.plan);
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
        put(format!("{k}.within"), within(s, m, 1.5));
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
    for (k, t) in tables(s, plan, suite.population) {
        put(k.into(), t);
    }
    put("population".into(), suite.population.name.into());
    put("n".into(), suite.population.sensor_periods.to_string());
    let surveyed = suite.results.iter().filter_map(|r| r.survey.as_ref());
    let (mut banks, mut full, mut left) = (0, 0, 0);
    let (mut rounds, mut paths) = (Vec::new(), Vec::new());
    for o in surveyed {
        banks += 1;
        full += (o.bank.as_slice().len() == mras::MAX_PATHS) as usize;
        left += !o.unobserved.is_empty() as usize;
        rounds.push(o.rounds as f64);
        paths.push(o.bank.as_slice().len() as f64);
    }
    put("survey.max_paths".into(), mras::MAX_PATHS.to_string());
    put("survey.banks".into(), banks.to_string());
    put("survey.full".into(), full.to_string());
    put("survey.left".into(), left.to_string());
    // Median and maximum over the banks.
    for (key, mut v) in [("survey.rounds", rounds), ("survey.paths", paths)] {
        v.sort_by(f64::total_cmp);
        let shown = |x: Option<&f64>| x.map_or("—".into(), |x| format!("{x:.0}"));
        put(key.into(), shown(v.get(v.len() / 2)));
        put(format!("{key}_max"), shown(v.last()));
    }
    for (k, x) in info.figures(s, plan).into_iter().chain(plan.figures()) {
        put(k.into(), x);
    }
    v
}

/// "every phase" or "k of n phases (not: a, b)": where the median of `m` is within
/// `bound` times the oracle's.
fn within(s: &super::stats::Summary, m: Method, bound: f64) -> String {
    let over: Vec<&str> = s
        .phases
        .iter()
        // A ratio that is not a number is not within the bound either.
        .filter(|c| c.ratio_to_oracle(m).is_nan() || c.ratio_to_oracle(m) > bound)
        .map(|c| c.name.as_str())
        .collect();
    match over.len() {
        0 => "every phase".into(),
        k => format!(
            "{} of {} phases (not: {})",
            s.phases.len() - k,
            s.phases.len(),
            over.join(", ")
        ),
    }
}

/// The page: [`TEMPLATE`] filled with `values` (the reduced variant's among them, with
/// [`REDUCED_PREFIX`]), plots linked from `plots`.
pub(crate) fn markdown(values: &BTreeMap<String, String>, plots: &str) -> Result<String> {
    let page = render(TEMPLATE, values)?;
    Ok(page.replace("](results/", &format!("]({plots}/")))
}

/// `values` and `reduced` (with [`REDUCED_PREFIX`]) in one map: what the page names.
pub fn page_values(
    values: &BTreeMap<String, String>,
    reduced: &BTreeMap<String, String>,
) -> BTreeMap<String, String> {
    let mut all = values.clone();
    all.extend(
        reduced
            .iter()
            .map(|(k, v)| (format!("{REDUCED_PREFIX}{k}"), v.clone())),
    );
    all
}

/// `template` with each `{{name}}` replaced by its value; an unknown name is an error
/// that gives the template's line.
pub fn render(template: &str, values: &BTreeMap<String, String>) -> Result<String> {
    docgen::render(template, values).map_err(|e| anyhow!("results {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_names_the_line_of_an_unknown_figure() {
        let v = BTreeMap::from([("a.b".to_string(), "1.5x".to_string())]);
        assert_eq!(render("x {{a.b}} y", &v).unwrap(), "x 1.5x y");
        let e = render("one\ntwo {{a.c}}", &v).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("`a.c`"), "{e}");
    }
}

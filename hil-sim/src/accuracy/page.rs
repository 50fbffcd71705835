//! The results page (docs/results.md): the hand-written `results.template.md` beside
//! this file, its `{{name}}` placeholders filled from the run's [`Summary`]. The prose
//! lives in the template; this file names the run's figures, `tables.rs` builds the
//! tables, and the plan and the run name their own (`Plan::figures`, `RunInfo::figures`).

use super::report::{RunInfo, Suite};
use super::tables::{mrad, ratio, tables, versus};
use super::{Method, SPECTRUM_HARMONICS_OF_THETA_S};
use anyhow::{anyhow, Result};
use std::collections::BTreeMap;

pub const TEMPLATE: &str = include_str!("results.template.md");

/// Every figure the template may name: the first suite's by name, the others' with the
/// prefix `n<N>.` (`n1.ours_data.load.x`).
fn values(suites: &[&Suite], info: &RunInfo) -> BTreeMap<String, String> {
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

/// The page: [`TEMPLATE`] filled, plots linked from `plots`.
pub(crate) fn markdown(suites: &[&Suite], info: &RunInfo, plots: &str) -> Result<String> {
    let page = render(TEMPLATE, &values(suites, info))?;
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

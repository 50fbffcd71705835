//! Aggregation over sensors: median, 95th percentile and worst case per method.

use super::{Method, Plan, Residual, SensorResult, SPECTRUM_HARMONICS_OF_THETA_S, SPECTRUM_PHASE};

/// Order statistics of one metric over the sensors that have it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dist {
    pub median: f64,
    pub p95: f64,
    pub worst: f64,
    /// Sensors with a finite value.
    pub count: usize,
}

impl Dist {
    /// Nearest-rank percentiles of the finite values; NaN everywhere when there is none.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let rank = |q: f64| {
            let n = v.len();
            v[((q * n as f64).ceil() as usize).clamp(1, n) - 1]
        };
        if v.is_empty() {
            return Self {
                median: f64::NAN,
                p95: f64::NAN,
                worst: f64::NAN,
                count: 0,
            };
        }
        Self {
            median: rank(0.5),
            p95: rank(0.95),
            worst: v[v.len() - 1],
            count: v.len(),
        }
    }
}

/// A method's residual over sensors in one condition (rad, mechanical).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MethodStats {
    pub pk_pk: Dist,
    pub rms: Dist,
}

impl MethodStats {
    fn of(residuals: impl Iterator<Item = Residual> + Clone) -> Self {
        Self {
            pk_pk: Dist::of(residuals.clone().map(|r| r.pk_pk_rad)),
            rms: Dist::of(residuals.map(|r| r.rms_rad)),
        }
    }
}

/// One condition (an evaluated phase, or each sensor's worst phase) for every method.
#[derive(Clone, Debug)]
pub struct Condition {
    pub name: String,
    /// In [`Method::ALL`] order.
    pub methods: Vec<MethodStats>,
}

impl Condition {
    pub fn get(&self, m: Method) -> &MethodStats {
        &self.methods[m.index()]
    }

    /// Median pk-pk of `m` over the oracle's.
    pub fn ratio_to_oracle(&self, m: Method) -> f64 {
        self.get(m).pk_pk.median / self.get(Method::Oracle).pk_pk.median
    }

    /// 95th percentile pk-pk of raw over that of `m`.
    pub fn p95_reduction(&self, m: Method) -> f64 {
        self.get(Method::Raw).pk_pk.p95 / self.get(m).pk_pk.p95
    }
}

/// A tracker's convergence and health over the sensors.
#[derive(Clone, Debug)]
pub struct TrackerStats {
    pub method: Method,
    /// Revolutions to `converged`, over the sensors where it happened.
    pub converged_revs: Dist,
    /// Sensors where `converged` never held during the run.
    pub never_converged: usize,
    /// Sensors where it did not hold by the end of commissioning.
    pub not_converged_in_commissioning: usize,
    pub lost_lock: usize,
    pub any_fault: usize,
    /// Median pk-pk residual in the first evaluated phase of the sensors not converged
    /// by the end of commissioning, and of all (rad): what the late ones have in common.
    pub late_pk_pk_median_rad: f64,
    pub all_pk_pk_median_rad: f64,
}

/// Everything the results page shows.
#[derive(Clone, Debug)]
pub struct Summary {
    pub sensors: usize,
    /// Each sensor's largest residual over the evaluated phases.
    pub worst_phase: Condition,
    /// Per evaluated phase.
    pub phases: Vec<Condition>,
    pub trackers: Vec<TrackerStats>,
    /// Per method (in [`Method::ALL`] order): sensors whose calibration failed to fit.
    pub fit_failures: Vec<usize>,
    /// Per method: median over sensors of the amplitude of error harmonic m = 1.. in
    /// the spectrum phase (rad, mechanical).
    pub spectrum_median_rad: Vec<[f64; SPECTRUM_HARMONICS_OF_THETA_S]>,
}

pub fn summarise(results: &[SensorResult], plan: &Plan) -> Summary {
    let condition = |name: String, f: &dyn Fn(&SensorResult, Method) -> Residual| Condition {
        name,
        methods: Method::ALL
            .iter()
            .map(|&m| MethodStats::of(results.iter().map(|r| f(r, m))))
            .collect(),
    };
    let phases = plan
        .evaluation()
        .iter()
        .enumerate()
        .map(|(i, p)| condition(p.name.to_string(), &|r, m| r.residual(i, m)))
        .collect();
    let trackers = Method::MRAS
        .iter()
        .enumerate()
        .map(|(i, &method)| {
            let o = results.iter().map(|r| &r.mras[i]);
            TrackerStats {
                method,
                converged_revs: Dist::of(o.clone().filter_map(|t| t.converged_revs)),
                never_converged: o.clone().filter(|t| t.converged_revs.is_none()).count(),
                not_converged_in_commissioning: o
                    .clone()
                    .filter(|t| !t.converged_in_commissioning)
                    .count(),
                lost_lock: o.clone().filter(|t| t.lost_lock).count(),
                any_fault: o.filter(|t| t.first_fault.is_some()).count(),
                late_pk_pk_median_rad: Dist::of(
                    results
                        .iter()
                        .filter(|r| !r.mras[i].converged_in_commissioning)
                        .map(|r| r.residual(SPECTRUM_PHASE, method).pk_pk_rad),
                )
                .median,
                all_pk_pk_median_rad: Dist::of(
                    results
                        .iter()
                        .map(|r| r.residual(SPECTRUM_PHASE, method).pk_pk_rad),
                )
                .median,
            }
        })
        .collect();
    let spectrum_median_rad = Method::ALL
        .iter()
        .map(|m| {
            std::array::from_fn(|k| {
                Dist::of(results.iter().map(|r| r.spectrum_rad[m.index()][k])).median
            })
        })
        .collect();
    Summary {
        sensors: results.len(),
        spectrum_median_rad,
        worst_phase: condition("worst evaluated phase".into(), &|r, m| r.worst(m)),
        phases,
        trackers,
        fit_failures: Method::ALL
            .iter()
            .map(|m| {
                results
                    .iter()
                    .filter(|r| r.fit_failures.iter().any(|(f, _)| f == m))
                    .count()
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles_skip_nan() {
        let d = Dist::of((1..=100).map(f64::from).chain([f64::NAN]));
        assert_eq!(
            (d.median, d.p95, d.worst, d.count),
            (50.0, 95.0, 100.0, 100)
        );
        let one = Dist::of([3.0]);
        assert_eq!((one.median, one.p95, one.worst), (3.0, 3.0, 3.0));
        assert!(Dist::of([f64::NAN]).median.is_nan());
    }
}

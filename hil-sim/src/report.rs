//! Scenario output: the printed summary, CSV time series, JSON summary and plots.

use crate::plots::{self, Series};
use crate::scenario::{
    path_name, NamedCoefficient, RunOutcome, RunSummary, Scenario, SPECTRUM_HARMONICS_OF_THETA_RM,
};
use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::Path;

/// The side-by-side summary of a scenario's runs.
/// `reference`: the exact decoupling coefficients of the scenario's sensor, if known
/// (see [`crate::scenario::reference_coefficients`]).
pub fn summary_text(
    sc: &Scenario,
    runs: &[&RunSummary],
    reference: Option<&[NamedCoefficient]>,
) -> String {
    let f = &sc.file;
    let mut s = String::new();
    let _ = writeln!(s, "scenario {}: {}", f.name, f.description);
    let _ = writeln!(
        s,
        "  {:.2} s simulated at {:.0} kHz, MRAS enabled at {:.2} s",
        runs.first().map_or(0.0, |r| r.duration_s),
        f.sample_rate_hz / 1e3,
        f.mras_enable_s
    );
    let mut head = format!("  {:<44}", "");
    for r in runs {
        head += &format!("{:>16}", r.variant.label());
    }
    let _ = writeln!(s, "{head}");
    type Getter = fn(&RunSummary) -> String;
    let lines: [(&str, Getter); 10] = [
        ("raw sensor spatial error, pk-pk (mrad)", |r| {
            format!("{:.3}", r.after.raw_pk_pk_mrad)
        }),
        ("raw sensor spatial error, RMS (mrad)", |r| {
            format!("{:.3}", r.after.raw_rms_mrad)
        }),
        ("θ̂ spatial error before MRAS, pk-pk (mrad)", |r| {
            r.before
                .as_ref()
                .map_or("-".into(), |b| format!("{:.3}", b.estimate_pk_pk_mrad))
        }),
        ("θ̂ spatial error at the end, pk-pk (mrad)", |r| {
            format!("{:.4}", r.after.estimate_pk_pk_mrad)
        }),
        ("θ̂ spatial error at the end, RMS (mrad)", |r| {
            format!("{:.4}", r.after.estimate_rms_mrad)
        }),
        ("tracking error θ*-θ̂ before, pk-pk (mrad)", |r| {
            r.before
                .as_ref()
                .map_or("-".into(), |b| format!("{:.3}", b.tracking_pk_pk_mrad))
        }),
        ("tracking error θ*-θ̂ at the end, pk-pk (mrad)", |r| {
            format!("{:.3}", r.after.tracking_pk_pk_mrad)
        }),
        ("reduction of raw spatial error (x)", |r| {
            format!(
                "{:.0}",
                r.after.raw_pk_pk_mrad / r.after.estimate_pk_pk_mrad
            )
        }),
        ("converged after (s / rev)", |r| {
            match (r.converged_after_s, r.converged_after_revs) {
                (Some(s), Some(n)) => format!("{s:.2} / {n:.1}"),
                _ => "not reached".into(),
            }
        }),
        ("faulted samples", |r| r.faults.to_string()),
    ];
    for (label, get) in lines {
        let mut line = format!("  {label:<44}");
        for r in runs {
            line += &format!("{:>16}", get(r));
        }
        let _ = writeln!(s, "{line}");
    }
    let _ = writeln!(
        s,
        "  final coefficients (scaled units){}:",
        if reference.is_some() {
            "; truth: the sensor's exact fixed point"
        } else {
            ""
        }
    );
    if let Some(first) = runs.first() {
        let mut head = format!("    {:<42}", "");
        for r in runs {
            head += &format!("{:>16}", r.variant.label());
        }
        if reference.is_some() {
            head += &format!("{:>16}", "truth");
        }
        let _ = writeln!(s, "{head}");
        let cell = |re: f32, im: f32| format!("{:>16}", format!("{re:+.4}{im:+.4}j"));
        for (i, (name, _, _)) in first.coefficients.iter().enumerate() {
            let mut line = format!("    {name:<42}");
            for r in runs {
                if let Some((_, re, im)) = r.coefficients.get(i) {
                    line += &cell(*re, *im);
                }
            }
            if let Some((_, re, im)) = reference.and_then(|r| r.get(i)) {
                line += &cell(*re, *im);
            }
            let _ = writeln!(s, "{line}");
        }
    }
    s
}

fn write_csv(path: &Path, out: &RunOutcome) -> Result<()> {
    let err = |e: csv::Error| anyhow::Error::new(e).context(path.display().to_string());
    let mut w = csv::Writer::from_path(path).map_err(err)?;
    let mut head: Vec<String> = [
        "t_s",
        "theta_rad",
        "theta_hat_rad",
        "omega_rad_s",
        "omega_hat_rad_s",
        "tracking_error_rad",
        "torque_cmd_nm",
        "x",
        "y",
        "zd_x",
        "zd_y",
    ]
    .map(String::from)
    .to_vec();
    if let Some(r) = out.rows.first() {
        for (k, _) in r.coefficients.iter() {
            head.push(format!("{}_re", path_name(k)));
            head.push(format!("{}_im", path_name(k)));
        }
    }
    w.write_record(&head).map_err(err)?;
    for r in &out.rows {
        let mut rec = vec![
            r.t_s.to_string(),
            r.theta_rad.to_string(),
            r.theta_hat_rad.to_string(),
            r.omega_rad_s.to_string(),
            r.omega_hat_rad_s.to_string(),
            r.tracking_error_rad.to_string(),
            r.torque_cmd_nm.to_string(),
            r.x.to_string(),
            r.y.to_string(),
            r.zd_x.to_string(),
            r.zd_y.to_string(),
        ];
        for (_, v) in r.coefficients.iter() {
            rec.push(v.re.to_string());
            rec.push(v.im.to_string());
        }
        w.write_record(&rec).map_err(err)?;
    }
    w.flush().with_context(|| path.display().to_string())
}

/// Write `timeseries.csv`, `summary.json` and the plots of one run into `dir`.
pub fn write_run(dir: &Path, out: &RunOutcome, with_plots: bool) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    write_csv(&dir.join("timeseries.csv"), out)?;
    let json = serde_json::to_string_pretty(&out.summary)?;
    std::fs::write(dir.join("summary.json"), json)
        .with_context(|| dir.join("summary.json").display().to_string())?;
    if !with_plots {
        return Ok(());
    }
    let s = &out.summary;
    let title = |what: &str| format!("{} ({}): {what}", s.scenario, s.variant.label());

    // Sensor vector image before/after decoupling (paper Fig. 8a).
    let half = out.rows.len() / 2;
    let raw: Vec<(f64, f64)> = out.rows.iter().map(|r| (r.x as f64, r.y as f64)).collect();
    let dec: Vec<(f64, f64)> = out.rows[half..]
        .iter()
        .map(|r| (r.zd_x as f64, r.zd_y as f64))
        .collect();
    let circle: Vec<(f64, f64)> = (0..=360)
        .map(|i| {
            let a = (i as f64).to_radians();
            (a.cos(), a.sin())
        })
        .collect();
    plots::vector_image(
        &dir.join("sensor_image"),
        &title("sensor vector"),
        &[
            Series {
                label: "measured",
                points: &raw,
            },
            Series {
                label: "decoupled (2nd half)",
                points: &dec,
            },
            Series {
                label: "unit circle",
                points: &circle,
            },
        ],
    )?;

    // Coefficient convergence (Fig. 8b-e).
    let mut coef_series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    if let Some(first) = out.rows.first() {
        for (i, (k, _)) in first.coefficients.iter().enumerate() {
            for part in ["re", "im"] {
                let pts = out
                    .rows
                    .iter()
                    .map(|r| {
                        let v = r.coefficients.iter().nth(i).map_or(0.0, |(_, v)| {
                            if part == "re" {
                                v.re
                            } else {
                                v.im
                            }
                        });
                        (r.t_s, v as f64)
                    })
                    .collect();
                coef_series.push((format!("{} {part}", path_name(k)), pts));
            }
        }
    }
    let series: Vec<Series> = coef_series
        .iter()
        .map(|(l, p)| Series {
            label: l,
            points: p,
        })
        .collect();
    plots::line_chart(
        &dir.join("coefficients"),
        &title("decoupling coefficients"),
        "time (s)",
        "coefficient (scaled units)",
        &series,
    )?;

    // Position error vs time (less its final constant, which no sensor can observe:
    // an N-period sensor knows θrm only modulo 2π/N), and vs angle at the end.
    let tail = &out.rows[out.rows.len() * 4 / 5..];
    let offset = tail
        .iter()
        .map(|r| r.theta_hat_rad - r.theta_rad)
        .sum::<f64>()
        / tail.len().max(1) as f64;
    let est_err: Vec<(f64, f64)> = out
        .rows
        .iter()
        .map(|r| (r.t_s, (r.theta_hat_rad - r.theta_rad - offset) * 1e3))
        .collect();
    let track: Vec<(f64, f64)> = out
        .rows
        .iter()
        .map(|r| (r.t_s, r.tracking_error_rad * 1e3))
        .collect();
    plots::line_chart(
        &dir.join("error_vs_time"),
        &title("position error"),
        "time (s)",
        "error (mrad)",
        &[
            Series {
                label: "estimate θ̂ - θ (constant removed)",
                points: &est_err,
            },
            Series {
                label: "tracking θ* - θ̂",
                points: &track,
            },
        ],
    )?;
    let mrad = |v: &[(f64, f64)]| -> Vec<(f64, f64)> {
        v.iter().map(|(a, e)| (a.to_degrees(), e * 1e3)).collect()
    };
    let raw_a = mrad(&s.after.raw_by_angle);
    let est_a = mrad(&s.after.estimate_by_angle);
    let mut by_angle = vec![
        Series {
            label: "raw sensor (atan2)",
            points: &raw_a,
        },
        Series {
            label: "θ̂ at the end",
            points: &est_a,
        },
    ];
    let before_a = s.before.as_ref().map(|b| mrad(&b.estimate_by_angle));
    if let Some(b) = &before_a {
        by_angle.push(Series {
            label: "θ̂ before MRAS",
            points: b,
        });
    }
    plots::line_chart(
        &dir.join("error_vs_angle"),
        &title("spatial error"),
        "mechanical angle (deg)",
        "error, offset removed (mrad)",
        &by_angle,
    )?;

    // Error spectrum by spatial harmonic.
    let harmonics: Vec<u32> = (1..=SPECTRUM_HARMONICS_OF_THETA_RM).collect();
    let mut groups: Vec<(&str, &[f64])> = vec![("raw sensor", &s.after.raw_spectrum_mrad)];
    if let Some(b) = &s.before {
        groups.push(("θ̂ before MRAS", &b.estimate_spectrum_mrad));
    }
    groups.push(("θ̂ at the end", &s.after.estimate_spectrum_mrad));
    plots::spectrum_chart(
        &dir.join("spectrum"),
        &title("spatial error spectrum"),
        "amplitude (mrad)",
        &harmonics,
        &groups,
    )?;
    Ok(())
}

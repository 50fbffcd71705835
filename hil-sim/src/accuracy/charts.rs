//! The results page's two own charts, PNG only (the page embeds them; SVG of 5 000 CDF
//! points would only grow the docs): the distribution of a residual over sensors (CDF,
//! log x) and a grouped bar chart per condition (log y). The error spectrum uses
//! `plots::spectrum_chart`; the frame, legend and file are [`crate::figure`]'s.

use crate::figure::{bar_key, color, err, legend, line_key, png, Frame, FONT};
use anyhow::{anyhow, bail, Result};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

const SIZE: (u32, u32) = (1000, 620);

/// Decades covering the positive finite values, with one decade of margin below.
fn log_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
    (hi > 0.0).then(|| {
        (
            10f64.powf(lo.log10().floor()),
            10f64.powf(hi.log10().ceil()),
        )
    })
}

fn tick(v: &f64) -> String {
    if (1e-3..1e4).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Fraction of sensors at or below each residual, one line per method, log x.
pub fn cdf_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    series: &[(&str, Vec<f64>)],
) -> Result<()> {
    let (lo, hi) = log_range(series.iter().flat_map(|s| s.1.iter().copied()))
        .ok_or_else(|| anyhow!("{}: no positive value to plot", path.display()))?;
    png(path, SIZE, |root| {
        let y_desc = "fraction of sensors at or below";
        let mut chart = Frame::page(title, (55, 70), Some(x_label), y_desc)
            .x_fmt(&tick)
            .draw(root, (lo..hi).log_scale(), 0.0..1.0)?;
        for (i, (label, values)) in series.iter().enumerate() {
            let mut v: Vec<f64> = values
                .iter()
                .copied()
                .filter(|v| v.is_finite() && *v > 0.0)
                .collect();
            v.sort_by(f64::total_cmp);
            let n = v.len() as f64;
            let steps = v.iter().enumerate().map(|(k, &x)| (x, (k + 1) as f64 / n));
            chart
                .draw_series(LineSeries::new(steps, color(i).stroke_width(2)))
                .map_err(err)?
                .label(*label)
                .legend(line_key(color(i)));
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft, 15)
    })
}

/// One group of bars per category (`groups[g].1[c]` is group g's value in category c),
/// log y; non-positive values have no bar.
pub fn grouped_bars(
    path: &Path,
    title: &str,
    y_label: &str,
    categories: &[&str],
    groups: &[(&str, Vec<f64>)],
) -> Result<()> {
    if groups.iter().any(|g| g.1.len() != categories.len()) {
        bail!(
            "{}: a group's length differs from the categories",
            path.display()
        );
    }
    let (lo, _) = log_range(groups.iter().flat_map(|g| g.1.iter().copied()))
        .ok_or_else(|| anyhow!("{}: no positive value to plot", path.display()))?;
    let top = groups
        .iter()
        .flat_map(|g| g.1.iter().copied())
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        * 2.0;
    let n = categories.len();
    // An empty stretch on the right holds the legend clear of the bars.
    let legend_room = n as f64 / 3.0;
    png(path, SIZE, |root| {
        // Category names are drawn below (plotters' ticks would skip some).
        let mut chart = Frame::page(title, (45, 70), None, y_label)
            .no_x_grid()
            .no_x_ticks()
            .y_fmt(&tick)
            .draw(
                root,
                -0.5..n as f64 - 0.5 + legend_room,
                (lo..top).log_scale(),
            )?;
        let style = TextStyle::from((FONT, 15).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
        for (i, name) in categories.iter().enumerate() {
            let (px, py) = chart.backend_coord(&(i as f64, lo));
            root.draw(&Text::new(*name, (px, py + 8), style.clone()))
                .map_err(err)?;
        }
        let width = 0.84 / groups.len() as f64;
        for (g, (name, values)) in groups.iter().enumerate() {
            let bars = values
                .iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite() && **v > lo)
                .map(|(k, &v)| {
                    let x0 = k as f64 - 0.42 + g as f64 * width;
                    Rectangle::new([(x0, lo), (x0 + width * 0.9, v)], color(g).filled())
                });
            chart
                .draw_series(bars)
                .map_err(err)?
                .label(*name)
                .legend(bar_key(color(g)));
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight, 14)
    })
}

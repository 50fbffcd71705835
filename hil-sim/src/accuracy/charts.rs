//! The results page's two own charts, PNG only (the page embeds them; SVG of 5 000 CDF
//! points would only grow the docs): the distribution of a residual over sensors (CDF,
//! log x) and a grouped bar chart per condition (log y). The error spectrum uses
//! `plots::spectrum_chart`.

use crate::plots::{ensure_font, FONT, PALETTE};
use anyhow::{anyhow, bail, Result};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

const SIZE: (u32, u32) = (1000, 620);

fn err(path: &Path) -> impl Fn(String) -> anyhow::Error + '_ {
    move |e| anyhow!("cannot draw {}: {e}", path.display())
}

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

fn tick(v: f64) -> String {
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
    ensure_font()?;
    let (lo, hi) = log_range(series.iter().flat_map(|s| s.1.iter().copied()))
        .ok_or_else(|| anyhow!("{}: no positive value to plot", path.display()))?;
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    let e = err(path);
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .caption(title, (FONT, 24).into_font().style(FontStyle::Bold))
        .x_label_area_size(55)
        .y_label_area_size(70)
        .build_cartesian_2d((lo..hi).log_scale(), 0.0..1.0)
        .map_err(|x| e(x.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc("fraction of sensors at or below")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .x_label_formatter(&|v| tick(*v))
        .light_line_style(RGBColor(240, 240, 240))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    for (i, (label, values)) in series.iter().enumerate() {
        let mut v: Vec<f64> = values
            .iter()
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        let c = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                v.iter().enumerate().map(|(k, &x)| (x, (k + 1) as f64 / n)),
                c.stroke_width(2),
            ))
            .map_err(|x| e(x.to_string()))?
            .label(*label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], c.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.5))
        .label_font((FONT, 15))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    root.present().map_err(|x| e(x.to_string()))
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
    ensure_font()?;
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
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    let e = err(path);
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let n = categories.len();
    // An empty stretch on the right holds the legend clear of the bars.
    let legend_room = n as f64 / 3.0;
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .caption(title, (FONT, 24).into_font().style(FontStyle::Bold))
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(-0.5..n as f64 - 0.5 + legend_room, (lo..top).log_scale())
        .map_err(|x| e(x.to_string()))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        // Category names are drawn below (plotters' ticks would skip some).
        .x_labels(0)
        .y_label_formatter(&|v| tick(*v))
        .y_desc(y_label)
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .light_line_style(RGBColor(240, 240, 240))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    let style = TextStyle::from((FONT, 15).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    for (i, name) in categories.iter().enumerate() {
        let (px, py) = chart.backend_coord(&(i as f64, lo));
        root.draw(&Text::new(*name, (px, py + 8), style.clone()))
            .map_err(|x| e(x.to_string()))?;
    }
    let width = 0.84 / groups.len() as f64;
    for (g, (name, values)) in groups.iter().enumerate() {
        let c = PALETTE[g % PALETTE.len()];
        let bars = values
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite() && **v > lo)
            .map(|(k, &v)| {
                let x0 = k as f64 - 0.42 + g as f64 * width;
                Rectangle::new([(x0, lo), (x0 + width * 0.9, v)], c.filled())
            });
        chart
            .draw_series(bars)
            .map_err(|x| e(x.to_string()))?
            .label(*name)
            .legend(move |(x, y)| Rectangle::new([(x + 4, y - 6), (x + 20, y + 6)], c.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.5))
        .label_font((FONT, 14))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    root.present().map_err(|x| e(x.to_string()))
}

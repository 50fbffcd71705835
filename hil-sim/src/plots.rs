//! The simulation's PNG and SVG plots: line charts, the sensor-vector image and the error
//! spectrum, each written as `<stem>.png` and `<stem>.svg` with the same content (the frame,
//! legend and files are [`crate::figure`]'s).
//!
//! Series longer than [`MAX_DRAW_POINTS`] are decimated before drawing (see [`decimate`]):
//! a chart with 10⁶ samples per series would otherwise take seconds and produce a
//! hundred-megabyte SVG, while a 1000-pixel-wide image cannot show more detail anyway.

use crate::figure::{
    bar_key, color, err, legend, line_key, png_and_svg, tick_label, Frame, MARGIN_PX, TITLE_PX,
};
use anyhow::{anyhow, bail, Result};
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint};
use plotters::prelude::*;
use std::collections::HashSet;
use std::ops::Range;
use std::path::Path;

/// One named line or point set.
#[derive(Clone, Copy, Debug)]
pub struct Series<'a> {
    pub label: &'a str,
    pub points: &'a [(f64, f64)],
}

impl<'a> Series<'a> {
    pub fn new(label: &'a str, points: &'a [(f64, f64)]) -> Self {
        Self { label, points }
    }
}

/// Upper bound on the points drawn per series; longer series are decimated with a min/max
/// envelope so that peaks survive.
pub const MAX_DRAW_POINTS: usize = 20_000;

const LINE_SIZE: (u32, u32) = (1000, 600);
const VECTOR_SIZE: (u32, u32) = (700, 700);
const SPECTRUM_SIZE: (u32, u32) = (1000, 600);
/// Label areas below and left of the plotting area, in pixels.
const LINE_LABEL_PX: (u32, u32) = (55, 90);
const VECTOR_LABEL_PX: (u32, u32) = (55, 75);
const LEGEND_PX: u32 = 16;

/// Line chart (1000×600) of one coloured line per series, with a legend of the series labels.
///
/// Axis ranges cover the finite data with a 5 % margin. Non-finite points are skipped; a
/// series with none left stays in the legend marked "(no data)". Series longer than
/// [`MAX_DRAW_POINTS`] are decimated with a per-bucket min/max envelope (peaks are kept).
/// Writes `<stem>.png` and `<stem>.svg`; errors if no series has a finite point.
pub fn line_chart(
    stem: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    let series: Vec<PreparedSeries> = series
        .iter()
        .map(|s| PreparedSeries::new(s.label, decimate(s.points, MAX_DRAW_POINTS)))
        .collect();
    let (x, y) = data_bounds(series.iter().flat_map(|s| s.points.iter()))
        .ok_or_else(|| no_data_error(stem, title))?;
    let (x, y) = (pad(x, 0.05), pad(y, 0.05));
    let corner = legend_corner(&series, (&x, &y), plot_px(LINE_SIZE, LINE_LABEL_PX), true);
    png_and_svg!(stem, LINE_SIZE, |root| {
        let mut chart = Frame::new(title, LINE_LABEL_PX, x_label, y_label)
            .x_fmt(&tick_label)
            .y_fmt(&tick_label)
            .draw(root, x.clone(), y.clone())?;
        for (i, s) in series.iter().enumerate() {
            let c = color(i);
            // Thin lines for dense data, where 2 px strokes would merge into a blob.
            let width = if s.points.len() > 2000 { 1 } else { 2 };
            if let [p] = s.points[..] {
                // A line through one point draws nothing.
                chart
                    .draw_series([Circle::new(p, 3, c.filled())])
                    .map_err(err)?;
            }
            let line = LineSeries::new(s.points.iter().copied(), c.stroke_width(width));
            let drawn = chart.draw_series(line).map_err(err)?;
            if !s.label.is_empty() {
                drawn.label(s.label.as_str()).legend(line_key(c));
            }
        }
        series_legend(&mut chart, series.iter().map(|s| s.label.as_str()), &corner)
    })
}

/// Equal-aspect X-Y image (700×700) of sensor vectors (paper Fig. 8a), one point cloud per
/// series, with a legend. Pass the reference unit circle as its own series.
///
/// Both axes get the same range, symmetric around 0 and covering every finite point, on a
/// square plotting area, so a circle looks like a circle. Points that fall on the same
/// screen cell are drawn once, and each series is capped at [`MAX_DRAW_POINTS`] with a
/// min/max envelope, which keeps the outline of 10⁶-sample recordings.
/// Writes `<stem>.png` and `<stem>.svg`; errors if no series has a finite point.
pub fn vector_image(stem: &Path, title: &str, series: &[Series]) -> Result<()> {
    let bounds = data_bounds(
        series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| is_finite(p)),
    )
    .ok_or_else(|| no_data_error(stem, title))?;
    let reach = [bounds.0.start, bounds.0.end, bounds.1.start, bounds.1.end]
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()));
    let reach = if reach > 0.0 { reach * 1.08 } else { 1.0 };
    let range = -reach..reach;
    // Lay out the chart so the plotting area is exactly square: equal aspect.
    let (w, h) = plot_px(VECTOR_SIZE, VECTOR_LABEL_PX);
    let side = w.min(h);
    // 2-pixel cells: with 3-pixel dots, dropping further points of a cell changes nothing visible.
    let series: Vec<PreparedSeries> = series
        .iter()
        .map(|s| {
            let unique = dedup_on_grid(s.points, &range, side / 2);
            PreparedSeries::new(s.label, decimate(&unique, MAX_DRAW_POINTS))
        })
        .collect();
    let corner = legend_corner(&series, (&range, &range), (side, side), false);
    png_and_svg!(stem, VECTOR_SIZE, |root| {
        let mut chart = Frame::new(title, VECTOR_LABEL_PX, "x", "y")
            .extra_margin(w - side, h - side)
            .x_fmt(&tick_label)
            .y_fmt(&tick_label)
            .draw(root, range.clone(), range.clone())?;
        for (i, s) in series.iter().enumerate() {
            let c = color(i);
            let dots = s.points.iter().map(|&p| Circle::new(p, 1.5, c.filled()));
            let drawn = chart.draw_series(dots).map_err(err)?;
            if !s.label.is_empty() {
                drawn
                    .label(s.label.as_str())
                    .legend(move |(x, y)| Circle::new((x + 12, y), 4, c.filled()));
            }
        }
        series_legend(&mut chart, series.iter().map(|s| s.label.as_str()), &corner)
    })
}

/// Grouped bar chart (1000×600) of an error spectrum by harmonic, log-scale y, one colour per
/// group with a legend. `groups[i].1[j]` is group i's amplitude at `harmonics[j]`.
///
/// The y axis runs from a decade below the smallest positive value (rounded down to a power
/// of ten) to twice the largest; zero, negative and non-finite amplitudes have no bar (they
/// sit at the floor); a group with no bar at all says so in the legend. Errors if a group's
/// length differs from `harmonics`. Writes `<stem>.png` and `<stem>.svg`.
pub fn spectrum_chart(
    stem: &Path,
    title: &str,
    y_label: &str,
    harmonics: &[u32],
    groups: &[(&str, &[f64])],
) -> Result<()> {
    if harmonics.is_empty() || groups.is_empty() {
        bail!(
            "spectrum chart '{title}' ({}): no harmonics or no groups to draw",
            stem.display()
        );
    }
    if let Some((name, values)) = groups.iter().find(|(_, v)| v.len() != harmonics.len()) {
        bail!(
            "spectrum chart '{title}' ({}): group '{name}' has {} values for {} harmonics",
            stem.display(),
            values.len(),
            harmonics.len()
        );
    }
    let positive = groups
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .filter(|v| v.is_finite() && *v > 0.0);
    let (min_pos, max_pos) = positive.fold((f64::INFINITY, 0.0_f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    // All zero (e.g. an ideal simulation) is a valid result: show empty decades, not an error.
    let (floor, top) = if max_pos > 0.0 {
        (10f64.powf((min_pos / 10.0).log10().floor()), max_pos * 2.0)
    } else {
        (1e-3, 1.0)
    };
    let n = harmonics.len();
    let x = -0.5..n as f64 - 0.5;
    let width = 0.8 / groups.len() as f64;
    // Legend placement: sample each bar's column in axis-normalised coordinates.
    let span = (top / floor).ln();
    let mut samples = Vec::new();
    for (g, (_, values)) in groups.iter().enumerate() {
        for (j, v) in values.iter().enumerate() {
            let xc = j as f64 - 0.4 + (g as f64 + 0.5) * width;
            let height = if v.is_finite() && *v > floor {
                ((v / floor).ln() / span).min(1.0)
            } else {
                0.0
            };
            let steps = (height * 40.0).ceil() as usize;
            for k in 0..=steps {
                samples.push(((xc - x.start) / (x.end - x.start), height * k as f64 / 40.0));
            }
        }
    }
    let labels: Vec<&str> = groups.iter().map(|(n, _)| *n).collect();
    let corner = choose_corner(&samples, &labels, plot_px(SPECTRUM_SIZE, LINE_LABEL_PX));
    // Label every harmonic unless they would crowd (about 25 fit in the width).
    let step = n.div_ceil(25).max(1);
    let ticks: Vec<f64> = (0..n).step_by(step).map(|i| i as f64).collect();
    // One notation per axis: "0.01" next to "1e-4" reads badly.
    let scientific = floor < 1e-3 || top >= 1e5;
    let log_label = |v: &f64| match tick_label(v).parse::<f64>() {
        // The rounded tick in scientific notation; 1 stays "1" (tick_label's form).
        Ok(r) if scientific && r != 1.0 => format!("{r:e}"),
        _ => tick_label(v),
    };
    let harmonic_label = |v: &f64| {
        let i = v.round();
        if i >= 0.0 && (i as usize) < n && (v - i).abs() < 1e-6 {
            harmonics[i as usize].to_string()
        } else {
            String::new()
        }
    };
    png_and_svg!(stem, SPECTRUM_SIZE, |root| {
        let axis = HarmonicAxis {
            range: x.clone(),
            ticks: ticks.clone(),
        };
        let mut chart = Frame::new(title, LINE_LABEL_PX, "harmonic", y_label)
            .no_x_grid()
            .x_fmt(&harmonic_label)
            .y_fmt(&log_label)
            .draw(root, axis, (floor..top).log_scale())?;
        for (g, (name, values)) in groups.iter().enumerate() {
            let c = color(g);
            let bars = values
                .iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite() && **v > floor)
                .map(|(j, &v)| {
                    let x0 = j as f64 - 0.4 + g as f64 * width;
                    Rectangle::new([(x0, floor), (x0 + width, v)], c.filled())
                });
            let drawn = chart.draw_series(bars).map_err(err)?;
            if !name.is_empty() {
                let visible = values.iter().any(|&v| v.is_finite() && v > floor);
                let label = match visible {
                    true => name.to_string(),
                    false => format!("{name} (no positive values)"),
                };
                drawn.label(label).legend(bar_key(c));
            }
        }
        series_legend(&mut chart, groups.iter().map(|(name, _)| *name), &corner)
    })
}

/// The legend, if any series has a label.
fn series_legend<'a, 'l, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    mut labels: impl Iterator<Item = &'l str>,
    corner: &SeriesLabelPosition,
) -> Result<()> {
    match labels.any(|l| !l.is_empty()) {
        true => legend(chart, corner.clone(), LEGEND_PX),
        false => Ok(()),
    }
}

/// Linear x axis with one tick per (shown) harmonic index; plotters' `with_key_points` on an
/// `f64` range loses the label formatter, hence this small axis type.
struct HarmonicAxis {
    range: Range<f64>,
    ticks: Vec<f64>,
}

impl Ranged for HarmonicAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let t = (value - self.range.start) / (self.range.end - self.range.start);
        limit.0 + (t * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.ticks.clone()
        }
    }

    fn range(&self) -> Range<f64> {
        self.range.clone()
    }
}

/// Reduces `points` to at most about `max` finite points for drawing.
///
/// Non-finite points are dropped. If more than `max` remain, they are cut into `max / 4`
/// consecutive buckets and each bucket keeps, in original order, its points with the
/// smallest and largest x and y. For a time series that is first, last, min and max, so
/// the drawn line still reaches every peak of the original; for an X-Y trajectory it keeps
/// the outline. Nothing is interpolated: every returned point is an original sample.
pub fn decimate(points: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    let finite: Vec<(f64, f64)> = points.iter().copied().filter(is_finite).collect();
    let buckets = (max / 4).max(1);
    if finite.len() <= max.max(4) {
        return finite;
    }
    let size = finite.len().div_ceil(buckets);
    let mut out = Vec::with_capacity(4 * buckets);
    for chunk in finite.chunks(size) {
        // The first point with the smallest x, largest x, smallest y, largest y.
        let mut keep = [0usize; 4];
        for (i, p) in chunk.iter().enumerate() {
            let [x_lo, x_hi, y_lo, y_hi] = keep.map(|k| chunk[k]);
            let wins = [p.0 < x_lo.0, p.0 > x_hi.0, p.1 < y_lo.1, p.1 > y_hi.1];
            for (k, _) in keep.iter_mut().zip(wins).filter(|(_, win)| *win) {
                *k = i;
            }
        }
        keep.sort_unstable();
        for (j, &i) in keep.iter().enumerate() {
            if j == 0 || keep[j - 1] != i {
                out.push(chunk[i]);
            }
        }
    }
    out
}

fn is_finite(p: &(f64, f64)) -> bool {
    p.0.is_finite() && p.1.is_finite()
}

/// Keeps the first finite point in each cell of a `cells`×`cells` grid over `range`², in order.
/// A point cloud drawn at screen resolution looks the same, and the SVG stays small.
fn dedup_on_grid(points: &[(f64, f64)], range: &Range<f64>, cells: u32) -> Vec<(f64, f64)> {
    let scale = f64::from(cells) / (range.end - range.start);
    let cell = |v: f64| ((v - range.start) * scale) as u32;
    let mut seen = HashSet::new();
    points
        .iter()
        .copied()
        .filter(is_finite)
        .filter(|p| seen.insert((cell(p.0), cell(p.1))))
        .collect()
}

fn data_bounds<'a>(
    points: impl Iterator<Item = &'a (f64, f64)>,
) -> Option<(Range<f64>, Range<f64>)> {
    points.fold(None, |acc, &(x, y)| {
        Some(match acc {
            None => (x..x, y..y),
            Some((xr, yr)) => (
                xr.start.min(x)..xr.end.max(x),
                yr.start.min(y)..yr.end.max(y),
            ),
        })
    })
}

/// Widens a range by `frac` of its span on each side; a zero-width range gets a unit span.
fn pad(r: Range<f64>, frac: f64) -> Range<f64> {
    let span = r.end - r.start;
    let half = match (span > 0.0, r.start != 0.0) {
        (true, _) => span * frac,
        (false, true) => r.start.abs() * 0.1,
        (false, false) => 1.0,
    };
    r.start - half..r.end + half
}

fn no_data_error(stem: &Path, title: &str) -> anyhow::Error {
    anyhow!(
        "chart '{title}' ({}): no finite data points in any series",
        stem.display()
    )
}

/// A series ready to draw: finite, decimated points and the legend text.
struct PreparedSeries {
    label: String,
    points: Vec<(f64, f64)>,
}

impl PreparedSeries {
    fn new(label: &str, points: Vec<(f64, f64)>) -> Self {
        let label = if points.is_empty() && !label.is_empty() {
            format!("{label} (no data)")
        } else {
            label.to_string()
        };
        Self { label, points }
    }
}

/// Plotting-area size in pixels of a chart of `size` with label areas `label_px` (below,
/// left): lays out the square vector image and sizes legend estimates.
fn plot_px(size: (u32, u32), label_px: (u32, u32)) -> (u32, u32) {
    (
        size.0 - 2 * MARGIN_PX - label_px.1,
        size.1 - 2 * MARGIN_PX - (TITLE_PX + 10) - label_px.0,
    )
}

/// Picks the plot corner where the legend hides the fewest data points.
fn legend_corner(
    series: &[PreparedSeries],
    (x, y): (&Range<f64>, &Range<f64>),
    plot: (u32, u32),
    lines: bool,
) -> SeriesLabelPosition {
    let norm = |p: &(f64, f64)| {
        (
            (p.0 - x.start) / (x.end - x.start),
            (p.1 - y.start) / (y.end - y.start),
        )
    };
    let mut samples = Vec::new();
    for s in series {
        let mut prev: Option<(f64, f64)> = None;
        for p in s.points.iter().map(norm) {
            // Sparse lines can cross a corner without a vertex in it: sample along segments.
            if let (true, Some(q)) = (lines, prev) {
                let steps = ((p.0 - q.0).hypot(p.1 - q.1) / 0.01).ceil().min(200.0) as usize;
                for k in 1..steps {
                    let t = k as f64 / steps as f64;
                    samples.push((q.0 + (p.0 - q.0) * t, q.1 + (p.1 - q.1) * t));
                }
            }
            samples.push(p);
            prev = Some(p);
        }
    }
    let labels: Vec<&str> = series.iter().map(|s| s.label.as_str()).collect();
    choose_corner(&samples, &labels, plot)
}

/// Counts axis-normalised samples under the legend box at each corner; the first corner with
/// the fewest wins (upper right preferred, as readers expect it there).
fn choose_corner(samples: &[(f64, f64)], labels: &[&str], plot: (u32, u32)) -> SeriesLabelPosition {
    let chars = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0) as f64;
    let entries = labels.iter().filter(|l| !l.is_empty()).count() as f64;
    let w = ((chars * 0.6 * f64::from(LEGEND_PX) + 50.0) / f64::from(plot.0)).min(1.0);
    let h = ((entries * (f64::from(LEGEND_PX) + 8.0) + 20.0) / f64::from(plot.1)).min(1.0);
    let corners = [
        (SeriesLabelPosition::UpperRight, 1.0 - w..1.0, 1.0 - h..1.0),
        (SeriesLabelPosition::UpperLeft, 0.0..w, 1.0 - h..1.0),
        (SeriesLabelPosition::LowerRight, 1.0 - w..1.0, 0.0..h),
        (SeriesLabelPosition::LowerLeft, 0.0..w, 0.0..h),
    ];
    let mut best = (SeriesLabelPosition::UpperRight, usize::MAX);
    for (pos, xr, yr) in corners {
        let hidden = samples
            .iter()
            .filter(|p| xr.contains(&p.0) && yr.contains(&p.1))
            .count();
        if hidden < best.1 {
            best = (pos, hidden);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::figure::with_extension;
    use std::time::{Duration, Instant};

    fn png_size(path: &Path) -> (u32, u32) {
        let bytes = std::fs::read(path).unwrap();
        assert_eq!(
            &bytes[..8],
            b"\x89PNG\r\n\x1a\n",
            "{} is not a PNG",
            path.display()
        );
        assert_eq!(&bytes[12..16], b"IHDR");
        let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
        (be(&bytes[16..20]), be(&bytes[20..24]))
    }

    fn check_outputs(stem: &Path, size: (u32, u32), texts: &[&str]) {
        assert_eq!(png_size(&with_extension(stem, "png")), size);
        let svg = std::fs::read_to_string(with_extension(stem, "svg")).unwrap();
        assert!(svg.contains("<svg"));
        for t in texts {
            assert!(svg.contains(t), "SVG lacks {t:?}");
        }
    }

    fn sine(n: usize, phase: f64) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 1e-3;
                (t, (-t * 2.0).exp() * (t * 30.0 + phase).sin())
            })
            .collect()
    }

    #[test]
    fn line_chart_writes_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("nested/dir/speed");
        let a = sine(2000, 0.0);
        let mut b = sine(2000, 1.0);
        b[10] = (f64::NAN, 0.0);
        b[11] = (0.5, f64::INFINITY);
        let series = [
            Series::new("measured", &a),
            Series::new("estimated", &b),
            Series::new("missing", &[]),
        ];
        line_chart(
            &stem,
            "Speed estimate",
            "time [s]",
            "speed [rad/s]",
            &series,
        )
        .unwrap();
        check_outputs(
            &stem,
            LINE_SIZE,
            &[
                "Speed estimate",
                "measured",
                "estimated",
                "missing (no data)",
                "time [s]",
            ],
        );
    }

    #[test]
    fn stem_keeps_its_dots() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("run.1");
        let a = sine(10, 0.0);
        line_chart(&stem, "t", "x", "y", &[Series::new("a", &a)]).unwrap();
        assert!(dir.path().join("run.1.png").exists());
        assert!(dir.path().join("run.1.svg").exists());
    }

    #[test]
    fn all_nan_is_an_error_naming_the_chart() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("bad");
        let nan = [(f64::NAN, 1.0), (1.0, f64::NAN)];
        let e = line_chart(&stem, "Broken", "x", "y", &[Series::new("n", &nan)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("Broken") && e.contains("bad"), "{e}");
        assert!(vector_image(&stem, "Broken", &[Series::new("n", &nan)]).is_err());
        assert!(line_chart(&stem, "Empty", "x", "y", &[]).is_err());
        assert!(!with_extension(&stem, "png").exists());
    }

    #[test]
    fn unwritable_location_reports_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("plain-file");
        std::fs::write(&file, "x").unwrap();
        let stem = file.join("chart");
        let a = sine(10, 0.0);
        let e = line_chart(&stem, "t", "x", "y", &[Series::new("a", &a)]).unwrap_err();
        let e = format!("{e:#}");
        assert!(e.contains("plain-file"), "{e}");
    }

    #[test]
    fn decimation_keeps_peaks_and_bounds_size() {
        let mut pts = sine(1_000_000, 0.0);
        pts[123_457].1 = 50.0;
        pts[876_543].1 = -50.0;
        let d = decimate(&pts, MAX_DRAW_POINTS);
        assert!(d.len() <= MAX_DRAW_POINTS, "{}", d.len());
        assert!(d.len() > MAX_DRAW_POINTS / 2);
        assert!(d.contains(&pts[123_457]) && d.contains(&pts[876_543]));
        assert_eq!(d.first(), pts.first());
        assert_eq!(d.last(), pts.last());
        assert!(d.windows(2).all(|w| w[0].0 < w[1].0), "order kept");
        let short = sine(100, 0.0);
        assert_eq!(decimate(&short, MAX_DRAW_POINTS), short);
    }

    #[test]
    fn million_points_render_quickly() {
        let dir = tempfile::tempdir().unwrap();
        let (pts, big) = (sine(1_000_000, 0.0), dir.path().join("big"));
        let start = Instant::now();
        line_chart(&big, "Big", "t", "y", &[Series::new("1e6", &pts)]).unwrap();
        let line = start.elapsed();
        let xy: Vec<(f64, f64)> = (0..1_000_000)
            .map(|i| {
                let a = i as f64 * 0.01;
                (a.cos() * 1.1 + 0.05, a.sin() * 0.9)
            })
            .collect();
        let start = Instant::now();
        vector_image(
            &dir.path().join("bigxy"),
            "Big XY",
            &[Series::new("xy", &xy)],
        )
        .unwrap();
        let vector = start.elapsed();
        eprintln!("1e6 points: line chart {line:?}, vector image {vector:?}");
        // Generous bound for unoptimised test builds on a slow CI machine.
        assert!(line < Duration::from_secs(20) && vector < Duration::from_secs(20));
        let svg = std::fs::metadata(dir.path().join("bigxy.svg"))
            .unwrap()
            .len();
        assert!(svg < 3_000_000, "vector SVG is {svg} bytes");
    }

    #[test]
    fn vector_image_writes_square_images() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("xy");
        let circle: Vec<(f64, f64)> = (0..=360)
            .map(|d| {
                (
                    f64::from(d).to_radians().cos(),
                    f64::from(d).to_radians().sin(),
                )
            })
            .collect();
        let ellipse: Vec<(f64, f64)> = circle
            .iter()
            .map(|&(x, y)| (1.3 * x + 0.2, 0.7 * y))
            .collect();
        vector_image(
            &stem,
            "Sensor vector",
            &[
                Series::new("before", &ellipse),
                Series::new("after", &circle),
                Series::new("unit circle", &circle),
            ],
        )
        .unwrap();
        check_outputs(
            &stem,
            VECTOR_SIZE,
            &["Sensor vector", "before", "after", "unit circle"],
        );
    }

    #[test]
    fn spectrum_chart_handles_zeros_and_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("spectrum");
        let h = [1, 2, 3, 5, 7];
        let before = [1e-2, 3e-3, 0.0, 5e-4, -1.0];
        let after = [2e-4, f64::NAN, 1e-5, 0.0, 3e-6];
        spectrum_chart(
            &stem,
            "Error spectrum",
            "amplitude [rad]",
            &h,
            &[("before", &before), ("after", &after)],
        )
        .unwrap();
        check_outputs(
            &stem,
            SPECTRUM_SIZE,
            &["Error spectrum", "before", "after", "amplitude"],
        );
        let zeros = [0.0; 5];
        spectrum_chart(&stem, "All zero", "a", &h, &[("z", &zeros)]).unwrap();
        check_outputs(
            &stem,
            SPECTRUM_SIZE,
            &["All zero", "z (no positive values)"],
        );
        assert!(spectrum_chart(&stem, "Short", "a", &h, &[("s", &zeros[..2])]).is_err());
        assert!(spectrum_chart(&stem, "None", "a", &[], &[]).is_err());
    }
}

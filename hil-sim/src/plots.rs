//! PNG and SVG plots drawn with plotters.
//!
//! The DejaVu Sans font is compiled in (crate `dejavu`) and registered with plotters, so PNG
//! text does not depend on fonts installed on the machine. Every chart is drawn by one function
//! generic over the drawing backend and run once for the bitmap and once for the SVG backend,
//! so `<stem>.png` and `<stem>.svg` always show the same content.
//!
//! Series longer than [`MAX_DRAW_POINTS`] are decimated before drawing (see [`decimate`]):
//! a chart with 10⁶ samples per series would otherwise take seconds and produce a
//! hundred-megabyte SVG, while a 1000-pixel-wide image cannot show more detail anyway.

use anyhow::{anyhow, bail, Context, Result};
use std::collections::HashSet;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::register_font;

/// One named line or point set.
#[derive(Clone, Copy, Debug)]
pub struct Series<'a> {
    pub label: &'a str,
    pub points: &'a [(f64, f64)],
}

/// Upper bound on the points drawn per series; longer series are decimated with a min/max
/// envelope so that peaks survive.
pub const MAX_DRAW_POINTS: usize = 20_000;

/// Font family the DejaVu font is registered under (plotters' name for the generic sans font).
pub(crate) const FONT: &str = "sans-serif";

const LINE_SIZE: (u32, u32) = (1000, 600);
const VECTOR_SIZE: (u32, u32) = (700, 700);
const SPECTRUM_SIZE: (u32, u32) = (1000, 600);

const TITLE_PX: u32 = 26;
const AXIS_DESC_PX: u32 = 18;
const TICK_PX: u32 = 15;
const LEGEND_PX: u32 = 16;

/// Tableau-10 colours: distinguishable, print well, and colour-blind friendlier than RGB primaries.
pub(crate) const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

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
    let prepared: Vec<PreparedSeries> = series
        .iter()
        .map(|s| PreparedSeries::new(s.label, decimate(s.points, MAX_DRAW_POINTS)))
        .collect();
    let (x, y) = data_bounds(prepared.iter().flat_map(|s| s.points.iter()))
        .ok_or_else(|| no_data_error(stem, title))?;
    let x = pad(x, 0.05);
    let y = pad(y, 0.05);
    let legend = legend_corner(&prepared, (&x, &y), plot_px(LINE_SIZE, LINE_MARGINS), true);
    let figure = LineFigure {
        title,
        x_label,
        y_label,
        series: prepared,
        x,
        y,
        legend,
    };
    render(stem, &figure)
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
    let side = vector_plot_side();
    // 2-pixel cells: with 3-pixel dots, dropping further points of a cell changes nothing visible.
    let prepared: Vec<PreparedSeries> = series
        .iter()
        .map(|s| {
            let unique = dedup_on_grid(s.points, &range, side / 2);
            PreparedSeries::new(s.label, decimate(&unique, MAX_DRAW_POINTS))
        })
        .collect();
    let legend = legend_corner(&prepared, (&range, &range), (side, side), false);
    let figure = VectorFigure {
        title,
        series: prepared,
        range,
        legend,
    };
    render(stem, &figure)
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
    let x = -0.5..harmonics.len() as f64 - 0.5;
    // Legend placement: sample each bar's column in axis-normalised coordinates.
    let span = (top / floor).ln();
    let mut samples = Vec::new();
    let width = 0.8 / groups.len() as f64;
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
    let legend = choose_corner(&samples, &labels, plot_px(SPECTRUM_SIZE, SPECTRUM_MARGINS));
    let figure = SpectrumFigure {
        title,
        y_label,
        harmonics,
        groups,
        x,
        y: floor..top,
        legend,
    };
    render(stem, &figure)
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
        let mut keep = [0usize; 4];
        for (i, p) in chunk.iter().enumerate() {
            if p.0 < chunk[keep[0]].0 {
                keep[0] = i;
            }
            if p.0 > chunk[keep[1]].0 {
                keep[1] = i;
            }
            if p.1 < chunk[keep[2]].1 {
                keep[2] = i;
            }
            if p.1 > chunk[keep[3]].1 {
                keep[3] = i;
            }
        }
        keep.sort_unstable();
        let mut last = None;
        for i in keep {
            if last != Some(i) {
                out.push(chunk[i]);
                last = Some(i);
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
    if span > 0.0 {
        r.start - span * frac..r.end + span * frac
    } else {
        let half = if r.start != 0.0 {
            r.start.abs() * 0.1
        } else {
            1.0
        };
        r.start - half..r.end + half
    }
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

/// Chart margins and label-area sizes in pixels, used both for building the chart and for
/// estimating the plotting-area size when placing the legend.
#[derive(Clone, Copy)]
struct Margins {
    margin: u32,
    title: u32,
    left: u32,
    bottom: u32,
}

const LINE_MARGINS: Margins = Margins {
    margin: 15,
    title: TITLE_PX + 10,
    left: 90,
    bottom: 55,
};
const SPECTRUM_MARGINS: Margins = LINE_MARGINS;
const VECTOR_MARGINS: Margins = Margins {
    margin: 15,
    title: TITLE_PX + 10,
    left: 75,
    bottom: 55,
};

/// Plotting-area size in pixels: lays out the square vector image and sizes legend estimates.
fn plot_px(size: (u32, u32), m: Margins) -> (u32, u32) {
    (
        size.0 - 2 * m.margin - m.left,
        size.1 - 2 * m.margin - m.title - m.bottom,
    )
}

/// Side of the square plotting area of the vector image.
fn vector_plot_side() -> u32 {
    let (w, h) = plot_px(VECTOR_SIZE, VECTOR_MARGINS);
    w.min(h)
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

/// A chart that can draw itself on any plotters backend.
trait Figure {
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>;
}

/// Draws `figure` into `<stem>.png` and `<stem>.svg`, creating the parent directory.
fn render<F: Figure>(stem: &Path, figure: &F) -> Result<()> {
    ensure_font()?;
    if let Some(dir) = stem.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create directory {}", dir.display()))?;
    }
    let png = with_extension(stem, "png");
    {
        let root = BitMapBackend::new(&png, figure.size()).into_drawing_area();
        figure
            .draw(&root)
            .with_context(|| format!("cannot draw {}", png.display()))?;
        root.present()
            .with_context(|| format!("cannot write {}", png.display()))?;
    }
    let svg = with_extension(stem, "svg");
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, figure.size()).into_drawing_area();
        figure
            .draw(&root)
            .with_context(|| format!("cannot draw {}", svg.display()))?;
        root.present()
            .with_context(|| format!("cannot draw {}", svg.display()))?;
    }
    std::fs::write(&svg, text).with_context(|| format!("cannot write {}", svg.display()))
}

/// Appends `.ext` (a stem like `run.1` must not lose its `.1` as `set_extension` would do).
fn with_extension(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

/// Registers DejaVu Sans once; with the `ab_glyph` feature plotters knows no system fonts.
pub(crate) fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        let normal = register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok();
        let bold = register_font(FONT, FontStyle::Bold, dejavu::sans::bold()).is_ok();
        normal && bold
    });
    if ok {
        Ok(())
    } else {
        Err(anyhow!("cannot load the bundled DejaVu Sans font"))
    }
}

/// Plotters' errors as messages: the backends' error types carry no `'static` bound.
fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("{e}")
}

/// Bold title. `FontDesc::style` would keep the regular glyphs (plotters loads the font data
/// on construction), so the bold face is requested up front.
fn title_style() -> TextStyle<'static> {
    FontDesc::new(FontFamily::SansSerif, f64::from(TITLE_PX), FontStyle::Bold).into()
}

/// Tick labels: plain decimals in a readable range, scientific notation outside it.
fn tick_label(v: f64) -> String {
    // Log-axis ticks come from repeated multiplication (9.999999999999999e-5): round to 6
    // significant digits first, then print the shortest form.
    let v: f64 = format!("{v:.5e}").parse().unwrap_or(v);
    let a = v.abs();
    // Linear ticks stepped from a range land on ±2e-16 instead of 0.
    if a < 1e-12 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:e}")
    } else {
        let s = format!("{v:.6}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".into()
        } else {
            s.into()
        }
    }
}

fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    labelled: bool,
    position: &SeriesLabelPosition,
) -> Result<()> {
    if !labelled {
        return Ok(());
    }
    chart
        .configure_series_labels()
        .position(position.clone())
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.5))
        .label_font((FONT, LEGEND_PX))
        .draw()
        .map_err(err)
}

struct LineFigure<'a> {
    title: &'a str,
    x_label: &'a str,
    y_label: &'a str,
    series: Vec<PreparedSeries>,
    x: Range<f64>,
    y: Range<f64>,
    legend: SeriesLabelPosition,
}

impl Figure for LineFigure<'_> {
    fn size(&self) -> (u32, u32) {
        LINE_SIZE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let m = LINE_MARGINS;
        let mut chart = ChartBuilder::on(root)
            .margin(m.margin)
            .caption(self.title, title_style())
            .x_label_area_size(m.bottom)
            .y_label_area_size(m.left)
            .build_cartesian_2d(self.x.clone(), self.y.clone())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(self.x_label)
            .y_desc(self.y_label)
            .label_style((FONT, TICK_PX))
            .axis_desc_style((FONT, AXIS_DESC_PX))
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .light_line_style(RGBColor(240, 240, 240))
            .bold_line_style(RGBColor(215, 215, 215))
            .draw()
            .map_err(err)?;
        for (i, s) in self.series.iter().enumerate() {
            let c = color(i);
            // Thin lines for dense data, where 2 px strokes would merge into a blob.
            let width = if s.points.len() > 2000 { 1 } else { 2 };
            if let [p] = s.points[..] {
                // A line through one point draws nothing.
                chart
                    .draw_series([Circle::new(p, 3, c.filled())])
                    .map_err(err)?;
            }
            let drawn = chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    c.stroke_width(width),
                ))
                .map_err(err)?;
            if !s.label.is_empty() {
                drawn.label(s.label.as_str()).legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 24, y)], c.stroke_width(3))
                });
            }
        }
        let labelled = self.series.iter().any(|s| !s.label.is_empty());
        draw_legend(&mut chart, labelled, &self.legend)
    }
}

struct VectorFigure<'a> {
    title: &'a str,
    series: Vec<PreparedSeries>,
    range: Range<f64>,
    legend: SeriesLabelPosition,
}

impl Figure for VectorFigure<'_> {
    fn size(&self) -> (u32, u32) {
        VECTOR_SIZE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let m = VECTOR_MARGINS;
        // Lay out the chart so the plotting area is exactly square: equal aspect.
        let (w, h) = plot_px(VECTOR_SIZE, m);
        let side = w.min(h);
        let mut chart = ChartBuilder::on(root)
            .margin(m.margin)
            .margin_right(m.margin + (w - side))
            .margin_top(m.margin + (h - side))
            .caption(self.title, title_style())
            .x_label_area_size(m.bottom)
            .y_label_area_size(m.left)
            .build_cartesian_2d(self.range.clone(), self.range.clone())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("x")
            .y_desc("y")
            .label_style((FONT, TICK_PX))
            .axis_desc_style((FONT, AXIS_DESC_PX))
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .light_line_style(RGBColor(240, 240, 240))
            .bold_line_style(RGBColor(215, 215, 215))
            .draw()
            .map_err(err)?;
        for (i, s) in self.series.iter().enumerate() {
            let c = color(i);
            let drawn = chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 1.5, c.filled())))
                .map_err(err)?;
            if !s.label.is_empty() {
                drawn
                    .label(s.label.as_str())
                    .legend(move |(x, y)| Circle::new((x + 12, y), 4, c.filled()));
            }
        }
        let labelled = self.series.iter().any(|s| !s.label.is_empty());
        draw_legend(&mut chart, labelled, &self.legend)
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

struct SpectrumFigure<'a> {
    title: &'a str,
    y_label: &'a str,
    harmonics: &'a [u32],
    groups: &'a [(&'a str, &'a [f64])],
    x: Range<f64>,
    y: Range<f64>,
    legend: SeriesLabelPosition,
}

impl Figure for SpectrumFigure<'_> {
    fn size(&self) -> (u32, u32) {
        SPECTRUM_SIZE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let m = SPECTRUM_MARGINS;
        let n = self.harmonics.len();
        // Label every harmonic unless they would crowd (about 25 fit in the width).
        let step = n.div_ceil(25).max(1);
        let ticks: Vec<f64> = (0..n).step_by(step).map(|i| i as f64).collect();
        let mut chart = ChartBuilder::on(root)
            .margin(m.margin)
            .caption(self.title, title_style())
            .x_label_area_size(m.bottom)
            .y_label_area_size(m.left)
            .build_cartesian_2d(
                HarmonicAxis {
                    range: self.x.clone(),
                    ticks,
                },
                self.y.clone().log_scale(),
            )
            .map_err(err)?;
        // One notation per axis: "0.01" next to "1e-4" reads badly.
        let scientific = self.y.start < 1e-3 || self.y.end >= 1e5;
        let log_label = |v: &f64| {
            if scientific {
                tick_label(*v).parse::<f64>().map_or_else(
                    |_| tick_label(*v),
                    |r| match r {
                        1.0 => "1".into(),
                        _ => format!("{r:e}"),
                    },
                )
            } else {
                tick_label(*v)
            }
        };
        let harmonic_label = |v: &f64| {
            let i = v.round();
            if i >= 0.0 && (i as usize) < n && (v - i).abs() < 1e-6 {
                self.harmonics[i as usize].to_string()
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc("harmonic")
            .y_desc(self.y_label)
            .label_style((FONT, TICK_PX))
            .axis_desc_style((FONT, AXIS_DESC_PX))
            .x_label_formatter(&harmonic_label)
            .y_label_formatter(&log_label)
            .light_line_style(RGBColor(240, 240, 240))
            .bold_line_style(RGBColor(215, 215, 215))
            .draw()
            .map_err(err)?;
        let floor = self.y.start;
        let width = 0.8 / self.groups.len() as f64;
        for (g, (name, values)) in self.groups.iter().enumerate() {
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
                let label = if visible {
                    name.to_string()
                } else {
                    format!("{name} (no positive values)")
                };
                drawn.label(label).legend(move |(x, y)| {
                    Rectangle::new([(x + 4, y - 6), (x + 20, y + 6)], c.filled())
                });
            }
        }
        let labelled = self.groups.iter().any(|(name, _)| !name.is_empty());
        draw_legend(&mut chart, labelled, &self.legend)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
            Series {
                label: "measured",
                points: &a,
            },
            Series {
                label: "estimated",
                points: &b,
            },
            Series {
                label: "missing",
                points: &[],
            },
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
        line_chart(
            &stem,
            "t",
            "x",
            "y",
            &[Series {
                label: "a",
                points: &a,
            }],
        )
        .unwrap();
        assert!(dir.path().join("run.1.png").exists());
        assert!(dir.path().join("run.1.svg").exists());
    }

    #[test]
    fn all_nan_is_an_error_naming_the_chart() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("bad");
        let nan = [(f64::NAN, 1.0), (1.0, f64::NAN)];
        let e = line_chart(
            &stem,
            "Broken",
            "x",
            "y",
            &[Series {
                label: "n",
                points: &nan,
            }],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("Broken") && e.contains("bad"), "{e}");
        assert!(vector_image(
            &stem,
            "Broken",
            &[Series {
                label: "n",
                points: &nan
            }]
        )
        .is_err());
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
        let e = line_chart(
            &stem,
            "t",
            "x",
            "y",
            &[Series {
                label: "a",
                points: &a,
            }],
        )
        .unwrap_err();
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
        let pts = sine(1_000_000, 0.0);
        let start = Instant::now();
        line_chart(
            &dir.path().join("big"),
            "Big",
            "t",
            "y",
            &[Series {
                label: "1e6",
                points: &pts,
            }],
        )
        .unwrap();
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
            &[Series {
                label: "xy",
                points: &xy,
            }],
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
                Series {
                    label: "before",
                    points: &ellipse,
                },
                Series {
                    label: "after",
                    points: &circle,
                },
                Series {
                    label: "unit circle",
                    points: &circle,
                },
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

    #[test]
    fn tick_labels_are_readable() {
        assert_eq!(tick_label(0.0), "0");
        assert_eq!(tick_label(-2.220446049250313e-16), "0");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(tick_label(-3.0), "-3");
        assert_eq!(tick_label(1e-5), "1e-5");
        assert_eq!(tick_label(2e6), "2e6");
        assert_eq!(tick_label(9.999999999999999e-5), "1e-4");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
    }
}

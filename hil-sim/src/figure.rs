//! What every chart shares, so a figure ([`crate::plots`], [`crate::accuracy::charts`])
//! states only its data, titles, axes and series: the bundled font, the palette, tick
//! labels, the frame ([`Frame`]: white background, title, margins, label areas, mesh, axis
//! descriptions), the legend and its keys, and the PNG/SVG files.
//!
//! The DejaVu Sans font is compiled in (crate `dejavu`) and registered with plotters, so PNG
//! text does not depend on fonts installed on the machine.

use anyhow::{anyhow, Context, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::register_font;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Font family the DejaVu font is registered under (plotters' name for the generic sans font).
pub(crate) const FONT: &str = "sans-serif";
/// Title size of the simulation plots; the legend-placement estimate uses it too.
pub(crate) const TITLE_PX: u32 = 26;
/// Outer margin of every chart.
pub(crate) const MARGIN_PX: u32 = 15;
const AXIS_DESC_PX: u32 = 18;
const TICK_PX: u32 = 15;

/// Tableau-10 colours: distinguishable, print well, and colour-blind friendlier than RGB primaries.
const PALETTE: [RGBColor; 10] = [
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

/// Colour of series `i`.
pub(crate) fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Plotters' errors as messages: the backends' error types carry no `'static` bound.
pub(crate) fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("{e}")
}

/// Registers DejaVu Sans once; with the `ab_glyph` feature plotters knows no system fonts.
fn ensure_font() -> Result<()> {
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

/// Tick labels: plain decimals in a readable range, scientific notation outside it.
pub(crate) fn tick_label(v: &f64) -> String {
    // Log-axis ticks come from repeated multiplication (9.999999999999999e-5): round to 6
    // significant digits first, then print the shortest form.
    let v: f64 = format!("{v:.5e}").parse().unwrap_or(*v);
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

/// A formatter of tick labels for values of type `V`.
type Fmt<'a, V> = Option<&'a dyn Fn(&V) -> String>;

/// The chart [`Frame::draw`] returns, over the axes made from `XS` and `YS`.
type Chart<'r, DB, XS, YS> = ChartContext<
    'r,
    DB,
    Cartesian2d<<XS as AsRangedCoord>::CoordDescType, <YS as AsRangedCoord>::CoordDescType>,
>;

/// A chart's frame: everything but its data. `X` and `Y` are the axes' value types.
pub(crate) struct Frame<'a, X, Y> {
    title: &'a str,
    title_style: TextStyle<'static>,
    /// Label areas below (x axis) and left of (y axis) the plotting area, in pixels.
    label_px: (u32, u32),
    /// Margin added right and above, in pixels (to make the plotting area square).
    extra_px: (u32, u32),
    desc: (Option<&'a str>, Option<&'a str>),
    fmt: (Fmt<'a, X>, Fmt<'a, Y>),
    bold_grid: bool,
    x_grid: bool,
    x_ticks: bool,
}

impl<'a, X, Y> Frame<'a, X, Y> {
    /// The simulation plots' frame: a bold title, the x and y axis descriptions, a darker
    /// line at each labelled tick.
    pub fn new(title: &'a str, label_px: (u32, u32), x_desc: &'a str, y_desc: &'a str) -> Self {
        // `FontDesc::style` would keep the regular glyphs (plotters loads the font data on
        // construction), so the bold face is requested up front.
        let bold = FontDesc::new(FontFamily::SansSerif, f64::from(TITLE_PX), FontStyle::Bold);
        Self {
            title,
            title_style: bold.into(),
            label_px,
            extra_px: (0, 0),
            desc: (Some(x_desc), Some(y_desc)),
            fmt: (None, None),
            bold_grid: true,
            x_grid: true,
            x_ticks: true,
        }
    }

    /// The results page's frame: its charts were published with this title style, which
    /// asks for bold through `FontDesc::style` and so draws regular glyphs, and with
    /// plotters' default lines at labelled ticks.
    pub fn page(
        title: &'a str,
        label_px: (u32, u32),
        x_desc: Option<&'a str>,
        y_desc: &'a str,
    ) -> Self {
        Self {
            title_style: (FONT, 24).into_font().style(FontStyle::Bold).into(),
            desc: (x_desc, Some(y_desc)),
            bold_grid: false,
            ..Self::new(title, label_px, "", y_desc)
        }
    }

    pub fn x_fmt(mut self, f: &'a dyn Fn(&X) -> String) -> Self {
        self.fmt.0 = Some(f);
        self
    }

    pub fn y_fmt(mut self, f: &'a dyn Fn(&Y) -> String) -> Self {
        self.fmt.1 = Some(f);
        self
    }

    /// No vertical grid lines (bar charts).
    pub fn no_x_grid(mut self) -> Self {
        self.x_grid = false;
        self
    }

    /// No x tick labels (the figure draws its own).
    pub fn no_x_ticks(mut self) -> Self {
        self.x_ticks = false;
        self
    }

    pub fn extra_margin(mut self, right_px: u32, top_px: u32) -> Self {
        self.extra_px = (right_px, top_px);
        self
    }

    /// Fills `root` white and draws the frame around axes `x` and `y`; the figure draws
    /// its series into the returned chart.
    pub fn draw<'r, DB, XS, YS>(
        self,
        root: &'r DrawingArea<DB, Shift>,
        x: XS,
        y: YS,
    ) -> Result<Chart<'r, DB, XS, YS>>
    where
        DB: DrawingBackend,
        XS: AsRangedCoord<Value = X>,
        YS: AsRangedCoord<Value = Y>,
        XS::CoordDescType: ValueFormatter<X>,
        YS::CoordDescType: ValueFormatter<Y>,
    {
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(root)
            .margin(MARGIN_PX)
            .margin_right(MARGIN_PX + self.extra_px.0)
            .margin_top(MARGIN_PX + self.extra_px.1)
            .caption(self.title, self.title_style)
            .x_label_area_size(self.label_px.0)
            .y_label_area_size(self.label_px.1)
            .build_cartesian_2d(x, y)
            .map_err(err)?;
        let mut mesh = chart.configure_mesh();
        mesh.label_style((FONT, TICK_PX))
            .axis_desc_style((FONT, AXIS_DESC_PX))
            .light_line_style(RGBColor(240, 240, 240));
        if let Some(d) = self.desc.0 {
            mesh.x_desc(d);
        }
        if let Some(d) = self.desc.1 {
            mesh.y_desc(d);
        }
        if let Some(f) = self.fmt.0 {
            mesh.x_label_formatter(f);
        }
        if let Some(f) = self.fmt.1 {
            mesh.y_label_formatter(f);
        }
        if self.bold_grid {
            mesh.bold_line_style(RGBColor(215, 215, 215));
        }
        if !self.x_grid {
            mesh.disable_x_mesh();
        }
        if !self.x_ticks {
            mesh.x_labels(0);
        }
        mesh.draw().map_err(err)?;
        Ok(chart)
    }
}

/// Draws the legend of the labelled series at `position`, in text of `font_px`.
pub(crate) fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
    font_px: u32,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.5))
        .label_font((FONT, font_px))
        .draw()
        .map_err(err)
}

/// Legend key of a line series.
pub(crate) fn line_key(c: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new([(x, y), (x + 24, y)], c.stroke_width(3))
}

/// Legend key of a bar series.
pub(crate) fn bar_key(c: RGBColor) -> impl Fn((i32, i32)) -> Rectangle<(i32, i32)> {
    move |(x, y)| Rectangle::new([(x + 4, y - 6), (x + 20, y + 6)], c.filled())
}

/// A PNG at `path` of `size` pixels, drawn by `draw`.
pub(crate) fn png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, size).into_drawing_area();
    draw(&root).with_context(|| format!("cannot draw {}", path.display()))?;
    root.present()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// `<stem>.png` and `<stem>.svg` of one figure, creating the parent directory: `png` and
/// `svg` draw the same on each backend (use [`png_and_svg!`]).
pub(crate) fn write_png_and_svg(
    stem: &Path,
    size: (u32, u32),
    png_draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
    svg_draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    ensure_font()?;
    if let Some(dir) = stem.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create directory {}", dir.display()))?;
    }
    png(&with_extension(stem, "png"), size, png_draw)?;
    let svg = with_extension(stem, "svg");
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        svg_draw(&root).with_context(|| format!("cannot draw {}", svg.display()))?;
        root.present()
            .with_context(|| format!("cannot draw {}", svg.display()))?;
    }
    std::fs::write(&svg, text).with_context(|| format!("cannot write {}", svg.display()))
}

/// `<stem>.png` and `<stem>.svg` drawn by one body with `root` bound to each backend's
/// drawing area: plotters' backends are distinct types, so the body is compiled twice
/// and the two files cannot show different content.
macro_rules! png_and_svg {
    ($stem:expr, $size:expr, |$root:ident| $body:expr) => {
        $crate::figure::write_png_and_svg($stem, $size, |$root| $body, |$root| $body)
    };
}
pub(crate) use png_and_svg;

/// Appends `.ext` (a stem like `run.1` must not lose its `.1` as `set_extension` would do).
pub(crate) fn with_extension(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

#[cfg(test)]
mod tests {
    use super::tick_label;

    #[test]
    fn tick_labels_are_readable() {
        assert_eq!(tick_label(&0.0), "0");
        assert_eq!(tick_label(&-2.220446049250313e-16), "0");
        assert_eq!(tick_label(&0.25), "0.25");
        assert_eq!(tick_label(&-3.0), "-3");
        assert_eq!(tick_label(&1e-5), "1e-5");
        assert_eq!(tick_label(&2e6), "2e6");
        assert_eq!(tick_label(&9.999999999999999e-5), "1e-4");
        assert_eq!(tick_label(&0.30000000000000004), "0.3");
    }
}

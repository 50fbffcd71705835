//! PNG and SVG plots (plotters, DejaVu font bundled). STUB: being written.

use std::path::Path;

/// One named line or point set.
#[derive(Clone, Copy, Debug)]
pub struct Series<'a> {
    pub label: &'a str,
    pub points: &'a [(f64, f64)],
}

/// Line chart; writes `<stem>.png` and `<stem>.svg`.
pub fn line_chart(
    _stem: &Path,
    _title: &str,
    _x_label: &str,
    _y_label: &str,
    _series: &[Series],
) -> Result<(), String> {
    Err("not implemented yet".into())
}

/// Equal-aspect X-Y image of sensor vectors (paper Fig. 8a); writes PNG and SVG.
pub fn vector_image(_stem: &Path, _title: &str, _series: &[Series]) -> Result<(), String> {
    Err("not implemented yet".into())
}

/// Grouped bar chart of an error spectrum by harmonic, log-scale y; writes PNG and SVG.
/// `groups[i].1[j]` is group i's amplitude at `harmonics[j]`.
pub fn spectrum_chart(
    _stem: &Path,
    _title: &str,
    _y_label: &str,
    _harmonics: &[u32],
    _groups: &[(&str, &[f64])],
) -> Result<(), String> {
    Err("not implemented yet".into())
}

//! What every plot shares: the embedded font, text sizes, colours, clipping of
//! absurd values, and breaking lines at gaps.

use std::sync::OnceLock;

use plotters::chart::{MeshStyle, SeriesLabelStyle};
use plotters::coord::CoordTranslate;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::report::stats::TIME_WEIGHT_CAP_S;

/// Font family every text uses; registered from the embedded DejaVu Sans.
pub const FONT: &str = "sans-serif";
/// Title size (px).
pub const TITLE_PX: u32 = 26;
/// Axis description size (px).
pub const AXIS_DESC_PX: u32 = 20;
/// Tick label and legend size (px).
pub const LABEL_PX: u32 = 16;

/// Largest RSE an axis shows (m); larger values are drawn at this edge.
pub const RSE_CAP_M: f64 = 5.0;
/// Smallest top of an RSE axis (m), so a near-perfect run is not magnified into noise.
pub const RSE_MIN_TOP_M: f64 = 0.5;
/// A line is broken where consecutive samples are further apart than this (s).
pub const LINE_GAP_S: f64 = 2.0 * TIME_WEIGHT_CAP_S;

/// Red of the RSE lines (the paper's).
pub const RSE_RED: RGBColor = RGBColor(210, 30, 30);
/// Blue of θ (the paper's).
pub const THETA_BLUE: RGBColor = RGBColor(20, 70, 200);
/// Fill of the acceptable θ band.
pub const BAND_FILL: RGBColor = RGBColor(200, 235, 200);
/// One colour per robot (paths, distances), avoiding the estimate colours
/// (green, black, red).
pub const ROBOT_COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
    RGBColor(127, 127, 127),
];

/// Colour of robot `k`.
pub fn robot_colour(k: usize) -> RGBColor {
    ROBOT_COLOURS[k % ROBOT_COLOURS.len()]
}

/// Register the embedded DejaVu Sans as [`FONT`] (once per process).
///
/// There are no system fonts on the machines this runs on; both backends need a
/// registered font to measure text, and the PNG backend to draw it.
pub fn ensure_fonts() -> Result<(), String> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            let faces = [
                (FontStyle::Normal, dejavu::sans::regular()),
                (FontStyle::Bold, dejavu::sans::bold()),
                (FontStyle::Italic, dejavu::sans::oblique()),
                (FontStyle::Oblique, dejavu::sans::oblique()),
            ];
            for (style, bytes) in faces {
                plotters::style::register_font(FONT, style, bytes)
                    .map_err(|_| "the embedded DejaVu Sans font was rejected".to_string())?;
            }
            Ok(())
        })
        .clone()
}

/// Title text style.
pub fn title_style() -> TextStyle<'static> {
    (FONT, TITLE_PX).into_font().style(FontStyle::Bold).color(&BLACK)
}

/// Axis description style.
pub fn axis_desc_style() -> TextStyle<'static> {
    (FONT, AXIS_DESC_PX).into_font().color(&BLACK)
}

/// Tick labels, legends, notes.
pub fn label_style() -> TextStyle<'static> {
    (FONT, LABEL_PX).into_font().color(&BLACK)
}

/// RSE colour as the paper's RViz display: green → black over 0–0.5 m, red above.
pub fn rse_colour(rse_m: f64) -> RGBColor {
    if !(rse_m <= 0.5) {
        return RGBColor(230, 0, 0);
    }
    let g = (220.0 * (1.0 - rse_m.max(0.0) / 0.5)).round() as u8;
    RGBColor(0, g, 0)
}

/// Top of an RSE axis for `values` (m): the largest value with 10 % headroom,
/// at least [`RSE_MIN_TOP_M`], at most [`RSE_CAP_M`]; and whether any value is
/// above the cap (then drawn at the edge).
pub fn rse_axis_top(values: impl IntoIterator<Item = f64>) -> (f64, bool) {
    let max = values.into_iter().filter(|v| v.is_finite()).fold(0.0, f64::max);
    if max > RSE_CAP_M { (RSE_CAP_M, true) } else { ((max * 1.1).clamp(RSE_MIN_TOP_M, RSE_CAP_M), false) }
}

/// Axis description of an RSE axis whose top is `top_m`, saying when values
/// above it are drawn at the edge.
pub fn rse_axis_desc(top_m: f64, clipped: bool) -> String {
    if clipped { format!("RSE (m); values > {top_m:.1} m drawn at {top_m:.1} m") } else { "RSE (m)".into() }
}

/// Split `(t, value)` samples into polylines, breaking at absent values and at
/// time gaps longer than [`LINE_GAP_S`]; values are clamped to `[lo, hi]`.
pub fn polylines(
    samples: impl IntoIterator<Item = (f64, Option<f64>)>,
    lo: f64,
    hi: f64,
) -> Vec<Vec<(f64, f64)>> {
    let mut lines: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut current: Vec<(f64, f64)> = Vec::new();
    for (t, v) in samples {
        let gap = current.last().is_some_and(|(t0, _)| t - t0 > LINE_GAP_S);
        match v.filter(|v| !v.is_nan()) {
            Some(v) if !gap => current.push((t, v.clamp(lo, hi))),
            Some(v) => {
                lines.push(std::mem::take(&mut current));
                current.push((t, v.clamp(lo, hi)));
            }
            None => lines.push(std::mem::take(&mut current)),
        }
    }
    lines.push(current);
    lines.retain(|l| !l.is_empty());
    lines
}

/// Most samples a time series may have to be drawn 2 px wide.
///
/// Thick polylines are drawn with mitred joins, which spike at the sharp turns
/// of a dense noisy series (hundreds of estimates per second); dense series are
/// drawn 1 px wide.
pub const THICK_LINE_MAX_POINTS: usize = 400;

/// Stroke width (px) of a time series with `points` samples.
pub fn line_width(points: usize) -> u32 {
    if points <= THICK_LINE_MAX_POINTS { 2 } else { 1 }
}

/// End of the time axis (s): the run's duration or the last sample, at least 1 s.
pub fn time_axis_end(duration_s: f64, last_t_s: Option<f64>) -> f64 {
    let end = duration_s.max(last_t_s.unwrap_or(0.0));
    if end.is_finite() && end > 0.0 { end } else { 1.0 }
}

/// The grid and text of every chart's axes: house fonts, faint light lines,
/// grey bold lines.
pub fn styled_mesh<'m, 'a, 'b, X: Ranged, Y: Ranged, DB: DrawingBackend>(
    mesh: &'m mut MeshStyle<'a, 'b, X, Y, DB>,
) -> &'m mut MeshStyle<'a, 'b, X, Y, DB> {
    mesh.axis_desc_style(axis_desc_style())
        .label_style(label_style())
        .light_line_style(RGBColor(245, 245, 245))
        .bold_line_style(RGBColor(225, 225, 225))
}

/// Draws a chart's legend: upper right, on a white box with a black border.
pub fn draw_legend<'a, 'b, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    mut legend: SeriesLabelStyle<'a, 'b, DB, CT>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    legend
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(label_style())
        .margin(10)
        .draw()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rse_colours_follow_the_paper() {
        assert_eq!(rse_colour(0.0), RGBColor(0, 220, 0));
        assert_eq!(rse_colour(0.5), RGBColor(0, 0, 0));
        assert_eq!(rse_colour(0.25), RGBColor(0, 110, 0));
        assert_eq!(rse_colour(0.6), RGBColor(230, 0, 0));
        assert_eq!(rse_colour(f64::NAN), RGBColor(230, 0, 0));
    }

    #[test]
    fn lines_break_at_gaps_and_absent_values() {
        let s = [(0.0, Some(1.0)), (0.5, Some(9.0)), (1.0, None), (1.5, Some(2.0)), (10.0, Some(3.0))];
        let l = polylines(s, 0.0, 5.0);
        assert_eq!(l, vec![vec![(0.0, 1.0), (0.5, 5.0)], vec![(1.5, 2.0)], vec![(10.0, 3.0)]]);
    }

    #[test]
    fn rse_axis_is_capped() {
        assert_eq!(rse_axis_top([0.1]), (0.5, false));
        let (top, clipped) = rse_axis_top([2.0]);
        assert!((top - 2.2).abs() < 1e-12 && !clipped);
        assert_eq!(rse_axis_top([50.0]), (5.0, true));
    }
}

//! `comparison_theta`: one scenario run with active positioning on and off.
//! Top panel θ over time for both runs with the band shaded; bottom panel the
//! RSE of both, on a shared time axis.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{
    BAND_FILL, draw_legend, label_style, line_width, polylines, rse_axis_desc, rse_axis_top, styled_mesh,
    time_axis_end, title_style,
};
use super::{Figure, PlotResult};
use crate::report::derived::Derived;
use crate::report::record::RunRecord;

/// Colour of the active run.
const ACTIVE: RGBColor = RGBColor(20, 70, 200);
/// Colour of the passive run.
const PASSIVE: RGBColor = RGBColor(240, 120, 0);

/// The figure: both runs and their derived values.
#[derive(Debug)]
pub struct ComparisonTheta<'a> {
    /// Active positioning on.
    pub on: (&'a RunRecord, &'a Derived),
    /// Active positioning off.
    pub off: (&'a RunRecord, &'a Derived),
}

impl ComparisonTheta<'_> {
    fn runs(&self) -> [(&RunRecord, &Derived, RGBColor, &'static str); 2] {
        [(self.on.0, self.on.1, ACTIVE, "active positioning"), (self.off.0, self.off.1, PASSIVE, "passive")]
    }
}

impl Figure for ComparisonTheta<'_> {
    fn size(&self) -> (u32, u32) {
        (1200, 900)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> PlotResult {
        let title = format!("Active positioning on vs off: θ and RSE over time — {}", self.on.0.name);
        let area = root.titled(&title, title_style())?;
        let (_, h) = area.dim_in_pixel();
        let (top_area, bottom_area) = area.split_vertically(h / 2);
        let t_end = self
            .runs()
            .iter()
            .map(|(r, _, _, _)| time_axis_end(r.duration_s, r.rows.last().map(|row| row.t_s)))
            .fold(1.0, f64::max);

        // θ panel.
        let mut chart = ChartBuilder::on(&top_area)
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(75)
            .build_cartesian_2d(0.0..t_end, 0.0..180.0)?;
        let mut mesh = chart.configure_mesh();
        mesh.x_desc("time (s)").y_desc("θ (°)").y_label_formatter(&|v| format!("{v:.0}"));
        styled_mesh(&mut mesh).draw()?;
        let (lo, hi) = self.on.0.theta_band_deg;
        if lo.is_finite() && hi.is_finite() && lo < hi {
            let band = Rectangle::new(
                [(0.0, lo.clamp(0.0, 180.0)), (t_end, hi.clamp(0.0, 180.0))],
                BAND_FILL.filled(),
            );
            chart
                .draw_series(std::iter::once(band))?
                .label(format!("θ band {lo:.0}–{hi:.0}°"))
                .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 24, y + 6)], BAND_FILL.filled()));
        }
        for (r, d, colour, name) in self.runs() {
            let samples = r.rows.iter().zip(&d.theta_deg).map(|(row, t)| (row.t_s, Some(*t)));
            for (j, line) in polylines(samples, 0.0, 180.0).into_iter().enumerate() {
                let series = chart
                    .draw_series(LineSeries::new(line, colour.stroke_width(line_width(r.rows.len()))))?;
                if j == 0 {
                    series.label(format!("θ (°), {name}")).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3))
                    });
                }
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(label_style())
            .margin(10)
            .draw()?;

        // RSE panel.
        let all_rse = self.runs().into_iter().flat_map(|(_, d, _, _)| d.rse_m.iter().flatten().copied());
        let (rse_top, clipped) = rse_axis_top(all_rse.collect::<Vec<_>>());
        let mut chart = ChartBuilder::on(&bottom_area)
            .margin(15)
            .x_label_area_size(55)
            .y_label_area_size(75)
            .build_cartesian_2d(0.0..t_end, 0.0..rse_top)?;
        let mut mesh = chart.configure_mesh();
        mesh.x_desc("time (s)").y_desc(rse_axis_desc(rse_top, clipped));
        styled_mesh(&mut mesh).draw()?;
        let mut labelled = false;
        for (r, d, colour, name) in self.runs() {
            let samples = r.rows.iter().zip(&d.rse_m).map(|(row, e)| (row.t_s, *e));
            for (j, line) in polylines(samples, 0.0, rse_top).into_iter().enumerate() {
                let series = chart
                    .draw_series(LineSeries::new(line, colour.stroke_width(line_width(r.rows.len()))))?;
                if j == 0 {
                    labelled = true;
                    series.label(format!("RSE (m), {name}")).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3))
                    });
                }
            }
        }
        if labelled {
            draw_legend(chart.configure_series_labels())?;
        }
        Ok(())
    }
}

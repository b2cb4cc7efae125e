//! `theta_rse`: θ over time with the acceptable band shaded, and the RSE over
//! time on a second axis (the paper's "θ and RSE over time").

use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{
    BAND_FILL, RSE_RED, THETA_BLUE, axis_desc_style, draw_legend, label_style, line_width, polylines,
    rse_axis_desc, rse_axis_top, styled_mesh, time_axis_end, title_style,
};
use super::{Figure, PlotResult};
use crate::report::derived::Derived;
use crate::report::record::RunRecord;

/// Lighter blue of the published θ when the true θ is drawn too.
const PUBLISHED_BLUE: RGBColor = RGBColor(120, 160, 240);

/// The figure: a record and its derived values.
#[derive(Debug)]
pub struct ThetaRse<'a> {
    /// The run.
    pub record: &'a RunRecord,
    /// Its derived per-row values.
    pub derived: &'a Derived,
}

impl Figure for ThetaRse<'_> {
    fn size(&self) -> (u32, u32) {
        (1200, 700)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> PlotResult {
        let r = self.record;
        let area = root.titled(&format!("θ and RSE over time — {}", r.name), title_style())?;
        let t_end = time_axis_end(r.duration_s, r.rows.last().map(|row| row.t_s));
        let (rse_top, clipped) = rse_axis_top(self.derived.rse_m.iter().flatten().copied());

        let mut chart = ChartBuilder::on(&area)
            .margin(15)
            .x_label_area_size(55)
            .y_label_area_size(75)
            .right_y_label_area_size(75)
            .build_cartesian_2d(0.0..t_end, 0.0..180.0)?
            .set_secondary_coord(0.0..t_end, 0.0..rse_top);
        let mut mesh = chart.configure_mesh();
        mesh.x_desc("time (s)").y_desc("θ (°)").y_label_formatter(&|v| format!("{v:.0}"));
        styled_mesh(&mut mesh).draw()?;
        chart
            .configure_secondary_axes()
            .y_desc(rse_axis_desc(rse_top, clipped))
            .axis_desc_style(axis_desc_style())
            .label_style(label_style())
            .draw()?;

        let (lo, hi) = r.theta_band_deg;
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

        let has_true = r.rows.iter().any(|row| row.true_theta_deg.is_some());
        let published_colour = if has_true { PUBLISHED_BLUE } else { THETA_BLUE };
        let published = r.rows.iter().map(|row| (row.t_s, Some(row.theta_deg)));
        for (j, line) in polylines(published, 0.0, 180.0).into_iter().enumerate() {
            let series = chart.draw_series(LineSeries::new(line, published_colour.stroke_width(1)))?;
            if j == 0 {
                series.label("θ published (°)").legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], published_colour.stroke_width(3))
                });
            }
        }
        let truth = r.rows.iter().map(|row| (row.t_s, row.true_theta_deg));
        for (j, line) in polylines(truth, 0.0, 180.0).into_iter().enumerate() {
            let series = chart
                .draw_series(LineSeries::new(line, THETA_BLUE.stroke_width(line_width(r.rows.len()))))?;
            if j == 0 {
                series
                    .label("θ true (°)")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], THETA_BLUE.stroke_width(3)));
            }
        }
        let rse = r.rows.iter().zip(&self.derived.rse_m).map(|(row, rse)| (row.t_s, *rse));
        for (j, line) in polylines(rse, 0.0, rse_top).into_iter().enumerate() {
            let series = chart.draw_secondary_series(LineSeries::new(
                line,
                RSE_RED.stroke_width(line_width(r.rows.len())),
            ))?;
            if j == 0 {
                series
                    .label("RSE (m), right axis")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], RSE_RED.stroke_width(3)));
            }
        }
        draw_legend(chart.configure_series_labels())?;
        Ok(())
    }
}

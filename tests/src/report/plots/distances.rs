//! `distances_rse`: robot–source distances d1 … dN and the RSE over time, on
//! two y axes (the paper's "d1, d2 and RSE over time").

use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{
    RSE_RED, axis_desc_style, draw_legend, label_style, line_width, polylines, robot_colour, rse_axis_desc,
    rse_axis_top, styled_mesh, time_axis_end, title_style,
};
use super::{Figure, PlotResult, note_centred};
use crate::report::csv::distance_columns;
use crate::report::derived::Derived;
use crate::report::record::RunRecord;

/// The figure: a record and its derived values.
#[derive(Debug)]
pub struct DistancesRse<'a> {
    /// The run.
    pub record: &'a RunRecord,
    /// Its derived per-row values.
    pub derived: &'a Derived,
}

impl Figure for DistancesRse<'_> {
    fn size(&self) -> (u32, u32) {
        (1200, 700)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> PlotResult {
        let r = self.record;
        let area =
            root.titled(&format!("Robot–source distances and RSE over time — {}", r.name), title_style())?;
        let t_end = time_axis_end(r.duration_s, r.rows.last().map(|row| row.t_s));
        let d_max = r.rows.iter().flat_map(|row| row.distances_m.iter().copied()).filter(|d| d.is_finite());
        let d_max = d_max.fold(0.0, f64::max);
        let d_top = if d_max > 0.0 { d_max * 1.1 } else { 1.0 };
        let rse_values = self.derived.rse_m.iter().flatten().copied();
        let (rse_top, clipped) = rse_axis_top(rse_values);

        let mut chart = ChartBuilder::on(&area)
            .margin(15)
            .x_label_area_size(55)
            .y_label_area_size(75)
            .right_y_label_area_size(75)
            .build_cartesian_2d(0.0..t_end, 0.0..d_top)?
            .set_secondary_coord(0.0..t_end, 0.0..rse_top);
        let mut mesh = chart.configure_mesh();
        mesh.x_desc("time (s)").y_desc("distance robot–source (m)");
        styled_mesh(&mut mesh).draw()?;
        chart
            .configure_secondary_axes()
            .y_desc(rse_axis_desc(rse_top, clipped))
            .axis_desc_style(axis_desc_style())
            .label_style(label_style())
            .draw()?;

        let width = line_width(r.rows.len());
        let mut labelled = false;
        for k in 0..distance_columns(r) {
            let colour = robot_colour(k);
            let id = r.robot_ids.get(k).map_or_else(|| format!("robot {}", k + 1), |id| id.clone());
            let samples = r.rows.iter().map(|row| (row.t_s, row.distances_m.get(k).copied()));
            for (j, line) in polylines(samples, 0.0, d_top).into_iter().enumerate() {
                let series = chart.draw_series(LineSeries::new(line, colour.stroke_width(width)))?;
                if j == 0 {
                    labelled = true;
                    series.label(format!("d{} (m), {id}", k + 1)).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3))
                    });
                }
            }
        }
        let samples = r.rows.iter().zip(&self.derived.rse_m).map(|(row, rse)| (row.t_s, *rse));
        for (j, line) in polylines(samples, 0.0, rse_top).into_iter().enumerate() {
            let series = chart.draw_secondary_series(LineSeries::new(line, RSE_RED.stroke_width(width)))?;
            if j == 0 {
                labelled = true;
                series
                    .label("RSE (m), right axis")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], RSE_RED.stroke_width(3)));
            }
        }
        if labelled {
            draw_legend(chart.configure_series_labels())?;
        } else {
            let msg = "no truth in this record: no distances, no RSE";
            note_centred(&chart.plotting_area().strip_coord_spec(), msg)?;
        }
        Ok(())
    }
}

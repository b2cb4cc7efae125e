//! `rse_vs_theta`: mean RSE ± std in 15° bins of θ (the paper's "RSE in relation
//! to θ"), over the faint scatter of every estimate; the triangulation beside a
//! filtered estimate in a second colour when the record has one.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::style::{
    BAND_FILL, draw_legend, label_style, rse_axis_desc, rse_axis_top, styled_mesh, title_style,
};
use super::{Figure, PlotResult};
use crate::report::bins::ThetaBin;
use crate::report::derived::{Derived, ThetaSource};
use crate::report::record::RunRecord;
use crate::report::stats;

/// Colour of the triangulation's bins.
const TRI_ORANGE: RGBColor = RGBColor(230, 120, 0);

/// The figure: a record, its derived values and its θ bins.
#[derive(Debug)]
pub struct RseVsTheta<'a> {
    /// The run.
    pub record: &'a RunRecord,
    /// Its derived per-row values.
    pub derived: &'a Derived,
    /// Its θ bins.
    pub bins: &'a [ThetaBin],
}

/// Mean, mean − std, mean + std of a bin (std 0 below two samples).
fn bar(mean: Option<f64>, std: Option<f64>) -> Option<(f64, f64, f64)> {
    let m = mean?;
    let s = std.unwrap_or(0.0);
    Some((m, (m - s).max(0.0), m + s))
}

impl Figure for RseVsTheta<'_> {
    fn size(&self) -> (u32, u32) {
        (1000, 700)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> PlotResult {
        let r = self.record;
        let d = self.derived;
        let area = root.titled(&format!("RSE in relation to θ (15° bins) — {}", r.name), title_style())?;

        // Top from the bars and the bulk of the scatter, so outliers do not flatten the bars.
        let rse: Vec<f64> =
            d.rse_m.iter().flatten().copied().chain(d.tri_rse_m.iter().flatten().copied()).collect();
        let bar_tops = self.bins.iter().flat_map(|b| {
            [bar(b.rse_mean_m, b.rse_std_m).map(|x| x.2), bar(b.tri_rse_mean_m, b.tri_rse_std_m).map(|x| x.2)]
        });
        let (top, _) = rse_axis_top(bar_tops.flatten().chain(stats::p95(&rse)));
        // Clipped: a drawn point (the estimates' scatter) or a bar above the top.
        let clipped = d.rse_m.iter().flatten().any(|v| *v > top)
            || self.bins.iter().any(|b| {
                let bars = [bar(b.rse_mean_m, b.rse_std_m), bar(b.tri_rse_mean_m, b.tri_rse_std_m)];
                bars.iter().flatten().any(|x| x.2 > top)
            });

        let theta_desc = match d.theta_source {
            ThetaSource::Published => "θ published by the coordinator (°)",
            ThetaSource::Mixed => "θ (°): true where known, else published",
            _ => "θ at the true source (°)",
        };
        let mut chart = ChartBuilder::on(&area)
            .margin(15)
            .x_label_area_size(55)
            .y_label_area_size(75)
            .margin_top(40)
            .build_cartesian_2d(0.0..180.0, 0.0..top)?;
        let mut mesh = chart.configure_mesh();
        mesh.x_desc(theta_desc)
            .y_desc(rse_axis_desc(top, clipped))
            .x_labels(13)
            .x_label_formatter(&|v| format!("{v:.0}"));
        styled_mesh(&mut mesh).draw()?;
        // Sample count of each bin above the plot, at the bin's centre (root pixels).
        let count_style = label_style().pos(Pos::new(HPos::Center, VPos::Bottom));
        for b in self.bins {
            let (px, py) = chart.backend_coord(&(b.theta_mid_deg(), top));
            root.draw_text(&format!("n={}", b.rse_count), &count_style, (px, py - 6))?;
        }

        let (lo, hi) = r.theta_band_deg;
        if lo.is_finite() && hi.is_finite() && lo < hi {
            let band = Rectangle::new(
                [(lo.clamp(0.0, 180.0), 0.0), (hi.clamp(0.0, 180.0), top)],
                BAND_FILL.filled(),
            );
            chart
                .draw_series(std::iter::once(band))?
                .label(format!("θ band {lo:.0}–{hi:.0}°"))
                .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 24, y + 6)], BAND_FILL.filled()));
        }

        let faint = RGBColor(90, 90, 90).mix(0.25).filled();
        let points = d.theta_deg.iter().zip(&d.rse_m).filter_map(|(t, e)| Some((*t, (*e)?)));
        let points: Vec<(f64, f64)> = points.filter(|(t, _)| (0.0..=180.0).contains(t)).collect();
        if !points.is_empty() {
            chart
                .draw_series(points.iter().map(|(t, e)| Circle::new((*t, e.min(top)), 2, faint)))?
                .label("every estimate")
                .legend(move |(x, y)| Circle::new((x + 12, y), 3, faint));
        }

        let series = [
            (
                self.bins
                    .iter()
                    .map(|b| (b.theta_mid_deg(), bar(b.rse_mean_m, b.rse_std_m)))
                    .collect::<Vec<_>>(),
                BLACK,
                0.0,
                "mean ± std",
            ),
            (
                self.bins
                    .iter()
                    .map(|b| (b.theta_mid_deg(), bar(b.tri_rse_mean_m, b.tri_rse_std_m)))
                    .collect(),
                TRI_ORANGE,
                2.0,
                "triangulation mean ± std",
            ),
        ];
        for (bars, colour, dx, name) in series {
            let bars: Vec<(f64, (f64, f64, f64))> = bars
                .into_iter()
                .filter_map(|(t, b)| Some((t + dx, b?)))
                .map(|(t, (m, l, h))| (t, (m.min(top), l.min(top), h.min(top))))
                .collect();
            if bars.is_empty() {
                continue;
            }
            chart.draw_series(LineSeries::new(
                bars.iter().map(|(t, (m, _, _))| (*t, *m)),
                colour.stroke_width(1),
            ))?;
            chart
                .draw_series(bars.iter().map(|(t, (m, l, h))| {
                    ErrorBar::new_vertical(*t, *l, *m, *h, colour.stroke_width(2), 10)
                }))?;
            chart
                .draw_series(bars.iter().map(|(t, (m, _, _))| Circle::new((*t, *m), 5, colour.filled())))?
                .label(name)
                .legend(move |(x, y)| Circle::new((x + 12, y), 5, colour.filled()));
        }

        draw_legend(chart.configure_series_labels())?;
        Ok(())
    }
}

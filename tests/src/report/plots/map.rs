//! `map`: top-down map of the run (map frame, equal aspect): the room's floor
//! and obstacles, each robot's path (start ●, end ■, commanded goals ✕), every
//! true source's path labelled with its index (`S0`, `S1`, …), and the
//! published estimates: coloured by RSE as the paper's RViz display (green →
//! black over 0–0.5 m, red above) when the run has one true source and one
//! published id, else coloured by their `source_id` (legend lists the ids).

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::style::{axis_desc_style, label_style, robot_colour, rse_colour, title_style};
use super::{Figure, PlotResult};
use crate::report::derived::Derived;
use crate::report::record::RunRecord;

/// Colour of the true source.
const SOURCE: RGBColor = RGBColor(190, 0, 190);
/// Colour of estimates without truth (no RSE).
const NO_TRUTH: RGBColor = RGBColor(70, 70, 200);
/// Floor fill and obstacle fill.
const FLOOR: RGBColor = RGBColor(246, 244, 238);
const OBSTACLE: RGBColor = RGBColor(175, 175, 175);
/// Colours of estimates by source id (id 0, no live track, is grey).
const ID_COLOURS: [RGBColor; 8] = [
    RGBColor(230, 120, 0),
    RGBColor(0, 150, 70),
    RGBColor(0, 110, 220),
    RGBColor(200, 30, 30),
    RGBColor(130, 70, 190),
    RGBColor(0, 170, 170),
    RGBColor(160, 120, 40),
    RGBColor(230, 80, 160),
];

/// Colour of estimates with `source_id` `id`.
pub fn id_colour(id: u64) -> RGBColor {
    if id == 0 { RGBColor(150, 150, 150) } else { ID_COLOURS[((id - 1) % ID_COLOURS.len() as u64) as usize] }
}

/// The published source ids of a record, sorted.
fn published_ids(record: &RunRecord) -> Vec<u64> {
    let mut ids: Vec<u64> = record.rows.iter().map(|r| r.source_id).collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

/// Whether the map colours estimates by source id (several true sources or ids).
pub fn colours_by_id(record: &RunRecord) -> bool {
    record.sources.len() > 1 || published_ids(record).len() > 1
}

/// Pixel layout of the chart: margin, bottom and left label areas; legend panel width.
const MARGIN: u32 = 15;
const X_LABELS: u32 = 55;
const Y_LABELS: u32 = 70;
const PANEL: u32 = 300;

/// The figure: a record and its derived values.
#[derive(Debug)]
pub struct MapFigure<'a> {
    /// The run.
    pub record: &'a RunRecord,
    /// Its derived per-row values.
    pub derived: &'a Derived,
}

/// Axis-aligned extent of the map (m): `(x0, x1, y0, y1)`.
pub fn extent(record: &RunRecord) -> (f64, f64, f64, f64) {
    let mut pts: Vec<[f64; 2]> = Vec::new();
    if let Some(room) = &record.room {
        pts.extend(room.floor.iter().chain(room.obstacles.iter().flatten()));
    }
    if pts.is_empty() {
        for robot in &record.robots {
            pts.extend(robot.samples.iter().map(|s| [s.1, s.2]));
            pts.extend(robot.goals.iter().map(|g| [g.1, g.2]));
        }
        pts.extend(record.sources.iter().flat_map(|s| s.path.iter()).map(|(_, p)| [p.x, p.y]));
    }
    if pts.is_empty() {
        pts.extend(record.rows.iter().filter_map(|r| r.estimate_in_map).map(|p| [p.x, p.y]));
    }
    pts.retain(|p| p[0].is_finite() && p[1].is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in &pts {
        (x0, x1, y0, y1) = (x0.min(p[0]), x1.max(p[0]), y0.min(p[1]), y1.max(p[1]));
    }
    if pts.is_empty() {
        return (-1.0, 1.0, -1.0, 1.0);
    }
    let pad = (0.05 * (x1 - x0).max(y1 - y0)).max(0.3);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (hx, hy) = ((0.5 * (x1 - x0)).max(0.5) + pad, (0.5 * (y1 - y0)).max(0.5) + pad);
    (cx - hx, cx + hx, cy - hy, cy + hy)
}

/// Grow `(x0, x1, y0, y1)` about its centre so that one metre has the same
/// length in pixels on both axes of a `width_px × height_px` plot.
pub fn equal_aspect(e: (f64, f64, f64, f64), width_px: u32, height_px: u32) -> (f64, f64, f64, f64) {
    let (w, h) = (f64::from(width_px.max(1)), f64::from(height_px.max(1)));
    let m_per_px = ((e.1 - e.0) / w).max((e.3 - e.2) / h);
    let (cx, cy) = (0.5 * (e.0 + e.1), 0.5 * (e.2 + e.3));
    (cx - 0.5 * m_per_px * w, cx + 0.5 * m_per_px * w, cy - 0.5 * m_per_px * h, cy + 0.5 * m_per_px * h)
}

impl Figure for MapFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (1300, 1000)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> PlotResult {
        let r = self.record;
        let area = root.titled(&format!("Top-down map — {}", r.name), title_style())?;
        let (w, h) = area.dim_in_pixel();
        let (plot_area, panel) = area.split_horizontally(w.saturating_sub(PANEL));
        let plot_w = (w.saturating_sub(PANEL)).saturating_sub(2 * MARGIN + Y_LABELS);
        let plot_h = h.saturating_sub(2 * MARGIN + X_LABELS);
        let (x0, x1, y0, y1) = equal_aspect(extent(r), plot_w, plot_h);

        let mut chart = ChartBuilder::on(&plot_area)
            .margin(MARGIN)
            .x_label_area_size(X_LABELS)
            .y_label_area_size(Y_LABELS)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc("x (m), map frame")
            .y_desc("y (m)")
            .axis_desc_style(axis_desc_style())
            .label_style(label_style())
            .light_line_style(RGBColor(248, 248, 248))
            .bold_line_style(RGBColor(230, 230, 230))
            .draw()?;

        if let Some(room) = &r.room {
            let floor: Vec<(f64, f64)> = room.floor.iter().map(|p| (p[0], p[1])).collect();
            chart.draw_series(std::iter::once(Polygon::new(floor.clone(), FLOOR.filled())))?;
            chart.draw_series(std::iter::once(closed(floor, BLACK.stroke_width(2))))?;
            for obstacle in &room.obstacles {
                let pts: Vec<(f64, f64)> = obstacle.iter().map(|p| (p[0], p[1])).collect();
                chart.draw_series(std::iter::once(Polygon::new(pts.clone(), OBSTACLE.filled())))?;
                chart.draw_series(std::iter::once(closed(pts, RGBColor(80, 80, 80).stroke_width(1))))?;
            }
        }

        // Estimates under the truth and the robots, so those stay visible.
        let mut outside = 0usize;
        let mut without_truth = 0usize;
        let by_id = colours_by_id(r);
        let estimates = r
            .rows
            .iter()
            .zip(&self.derived.rse_m)
            .filter_map(|(row, rse)| Some((row.estimate_in_map?, *rse, row.source_id)));
        let estimates: Vec<_> = estimates.filter(|(p, _, _)| p.x.is_finite() && p.y.is_finite()).collect();
        // Smaller dots when there are many, so the picture is not one blob.
        let radius = match estimates.len() {
            0..=500 => 4,
            501..=3000 => 3,
            _ => 2,
        };
        chart.draw_series(estimates.iter().map(|(p, rse, id)| {
            let (x, y) = (p.x.clamp(x0, x1), p.y.clamp(y0, y1));
            outside += usize::from(x != p.x || y != p.y);
            without_truth += usize::from(rse.is_none() && !by_id);
            let colour = if by_id { id_colour(*id) } else { rse.map_or(NO_TRUTH, rse_colour) };
            Circle::new((x, y), radius, colour.filled())
        }))?;

        for (k, robot) in r.robots.iter().enumerate() {
            let colour = robot_colour(k);
            let path: Vec<(f64, f64)> = robot.samples.iter().map(|s| (s.1, s.2)).collect();
            chart.draw_series(std::iter::once(PathElement::new(path.clone(), colour.stroke_width(2))))?;
            if let (Some(start), Some(end)) = (path.first(), path.last()) {
                chart.draw_series(std::iter::once(Circle::new(*start, 7, colour.filled())))?;
                chart.draw_series(std::iter::once(
                    EmptyElement::at(*end) + Rectangle::new([(-6, -6), (6, 6)], colour.filled()),
                ))?;
            }
            chart
                .draw_series(robot.goals.iter().map(|g| Cross::new((g.1, g.2), 7, colour.stroke_width(3))))?;
        }

        let index_style = label_style().color(&SOURCE).pos(Pos::new(HPos::Left, VPos::Bottom));
        for (k, truth) in r.sources.iter().enumerate() {
            let source: Vec<(f64, f64)> = truth.path.iter().map(|(_, p)| (p.x, p.y)).collect();
            chart.draw_series(std::iter::once(PathElement::new(source.clone(), SOURCE.stroke_width(2))))?;
            for p in [source.first(), source.last()].into_iter().flatten() {
                // The true source's marker: a ring with a cross.
                let marker = EmptyElement::at(*p)
                    + Circle::new((0, 0), 10, SOURCE.stroke_width(3))
                    + Cross::new((0, 0), 5, SOURCE.stroke_width(2));
                chart.draw_series(std::iter::once(marker))?;
            }
            if let Some(p) = source.first().filter(|_| r.sources.len() > 1) {
                let label = EmptyElement::at(*p) + Text::new(format!("S{k}"), (12, -10), index_style.clone());
                chart.draw_series(std::iter::once(label))?;
            }
        }

        legend(&panel, r, outside, without_truth)
    }
}

/// A closed outline of a polygon.
fn closed(mut pts: Vec<(f64, f64)>, style: ShapeStyle) -> PathElement<(f64, f64)> {
    if let Some(first) = pts.first().copied() {
        pts.push(first);
    }
    PathElement::new(pts, style)
}

/// The legend panel, drawn in pixels on the right of the map.
fn legend<DB: DrawingBackend>(
    panel: &DrawingArea<DB, Shift>,
    r: &RunRecord,
    outside: usize,
    no_truth: usize,
) -> PlotResult {
    let text = label_style().pos(Pos::new(HPos::Left, VPos::Center));
    let (x, tx) = (20, 60);
    let mut y = 50;
    let row = |y: &mut i32, label: &str| -> PlotResult {
        panel.draw_text(label, &text, (tx, *y))?;
        *y += 30;
        Ok(())
    };
    if r.room.is_some() {
        panel.draw(&Rectangle::new([(x, y - 9), (x + 28, y + 9)], FLOOR.filled()))?;
        panel.draw(&Rectangle::new([(x, y - 9), (x + 28, y + 9)], BLACK.stroke_width(2)))?;
        row(&mut y, "floor")?;
    }
    if r.room.as_ref().is_some_and(|room| !room.obstacles.is_empty()) {
        panel.draw(&Rectangle::new([(x, y - 9), (x + 28, y + 9)], OBSTACLE.filled()))?;
        row(&mut y, "obstacle")?;
    }
    for (k, robot) in r.robots.iter().enumerate() {
        panel.draw(&PathElement::new(vec![(x, y), (x + 28, y)], robot_colour(k).stroke_width(3)))?;
        row(&mut y, &format!("robot {}", robot.id))?;
    }
    if !r.robots.is_empty() {
        panel.draw(&Circle::new((x + 14, y), 7, BLACK.filled()))?;
        row(&mut y, "robot start")?;
        panel.draw(&Rectangle::new([(x + 8, y - 6), (x + 20, y + 6)], BLACK.filled()))?;
        row(&mut y, "robot end")?;
    }
    if r.robots.iter().any(|robot| !robot.goals.is_empty()) {
        panel.draw(&Cross::new((x + 14, y), 7, BLACK.stroke_width(3)))?;
        row(&mut y, "commanded goal")?;
    }
    if !r.sources.is_empty() {
        panel.draw(&(EmptyElement::at((x + 14, y)) + Circle::new((0, 0), 10, SOURCE.stroke_width(3))))?;
        let what =
            if r.sources.len() > 1 { "true sources Sk (start, end)" } else { "true source (start, end)" };
        row(&mut y, what)?;
    }
    y += 10;
    if colours_by_id(r) {
        panel.draw_text("estimates, coloured by source id:", &text, (x, y))?;
        y += 30;
        let ids = published_ids(r);
        for id in ids.iter().take(12) {
            panel.draw(&Circle::new((x + 14, y), 6, id_colour(*id).filled()))?;
            row(&mut y, &if *id == 0 { "id 0 (no live track)".to_string() } else { format!("id {id}") })?;
        }
        if ids.len() > 12 {
            row(&mut y, &format!("… {} ids in all", ids.len()))?;
        }
        if outside > 0 {
            row(&mut y, &format!("{outside} estimates outside the map"))?;
            row(&mut y, "are drawn at its edge")?;
        }
        return Ok(());
    }
    panel.draw_text("estimates, coloured by RSE (m):", &text, (x, y))?;
    y += 30;
    // Colour bar: 0–0.5 m green → black, then a red block for above 0.5 m.
    let (bar_w, gap, red_w) = (160, 30, 60);
    for i in 0..bar_w {
        let c = rse_colour(0.5 * f64::from(i) / f64::from(bar_w - 1));
        panel.draw(&Rectangle::new([(x + i, y - 10), (x + i + 1, y + 10)], c.filled()))?;
    }
    let red = [(x + bar_w + gap, y - 10), (x + bar_w + gap + red_w, y + 10)];
    panel.draw(&Rectangle::new(red, rse_colour(1.0).filled()))?;
    let ticks = label_style().pos(Pos::new(HPos::Center, VPos::Top));
    for (px, label) in [(0, "0"), (bar_w / 2, "0.25"), (bar_w, "0.5"), (bar_w + gap + red_w / 2, "> 0.5")] {
        panel.draw_text(label, &ticks, (x + px, y + 14))?;
    }
    y += 50;
    if no_truth > 0 {
        panel.draw(&Circle::new((x + 14, y), 5, NO_TRUTH.filled()))?;
        row(&mut y, &format!("estimate without truth ({no_truth})"))?;
    }
    if outside > 0 {
        row(&mut y, &format!("{outside} estimates outside the map"))?;
        row(&mut y, "are drawn at its edge")?;
    }
    Ok(())
}

//! `timeline.csv`: one row per published estimate.
//!
//! Columns, in order (units in the names):
//!
//! | column | meaning |
//! |---|---|
//! | `t_s` | time since the start of the run (s) |
//! | `d1_m` … `dN_m` | true distance robot k → source (m), one per robot in `robot_ids` order |
//! | `theta_deg` | θ as published by the coordinator (degrees) |
//! | `gdop` | GDOP as published (`inf` when the geometry gave none) |
//! | `est_x_m`, `est_y_m`, `est_z_m` | published estimate, map frame (m) |
//! | `truth_x_m`, `truth_y_m`, `truth_z_m` | true source position (m) |
//! | `rse_m` | ‖estimate − truth‖ (m) |
//! | `true_theta_deg` | θ at the true source between the true arrays (degrees) |
//! | `theta_in_band` | whether the θ used for statistics (true θ if known, else published) is in the band |
//! | `trusted` | whether the coordinator marked the estimate trusted |
//! | `method` | how the estimate was obtained (`ray_pair`, `kalman_filter`, …) |
//! | `robots` | robots whose rays contributed, separated by `;` |
//! | `tri_x_m`, `tri_y_m`, `tri_z_m` | triangulation beside a filtered estimate (m) |
//! | `tri_rse_m` | its RSE (m) |
//! | `nees` | eᵀP⁻¹e of the published estimate against the truth, P its published covariance |
//! | `source_id` | the estimate's `source_id` as published (0: no live track) |
//! | `truth_source` | index of the true source the row is scored against: the nearest one active at the stamp |
//! | `smooth_t_s` | time of the track's fixed-lag smoothed state published with the estimate (s; earlier than `t_s`) |
//! | `smooth_x_m`, `smooth_y_m`, `smooth_z_m` | the smoothed position (m) |
//! | `smooth_rse_m` | its error against the same true source at `smooth_t_s` (m) |
//! | `smooth_nees` | its eᵀP⁻¹e with its own covariance |
//! | `smooth_trusted` | whether it was published trusted (empty without a smoothed state) |
//!
//! The set of columns never depends on the data: a value that is absent (no
//! estimate position, no truth in a replay without truth, no triangulation) is an
//! empty cell, so the truth and RSE columns are present but empty in a replay
//! without truth. Numbers are written with 6 decimals; non-finite numbers as
//! `inf`, `-inf` or `nan`. Booleans are `true`/`false`. Text is quoted when it
//! holds a comma, quote or line break.

use std::fmt::Write as _;

use nalgebra::Point3;

use super::derived::{in_band, theta_for_stats_deg};
use super::record::RunRecord;

/// Number of robot distance columns: one per robot id, or as many as the
/// longest `distances_m` if that is longer.
pub fn distance_columns(record: &RunRecord) -> usize {
    let longest = record.rows.iter().map(|r| r.distances_m.len()).max().unwrap_or(0);
    record.robot_ids.len().max(longest)
}

/// The header of `timeline.csv` for `record` (column names, in order).
pub fn timeline_header(record: &RunRecord) -> Vec<String> {
    let mut cols = vec!["t_s".to_string()];
    cols.extend((1..=distance_columns(record)).map(|k| format!("d{k}_m")));
    cols.extend(
        [
            "theta_deg",
            "gdop",
            "est_x_m",
            "est_y_m",
            "est_z_m",
            "truth_x_m",
            "truth_y_m",
            "truth_z_m",
            "rse_m",
            "true_theta_deg",
            "theta_in_band",
            "trusted",
            "method",
            "robots",
            "tri_x_m",
            "tri_y_m",
            "tri_z_m",
            "tri_rse_m",
            "nees",
            "source_id",
            "truth_source",
            "smooth_t_s",
            "smooth_x_m",
            "smooth_y_m",
            "smooth_z_m",
            "smooth_rse_m",
            "smooth_nees",
            "smooth_trusted",
        ]
        .map(String::from),
    );
    cols
}

/// `timeline.csv` as text (header line, then one line per row, `\n` endings).
pub fn timeline_csv(record: &RunRecord) -> String {
    let n_d = distance_columns(record);
    let mut out = timeline_header(record).join(",");
    out.push('\n');
    let mut cells: Vec<String> = Vec::new();
    for row in &record.rows {
        cells.clear();
        cells.push(num(row.t_s));
        cells.extend((0..n_d).map(|k| row.distances_m.get(k).map_or_else(String::new, |d| num(*d))));
        cells.push(num(row.theta_deg));
        cells.push(num(row.gdop));
        point(&mut cells, row.estimate_in_map);
        point(&mut cells, row.truth_in_map);
        cells.push(opt(row.rse_m()));
        cells.push(opt(row.true_theta_deg));
        cells.push(in_band(theta_for_stats_deg(row), record.theta_band_deg).to_string());
        cells.push(row.trusted.to_string());
        cells.push(text(&row.method));
        cells.push(text(&row.robots.join(";")));
        point(&mut cells, row.triangulation_in_map);
        cells.push(opt(row.triangulation_rse_m()));
        cells.push(opt(row.nees()));
        cells.push(row.source_id.to_string());
        cells.push(row.truth_source.map_or_else(String::new, |k| k.to_string()));
        let s = row.smoothed.as_ref();
        cells.push(opt(s.map(|s| s.t_s)));
        point(&mut cells, s.map(|s| s.estimate_in_map));
        cells.push(opt(s.and_then(|s| s.rse_m())));
        cells.push(opt(s.and_then(|s| s.nees())));
        cells.push(s.map_or_else(String::new, |s| s.trusted.to_string()));
        let _ = writeln!(out, "{}", cells.join(","));
    }
    out
}

/// A number with 6 decimals, or `inf`/`-inf`/`nan`.
pub fn num(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf".into() } else { "-inf".into() }
    } else {
        format!("{v:.6}")
    }
}

/// [`num`] or an empty cell.
pub fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, num)
}

/// A text cell, quoted (RFC 4180) when it holds a comma, quote or line break.
pub fn text(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

fn point(cells: &mut Vec<String>, p: Option<Point3<f64>>) {
    match p {
        Some(p) => cells.extend([num(p.x), num(p.y), num(p.z)]),
        None => cells.extend([String::new(), String::new(), String::new()]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_and_text_cells() {
        assert_eq!(num(f64::INFINITY), "inf");
        assert_eq!(num(f64::NEG_INFINITY), "-inf");
        assert_eq!(num(f64::NAN), "nan");
        assert_eq!(num(1.5), "1.500000");
        assert_eq!(opt(None), "");
        assert_eq!(text("a,b"), "\"a,b\"");
        assert_eq!(text("say \"hi\""), "\"say \"\"hi\"\"\"");
        assert_eq!(text("kalman_filter"), "kalman_filter");
    }
}

//! Reports of a run: `timeline.csv`, `theta_bins.csv`, `summary.json`, plots.
//!
//! [`write_reports`] turns a [`RunRecord`] into, in `out_dir`:
//!
//! | file | what |
//! |---|---|
//! | `timeline.csv` | one row per published estimate ([`csv`] lists the columns) |
//! | `theta_bins.csv` | RSE mean/std/count in 15° bins of θ ([`bins`]) |
//! | `summary.json` | the run's figures ([`Summary`]; conventions in [`summary`]; the `multi_target` object in [`multi`]) |
//! | `commands.csv` | reposition commands the robots received: `t_s, robot, detail` |
//! | `goals.csv` | the goals of those commands, `t_s, robot, x_m, y_m, true_range_m` ([`goals_csv`]) |
//! | `distances_rse.{svg,png}` | d1 … dN and RSE over time |
//! | `theta_rse.{svg,png}` | θ over time with the band, and RSE |
//! | `rse_vs_theta.{svg,png}` | mean RSE ± std per 15° bin over the scatter of all estimates |
//! | `map.{svg,png}` | top-down map: room, robot paths and goals, every true source (numbered), estimates by RSE (one source) or by `source_id` (several) |
//!
//! [`write_comparison`] does it for one scenario run with active positioning on
//! and off, side by side. [`print_summary_table`] and [`print_comparison_table`]
//! print the figures for a terminal.

pub mod bins;
pub mod comparison;
pub mod csv;
pub mod derived;
pub mod multi;
pub mod plots;
pub mod record;
pub mod stats;
pub mod summary;
pub mod table;

use std::path::Path;

pub use comparison::write_comparison;
pub use derived::ThetaSource;
pub use multi::MultiTargetSummary;
pub use record::{RobotPath, RoomOutline, RunRecord, SmoothedRow, SourceTruth, TimelineRow};
pub use summary::{SmoothedSummary, Summary, TriangulationSummary, distinct_smoothed_states};
pub use table::{format_comparison_table, format_summary_table, print_comparison_table, print_summary_table};

use crate::SimError;
use derived::Derived;

/// File name of the timeline.
pub const TIMELINE_CSV: &str = "timeline.csv";
/// File name of the θ bins.
pub const THETA_BINS_CSV: &str = "theta_bins.csv";
/// File name of the summary.
pub const SUMMARY_JSON: &str = "summary.json";
/// File name of the reposition commands.
pub const COMMANDS_CSV: &str = "commands.csv";
/// File name of the commanded goals.
pub const GOALS_CSV: &str = "goals.csv";
/// Stems of the plots of one run; each is written as `.svg` and `.png`.
pub const PLOT_STEMS: [&str; 4] = ["distances_rse", "theta_rse", "rse_vs_theta", "map"];
/// File name of the side-by-side summaries of [`write_comparison`].
pub const COMPARISON_JSON: &str = "comparison.json";
/// Stem of the comparison plot (`.svg` and `.png`).
pub const COMPARISON_PLOT_STEM: &str = "comparison_theta";

/// Write every report of `record` into `out_dir` (created if missing) and return its summary.
///
/// Errors: a record whose rows are not in time order or whose θ band is not a
/// finite `lo ≤ hi` ([`SimError::InvalidConfig`]); a file that cannot be written
/// or drawn ([`SimError::File`], [`SimError::Json`] or [`SimError::Plot`], naming the file).
pub fn write_reports(record: &RunRecord, out_dir: &Path) -> Result<Summary, SimError> {
    validate(record)?;
    std::fs::create_dir_all(out_dir).map_err(|e| SimError::file(out_dir, e))?;
    let derived = Derived::new(record);

    write(out_dir, TIMELINE_CSV, &csv::timeline_csv(record))?;
    let theta_bins = bins::theta_bins(&derived);
    write(out_dir, THETA_BINS_CSV, &bins::bins_csv(&theta_bins, derived.theta_source))?;
    let summary = Summary::new(record, &derived);
    write(out_dir, SUMMARY_JSON, &summary.to_json())?;
    write(out_dir, COMMANDS_CSV, &commands_csv(record))?;
    write(out_dir, GOALS_CSV, &goals_csv(record))?;

    let [distances, theta, rse_theta, map] = PLOT_STEMS;
    plots::save(&plots::distances::DistancesRse { record, derived: &derived }, out_dir, distances)?;
    plots::save(&plots::theta::ThetaRse { record, derived: &derived }, out_dir, theta)?;
    let figure = plots::rse_theta::RseVsTheta { record, derived: &derived, bins: &theta_bins };
    plots::save(&figure, out_dir, rse_theta)?;
    plots::save(&plots::map::MapFigure { record, derived: &derived }, out_dir, map)?;
    Ok(summary)
}

/// Reject records the reports would silently misread.
fn validate(record: &RunRecord) -> Result<(), SimError> {
    let (lo, hi) = record.theta_band_deg;
    if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
        return Err(SimError::invalid(
            "theta_band_deg",
            format!("must be finite with lo ≤ hi, got ({lo}, {hi})"),
        ));
    }
    if let Some((i, row)) = record.rows.iter().enumerate().find(|(_, r)| !r.t_s.is_finite()) {
        return Err(SimError::invalid("rows.t_s", format!("must be finite, row {i} has {}", row.t_s)));
    }
    for (i, pair) in record.rows.windows(2).enumerate() {
        if pair[1].t_s < pair[0].t_s {
            let reason = format!(
                "must be in time order: row {} at {} s follows {} s",
                i + 1,
                pair[1].t_s,
                pair[0].t_s
            );
            return Err(SimError::invalid("rows.t_s", reason));
        }
    }
    Ok(())
}

/// `commands.csv` as text: a header, then one line per command in the order
/// received; text cells are quoted as in `timeline.csv` ([`csv::text`]).
pub fn commands_csv(record: &RunRecord) -> String {
    let mut out = String::from("t_s,robot,detail\n");
    for (t_s, robot, detail) in &record.commands {
        out.push_str(&format!("{t_s:.3},{},{}\n", csv::text(robot), csv::text(detail)));
    }
    out
}

/// `goals.csv` as text: a header, then every goal a robot was commanded to,
/// in time order (robots in record order at equal times). `true_range_m` is
/// the horizontal distance from the goal to the nearest true source playing
/// within a second of the command (the keep-out is about that distance;
/// empty when no source's truth is known), so that goals planned around an
/// estimate that was off show up in a replay as in a live run.
pub fn goals_csv(record: &RunRecord) -> String {
    let mut goals: Vec<(f64, &str, f64, f64)> = record
        .robots
        .iter()
        .flat_map(|r| r.goals.iter().map(move |&(t, x, y)| (t, r.id.as_str(), x, y)))
        .collect();
    goals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = String::from("t_s,robot,x_m,y_m,true_range_m\n");
    for (t_s, robot, x, y) in goals {
        let range = record
            .sources
            .iter()
            .filter(|s| s.active_within(t_s - 1.0, t_s + 1.0))
            .filter_map(|s| s.position_at(t_s))
            .map(|p| (p.x - x).hypot(p.y - y))
            .min_by(f64::total_cmp);
        let range = range.map_or(String::new(), |r| format!("{r:.3}"));
        out.push_str(&format!("{t_s:.3},{},{x:.3},{y:.3},{range}\n", csv::text(robot)));
    }
    out
}

/// Write `contents` to `dir/name`.
fn write(dir: &Path, name: &str, contents: &str) -> Result<(), SimError> {
    let path = dir.join(name);
    std::fs::write(&path, contents).map_err(|e| SimError::file(&path, e))
}

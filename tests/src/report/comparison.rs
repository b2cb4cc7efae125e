//! One scenario and seed run with active positioning on and off, reported side by side.
//!
//! [`write_comparison`] writes, in `out_dir`:
//! - `active/` and `passive/`: each run's full report ([`super::write_reports`]);
//! - `comparison.json`: `{"scenario", "active": Summary, "passive": Summary,
//!   "difference": {key: passive − active}}` for the headline figures (a
//!   positive RSE difference means active positioning lowered the error);
//! - `comparison_theta.{svg,png}`: θ of both runs with the band, and both RSEs.
//!
//! Printing is left to the caller ([`super::print_comparison_table`]).

use std::path::Path;

use serde::Serialize;
use serde_json::{Map, Value};

use super::derived::Derived;
use super::plots::{self, comparison::ComparisonTheta};
use super::summary::Summary;
use super::{COMPARISON_JSON, COMPARISON_PLOT_STEM, RunRecord, write_reports};
use crate::SimError;

/// Figures whose difference `passive − active` is written in `comparison.json`.
const DIFFERENCES: [&str; 8] = [
    "rse_median_m",
    "rse_p95_m",
    "rse_p95_in_band_m",
    "rse_p95_out_of_band_m",
    "time_in_band_ratio",
    "time_to_band_s",
    "in_band_ratio_after_convergence",
    "rse_p95_after_convergence_m",
];

#[derive(Serialize)]
struct Comparison<'a> {
    scenario: &'a str,
    active: &'a Summary,
    passive: &'a Summary,
    difference: Map<String, Value>,
}

/// Write both runs' reports and their comparison; returns `(active, passive)` summaries.
///
/// Errors: `on` without or `off` with active positioning
/// ([`SimError::InvalidConfig`], the arguments are probably swapped), and
/// everything [`write_reports`] returns.
pub fn write_comparison(
    on: &RunRecord,
    off: &RunRecord,
    out_dir: &Path,
) -> Result<(Summary, Summary), SimError> {
    if !on.active_positioning || off.active_positioning {
        let reason = format!(
            "expected `on` with and `off` without active positioning, got on={} off={}",
            on.active_positioning, off.active_positioning
        );
        return Err(SimError::invalid("active_positioning", reason));
    }
    let active = write_reports(on, &out_dir.join("active"))?;
    let passive = write_reports(off, &out_dir.join("passive"))?;

    let comparison = Comparison {
        scenario: &on.name,
        active: &active,
        passive: &passive,
        difference: differences(&active, &passive),
    };
    let mut json = serde_json::to_string_pretty(&comparison)
        .map_err(|source| SimError::Json { what: COMPARISON_JSON.into(), source })?;
    json.push('\n');
    let path = out_dir.join(COMPARISON_JSON);
    std::fs::write(&path, json).map_err(|e| SimError::file(&path, e))?;

    let (d_on, d_off) = (Derived::new(on), Derived::new(off));
    plots::save(&ComparisonTheta { on: (on, &d_on), off: (off, &d_off) }, out_dir, COMPARISON_PLOT_STEM)?;
    Ok((active, passive))
}

/// `passive − active` for each of [`DIFFERENCES`]; `null` when either is undefined.
fn differences(active: &Summary, passive: &Summary) -> Map<String, Value> {
    let (a, p) =
        (serde_json::to_value(active).unwrap_or_default(), serde_json::to_value(passive).unwrap_or_default());
    DIFFERENCES
        .iter()
        .map(|key| {
            let diff = match (a.get(key).and_then(Value::as_f64), p.get(key).and_then(Value::as_f64)) {
                (Some(a), Some(p)) => Value::from(p - a),
                _ => Value::Null,
            };
            (key.to_string(), diff)
        })
        .collect()
}

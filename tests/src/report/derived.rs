//! Per-row values every report derives the same way: which θ is used, whether
//! it is in the band, the RSE of the estimate and of the triangulation.

use serde::Serialize;

use super::record::{RunRecord, TimelineRow};
use super::stats;

/// Which θ the band statistics and the θ bins use.
///
/// The paper's θ is the angle at the *true* source between the *true* array
/// positions, so the true θ is used whenever the record has it; a replay
/// without truth falls back to the θ the coordinator published.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ThetaSource {
    /// Every row has a true θ.
    True,
    /// No row has a true θ: the published θ is used.
    Published,
    /// Some rows have a true θ (used there), the others use the published θ.
    Mixed,
    /// The record has no rows.
    None,
}

impl ThetaSource {
    /// Name as written in CSV files and JSON (`true`, `published`, `mixed`, `none`).
    pub fn as_str(self) -> &'static str {
        match self {
            ThetaSource::True => "true",
            ThetaSource::Published => "published",
            ThetaSource::Mixed => "mixed",
            ThetaSource::None => "none",
        }
    }

    /// The source used for a record's rows.
    pub fn of(record: &RunRecord) -> Self {
        let with_true = record.rows.iter().filter(|r| r.true_theta_deg.is_some()).count();
        match (record.rows.len(), with_true) {
            (0, _) => ThetaSource::None,
            (n, t) if t == n => ThetaSource::True,
            (_, 0) => ThetaSource::Published,
            _ => ThetaSource::Mixed,
        }
    }
}

/// θ of a row for statistics (degrees): the true θ when known, else the published one.
pub fn theta_for_stats_deg(row: &TimelineRow) -> f64 {
    row.true_theta_deg.unwrap_or(row.theta_deg)
}

/// Whether `theta_deg` lies in the closed band `[lo, hi]` (degrees); NaN is out.
pub fn in_band(theta_deg: f64, band_deg: (f64, f64)) -> bool {
    theta_deg >= band_deg.0 && theta_deg <= band_deg.1
}

/// A finite RSE of the published estimate (m), when estimate and truth exist.
pub fn rse(row: &TimelineRow) -> Option<f64> {
    row.rse_m().filter(|v| v.is_finite())
}

/// A finite RSE of the triangulation beside a filtered estimate (m).
pub fn tri_rse(row: &TimelineRow) -> Option<f64> {
    row.triangulation_rse_m().filter(|v| v.is_finite())
}

/// The values derived once per record and shared by the summary and the plots.
#[derive(Clone, Debug)]
pub struct Derived {
    /// θ used for statistics per row (degrees), see [`theta_for_stats_deg`].
    pub theta_deg: Vec<f64>,
    /// Whether that θ is in the record's band.
    pub in_band: Vec<bool>,
    /// Time each row stands for (s), see [`stats::time_weights`].
    pub weights_s: Vec<f64>,
    /// RSE per row (m).
    pub rse_m: Vec<Option<f64>>,
    /// Triangulation RSE per row (m).
    pub tri_rse_m: Vec<Option<f64>>,
    /// Which θ was used.
    pub theta_source: ThetaSource,
}

impl Derived {
    /// Derive everything from `record`.
    pub fn new(record: &RunRecord) -> Self {
        let times: Vec<f64> = record.rows.iter().map(|r| r.t_s).collect();
        let theta_deg: Vec<f64> = record.rows.iter().map(theta_for_stats_deg).collect();
        Derived {
            in_band: theta_deg.iter().map(|t| in_band(*t, record.theta_band_deg)).collect(),
            theta_deg,
            weights_s: stats::time_weights(&times, record.duration_s),
            rse_m: record.rows.iter().map(rse).collect(),
            tri_rse_m: record.rows.iter().map(tri_rse).collect(),
            theta_source: ThetaSource::of(record),
        }
    }
}

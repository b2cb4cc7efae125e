//! What a simulation or replay run records, for reports and plots.
//!
//! The runner fills a [`RunRecord`]; [`super::write_reports`] turns it into
//! `timeline.csv`, `theta_bins.csv`, `summary.json` and the plots.

use nalgebra::{Matrix3, Point3};

/// One published estimate of the coordinator, with the truth at its stamp.
#[derive(Clone, Debug, PartialEq)]
pub struct TimelineRow {
    /// Time since the start of the run (s), from the estimate's stamp.
    pub t_s: f64,
    /// True distance from each robot's array centre to the source (m), in robot order.
    /// Empty when no truth is known (replay without a truth trajectory).
    pub distances_m: Vec<f64>,
    /// θ as the coordinator published it (degrees): for two robots, the angle at the
    /// source between them; for more, the best pair.
    pub theta_deg: f64,
    /// θ at the true source between the true array positions (degrees), when truth is known.
    pub true_theta_deg: Option<f64>,
    /// GDOP as published (infinite when the geometry gave none).
    pub gdop: f64,
    /// Published position (map frame, m): the coordinator's best estimate.
    pub estimate_in_map: Option<Point3<f64>>,
    /// The instantaneous triangulation published beside it (the paper's method,
    /// refined on the floor-image model for folded rays), when
    /// the best estimate is a filtered one.
    pub triangulation_in_map: Option<Point3<f64>>,
    /// Whether the coordinator marked the estimate trusted.
    pub trusted: bool,
    /// How the best estimate was obtained (`ray_pair`, `levenberg_marquardt`, `kalman_filter`, …).
    pub method: String,
    /// Robots whose rays contributed.
    pub robots: Vec<String>,
    /// True source position at the estimate's stamp (map frame, m), when known.
    pub truth_in_map: Option<Point3<f64>>,
    /// Covariance published with the best estimate (m², map frame), when there is one.
    pub covariance: Option<Matrix3<f64>>,
    /// The estimate's `source_id` as published (0: no live track followed it).
    pub source_id: u64,
    /// Index of the true source the row is scored against (`truth_in_map`,
    /// `distances_m`, `true_theta_deg`): the nearest one active at the stamp
    /// ([`super::multi::nearest_truth`]); `None` without truth.
    pub truth_source: Option<usize>,
    /// The track's fixed-lag smoothed state published with the estimate, scored
    /// against the truth at its own (earlier) stamp.
    pub smoothed: Option<SmoothedRow>,
}

/// A smoothed state published beside an estimate (`SourceEstimate.smoothed`),
/// with the truth at its stamp.
#[derive(Clone, Debug, PartialEq)]
pub struct SmoothedRow {
    /// Time the state refers to, since the start of the run (s).
    pub t_s: f64,
    /// Smoothed position (map frame, m).
    pub estimate_in_map: Point3<f64>,
    /// Its position covariance (m²).
    pub covariance: Option<Matrix3<f64>>,
    /// True source position at `t_s` (the same true source as the row's), when known.
    pub truth_in_map: Option<Point3<f64>>,
    /// θ at that true source between the true arrays at `t_s` (degrees).
    pub true_theta_deg: Option<f64>,
    /// Whether it was published trusted.
    pub trusted: bool,
}

impl SmoothedRow {
    /// ‖estimate − truth‖ (m), when the truth is known.
    pub fn rse_m(&self) -> Option<f64> {
        Some((self.estimate_in_map - self.truth_in_map?).norm())
    }

    /// eᵀP⁻¹e against the truth (χ², 3 dof, when the covariance is honest).
    pub fn nees(&self) -> Option<f64> {
        let e = self.estimate_in_map - self.truth_in_map?;
        let chol = self.covariance?.cholesky()?;
        Some(e.dot(&chol.solve(&e)))
    }
}

impl TimelineRow {
    /// Root square error ‖estimate − truth‖ (m), when both exist.
    pub fn rse_m(&self) -> Option<f64> {
        Some((self.estimate_in_map? - self.truth_in_map?).norm())
    }

    /// Normalized estimation error squared, eᵀ P⁻¹ e with e = estimate − truth and
    /// P the published covariance: χ² with 3 degrees of freedom (mean 3) when the
    /// covariance is honest. `None` without truth, covariance, or when P is not
    /// positive definite.
    pub fn nees(&self) -> Option<f64> {
        let e = self.estimate_in_map? - self.truth_in_map?;
        let chol = self.covariance?.cholesky()?;
        Some(e.dot(&chol.solve(&e)))
    }

    /// RSE of the triangulation beside a filtered estimate (m).
    pub fn triangulation_rse_m(&self) -> Option<f64> {
        Some((self.triangulation_in_map? - self.truth_in_map?).norm())
    }
}

/// A robot's path during the run.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotPath {
    /// Robot id.
    pub id: String,
    /// True base positions over time: (t_s, x_m, y_m, yaw_rad).
    pub samples: Vec<(f64, f64, f64, f64)>,
    /// Goals the robot was commanded to, (t_s when issued, x_m, y_m).
    pub goals: Vec<(f64, f64, f64)>,
}

/// The truth of one source: where it was and when it played.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceTruth {
    /// Positions over time: (t_s, position in the map frame, m), in time order;
    /// linearly interpolated between samples, held outside them.
    pub path: Vec<(f64, Point3<f64>)>,
    /// When it played: `[start_s, end_s)` intervals; empty means always.
    pub active: Vec<(f64, f64)>,
}

impl SourceTruth {
    /// A source that always plays.
    pub fn always(path: Vec<(f64, Point3<f64>)>) -> Self {
        SourceTruth { path, active: Vec::new() }
    }

    /// Whether it plays at `t_s`.
    pub fn active_at(&self, t_s: f64) -> bool {
        self.active.is_empty() || self.active.iter().any(|(a, b)| *a <= t_s && t_s < *b)
    }

    /// Whether it plays at some time in `(from_s, to_s]`.
    pub fn active_within(&self, from_s: f64, to_s: f64) -> bool {
        self.active.is_empty() || self.active.iter().any(|(a, b)| *a <= to_s && *b > from_s)
    }

    /// Its position at `t_s` (`None` with an empty path).
    pub fn position_at(&self, t_s: f64) -> Option<Point3<f64>> {
        let p = &self.path;
        let i = p.partition_point(|(t, _)| *t <= t_s);
        if i == 0 {
            return p.first().map(|(_, x)| *x);
        }
        if i == p.len() {
            return p.last().map(|(_, x)| *x);
        }
        let ((t0, a), (t1, b)) = (p[i - 1], p[i]);
        let u = if t1 > t0 { (t_s - t0) / (t1 - t0) } else { 0.0 };
        Some(a + (b - a) * u)
    }
}

/// The room as drawn on the top-down map.
#[derive(Clone, Debug, PartialEq)]
pub struct RoomOutline {
    /// Floor polygon (map frame, m), counter-clockwise.
    pub floor: Vec<[f64; 2]>,
    /// Obstacle polygons.
    pub obstacles: Vec<Vec<[f64; 2]>>,
}

/// Everything a run recorded.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRecord {
    /// Scenario name (or "replay").
    pub name: String,
    /// Simulated (or replayed) duration (s).
    pub duration_s: f64,
    /// Whether active positioning was on.
    pub active_positioning: bool,
    /// The acceptable θ band (degrees).
    pub theta_band_deg: (f64, f64),
    /// One row per published estimate, in time order.
    pub rows: Vec<TimelineRow>,
    /// Robot ids, in the order of `TimelineRow::distances_m`.
    pub robot_ids: Vec<String>,
    /// Robot paths (empty in replay without poses).
    pub robots: Vec<RobotPath>,
    /// Every true source (scenario order, or `--truth` order in a replay); empty
    /// when unknown. Source 0 is the one the single-source figures were made for.
    pub sources: Vec<SourceTruth>,
    /// Room outline for the map, when known.
    pub room: Option<RoomOutline>,
    /// Seed of the run (simulation only).
    pub seed: Option<u64>,
    /// Reposition commands the robots received: (t_s, robot id, the
    /// coordinator's detail text: reason, θ, and the planner's note).
    pub commands: Vec<(f64, String, String)>,
}

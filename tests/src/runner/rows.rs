//! Turns published estimates into timeline rows scored against the truth.

use nalgebra::Point3;
use soundmap_proto::{Stamp, wire};

use super::SIM_EPOCH;
use super::robot::SimRobot;
use crate::report::multi::nearest_truth;
use crate::report::{SmoothedRow, SourceTruth, TimelineRow};
use crate::scenario::Scenario;

/// Builds [`TimelineRow`]s.
#[derive(Debug)]
pub struct RowMaker {
    truths: Vec<SourceTruth>,
    rows: Vec<TimelineRow>,
}

/// The exact truth of a scenario source: its path points and `active` intervals.
pub fn source_truth(spec: &crate::scenario::SourceSpec) -> SourceTruth {
    SourceTruth {
        path: spec.path.iter().map(|p| (p.t_s, Point3::new(p.x_m, p.y_m, p.z_m))).collect(),
        active: spec.active_intervals(),
    }
}

/// The truth a row at `t_s` with estimate `estimate` is scored against: the
/// nearest true source active at `t_s` ([`nearest_truth`]), with its position.
pub fn truth_for(
    truths: &[SourceTruth],
    t_s: f64,
    estimate: Option<Point3<f64>>,
) -> Option<(usize, Point3<f64>)> {
    let k = nearest_truth(truths, t_s, estimate)?;
    Some((k, truths[k].position_at(t_s)?))
}

/// The name of a wire estimate method.
pub fn method_name(m: i32) -> String {
    match wire::EstimateMethod::try_from(m) {
        Ok(wire::EstimateMethod::RayPair) => "ray_pair",
        Ok(wire::EstimateMethod::LeastSquares) => "least_squares",
        Ok(wire::EstimateMethod::LevenbergMarquardt) => "levenberg_marquardt",
        Ok(wire::EstimateMethod::KalmanFilter) => "kalman_filter",
        _ => "none",
    }
    .into()
}

/// A wire point.
pub fn point(v: &Option<wire::Vec3>) -> Option<Point3<f64>> {
    v.as_ref().map(|v| Point3::new(v.x, v.y, v.z))
}

/// θ at `x` between the points, for two; the pair closest to 90° for more (degrees).
pub fn best_theta_deg(x: &Point3<f64>, points: &[Point3<f64>]) -> f64 {
    let mut best: Option<f64> = None;
    for i in 0..points.len() {
        for j in (i + 1)..points.len() {
            let t = soundmap_server::uncertainty::angle_at_deg(x, &points[i], &points[j]);
            if best.is_none_or(|b| (t - 90.0).abs() < (b - 90.0).abs()) {
                best = Some(t);
            }
        }
    }
    best.unwrap_or(0.0)
}

/// A published estimate as a timeline row, scored against `truth` (the true
/// source's index and position) and the true array centres (`arrays`, in robot
/// order) at its stamp.
pub fn row_of(
    e: &wire::SourceEstimate,
    t0: Stamp,
    truth: Option<(usize, Point3<f64>)>,
    arrays: &[Point3<f64>],
) -> TimelineRow {
    let truth_source = truth.map(|(k, _)| k);
    let truth = truth.map(|(_, p)| p);
    let t_s = Stamp::from_ns(e.stamp_ns).seconds_since(t0);
    let triangulation = if e.filtered.is_some() {
        e.triangulation.as_ref().and_then(|t| point(&t.position_in_map_m))
    } else {
        None
    };
    TimelineRow {
        t_s,
        distances_m: truth.map(|s| arrays.iter().map(|a| (a - s).norm()).collect()).unwrap_or_default(),
        theta_deg: e.theta_deg,
        true_theta_deg: truth.filter(|_| arrays.len() >= 2).map(|s| best_theta_deg(&s, arrays)),
        gdop: if e.gdop > 0.0 { e.gdop } else { f64::INFINITY },
        estimate_in_map: point(&e.position_in_map_m),
        triangulation_in_map: triangulation,
        trusted: e.trusted,
        method: method_name(e.method),
        robots: e.robots.clone(),
        truth_in_map: truth,
        covariance: e.covariance.as_ref().and_then(soundmap_proto::monitoring::covariance_from_wire),
        source_id: e.source_id,
        truth_source,
        smoothed: None,
    }
}

/// A published smoothed state as a [`SmoothedRow`], scored against `truth`
/// (the true source's position at the state's own stamp) and the true array
/// centres `arrays` then. `None` without a position.
pub fn smoothed_row(
    s: &wire::SmoothedState,
    t0: Stamp,
    truth: Option<Point3<f64>>,
    arrays: &[Point3<f64>],
) -> Option<SmoothedRow> {
    Some(SmoothedRow {
        t_s: Stamp::from_ns(s.stamp_ns).seconds_since(t0),
        estimate_in_map: point(&s.position_in_map_m)?,
        covariance: s.position_covariance.as_ref().and_then(soundmap_proto::monitoring::covariance_from_wire),
        truth_in_map: truth,
        true_theta_deg: truth.filter(|_| arrays.len() >= 2).map(|p| best_theta_deg(&p, arrays)),
        trusted: s.trusted,
    })
}

impl RowMaker {
    /// Rows for `scenario`, each scored against its nearest active source.
    pub fn new(scenario: &Scenario, _robots: &[SimRobot]) -> Self {
        RowMaker { truths: scenario.sources.iter().map(source_truth).collect(), rows: Vec::new() }
    }

    /// Records an estimate.
    pub fn push(&mut self, e: &wire::SourceEstimate, robots: &[SimRobot]) {
        let t_s = Stamp::from_ns(e.stamp_ns).seconds_since(SIM_EPOCH);
        let arrays: Vec<Point3<f64>> = robots.iter().map(|r| r.array_centre_at(t_s)).collect();
        let truth = truth_for(&self.truths, t_s, point(&e.position_in_map_m));
        let mut row = row_of(e, SIM_EPOCH, truth, &arrays);
        if let Some(s) = &e.smoothed {
            let ts = Stamp::from_ns(s.stamp_ns).seconds_since(SIM_EPOCH);
            let arrays: Vec<Point3<f64>> = robots.iter().map(|r| r.array_centre_at(ts)).collect();
            let truth = truth.and_then(|(k, _)| self.truths[k].position_at(ts));
            row.smoothed = smoothed_row(s, SIM_EPOCH, truth, &arrays);
        }
        self.rows.push(row);
    }

    /// The rows, in publication order.
    pub fn finish(self) -> Vec<TimelineRow> {
        self.rows
    }
}

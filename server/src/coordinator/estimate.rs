//! What the coordinator publishes about a source: the instantaneous
//! triangulation of the aligned rays (the paper's method; for folded rays of
//! planar arrays, refined on the floor-image model) and, beside it, the
//! tracked (filtered) state; and which of the two is the "best" estimate.

use nalgebra::{Matrix3, Point3};
use soundmap_proto::{RobotId, Stamp};

use crate::planner::SourceEstimate;
use crate::stats::chi2_quantile;
use crate::tracking::{SmoothedEstimate, TrackEstimate, TrackState};
use crate::triangulation::{Degeneracy, Gate, GateReason, Method, Triangulation, TriangulationConfig};

/// Farthest the triangulation may lie from a confirmed track, horizontally,
/// to count as the track's fix for the planner's keep-out (m): further off,
/// it is an outlier or another source's rays, which the track's own gate
/// judges.
pub const FIX_WITHIN_M: f64 = 3.0;

/// One published estimate of a source.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// Coordinator-wide source id: the id of the track following the source,
    /// 0 when no live track does (tracking off, not started yet, or lost).
    pub source_id: u64,
    /// Stamp of the newest observation used.
    pub stamp: Stamp,
    /// Robots whose rays were combined, in ray order.
    pub robots: Vec<RobotId>,
    /// The instantaneous triangulation of those rays.
    pub triangulation: Triangulation,
    /// The track's state predicted to `stamp`, when a track exists (its
    /// `state` says whether it is tentative, confirmed or lost).
    pub filtered: Option<TrackEstimate>,
    /// The track's fixed-lag smoothed state (about
    /// `tracking.smoothing_lag_s` behind `stamp`), when smoothing is on and
    /// the track is older than the lag.
    pub smoothed: Option<SmoothedEstimate>,
    /// Share of the triangulation's covariance added to the filter's in the
    /// published covariance (`tracking.correlated_doa_fraction`).
    pub correlated_doa_fraction: f64,
}

/// Where the best position of an [`Estimate`] comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BestSource {
    /// The track: confirmed and trusted.
    Filter,
    /// The triangulation (trusted or not: see [`Estimate::trusted`]).
    Triangulation,
}

impl Estimate {
    /// The filtered state is used when its track is confirmed and trusted
    /// (position RMS within `tracking.trusted_max_rms_m`); otherwise the triangulation.
    pub fn best_source(&self) -> BestSource {
        match &self.filtered {
            Some(f) if f.trusted => BestSource::Filter,
            _ => BestSource::Triangulation,
        }
    }

    /// Best position, if any (map frame, m).
    pub fn position(&self) -> Option<Point3<f64>> {
        match (self.best_source(), &self.filtered) {
            (BestSource::Filter, Some(f)) => Some(f.position_in_map),
            _ => self.triangulation.solution().map(|s| s.source_in_map),
        }
    }

    /// Covariance of [`Estimate::position`] (m²). For the filter: its own plus
    /// `correlated_doa_fraction` × the current triangulation's, the error its
    /// averaging cannot remove when the DoAs' errors persist.
    pub fn covariance(&self) -> Option<Matrix3<f64>> {
        match (self.best_source(), &self.filtered) {
            (BestSource::Filter, Some(f)) => Some(f.position_covariance() + self.correlated_floor()),
            _ => self.triangulation.solution().and_then(|s| s.quality.covariance),
        }
    }

    /// `correlated_doa_fraction` × the current triangulation's covariance
    /// (zero without one): what averaging the DoAs cannot remove when their
    /// errors persist, added to the filter's and the smoother's own.
    fn correlated_floor(&self) -> Matrix3<f64> {
        let floor = self.triangulation.solution().and_then(|s| s.quality.covariance);
        floor.map_or_else(Matrix3::zeros, |c| c * self.correlated_doa_fraction)
    }

    /// Covariance of the smoothed state as published (m²): the smoother's own
    /// plus `correlated_doa_fraction` × the current triangulation's, as for the
    /// filter ([`Estimate::covariance`]): the smoother averages the DoAs as if
    /// their errors were independent, and they are not. `None` without a
    /// smoothed state.
    pub fn smoothed_covariance(&self) -> Option<Matrix3<f64>> {
        Some(self.smoothed.as_ref()?.position_covariance() + self.correlated_floor())
    }

    /// Whether the smoothed state can be trusted to its published covariance:
    /// its track is trusted now (confirmed, consistent, at a good geometry or
    /// with evidence from one, [`TrackEstimate::trusted`]) and the estimate is
    /// trusted ([`Estimate::trusted`]).
    pub fn smoothed_trusted(&self) -> bool {
        self.smoothed.is_some() && self.filtered.as_ref().is_some_and(|f| f.trusted) && self.trusted()
    }

    /// Estimator of [`Estimate::position`]: `None` for the filter, else the triangulation's.
    pub fn triangulation_method(&self) -> Option<Method> {
        self.triangulation.solution().map(|s| s.method)
    }

    /// Whether the best estimate can be trusted to its covariance: a trusted
    /// track whose current rays are not ill-conditioned, or else a
    /// triangulation its gate accepted.
    ///
    /// A filter fed at θ ≈ 10° keeps shrinking its covariance with every DoA
    /// as if their errors were independent, but a room biases each robot's DoAs
    /// consistently for a given geometry: averaging them does not pin down
    /// the depth. So a filtered estimate is not trusted while the instantaneous
    /// geometry is ill-conditioned (or degenerate), however small its covariance.
    pub fn trusted(&self) -> bool {
        match self.best_source() {
            BestSource::Filter => match &self.triangulation {
                Triangulation::Solved(s) => {
                    !matches!(s.gate, Gate::Rejected(GateReason::IllConditioned { .. }))
                }
                Triangulation::Degenerate(_) => false,
            },
            BestSource::Triangulation => {
                matches!(self.triangulation.solution(), Some(s) if s.gate == Gate::Accepted)
            }
        }
    }

    /// Whether the rays of at least two robots were combined (the sound map
    /// also publishes a source on one robot's ray for a short while).
    pub fn triangulated(&self) -> bool {
        self.robots.len() >= 2
    }

    /// GDOP of the triangulation (infinite when not available).
    pub fn gdop(&self) -> f64 {
        self.triangulation.solution().map_or(f64::INFINITY, |s| s.quality.gdop)
    }

    /// θ at the source (degrees): from the triangulation, or between the ray
    /// directions when the rays give no point.
    pub fn theta_deg(&self) -> f64 {
        match &self.triangulation {
            Triangulation::Solved(s) => s.quality.theta_deg,
            Triangulation::Degenerate(d) => match d {
                Degeneracy::NearParallel { ray_angle_deg }
                | Degeneracy::BehindArray { ray_angle_deg, .. } => *ray_angle_deg,
                Degeneracy::TooFewRays { .. } => 0.0,
            },
        }
    }

    /// The source as the planner should see it, or why there is none:
    /// - the filtered state (with its velocity) when the track is confirmed;
    /// - else the triangulation when its gate accepted it, *or* rejected it only
    ///   for its geometry (ill-conditioned or too uncertain) while its rays agree
    ///   (residual χ² within the gate): that is exactly the bad geometry the
    ///   planner must fix (the paper's θ ≈ 9°), and its covariance says how
    ///   vague it is (the planner refuses beyond `planner.max_source_rms_m`);
    /// - never rays that disagree, a point too far, or no point.
    ///
    /// With the filtered state goes the triangulation of the same rays as its
    /// fix, when the gate accepted it and it lies within [`FIX_WITHIN_M`] of
    /// the track horizontally: the planner's keep-out covers the way from the
    /// track to it (a filter following a walker lags behind it).
    pub fn planning_source(&self, triangulation: &TriangulationConfig) -> Result<SourceEstimate, String> {
        if let Some(f) = self.filtered.as_ref().filter(|f| f.state == TrackState::Confirmed) {
            let fix_in_map = match &self.triangulation {
                Triangulation::Solved(s)
                    if s.gate == Gate::Accepted
                        && (s.source_in_map - f.position_in_map).xy().norm() <= FIX_WITHIN_M =>
                {
                    Some(s.source_in_map)
                }
                _ => None,
            };
            return Ok(SourceEstimate {
                position_in_map: f.position_in_map,
                covariance_m2: f.position_covariance(),
                velocity_in_map: Some(f.velocity_in_map),
                fix_in_map,
            });
        }
        let s = match &self.triangulation {
            Triangulation::Solved(s) => s,
            Triangulation::Degenerate(d) => return Err(format!("no source estimate: {d}")),
        };
        let usable = match s.gate {
            Gate::Accepted => true,
            Gate::Rejected(GateReason::IllConditioned { .. } | GateReason::Uncertain { .. }) => {
                s.residual_chi2 <= chi2_quantile(s.residual_dof, triangulation.residual_probability)
            }
            Gate::Rejected(_) => false,
        };
        match (usable, s.quality.covariance) {
            (true, Some(c)) => Ok(SourceEstimate {
                position_in_map: s.source_in_map,
                covariance_m2: c,
                velocity_in_map: None,
                fix_in_map: None,
            }),
            (true, None) => Err("no source estimate: the triangulation has no covariance".into()),
            (false, _) => Err(format!(
                "no usable source estimate: triangulation rejected ({})",
                match s.gate {
                    Gate::Rejected(r) => r.to_string(),
                    Gate::Accepted => "accepted".into(),
                }
            )),
        }
    }
}

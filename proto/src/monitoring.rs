//! Domain types of the `Monitoring` service and their wire conversions: a
//! robot's liveness, the planner's latest decision, the operator's active
//! positioning settings, and covariances read back from the wire.
//!
//! The coordinator builds these and sends them; clients (the simulator,
//! dashboards, tests) read the wire forms back with the same functions. Wire
//! numbers that must be finite (GDOP, θ) are sent as 0 when they are not: the
//! wire has no infinities, and `trusted`/the gate tell the rest.
//!
//! Conversions of a source estimate (triangulation, filtered state) and of a
//! robot's full state stay with the coordinator, whose types they read.

use nalgebra::Matrix3;

use crate::stamp::Stamp;
use crate::wire;

/// Liveness of a robot, as monitoring reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Liveness {
    /// Connected and heard from within the stale timeout.
    Live,
    /// Connected but silent too long; out of triangulation.
    Stale,
    /// Stream closed; state kept for a reconnection.
    Disconnected,
}

impl Liveness {
    /// The wire value.
    pub fn to_wire(self) -> wire::Liveness {
        match self {
            Liveness::Live => wire::Liveness::Live,
            Liveness::Stale => wire::Liveness::Stale,
            Liveness::Disconnected => wire::Liveness::Disconnected,
        }
    }
}

/// Kind of the planner's latest decision.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlanKind {
    /// Goals were sent.
    Planned,
    /// The robots were left as they are.
    Hold,
    /// No placement meets the constraints.
    Infeasible,
}

impl PlanKind {
    /// The wire value.
    pub fn to_wire(self) -> wire::PlannerOutcome {
        match self {
            PlanKind::Planned => wire::PlannerOutcome::Planned,
            PlanKind::Hold => wire::PlannerOutcome::Hold,
            PlanKind::Infeasible => wire::PlannerOutcome::Infeasible,
        }
    }
}

/// The planner's latest decision, for monitoring (waits for the planning
/// period are not decisions and leave it unchanged).
#[derive(Clone, Debug, PartialEq)]
pub struct PlannerStatus {
    /// Coordinator clock of the decision.
    pub decided: Stamp,
    /// What it was.
    pub kind: PlanKind,
    /// Short stable name of the reason (`geometry_good`, `no_source`, …), for logs.
    pub key: &'static str,
    /// The reason in words.
    pub detail: String,
    /// When goals were last sent.
    pub last_planned: Option<Stamp>,
    /// Commands sent since start.
    pub commands_issued: u64,
    /// Of the last plan: best pairwise θ (degrees) and GDOP once its goals are reached.
    pub predicted_theta_deg: Option<f64>,
    /// See `predicted_theta_deg`.
    pub predicted_gdop: Option<f64>,
    /// The last plan came from the sampling fallback.
    pub used_fallback: bool,
}

impl PlannerStatus {
    /// The wire form (`PlannerStatus`); absent or non-finite predictions are 0.
    pub fn to_wire(&self) -> wire::PlannerStatus {
        wire::PlannerStatus {
            decided_ns: self.decided.as_ns(),
            outcome: self.kind.to_wire() as i32,
            detail: self.detail.clone(),
            last_planned_ns: self.last_planned.map_or(0, |t| t.as_ns()),
            commands_issued: self.commands_issued,
            predicted_theta_deg: self.predicted_theta_deg.map_or(0.0, |v| finite_or(v, 0.0)),
            predicted_gdop: self.predicted_gdop.map_or(0.0, |v| finite_or(v, 0.0)),
            used_fallback: self.used_fallback,
        }
    }
}

/// The operator-facing active positioning settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositioningSettings {
    /// Whether reposition commands are sent.
    pub enabled: bool,
    /// Acceptable θ band (degrees).
    pub theta_min_deg: f64,
    /// See `theta_min_deg`.
    pub theta_max_deg: f64,
}

impl PositioningSettings {
    /// The wire form (`ActivePositioning`).
    pub fn to_wire(&self) -> wire::ActivePositioning {
        wire::ActivePositioning {
            enabled: self.enabled,
            theta_min_deg: self.theta_min_deg,
            theta_max_deg: self.theta_max_deg,
        }
    }
}

/// A change of the settings; `None` keeps the current value. The values are
/// checked by the coordinator, which knows the planner's hysteresis.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PositioningUpdate {
    /// Switch on or off.
    pub enabled: Option<bool>,
    /// New lower edge (degrees).
    pub theta_min_deg: Option<f64>,
    /// New upper edge (degrees).
    pub theta_max_deg: Option<f64>,
}

impl PositioningUpdate {
    /// From a `SetActivePositioningRequest`.
    pub fn from_wire(r: &wire::SetActivePositioningRequest) -> Self {
        PositioningUpdate {
            enabled: r.enabled,
            theta_min_deg: r.theta_min_deg,
            theta_max_deg: r.theta_max_deg,
        }
    }
}

/// Reads a 3×3 covariance (m², row-major) back from the wire; `None` unless it
/// has 9 values.
pub fn covariance_from_wire(c: &wire::Covariance3) -> Option<Matrix3<f64>> {
    (c.values_m2.len() == 9).then(|| Matrix3::from_fn(|r, k| c.values_m2[r * 3 + k]))
}

/// `v` when finite, else `fallback` (the wire carries no infinities).
pub fn finite_or(v: f64, fallback: f64) -> f64 {
    if v.is_finite() { v } else { fallback }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::covariance3_to_wire;

    #[test]
    fn covariance_round_trips_and_short_lists_are_refused() {
        let m = Matrix3::new(1.0, 0.1, 0.2, 0.1, 2.0, 0.3, 0.2, 0.3, 3.0);
        assert_eq!(covariance_from_wire(&covariance3_to_wire(&m)), Some(m));
        assert_eq!(covariance_from_wire(&wire::Covariance3 { values_m2: vec![1.0; 8] }), None);
    }

    #[test]
    fn planner_status_sends_non_finite_predictions_as_zero() {
        let s = PlannerStatus {
            decided: Stamp::from_ns(5),
            kind: PlanKind::Infeasible,
            key: "no_free_spot",
            detail: "d".into(),
            last_planned: None,
            commands_issued: 3,
            predicted_theta_deg: Some(f64::NAN),
            predicted_gdop: Some(1.5),
            used_fallback: true,
        };
        let w = s.to_wire();
        assert_eq!(w.outcome, wire::PlannerOutcome::Infeasible as i32);
        assert_eq!((w.decided_ns, w.last_planned_ns, w.commands_issued), (5, 0, 3));
        assert_eq!((w.predicted_theta_deg, w.predicted_gdop, w.used_fallback), (0.0, 1.5, true));
        assert_eq!(Liveness::Stale.to_wire(), wire::Liveness::Stale);
    }
}

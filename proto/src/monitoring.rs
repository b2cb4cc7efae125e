//! Domain types of the `Monitoring` service and their wire conversions: a
//! robot's liveness and state, the planner's latest decision, the operator's
//! active positioning settings, and covariances read back from the wire.
//!
//! The coordinator builds these and sends them; clients (the simulator,
//! dashboards, tests) read the wire forms back with the same functions. Wire
//! numbers that must be finite (GDOP, θ) are sent as 0 when they are not: the
//! wire has no infinities, and `trusted`/the gate tell the rest.
//!
//! Conversions of a source estimate (triangulation, filtered state) stay with
//! the coordinator, whose estimator types they read.

use nalgebra::{Isometry3, Matrix3};

use crate::geometry::pose_to_wire;
use crate::messages::{ArrayInfo, BaseLimits, CommandState, RepositionCommand};
use crate::robot_id::RobotId;
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

/// What monitoring reports of one robot.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotStatus<'a> {
    /// The robot.
    pub robot_id: &'a RobotId,
    /// Its liveness now.
    pub liveness: Liveness,
    /// Coordinator clock when last heard from.
    pub last_seen: Stamp,
    /// Stamp of its last accepted observation.
    pub last_observation: Option<Stamp>,
    /// Its base pose in the map at that observation.
    pub map_from_base: Option<Isometry3<f64>>,
    /// Its array, from its hello.
    pub array: &'a ArrayInfo,
    /// Its software version, from its hello.
    pub software_version: &'a str,
    /// Its base's limits, from its hello.
    pub base_limits: BaseLimits,
    /// Observations accepted since start.
    pub observations_accepted: u64,
    /// Observations rejected since start.
    pub observations_rejected: u64,
    /// The latest command sent to it and its last report on it (`None`: not yet acknowledged).
    pub active_command: Option<(&'a RepositionCommand, Option<CommandState>)>,
}

impl RobotStatus<'_> {
    /// The wire form (`RobotState`); absent stamps are 0.
    pub fn to_wire(&self) -> wire::RobotState {
        wire::RobotState {
            robot_id: self.robot_id.to_string(),
            liveness: self.liveness.to_wire() as i32,
            last_seen_ns: self.last_seen.as_ns(),
            last_observation_ns: self.last_observation.map_or(0, |s| s.as_ns()),
            map_from_base: self.map_from_base.as_ref().map(pose_to_wire),
            array: Some(self.array.to_wire()),
            software_version: self.software_version.into(),
            observations_accepted: self.observations_accepted,
            observations_rejected: self.observations_rejected,
            active_command: self.active_command.map(|(c, _)| c.to_wire()),
            active_command_state: self
                .active_command
                .and_then(|(_, s)| s)
                .map_or(wire::CommandState::Unspecified, |s| s.to_wire())
                as i32,
            base_limits: self.base_limits.to_wire(),
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
    fn robot_status_reports_its_command_and_the_state_of_it() {
        let id = RobotId::parse("r1", "id").unwrap();
        let array = ArrayInfo {
            base_from_array: Isometry3::translation(0.0, 0.0, 0.5),
            microphone_count: 4,
            preset: None,
            microphone_positions: vec![],
            srp_band_hz: None,
            direct_path_elevations: false,
        };
        let command = RepositionCommand {
            command_id: 7,
            goal_map_from_base: Isometry3::translation(1.0, 2.0, 0.0),
            look_at_in_map: nalgebra::Point3::origin(),
            reason: crate::messages::RepositionReason::GdopHigh,
            detail: String::new(),
            deadline: Stamp::from_ns(9),
            issued: Stamp::from_ns(3),
        };
        let mut s = RobotStatus {
            robot_id: &id,
            liveness: Liveness::Live,
            last_seen: Stamp::from_ns(8),
            last_observation: None,
            map_from_base: None,
            array: &array,
            software_version: "v",
            observations_accepted: 4,
            observations_rejected: 1,
            active_command: Some((&command, None)),
            base_limits: BaseLimits { max_speed_m_per_s: Some(0.22), max_turn_rate_deg_per_s: None },
        };
        let w = s.to_wire();
        let limits = w.base_limits.expect("declared limits are shown");
        assert_eq!((limits.max_speed_m_per_s, limits.max_turn_rate_deg_per_s), (0.22, 0.0));
        assert_eq!((w.robot_id.as_str(), w.liveness), ("r1", wire::Liveness::Live as i32));
        assert_eq!((w.last_seen_ns, w.last_observation_ns, w.map_from_base), (8, 0, None));
        assert_eq!(w.active_command.map(|c| c.command_id), Some(7));
        assert_eq!(w.active_command_state, wire::CommandState::Unspecified as i32, "not yet acknowledged");
        s.active_command = Some((&command, Some(CommandState::Executing)));
        assert_eq!(s.to_wire().active_command_state, wire::CommandState::Executing as i32);
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

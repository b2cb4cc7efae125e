//! What a planning cycle decides: goals, a hold, or an infeasibility. All are
//! values, never errors (DESIGN.md style rule 5).

use std::fmt;

use nalgebra::{Isometry3, Point2, Point3};
use soundmap_proto::{RepositionReason, RobotId};

/// A goal for one robot's base.
#[derive(Clone, Debug, PartialEq)]
pub struct Goal {
    /// Index into [`PlannerInput::robots`](super::PlannerInput::robots).
    pub robot: usize,
    /// That robot's id.
    pub robot_id: RobotId,
    /// Goal pose of the base, map frame: z = 0, level, yaw facing the source.
    pub map_from_base: Isometry3<f64>,
    /// The point the robot faces on arrival (the predicted source, map frame, m).
    pub look_at_in_map: Point3<f64>,
    /// Where the robot is ultimately heading: its spot in the target pattern
    /// (map xy, m). The goal is this spot when it is within one step, else a
    /// waypoint toward it.
    pub target_in_map: Point2<f64>,
    /// Best pairwise θ at the source once all goals of this plan are reached (degrees).
    pub predicted_theta_deg: f64,
    /// GDOP once all goals of this plan are reached.
    pub predicted_gdop: f64,
    /// √tr J⁻¹ once all goals of this plan are reached (m).
    pub predicted_rms_m: f64,
    /// Why the robot is asked to move.
    pub reason: RepositionReason,
    /// The convex problem failed and the sampling search produced this goal.
    pub used_fallback: bool,
    /// Operator-readable remark, e.g. that the ideal spot was blocked and where instead.
    pub note: Option<String>,
}

impl Goal {
    /// Adds `remark` to the goal's note, after what it already says.
    pub(crate) fn add_note(&mut self, remark: String) {
        self.note = Some(match self.note.take() {
            Some(n) => format!("{n}; {remark}"),
            None => remark,
        });
    }
}

/// Why the planner does not move anyone this cycle.
#[derive(Clone, Debug, PartialEq)]
pub enum HoldReason {
    /// Fewer than two robots.
    TooFewRobots {
        /// Robots given.
        count: usize,
    },
    /// The source estimate is too vague to plan around.
    SourceUntrusted {
        /// Its √tr P (m).
        rms_m: f64,
        /// Largest accepted (m).
        max_m: f64,
    },
    /// An input is unusable (non-finite number, duplicate id, …).
    InvalidInput {
        /// What is wrong.
        detail: String,
    },
    /// The last re-tasking is more recent than the planning period.
    NotDue {
        /// Seconds until re-tasking is allowed.
        wait_s: f64,
    },
    /// θ in band, GDOP fine, and the predicted improvement is not worth the motion.
    GeometryGood {
        /// Current best pairwise θ (degrees).
        theta_deg: f64,
        /// Current GDOP.
        gdop: f64,
        /// Predicted relative reduction of √tr J⁻¹ at the target pattern.
        improvement: f64,
    },
    /// Robots are driving to goals that are still valid for the source.
    GoalsInProgress,
    /// A re-plan was due, but every robot is already where the plan would put it.
    AtBestFeasible {
        /// Current best pairwise θ (degrees).
        theta_deg: f64,
        /// Current GDOP.
        gdop: f64,
    },
}

impl fmt::Display for HoldReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HoldReason::TooFewRobots { count } => write!(f, "{count} robot(s): at least 2 needed"),
            HoldReason::SourceUntrusted { rms_m, max_m } => {
                write!(f, "source estimate too uncertain ({rms_m:.2} m RMS > {max_m} m)")
            }
            HoldReason::InvalidInput { detail } => write!(f, "invalid input: {detail}"),
            HoldReason::NotDue { wait_s } => write!(f, "next re-tasking allowed in {wait_s:.2} s"),
            HoldReason::GeometryGood { theta_deg, gdop, improvement } => write!(
                f,
                "geometry good (θ {theta_deg:.1}°, GDOP {gdop:.2}); moving would gain {:.0} %",
                improvement * 100.0
            ),
            HoldReason::GoalsInProgress => write!(f, "robots are driving to still-valid goals"),
            HoldReason::AtBestFeasible { theta_deg, gdop } => {
                write!(f, "already at the best feasible placement (θ {theta_deg:.1}°, GDOP {gdop:.2})")
            }
        }
    }
}

/// Why no feasible placement exists.
#[derive(Clone, Debug, PartialEq)]
pub enum InfeasibleReason {
    /// No free spot in the ring [r_min, r_max] around the source at all.
    NoFreeSpotAroundSource {
        /// Source position, map xy (m).
        source_xy: [f64; 2],
        /// r_min, r_max (m).
        ring_m: [f64; 2],
    },
    /// A robot has no free, separated spot within one step that keeps the range constraints.
    RobotStuck {
        /// Robot index.
        robot: usize,
        /// Its id.
        robot_id: RobotId,
        /// What blocks it.
        detail: String,
    },
    /// Neither the convex problem nor the sampling search found goals meeting every constraint.
    NoJointPlacement {
        /// What the convex problem and the search reported.
        detail: String,
    },
}

impl fmt::Display for InfeasibleReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InfeasibleReason::NoFreeSpotAroundSource { source_xy, ring_m } => write!(
                f,
                "no free spot {:.2}–{:.2} m around the source at ({:.2}, {:.2})",
                ring_m[0], ring_m[1], source_xy[0], source_xy[1]
            ),
            InfeasibleReason::RobotStuck { robot, robot_id, detail } => {
                write!(f, "robot {robot} ({robot_id}) cannot move to a valid spot: {detail}")
            }
            InfeasibleReason::NoJointPlacement { detail } => {
                write!(f, "no placement meets all constraints: {detail}")
            }
        }
    }
}

/// Result of one planning cycle.
#[derive(Clone, Debug, PartialEq)]
pub enum PlanOutcome {
    /// Send these goals (only robots that must move get one).
    Planned(Vec<Goal>),
    /// Leave the robots as they are.
    Hold(HoldReason),
    /// Nothing feasible; the robots keep what they have.
    Infeasible(InfeasibleReason),
}

//! A navigator that drives a robot to a commanded goal pose, reporting progress
//! the way a robot answers a `RepositionCommand`.
//!
//! A new goal replaces the current one (which ends `Canceled`). The robot turns
//! toward the goal point and drives there (see [`super::steering`]), then turns
//! in place to the goal heading. It has arrived (`Succeeded`) when within
//! `position_tolerance_m` and `yaw_tolerance_rad` and nearly stopped. A goal
//! still open at its deadline ends `Failed`. Progress reports the
//! straight-line distance remaining (there are no obstacles in the simulation).

use nalgebra::Isometry3;
use soundmap_proto::CommandState;

use super::diff_drive::{DriveLimits, Pose2, Twist, wrap_angle};
use super::steering::{SteeringConfig, steer_toward, turn_toward};
use crate::error::SimError;

/// Navigator settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavigatorConfig {
    /// Arrival distance (m).
    pub position_tolerance_m: f64,
    /// Arrival heading error (rad).
    pub yaw_tolerance_rad: f64,
    /// Speeds below these count as stopped (m/s, rad/s).
    pub stopped_linear_m_per_s: f64,
    /// See `stopped_linear_m_per_s`.
    pub stopped_angular_rad_per_s: f64,
    /// Steering gains.
    pub steering: SteeringConfig,
}

impl Default for NavigatorConfig {
    /// 0.1 m, 0.05 rad (3°), stopped below 0.02 m/s and 0.05 rad/s.
    fn default() -> Self {
        NavigatorConfig {
            position_tolerance_m: 0.1,
            yaw_tolerance_rad: 0.05,
            stopped_linear_m_per_s: 0.02,
            stopped_angular_rad_per_s: 0.05,
            steering: SteeringConfig::default(),
        }
    }
}

/// A goal's progress, as reported to the coordinator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavProgress {
    /// The goal (command id).
    pub goal_id: u64,
    /// Executing, Succeeded, Failed (deadline passed) or Canceled (replaced).
    pub state: CommandState,
    /// Straight-line distance to the goal position (m).
    pub distance_remaining_m: f64,
    /// Goal heading minus current heading, wrapped (rad).
    pub yaw_error_rad: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Goal {
    id: u64,
    pose: Pose2,
    deadline_s: Option<f64>,
    /// In the final in-place turn.
    aligning: bool,
}

/// Drives to goal poses.
#[derive(Clone, Debug, PartialEq)]
pub struct Navigator {
    config: NavigatorConfig,
    goal: Option<Goal>,
    last: Option<NavProgress>,
}

impl Navigator {
    /// An idle navigator.
    pub fn new(config: NavigatorConfig) -> Self {
        Navigator { config, goal: None, last: None }
    }

    /// Accepts goal `goal_id`: reach the planar part of `goal_map_from_base`,
    /// before `deadline_s` (simulated seconds) if given. Returns the progress of
    /// the goal it replaces, now `Canceled`, if one was open. A goal that is not
    /// finite is refused (the current goal, if any, stays).
    pub fn set_goal(
        &mut self,
        goal_id: u64,
        goal_map_from_base: &Isometry3<f64>,
        deadline_s: Option<f64>,
    ) -> Result<Option<NavProgress>, SimError> {
        let pose = Pose2::from_map_from_base(goal_map_from_base);
        if ![pose.x_m, pose.y_m, pose.yaw_rad].iter().all(|v| v.is_finite()) {
            return Err(SimError::invalid("goal_map_from_base", "must be finite"));
        }
        if deadline_s.is_some_and(|t| t.is_nan()) {
            return Err(SimError::invalid("deadline_s", "must not be NaN"));
        }
        let replaced = self.cancel();
        self.goal = Some(Goal { id: goal_id, pose, deadline_s, aligning: false });
        self.last = Some(NavProgress {
            goal_id,
            state: CommandState::Executing,
            distance_remaining_m: f64::NAN,
            yaw_error_rad: f64::NAN,
        });
        Ok(replaced)
    }

    /// Cancels the open goal, if any, and returns its final progress.
    pub fn cancel(&mut self) -> Option<NavProgress> {
        let goal = self.goal.take()?;
        let mut p = self.last.filter(|p| p.goal_id == goal.id).unwrap_or(NavProgress {
            goal_id: goal.id,
            state: CommandState::Canceled,
            distance_remaining_m: f64::NAN,
            yaw_error_rad: f64::NAN,
        });
        p.state = CommandState::Canceled;
        self.last = Some(p);
        Some(p)
    }

    /// The latest progress (of the open goal, or of the last one closed).
    pub fn progress(&self) -> Option<NavProgress> {
        self.last
    }

    /// The command for a robot at `pose` moving at `twist`, at time `now_s`,
    /// and the goal's progress (`None` when no goal was ever given).
    pub fn step(
        &mut self,
        now_s: f64,
        pose: &Pose2,
        twist: &Twist,
        limits: &DriveLimits,
    ) -> (Twist, Option<NavProgress>) {
        let Some(goal) = self.goal.as_mut() else {
            return (Twist::default(), self.last);
        };
        let c = &self.config;
        let d = pose.distance_to(&goal.pose);
        let yaw_error = wrap_angle(goal.pose.yaw_rad - pose.yaw_rad);
        let mut progress = NavProgress {
            goal_id: goal.id,
            state: CommandState::Executing,
            distance_remaining_m: d,
            yaw_error_rad: yaw_error,
        };
        let stopped = twist.linear_m_per_s.abs() < c.stopped_linear_m_per_s
            && twist.angular_rad_per_s.abs() < c.stopped_angular_rad_per_s;
        if d <= c.position_tolerance_m && yaw_error.abs() <= c.yaw_tolerance_rad && stopped {
            progress.state = CommandState::Succeeded;
            self.goal = None;
            self.last = Some(progress);
            return (Twist::default(), self.last);
        }
        if goal.deadline_s.is_some_and(|t| now_s > t) {
            progress.state = CommandState::Failed;
            self.goal = None;
            self.last = Some(progress);
            return (Twist::default(), self.last);
        }
        // Hysteresis: start aligning inside the tolerance, resume driving only
        // if pushed out to twice the tolerance.
        if d <= c.position_tolerance_m {
            goal.aligning = true;
        } else if d > 2.0 * c.position_tolerance_m {
            goal.aligning = false;
        }
        let command = if goal.aligning {
            turn_toward(pose, goal.pose.yaw_rad, limits, &c.steering)
        } else {
            let cap = limits.max_speed_m_per_s;
            steer_toward(pose, goal.pose.x_m, goal.pose.y_m, cap, true, limits, &c.steering)
        };
        self.last = Some(progress);
        (command, self.last)
    }
}

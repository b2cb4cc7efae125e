//! Trajectories sampled at a fixed step, with interpolation at any time: what a
//! scenario needs to place a robot (and its array) at an audio block's time.

use nalgebra::Isometry3;

use super::diff_drive::{DiffDriveRobot, DriveLimits, Pose2, wrap_angle};
use super::waypoints::{FollowerConfig, Waypoint, WaypointFollower};
use crate::error::SimError;

/// Poses at `start_s + i·step_s`.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledTrajectory {
    start_s: f64,
    step_s: f64,
    poses: Vec<Pose2>,
}

impl SampledTrajectory {
    /// From samples (at least one) taken every `step_s` from `start_s`.
    pub fn new(start_s: f64, step_s: f64, poses: Vec<Pose2>) -> Result<Self, SimError> {
        if poses.is_empty() {
            return Err(SimError::invalid("trajectory.poses", "at least one pose is needed"));
        }
        if !(step_s.is_finite() && step_s > 0.0 && start_s.is_finite()) {
            return Err(SimError::invalid("trajectory.step_s", format!("must be > 0, got {step_s}")));
        }
        Ok(SampledTrajectory { start_s, step_s, poses })
    }

    /// Simulates a robot starting at rest at `start` (time 0) following
    /// `waypoints` for `duration_s`, integrated (and sampled) every `step_s`.
    pub fn from_waypoints(
        start: Pose2,
        waypoints: Vec<Waypoint>,
        limits: DriveLimits,
        follower: FollowerConfig,
        step_s: f64,
        duration_s: f64,
    ) -> Result<Self, SimError> {
        let mut robot = DiffDriveRobot::new(start, limits, step_s)?;
        let mut f = WaypointFollower::new(waypoints, follower);
        let n = (duration_s / step_s).ceil().max(0.0) as usize;
        let mut poses = Vec::with_capacity(n + 1);
        poses.push(robot.pose());
        for _ in 0..n {
            let (cmd, _) = f.command(robot.time_s(), &robot.pose(), &limits);
            robot.step(cmd);
            poses.push(robot.pose());
        }
        Self::new(0.0, step_s, poses)
    }

    /// The samples.
    pub fn poses(&self) -> &[Pose2] {
        &self.poses
    }

    /// Time of the first sample (s).
    pub fn start_s(&self) -> f64 {
        self.start_s
    }

    /// Time of the last sample (s).
    pub fn end_s(&self) -> f64 {
        self.start_s + (self.poses.len() - 1) as f64 * self.step_s
    }

    /// Pose at `t_s`, linearly interpolated (heading along the shorter arc);
    /// held constant outside the sampled span.
    pub fn pose_at(&self, t_s: f64) -> Pose2 {
        let u = ((t_s - self.start_s) / self.step_s).max(0.0);
        let i = (u.floor() as usize).min(self.poses.len() - 1);
        if i + 1 >= self.poses.len() {
            return self.poses[i];
        }
        let f = u - i as f64;
        let (a, b) = (self.poses[i], self.poses[i + 1]);
        Pose2 {
            x_m: a.x_m + f * (b.x_m - a.x_m),
            y_m: a.y_m + f * (b.y_m - a.y_m),
            yaw_rad: wrap_angle(a.yaw_rad + f * wrap_angle(b.yaw_rad - a.yaw_rad)),
        }
    }

    /// `map_from_base` at `t_s` (z = 0).
    pub fn map_from_base_at(&self, t_s: f64) -> Isometry3<f64> {
        self.pose_at(t_s).map_from_base()
    }
}

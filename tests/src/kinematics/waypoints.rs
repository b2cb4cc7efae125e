//! Following a list of waypoints, timed or not.
//!
//! Untimed waypoints are driven through at full speed (the last one is a stop).
//! A timed waypoint sets the speed to arrive at its time (`remaining distance /
//! remaining time`, within the limits); reached early, the robot waits there
//! until that time before going on. A waypoint counts as reached within
//! `tolerance_m`.

use super::diff_drive::{DriveLimits, Pose2, Twist};
use super::steering::{SteeringConfig, steer_toward};

/// A point to pass through.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Waypoint {
    /// Map x (m).
    pub x_m: f64,
    /// Map y (m).
    pub y_m: f64,
    /// When to be there (s of simulated time), if timed.
    pub arrival_s: Option<f64>,
}

impl Waypoint {
    /// An untimed waypoint.
    pub fn at(x_m: f64, y_m: f64) -> Self {
        Waypoint { x_m, y_m, arrival_s: None }
    }

    /// A waypoint to reach at `arrival_s`.
    pub fn timed(x_m: f64, y_m: f64, arrival_s: f64) -> Self {
        Waypoint { x_m, y_m, arrival_s: Some(arrival_s) }
    }
}

/// Waypoint following settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FollowerConfig {
    /// Distance at which a waypoint counts as reached (m).
    pub tolerance_m: f64,
    /// Steering gains.
    pub steering: SteeringConfig,
}

impl Default for FollowerConfig {
    /// 0.1 m tolerance, default steering.
    fn default() -> Self {
        FollowerConfig { tolerance_m: 0.1, steering: SteeringConfig::default() }
    }
}

/// Where the follower is in its list.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FollowStatus {
    /// Heading for waypoint `index`.
    Driving {
        /// Index of the target waypoint.
        index: usize,
        /// Straight-line distance to it (m).
        distance_m: f64,
    },
    /// Waiting at waypoint `index` for its time.
    Waiting {
        /// Index of the waypoint reached early.
        index: usize,
    },
    /// All waypoints reached.
    Done,
}

/// Drives a robot through waypoints in order.
#[derive(Clone, Debug, PartialEq)]
pub struct WaypointFollower {
    waypoints: Vec<Waypoint>,
    config: FollowerConfig,
    index: usize,
    /// Time each waypoint was reached (s).
    reached_s: Vec<f64>,
}

impl WaypointFollower {
    /// A follower for `waypoints`.
    pub fn new(waypoints: Vec<Waypoint>, config: FollowerConfig) -> Self {
        WaypointFollower { waypoints, config, index: 0, reached_s: Vec::new() }
    }

    /// The waypoints.
    pub fn waypoints(&self) -> &[Waypoint] {
        &self.waypoints
    }

    /// When each waypoint reached so far was reached (s).
    pub fn reached_s(&self) -> &[f64] {
        &self.reached_s
    }

    /// Whether every waypoint has been reached.
    pub fn is_done(&self) -> bool {
        self.index >= self.waypoints.len()
    }

    /// The command for a robot at `pose` at time `now_s`, and the status.
    pub fn command(&mut self, now_s: f64, pose: &Pose2, limits: &DriveLimits) -> (Twist, FollowStatus) {
        loop {
            let Some(wp) = self.waypoints.get(self.index).copied() else {
                return (Twist::default(), FollowStatus::Done);
            };
            let d = (wp.x_m - pose.x_m).hypot(wp.y_m - pose.y_m);
            if d <= self.config.tolerance_m {
                if self.reached_s.len() <= self.index {
                    self.reached_s.push(now_s);
                }
                if let Some(t) = wp.arrival_s
                    && now_s < t
                {
                    return (Twist::default(), FollowStatus::Waiting { index: self.index });
                }
                self.index += 1;
                continue;
            }
            let last = self.index + 1 == self.waypoints.len();
            let timed = wp.arrival_s.is_some();
            let cap = match wp.arrival_s {
                Some(t) if t > now_s => d / (t - now_s),
                _ => limits.max_speed_m_per_s,
            };
            // Timed waypoints are stops too: the robot may have to wait there.
            let twist = steer_toward(pose, wp.x_m, wp.y_m, cap, last || timed, limits, &self.config.steering);
            return (twist, FollowStatus::Driving { index: self.index, distance_m: d });
        }
    }
}

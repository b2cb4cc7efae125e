//! Turn-then-drive steering toward a point, shared by the waypoint follower and
//! the navigator.
//!
//! The heading error `e` to the target sets the turn rate `ω = k·e`. Beyond
//! `turn_in_place_above_rad` the robot only turns; below it drives at
//! `v·cos(e)`, so it curves onto the line to the target. When the target is a
//! stopping point, `v ≤ √(2·a·0.8·d)` lets the acceleration limit stop it there.

use super::diff_drive::{DriveLimits, Pose2, Twist, wrap_angle};

/// Gains of the steering law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SteeringConfig {
    /// Turn rate per radian of heading error (1/s).
    pub heading_gain_per_s: f64,
    /// Heading errors above this make the robot turn in place (rad).
    pub turn_in_place_above_rad: f64,
}

impl Default for SteeringConfig {
    /// Gain 2/s, turn in place above 0.6 rad (34°).
    fn default() -> Self {
        SteeringConfig { heading_gain_per_s: 2.0, turn_in_place_above_rad: 0.6 }
    }
}

/// The twist that takes a robot at `pose` toward `(x_m, y_m)` at no more than
/// `speed_cap_m_per_s`, slowing down to stop there when `stop_there`.
pub fn steer_toward(
    pose: &Pose2,
    x_m: f64,
    y_m: f64,
    speed_cap_m_per_s: f64,
    stop_there: bool,
    limits: &DriveLimits,
    config: &SteeringConfig,
) -> Twist {
    let (dx, dy) = (x_m - pose.x_m, y_m - pose.y_m);
    let d = dx.hypot(dy);
    let e = wrap_angle(dy.atan2(dx) - pose.yaw_rad);
    let w = (config.heading_gain_per_s * e)
        .clamp(-limits.max_turn_rate_rad_per_s, limits.max_turn_rate_rad_per_s);
    if e.abs() > config.turn_in_place_above_rad {
        return Twist::new(0.0, w);
    }
    let mut v = speed_cap_m_per_s.min(limits.max_speed_m_per_s).max(0.0);
    if stop_there {
        v = v.min((2.0 * limits.max_accel_m_per_s2 * 0.8 * d).sqrt());
    }
    Twist::new(v * e.cos().max(0.0), w)
}

/// The twist that turns a robot at `pose` in place toward heading `yaw_rad`.
pub fn turn_toward(pose: &Pose2, yaw_rad: f64, limits: &DriveLimits, config: &SteeringConfig) -> Twist {
    let e = wrap_angle(yaw_rad - pose.yaw_rad);
    // Cap the rate so that the angular deceleration limit can stop the turn on target.
    let stop_cap = (2.0 * limits.max_angular_accel_rad_per_s2 * 0.8 * e.abs()).sqrt();
    let w = (config.heading_gain_per_s * e).clamp(-stop_cap, stop_cap);
    Twist::new(0.0, w.clamp(-limits.max_turn_rate_rad_per_s, limits.max_turn_rate_rad_per_s))
}

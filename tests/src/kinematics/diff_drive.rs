//! Differential-drive (unicycle) kinematics with speed, acceleration and
//! turn-rate limits, integrated at a fixed time step.
//!
//! State: planar pose `(x, y, yaw)` of the base in the `map` frame (m, rad,
//! yaw counter-clockwise from map x) and the current twist `(v, ω)` (m/s,
//! rad/s; base x forward, z up). Ground robots stand at z = 0. A step clamps
//! the commanded twist to the limits, moves `(v, ω)` toward it no faster than
//! the accelerations allow, then integrates the arc exactly for `dt`.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use crate::error::SimError;

/// A planar pose of the base in the map frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose2 {
    /// Map x (m).
    pub x_m: f64,
    /// Map y (m).
    pub y_m: f64,
    /// Heading, counter-clockwise from map x (rad).
    pub yaw_rad: f64,
}

impl Pose2 {
    /// A pose.
    pub fn new(x_m: f64, y_m: f64, yaw_rad: f64) -> Self {
        Pose2 { x_m, y_m, yaw_rad }
    }

    /// `map_from_base` at z = 0.
    pub fn map_from_base(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.x_m, self.y_m, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.yaw_rad),
        )
    }

    /// The planar part of a 3D `map_from_base` (x, y and the heading of base x
    /// projected on the ground plane).
    pub fn from_map_from_base(map_from_base: &Isometry3<f64>) -> Self {
        let forward = map_from_base.rotation * Vector3::x();
        let t = map_from_base.translation.vector;
        Pose2 { x_m: t.x, y_m: t.y, yaw_rad: forward.y.atan2(forward.x) }
    }

    /// Distance to another pose's position (m).
    pub fn distance_to(&self, other: &Pose2) -> f64 {
        (other.x_m - self.x_m).hypot(other.y_m - self.y_m)
    }
}

/// A commanded or actual velocity of the base.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Twist {
    /// Forward speed (m/s).
    pub linear_m_per_s: f64,
    /// Turn rate, counter-clockwise (rad/s).
    pub angular_rad_per_s: f64,
}

impl Twist {
    /// A twist.
    pub fn new(linear_m_per_s: f64, angular_rad_per_s: f64) -> Self {
        Twist { linear_m_per_s, angular_rad_per_s }
    }
}

/// Motion limits. Defaults are gentler than the paper's 2 m/s maximum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveLimits {
    /// Highest forward speed (m/s).
    pub max_speed_m_per_s: f64,
    /// Highest backward speed (m/s, ≥ 0; 0 forbids reversing).
    pub max_reverse_speed_m_per_s: f64,
    /// Highest linear acceleration and deceleration (m/s²).
    pub max_accel_m_per_s2: f64,
    /// Highest turn rate (rad/s).
    pub max_turn_rate_rad_per_s: f64,
    /// Highest angular acceleration (rad/s²).
    pub max_angular_accel_rad_per_s2: f64,
}

impl Default for DriveLimits {
    /// 0.5 m/s, no reversing, 0.5 m/s², 1 rad/s, 2 rad/s².
    fn default() -> Self {
        DriveLimits {
            max_speed_m_per_s: 0.5,
            max_reverse_speed_m_per_s: 0.0,
            max_accel_m_per_s2: 0.5,
            max_turn_rate_rad_per_s: 1.0,
            max_angular_accel_rad_per_s2: 2.0,
        }
    }
}

impl DriveLimits {
    /// Checks that every limit is finite and positive (reverse speed ≥ 0).
    pub fn validate(&self) -> Result<(), SimError> {
        let positive = [
            ("limits.max_speed_m_per_s", self.max_speed_m_per_s),
            ("limits.max_accel_m_per_s2", self.max_accel_m_per_s2),
            ("limits.max_turn_rate_rad_per_s", self.max_turn_rate_rad_per_s),
            ("limits.max_angular_accel_rad_per_s2", self.max_angular_accel_rad_per_s2),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(SimError::invalid(field, format!("must be finite and > 0, got {v}")));
            }
        }
        let r = self.max_reverse_speed_m_per_s;
        if !(r.is_finite() && r >= 0.0) {
            return Err(SimError::invalid(
                "limits.max_reverse_speed_m_per_s",
                format!("must be ≥ 0, got {r}"),
            ));
        }
        Ok(())
    }
}

/// A simulated differential-drive base.
#[derive(Clone, Debug, PartialEq)]
pub struct DiffDriveRobot {
    pose: Pose2,
    twist: Twist,
    limits: DriveLimits,
    time_step_s: f64,
    time_s: f64,
}

impl DiffDriveRobot {
    /// A robot at rest at `pose`, integrated every `time_step_s` seconds.
    pub fn new(pose: Pose2, limits: DriveLimits, time_step_s: f64) -> Result<Self, SimError> {
        limits.validate()?;
        if !(time_step_s.is_finite() && time_step_s > 0.0) {
            return Err(SimError::invalid("time_step_s", format!("must be > 0, got {time_step_s}")));
        }
        if ![pose.x_m, pose.y_m, pose.yaw_rad].iter().all(|v| v.is_finite()) {
            return Err(SimError::invalid("pose", "must be finite"));
        }
        Ok(DiffDriveRobot { pose, twist: Twist::default(), limits, time_step_s, time_s: 0.0 })
    }

    /// Current pose.
    pub fn pose(&self) -> Pose2 {
        self.pose
    }

    /// Current `map_from_base` (z = 0).
    pub fn map_from_base(&self) -> Isometry3<f64> {
        self.pose.map_from_base()
    }

    /// Current twist.
    pub fn twist(&self) -> Twist {
        self.twist
    }

    /// The limits.
    pub fn limits(&self) -> &DriveLimits {
        &self.limits
    }

    /// The integration step (s).
    pub fn time_step_s(&self) -> f64 {
        self.time_step_s
    }

    /// Simulated time since creation (s).
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Advances one time step toward `command` within the limits (a command
    /// component that is not finite counts as 0).
    pub fn step(&mut self, command: Twist) {
        let l = &self.limits;
        let dt = self.time_step_s;
        let v_cmd =
            finite_or_zero(command.linear_m_per_s).clamp(-l.max_reverse_speed_m_per_s, l.max_speed_m_per_s);
        let w_cmd = finite_or_zero(command.angular_rad_per_s)
            .clamp(-l.max_turn_rate_rad_per_s, l.max_turn_rate_rad_per_s);
        let dv =
            (v_cmd - self.twist.linear_m_per_s).clamp(-l.max_accel_m_per_s2 * dt, l.max_accel_m_per_s2 * dt);
        let dw = (w_cmd - self.twist.angular_rad_per_s)
            .clamp(-l.max_angular_accel_rad_per_s2 * dt, l.max_angular_accel_rad_per_s2 * dt);
        let v = self.twist.linear_m_per_s + dv;
        let w = self.twist.angular_rad_per_s + dw;
        // Exact arc for constant (v, ω) over dt.
        let yaw0 = self.pose.yaw_rad;
        let yaw1 = yaw0 + w * dt;
        if (w * dt).abs() < 1e-9 {
            let mid = yaw0 + 0.5 * w * dt;
            self.pose.x_m += v * dt * mid.cos();
            self.pose.y_m += v * dt * mid.sin();
        } else {
            self.pose.x_m += v / w * (yaw1.sin() - yaw0.sin());
            self.pose.y_m -= v / w * (yaw1.cos() - yaw0.cos());
        }
        self.pose.yaw_rad = wrap_angle(yaw1);
        self.twist = Twist { linear_m_per_s: v, angular_rad_per_s: w };
        self.time_s += dt;
    }
}

/// `a` wrapped to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = 2.0 * std::f64::consts::PI;
    let r = (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    if r <= -std::f64::consts::PI { r + two_pi } else { r }
}

fn finite_or_zero(v: f64) -> f64 {
    if v.is_finite() { v } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_round_trips_through_isometry() {
        let p = Pose2::new(1.5, -2.0, 2.5);
        let q = Pose2::from_map_from_base(&p.map_from_base());
        assert!(
            (q.x_m - 1.5).abs() < 1e-12 && (q.y_m + 2.0).abs() < 1e-12 && (q.yaw_rad - 2.5).abs() < 1e-12
        );
    }

    #[test]
    fn constant_twist_drives_a_circle() {
        let limits =
            DriveLimits { max_accel_m_per_s2: 1e9, max_angular_accel_rad_per_s2: 1e9, ..Default::default() };
        let mut r = DiffDriveRobot::new(Pose2::default(), limits, 0.01).unwrap();
        // v = 0.5 m/s, ω = 0.5 rad/s: radius 1 m, full circle in 4π s.
        let steps = (4.0 * std::f64::consts::PI / 0.01).round() as usize;
        for _ in 0..steps {
            r.step(Twist::new(0.5, 0.5));
        }
        let p = r.pose();
        assert!(p.x_m.abs() < 0.01 && p.y_m.abs() < 0.01, "{p:?}");
    }

    #[test]
    fn wrap() {
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(-0.5) + 0.5).abs() < 1e-12);
    }
}

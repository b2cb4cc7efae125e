//! Robot poses: TUM trajectories for replay, JSON-lines feeds from a SLAM
//! bridge, and a bounded buffer that answers `map_from_base` at any stamp by
//! interpolation (linear on translation, SLERP on rotation along the shorter arc).
//!
//! - [`tum`]: `t tx ty tz qx qy qz qw` files (t in seconds), with a time mapping.
//! - [`jsonl`]: the live feed format and its TCP / standard-input readers.
//! - [`attach`]: holds DoA frames until the pose at their stamp is known.
//!
//! Frames: every pose is `map_from_base` (robot base in the shared SLAM map).

pub mod attach;
pub mod jsonl;
pub mod tum;

use std::collections::VecDeque;
use std::fmt;

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};
use soundmap_proto::Stamp;

use crate::AgentError;

pub use attach::{Attached, Attacher};
pub use jsonl::{PoseLine, parse_pose_line};
pub use tum::{PoseTimeMapping, parse_tum, read_tum};

/// Largest accepted deviation of a quaternion's norm from 1 (as in the gRPC contract);
/// quaternions within it are renormalized.
pub const QUATERNION_TOLERANCE: f64 = 1e-2;

/// A pose of the robot base in the map at one instant.
#[derive(Clone, Debug, PartialEq)]
pub struct StampedPose {
    /// When the robot was there.
    pub stamp: Stamp,
    /// Base frame in the map frame.
    pub map_from_base: Isometry3<f64>,
    /// Optional covariance over (x, y, z, rx, ry, rz), m² / m·rad / rad².
    pub covariance: Option<Matrix6<f64>>,
}

/// Builds a rotation from quaternion components (Hamilton, `w` scalar), rejecting
/// non-finite, zero and far-from-unit quaternions with a message saying why.
pub fn rotation_from_components(qx: f64, qy: f64, qz: f64, qw: f64) -> Result<UnitQuaternion<f64>, String> {
    if ![qx, qy, qz, qw].iter().all(|v| v.is_finite()) {
        return Err(format!("quaternion ({qx}, {qy}, {qz}, {qw}) (x, y, z, w) is not finite"));
    }
    let q = Quaternion::new(qw, qx, qy, qz);
    let norm = q.norm();
    if norm == 0.0 {
        return Err("zero quaternion (all components 0)".into());
    }
    if (norm - 1.0).abs() > QUATERNION_TOLERANCE {
        return Err(format!(
            "quaternion norm {norm:.6} is not 1 (accepted within {QUATERNION_TOLERANCE}): not a rotation"
        ));
    }
    Ok(UnitQuaternion::from_quaternion(q))
}

/// Builds a pose from translation (m) and quaternion components.
pub fn pose_from_components(t: [f64; 3], q: [f64; 4]) -> Result<Isometry3<f64>, String> {
    if !t.iter().all(|v| v.is_finite()) {
        return Err(format!("translation ({}, {}, {}) is not finite", t[0], t[1], t[2]));
    }
    let r = rotation_from_components(q[0], q[1], q[2], q[3])?;
    Ok(Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), r))
}

/// Limits of a [`PoseBuffer`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseBufferConfig {
    /// Most poses kept; the oldest is dropped when a new one arrives.
    pub capacity: usize,
    /// Longest interval between the two poses an interpolation uses, seconds.
    pub max_gap_s: f64,
    /// How far a stamp may lie before the first or after the last pose and still get
    /// that end pose (held, not extrapolated), seconds.
    pub extrapolation_tolerance_s: f64,
}

impl Default for PoseBufferConfig {
    /// 10 000 poses (over 3 min at 50 Hz), 0.5 s gaps, 20 ms tolerance.
    fn default() -> Self {
        PoseBufferConfig { capacity: 10_000, max_gap_s: 0.5, extrapolation_tolerance_s: 0.02 }
    }
}

impl PoseBufferConfig {
    /// Checks the limits; errors name the field (`capacity`, `max_gap_s`, `extrapolation_tolerance_s`).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if self.capacity < 2 {
            return Err((
                "capacity",
                format!("{} poses: at least 2 are needed to interpolate", self.capacity),
            ));
        }
        if !(self.max_gap_s.is_finite() && self.max_gap_s > 0.0) {
            return Err(("max_gap_s", format!("{} s: must be positive and finite", self.max_gap_s)));
        }
        if !(self.extrapolation_tolerance_s.is_finite() && self.extrapolation_tolerance_s >= 0.0) {
            return Err((
                "extrapolation_tolerance_s",
                format!("{} s: must be non-negative and finite", self.extrapolation_tolerance_s),
            ));
        }
        Ok(())
    }
}

/// Why a buffer cannot give a pose at a stamp. `AfterLast` is usually transient
/// (the pose has not arrived yet); the others are final for that stamp.
#[derive(Clone, Debug, PartialEq)]
pub enum PoseLookupError {
    /// No pose yet.
    Empty,
    /// The stamp is older than the oldest pose kept (beyond the tolerance).
    BeforeFirst {
        /// Stamp asked for.
        at: Stamp,
        /// Oldest pose kept.
        first: Stamp,
    },
    /// The stamp is newer than the newest pose (beyond the tolerance).
    AfterLast {
        /// Stamp asked for.
        at: Stamp,
        /// Newest pose.
        last: Stamp,
    },
    /// The poses around the stamp are too far apart to interpolate.
    Gap {
        /// Stamp asked for.
        at: Stamp,
        /// Pose before.
        before: Stamp,
        /// Pose after.
        after: Stamp,
    },
}

impl fmt::Display for PoseLookupError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PoseLookupError::Empty => write!(f, "no pose received yet"),
            PoseLookupError::BeforeFirst { at, first } => write!(
                f,
                "no pose at {at}: {:.3} s before the oldest pose kept ({first})",
                first.seconds_since(*at)
            ),
            PoseLookupError::AfterLast { at, last } => {
                write!(f, "no pose at {at}: {:.3} s after the newest pose ({last})", at.seconds_since(*last))
            }
            PoseLookupError::Gap { at, before, after } => write!(
                f,
                "no pose at {at}: the poses around it ({before} and {after}) are {:.3} s apart",
                after.seconds_since(*before)
            ),
        }
    }
}

/// A bounded, time-ordered buffer of poses from one source.
#[derive(Clone, Debug)]
pub struct PoseBuffer {
    source_name: String,
    config: PoseBufferConfig,
    poses: VecDeque<StampedPose>,
    dropped: u64,
}

impl PoseBuffer {
    /// An empty buffer for poses from `source_name` (used in errors).
    pub fn new(source_name: impl Into<String>, config: PoseBufferConfig) -> Result<Self, AgentError> {
        let source_name = source_name.into();
        config.validate().map_err(|(field, message)| AgentError::Pose {
            source_name: source_name.clone(),
            message: format!("{field}: {message}"),
        })?;
        Ok(PoseBuffer { source_name, config, poses: VecDeque::with_capacity(config.capacity), dropped: 0 })
    }

    /// Appends a pose, dropping the oldest when full. Stamps must strictly increase.
    pub fn push(&mut self, pose: StampedPose) -> Result<(), AgentError> {
        if let Some(last) = self.poses.back()
            && pose.stamp <= last.stamp
        {
            return Err(AgentError::Pose {
                source_name: self.source_name.clone(),
                message: format!(
                    "time does not increase: pose at {} after a pose at {}",
                    pose.stamp, last.stamp
                ),
            });
        }
        if self.poses.len() == self.config.capacity {
            self.poses.pop_front();
            self.dropped += 1;
        }
        self.poses.push_back(pose);
        Ok(())
    }

    /// The pose at `at`: interpolated between the poses around it, or the end pose
    /// when `at` is within the extrapolation tolerance outside the buffer.
    pub fn lookup(&self, at: Stamp) -> Result<StampedPose, PoseLookupError> {
        let (first, last) = match (self.poses.front(), self.poses.back()) {
            (Some(f), Some(l)) => (f, l),
            _ => return Err(PoseLookupError::Empty),
        };
        let tol_ns = (self.config.extrapolation_tolerance_s * 1e9).round() as i64;
        if at <= first.stamp {
            return if first.stamp - at <= tol_ns {
                Ok(StampedPose { stamp: at, ..first.clone() })
            } else {
                Err(PoseLookupError::BeforeFirst { at, first: first.stamp })
            };
        }
        if at >= last.stamp {
            return if at - last.stamp <= tol_ns {
                Ok(StampedPose { stamp: at, ..last.clone() })
            } else {
                Err(PoseLookupError::AfterLast { at, last: last.stamp })
            };
        }
        // first.stamp < at < last.stamp: index of the first pose after `at`.
        let k = self.poses.partition_point(|p| p.stamp <= at);
        let (a, b) = (&self.poses[k - 1], &self.poses[k]);
        if b.stamp.seconds_since(a.stamp) > self.config.max_gap_s {
            return Err(PoseLookupError::Gap { at, before: a.stamp, after: b.stamp });
        }
        Ok(interpolate(a, b, at))
    }

    /// [`lookup`](Self::lookup) with the failure as an [`AgentError::Pose`] naming the source.
    pub fn map_from_base(&self, at: Stamp) -> Result<Isometry3<f64>, AgentError> {
        self.lookup(at)
            .map(|p| p.map_from_base)
            .map_err(|e| AgentError::Pose { source_name: self.source_name.clone(), message: e.to_string() })
    }

    /// The source name used in errors.
    pub fn source_name(&self) -> &str {
        &self.source_name
    }

    /// Number of poses held.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when no pose is held.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The newest pose.
    pub fn last(&self) -> Option<&StampedPose> {
        self.poses.back()
    }

    /// Poses dropped because the buffer was full.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// The pose at `at` between `a` and `b` (`a.stamp < b.stamp`): translation and
/// covariance linear, rotation SLERP along the shorter arc.
pub fn interpolate(a: &StampedPose, b: &StampedPose, at: Stamp) -> StampedPose {
    let span = (b.stamp - a.stamp) as f64;
    let t = if span > 0.0 { ((at - a.stamp) as f64 / span).clamp(0.0, 1.0) } else { 0.0 };
    let ta = a.map_from_base.translation.vector;
    let tb = b.map_from_base.translation.vector;
    let ra = a.map_from_base.rotation;
    let mut rb = b.map_from_base.rotation;
    if ra.coords.dot(&rb.coords) < 0.0 {
        rb = UnitQuaternion::new_unchecked(-rb.into_inner());
    }
    // Nearly equal rotations make SLERP ill-conditioned; normalized lerp is exact enough there.
    let r = ra.try_slerp(&rb, t, 1e-9).unwrap_or_else(|| ra.nlerp(&rb, t));
    let covariance = match (&a.covariance, &b.covariance) {
        (Some(ca), Some(cb)) => Some(ca * (1.0 - t) + cb * t),
        (Some(c), None) | (None, Some(c)) => Some(*c),
        (None, None) => None,
    };
    StampedPose {
        stamp: at,
        map_from_base: Isometry3::from_parts(Translation3::from(ta + (tb - ta) * t), r),
        covariance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn pose(ns: i64, x: f64, yaw: f64) -> StampedPose {
        StampedPose {
            stamp: Stamp::from_ns(ns),
            map_from_base: Isometry3::new(Vector3::new(x, 0.0, 0.0), Vector3::new(0.0, 0.0, yaw)),
            covariance: None,
        }
    }

    #[test]
    fn slerp_takes_the_shorter_arc() {
        // Yaw 170° to −170°: the short way goes through 180°, not through 0°.
        let a = pose(0, 0.0, 170f64.to_radians());
        let mut b = pose(1_000, 2.0, (-170f64).to_radians());
        // Same rotation written with the opposite quaternion sign.
        b.map_from_base.rotation = UnitQuaternion::new_unchecked(-b.map_from_base.rotation.into_inner());
        let m = interpolate(&a, &b, Stamp::from_ns(500));
        assert!((m.map_from_base.translation.vector.x - 1.0).abs() < 1e-12);
        let yaw = m.map_from_base.rotation.euler_angles().2;
        assert!((yaw.abs() - std::f64::consts::PI).abs() < 1e-9, "yaw {yaw}");
    }

    #[test]
    fn bad_quaternions_are_rejected() {
        assert!(rotation_from_components(0.0, 0.0, 0.0, 0.0).unwrap_err().contains("zero"));
        assert!(rotation_from_components(0.0, 0.0, f64::NAN, 1.0).unwrap_err().contains("not finite"));
        assert!(rotation_from_components(0.0, 0.0, 0.0, 2.0).unwrap_err().contains("norm 2.0"));
        assert!(rotation_from_components(0.0, 0.0, 0.0, 1.005).is_ok());
    }
}

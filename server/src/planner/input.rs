//! What the planner is given each cycle: the source estimate and the robots.

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Vector3};
use soundmap_proto::{BaseLimits, RobotId};

/// The tracked source, map frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceEstimate {
    /// Estimated position (m).
    pub position_in_map: Point3<f64>,
    /// Position covariance (m²).
    pub covariance_m2: Matrix3<f64>,
    /// Estimated velocity (m/s), when tracked.
    pub velocity_in_map: Option<Vector3<f64>>,
    /// The newest instantaneous triangulation of the robots' rays (m), when
    /// the estimate is a filter's and the triangulation was accepted: the
    /// keep-out covers the way from the estimate to it as well, because a
    /// filter following a walker lags behind it (`cycle::KeepOut`).
    pub fix_in_map: Option<Point3<f64>>,
}

impl SourceEstimate {
    /// A source with an isotropic position σ (m) and no velocity.
    pub fn at(position_in_map: Point3<f64>, sigma_m: f64) -> Self {
        SourceEstimate {
            position_in_map,
            covariance_m2: Matrix3::identity() * sigma_m * sigma_m,
            velocity_in_map: None,
            fix_in_map: None,
        }
    }

    /// Where the source is predicted `lead_s` ahead with its velocity (m;
    /// where it is, without one).
    pub fn predicted(&self, lead_s: f64) -> Point3<f64> {
        self.position_in_map + self.velocity_in_map.unwrap_or_default() * lead_s
    }

    /// √tr P (m): RMS 3D position uncertainty.
    pub fn rms_m(&self) -> f64 {
        self.covariance_m2.trace().max(0.0).sqrt()
    }
}

/// One robot as the planner sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotState {
    /// Identity (goals are matched to robots across cycles by id).
    pub id: RobotId,
    /// Current pose of the base, map frame.
    pub map_from_base: Isometry3<f64>,
    /// Pose of the microphone array on the base (configuration).
    pub base_from_array: Isometry3<f64>,
    /// 1-σ angular noise of its DoAs per tangent axis (rad).
    pub sigma_rad: f64,
    /// The goal it is driving to, when busy with a previous command.
    pub active_goal: Option<Isometry3<f64>>,
    /// Its base's speed and turn rate as its hello declared them (the
    /// `[planner]` settings stand in for what it did not declare).
    pub base: BaseLimits,
}

impl RobotState {
    /// Base position in the map's xy plane (m).
    pub fn base_xy(&self) -> Point2<f64> {
        let t = self.map_from_base.translation.vector;
        Point2::new(t.x, t.y)
    }

    /// Where the robot ends up without a new goal (map xy, m): its active
    /// goal, else where it is.
    pub fn destination_xy(&self) -> Point2<f64> {
        self.active_goal.map_or_else(|| self.base_xy(), |g| super::xy_of(&g))
    }

    /// Array centre in the map frame at the current pose (m).
    pub fn array_in_map(&self) -> Point3<f64> {
        (self.map_from_base * self.base_from_array) * Point3::origin()
    }

    /// Whether every number is finite and σ is positive.
    pub(crate) fn is_valid(&self) -> bool {
        let iso_ok = |i: &Isometry3<f64>| {
            i.translation.vector.iter().all(|v| v.is_finite())
                && i.rotation.coords.iter().all(|v| v.is_finite())
        };
        iso_ok(&self.map_from_base)
            && iso_ok(&self.base_from_array)
            && self.active_goal.as_ref().is_none_or(iso_ok)
            && self.sigma_rad.is_finite()
            && self.sigma_rad > 0.0
    }
}

/// Everything one planning cycle needs besides the configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannerInput {
    /// The source to localize.
    pub source: SourceEstimate,
    /// The robots; [`Goal::robot`](super::Goal::robot) indexes this list.
    pub robots: Vec<RobotState>,
    /// Other known sources (the sound map's other confirmed sources): no goal
    /// is planned for them, but every goal keeps out of their keep-outs as it
    /// does of `source`'s, and a robot inside one backs out (`planner::escape`).
    pub others: Vec<SourceEstimate>,
}

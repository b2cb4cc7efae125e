//! What the coordinator publishes about a source.

use nalgebra::{Matrix3, Point3};
use soundmap_proto::{RobotId, Stamp};

use crate::triangulation::{Gate, Triangulation};

/// One published estimate of a source.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// Coordinator-wide source id.
    pub source_id: u64,
    /// Stamp of the newest observation used.
    pub stamp: Stamp,
    /// Robots whose rays were combined, in ray order.
    pub robots: Vec<RobotId>,
    /// The instantaneous triangulation of those rays.
    pub triangulation: Triangulation,
}

impl Estimate {
    /// Best position, if any (map frame, m).
    pub fn position(&self) -> Option<Point3<f64>> {
        self.triangulation.solution().map(|s| s.point)
    }

    /// Covariance of [`Estimate::position`] (m²).
    pub fn covariance(&self) -> Option<Matrix3<f64>> {
        self.triangulation.solution().and_then(|s| s.quality.covariance)
    }

    /// Whether the estimate passed its gate.
    pub fn trusted(&self) -> bool {
        matches!(self.triangulation.solution(), Some(s) if s.gate == Gate::Accepted)
    }

    /// GDOP (infinite when not available).
    pub fn gdop(&self) -> f64 {
        self.triangulation.solution().map_or(f64::INFINITY, |s| s.quality.gdop)
    }

    /// θ at the source (degrees): from the estimate, or between the ray
    /// directions when the rays give no point.
    pub fn theta_deg(&self) -> f64 {
        match &self.triangulation {
            Triangulation::Solved(s) => s.quality.theta_deg,
            Triangulation::Degenerate(d) => match d {
                crate::triangulation::Degeneracy::NearParallel { ray_angle_deg }
                | crate::triangulation::Degeneracy::BehindArray { ray_angle_deg, .. } => *ray_angle_deg,
                crate::triangulation::Degeneracy::TooFewRays { .. } => 0.0,
            },
        }
    }
}

//! Bearing rays in the map frame, built from a robot's DoA and its pose.

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Unit, Vector3};

use crate::floor_image::FloorFold;

/// Shortest range used when a weight needs a range (m). Closer than this,
/// the far-field DoA model does not hold anyway (theory §1.3).
pub const MIN_RANGE_M: f64 = 0.3;

/// A bearing from a microphone array, in the map frame.
///
/// The ray starts at the array's acoustic centre (`map_from_base *
/// base_from_array * 0`), not at the robot base: an ignored array height is
/// an elevation bias (theory §1.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Array centre in the map frame (m).
    pub origin_in_map: Point3<f64>,
    /// Unit direction toward the source, map frame.
    pub direction_in_map: Unit<Vector3<f64>>,
    /// 1-σ angular noise per tangent axis (rad): the DoA's own uncertainty
    /// combined with the pose's rotation uncertainty.
    pub sigma_rad: f64,
    /// 1-σ lateral uncertainty of the origin (m), from the pose's position covariance.
    pub origin_sigma_m: f64,
    /// What a planar array on a ground robot measures instead of the direct
    /// direction (folded elevation, pulled toward the floor image), when known:
    /// the tracker's measurement model then uses it (see [`crate::floor_image`]).
    pub fold: Option<FloorFold>,
}

impl Ray {
    /// A ray from a DoA in the array frame.
    ///
    /// `doa_sigma_rad` is the DoA's 1-σ per tangent axis. The pose covariance,
    /// when given (6×6 over x, y, z, rx, ry, rz in the map frame), adds its
    /// rotation part projected on the ray's tangent plane to the angular
    /// variance and its position part to the origin's lateral variance
    /// (theory §1.7: σ_eff² = σ_DoA² + σ_rot² + (σ_pos,⊥/r)²).
    pub fn from_doa(
        map_from_base: &Isometry3<f64>,
        base_from_array: &Isometry3<f64>,
        doa_in_array: &Unit<Vector3<f64>>,
        doa_sigma_rad: f64,
        pose_covariance: Option<&Matrix6<f64>>,
    ) -> Ray {
        let map_from_array = map_from_base * base_from_array;
        let origin_in_map = map_from_array * Point3::origin();
        let direction_in_map = Unit::new_normalize(map_from_array * doa_in_array.into_inner());
        let (mut var_ang, mut var_pos) = (doa_sigma_rad * doa_sigma_rad, 0.0);
        if let Some(c) = pose_covariance {
            let (b1, b2) = tangent_basis(&direction_in_map);
            let pos: Matrix3<f64> = c.fixed_view::<3, 3>(0, 0).into();
            let rot: Matrix3<f64> = c.fixed_view::<3, 3>(3, 3).into();
            // A small rotation δφ moves the direction by δφ × d; on the tangent axes
            // b_k that is b_kᵀ[−d]ₓδφ = (d × b_k)ᵀ δφ.
            let a1 = direction_in_map.cross(&b1);
            let a2 = direction_in_map.cross(&b2);
            var_ang += 0.5 * ((a1.transpose() * rot * a1)[0] + (a2.transpose() * rot * a2)[0]);
            var_pos += 0.5 * ((b1.transpose() * pos * b1)[0] + (b2.transpose() * pos * b2)[0]);
        }
        Ray {
            origin_in_map,
            direction_in_map,
            sigma_rad: var_ang.max(0.0).sqrt(),
            origin_sigma_m: var_pos.max(0.0).sqrt(),
            fold: None,
        }
    }

    /// Lateral variance at range `range_m` (m²): σ²r² + σ_origin².
    pub fn lateral_variance(&self, range_m: f64) -> f64 {
        let r = range_m.max(MIN_RANGE_M);
        self.sigma_rad * self.sigma_rad * r * r + self.origin_sigma_m * self.origin_sigma_m
    }

    /// Effective angular variance at range `range_m` (rad²): σ² + (σ_origin/r)².
    pub fn angular_variance(&self, range_m: f64) -> f64 {
        self.lateral_variance(range_m) / range_m.max(MIN_RANGE_M).powi(2)
    }

    /// Signed distance along the ray to the foot of the perpendicular from `p` (m).
    pub fn along(&self, p: &Point3<f64>) -> f64 {
        self.direction_in_map.dot(&(p - self.origin_in_map))
    }

    /// Distance from `p` to the ray's line (m).
    pub fn distance_to(&self, p: &Point3<f64>) -> f64 {
        let v = p - self.origin_in_map;
        (v - self.direction_in_map.into_inner() * self.direction_in_map.dot(&v)).norm()
    }

    /// The point at distance `s` along the ray.
    pub fn at(&self, s: f64) -> Point3<f64> {
        self.origin_in_map + self.direction_in_map.into_inner() * s
    }
}

/// An orthonormal basis (b₁, b₂) of the plane perpendicular to `d`, built as
/// in theory §1.5: b₁ = normalize(d × t) with t = e_x if |d_x| < 0.9 else e_y, b₂ = d × b₁.
pub fn tangent_basis(d: &Unit<Vector3<f64>>) -> (Vector3<f64>, Vector3<f64>) {
    let t = if d.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let b1 = d.cross(&t).normalize();
    let b2 = d.cross(&b1);
    (b1, b2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origin_is_array_centre_and_direction_rotates() {
        let map_from_base =
            Isometry3::new(Vector3::new(2.0, 1.0, 0.0), Vector3::z() * std::f64::consts::FRAC_PI_2);
        let base_from_array = Isometry3::translation(0.1, 0.0, 0.48);
        let doa = Unit::new_normalize(Vector3::x());
        let r = Ray::from_doa(&map_from_base, &base_from_array, &doa, 0.05, None);
        assert!((r.origin_in_map - Point3::new(2.0, 1.1, 0.48)).norm() < 1e-12);
        assert!((r.direction_in_map.into_inner() - Vector3::y()).norm() < 1e-12);
        assert_eq!(r.sigma_rad, 0.05);
        assert_eq!(r.origin_sigma_m, 0.0);
    }

    #[test]
    fn yaw_variance_projects_onto_horizontal_rays_only() {
        let mut c = Matrix6::zeros();
        c[(5, 5)] = 0.02f64.powi(2); // yaw σ 0.02 rad
        let id = Isometry3::identity();
        let horizontal = Ray::from_doa(&id, &id, &Unit::new_normalize(Vector3::x()), 0.0, Some(&c));
        // Yaw moves a horizontal ray along one of its two tangent axes: per-axis mean σ² = 0.02²/2.
        assert!((horizontal.sigma_rad - 0.02 / 2f64.sqrt()).abs() < 1e-12);
        let vertical = Ray::from_doa(&id, &id, &Unit::new_normalize(Vector3::z()), 0.0, Some(&c));
        assert!(vertical.sigma_rad < 1e-12);
    }

    #[test]
    fn basis_is_orthonormal() {
        for d in [Vector3::x(), Vector3::y(), Vector3::new(0.3, -0.2, 0.9), -Vector3::z()] {
            let d = Unit::new_normalize(d);
            let (b1, b2) = tangent_basis(&d);
            assert!(b1.dot(&d).abs() < 1e-12 && b2.dot(&d).abs() < 1e-12 && b1.dot(&b2).abs() < 1e-12);
            assert!((b1.norm() - 1.0).abs() < 1e-12 && (b2.norm() - 1.0).abs() < 1e-12);
        }
    }
}

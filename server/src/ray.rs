//! Bearing rays in the map frame, built from a robot's DoA and its pose.

use nalgebra::{Isometry3, Matrix2, Matrix3, Matrix3x2, Matrix6, Point3, Unit, Vector2, Vector3};

use crate::floor_image::FloorFold;
use crate::uncertainty::{AsSensor, Sensor};

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

    /// The vertical tangent of the ray's direction (unit, ⊥ the direction, in
    /// its vertical plane) and the angular variance its DoA has along it on
    /// top of [`Ray::angular_variance`] (rad²), for a ray whose array resolves
    /// elevation worse than azimuth ([`FloorFold::vertical_spread`]); `None`
    /// otherwise, or for a ray pointing straight up or down.
    ///
    /// A DoA's information along a tangent t is ∝ tᵀCt, C the covariance of
    /// the microphones' positions (the Cramér–Rao bound of delay-based
    /// direction finding). Along the horizontal tangent that is the array's
    /// horizontal spread; along the vertical one, sin²e of it plus cos²e of
    /// its vertical spread, e the elevation above the array's plane. With
    /// the reported σ taken as the horizontal axis's, the vertical axis's is
    /// σ_v² = σ² / (sin²e + ρ·cos²e + 1.25·σ), ρ the vertical-to-horizontal
    /// spread. The last term is the second-order limit on the plane itself,
    /// where a planar array reads e = √(2|n|) from a horizontal error n:
    /// E\[e²\] = 0.8·σ. The same sensitivity scales the reflections' pull: an
    /// image that moves the horizontal component by δ moves the elevation by
    /// δ / sin e (see [`crate::floor_image`], "Elevation is resolved worse
    /// than azimuth", for numbers).
    pub fn vertical_excess(&self) -> Option<(Vector3<f64>, f64)> {
        let rho = self.fold?.vertical_spread?;
        let d = self.direction_in_map;
        let h = Vector3::z().cross(&d);
        let n = h.norm();
        if !(n > 1e-9) {
            return None;
        }
        let v = d.cross(&(h / n));
        let sin2 = d.z * d.z;
        let sigma = self.sigma_rad;
        let info = sin2 + rho.max(0.0) * (1.0 - sin2) + 1.25 * sigma;
        let excess = sigma * sigma * (1.0 / info - 1.0).max(0.0);
        (excess.is_finite() && excess > 0.0).then_some((v, excess))
    }

    /// Angular noise covariance (rad²) of the DoA at range `range_m` on the
    /// tangent axes `basis` (two orthonormal columns ⊥ a direction near the
    /// ray's): [`Ray::angular_variance`] on both, plus the vertical excess
    /// ([`Ray::vertical_excess`]) along the vertical tangent's projection.
    pub fn angular_covariance(&self, basis: &Matrix3x2<f64>, range_m: f64) -> Matrix2<f64> {
        self.covariance_with(self.vertical_excess(), basis, range_m)
    }

    /// The information matrix R⁻¹ (rad⁻²) of [`Ray::angular_covariance`] on
    /// `basis`: I / [`Ray::angular_variance`] without a vertical excess (or
    /// when R cannot be inverted).
    pub fn angular_information(&self, basis: &Matrix3x2<f64>, range_m: f64) -> Matrix2<f64> {
        self.information_with(self.vertical_excess(), basis, range_m)
    }

    /// Fisher information (m⁻²) the ray's DoA carries about a source at `x`:
    /// (I − uuᵀ)/(σ²r² + σ_origin²) with u toward `x`, or with the vertical
    /// excess, B R⁻¹ Bᵀ / r² with B the tangent basis at u and R⁻¹
    /// [`Ray::angular_information`].
    pub fn fisher_at(&self, x: &Point3<f64>) -> Matrix3<f64> {
        let Some(excess) = self.vertical_excess() else {
            return Sensor::from(self).fisher_at(x);
        };
        let v = x - self.origin_in_map;
        let r = v.norm().max(MIN_RANGE_M);
        let (b1, b2) = tangent_basis(&Unit::new_unchecked(v / r));
        let basis = Matrix3x2::from_columns(&[b1, b2]);
        basis * self.information_with(Some(excess), &basis, r) * basis.transpose() / (r * r)
    }

    /// [`Ray::angular_covariance`] with the vertical excess already known.
    fn covariance_with(
        &self,
        excess: Option<(Vector3<f64>, f64)>,
        basis: &Matrix3x2<f64>,
        range_m: f64,
    ) -> Matrix2<f64> {
        let iso = Matrix2::identity() * self.angular_variance(range_m);
        match excess {
            Some((v, excess)) => {
                let p: Vector2<f64> = basis.transpose() * v;
                iso + p * p.transpose() * excess
            }
            None => iso,
        }
    }

    /// [`Ray::angular_information`] with the vertical excess already known.
    fn information_with(
        &self,
        excess: Option<(Vector3<f64>, f64)>,
        basis: &Matrix3x2<f64>,
        range_m: f64,
    ) -> Matrix2<f64> {
        let iso = || Matrix2::identity() / self.angular_variance(range_m);
        match excess {
            Some(_) => self.covariance_with(excess, basis, range_m).try_inverse().unwrap_or_else(iso),
            None => iso(),
        }
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

    /// A level planar array's DoA at elevation `e_deg`, σ 1°, vertical spread `rho`.
    fn planar(e_deg: f64, rho: Option<f64>) -> Ray {
        let (s, c) = e_deg.to_radians().sin_cos();
        let fold = crate::floor_image::three_mic_fold(0.6, rho);
        Ray {
            origin_in_map: Point3::new(0.0, 0.0, 0.5),
            direction_in_map: Unit::new_normalize(Vector3::new(c * 0.6, c * 0.8, s)),
            sigma_rad: 1f64.to_radians(),
            origin_sigma_m: 0.0,
            fold: Some(fold),
        }
    }

    #[test]
    fn a_planar_arrays_elevation_is_noisier_near_its_plane() {
        let sigma = 1f64.to_radians();
        // On the plane of a flat array: the second-order limit, E[e²] = 0.8σ.
        let (v, excess) = planar(0.0, Some(0.0)).vertical_excess().unwrap();
        assert!(v.z > 0.999, "{v}");
        assert!((sigma * sigma + excess - 0.8 * sigma).abs() < 1e-9 * sigma);
        // 20° up with the 16SoundsUSB's spread: σ_v ≈ 2.65°.
        let (v, excess) = planar(20.0, Some(0.003568)).vertical_excess().unwrap();
        assert!(v.dot(&planar(20.0, None).direction_in_map).abs() < 1e-12);
        assert!(((sigma * sigma + excess).sqrt().to_degrees() - 2.654).abs() < 0.01);
        // Nothing extra without the model, straight up, or for an array as tall as wide.
        assert!(planar(20.0, None).vertical_excess().is_none());
        assert!(planar(90.0, Some(0.0)).vertical_excess().is_none());
        assert!(planar(20.0, Some(1.0)).vertical_excess().is_none());
        // The covariance on any tangent basis carries the excess along the vertical only.
        let ray = planar(10.0, Some(0.0));
        let (b1, b2) = tangent_basis(&ray.direction_in_map);
        let basis = Matrix3x2::from_columns(&[b1, b2]);
        let cov = ray.angular_covariance(&basis, 3.0);
        let (v, excess) = ray.vertical_excess().unwrap();
        let h = ray.direction_in_map.cross(&v);
        let along = |t: Vector3<f64>| {
            let p = basis.transpose() * t;
            (p.transpose() * cov * p)[0]
        };
        assert!((along(h) - sigma * sigma).abs() < 1e-12);
        assert!((along(v) - sigma * sigma - excess).abs() < 1e-12);
        // And the Fisher information has less of it along the vertical tangent.
        let x = ray.at(3.0);
        let j = ray.fisher_at(&x);
        assert!((h.transpose() * j * h)[0] > 10.0 * (v.transpose() * j * v)[0]);
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

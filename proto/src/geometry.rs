//! Checked conversions of geometric wire types into nalgebra types.

use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3,
};

use crate::error::{Problem, ValidationError};
use crate::stamp::Stamp;
use crate::wire;

/// Tolerances and clock used when validating incoming messages.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// The receiver's clock; stamps further than `max_future_ns` ahead of it are rejected.
    pub now: Stamp,
    /// Largest accepted lead of a stamp over `now`, nanoseconds.
    pub max_future_ns: i64,
    /// Largest accepted age of a stamp behind `now`, nanoseconds.
    pub max_past_ns: i64,
    /// Accepted deviation of a direction's norm from 1 (directions within it are renormalized).
    pub unit_vector_tolerance: f64,
    /// Accepted deviation of a quaternion's norm from 1 (quaternions within it are renormalized).
    pub quaternion_tolerance: f64,
}

impl Limits {
    /// Default tolerances: 1e-3 on directions, 1e-2 on quaternions, stamps up
    /// to 1 s ahead and of any age (the coordinator sets its own horizon).
    pub fn at(now: Stamp) -> Self {
        Limits {
            now,
            max_future_ns: 1_000_000_000,
            max_past_ns: i64::MAX,
            unit_vector_tolerance: 1e-3,
            quaternion_tolerance: 1e-2,
        }
    }

    /// Checks a Unix-nanosecond stamp: not negative, not too far ahead of
    /// `now`, not older than `max_past_ns` behind it.
    pub fn stamp(&self, ns: i64, field: &str) -> Result<Stamp, ValidationError> {
        if ns < 0 {
            return Err(ValidationError::new(field, Problem::NegativeStamp(ns)));
        }
        let ahead = ns.saturating_sub(self.now.as_ns());
        if ahead > self.max_future_ns {
            return Err(ValidationError::new(
                field,
                Problem::InFuture {
                    stamp_ns: ns,
                    ahead_ms: ahead as f64 * 1e-6,
                    max_ms: (self.max_future_ns / 1_000_000) as u64,
                },
            ));
        }
        let behind = self.now.as_ns().saturating_sub(ns);
        if behind > self.max_past_ns {
            return Err(ValidationError::new(
                field,
                Problem::TooOld {
                    stamp_ns: ns,
                    behind_ms: behind as f64 * 1e-6,
                    max_ms: (self.max_past_ns / 1_000_000) as u64,
                },
            ));
        }
        Ok(Stamp::from_ns(ns))
    }
}

/// The aperture of a microphone array: the largest distance between two of
/// `positions` (m; 0 with fewer than two).
pub fn aperture_m(positions: &[Point3<f64>]) -> f64 {
    positions
        .iter()
        .enumerate()
        .flat_map(|(i, a)| positions[i + 1..].iter().map(move |b| (a - b).norm()))
        .fold(0.0, f64::max)
}

/// Checks that `v` is finite; errors name `field`.
pub fn finite(v: f64, field: &str) -> Result<f64, ValidationError> {
    if v.is_finite() { Ok(v) } else { Err(ValidationError::new(field, Problem::NonFinite(v))) }
}

fn present<'a, T>(v: &'a Option<T>, field: &str) -> Result<&'a T, ValidationError> {
    v.as_ref().ok_or_else(|| ValidationError::new(field, Problem::Missing))
}

/// A required finite 3-vector.
pub fn vector_from_wire(v: &Option<wire::Vec3>, field: &str) -> Result<Vector3<f64>, ValidationError> {
    let v = present(v, field)?;
    Ok(Vector3::new(
        finite(v.x, &format!("{field}.x"))?,
        finite(v.y, &format!("{field}.y"))?,
        finite(v.z, &format!("{field}.z"))?,
    ))
}

/// A required finite point.
pub fn point_from_wire(v: &Option<wire::Vec3>, field: &str) -> Result<Point3<f64>, ValidationError> {
    vector_from_wire(v, field).map(Point3::from)
}

/// A required unit direction, renormalized when within `limits.unit_vector_tolerance` of unit norm.
pub fn direction_from_wire(
    v: &Option<wire::Vec3>,
    field: &str,
    limits: &Limits,
) -> Result<Unit<Vector3<f64>>, ValidationError> {
    let v = vector_from_wire(v, field)?;
    let norm = v.norm();
    if (norm - 1.0).abs() > limits.unit_vector_tolerance {
        return Err(ValidationError::new(
            field,
            Problem::NotUnitVector { norm, tolerance: limits.unit_vector_tolerance },
        ));
    }
    Ok(Unit::new_normalize(v))
}

/// A required rotation, renormalized when within `limits.quaternion_tolerance` of unit norm.
pub fn rotation_from_wire(
    q: &Option<wire::Quaternion>,
    field: &str,
    limits: &Limits,
) -> Result<UnitQuaternion<f64>, ValidationError> {
    let q = present(q, field)?;
    let w = finite(q.w, &format!("{field}.w"))?;
    let x = finite(q.x, &format!("{field}.x"))?;
    let y = finite(q.y, &format!("{field}.y"))?;
    let z = finite(q.z, &format!("{field}.z"))?;
    let quat = Quaternion::new(w, x, y, z);
    let norm = quat.norm();
    if norm == 0.0 {
        return Err(ValidationError::new(field, Problem::ZeroQuaternion));
    }
    if (norm - 1.0).abs() > limits.quaternion_tolerance {
        return Err(ValidationError::new(
            field,
            Problem::NotUnitQuaternion { norm, tolerance: limits.quaternion_tolerance },
        ));
    }
    Ok(UnitQuaternion::from_quaternion(quat))
}

/// A required rigid transform.
pub fn pose_from_wire(
    p: &Option<wire::Pose>,
    field: &str,
    limits: &Limits,
) -> Result<Isometry3<f64>, ValidationError> {
    let p = present(p, field)?;
    let t = vector_from_wire(&p.translation_m, &format!("{field}.translation_m"))?;
    let r = rotation_from_wire(&p.rotation, &format!("{field}.rotation"), limits)?;
    Ok(Isometry3::from_parts(Translation3::from(t), r))
}

/// An optional 6×6 pose covariance: absent or empty gives `None`.
pub fn pose_covariance_from_wire(
    c: &Option<wire::PoseCovariance>,
    field: &str,
) -> Result<Option<Matrix6<f64>>, ValidationError> {
    let Some(c) = c else { return Ok(None) };
    if c.values.is_empty() {
        return Ok(None);
    }
    let m = square_from_values::<6>(&c.values, &format!("{field}.values"))?;
    Ok(Some(Matrix6::from_fn(|r, col| m[r][col])))
}

/// An optional 3×3 covariance.
pub fn covariance3_from_wire(
    c: &Option<wire::Covariance3>,
    field: &str,
) -> Result<Option<Matrix3<f64>>, ValidationError> {
    let Some(c) = c else { return Ok(None) };
    if c.values_m2.is_empty() {
        return Ok(None);
    }
    let m = square_from_values::<3>(&c.values_m2, &format!("{field}.values_m2"))?;
    Ok(Some(Matrix3::from_fn(|r, col| m[r][col])))
}

fn square_from_values<const N: usize>(values: &[f64], field: &str) -> Result<[[f64; N]; N], ValidationError> {
    if values.len() != N * N {
        return Err(ValidationError::new(field, Problem::WrongLength { expected: N * N, got: values.len() }));
    }
    let mut m = [[0.0; N]; N];
    for r in 0..N {
        for c in 0..N {
            m[r][c] = finite(values[r * N + c], &format!("{field}[{}]", r * N + c))?;
        }
    }
    for r in 0..N {
        if m[r][r] < 0.0 {
            return Err(ValidationError::new(
                format!("{field}[{}]", r * N + r),
                Problem::OutOfRange { value: m[r][r], range: "[0, ∞) (a variance)" },
            ));
        }
        for c in (r + 1)..N {
            let scale = m[r][c].abs().max(m[c][r].abs()).max(1e-300);
            if (m[r][c] - m[c][r]).abs() > 1e-9 * scale.max(1.0) {
                return Err(ValidationError::new(field, Problem::NotSymmetric { row: r, col: c }));
            }
        }
    }
    Ok(m)
}

/// Wire form of a vector or point.
pub fn vec3_to_wire(v: &Vector3<f64>) -> wire::Vec3 {
    wire::Vec3 { x: v.x, y: v.y, z: v.z }
}

/// Wire form of a rigid transform.
pub fn pose_to_wire(p: &Isometry3<f64>) -> wire::Pose {
    let q = p.rotation.quaternion();
    wire::Pose {
        translation_m: Some(vec3_to_wire(&p.translation.vector)),
        rotation: Some(wire::Quaternion { w: q.w, x: q.i, y: q.j, z: q.k }),
    }
}

/// Wire form of a 3×3 covariance.
pub fn covariance3_to_wire(m: &Matrix3<f64>) -> wire::Covariance3 {
    wire::Covariance3 { values_m2: (0..9).map(|k| m[(k / 3, k % 3)]).collect() }
}

/// Wire form of a 6×6 pose covariance.
pub fn pose_covariance_to_wire(m: &Matrix6<f64>) -> wire::PoseCovariance {
    wire::PoseCovariance { values: (0..36).map(|k| m[(k / 6, k % 6)]).collect() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aperture_is_the_largest_distance_between_two_microphones() {
        let square = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.3, 0.0, 0.0),
            Point3::new(0.3, 0.4, 0.0),
            Point3::new(0.0, 0.4, 0.0),
        ];
        assert!((aperture_m(&square) - 0.5).abs() < 1e-12);
        assert_eq!(aperture_m(&square[..1]), 0.0);
        assert_eq!(aperture_m(&[]), 0.0);
    }

    fn lim() -> Limits {
        Limits::at(Stamp::from_ns(1_000_000_000_000))
    }

    #[test]
    fn direction_checks() {
        let l = lim();
        let ok = Some(wire::Vec3 { x: 0.0, y: 0.6, z: 0.8004 });
        let d = direction_from_wire(&ok, "d", &l).unwrap();
        assert!((d.norm() - 1.0).abs() < 1e-15);
        let long = Some(wire::Vec3 { x: 1.0, y: 1.0, z: 0.0 });
        let e = direction_from_wire(&long, "obs.doas[0].direction_in_array", &l).unwrap_err();
        assert_eq!(e.field, "obs.doas[0].direction_in_array");
        assert!(matches!(e.problem, Problem::NotUnitVector { .. }));
        let nan = Some(wire::Vec3 { x: f64::NAN, y: 0.0, z: 1.0 });
        let e = direction_from_wire(&nan, "d", &l).unwrap_err();
        assert_eq!(e.field, "d.x");
        assert_eq!(direction_from_wire(&None, "d", &l).unwrap_err().problem, Problem::Missing);
    }

    #[test]
    fn quaternion_checks() {
        let l = lim();
        let zero = Some(wire::Quaternion { w: 0.0, x: 0.0, y: 0.0, z: 0.0 });
        assert_eq!(rotation_from_wire(&zero, "q", &l).unwrap_err().problem, Problem::ZeroQuaternion);
        let far = Some(wire::Quaternion { w: 0.3, x: 0.0, y: 0.0, z: 0.0 });
        assert!(matches!(
            rotation_from_wire(&far, "q", &l).unwrap_err().problem,
            Problem::NotUnitQuaternion { .. }
        ));
        let near = Some(wire::Quaternion { w: 1.004, x: 0.0, y: 0.0, z: 0.0 });
        assert!(rotation_from_wire(&near, "q", &l).is_ok());
        let inf = Some(wire::Quaternion { w: f64::INFINITY, x: 0.0, y: 0.0, z: 0.0 });
        assert_eq!(rotation_from_wire(&inf, "q", &l).unwrap_err().field, "q.w");
    }

    #[test]
    fn pose_round_trip() {
        let l = lim();
        let p = Isometry3::new(Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.1, 0.2, 1.3));
        let back = pose_from_wire(&Some(pose_to_wire(&p)), "p", &l).unwrap();
        assert!((back.to_homogeneous() - p.to_homogeneous()).abs().max() < 1e-12);
        let missing_rot =
            Some(wire::Pose { translation_m: Some(vec3_to_wire(&Vector3::zeros())), rotation: None });
        assert_eq!(
            pose_from_wire(&missing_rot, "obs.map_from_base", &l).unwrap_err().field,
            "obs.map_from_base.rotation"
        );
    }

    #[test]
    fn stamp_checks() {
        let l = lim();
        assert!(l.stamp(l.now.as_ns() + 500_000_000, "s").is_ok());
        assert!(matches!(
            l.stamp(l.now.as_ns() + 5_000_000_000, "s").unwrap_err().problem,
            Problem::InFuture { .. }
        ));
        assert!(matches!(l.stamp(-1, "s").unwrap_err().problem, Problem::NegativeStamp(-1)));
    }

    #[test]
    fn covariance_checks() {
        let mut v = vec![0.0; 36];
        for k in 0..6 {
            v[k * 7] = 0.01;
        }
        let c = Some(wire::PoseCovariance { values: v.clone() });
        assert!(pose_covariance_from_wire(&c, "cov").unwrap().is_some());
        v[1] = 0.5;
        let e = pose_covariance_from_wire(&Some(wire::PoseCovariance { values: v }), "cov").unwrap_err();
        assert!(matches!(e.problem, Problem::NotSymmetric { row: 0, col: 1 }));
        let e = pose_covariance_from_wire(&Some(wire::PoseCovariance { values: vec![1.0; 5] }), "cov")
            .unwrap_err();
        assert!(matches!(e.problem, Problem::WrongLength { expected: 36, got: 5 }));
        assert!(
            pose_covariance_from_wire(&Some(wire::PoseCovariance { values: vec![] }), "cov")
                .unwrap()
                .is_none()
        );
    }
}

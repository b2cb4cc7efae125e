//! Goal poses of ground robots and where their arrays sit at a candidate spot.

use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};

use crate::uncertainty::Sensor;

/// Pose of a ground robot's base at `base_xy` (map xy, m): z = 0, level, its
/// x axis pointing at the source's horizontal position (yaw 0 when on top of it).
pub fn facing_pose(base_xy: &Point2<f64>, source_in_map: &Point3<f64>) -> Isometry3<f64> {
    let d = Point2::new(source_in_map.x, source_in_map.y) - base_xy;
    let yaw = if d.norm() > 1e-12 { d.y.atan2(d.x) } else { 0.0 };
    Isometry3::from_parts(
        Translation3::new(base_xy.x, base_xy.y, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// Array centre (map frame, m) of a robot whose base stands at `base_xy` facing the source.
pub fn array_at(
    base_xy: &Point2<f64>,
    source_in_map: &Point3<f64>,
    base_from_array: &Isometry3<f64>,
) -> Point3<f64> {
    (facing_pose(base_xy, source_in_map) * base_from_array) * Point3::origin()
}

/// Bearing sensor of that robot at that spot, for the information calculus.
pub(crate) fn sensor_at(
    base_xy: &Point2<f64>,
    source_in_map: &Point3<f64>,
    base_from_array: &Isometry3<f64>,
    sigma_rad: f64,
) -> Sensor {
    Sensor { origin: array_at(base_xy, source_in_map, base_from_array), sigma_rad, origin_sigma_m: 0.0 }
}

/// Unit vector of bearing `phi` (rad) in the xy plane.
pub(crate) fn unit(phi: f64) -> nalgebra::Vector2<f64> {
    nalgebra::Vector2::new(phi.cos(), phi.sin())
}

/// Angle wrapped to (−π, π].
pub(crate) fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let r = a.rem_euclid(t);
    if r > std::f64::consts::PI { r - t } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goal_faces_the_source_and_carries_the_array_offset() {
        let src = Point3::new(3.0, 4.0, 1.6);
        let base = Point2::new(0.0, 0.0);
        let pose = facing_pose(&base, &src);
        let forward = pose * Vector3::x();
        assert!((forward - Vector3::new(0.6, 0.8, 0.0)).norm() < 1e-12);
        assert_eq!(pose.translation.vector.z, 0.0);
        let array = array_at(&base, &src, &Isometry3::translation(0.1, 0.0, 0.5));
        assert!((array - Point3::new(0.06, 0.08, 0.5)).norm() < 1e-12);
        assert!((wrap(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap(-0.5) + 0.5).abs() < 1e-15);
    }
}

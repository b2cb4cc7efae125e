//! What the live view draws, as Foxglove's own schemas (`foxglove.FrameTransforms`,
//! `foxglove.SceneUpdate`), so the stock 3D panel shows it without set-up.
//! Pure functions: coordinator data in, messages out.
//!
//! Frames: `map`, `{robot}/base` (child of `map`), `{robot}/array` (child of
//! `{robot}/base`). Every scene entity is drawn in `map`, so a recording shows
//! it even where its transforms were not kept.
//!
//! The 95 % covariance ellipsoid of a 3D Gaussian with covariance `P = V Λ Vᵀ`
//! is `{x : (x−μ)ᵀ P⁻¹ (x−μ) ≤ χ²₃(0.95)}` with `χ²₃(0.95) = 7.815`: its axes
//! are the eigenvectors `V` and its semi-axes `√(7.815 λᵢ)`. A source with
//! σ = 0.1 m on every axis gets a sphere of diameter `2·√(7.815·0.01) = 0.56 m`.
//! Foxglove's sphere primitive takes the full axis lengths (diameters) and the
//! orientation `V` (made right-handed) as a quaternion.

use foxglove::messages::{
    ArrowPrimitive, Color, Duration, FrameTransform, FrameTransforms, LinePrimitive, Pose, Quaternion,
    SceneEntity, SpherePrimitive, TextPrimitive, Timestamp, Vector3 as FgVector3,
    line_primitive::Type as LineType,
};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};
use soundmap_proto::wire;

/// The shared SLAM map frame.
pub const MAP_FRAME: &str = "map";
/// χ²₃(0.95): the squared Mahalanobis radius of the 95 % ellipsoid in 3D.
pub const CHI2_3_95: f64 = 7.814_727_903_251_178;
/// How long a ray stays drawn after its observation (s).
const RAY_LIFETIME_S: f64 = 0.5;
/// How long a source stays drawn after its last estimate (s).
const SOURCE_LIFETIME_S: f64 = 5.0;

/// A robot's base frame.
pub fn base_frame(robot: &str) -> String {
    format!("{robot}/base")
}

/// A robot's array frame.
pub fn array_frame(robot: &str) -> String {
    format!("{robot}/array")
}

/// A Foxglove timestamp from Unix nanoseconds (clamped at the epoch).
pub fn timestamp(ns: i64) -> Timestamp {
    let ns = ns.max(0) as u64;
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

fn lifetime(s: f64) -> Option<Duration> {
    Some(Duration::new(s.trunc() as i32, (s.fract() * 1e9) as u32))
}

fn vector(v: &Vector3<f64>) -> FgVector3 {
    FgVector3 { x: v.x, y: v.y, z: v.z }
}

fn point(p: &Point3<f64>) -> foxglove::messages::Point3 {
    foxglove::messages::Point3 { x: p.x, y: p.y, z: p.z }
}

fn quaternion(q: &UnitQuaternion<f64>) -> Quaternion {
    Quaternion { x: q.i, y: q.j, z: q.k, w: q.w }
}

fn pose(iso: &Isometry3<f64>) -> Pose {
    Pose { position: Some(vector(&iso.translation.vector)), orientation: Some(quaternion(&iso.rotation)) }
}

fn at(p: &Point3<f64>) -> Pose {
    pose(&Isometry3::translation(p.x, p.y, p.z))
}

/// An opaque colour from RGB in [0, 1].
pub fn rgb(r: f64, g: f64, b: f64) -> Color {
    Color { r, g, b, a: 1.0 }
}

/// The colour of a robot-local track id (a repeating palette of 8).
pub fn track_color(track_id: u64) -> Color {
    const PALETTE: [(f64, f64, f64); 8] = [
        (0.12, 0.47, 0.71),
        (1.00, 0.50, 0.05),
        (0.17, 0.63, 0.17),
        (0.84, 0.15, 0.16),
        (0.58, 0.40, 0.74),
        (0.55, 0.34, 0.29),
        (0.89, 0.47, 0.76),
        (0.09, 0.75, 0.81),
    ];
    let (r, g, b) = PALETTE[(track_id % PALETTE.len() as u64) as usize];
    rgb(r, g, b)
}

/// `map → {robot}/base` and `{robot}/base → {robot}/array` at `ns`.
pub fn transforms(
    ns: i64,
    robot: &str,
    map_from_base: &Isometry3<f64>,
    base_from_array: &Isometry3<f64>,
) -> FrameTransforms {
    let t = |parent: String, child: String, iso: &Isometry3<f64>| FrameTransform {
        timestamp: Some(timestamp(ns)),
        parent_frame_id: parent,
        child_frame_id: child,
        translation: Some(vector(&iso.translation.vector)),
        rotation: Some(quaternion(&iso.rotation)),
    };
    FrameTransforms {
        transforms: vec![
            t(MAP_FRAME.into(), base_frame(robot), map_from_base),
            t(base_frame(robot), array_frame(robot), base_from_array),
        ],
    }
}

/// Robot `robot`'s DoAs as rays `length_m` long from its array centre, in
/// `map`, one line per track (coloured by track id).
pub fn doa_rays(
    ns: i64,
    robot: &str,
    map_from_array: &Isometry3<f64>,
    doas: &[(u64, Vector3<f64>)],
    length_m: f64,
) -> SceneEntity {
    let origin = map_from_array * Point3::origin();
    let lines = doas
        .iter()
        .map(|(track, d)| LinePrimitive {
            r#type: LineType::LineList as i32,
            pose: Some(pose(&Isometry3::identity())),
            thickness: 0.02,
            scale_invariant: false,
            points: vec![point(&origin), point(&(origin + map_from_array.rotation * d * length_m))],
            color: Some(track_color(*track)),
            colors: vec![],
            indices: vec![],
        })
        .collect();
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: MAP_FRAME.into(),
        id: format!("doa/{robot}"),
        lifetime: lifetime(RAY_LIFETIME_S),
        lines,
        ..Default::default()
    }
}

/// The orientation and full axis lengths (m) of the 95 % ellipsoid of `cov`
/// (m²), or `None` when `cov` is not a finite covariance.
pub fn ellipsoid(cov: &Matrix3<f64>) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    if !cov.iter().all(|v| v.is_finite()) {
        return None;
    }
    let sym = (cov + cov.transpose()) * 0.5;
    let eig = sym.symmetric_eigen();
    let mut axes = eig.eigenvectors;
    if axes.determinant() < 0.0 {
        axes.set_column(2, &(-axes.column(2)));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(axes));
    let sizes = eig.eigenvalues.map(|l| 2.0 * (CHI2_3_95 * l.max(0.0)).sqrt());
    Some((rotation, sizes))
}

/// How a point marker is drawn: its colour, sphere size (m), ellipsoid
/// opacity, and its label's colour, font size and height above the point (m).
struct Marker {
    rgb: (f64, f64, f64),
    size_m: f64,
    ellipsoid_alpha: f64,
    label_rgb: (f64, f64, f64),
    font_size: f64,
    label_dz_m: f64,
}

/// A sphere at `p`, its 95 % ellipsoid when `cov` is given, and `label`.
fn marker_entity(
    ns: i64,
    id: String,
    p: Point3<f64>,
    cov: Option<&Matrix3<f64>>,
    m: &Marker,
    label: String,
) -> SceneEntity {
    let (r, g, b) = m.rgb;
    let mut spheres = vec![SpherePrimitive {
        pose: Some(at(&p)),
        size: Some(FgVector3 { x: m.size_m, y: m.size_m, z: m.size_m }),
        color: Some(rgb(r, g, b)),
    }];
    if let Some((q, sizes)) = cov.and_then(ellipsoid) {
        spheres.push(SpherePrimitive {
            pose: Some(pose(&Isometry3::from_parts(p.coords.into(), q))),
            size: Some(vector(&sizes)),
            color: Some(Color { r, g, b, a: m.ellipsoid_alpha }),
        });
    }
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: MAP_FRAME.into(),
        id,
        lifetime: lifetime(SOURCE_LIFETIME_S),
        spheres,
        texts: vec![TextPrimitive {
            pose: Some(at(&(p + Vector3::new(0.0, 0.0, m.label_dz_m)))),
            billboard: true,
            font_size: m.font_size,
            scale_invariant: true,
            color: Some(rgb(m.label_rgb.0, m.label_rgb.1, m.label_rgb.2)),
            text: label,
        }],
        ..Default::default()
    }
}

/// A source estimate: a sphere at its position, its 95 % ellipsoid, and its id
/// as text; green when trusted, orange when not. `None` without a position.
pub fn source_entity(ns: i64, e: &wire::SourceEstimate) -> Option<SceneEntity> {
    let p = e.position_in_map_m.as_ref()?;
    let rgb = if e.trusted { (0.10, 0.80, 0.25) } else { (1.00, 0.55, 0.05) };
    let marker = Marker {
        rgb,
        size_m: 0.15,
        ellipsoid_alpha: 0.25,
        label_rgb: (1.0, 1.0, 1.0),
        font_size: 14.0,
        label_dz_m: 0.25,
    };
    let cov = e.covariance.as_ref().and_then(soundmap_proto::monitoring::covariance_from_wire);
    let label =
        if e.trusted { format!("source {}", e.source_id) } else { format!("source {} ?", e.source_id) };
    Some(marker_entity(
        ns,
        format!("source/{}", e.source_id),
        Point3::new(p.x, p.y, p.z),
        cov.as_ref(),
        &marker,
        label,
    ))
}

const SMOOTHED_RGB: (f64, f64, f64) = (0.25, 0.65, 1.00);

/// A source's smoothed state (`SourceEstimate.smoothed`, about a second
/// behind): a small sky-blue sphere at the smoothed position, its 95 %
/// ellipsoid when trusted, and "source {id} −{lag} s" below it. `None` without one.
pub fn smoothed_entity(ns: i64, e: &wire::SourceEstimate) -> Option<SceneEntity> {
    let s = e.smoothed.as_ref()?;
    let p = s.position_in_map_m.as_ref()?;
    let marker = Marker {
        rgb: SMOOTHED_RGB,
        size_m: 0.1,
        ellipsoid_alpha: 0.15,
        label_rgb: SMOOTHED_RGB,
        font_size: 12.0,
        label_dz_m: -0.2,
    };
    let cov = s
        .position_covariance
        .as_ref()
        .filter(|_| s.trusted)
        .and_then(soundmap_proto::monitoring::covariance_from_wire);
    let label = format!("source {} −{:.1} s", e.source_id, s.lag_s);
    Some(marker_entity(
        ns,
        format!("smoothed/{}", e.source_id),
        Point3::new(p.x, p.y, p.z),
        cov.as_ref(),
        &marker,
        label,
    ))
}

/// A true source position (simulation and scored replays): a small white sphere.
pub fn truth_entity(ns: i64, index: usize, p: &Point3<f64>, active: bool) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: MAP_FRAME.into(),
        id: format!("truth/{index}"),
        spheres: vec![SpherePrimitive {
            pose: Some(at(p)),
            size: Some(FgVector3 { x: 0.1, y: 0.1, z: 0.1 }),
            color: Some(Color { r: 1.0, g: 1.0, b: 1.0, a: if active { 0.9 } else { 0.3 } }),
        }],
        ..Default::default()
    }
}

/// A reposition goal: an arrow at the goal pose (x forward), 0.5 m long.
pub fn goal_entity(ns: i64, robot: &str, goal_map_from_base: &Isometry3<f64>) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: MAP_FRAME.into(),
        id: format!("goal/{robot}"),
        arrows: vec![ArrowPrimitive {
            pose: Some(pose(goal_map_from_base)),
            shaft_length: 0.35,
            shaft_diameter: 0.05,
            head_length: 0.15,
            head_diameter: 0.12,
            color: Some(rgb(0.95, 0.85, 0.10)),
        }],
        ..Default::default()
    }
}

/// A robot's path so far (its array centre, in `map`), as a line strip.
pub fn path_entity(ns: i64, robot: &str, points: impl Iterator<Item = Point3<f64>>) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: MAP_FRAME.into(),
        id: format!("path/{robot}"),
        lines: vec![LinePrimitive {
            r#type: LineType::LineStrip as i32,
            pose: Some(pose(&Isometry3::identity())),
            thickness: 0.03,
            points: points.map(|p| point(&p)).collect(),
            color: Some(Color { r: 0.6, g: 0.6, b: 0.9, a: 0.8 }),
            ..Default::default()
        }],
        ..Default::default()
    }
}

/// The room outline and obstacles (`[x, y]` polygons, m) as closed lines on the floor.
pub fn room_entity(ns: i64, room: &[[f64; 2]], obstacles: &[Vec<[f64; 2]>]) -> SceneEntity {
    let outline = |poly: &[[f64; 2]], color: Color| LinePrimitive {
        r#type: LineType::LineLoop as i32,
        pose: Some(pose(&Isometry3::identity())),
        thickness: 0.04,
        points: poly.iter().map(|[x, y]| foxglove::messages::Point3 { x: *x, y: *y, z: 0.0 }).collect(),
        color: Some(color),
        ..Default::default()
    };
    let mut lines = Vec::with_capacity(1 + obstacles.len());
    if room.len() >= 2 {
        lines.push(outline(room, rgb(0.8, 0.8, 0.8)));
    }
    lines.extend(obstacles.iter().filter(|o| o.len() >= 2).map(|o| outline(o, rgb(0.9, 0.3, 0.3))));
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: MAP_FRAME.into(),
        id: "room".into(),
        lines,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_smoothed_state_is_drawn_beside_the_estimate() {
        let mut e = wire::SourceEstimate { source_id: 3, ..Default::default() };
        assert!(smoothed_entity(0, &e).is_none());
        e.smoothed = Some(wire::SmoothedState {
            stamp_ns: 0,
            lag_s: 1.04,
            position_in_map_m: Some(wire::Vec3 { x: 1.0, y: 2.0, z: 1.2 }),
            position_covariance: Some(soundmap_proto::geometry::covariance3_to_wire(
                &(Matrix3::identity() * 0.01),
            )),
            trusted: true,
            ..Default::default()
        });
        let entity = smoothed_entity(5, &e).unwrap();
        assert_eq!(entity.id, "smoothed/3");
        assert_eq!(entity.spheres.len(), 2, "the position and, trusted, its ellipsoid");
        assert_eq!(entity.texts[0].text, "source 3 −1.0 s");
        e.smoothed.as_mut().unwrap().trusted = false;
        assert_eq!(smoothed_entity(5, &e).unwrap().spheres.len(), 1);
    }

    #[test]
    fn ellipsoid_of_an_isotropic_covariance_is_a_sphere_of_the_95_percent_radius() {
        let (_, sizes) = ellipsoid(&(Matrix3::identity() * 0.01)).unwrap();
        for s in sizes.iter() {
            assert!((s - 0.559).abs() < 1e-3, "{s}");
        }
    }

    #[test]
    fn ellipsoid_axes_follow_the_covariance() {
        // σ = 1 m along the map's diagonal x = y, 0.1 m across it and in z.
        let u = Vector3::new(1.0, 1.0, 0.0).normalize();
        let cov = u * u.transpose() * 1.0 + (Matrix3::identity() - u * u.transpose()) * 0.01;
        let (q, sizes) = ellipsoid(&cov).unwrap();
        let k = sizes.imax();
        let axis = q * Vector3::ith(k, 1.0);
        assert!(axis.dot(&u).abs() > 0.999, "{axis}");
        assert!((sizes[k] - 2.0 * CHI2_3_95.sqrt()).abs() < 1e-9);
        assert!(ellipsoid(&Matrix3::from_element(f64::NAN)).is_none());
    }

    #[test]
    fn rays_start_at_the_array_and_point_along_the_doa_in_map() {
        let map_from_array =
            Isometry3::new(Vector3::new(1.0, 2.0, 0.5), Vector3::z() * std::f64::consts::FRAC_PI_2);
        let e = doa_rays(0, "r1", &map_from_array, &[(3, Vector3::x())], 2.0);
        let pts = &e.lines[0].points;
        assert_eq!((pts[0].x, pts[0].y, pts[0].z), (1.0, 2.0, 0.5));
        assert!((pts[1].x - 1.0).abs() < 1e-12 && (pts[1].y - 4.0).abs() < 1e-12);
        assert_eq!(e.lines[0].color, Some(track_color(3)));
    }
}

//! Microphone array geometry: microphone positions and directivity in the
//! `array` frame, the array's pose on the robot, and the region of directions
//! the array searches by default.
//!
//! Frames and units: positions in metres in the `array` frame (x forward,
//! y left, z up when the array is mounted level). DoAs are unit vectors in
//! the same frame, pointing from the array origin toward the source; the
//! coordinator's rays start at the array origin (`map_from_base *
//! base_from_array * 0`), so the origin should be the array's acoustic centre.
//! The built-in presets put it at the microphones' centroid.
//!
//! Arrays come from a built-in preset ([`presets`]) or a TOML file ([`mod@file`]);
//! [`ArrayGeometry::load`] takes either.

pub mod file;
pub mod presets;

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Unit, Vector3};

use crate::error::AgentError;

/// Smallest distance allowed between two microphones, metres.
pub const MIN_MICROPHONE_SPACING_M: f64 = 1e-3;

/// Tolerance under which an array counts as planar, metres (largest distance
/// of a microphone from the best-fit plane).
pub const PLANAR_TOLERANCE_M: f64 = 1e-4;

/// A microphone's directivity: full gain within `full_gain_angle_rad` of its
/// [`Microphone::axis_in_array`], no gain beyond `zero_gain_angle_rad`, a raised
/// cosine in between (ODAS's `angle = (full, zero)` in degrees).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Directivity {
    /// Angle from the microphone axis up to which the gain is 1, radians.
    pub full_gain_angle_rad: f64,
    /// Angle from the microphone axis beyond which the gain is 0, radians.
    pub zero_gain_angle_rad: f64,
}

impl Default for Directivity {
    /// Full gain over the front hemisphere, fading to zero 20° behind it.
    fn default() -> Self {
        Directivity { full_gain_angle_rad: 80f64.to_radians(), zero_gain_angle_rad: 100f64.to_radians() }
    }
}

/// One microphone of an array.
#[derive(Clone, Debug, PartialEq)]
pub struct Microphone {
    /// Position in the `array` frame, metres.
    pub position_in_array: Point3<f64>,
    /// Axis of a directional microphone (unit vector, `array` frame);
    /// `None` for an omnidirectional one.
    pub axis_in_array: Option<Unit<Vector3<f64>>>,
    /// Gain pattern around `axis_in_array` (ignored when it is `None`).
    pub directivity: Directivity,
}

impl Microphone {
    /// An omnidirectional microphone at `position_in_array` (metres, array frame).
    pub fn omni(position_in_array: Point3<f64>) -> Self {
        Microphone { position_in_array, axis_in_array: None, directivity: Directivity::default() }
    }

    /// Gain in [0, 1] of this microphone for a source in direction `doa`
    /// (unit vector, array frame); 1 for an omnidirectional microphone.
    pub fn gain(&self, doa: &Unit<Vector3<f64>>) -> f64 {
        let Some(axis) = self.axis_in_array else { return 1.0 };
        let angle = axis.dot(doa).clamp(-1.0, 1.0).acos();
        let Directivity { full_gain_angle_rad: a, zero_gain_angle_rad: b } = self.directivity;
        if angle <= a {
            1.0
        } else if angle >= b {
            0.0
        } else {
            0.5 + 0.5 * (std::f64::consts::PI * (angle - a) / (b - a)).cos()
        }
    }
}

/// A cone of directions: those within `max_angle_rad` of `axis`.
/// `max_angle_rad = π` is the whole sphere, `π/2` a hemisphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SearchRegion {
    /// Axis of the cone (unit vector, array frame).
    pub axis: Unit<Vector3<f64>>,
    /// Half-angle of the cone, radians, in (0, π].
    pub max_angle_rad: f64,
}

impl SearchRegion {
    /// Every direction.
    pub fn full_sphere() -> Self {
        SearchRegion { axis: Vector3::z_axis(), max_angle_rad: std::f64::consts::PI }
    }

    /// Directions with z ≥ 0 in the array frame (at or above the array plane).
    pub fn upper_hemisphere() -> Self {
        SearchRegion { axis: Vector3::z_axis(), max_angle_rad: std::f64::consts::FRAC_PI_2 }
    }

    /// Whether `d` (unit vector) is inside the region, with `margin_rad` of slack.
    pub fn contains(&self, d: &Vector3<f64>, margin_rad: f64) -> bool {
        let limit = self.max_angle_rad + margin_rad;
        limit >= std::f64::consts::PI || self.axis.dot(d) >= limit.cos() - 1e-12
    }

    /// `d` itself when inside, else the closest direction on the region's boundary.
    pub fn clamp(&self, d: Unit<Vector3<f64>>) -> Unit<Vector3<f64>> {
        if self.contains(&d, 0.0) {
            return d;
        }
        self.at_angle_from_axis(&d, self.max_angle_rad).map_or(self.axis, Unit::new_normalize)
    }

    /// The direction at `d`'s place around the axis and `angle_rad` from it
    /// (unit up to rounding); `None` when `d` lies along the axis.
    pub fn at_angle_from_axis(&self, d: &Vector3<f64>, angle_rad: f64) -> Option<Vector3<f64>> {
        let a = self.axis.into_inner();
        let perp = Unit::try_new(d - a * a.dot(d), 1e-12)?;
        let (s, c) = angle_rad.sin_cos();
        Some(a * c + perp.into_inner() * s)
    }
}

/// A microphone array: its microphones (channel `i` of the audio is
/// microphone `i`), its pose on the robot and its default search region.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayGeometry {
    /// Preset name or the name given in the file.
    pub name: String,
    /// Microphones in channel order.
    pub microphones: Vec<Microphone>,
    /// Pose of the `array` frame in the robot's `base` frame.
    pub base_from_array: Isometry3<f64>,
    /// Directions searched unless the localization config overrides it.
    pub default_region: SearchRegion,
}

impl ArrayGeometry {
    /// Builds and validates an array. `origin` names the source in errors
    /// (a file path, or `<preset NAME>`).
    pub fn new(
        name: impl Into<String>,
        microphones: Vec<Microphone>,
        base_from_array: Isometry3<f64>,
        default_region: SearchRegion,
        origin: &Path,
    ) -> Result<Self, AgentError> {
        let g = ArrayGeometry { name: name.into(), microphones, base_from_array, default_region };
        g.validate(origin)?;
        Ok(g)
    }

    /// A preset name (see [`presets::NAMES`]) or a path to a `.toml` array file.
    pub fn load(preset_or_path: &str) -> Result<Self, AgentError> {
        if let Some(g) = presets::by_name(preset_or_path) {
            return Ok(g);
        }
        let path = Path::new(preset_or_path);
        let looks_like_path = preset_or_path.ends_with(".toml")
            || preset_or_path.contains(std::path::MAIN_SEPARATOR)
            || preset_or_path.contains('/');
        if !looks_like_path {
            return Err(AgentError::Config {
                path: PathBuf::from(format!("<preset {preset_or_path}>")),
                field: "array".into(),
                message: format!(
                    "unknown array preset `{preset_or_path}` (known: {}); give a path to a .toml file for a custom array",
                    presets::NAMES.join(", ")
                ),
            });
        }
        file::load_file(path)
    }

    /// The same array mounted at `base_from_array` on the robot.
    pub fn with_base_from_array(mut self, base_from_array: Isometry3<f64>) -> Self {
        self.base_from_array = base_from_array;
        self
    }

    /// Number of microphones (= audio channels).
    pub fn channels(&self) -> usize {
        self.microphones.len()
    }

    /// Checks that an audio source with `channels` channels fits this array;
    /// the error names `source_name` (e.g. the WAV file) and field `channels`.
    pub fn check_channels(&self, channels: usize, source_name: &str) -> Result<(), AgentError> {
        if channels == self.channels() {
            return Ok(());
        }
        Err(AgentError::Config {
            path: PathBuf::from(source_name),
            field: "channels".into(),
            message: format!(
                "has {channels} channels but array `{}` has {} microphones (one channel per microphone, in order)",
                self.name,
                self.channels()
            ),
        })
    }

    /// Microphone positions, metres, array frame.
    pub fn positions(&self) -> impl ExactSizeIterator<Item = Point3<f64>> + '_ {
        self.microphones.iter().map(|m| m.position_in_array)
    }

    /// Centroid of the microphones, array frame.
    pub fn centroid(&self) -> Point3<f64> {
        let sum: Vector3<f64> = self.positions().map(|p| p.coords).sum();
        Point3::from(sum / self.channels() as f64)
    }

    /// Largest distance between two microphones (aperture), metres.
    pub fn aperture_m(&self) -> f64 {
        let p: Vec<_> = self.positions().collect();
        soundmap_proto::aperture_m(&p)
    }

    /// Normal of the best-fit plane through the microphones and the largest
    /// distance of a microphone from that plane (metres). The normal is the
    /// eigenvector of the smallest eigenvalue of the scatter matrix, signed
    /// so that its largest component is positive along z, then x.
    pub fn best_fit_plane(&self) -> (Unit<Vector3<f64>>, f64) {
        let c = self.centroid();
        let mut s = nalgebra::Matrix3::zeros();
        for p in self.positions() {
            let d = p - c;
            s += d * d.transpose();
        }
        let eig = s.symmetric_eigen();
        let k = eig.eigenvalues.imin();
        let mut n: Vector3<f64> = eig.eigenvectors.column(k).into_owned();
        let key = if n.z.abs() > 1e-9 { n.z } else { n.x };
        if key < 0.0 {
            n = -n;
        }
        let n = Unit::new_normalize(n);
        let dev = self.positions().map(|p| (p - c).dot(&n).abs()).fold(0.0, f64::max);
        (n, dev)
    }

    /// Whether all microphones lie in one plane (within [`PLANAR_TOLERANCE_M`]).
    /// A planar array cannot tell the two sides of its plane apart.
    pub fn is_planar(&self) -> bool {
        self.channels() < 4 || self.best_fit_plane().1 <= PLANAR_TOLERANCE_M
    }

    /// The same array with its origin moved to the microphones' centroid
    /// (positions shifted, `base_from_array` compensated so the microphones
    /// stay where they are on the robot).
    pub fn centred(mut self) -> Self {
        let c = self.centroid().coords;
        for m in &mut self.microphones {
            m.position_in_array -= c;
        }
        let shift = self.base_from_array.rotation * c;
        self.base_from_array.translation.vector += shift;
        self
    }

    /// Checks the invariants; errors name `origin` and the field.
    pub fn validate(&self, origin: &Path) -> Result<(), AgentError> {
        let err = |field: String, message: String| AgentError::Config {
            path: origin.to_path_buf(),
            field,
            message,
        };
        if self.name.trim().is_empty() {
            return Err(err("name".into(), "must not be empty".into()));
        }
        if self.microphones.len() < 2 {
            return Err(err(
                "microphones".into(),
                format!("an array needs at least 2 microphones, got {}", self.microphones.len()),
            ));
        }
        for (i, m) in self.microphones.iter().enumerate() {
            if !m.position_in_array.coords.iter().all(|v| v.is_finite()) {
                return Err(err(
                    format!("microphones[{i}].position_m"),
                    format!("must be finite, got {:?}", m.position_in_array.coords.as_slice()),
                ));
            }
            if m.position_in_array.coords.norm() > 10.0 {
                return Err(err(
                    format!("microphones[{i}].position_m"),
                    "is more than 10 m from the array origin (positions are in metres)".into(),
                ));
            }
            if let Some(d) = m.axis_in_array
                && !d.iter().all(|v| v.is_finite())
            {
                return Err(err(format!("microphones[{i}].direction"), "must be finite".into()));
            }
            let Directivity { full_gain_angle_rad: a, zero_gain_angle_rad: b } = m.directivity;
            if !(a.is_finite() && b.is_finite() && 0.0 <= a && a < b && b <= std::f64::consts::PI) {
                return Err(err(
                    format!("microphones[{i}].directivity_deg"),
                    format!(
                        "needs 0 <= full-gain angle < zero-gain angle <= 180, got [{}, {}]",
                        a.to_degrees(),
                        b.to_degrees()
                    ),
                ));
            }
            for (j, other) in self.microphones[..i].iter().enumerate() {
                let d = (m.position_in_array - other.position_in_array).norm();
                if d < MIN_MICROPHONE_SPACING_M {
                    return Err(err(
                        format!("microphones[{i}].position_m"),
                        format!(
                            "is {:.2} mm from microphones[{j}]; microphones must be at least {} mm apart",
                            d * 1e3,
                            MIN_MICROPHONE_SPACING_M * 1e3
                        ),
                    ));
                }
            }
        }
        let t = self.base_from_array.translation.vector;
        let q = self.base_from_array.rotation.coords;
        if !(t.iter().chain(q.iter()).all(|v| v.is_finite())) {
            return Err(err("base_from_array".into(), "must be finite".into()));
        }
        let r = &self.default_region;
        if !(r.axis.iter().all(|v| v.is_finite())
            && r.max_angle_rad > 0.0
            && r.max_angle_rad <= std::f64::consts::PI)
        {
            return Err(err(
                "search_region".into(),
                "needs a finite axis and 0 < max_angle_deg <= 180".into(),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mic(x: f64, y: f64, z: f64) -> Microphone {
        Microphone::omni(Point3::new(x, y, z))
    }

    #[test]
    fn region_clamp_projects_onto_boundary() {
        let r = SearchRegion::upper_hemisphere();
        let below = Unit::new_normalize(Vector3::new(1.0, 0.0, -0.5));
        let c = r.clamp(below);
        assert!(c.z.abs() < 1e-12 && (c.x - 1.0).abs() < 1e-12);
        let above = Unit::new_normalize(Vector3::new(1.0, 2.0, 0.5));
        assert_eq!(r.clamp(above), above);
        assert!(SearchRegion::full_sphere().contains(&-Vector3::z(), 0.0));
    }

    #[test]
    fn directivity_gain_is_one_in_front_zero_behind() {
        let mut m = mic(0.0, 0.0, 0.0);
        m.axis_in_array = Some(Vector3::z_axis());
        assert_eq!(m.gain(&Vector3::z_axis()), 1.0);
        assert_eq!(m.gain(&-Vector3::z_axis()), 0.0);
        let g = m.gain(&Vector3::x_axis());
        assert!((g - 0.5).abs() < 1e-12, "{g}");
    }

    #[test]
    fn centred_keeps_microphones_in_place_on_the_robot() {
        let g = ArrayGeometry::new(
            "t",
            vec![mic(0.1, 0.0, 0.02), mic(-0.1, 0.0, 0.02), mic(0.0, 0.1, 0.04)],
            Isometry3::translation(0.0, 0.0, 0.48),
            SearchRegion::full_sphere(),
            Path::new("<test>"),
        )
        .unwrap();
        let c = g.clone().centred();
        assert!(c.centroid().coords.norm() < 1e-12);
        for (a, b) in g.microphones.iter().zip(&c.microphones) {
            let pa = g.base_from_array * a.position_in_array;
            let pb = c.base_from_array * b.position_in_array;
            assert!((pa - pb).norm() < 1e-12);
        }
    }

    #[test]
    fn planarity() {
        let flat = ArrayGeometry::new(
            "flat",
            vec![mic(0.1, 0.0, 0.0), mic(0.0, 0.1, 0.0), mic(-0.1, 0.0, 0.0), mic(0.0, -0.1, 0.0)],
            Isometry3::identity(),
            SearchRegion::full_sphere(),
            Path::new("<test>"),
        )
        .unwrap();
        assert!(flat.is_planar());
        let (n, _) = flat.best_fit_plane();
        assert!((n.z - 1.0).abs() < 1e-9);
        let mut bumpy = flat.clone();
        bumpy.microphones[0].position_in_array.z = 0.01;
        assert!(!bumpy.is_planar());
    }
}

//! Array files (TOML). Unknown keys are rejected; every error names the file
//! and the field (e.g. `microphones[3].position_m`).
//!
//! ```toml
//! name = "my-array"                      # required
//!
//! [base_from_array]                      # optional, default: identity
//! translation_m = [0.0, 0.0, 0.48]       # array origin in the base frame, metres
//! rotation_xyzw = [0.0, 0.0, 0.0, 1.0]   # unit quaternion base <- array (normalized on load)
//!
//! [search_region]                        # optional, see below
//! axis = [0.0, 0.0, 1.0]                 # array frame
//! max_angle_deg = 90.0                   # 90 = hemisphere, 180 = whole sphere
//!
//! [[microphones]]                        # one table per channel, in channel order (>= 2)
//! position_m = [0.1, 0.0, 0.0]           # array frame (x forward, y left, z up), metres
//! direction = [0.0, 0.0, 1.0]            # optional: axis of a directional microphone
//! directivity_deg = [80.0, 100.0]        # optional: full gain within 80°, none beyond 100°
//! ```
//!
//! Positions are used as given: put the origin at the array's acoustic centre
//! (the centroid of the microphones is a good choice), because the DoA rays
//! start there. Without `search_region`, a planar array searches the half
//! space on the +z side of its plane (+x if the plane is vertical), since it
//! cannot tell the two sides apart; any other array searches the whole sphere.

use std::path::Path;

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3};
use serde::Deserialize;

use super::{ArrayGeometry, Directivity, Microphone, SearchRegion};
use crate::error::AgentError;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArrayFile {
    name: String,
    #[serde(default)]
    base_from_array: Option<PoseFile>,
    #[serde(default)]
    search_region: Option<RegionFile>,
    microphones: Vec<MicrophoneFile>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseFile {
    #[serde(default)]
    translation_m: [f64; 3],
    #[serde(default = "identity_xyzw")]
    rotation_xyzw: [f64; 4],
}

fn identity_xyzw() -> [f64; 4] {
    [0.0, 0.0, 0.0, 1.0]
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RegionFile {
    axis: [f64; 3],
    max_angle_deg: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MicrophoneFile {
    position_m: [f64; 3],
    #[serde(default)]
    direction: Option<[f64; 3]>,
    #[serde(default)]
    directivity_deg: Option<[f64; 2]>,
}

/// Reads and validates an array file.
pub fn load_file(path: &Path) -> Result<ArrayGeometry, AgentError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| AgentError::Io { path: path.to_path_buf(), source })?;
    from_toml_str(&text, path)
}

/// Parses and validates an array description; `path` names the source in errors.
pub fn from_toml_str(text: &str, path: &Path) -> Result<ArrayGeometry, AgentError> {
    let err =
        |field: String, message: String| AgentError::Config { path: path.to_path_buf(), field, message };
    let file: ArrayFile = toml::from_str(text).map_err(|e| {
        let (field, message) = field_of_error(text, &e);
        err(field, message)
    })?;

    let base_from_array = match &file.base_from_array {
        None => Isometry3::identity(),
        Some(p) => {
            let [x, y, z, w] = p.rotation_xyzw;
            let q = Quaternion::new(w, x, y, z);
            if !(q.coords.iter().all(|v| v.is_finite()) && q.norm() > 1e-6) {
                return Err(err(
                    "base_from_array.rotation_xyzw".into(),
                    "must be a finite, non-zero quaternion [x, y, z, w]".into(),
                ));
            }
            if !p.translation_m.iter().all(|v| v.is_finite()) {
                return Err(err("base_from_array.translation_m".into(), "must be finite".into()));
            }
            let [tx, ty, tz] = p.translation_m;
            Isometry3::from_parts(Translation3::new(tx, ty, tz), UnitQuaternion::from_quaternion(q))
        }
    };

    let mut microphones = Vec::with_capacity(file.microphones.len());
    for (i, m) in file.microphones.iter().enumerate() {
        let direction = match m.direction {
            None => None,
            Some(d) => {
                let v = Vector3::from(d);
                let unit = (v.iter().all(|c| c.is_finite()))
                    .then(|| Unit::try_new(v, 1e-9))
                    .flatten()
                    .ok_or_else(|| {
                        err(format!("microphones[{i}].direction"), "must be a finite non-zero vector".into())
                    })?;
                Some(unit)
            }
        };
        let directivity = match m.directivity_deg {
            None => Directivity::default(),
            Some([a, b]) => {
                Directivity { full_gain_angle_rad: a.to_radians(), zero_gain_angle_rad: b.to_radians() }
            }
        };
        if m.directivity_deg.is_some() && direction.is_none() {
            return Err(err(
                format!("microphones[{i}].directivity_deg"),
                "needs `direction` (the microphone axis)".into(),
            ));
        }
        microphones.push(Microphone {
            position_in_array: Point3::from(m.position_m),
            axis_in_array: direction,
            directivity,
        });
    }

    let region_given = file.search_region.as_ref().map(|r| {
        let axis = Vector3::from(r.axis);
        let ok = axis.iter().all(|c| c.is_finite())
            && r.max_angle_deg.is_finite()
            && r.max_angle_deg > 0.0
            && r.max_angle_deg <= 180.0;
        (ok.then(|| Unit::try_new(axis, 1e-9)).flatten(), r.max_angle_deg)
    });
    let region = match region_given {
        Some((Some(axis), deg)) => Some(SearchRegion { axis, max_angle_rad: deg.to_radians() }),
        Some((None, _)) => {
            return Err(err(
                "search_region".into(),
                "needs a finite non-zero `axis` and 0 < `max_angle_deg` <= 180".into(),
            ));
        }
        None => None,
    };

    let mut g = ArrayGeometry {
        name: file.name,
        microphones,
        base_from_array,
        default_region: region.unwrap_or_else(SearchRegion::full_sphere),
    };
    g.validate(path)?;
    if region.is_none() && g.is_planar() {
        let (normal, _) = g.best_fit_plane();
        g.default_region = SearchRegion { axis: normal, max_angle_rad: std::f64::consts::FRAC_PI_2 };
    }
    Ok(g)
}

/// Maps a TOML/serde error to (field path, message) using its byte span:
/// the enclosing `[table]` / `[[array]]` header (with its index) and the key
/// on the line the span starts on; `missing field` errors add the field name.
fn field_of_error(text: &str, e: &toml::de::Error) -> (String, String) {
    let message = e.message().trim().to_string();
    let backticked = message.split('`').nth(1).map(str::to_string);
    let Some(span) = e.span().filter(|s| !s.is_empty()) else {
        // No (or an empty) span: the error is about the document's root table.
        return (backticked.unwrap_or_else(|| "<document>".into()), message);
    };
    let line_no = text[..span.start.min(text.len())].matches('\n').count() + 1;
    let mut table = String::new();
    let mut key = None::<String>;
    let mut counts: std::collections::HashMap<String, usize> = Default::default();
    for line in text.lines().take(line_no) {
        let t = line.trim();
        if let Some(name) = t.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = name.trim().to_string();
            let n = counts.entry(name.clone()).or_insert(0);
            table = format!("{name}[{n}]");
            *n += 1;
            key = None;
        } else if let Some(name) = t.strip_prefix('[').and_then(|r| r.split(']').next()) {
            table = name.trim().to_string();
            key = None;
        } else if let Some((k, _)) = t.split_once('=')
            && !t.starts_with('#')
        {
            key = Some(k.trim().trim_matches('"').to_string());
        } else if let Some(k) = t.split_whitespace().next().filter(|k| !k.starts_with('#') && !k.is_empty()) {
            // A bare key (e.g. an unknown key without a value) or a continuation line.
            if !k.starts_with([
                '[', ']', '0', '1', '2', '3', '4', '5', '6', '7', '8', '9', '-', '+', '"', '\'',
            ]) {
                key = Some(k.to_string());
            }
        }
    }
    let at_header = text.lines().nth(line_no - 1).is_some_and(|l| l.trim_start().starts_with('['));
    let join = |a: &str, b: &str| if a.is_empty() { b.to_string() } else { format!("{a}.{b}") };
    let field = if message.starts_with("missing field") || message.starts_with("unknown field") {
        join(&table, backticked.as_deref().unwrap_or("?"))
    } else if let Some(k) = key.filter(|_| !at_header) {
        join(&table, &k)
    } else if table.is_empty() {
        "<document>".into()
    } else {
        table
    };
    (field, format!("{message} (line {line_no})"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimal_file_parses_with_defaults() {
        let text = "name = \"pair\"\n[[microphones]]\nposition_m = [0.05, 0, 0]\n[[microphones]]\nposition_m = [-0.05, 0, 0]\n";
        let g = from_toml_str(text, Path::new("a.toml")).unwrap();
        assert_eq!(g.channels(), 2);
        assert_eq!(g.base_from_array, Isometry3::identity());
        assert!(g.is_planar());
    }

    #[test]
    fn error_paths_name_the_field() {
        let text =
            "name = \"x\"\n[[microphones]]\nposition_m = [0, 0, 0]\n[[microphones]]\nposition_m = [1, 2]\n";
        let Err(AgentError::Config { field, .. }) = from_toml_str(text, Path::new("a.toml")) else {
            panic!()
        };
        assert_eq!(field, "microphones[1].position_m");
    }
}

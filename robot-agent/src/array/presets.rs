//! Built-in microphone arrays, by name.
//!
//! | name | microphones | aperture | default search region |
//! |---|---|---|---|
//! | `16soundsusb-pioneer` | 16, two rectangular rings | 0.49 m | upper hemisphere |
//! | `16soundsusb-turtlebot` | 16, two rectangular rings | 0.42 m | upper hemisphere |
//! | `respeaker-4` | 4 on a circle, r = 32 mm | 64 mm | upper hemisphere |
//! | `respeaker-6` | 6 on a circle, r = 46.3 mm | 93 mm | upper hemisphere |
//! | `uma8` | 6 on a circle, r = 43 mm, + 1 centre | 86 mm | upper hemisphere |
//!
//! All presets put the array origin at the microphones' centroid (the ray
//! origin of the whole system) and use omnidirectional microphones.
//!
//! **Why the upper hemisphere.** `respeaker-4`, `respeaker-6` and `uma8` are
//! planar: a source and its mirror image through the array plane give the
//! same delays, so a planar array cannot tell above from below. Mounted level
//! on a ground robot, the sources of interest (people, loudspeakers) are
//! above it, so these presets search z ≥ 0. The 16SoundsUSB arrays are only
//! nearly planar (1.5 cm between the two rings' heights, i.e. at most 0.7
//! samples of extra delay at 16 kHz for a source straight overhead and almost
//! none near the horizon), too little to resolve above/below robustly once
//! the floor reflects sound; the paper's sources are above its arrays
//! (source at 1.12 m, arrays at 0.48 m), so they also search z ≥ 0. A source
//! below the array plane is then reported on the horizon (its azimuth stays
//! right). Override the region in the localization config (or give a
//! `search_region` in an array file) to search the whole sphere.

use std::path::PathBuf;

use nalgebra::{Isometry3, Point3};

use super::{ArrayGeometry, Microphone, SearchRegion};

/// Names of the built-in arrays, for [`by_name`] and error messages.
pub const NAMES: &[&str] =
    &["16soundsusb-pioneer", "16soundsusb-turtlebot", "respeaker-4", "respeaker-6", "uma8"];

/// Height of the 16SoundsUSB arrays' board above the ground on both robots
/// of the paper, metres.
pub const SIXTEEN_SOUNDS_BOARD_HEIGHT_M: f64 = 0.48;

/// The built-in array called `name`, if any.
pub fn by_name(name: &str) -> Option<ArrayGeometry> {
    let g = match name {
        // Table "Position of the microphones on the MA (cm)" of the paper.
        "16soundsusb-pioneer" => sixteen_sounds(name, [19.1, 24.5, 2.5], [33.2, 36.0, 4.0]),
        "16soundsusb-turtlebot" => sixteen_sounds(name, [18.5, 19.3, 2.6], [31.0, 28.4, 3.9]),
        "respeaker-4" => circle(name, 0.032, &[180.0, 270.0, 0.0, 90.0], false),
        "respeaker-6" => circle(name, 0.0463, &[120.0, 180.0, 240.0, 300.0, 0.0, 60.0], false),
        "uma8" => circle(name, 0.043, &[90.0, 30.0, -30.0, -90.0, -150.0, 150.0], true),
        _ => return None,
    };
    Some(g)
}

fn origin(name: &str) -> PathBuf {
    PathBuf::from(format!("<preset {name}>"))
}

/// The 16SoundsUSB arrays of the paper (IROS 2020, table "Position of the
/// microphones on the MA"), from `inner = [Δx1, Δy1, Δz1]` and
/// `outer = [Δx2, Δy2, Δz2]` in centimetres.
///
/// Interpretation of the table (the paper gives only the six numbers and a
/// figure): two rectangular rings of 8 microphones. The inner ring (channels
/// 1–8) has side Δx1 along x (forward) and Δy1 along y (left) at height Δz1
/// above the board; the outer ring (channels 9–16) has Δx2, Δy2 at Δz2. Each
/// ring has its 4 corners and 4 edge midpoints, numbered counter-clockwise
/// seen from above starting at the front-right corner: (+Δx/2, −Δy/2),
/// (+Δx/2, 0), (+Δx/2, +Δy/2), (0, +Δy/2), (−Δx/2, +Δy/2), (−Δx/2, 0),
/// (−Δx/2, −Δy/2), (0, −Δy/2).
///
/// Origin: the microphones' centroid. The z values are shifted so that the
/// centroid is at 0 (inner ring at −(Δz2−Δz1)/2, outer at +(Δz2−Δz1)/2), and
/// `base_from_array` is a translation of 0.48 m (board height on both robots)
/// + (Δz1+Δz2)/2 along z.
fn sixteen_sounds(name: &str, inner_cm: [f64; 3], outer_cm: [f64; 3]) -> ArrayGeometry {
    const CORNERS: [(f64, f64); 8] = [
        (1.0, -1.0),
        (1.0, 0.0),
        (1.0, 1.0),
        (0.0, 1.0),
        (-1.0, 1.0),
        (-1.0, 0.0),
        (-1.0, -1.0),
        (0.0, -1.0),
    ];
    let mean_z_m = 0.5 * (inner_cm[2] + outer_cm[2]) * 1e-2;
    let mut microphones = Vec::with_capacity(16);
    for [dx, dy, dz] in [inner_cm, outer_cm] {
        for (sx, sy) in CORNERS {
            microphones.push(Microphone::omni(Point3::new(
                sx * dx * 0.5e-2,
                sy * dy * 0.5e-2,
                dz * 1e-2 - mean_z_m,
            )));
        }
    }
    let base_from_array = Isometry3::translation(0.0, 0.0, SIXTEEN_SOUNDS_BOARD_HEIGHT_M + mean_z_m);
    ArrayGeometry::new(name, microphones, base_from_array, SearchRegion::upper_hemisphere(), &origin(name))
        .expect("built-in preset is valid")
}

/// A planar circular array in the z = 0 plane: microphones on a circle of
/// `radius_m` at azimuths `azimuths_deg` (counter-clockwise from +x), in
/// channel order, after a centre microphone when `centre` is set.
/// The mount pose is unknown: `base_from_array` is the identity (set it with
/// [`ArrayGeometry::with_base_from_array`]).
///
/// Sources (published facts, not code):
/// - `respeaker-4` (ReSpeaker USB 4 Mic Array / Mic Array v2.0, 4 raw
///   channels): microphones at (±32 mm, 0) and (0, ±32 mm), raw channels 1–4
///   at (−32, 0), (0, −32), (+32, 0), (0, +32) mm, as listed in ODAS's
///   configuration for this board (`respeaker_usb_4_mic_array.cfg`).
/// - `respeaker-6` (ReSpeaker 6-Mic Circular Array kit): circle of radius
///   46.3 mm, channels 1–6 at azimuths 120°, 180°, 240°, 300°, 0°, 60° (ODAS
///   `respeaker_6_mic_array.cfg`: "Circular shape, R = 0.0463m").
/// - `uma8` (miniDSP UMA-8, 7 MEMS microphones): one centre microphone and six
///   on a circle of radius 43 mm at 60° spacing (ODAS `minidsp.cfg`; the
///   "circular 7" geometry of Microsoft's microphone-array guidelines, radius
///   ≈ 42.5 mm); channel 1 at the centre, then azimuths 90°, 30°, −30°, −90°,
///   −150°, 150°.
fn circle(name: &str, radius_m: f64, azimuths_deg: &[f64], centre: bool) -> ArrayGeometry {
    let mut microphones = Vec::with_capacity(azimuths_deg.len() + 1);
    if centre {
        microphones.push(Microphone::omni(Point3::origin()));
    }
    for az in azimuths_deg {
        let (s, c) = az.to_radians().sin_cos();
        microphones.push(Microphone::omni(Point3::new(radius_m * c, radius_m * s, 0.0)));
    }
    ArrayGeometry::new(
        name,
        microphones,
        Isometry3::identity(),
        SearchRegion::upper_hemisphere(),
        &origin(name),
    )
    .expect("built-in preset is valid")
}

/// Every built-in array, in [`NAMES`] order.
pub fn all() -> Vec<ArrayGeometry> {
    NAMES.iter().map(|n| by_name(n).expect("listed preset exists")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sixteen_sounds_pioneer_matches_the_paper_table() {
        let g = by_name("16soundsusb-pioneer").unwrap();
        assert_eq!(g.channels(), 16);
        // Channel 1: front-right corner of the inner ring; channel 9: of the outer ring.
        let m1 = g.microphones[0].position_in_array;
        assert!((m1 - Point3::new(0.0955, -0.1225, -0.0075)).norm() < 1e-12, "{m1}");
        let m11 = g.microphones[10].position_in_array;
        assert!((m11 - Point3::new(0.166, 0.18, 0.0075)).norm() < 1e-12, "{m11}");
        assert!(g.centroid().coords.norm() < 1e-12);
        let t = g.base_from_array.translation.vector;
        assert!((t.z - (0.48 + 0.0325)).abs() < 1e-12);
        // Ring side lengths.
        let inner: Vec<_> = g.microphones[..8].iter().map(|m| m.position_in_array).collect();
        assert!(((inner[0] - inner[6]).x - 0.191).abs() < 1e-12);
        assert!(((inner[2] - inner[0]).y - 0.245).abs() < 1e-12);
        assert!(!g.is_planar());
    }

    #[test]
    fn every_preset_is_valid_and_centred() {
        for g in all() {
            assert!(g.centroid().coords.norm() < 1e-9, "{}", g.name);
            assert_eq!(g.default_region, SearchRegion::upper_hemisphere());
        }
        assert_eq!(by_name("respeaker-4").unwrap().channels(), 4);
        assert_eq!(by_name("respeaker-6").unwrap().channels(), 6);
        assert_eq!(by_name("uma8").unwrap().channels(), 7);
        assert!(by_name("uma8").unwrap().is_planar());
        assert!(by_name("nope").is_none());
    }
}

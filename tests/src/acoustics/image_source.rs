//! Image sources of a shoebox room (Allen & Berkley, 1979).
//!
//! Along each axis of length `L`, with the source at `s` from the low wall, the
//! images sit at `2·n·L + (1 − 2q)·s` for `n ∈ ℤ`, `q ∈ {0, 1}`; such an image has
//! met the low wall `|n − q|` times and the high wall `|n|` times. Its pressure
//! gain is the product of the walls' reflection coefficients over all bounces,
//! and its reflection order the total bounce count.

use nalgebra::{Point3, Vector3};

use super::room::ShoeboxRoom;

/// One image of a source.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageSource {
    /// Image position, map frame (m).
    pub position_in_map: Point3<f64>,
    /// Product of the reflection coefficients met (1 for the direct path).
    pub gain: f64,
    /// Number of wall reflections (0 for the direct path).
    pub order: u32,
}

/// Per-axis candidate: coordinate relative to the low wall, gain, order, and
/// its distance outside `[0, L]` (0 inside).
#[derive(Clone, Copy, Debug)]
struct AxisImage {
    coord: f64,
    gain: f64,
    order: u32,
    outside: f64,
}

/// Appends to `out` (after clearing it) every image of `source_in_map` of order
/// at most `max_order` that lies within `max_distance_m` of some point of the
/// room, i.e. that can reach some receiver in the room within
/// `max_distance_m / c`. The direct path (order 0) comes first.
pub fn image_sources_into(
    room: &ShoeboxRoom,
    source_in_map: &Point3<f64>,
    max_order: u32,
    max_distance_m: f64,
    out: &mut Vec<ImageSource>,
) {
    out.clear();
    let beta = room.reflection_coefficients();
    let size = room.size_m();
    let rel = source_in_map - room.min_corner_in_map();
    let axes: [Vec<AxisImage>; 3] = std::array::from_fn(|a| {
        axis_images(size[a], rel[a], beta[2 * a], beta[2 * a + 1], max_order, max_distance_m)
    });
    let r2 = max_distance_m * max_distance_m;
    for ix in &axes[0] {
        for iy in &axes[1] {
            let oxy = ix.order + iy.order;
            let dxy = ix.outside * ix.outside + iy.outside * iy.outside;
            if oxy > max_order || dxy > r2 {
                continue;
            }
            for iz in &axes[2] {
                if oxy + iz.order > max_order || dxy + iz.outside * iz.outside > r2 {
                    continue;
                }
                out.push(ImageSource {
                    position_in_map: room.min_corner_in_map() + Vector3::new(ix.coord, iy.coord, iz.coord),
                    gain: ix.gain * iy.gain * iz.gain,
                    order: oxy + iz.order,
                });
            }
        }
    }
    // Direct path first, then by order: convenient for callers and tests.
    out.sort_by_key(|i| i.order);
}

/// [`image_sources_into`] into a new vector.
pub fn image_sources(
    room: &ShoeboxRoom,
    source_in_map: &Point3<f64>,
    max_order: u32,
    max_distance_m: f64,
) -> Vec<ImageSource> {
    let mut out = Vec::new();
    image_sources_into(room, source_in_map, max_order, max_distance_m, &mut out);
    out
}

fn axis_images(
    len: f64,
    s: f64,
    beta_lo: f64,
    beta_hi: f64,
    max_order: u32,
    max_distance_m: f64,
) -> Vec<AxisImage> {
    let n_max = (max_distance_m / (2.0 * len)).ceil() as i64 + 1;
    let mut v = Vec::with_capacity((4 * n_max + 2) as usize);
    for n in -n_max..=n_max {
        for q in 0..=1i64 {
            let lo = (n - q).unsigned_abs() as u32;
            let hi = n.unsigned_abs() as u32;
            let order = lo + hi;
            if order > max_order {
                continue;
            }
            let coord = 2.0 * n as f64 * len + (1 - 2 * q) as f64 * s;
            let outside = (-coord).max(coord - len).max(0.0);
            if outside > max_distance_m {
                continue;
            }
            v.push(AxisImage {
                coord,
                gain: beta_lo.powi(lo as i32) * beta_hi.powi(hi as i32),
                order,
                outside,
            });
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> ShoeboxRoom {
        ShoeboxRoom::with_absorption(Point3::new(1.0, -2.0, 0.0), Vector3::new(4.0, 5.0, 3.0), [0.19; 6])
            .unwrap()
    }

    #[test]
    fn first_order_images_are_mirror_images() {
        let room = room();
        let s = Point3::new(2.0, 0.5, 1.2);
        let imgs = image_sources(&room, &s, 1, 100.0);
        assert_eq!(imgs.len(), 7);
        assert_eq!(imgs[0].position_in_map, s);
        assert_eq!(imgs[0].gain, 1.0);
        let beta = (1.0f64 - 0.19).sqrt();
        let expected = [
            Point3::new(2.0 - 2.0, 0.5, 1.2),  // mirrored in x = 1
            Point3::new(5.0 + 3.0, 0.5, 1.2),  // mirrored in x = 5
            Point3::new(2.0, -2.0 - 2.5, 1.2), // mirrored in y = −2
            Point3::new(2.0, 3.0 + 2.5, 1.2),  // mirrored in y = 3
            Point3::new(2.0, 0.5, -1.2),       // floor
            Point3::new(2.0, 0.5, 3.0 + 1.8),  // ceiling
        ];
        for e in expected {
            let hit = imgs.iter().find(|i| (i.position_in_map - e).norm() < 1e-12).expect("missing image");
            assert_eq!(hit.order, 1);
            assert!((hit.gain - beta).abs() < 1e-12);
        }
    }

    #[test]
    fn image_count_grows_like_sphere_volume_over_room_volume() {
        let room = room();
        let r = 40.0;
        let imgs = image_sources(&room, &Point3::new(3.0, 1.0, 1.0), 1000, r);
        // Images within r of the room box: about the volume of the box grown by r, over V.
        let s = room.size_m();
        let grown = s.x * s.y * s.z
            + 2.0 * r * (s.x * s.y + s.y * s.z + s.x * s.z)
            + std::f64::consts::PI * r * r * (s.x + s.y + s.z)
            + 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        let expected = grown / room.volume_m3();
        let ratio = imgs.len() as f64 / expected;
        assert!((0.95..1.05).contains(&ratio), "{} images, expected about {expected:.0}", imgs.len());
    }
}

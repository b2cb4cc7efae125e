//! ODAS-like DoAs from the simulator's truth, written as ODAS's SST JSON, for
//! testing and benchmarking robots that run ODAS without running ODAS.
//!
//! ## How a DoA is made
//!
//! For each robot and each ODAS hop (`hop_len` samples at `sample_rate_hz`,
//! ODAS's defaults 128 at 16 kHz: 125 objects a second):
//!
//! 1. **Truth**: the unit vector u₀ from the array centre (pose ∘ mount) to the
//!    true source.
//! 2. **Room bias**: SRP peaks in a room are pulled toward the strongest early
//!    reflections. With u_f and u_w the directions of the source's images in
//!    the floor and in the nearest wall (first-order image sources of the
//!    shoebox room), the biased direction is normalize(u₀ + w_f·u_f + w_w·u_w).
//!    Worked numbers: array at 0.35 m, talker at 1.3 m, 3 m away: the floor
//!    image is 38° below the direct path, and w_f = 0.05 moves the peak
//!    ≈ 0.05·38°/1.05 ≈ 1.8° down. Each robot draws its weights once per run
//!    (w_f ∈ [0.03, 0.07], w_w ∈ [0.02, 0.05]): the bias depends on the
//!    geometry and persists while it holds, as a real room's does. These
//!    ranges put the closest-point method's errors on these DoAs near what it
//!    gives on real ODAS output of a two-robot reverberant trial (median
//!    ≈ 0.12 m, p95 in band ≈ 0.4 m).
//! 3. **Jitter**: a first-order autoregressive tangent rotation (σ per axis
//!    `jitter_deg`, correlation time `jitter_tau_s`), standing for ODAS's
//!    frame-to-frame peak scatter after its tracker's smoothing.
//! 4. **Grid**: the direction is expressed in the array frame and snapped to
//!    the nearest point of ODAS's scan grid, the level-4 subdivided
//!    icosahedron (2562 points, ≈ 4° apart), and printed with 3 decimals as
//!    ODAS does.
//!
//! ## The format ([`sst_object`])
//!
//! One pretty-printed object per hop, concatenated with no separator,
//! `timeStamp` counting hops from 1, a fixed number of slots (4 here, ODAS's
//! usual `nTracks`), empty slots with id 0, tag "" and zeros:
//!
//! ```text
//! {
//!     "timeStamp": 1,
//!     "src": [
//!         { "id": 1, "tag": "dynamic", "x": 0.812, "y": -0.401, "z": 0.424, "activity": 0.973 },
//!         { "id": 0, "tag": "", "x": 0.000, "y": 0.000, "z": 0.000, "activity": 0.000 },
//!         ...
//!     ]
//! }
//! ```

pub mod trial;

use nalgebra::{Isometry3, Point3, Rotation3, Unit, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// ODAS's scan grid at `level`: the icosahedron's vertices with each face
/// split into 4 `level` times (10·4^level + 2 points; 2562 at level 4).
pub fn icosphere(level: u32) -> Vec<Vector3<f64>> {
    // The same subdivision as the agent's own SRP grid.
    soundmap_agent::srp::grid::SphereGrid::icosphere(level).points().to_vec()
}

/// The grid point nearest `d` (largest dot product).
pub fn snap(grid: &[Vector3<f64>], d: &Vector3<f64>) -> Vector3<f64> {
    grid.iter().copied().max_by(|a, b| a.dot(d).total_cmp(&b.dot(d))).unwrap_or(*d)
}

/// One slot of an SST object.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SstSlot {
    /// Track id (≥ 1).
    pub id: u64,
    /// Direction, array frame (printed with 3 decimals).
    pub direction: Vector3<f64>,
    /// Activity in [0, 1].
    pub activity: f64,
}

/// One SST object exactly as ODAS prints it, with `slots` slots (the given
/// tracks first, then empty ones with id 0).
pub fn sst_object(time_stamp: u64, tracks: &[SstSlot], slots: usize) -> String {
    let mut s = format!("{{\n    \"timeStamp\": {time_stamp},\n    \"src\": [\n");
    let n = slots.max(tracks.len());
    for k in 0..n {
        let line = match tracks.get(k) {
            Some(t) => format!(
                "        {{ \"id\": {}, \"tag\": \"dynamic\", \"x\": {:.3}, \"y\": {:.3}, \"z\": {:.3}, \"activity\": {:.3} }}",
                t.id, t.direction.x, t.direction.y, t.direction.z, t.activity
            ),
            None => "        { \"id\": 0, \"tag\": \"\", \"x\": 0.000, \"y\": 0.000, \"z\": 0.000, \"activity\": 0.000 }"
                .to_string(),
        };
        s.push_str(&line);
        s.push_str(if k + 1 < n { ",\n" } else { "\n" });
    }
    s.push_str("    ]\n}\n");
    s
}

/// The error model of ODAS-like DoAs (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdasLikeModel {
    /// Grid level (ODAS: 4).
    pub level: u32,
    /// Range of the floor-image weight w_f drawn per robot.
    pub floor_weight: (f64, f64),
    /// Range of the nearest-wall-image weight w_w drawn per robot.
    pub wall_weight: (f64, f64),
    /// 1-σ per tangent axis of the jitter (degrees).
    pub jitter_deg: f64,
    /// Its correlation time (s).
    pub jitter_tau_s: f64,
}

impl Default for OdasLikeModel {
    fn default() -> Self {
        OdasLikeModel {
            level: 4,
            floor_weight: (0.03, 0.07),
            wall_weight: (0.02, 0.05),
            jitter_deg: 2.0,
            jitter_tau_s: 0.3,
        }
    }
}

/// A shoebox room `[0, size.x] × [0, size.y] × [0, size.z]` (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shoebox {
    /// Its extent (m).
    pub size: Vector3<f64>,
}

impl Shoebox {
    /// The source's image in the floor and in the wall nearest to it.
    pub fn images(&self, s: &Point3<f64>) -> (Point3<f64>, Point3<f64>) {
        let floor = Point3::new(s.x, s.y, -s.z);
        let walls = [
            (s.x, Point3::new(-s.x, s.y, s.z)),
            (self.size.x - s.x, Point3::new(2.0 * self.size.x - s.x, s.y, s.z)),
            (s.y, Point3::new(s.x, -s.y, s.z)),
            (self.size.y - s.y, Point3::new(s.x, 2.0 * self.size.y - s.y, s.z)),
        ];
        let wall = walls.iter().min_by(|a, b| a.0.total_cmp(&b.0)).map_or(floor, |w| w.1);
        (floor, wall)
    }
}

/// One robot's ODAS-like DoA generator.
#[derive(Clone, Debug)]
pub struct OdasLikeRobot {
    model: OdasLikeModel,
    floor_weight: f64,
    wall_weight: f64,
    jitter: Vector2<f64>,
    rng: ChaCha8Rng,
}

impl OdasLikeRobot {
    /// A robot's generator, its bias weights drawn from `seed`.
    pub fn new(model: OdasLikeModel, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let floor_weight = rng.random_range(model.floor_weight.0..=model.floor_weight.1);
        let wall_weight = rng.random_range(model.wall_weight.0..=model.wall_weight.1);
        let s = model.jitter_deg.to_radians();
        let jitter = Vector2::new(gauss(&mut rng) * s, gauss(&mut rng) * s);
        OdasLikeRobot { model, floor_weight, wall_weight, jitter, rng }
    }

    /// The DoA (array frame, before the grid) of the source at `source` heard
    /// from the array at `map_from_array`, `dt_s` after the previous one.
    pub fn doa(
        &mut self,
        room: &Shoebox,
        map_from_array: &Isometry3<f64>,
        source: &Point3<f64>,
        dt_s: f64,
    ) -> Vector3<f64> {
        let o = map_from_array * Point3::origin();
        let (floor, wall) = room.images(source);
        let unit = |p: Point3<f64>| (p - o).normalize();
        let biased =
            (unit(*source) + unit(floor) * self.floor_weight + unit(wall) * self.wall_weight).normalize();
        // AR(1) jitter: ρ = exp(−dt/τ), stationary σ.
        let rho = (-dt_s / self.model.jitter_tau_s.max(1e-9)).exp();
        let s = self.model.jitter_deg.to_radians() * (1.0 - rho * rho).sqrt();
        self.jitter = self.jitter * rho + Vector2::new(gauss(&mut self.rng) * s, gauss(&mut self.rng) * s);
        let d = Unit::new_normalize(biased);
        let (b1, b2) = soundmap_server::ray::tangent_basis(&d);
        let axis = b1 * self.jitter.x + b2 * self.jitter.y;
        let jittered = match Unit::try_new(d.cross(&axis), 1e-15) {
            Some(k) => Rotation3::from_axis_angle(&k, axis.norm()) * d.into_inner(),
            None => d.into_inner(),
        };
        map_from_array.rotation.inverse() * jittered
    }
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_four_has_2562_points_about_4_degrees_apart() {
        let g = icosphere(4);
        assert_eq!(g.len(), 2562);
        assert!(g.iter().all(|p| (p.norm() - 1.0).abs() < 1e-12));
        // Nearest-neighbour spacing of a few points.
        for p in g.iter().step_by(97) {
            let nearest = g
                .iter()
                .filter(|q| *q != p)
                .map(|q| p.dot(q).clamp(-1.0, 1.0).acos().to_degrees())
                .fold(f64::INFINITY, f64::min);
            assert!((3.3..=4.9).contains(&nearest), "{nearest}");
        }
        let d = Vector3::new(0.3, -0.5, 0.8).normalize();
        let q = snap(&g, &d);
        assert!(d.dot(&q).acos().to_degrees() < 2.6);
    }

    #[test]
    fn objects_have_odas_layout() {
        let s = sst_object(
            7,
            &[SstSlot { id: 3, direction: Vector3::new(0.8123, -0.4, 0.424), activity: 0.97 }],
            4,
        );
        assert!(s.starts_with("{\n    \"timeStamp\": 7,\n    \"src\": [\n"));
        assert!(s.contains("{ \"id\": 3, \"tag\": \"dynamic\", \"x\": 0.812, \"y\": -0.400, \"z\": 0.424, \"activity\": 0.970 },\n"));
        assert_eq!(s.matches("\"id\": 0").count(), 3);
        assert!(s.ends_with("0.000 }\n    ]\n}\n"));
    }

    #[test]
    fn bias_pulls_down_toward_the_floor_image() {
        let room = Shoebox { size: Vector3::new(7.0, 6.0, 3.0) };
        let model = OdasLikeModel { jitter_deg: 0.0, wall_weight: (0.0, 0.0), ..OdasLikeModel::default() };
        let mut r = OdasLikeRobot::new(model, 1);
        let array = Isometry3::translation(1.0, 3.0, 0.35);
        let source = Point3::new(4.0, 3.0, 1.3);
        let d = r.doa(&room, &array, &source, 0.008);
        let truth = (source - Point3::new(1.0, 3.0, 0.35)).normalize();
        let down = truth.z.asin().to_degrees() - d.z.asin().to_degrees();
        assert!((0.8..3.5).contains(&down), "{down}");
    }
}

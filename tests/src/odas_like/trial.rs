//! A two-robot trial with ODAS-like DoAs, written as files a user of ODAS
//! would have: per robot a TUM pose file and an SST JSON file, and the true
//! source as TUM; plus the paper's closest-point (ray-to-ray midpoint)
//! triangulation of the very same DoAs at every hop, for comparison.
//!
//! Geometry (7 × 6 × 3 m room, arrays on the robots' mounts, talker at 1.3 m):
//! robot `r1` stays near (1, 1); robot `r2` starts 0.6 m beside it (θ at the
//! source ≈ 5°) and drives at 0.15 m/s around the room's front to the far
//! side of the source (θ ≈ 90°), then stays. The talker sways ±0.2 m with a
//! 20 s period, and with [`OdasTrialSpec::walk_m_per_s`] also walks back and
//! forth along x (±1.5 m, 2 s pauses at the ends). The seed moves r1 and the
//! talker by up to ±0.3 m and draws the DoA noise.

use std::io::Write;
use std::path::Path;

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use soundmap_agent::array::ArrayGeometry;
use soundmap_server::triangulation::pair::paper_ray_to_ray;

use super::{OdasLikeModel, OdasLikeRobot, Shoebox, SstSlot, icosphere, snap, sst_object};
use crate::error::SimError;
use crate::replay::{OdasRecording, RobotRecording, TruthTrack};
use crate::runner::recording::{tum_line, write_source_tum};

/// What to generate.
#[derive(Clone, Debug, PartialEq)]
pub struct OdasTrialSpec {
    /// Length (s).
    pub duration_s: f64,
    /// Seed of the geometry jitter and the DoA noise.
    pub seed: u64,
    /// DoA error model.
    pub model: OdasLikeModel,
    /// Array preset of both robots.
    pub array: String,
    /// Walking speed of the talker (m/s): 0 keeps it in place (swaying);
    /// above 0 it walks back and forth along x, 1.5 m each side of its spot,
    /// pausing 2 s at each end (and sways on top).
    pub walk_m_per_s: f64,
}

impl Default for OdasTrialSpec {
    fn default() -> Self {
        OdasTrialSpec {
            duration_s: 60.0,
            seed: 1,
            model: OdasLikeModel::default(),
            array: "16soundsusb-pioneer".into(),
            walk_m_per_s: 0.0,
        }
    }
}

/// One closest-point estimate of the same DoAs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestPointRow {
    /// Time since the start (s).
    pub t_s: f64,
    /// True θ at the source between the arrays (degrees, 0–180).
    pub true_theta_deg: f64,
    /// Its error (m).
    pub rse_m: f64,
    /// The closest point itself (map frame, m).
    pub point: Point3<f64>,
    /// The true source at that hop (map frame, m).
    pub truth: Point3<f64>,
}

/// The files written and the comparison.
#[derive(Clone, Debug)]
pub struct OdasTrial {
    /// The robots, as `soundmap-sim replay --robot` takes them.
    pub robots: Vec<RobotRecording>,
    /// The true source.
    pub truth: TruthTrack,
    /// The paper's method on the same DoAs at every hop where both robots hear the source.
    pub closest_point: Vec<ClosestPointRow>,
}

const HOP_LEN: u32 = 128;
const RATE_HZ: u32 = 16_000;

struct Paths {
    r1: Point3<f64>,
    source: Point3<f64>,
    walk_m_per_s: f64,
}

impl Paths {
    fn robot(&self, k: usize, t: f64) -> Isometry3<f64> {
        if k == 0 {
            return pose(self.r1.x, self.r1.y, 0.9);
        }
        let way: [(f64, f64); 4] = [(1.0, 1.6), (3.0, 1.0), (5.5, 1.0), (6.0, 3.0)];
        let mut left = 0.15 * t;
        for w in way.windows(2) {
            let (a, b) = (Vector3::new(w[0].0, w[0].1, 0.0), Vector3::new(w[1].0, w[1].1, 0.0));
            let len = (b - a).norm();
            let yaw = (b.y - a.y).atan2(b.x - a.x);
            if left <= len || w[1] == way[way.len() - 1] {
                let p = a + (b - a) * (left.min(len) / len);
                return pose(p.x, p.y, yaw);
            }
            left -= len;
        }
        unreachable!("the last segment returns")
    }

    fn source(&self, t: f64) -> Point3<f64> {
        let sway = 0.2 * (std::f64::consts::TAU * t / 20.0).sin();
        self.source + Vector3::new(sway + self.walk(t), 0.0, 0.0)
    }

    /// The walk's offset along x: from 0 to +1.5 m, pause, to −1.5 m, pause, back.
    fn walk(&self, t: f64) -> f64 {
        const HALF: f64 = 1.5;
        const PAUSE_S: f64 = 2.0;
        if self.walk_m_per_s <= 0.0 {
            return 0.0;
        }
        let leg = 2.0 * HALF / self.walk_m_per_s;
        let first = HALF / self.walk_m_per_s;
        if t < first {
            return self.walk_m_per_s * t;
        }
        // Then cycles of pause, leg down, pause, leg up.
        let cycle = 2.0 * (PAUSE_S + leg);
        let u = (t - first) % cycle;
        if u < PAUSE_S {
            HALF
        } else if u < PAUSE_S + leg {
            HALF - self.walk_m_per_s * (u - PAUSE_S)
        } else if u < 2.0 * PAUSE_S + leg {
            -HALF
        } else {
            -HALF + self.walk_m_per_s * (u - 2.0 * PAUSE_S - leg)
        }
    }
}

fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
}

/// Writes `dir/r1.tum`, `dir/r1.json`, `dir/r2.*` and `dir/source.tum`.
pub fn write_trial(dir: &Path, spec: &OdasTrialSpec) -> Result<OdasTrial, SimError> {
    std::fs::create_dir_all(dir).map_err(|e| SimError::file(dir, e))?;
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut jitter = || rng.random_range(-0.3..=0.3);
    let paths = Paths {
        r1: Point3::new(1.0 + jitter(), 1.0 + jitter(), 0.0),
        source: Point3::new(3.5 + jitter(), 4.5 + jitter(), 1.3),
        walk_m_per_s: spec.walk_m_per_s,
    };
    let room = Shoebox { size: Vector3::new(7.0, 6.0, 3.0) };
    let array = ArrayGeometry::load(&spec.array)?;
    let grid = icosphere(spec.model.level);
    let hop_s = HOP_LEN as f64 / RATE_HZ as f64;
    let hops = (spec.duration_s / hop_s).floor() as u64;
    let ids = ["r1", "r2"];
    let mut robots = Vec::new();
    let mut doas: Vec<Vec<Vector3<f64>>> = Vec::new();
    for (k, id) in ids.iter().enumerate() {
        let mut generator =
            OdasLikeRobot::new(spec.model, spec.seed.wrapping_mul(7919).wrapping_add(k as u64));
        let sst_path = dir.join(format!("{id}.json"));
        let mut sst = std::io::BufWriter::new(
            std::fs::File::create(&sst_path).map_err(|e| SimError::file(&sst_path, e))?,
        );
        let mut mine = Vec::with_capacity(hops as usize);
        for h in 0..hops {
            let t = h as f64 * hop_s;
            let map_from_array = paths.robot(k, t) * array.base_from_array;
            let d = snap(&grid, &generator.doa(&room, &map_from_array, &paths.source(t), hop_s));
            // As printed: 3 decimals.
            let printed = d.map(|c| (c * 1000.0).round() / 1000.0);
            mine.push(printed);
            let slot = SstSlot { id: 1, direction: d, activity: 0.95 };
            sst.write_all(sst_object(h + 1, &[slot], 4).as_bytes())
                .map_err(|e| SimError::file(&sst_path, e))?;
        }
        sst.flush().map_err(|e| SimError::file(&sst_path, e))?;
        doas.push(mine);
        let tum_path = dir.join(format!("{id}.tum"));
        let mut tum = std::io::BufWriter::new(
            std::fs::File::create(&tum_path).map_err(|e| SimError::file(&tum_path, e))?,
        );
        let steps = (spec.duration_s * 20.0).ceil() as i64 + 1;
        for n in 0..steps {
            let ns = n * 50_000_000;
            writeln!(tum, "{}", tum_line(ns, &paths.robot(k, ns as f64 * 1e-9)))
                .map_err(|e| SimError::file(&tum_path, e))?;
        }
        tum.flush().map_err(|e| SimError::file(&tum_path, e))?;
        robots.push(RobotRecording {
            id: id.to_string(),
            audio: None,
            odas: Some(OdasRecording { path: sst_path, hop_len: HOP_LEN, sample_rate_hz: RATE_HZ }),
            poses: tum_path,
            array: spec.array.clone(),
            start_s: 0.0,
            pose_std_m: None,
            yaw_std_deg: None,
            rosbag: None,
        });
    }
    let source_path = dir.join("source.tum");
    let samples: Vec<(i64, Point3<f64>)> = (0..=(spec.duration_s * 20.0).ceil() as i64)
        .map(|n| (n * 50_000_000, paths.source(n as f64 * 0.05)))
        .collect();
    write_source_tum(&source_path, &samples)?;
    let closest_point = (0..hops as usize)
        .filter_map(|h| {
            let t = h as f64 * hop_s;
            let s = paths.source(t);
            let rays: Vec<(Point3<f64>, Unit<Vector3<f64>>)> = (0..2)
                .map(|k| {
                    let m = paths.robot(k, t) * array.base_from_array;
                    (m * Point3::origin(), Unit::new_normalize(m.rotation * doas[k][h]))
                })
                .collect();
            let p = paper_ray_to_ray(&rays[0].0, &rays[0].1, &rays[1].0, &rays[1].1)?;
            let (a, b) = ((rays[0].0 - s).normalize(), (rays[1].0 - s).normalize());
            Some(ClosestPointRow {
                t_s: t,
                true_theta_deg: a.dot(&b).clamp(-1.0, 1.0).acos().to_degrees(),
                rse_m: (p - s).norm(),
                point: p,
                truth: s,
            })
        })
        .collect();
    Ok(OdasTrial { robots, truth: TruthTrack::always(source_path), closest_point })
}

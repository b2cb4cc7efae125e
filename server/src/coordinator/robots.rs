//! What the coordinator knows about each robot: identity, connection,
//! liveness, and a short history of its rays.
//!
//! The registry is bounded: a robot's history by time (`alignment.history_ms`
//! before its newest stamp) *and* by count (`server.max_history_per_robot`, so
//! that a flood of equal stamps cannot grow it), and is dropped when the robot
//! disconnects (a disconnected robot takes no part in alignment). Robots
//! disconnected longer than `server.robot_retention_s` are forgotten, and at
//! most `server.max_robots` are known: a new one replaces the one gone longest.
//! Tracker indices of forgotten robots are given again ([`IndexPool`]) only
//! once retention has passed, long after the trackers' lag and labels forgot them.

use std::collections::VecDeque;

use nalgebra::Isometry3;
pub use soundmap_proto::monitoring::{Liveness, RobotStatus};
use soundmap_proto::{Hello, Stamp};

use super::commands::{CommandLog, ConnId};
use crate::floor_image::ArrayPattern;
use crate::ray::Ray;

/// One DoA of an observation as a ray in the map, with what else the robot
/// said of it.
#[derive(Clone, Debug)]
pub struct TaggedRay {
    /// The ray, map frame.
    pub ray: Ray,
    /// The DoA's activity, [0, 1].
    pub activity: f64,
    /// The robot-local track id.
    pub track_id: u64,
    /// The track's spectral signature (dB per band), when the robot sends one.
    pub signature: Option<std::sync::Arc<[f32]>>,
    /// The aperture of the robot's array (m: the largest distance between
    /// two of its microphones), when its hello gives their positions.
    pub aperture_m: Option<f64>,
}

/// One observation kept for alignment: the robot's rays at a stamp.
#[derive(Clone, Debug)]
pub struct StoredObservation {
    /// Acoustic time of the DoAs.
    pub stamp: Stamp,
    /// Rays of the DoAs that passed the activity threshold, map frame.
    pub rays: Vec<TaggedRay>,
    /// Receipt time (coordinator clock).
    pub received: Stamp,
}

impl StoredObservation {
    /// The ray of the most active DoA.
    pub fn dominant(&self) -> Option<&Ray> {
        self.rays.iter().max_by(|a, b| a.activity.total_cmp(&b.activity)).map(|r| &r.ray)
    }
}

/// A robot known to the coordinator.
#[derive(Debug)]
pub struct RobotEntry {
    /// Its hello (identity, array).
    pub hello: Hello,
    /// Coordinator-wide index, in order of first connection (the tracker's robot number).
    pub index: u32,
    /// The stream it is connected on, if any.
    pub conn: Option<ConnId>,
    /// Coordinator clock when last heard from.
    pub last_seen: Stamp,
    /// Stamp and sequence of the last accepted observation.
    pub last_stamp: Option<Stamp>,
    /// Sequence of the last observation on the current stream.
    pub last_sequence: Option<u64>,
    /// Pose at the last accepted observation.
    pub last_map_from_base: Option<Isometry3<f64>>,
    /// Angular σ of the dominant ray of its last observation with DoAs (rad).
    pub last_sigma_rad: Option<f64>,
    /// Recent observations, oldest first, stamps non-decreasing.
    pub history: VecDeque<StoredObservation>,
    /// Observations accepted / rejected since start.
    pub accepted: u64,
    /// Observations rejected since start.
    pub rejected: u64,
    /// Reposition commands sent to it and its reports on them.
    pub commands: CommandLog,
    /// Its array's floor-image pattern, once looked up (`Some(None)`: the array
    /// is not planar, or its hello declares no microphone positions or SRP band).
    pub pattern: Option<Option<&'static ArrayPattern>>,
    /// Its array's aperture (m), when its hello gives the microphone positions.
    pub aperture_m: Option<f64>,
}

impl RobotEntry {
    /// A robot that just said hello on `conn`; `index` numbers it.
    pub fn new(hello: Hello, index: u32, conn: ConnId, now: Stamp) -> Self {
        let aperture_m = hello.array.aperture_m();
        RobotEntry {
            hello,
            index,
            conn: Some(conn),
            last_seen: now,
            last_stamp: None,
            last_sequence: None,
            last_map_from_base: None,
            last_sigma_rad: None,
            history: VecDeque::new(),
            accepted: 0,
            rejected: 0,
            commands: CommandLog::default(),
            pattern: None,
            aperture_m,
        }
    }

    /// What monitoring reports of it, given its liveness.
    pub fn status(&self, liveness: Liveness) -> RobotStatus<'_> {
        RobotStatus {
            robot_id: &self.hello.robot_id,
            liveness,
            last_seen: self.last_seen,
            last_observation: self.last_stamp,
            map_from_base: self.last_map_from_base,
            array: &self.hello.array,
            software_version: &self.hello.software_version,
            base_limits: self.hello.base_limits,
            observations_accepted: self.accepted,
            observations_rejected: self.rejected,
            active_command: self.commands.current.as_ref().map(|(c, s)| (c, *s)),
        }
    }

    /// Liveness at `now` given the stale timeout.
    pub fn liveness(&self, now: Stamp, stale_after_ns: i64) -> Liveness {
        match self.conn {
            None => Liveness::Disconnected,
            Some(_) if now - self.last_seen > stale_after_ns => Liveness::Stale,
            Some(_) => Liveness::Live,
        }
    }

    /// Appends an observation and forgets those older than `history_ns` before
    /// it, and the oldest beyond `max_len`. Returns how many the count bound dropped.
    pub fn remember(&mut self, obs: StoredObservation, history_ns: i64, max_len: usize) -> usize {
        let horizon = obs.stamp.plus_ns(-history_ns);
        self.history.push_back(obs);
        while self.history.front().is_some_and(|o| o.stamp < horizon) {
            self.history.pop_front();
        }
        let over = self.history.len().saturating_sub(max_len.max(1));
        self.history.drain(..over);
        over
    }

    /// Whether it is disconnected and was last heard more than `retention_ns` before `now`.
    pub fn gone_longer_than(&self, now: Stamp, retention_ns: i64) -> bool {
        self.conn.is_none() && now - self.last_seen > retention_ns
    }

    /// The kept observation with a dominant ray nearest to `t`, if within
    /// `window_ns`: of the [`NEAREST_SPAN`] kept on either side of `t`, the
    /// nearest with rays (the earlier on a tie).
    pub fn nearest(&self, t: Stamp, window_ns: i64) -> Option<&StoredObservation> {
        nearest_in(&self.history, t, window_ns)
    }
}

/// [`RobotEntry::nearest`] in a history sorted by stamp.
fn nearest_in(history: &VecDeque<StoredObservation>, t: Stamp, window_ns: i64) -> Option<&StoredObservation> {
    // `t` is usually the newest stamp of all, at or after this robot's
    // newest: then the insertion point is the end, without a search.
    let len = history.len();
    let i = match history.back() {
        Some(last) if last.stamp < t => len,
        _ => history.partition_point(|o| o.stamp < t),
    };
    let has_ray = |o: &&StoredObservation| !o.rays.is_empty();
    let within = |o: &&StoredObservation| (o.stamp - t).abs() <= window_ns;
    // The nearest with rays before `t` and at or after it, walking out from `t`.
    let before = history.range(i.saturating_sub(NEAREST_SPAN)..i).rev().find(has_ray).filter(within);
    let after = history.range(i..(i + NEAREST_SPAN).min(len)).find(has_ray).filter(within);
    match (before, after) {
        (Some(b), Some(a)) => Some(if (a.stamp - t).abs() < (b.stamp - t).abs() { a } else { b }),
        (b, a) => b.or(a),
    }
}

/// How many kept observations on either side of a stamp [`RobotEntry::nearest`] looks at.
pub const NEAREST_SPAN: usize = 8;

/// Tracker indices of robots: the smallest free one is given, so indices stay
/// below the number of robots known at once.
#[derive(Clone, Debug, Default)]
pub struct IndexPool {
    next: u32,
    free: std::collections::BTreeSet<u32>,
}

impl IndexPool {
    /// A pool where `used` are taken.
    pub fn with_used(used: impl IntoIterator<Item = u32>) -> Self {
        let used: std::collections::BTreeSet<u32> = used.into_iter().collect();
        let next = used.last().map_or(0, |m| m + 1);
        IndexPool { next, free: (0..next).filter(|i| !used.contains(i)).collect() }
    }

    /// A free index.
    pub fn take(&mut self) -> u32 {
        if let Some(i) = self.free.pop_first() {
            return i;
        }
        self.next += 1;
        self.next - 1
    }

    /// Gives `index` back.
    pub fn give_back(&mut self, index: u32) {
        self.free.insert(index);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_pool_reuses_the_smallest_free_index() {
        let mut p = IndexPool::with_used([0, 2]);
        assert_eq!(p.take(), 1);
        assert_eq!(p.take(), 3);
        p.give_back(0);
        assert_eq!(p.take(), 0);
        assert_eq!(p.take(), 4);
    }

    /// The nearest observation with rays among the `NEAREST_SPAN` on either
    /// side of the insertion point, by a plain scan (the earlier on a tie).
    fn nearest_by_scan(history: &VecDeque<StoredObservation>, t: Stamp, window_ns: i64) -> Option<Stamp> {
        let i = history.iter().filter(|o| o.stamp < t).count();
        let lo = i.saturating_sub(NEAREST_SPAN);
        let hi = (i + NEAREST_SPAN).min(history.len());
        let mut best: Option<&StoredObservation> = None;
        for o in history.range(lo..hi) {
            if o.rays.is_empty() || (o.stamp - t).abs() > window_ns {
                continue;
            }
            if best.is_none_or(|b| (o.stamp - t).abs() < (b.stamp - t).abs()) {
                best = Some(o);
            }
        }
        best.map(|o| o.stamp)
    }

    #[test]
    fn nearest_agrees_with_a_plain_scan() {
        use nalgebra::{Point3, Unit, Vector3};
        let ray = TaggedRay {
            ray: Ray {
                origin_in_map: Point3::origin(),
                direction_in_map: Unit::new_normalize(Vector3::x()),
                sigma_rad: 0.01,
                origin_sigma_m: 0.0,
                fold: None,
            },
            activity: 1.0,
            track_id: 1,
            signature: None,
            aperture_m: None,
        };
        // Stamps 10 ms apart with gaps and equal neighbours; some without rays.
        let mut state = 7u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            state >> 33
        };
        for _ in 0..40 {
            let mut history = VecDeque::new();
            let mut stamp = 1_000_000_000i64;
            for _ in 0..(next() % 30) {
                stamp += [0, 5_000_000, 10_000_000, 40_000_000][(next() % 4) as usize];
                let rays = if next() % 3 == 0 { vec![] } else { vec![ray.clone()] };
                history.push_back(StoredObservation {
                    stamp: Stamp::from_ns(stamp),
                    rays,
                    received: Stamp::from_ns(stamp),
                });
            }
            for _ in 0..50 {
                let t = Stamp::from_ns(1_000_000_000 + (next() % 500) as i64 * 1_000_000);
                for window_ns in [0, 5_000_000, 25_000_000, 1_000_000_000] {
                    assert_eq!(
                        nearest_in(&history, t, window_ns).map(|o| o.stamp),
                        nearest_by_scan(&history, t, window_ns),
                        "t {t:?} window {window_ns}"
                    );
                }
            }
        }
    }
}

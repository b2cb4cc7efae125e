//! The source tracker inside the coordinator: every live robot's dominant DoA
//! goes to the [`SourceTracker`], a track starts from a trusted triangulation
//! when there is none (or it was lost), and each estimate carries the track's
//! state beside the triangulation.
//!
//! DoAs are queued as observations arrive and applied in stamp order once per
//! batch ([`Tracking::flush`], called by the coordinator's `estimate` and
//! `tick`) up to a *watermark*: the oldest of the robots' latest observation
//! stamps. Each robot's stamps never decrease (validation enforces it), so no
//! DoA can arrive later stamped below the watermark: applied this way, DoAs
//! never arrive late at the tracker and it never re-runs its lag buffer
//! (which, with many robots streaming fast, costs far more than the updates).
//! The watermark waits at most [`MAX_HOLD_MS`] for a slow or silent robot.
//! The tracker's fixed-lag buffer still applies exactly whatever arrives late
//! anyway (a robot seen for the first time, one that waited longer).
//! Queuing also lets DoAs that arrive in the batch that starts a track, but
//! are stamped after its start, update it.

use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

use soundmap_proto::Stamp;

use crate::ray::Ray;
use crate::tracking::{InitOutcome, SourceTracker, TrackEstimate, TrackerConfig, UpdateOutcome};
use crate::triangulation::Triangulation;

/// What became of the DoAs given to the tracker since the coordinator started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TrackingCounters {
    /// Tracks started.
    pub tracks_started: u64,
    /// DoAs applied.
    pub applied: u64,
    /// DoAs rejected by the χ² gate.
    pub gated: u64,
    /// DoAs refused for any other reason: no track, before its start, too late, unusable.
    pub unused: u64,
    /// DoAs not given to the tracker because of the per-robot rate limit.
    pub skipped: u64,
}

/// A queued DoA, ordered by stamp then arrival.
#[derive(Debug)]
struct Queued {
    stamp: Stamp,
    arrival: u64,
    robot: u32,
    ray: Ray,
}

impl PartialEq for Queued {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Queued {}

impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Queued {
    fn cmp(&self, other: &Self) -> Ordering {
        (self.stamp, self.arrival).cmp(&(other.stamp, other.arrival))
    }
}

/// Longest a queued DoA waits for slower robots before it is applied (ms):
/// the filtered state is at most this much behind the newest DoA.
pub const MAX_HOLD_MS: i64 = 100;

/// Stamp up to which queued DoAs can be applied at `now`: the oldest of the
/// robots' latest stamps (`latest`), held at most [`MAX_HOLD_MS`] behind the
/// newest stamp and behind `now` (see the module docs).
pub(crate) fn watermark(latest: &[Option<Stamp>], newest: Option<Stamp>, now: Stamp) -> Option<Stamp> {
    let newest = newest?;
    let hold_ns = MAX_HOLD_MS * 1_000_000;
    let slowest = latest.iter().flatten().min().copied().unwrap_or(newest);
    Some(slowest.max(newest.plus_ns(-hold_ns)).max(newest.min(now.plus_ns(-hold_ns))))
}

/// The coordinator's tracker and its queue of DoAs.
#[derive(Debug)]
pub struct Tracking {
    /// `None` when `[tracking] enabled = false`.
    tracker: Option<SourceTracker>,
    /// DoAs not yet applied, oldest on top.
    queue: BinaryHeap<Reverse<Queued>>,
    /// Arrival counter (equal stamps are applied in arrival order).
    arrivals: u64,
    /// Latest observation stamp per robot index.
    latest: Vec<Option<Stamp>>,
    /// Newest observation stamp of any robot.
    newest: Option<Stamp>,
    /// Stamp of the last DoA queued per robot index (rate limit).
    last_queued: Vec<Option<Stamp>>,
    /// Shortest interval between two DoAs of a robot given to the tracker (ns).
    min_interval_ns: i64,
    counters: TrackingCounters,
}

impl Tracking {
    /// A tracker with no track, or none at all when `config.enabled` is false.
    pub fn new(config: &TrackerConfig) -> Self {
        Tracking {
            tracker: config.enabled.then(|| SourceTracker::new(config.clone())),
            queue: BinaryHeap::new(),
            arrivals: 0,
            latest: Vec::new(),
            newest: None,
            last_queued: Vec::new(),
            min_interval_ns: if config.max_doa_rate_hz > 0.0 {
                (1e9 / config.max_doa_rate_hz) as i64
            } else {
                0
            },
            counters: TrackingCounters::default(),
        }
    }

    /// Whether tracking is on.
    pub fn enabled(&self) -> bool {
        self.tracker.is_some()
    }

    /// Counters since start.
    pub fn counters(&self) -> TrackingCounters {
        self.counters
    }

    /// Robot `robot` sent an observation stamped `stamp` (with or without DoAs):
    /// it will send nothing older.
    pub fn note_stamp(&mut self, robot: u32, stamp: Stamp) {
        if self.tracker.is_none() {
            return;
        }
        let i = robot as usize;
        if self.latest.len() <= i {
            self.latest.resize(i + 1, None);
        }
        self.latest[i] = Some(self.latest[i].map_or(stamp, |l| l.max(stamp)));
        self.newest = Some(self.newest.map_or(stamp, |n| n.max(stamp)));
    }

    /// Robot `robot` is gone (stream closed): the watermark no longer waits for it.
    pub fn forget_robot(&mut self, robot: u32) {
        if let Some(l) = self.latest.get_mut(robot as usize) {
            *l = None;
        }
    }

    /// Queues the dominant DoA ray (map frame) of robot `robot` stamped `stamp`,
    /// unless that robot's previous one was queued less than
    /// 1/`max_doa_rate_hz` earlier (see [`TrackerConfig::max_doa_rate_hz`]).
    pub fn push(&mut self, stamp: Stamp, robot: u32, ray: Ray) {
        if self.tracker.is_some() {
            let i = robot as usize;
            if self.last_queued.len() <= i {
                self.last_queued.resize(i + 1, None);
            }
            if self.last_queued[i].is_some_and(|last| stamp - last < self.min_interval_ns && stamp >= last) {
                self.counters.skipped += 1;
                return;
            }
            self.last_queued[i] = Some(stamp);
            self.arrivals += 1;
            self.queue.push(Reverse(Queued { stamp, arrival: self.arrivals, robot, ray }));
        }
    }

    /// Stamp up to which queued DoAs can be applied at `now` (see the module docs).
    fn watermark(&self, now: Stamp) -> Option<Stamp> {
        watermark(&self.latest, self.newest, now)
    }

    /// Starts a track from `triangulation` (whose newest ray is stamped `stamp`)
    /// when there is none or it was lost and the triangulation's gate accepted it.
    pub fn start_if_needed(&mut self, stamp: Stamp, triangulation: &Triangulation) -> Option<InitOutcome> {
        let tracker = self.tracker.as_mut().filter(|t| t.needs_track())?;
        let outcome = tracker.initialize_from_triangulation(stamp, triangulation);
        if let InitOutcome::Started { track_id } = outcome {
            self.counters.tracks_started += 1;
            tracing::debug!(track_id, "source track started from a triangulation");
        }
        Some(outcome)
    }

    /// Applies the queued DoAs up to the watermark at `now`, in stamp order.
    pub fn flush(&mut self, now: Stamp) {
        let Some(watermark) = self.watermark(now) else { return };
        let Some(tracker) = self.tracker.as_mut() else { return };
        while self.queue.peek().is_some_and(|q| q.0.stamp <= watermark) {
            let Some(Reverse(q)) = self.queue.pop() else { break };
            match tracker.update(q.stamp, q.robot, &q.ray) {
                UpdateOutcome::Applied { .. } => self.counters.applied += 1,
                UpdateOutcome::Gated { .. } => self.counters.gated += 1,
                _ => self.counters.unused += 1,
            }
        }
    }

    /// Lifecycle timeouts at `now`.
    pub fn maintain(&mut self, now: Stamp) {
        if let Some(t) = self.tracker.as_mut() {
            t.maintain(now);
        }
    }

    /// The track predicted to `stamp` (or its newest state, if `stamp` is older), if any.
    pub fn estimate_at(&self, stamp: Stamp) -> Option<TrackEstimate> {
        self.tracker.as_ref()?.predict_to(stamp)
    }

    /// Id of the live (not lost) track, if any.
    pub fn live_track_id(&self) -> Option<u64> {
        let t = self.tracker.as_ref().filter(|t| !t.needs_track())?;
        t.estimate().map(|e| e.track_id)
    }
}

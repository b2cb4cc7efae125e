//! The source tracker inside the coordinator: every live robot's dominant DoA
//! goes to the [`SourceTracker`], a track starts from a trusted triangulation
//! (or one only too uncertain at a good geometry) when there is none (or it
//! was lost), and each estimate carries the track's state beside the
//! triangulation.
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

use soundmap_proto::Stamp;

use crate::ray::Ray;
use crate::tracking::{
    InitOutcome, SmoothedEstimate, SourceTracker, TrackEstimate, TrackerConfig, UpdateOutcome,
};
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
    /// Tracks restarted because they started from a poor geometry and a good one came.
    pub restarts: u64,
}

use super::doa_queue::DoaQueue;
pub use super::doa_queue::MAX_HOLD_MS;

/// The coordinator's tracker and its queue of DoAs.
#[derive(Debug)]
pub struct Tracking {
    /// `None` when `[tracking] enabled = false`.
    tracker: Option<SourceTracker>,
    /// DoAs not yet applied, at most `max_doa_rate_hz` per robot.
    queue: DoaQueue<Ray>,
    counters: TrackingCounters,
    /// Source ids published for the tracks (kept across restarts).
    pub ids: super::source_ids::SourceIds,
}

impl Tracking {
    /// A tracker with no track, or none at all when `config.enabled` is false.
    pub fn new(config: &TrackerConfig) -> Self {
        Tracking {
            tracker: config.enabled.then(|| SourceTracker::new(config.clone())),
            queue: DoaQueue::new(config.max_doa_rate_hz),
            counters: TrackingCounters::default(),
            ids: Default::default(),
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
        if self.tracker.is_some() {
            self.queue.note_stamp(robot, stamp);
        }
    }

    /// Robot `robot` is gone (stream closed): the watermark no longer waits for it.
    pub fn forget_robot(&mut self, robot: u32) {
        self.queue.forget_robot(robot);
    }

    /// Queues the dominant DoA ray (map frame) of robot `robot` stamped `stamp`,
    /// unless that robot's previous one was queued less than
    /// 1/`max_doa_rate_hz` earlier (see [`TrackerConfig::max_doa_rate_hz`]).
    pub fn push(&mut self, stamp: Stamp, robot: u32, ray: Ray) {
        if self.tracker.is_some() && !self.queue.push(stamp, robot, ray) {
            self.counters.skipped += 1;
        }
    }

    /// Starts a track from `triangulation` (whose newest ray is stamped `stamp`)
    /// when there is none or it was lost and the triangulation's gate accepted it.
    ///
    /// A live track that started from a poor geometry and has seen no good one
    /// since restarts from `triangulation` when it is accepted at a good θ
    /// ([`SourceTracker::should_restart_from`]): its biased start would
    /// otherwise be carried on.
    pub fn start_if_needed(&mut self, stamp: Stamp, triangulation: &Triangulation) -> Option<InitOutcome> {
        let tracker = self.tracker.as_mut()?;
        let restart = !tracker.needs_track() && tracker.should_restart_from(triangulation);
        if !(tracker.needs_track() || restart) {
            return None;
        }
        let outcome = tracker.initialize_from_triangulation(stamp, triangulation);
        if let InitOutcome::Started { track_id } = outcome {
            self.counters.tracks_started += 1;
            self.ids.started(track_id, triangulation.solution().map(|s| s.source_in_map), stamp);
            if restart {
                self.counters.restarts += 1;
            }
            tracing::debug!(track_id, restart, "source track started from a triangulation");
        }
        Some(outcome)
    }

    /// Applies the queued DoAs up to the watermark at `now`, in stamp order.
    pub fn flush(&mut self, now: Stamp) {
        let Some(watermark) = self.queue.watermark(now) else { return };
        let Some(tracker) = self.tracker.as_mut() else { return };
        while let Some(q) = self.queue.pop_until(watermark) {
            match tracker.update(q.stamp, q.robot, &q.item) {
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

    /// The track's fixed-lag smoothed state, if any.
    pub fn smoothed(&self) -> Option<SmoothedEstimate> {
        self.tracker.as_ref()?.smoothed()
    }

    /// The track's newest estimate, lost or not.
    pub fn track_estimate(&self) -> Option<TrackEstimate> {
        self.tracker.as_ref()?.estimate()
    }

    /// Source id of the live (not lost) track, if any.
    pub fn live_track_id(&self) -> Option<u64> {
        let t = self.tracker.as_ref().filter(|t| !t.needs_track())?;
        t.estimate().map(|e| self.ids.source_of(e.track_id).unwrap_or(e.track_id))
    }
}

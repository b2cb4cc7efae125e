//! The source tracker inside the coordinator: every live robot's dominant DoA
//! goes to the [`SourceTracker`], a track starts from a trusted triangulation
//! when there is none (or it was lost), and each estimate carries the track's
//! state beside the triangulation.
//!
//! DoAs are queued as observations arrive and applied in stamp order once per
//! batch ([`Tracking::flush`], called by the coordinator's `estimate` and
//! `tick`). The tracker's fixed-lag buffer makes the result independent of the
//! order; sorting only spares it re-running the DoAs that a late one precedes.
//! It also lets DoAs that arrive in the batch that starts a track, but are
//! stamped after its start, update it.

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
}

/// The coordinator's tracker and its queue of DoAs.
#[derive(Debug)]
pub struct Tracking {
    /// `None` when `[tracking] enabled = false`.
    tracker: Option<SourceTracker>,
    /// DoAs not yet applied: (stamp, robot index, ray).
    queue: Vec<(Stamp, u32, Ray)>,
    counters: TrackingCounters,
}

impl Tracking {
    /// A tracker with no track, or none at all when `config.enabled` is false.
    pub fn new(config: &TrackerConfig) -> Self {
        Tracking {
            tracker: config.enabled.then(|| SourceTracker::new(config.clone())),
            queue: Vec::new(),
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

    /// Queues the dominant DoA ray (map frame) of robot `robot` stamped `stamp`.
    pub fn push(&mut self, stamp: Stamp, robot: u32, ray: Ray) {
        if self.tracker.is_some() {
            self.queue.push((stamp, robot, ray));
        }
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

    /// Applies the queued DoAs in stamp order.
    pub fn flush(&mut self) {
        let Some(tracker) = self.tracker.as_mut() else { return };
        // Stable: equal stamps keep their arrival order.
        self.queue.sort_by_key(|d| d.0);
        for (stamp, robot, ray) in self.queue.drain(..) {
            match tracker.update(stamp, robot, &ray) {
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

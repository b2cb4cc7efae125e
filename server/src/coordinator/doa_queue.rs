//! DoAs waiting for the trackers: applied in stamp order up to a watermark
//! (see [`super::tracking`]'s docs), at most `max_doa_rate_hz` per robot.
//! One queue type for the single-source tracker (payload: a ray) and the
//! sound map (payload: an observation's rays).

use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

use soundmap_proto::Stamp;

/// Longest a queued DoA waits for slower robots before it is applied (ms):
/// the filtered state is at most this much behind the newest DoA.
pub const MAX_HOLD_MS: i64 = 100;

/// A queued item of robot `robot`, ordered by stamp then arrival.
#[derive(Debug)]
pub struct Queued<T> {
    /// Stamp of the DoA(s).
    pub stamp: Stamp,
    arrival: u64,
    /// Robot index.
    pub robot: u32,
    /// What is queued.
    pub item: T,
}

impl<T> PartialEq for Queued<T> {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl<T> Eq for Queued<T> {}

impl<T> PartialOrd for Queued<T> {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl<T> Ord for Queued<T> {
    fn cmp(&self, other: &Self) -> Ordering {
        (self.stamp, self.arrival).cmp(&(other.stamp, other.arrival))
    }
}

/// The queue, the robots' latest stamps (for the watermark) and the per-robot rate limit.
#[derive(Debug)]
pub struct DoaQueue<T> {
    /// Items not yet applied, oldest on top.
    queue: BinaryHeap<Reverse<Queued<T>>>,
    /// Arrival counter (equal stamps are applied in arrival order).
    arrivals: u64,
    /// Latest observation stamp per robot index.
    latest: Vec<Option<Stamp>>,
    /// Newest observation stamp of any robot.
    newest: Option<Stamp>,
    /// Stamp of the last item queued per robot index (rate limit).
    last_queued: Vec<Option<Stamp>>,
    /// Shortest interval between two items of a robot (ns).
    min_interval_ns: i64,
}

impl<T> DoaQueue<T> {
    /// An empty queue admitting at most `max_rate_hz` items per robot per
    /// second (0: every item).
    pub fn new(max_rate_hz: f64) -> Self {
        DoaQueue {
            queue: BinaryHeap::new(),
            arrivals: 0,
            latest: Vec::new(),
            newest: None,
            last_queued: Vec::new(),
            min_interval_ns: if max_rate_hz > 0.0 { (1e9 / max_rate_hz) as i64 } else { 0 },
        }
    }

    /// Robot `robot` sent an observation stamped `stamp` (with or without DoAs):
    /// it will send nothing older.
    pub fn note_stamp(&mut self, robot: u32, stamp: Stamp) {
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

    /// Queues `item` of robot `robot` stamped `stamp`, unless that robot's
    /// previous item was queued less than 1/`max_rate_hz` earlier. Returns
    /// whether it was queued.
    pub fn push(&mut self, stamp: Stamp, robot: u32, item: T) -> bool {
        let i = robot as usize;
        if self.last_queued.len() <= i {
            self.last_queued.resize(i + 1, None);
        }
        if self.last_queued[i].is_some_and(|last| stamp - last < self.min_interval_ns && stamp >= last) {
            return false;
        }
        self.last_queued[i] = Some(stamp);
        self.arrivals += 1;
        self.queue.push(Reverse(Queued { stamp, arrival: self.arrivals, robot, item }));
        true
    }

    /// Stamp up to which queued items can be applied at `now`: the oldest of
    /// the robots' latest stamps, held at most [`MAX_HOLD_MS`] behind the
    /// newest stamp and behind `now`.
    pub fn watermark(&self, now: Stamp) -> Option<Stamp> {
        let newest = self.newest?;
        let hold_ns = MAX_HOLD_MS * 1_000_000;
        let slowest = self.latest.iter().flatten().min().copied().unwrap_or(newest);
        Some(slowest.max(newest.plus_ns(-hold_ns)).max(newest.min(now.plus_ns(-hold_ns))))
    }

    /// The oldest queued item if it is stamped at or before `watermark`.
    pub fn pop_until(&mut self, watermark: Stamp) -> Option<Queued<T>> {
        if self.queue.peek().is_some_and(|q| q.0.stamp <= watermark) {
            self.queue.pop().map(|Reverse(q)| q)
        } else {
            None
        }
    }
}

//! A fixed-lag buffer that applies out-of-sequence measurements exactly
//! (theory §4.4).
//!
//! The buffer keeps, in time order, every measurement of the last `lag` together
//! with the filter state right after it (a snapshot), and the state before the
//! oldest one (the base). A measurement stamped before the newest is inserted in
//! order; the filter restarts from the snapshot just before it and re-runs the
//! later measurements. The result is the one in-order processing would have given,
//! bit for bit: the filter only ever sees the sorted sequence.
//!
//! Order is by stamp, then by the observation's own total order (`O: Ord`), so
//! equal stamps are also replayed in one order whatever their arrival order.
//! A measurement older than `newest − lag`, or not after an entry already pruned
//! into the base, is [`Refusal::TooLate`]; one not after the start (the track's
//! initialization) is [`Refusal::BeforeStart`]. Neither changes anything.
//!
//! The buffer is generic over the observation `O`, the snapshot `S` and the
//! step function, so it can be tested with toy states. It allocates its
//! capacity once, in [`LagBuffer::new`].

use std::collections::VecDeque;

use soundmap_proto::Stamp;

#[derive(Clone, Debug)]
struct Entry<O, S> {
    stamp: Stamp,
    observation: O,
    /// State after this observation.
    after: S,
}

/// What became of an inserted observation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Insertion<R> {
    /// Processed in order; `result` is what the step returned for it and
    /// `replayed` how many later observations were re-run after it.
    Processed {
        /// The step's result for this observation.
        result: R,
        /// Later observations re-run because this one arrived late.
        replayed: usize,
    },
    /// Not inserted.
    Refused(Refusal),
}

/// Why an observation cannot be inserted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Older than the lag (or than an entry already pruned): dropped.
    TooLate,
    /// Stamped at or before the start of the buffer: dropped.
    BeforeStart,
}

/// Time-ordered measurements of the last `lag` with the state after each.
#[derive(Clone, Debug)]
pub struct LagBuffer<O, S> {
    base: S,
    base_stamp: Stamp,
    start: Stamp,
    pruned_through: Option<Stamp>,
    entries: VecDeque<Entry<O, S>>,
    lag_ns: i64,
    capacity: usize,
}

impl<O: Ord, S> LagBuffer<O, S> {
    /// An empty buffer whose state is `start_state` at `start`. At most
    /// `capacity` (≥ 1) observations are kept even when more fall within the lag.
    pub fn new(start_state: S, start: Stamp, lag_ns: i64, capacity: usize) -> Self {
        let capacity = capacity.max(1);
        LagBuffer {
            base: start_state,
            base_stamp: start,
            start,
            pruned_through: None,
            entries: VecDeque::with_capacity(capacity + 1),
            lag_ns: lag_ns.max(0),
            capacity,
        }
    }

    /// The newest state and the stamp of the newest observation (or the start).
    pub fn latest(&self) -> (&S, Stamp) {
        self.entries.back().map_or((&self.base, self.base_stamp), |e| (&e.after, e.stamp))
    }

    /// The stamp of the newest observation, or the start when there is none.
    pub fn time(&self) -> Stamp {
        self.latest().1
    }

    /// The start stamp (observations must be strictly after it).
    pub fn start(&self) -> Stamp {
        self.start
    }

    /// The state before the oldest buffered observation (after the last
    /// pruned one, or the start state) and its stamp.
    pub fn base(&self) -> (&S, Stamp) {
        (&self.base, self.base_stamp)
    }

    /// The buffered states in time order, each after its observation, with its stamp.
    pub fn states(&self) -> impl Iterator<Item = (&S, Stamp)> {
        self.entries.iter().map(|e| (&e.after, e.stamp))
    }

    /// Observations held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when no observation is held.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Whether an observation stamped `stamp` could be inserted now, and if not why.
    pub fn admits(&self, stamp: Stamp) -> Result<(), Refusal> {
        if stamp <= self.start {
            Err(Refusal::BeforeStart)
        } else if stamp < self.time().plus_ns(-self.lag_ns) || self.pruned_through.is_some_and(|p| stamp <= p)
        {
            Err(Refusal::TooLate)
        } else {
            Ok(())
        }
    }

    /// The state in force just before an observation stamped `stamp` (the
    /// state after the last held observation stamped at or before it), with
    /// its stamp; `None` when such an observation could not be inserted.
    pub fn state_before(&self, stamp: Stamp) -> Option<(&S, Stamp)> {
        self.admits(stamp).ok()?;
        let i = self.entries.partition_point(|e| e.stamp <= stamp);
        Some(if i == 0 {
            (&self.base, self.base_stamp)
        } else {
            (&self.entries[i - 1].after, self.entries[i - 1].stamp)
        })
    }

    /// Inserts `observation` in time order and (re)runs `step` from the state
    /// before it: `step(state_before, stamp, observation) -> (state_after, result)`.
    pub fn insert<R>(
        &mut self,
        stamp: Stamp,
        observation: O,
        mut step: impl FnMut(&S, Stamp, &O) -> (S, R),
    ) -> Insertion<R> {
        if let Err(refusal) = self.admits(stamp) {
            return Insertion::Refused(refusal);
        }
        let at = self.entries.partition_point(|e| (e.stamp, &e.observation) <= (stamp, &observation));
        let before = if at == 0 { &self.base } else { &self.entries[at - 1].after };
        let (after, result) = step(before, stamp, &observation);
        self.entries.insert(at, Entry { stamp, observation, after });
        for j in at + 1..self.entries.len() {
            let (after, _) = {
                let (prev, this) = (&self.entries[j - 1], &self.entries[j]);
                step(&prev.after, this.stamp, &this.observation)
            };
            self.entries[j].after = after;
        }
        let replayed = self.entries.len() - at - 1;
        self.prune();
        Insertion::Processed { result, replayed }
    }

    /// Folds entries older than `newest − lag` (and any beyond the capacity)
    /// into the base.
    fn prune(&mut self) {
        let horizon = self.time().plus_ns(-self.lag_ns);
        while let Some(front) = self.entries.front() {
            if !(front.stamp < horizon || self.entries.len() > self.capacity) {
                break;
            }
            let e = self.entries.pop_front().expect("front exists");
            self.base = e.after;
            self.base_stamp = e.stamp;
            self.pruned_through = Some(e.stamp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A toy state: the sequence of observations seen, in processing order.
    #[allow(clippy::ptr_arg)] // the step takes `&S`
    fn step(s: &Vec<(i64, u32)>, t: Stamp, o: &u32) -> (Vec<(i64, u32)>, usize) {
        let mut s = s.clone();
        s.push((t.as_ns(), *o));
        let n = s.len();
        (s, n)
    }

    #[test]
    fn late_observations_are_replayed_in_order() {
        let mut b = LagBuffer::new(Vec::new(), Stamp::from_ns(0), 100, 64);
        for (t, o) in [(10, 1), (30, 2), (20, 3), (40, 4), (20, 0), (35, 5)] {
            assert!(matches!(b.insert(Stamp::from_ns(t), o, step), Insertion::Processed { .. }));
        }
        assert_eq!(b.latest().0, &vec![(10, 1), (20, 0), (20, 3), (30, 2), (35, 5), (40, 4)]);
        assert_eq!(b.time(), Stamp::from_ns(40));
        // The state before 30 is the one after the two stamped 20.
        assert_eq!(b.state_before(Stamp::from_ns(30)).unwrap().0.len(), 4);
    }

    #[test]
    fn too_late_and_before_start_change_nothing() {
        let mut b = LagBuffer::new(Vec::new(), Stamp::from_ns(5), 100, 64);
        assert_eq!(b.insert(Stamp::from_ns(5), 9, step), Insertion::Refused(Refusal::BeforeStart));
        for t in [10, 120, 200] {
            b.insert(Stamp::from_ns(t), 1, step);
        }
        // 200 − 100 = 100: 99 is too late, 100 is not; 10 was pruned into the base.
        assert_eq!(b.insert(Stamp::from_ns(99), 2, step), Insertion::Refused(Refusal::TooLate));
        assert_eq!(b.len(), 2);
        assert!(matches!(b.insert(Stamp::from_ns(100), 2, step), Insertion::Processed { replayed: 2, .. }));
        assert_eq!(b.latest().0, &vec![(10, 1), (100, 2), (120, 1), (200, 1)]);
    }

    #[test]
    fn capacity_prunes_early_and_refuses_what_it_no_longer_holds() {
        let mut b = LagBuffer::new(Vec::new(), Stamp::from_ns(0), 1_000, 3);
        for t in 1..=5 {
            b.insert(Stamp::from_ns(t * 10), 0, step);
        }
        assert_eq!(b.len(), 3);
        assert_eq!(b.insert(Stamp::from_ns(15), 0, step), Insertion::Refused(Refusal::TooLate));
        assert!(matches!(b.insert(Stamp::from_ns(35), 0, step), Insertion::Processed { replayed: 2, .. }));
        assert_eq!(b.latest().0.len(), 6);
    }
}

//! The agent core's bounded buffer of observations awaiting acknowledgement. Pure.

use std::collections::VecDeque;

use soundmap_proto::Observation;

/// Observations from the time they are produced until the coordinator
/// acknowledges them, in sequence order, with what has been sent on the current
/// stream. Sequence numbers are assigned here, from 1, and never reused, so they
/// increase across reconnections too.
#[derive(Clone, Debug)]
pub struct ObservationBuffer {
    capacity: usize,
    items: VecDeque<Observation>,
    next_sequence: u64,
    /// Highest sequence sent on the current stream.
    sent_up_to: u64,
    dropped: u64,
}

impl ObservationBuffer {
    /// Holds at most `capacity` (≥ 1) observations.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        ObservationBuffer {
            capacity,
            items: VecDeque::with_capacity(capacity),
            next_sequence: 1,
            sent_up_to: 0,
            dropped: 0,
        }
    }

    /// Assigns the next sequence number to `obs` and keeps it; drops the oldest
    /// observation (sent or not) when full. Returns the sequence.
    pub fn push(&mut self, mut obs: Observation) -> u64 {
        obs.sequence = self.next_sequence;
        self.next_sequence += 1;
        if self.items.len() == self.capacity {
            self.items.pop_front();
            self.dropped += 1;
        }
        self.items.push_back(obs);
        self.next_sequence - 1
    }

    /// The oldest observation not yet sent on the current stream.
    pub fn next_unsent(&self) -> Option<&Observation> {
        let k = self.items.partition_point(|o| o.sequence <= self.sent_up_to);
        self.items.get(k)
    }

    /// Records that everything up to `sequence` was sent on the current stream.
    pub fn mark_sent(&mut self, sequence: u64) {
        self.sent_up_to = self.sent_up_to.max(sequence);
    }

    /// The coordinator acknowledged everything up to `up_to`: forget it. Returns how many went.
    pub fn ack(&mut self, up_to: u64) -> usize {
        let k = self.items.partition_point(|o| o.sequence <= up_to);
        self.items.drain(..k);
        k
    }

    /// A new stream starts: everything kept is to be sent again.
    pub fn restart(&mut self) {
        self.sent_up_to = 0;
    }

    /// Observations kept (unacknowledged).
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when nothing awaits acknowledgement.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Observations dropped because the buffer was full.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Isometry3;
    use soundmap_proto::Stamp;

    use super::*;

    fn obs(ns: i64) -> Observation {
        Observation {
            sequence: 0,
            stamp: Stamp::from_ns(ns),
            map_from_base: Isometry3::identity(),
            pose_covariance: None,
            doas: vec![],
        }
    }

    #[test]
    fn drop_oldest_send_ack_and_resend() {
        let mut b = ObservationBuffer::new(3);
        for k in 0..5 {
            assert_eq!(b.push(obs(k)), k as u64 + 1);
        }
        assert_eq!((b.len(), b.dropped()), (3, 2));
        assert_eq!(b.next_unsent().unwrap().sequence, 3);
        b.mark_sent(3);
        b.mark_sent(4);
        assert_eq!(b.next_unsent().unwrap().sequence, 5);
        assert_eq!(b.ack(3), 1);
        b.restart();
        assert_eq!(b.next_unsent().unwrap().sequence, 4, "unacknowledged 4 is resent");
        b.mark_sent(5);
        assert!(b.next_unsent().is_none());
        assert_eq!(b.ack(10), 2);
        assert!(b.is_empty());
        assert_eq!(b.push(obs(9)), 6, "sequences are never reused");
    }
}

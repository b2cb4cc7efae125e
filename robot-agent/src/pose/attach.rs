//! Attaching poses to DoA frames: a frame waits until the pose buffer can answer
//! for its stamp (poses from a live SLAM feed arrive late), up to a maximum wait.
//! Pure: the caller passes `now`.

use std::collections::VecDeque;

use soundmap_proto::Stamp;

use super::{PoseBuffer, PoseLookupError, StampedPose};
use crate::AgentError;

/// What became of a frame.
#[derive(Clone, Debug, PartialEq)]
pub enum Attached<T> {
    /// The pose at the frame's stamp (`pose.stamp` is the frame's stamp).
    Ready {
        /// Interpolated pose.
        pose: StampedPose,
        /// The frame.
        payload: T,
    },
    /// No pose can be had for the frame; it is handed back with the reason.
    Dropped {
        /// The frame's stamp.
        stamp: Stamp,
        /// The frame.
        payload: T,
        /// Why.
        reason: PoseLookupError,
    },
}

/// Frames waiting for their pose, in stamp order, and the pose buffer.
#[derive(Debug)]
pub struct Attacher<T> {
    buffer: PoseBuffer,
    pending: VecDeque<(Stamp, T)>,
    max_wait_ns: i64,
    max_pending: usize,
    poses_complete: bool,
}

impl<T> Attacher<T> {
    /// Frames wait at most `max_wait_s` (measured as `now − stamp`) for a pose
    /// after their stamp to arrive; at most `max_pending` frames wait (the oldest
    /// is dropped beyond that).
    pub fn new(buffer: PoseBuffer, max_wait_s: f64, max_pending: usize) -> Self {
        Attacher {
            buffer,
            pending: VecDeque::new(),
            max_wait_ns: (max_wait_s.max(0.0) * 1e9) as i64,
            max_pending: max_pending.max(1),
            poses_complete: false,
        }
    }

    /// Adds a pose (stamps must increase).
    pub fn push_pose(&mut self, pose: StampedPose) -> Result<(), AgentError> {
        self.buffer.push(pose)
    }

    /// No more poses will come (end of a replayed trajectory): frames after the
    /// last pose are dropped instead of waiting.
    pub fn finish_poses(&mut self) {
        self.poses_complete = true;
    }

    /// Queues a frame; the oldest waiting frame is dropped into `out` when the queue is full.
    pub fn push_frame(&mut self, stamp: Stamp, payload: T, out: &mut Vec<Attached<T>>) {
        if self.pending.len() == self.max_pending
            && let Some((stamp, payload)) = self.pending.pop_front()
        {
            let reason = self.buffer.lookup(stamp).err().unwrap_or(PoseLookupError::Empty);
            out.push(Attached::Dropped { stamp, payload, reason });
        }
        self.pending.push_back((stamp, payload));
    }

    /// Resolves waiting frames in order into `out`: ready ones with their pose,
    /// hopeless ones dropped; stops at the first frame that may still get a pose.
    pub fn poll(&mut self, now: Stamp, out: &mut Vec<Attached<T>>) {
        while let Some((stamp, _)) = self.pending.front() {
            let stamp = *stamp;
            let result = self.buffer.lookup(stamp);
            let wait = match &result {
                Err(PoseLookupError::AfterLast { .. }) | Err(PoseLookupError::Empty) => {
                    !self.poses_complete && now - stamp < self.max_wait_ns
                }
                _ => false,
            };
            if wait {
                break;
            }
            let Some((stamp, payload)) = self.pending.pop_front() else { break };
            out.push(match result {
                Ok(pose) => Attached::Ready { pose, payload },
                Err(reason) => Attached::Dropped { stamp, payload, reason },
            });
        }
    }

    /// When the oldest waiting frame stops waiting for its pose (its stamp plus
    /// the maximum wait); `None` when nothing waits.
    pub fn next_deadline(&self) -> Option<Stamp> {
        self.pending.front().map(|(stamp, _)| stamp.plus_ns(self.max_wait_ns))
    }

    /// The pose buffer.
    pub fn buffer(&self) -> &PoseBuffer {
        &self.buffer
    }

    /// Frames waiting.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }
}

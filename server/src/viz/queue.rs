//! A bounded queue that never blocks its producer: when it is full, the
//! oldest entry makes room for the new one (and is counted).
//!
//! The coordinator task pushes what happened in a batch; the viewer thread
//! pops. A slow consumer therefore costs the producer one lock and one
//! `push_back` per event, never a wait, and memory stays bounded by
//! `capacity` entries.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex};

/// A drop-oldest queue shared by one or more producers and one consumer.
#[derive(Debug)]
pub struct DropOldest<T> {
    state: Mutex<State<T>>,
    ready: Condvar,
    capacity: usize,
}

#[derive(Debug)]
struct State<T> {
    items: VecDeque<T>,
    dropped: u64,
    closed: bool,
}

impl<T> DropOldest<T> {
    /// A queue holding at most `capacity` (≥ 1) entries.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        DropOldest {
            state: Mutex::new(State { items: VecDeque::new(), dropped: 0, closed: false }),
            ready: Condvar::new(),
            capacity,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State<T>> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Appends `item`; drops the oldest entry when full. Ignored once closed.
    pub fn push(&self, item: T) {
        let mut s = self.lock();
        if s.closed {
            return;
        }
        if s.items.len() >= self.capacity {
            s.items.pop_front();
            s.dropped += 1;
        }
        s.items.push_back(item);
        drop(s);
        self.ready.notify_one();
    }

    /// Waits for entries and moves them all into `out`; returns `false` when
    /// the queue is closed and empty (nothing more will come).
    pub fn pop_all(&self, out: &mut Vec<T>) -> bool {
        let mut s = self.lock();
        while s.items.is_empty() && !s.closed {
            s = self.ready.wait(s).unwrap_or_else(|p| p.into_inner());
        }
        if s.items.is_empty() {
            return false;
        }
        out.extend(s.items.drain(..));
        true
    }

    /// Stops accepting entries; the consumer gets what is queued, then `false`.
    pub fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// Entries dropped so far because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_queue_drops_the_oldest_and_counts() {
        let q = DropOldest::new(3);
        for i in 0..5 {
            q.push(i);
        }
        let mut out = Vec::new();
        assert!(q.pop_all(&mut out));
        assert_eq!(out, vec![2, 3, 4]);
        assert_eq!(q.dropped(), 2);
    }

    #[test]
    fn closed_queue_drains_then_ends() {
        let q = std::sync::Arc::new(DropOldest::new(8));
        q.push(1);
        q.close();
        q.push(2);
        let mut out = Vec::new();
        assert!(q.pop_all(&mut out));
        assert_eq!(out, vec![1]);
        out.clear();
        assert!(!q.pop_all(&mut out));
        let q2 = q.clone();
        let consumer = std::thread::spawn(move || {
            let mut v = Vec::new();
            q2.pop_all(&mut v)
        });
        assert!(!consumer.join().unwrap());
    }
}

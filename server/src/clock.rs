//! Where the coordinator's `now` comes from: the system clock live, a clock
//! driven by the simulator or a replay otherwise.

use std::sync::Arc;
use std::sync::atomic::{AtomicI64, Ordering};

use soundmap_proto::Stamp;

/// A source of the current time.
pub trait Clock: Send + Sync + std::fmt::Debug {
    /// The current time.
    fn now(&self) -> Stamp;
}

/// The system clock (Unix time).
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now(&self) -> Stamp {
        Stamp::now()
    }
}

/// A clock set by its owner: simulated or event time.
#[derive(Clone, Debug, Default)]
pub struct ManualClock(Arc<AtomicI64>);

impl ManualClock {
    /// A clock reading `start`.
    pub fn new(start: Stamp) -> Self {
        ManualClock(Arc::new(AtomicI64::new(start.as_ns())))
    }

    /// Sets the time. Clones of this clock see it.
    pub fn set(&self, t: Stamp) {
        self.0.store(t.as_ns(), Ordering::SeqCst);
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Stamp {
        Stamp::from_ns(self.0.load(Ordering::SeqCst))
    }
}

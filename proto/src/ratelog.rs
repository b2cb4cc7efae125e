//! Rate-limited warnings: the first occurrence of a kind of event in an
//! interval is logged in full; the others are counted, and the next
//! occurrence after the interval logs one summary line with their count.
//!
//! A client sending 5,000 invalid messages a second thus writes at most two
//! lines per interval (10 s by default) instead of 50,000, and nothing is
//! hidden: the count says how many were folded. Counting is a mutex-guarded
//! map lookup per event (tens of ns), shared by every task that logs. The
//! coordinator and the robot agent both log through it.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Per-kind state: when the interval started and how many were suppressed.
#[derive(Debug)]
struct Window {
    started: Instant,
    suppressed: u64,
}

/// A rate limiter of log lines by kind (a static key such as `"outbound_full"`).
#[derive(Debug)]
pub struct RateLog {
    interval: Duration,
    windows: Mutex<HashMap<&'static str, Window>>,
}

/// What the caller should log for one event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Log the event; `suppressed` others of its kind were not logged since the last line.
    Log {
        /// Events of this kind folded since the previous line.
        suppressed: u64,
    },
    /// Do not log it (it is counted).
    Quiet,
}

impl RateLog {
    /// At most one line per kind per `interval` (besides the first).
    pub fn new(interval: Duration) -> Self {
        RateLog { interval, windows: Mutex::new(HashMap::new()) }
    }

    /// Records one event of `kind` at `now` and says whether to log it.
    pub fn note_at(&self, kind: &'static str, now: Instant) -> Verdict {
        let mut w = self.windows.lock().unwrap_or_else(|p| p.into_inner());
        match w.get_mut(kind) {
            Some(win) if now.duration_since(win.started) < self.interval => {
                win.suppressed += 1;
                Verdict::Quiet
            }
            Some(win) => {
                let suppressed = win.suppressed;
                *win = Window { started: now, suppressed: 0 };
                Verdict::Log { suppressed }
            }
            None => {
                w.insert(kind, Window { started: now, suppressed: 0 });
                Verdict::Log { suppressed: 0 }
            }
        }
    }

    /// Records one event of `kind` now.
    pub fn note(&self, kind: &'static str) -> Verdict {
        self.note_at(kind, Instant::now())
    }
}

/// Logs a warning of `kind` through `$ratelog` at most once per interval, with
/// the number of occurrences folded into it (the calling crate uses `tracing`).
#[macro_export]
macro_rules! warn_limited {
    ($ratelog:expr, $kind:literal, $($arg:tt)+) => {
        if let $crate::ratelog::Verdict::Log { suppressed } = $ratelog.note($kind) {
            if suppressed > 0 {
                ::tracing::warn!(kind = $kind, suppressed, "{} ({} more like it since the last line)", format_args!($($arg)+), suppressed);
            } else {
                ::tracing::warn!(kind = $kind, "{}", format_args!($($arg)+));
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_per_interval_with_the_count_of_the_others() {
        let log = RateLog::new(Duration::from_secs(10));
        let t0 = Instant::now();
        assert_eq!(log.note_at("bad", t0), Verdict::Log { suppressed: 0 });
        let mut logged = 0;
        for i in 1..50_000u64 {
            // 5,000 events a second for 10 s.
            if log.note_at("bad", t0 + Duration::from_micros(200 * i)) != Verdict::Quiet {
                logged += 1;
            }
        }
        assert_eq!(logged, 0);
        assert_eq!(log.note_at("bad", t0 + Duration::from_secs(11)), Verdict::Log { suppressed: 49_999 });
        // Kinds are independent.
        assert_eq!(log.note_at("other", t0 + Duration::from_secs(11)), Verdict::Log { suppressed: 0 });
    }
}

//! The fleet timebase: Unix time in nanoseconds.

use std::fmt;
use std::ops::{Add, Sub};

/// A point in time, Unix nanoseconds. Audio is stamped by the time of its
/// first sample (derived from the sample count), poses and DoAs by the time
/// they refer to, never by when they were processed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Stamp(i64);

impl Stamp {
    /// The Unix epoch.
    pub const ZERO: Stamp = Stamp(0);

    /// From Unix nanoseconds.
    pub const fn from_ns(ns: i64) -> Self {
        Stamp(ns)
    }

    /// From Unix seconds (rounded to the nearest nanosecond).
    pub fn from_secs_f64(s: f64) -> Self {
        Stamp((s * 1e9).round() as i64)
    }

    /// Unix nanoseconds.
    pub const fn as_ns(self) -> i64 {
        self.0
    }

    /// Unix seconds.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    /// `self − earlier` in seconds (negative when `earlier` is later).
    pub fn seconds_since(self, earlier: Stamp) -> f64 {
        (self.0 - earlier.0) as f64 * 1e-9
    }

    /// The current system time.
    pub fn now() -> Self {
        let d = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        Stamp(d.as_nanos() as i64)
    }

    /// This stamp shifted by `ns` nanoseconds.
    pub const fn plus_ns(self, ns: i64) -> Self {
        Stamp(self.0.saturating_add(ns))
    }

    /// This stamp shifted by `s` seconds.
    pub fn plus_secs(self, s: f64) -> Self {
        self.plus_ns((s * 1e9).round() as i64)
    }
}

impl Add<std::time::Duration> for Stamp {
    type Output = Stamp;
    fn add(self, d: std::time::Duration) -> Stamp {
        self.plus_ns(d.as_nanos() as i64)
    }
}

impl Sub for Stamp {
    /// Difference in nanoseconds.
    type Output = i64;
    fn sub(self, rhs: Stamp) -> i64 {
        self.0 - rhs.0
    }
}

impl fmt::Display for Stamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ns", self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_round_trip() {
        let s = Stamp::from_secs_f64(1_700_000_000.125);
        assert!((s.as_secs_f64() - 1_700_000_000.125).abs() < 1e-6);
        assert_eq!(s.plus_secs(0.5) - s, 500_000_000);
        assert!((s.plus_ns(250_000_000).seconds_since(s) - 0.25).abs() < 1e-12);
    }
}

//! Service metrics: counters and the latency from an observation's receipt to
//! the publication of the first estimate that used it.

use std::sync::Mutex;
use std::time::Duration;

/// A log-bucketed latency histogram: 1 µs resolution below 64 µs, then
/// 32 sub-buckets per power of two (≈3% relative error), up to ~70 s.
#[derive(Clone, Debug)]
pub struct LatencyHistogram {
    buckets: Vec<u64>,
    count: u64,
    max_ns: u64,
}

const SUB: u64 = 32;

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram { buckets: vec![0; 64 * SUB as usize], count: 0, max_ns: 0 }
    }
}

fn bucket_of(us: u64) -> usize {
    if us < 2 * SUB {
        return us as usize;
    }
    let exp = 63 - us.leading_zeros() as u64; // ≥ log2(2·SUB)
    let shift = exp - SUB.trailing_zeros() as u64;
    let sub = (us >> shift) - SUB; // in [0, SUB)
    ((exp - SUB.trailing_zeros() as u64 + 1) * SUB + sub) as usize
}

fn lower_bound_of(bucket: usize) -> u64 {
    let b = bucket as u64;
    if b < 2 * SUB {
        return b;
    }
    let exp = b / SUB - 1 + SUB.trailing_zeros() as u64;
    let sub = b % SUB;
    (SUB + sub) << (exp - SUB.trailing_zeros() as u64)
}

impl LatencyHistogram {
    /// Records one latency.
    pub fn record(&mut self, d: Duration) {
        let us = d.as_micros().min(u64::MAX as u128) as u64;
        let b = bucket_of(us).min(self.buckets.len() - 1);
        self.buckets[b] += 1;
        self.count += 1;
        self.max_ns = self.max_ns.max(d.as_nanos().min(u64::MAX as u128) as u64);
    }

    /// Number of samples.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The `q` quantile (0..=1), as a bucket's lower bound; zero when empty.
    pub fn quantile(&self, q: f64) -> Duration {
        if self.count == 0 {
            return Duration::ZERO;
        }
        let target = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (b, n) in self.buckets.iter().enumerate() {
            seen += n;
            if seen >= target {
                return Duration::from_micros(lower_bound_of(b));
            }
        }
        Duration::from_nanos(self.max_ns)
    }

    /// Largest latency recorded.
    pub fn max(&self) -> Duration {
        Duration::from_nanos(self.max_ns)
    }
}

/// Metrics shared between the coordinator task and whoever reads them.
#[derive(Debug, Default)]
pub struct Metrics {
    /// Receipt → publication latency of observations that led to an estimate.
    pub latency: Mutex<LatencyHistogram>,
}

impl Metrics {
    /// A copy of the latency histogram, and resets it when `reset`.
    pub fn take_latency(&self, reset: bool) -> LatencyHistogram {
        let mut h = self.latency.lock().unwrap_or_else(|p| p.into_inner());
        let copy = h.clone();
        if reset {
            *h = LatencyHistogram::default();
        }
        copy
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_round_trip_within_3_percent() {
        for us in [0u64, 1, 63, 64, 65, 100, 1000, 4999, 123_456, 9_999_999] {
            let lb = lower_bound_of(bucket_of(us));
            assert!(lb <= us && (us - lb) as f64 <= 0.032 * us as f64 + 1.0, "{us} → {lb}");
        }
        let mut h = LatencyHistogram::default();
        for us in 1..=1000 {
            h.record(Duration::from_micros(us));
        }
        let p50 = h.quantile(0.5).as_micros() as f64;
        let p99 = h.quantile(0.99).as_micros() as f64;
        assert!((p50 - 500.0).abs() < 20.0 && (p99 - 990.0).abs() < 35.0, "{p50} {p99}");
    }
}

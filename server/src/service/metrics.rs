//! Service metrics: counters and the latency from an observation's receipt to
//! the publication of the first estimate that used it.
//!
//! Operators read them as Prometheus series ([`super::telemetry`], served at
//! `/metrics` by [`super::metrics_http`]); the latency there is the
//! `prometheus-client` histogram (coarse buckets, monotonic). [`LatencyHistogram`]
//! stays for the benchmarks, which need quantiles at ~3 % resolution over a
//! window they reset, which a Prometheus histogram cannot give back.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
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
    /// How often each resource bound (`[server]`) was hit, and the state store's work.
    pub limits: LimitCounters,
    /// The operators' series (`GET /metrics`, see [`super::telemetry`]).
    pub telemetry: super::telemetry::Telemetry,
    /// Robot streams open (kept by the coordinator task).
    pub robot_streams: std::sync::atomic::AtomicUsize,
}

/// Counters of the resource bounds and of the state store (monotonic since start).
#[derive(Debug, Default)]
pub struct LimitCounters {
    /// Connections closed at accept: `server.max_connections` reached.
    pub connections_refused_total: AtomicU64,
    /// Connections closed at accept: `server.max_connections_per_peer` reached.
    pub connections_refused_peer: AtomicU64,
    /// Connections closed after `server.idle_timeout_ms` without a byte read.
    pub connections_idle_closed: AtomicU64,
    /// Errors of the listening socket's accept (e.g. out of descriptors).
    pub accept_errors: AtomicU64,
    /// Robot streams refused: `server.max_robot_streams` open.
    pub robot_streams_refused: AtomicU64,
    /// Robot streams closed for sending no hello within `server.hello_timeout_ms`.
    pub hello_timeouts: AtomicU64,
    /// Observations rejected over `server.max_observation_rate_hz`.
    pub observations_rate_limited: AtomicU64,
    /// Observations dropped from a robot's history over `server.max_history_per_robot`.
    pub history_trimmed: AtomicU64,
    /// Robots forgotten: disconnected longer than `server.robot_retention_s`, or replaced at `server.max_robots`.
    pub robots_forgotten: AtomicU64,
    /// Hellos refused: `server.max_robots` robots known and all connected.
    pub robots_refused: AtomicU64,
    /// `GetState` answers that left robots or sources out (`server.max_state_entries`).
    pub state_truncated: AtomicU64,
    /// Messages not queued to a robot whose outbound queue was full or closed.
    pub outbound_dropped: AtomicU64,
    /// Snapshots written to the state store.
    pub state_writes: AtomicU64,
    /// Snapshots the state store failed to write.
    pub state_write_errors: AtomicU64,
    /// Microseconds spent writing snapshots (the writer thread's work).
    pub state_write_us: AtomicU64,
}

impl LimitCounters {
    /// Adds one to `counter`.
    pub fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// The counters by name, for export.
    pub fn snapshot(&self) -> Vec<(&'static str, u64)> {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        vec![
            ("connections_refused_total", get(&self.connections_refused_total)),
            ("connections_refused_peer", get(&self.connections_refused_peer)),
            ("connections_idle_closed", get(&self.connections_idle_closed)),
            ("accept_errors", get(&self.accept_errors)),
            ("robot_streams_refused", get(&self.robot_streams_refused)),
            ("hello_timeouts", get(&self.hello_timeouts)),
            ("observations_rate_limited", get(&self.observations_rate_limited)),
            ("history_trimmed", get(&self.history_trimmed)),
            ("robots_forgotten", get(&self.robots_forgotten)),
            ("robots_refused", get(&self.robots_refused)),
            ("state_truncated", get(&self.state_truncated)),
            ("outbound_dropped", get(&self.outbound_dropped)),
            ("state_writes", get(&self.state_writes)),
            ("state_write_errors", get(&self.state_write_errors)),
            ("state_write_us", get(&self.state_write_us)),
        ]
    }
}

impl Metrics {
    /// Robot streams open.
    pub fn robot_streams(&self) -> usize {
        self.robot_streams.load(std::sync::atomic::Ordering::Relaxed)
    }

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

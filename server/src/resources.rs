//! `[server]` and `[state]` of `coordinator.toml`: the bounds that keep the
//! coordinator's memory, descriptors and log volume finite whatever clients do,
//! and where its state survives a restart.
//!
//! Every bound has a default sized for a fleet of tens of robots with room to
//! spare, and each one that is hit is counted in the service metrics and
//! logged at most once per `log_interval_s` (with the count of the others).
//!
//! Worked numbers for the defaults: 1,024 connections need 1,024 descriptors
//! besides the ~30 the process holds (the shipped systemd unit raises the soft
//! limit to 65,536; without it the coordinator lowers the cap to the soft limit
//! less 64, and says so). A robot's history holds at most 512 observations: at
//! 125 Hz that is 4 s, more than the default 2 s of `alignment.history_ms`, so
//! the count bound only bites on floods of equal stamps. 1,024 known robots
//! of ~3 KB each (array, history cleared on disconnect) stay under 4 MB.

use std::path::PathBuf;

use serde::Deserialize;
use soundmap_proto::{Problem, ValidationError};

/// `[server]`: connection, stream, rate and memory bounds.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    /// Open TCP connections at most (all peers). Default 1024.
    pub max_connections: usize,
    /// Open TCP connections at most from one peer IP address. Default 64.
    pub max_connections_per_peer: usize,
    /// Concurrent HTTP/2 streams (calls) on one connection. Default 16.
    pub max_streams_per_connection: u32,
    /// Robot-link streams open at once, those still waiting for their hello included. Default 512.
    pub max_robot_streams: usize,
    /// A robot stream that sends no hello within this is closed (ms). Default 5000.
    pub hello_timeout_ms: u64,
    /// A connection from which nothing was read for this long is closed (ms).
    /// HTTP/2 keepalive pings make healthy peers answer well within it. Default 30000.
    pub idle_timeout_ms: u64,
    /// HTTP/2 keepalive: interval of the server's pings (ms). Default 10000.
    pub keepalive_interval_ms: u64,
    /// HTTP/2 keepalive: a ping unanswered for this long closes the connection (ms). Default 10000.
    pub keepalive_timeout_ms: u64,
    /// Observations per second one robot stream may send on average; more are
    /// rejected (RESOURCE_EXHAUSTED in-band errors). Bursts of one second are allowed. Default 400.
    pub max_observation_rate_hz: f64,
    /// Observations kept per robot for alignment, whatever their stamps. Default 512.
    pub max_history_per_robot: usize,
    /// Robots known at once; a new robot beyond it replaces the one gone
    /// longest, and is refused when all are connected. Default 1024.
    pub max_robots: usize,
    /// A robot disconnected this long is forgotten (s). Default 600.
    pub robot_retention_s: f64,
    /// `GetState` lists at most this many robots (live first, then the most
    /// recently seen) and this many sound-map entries. Default 256.
    pub max_state_entries: usize,
    /// Interval of the summaries of repeated warnings (s). Default 10.
    pub log_interval_s: f64,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            max_connections: 1024,
            max_connections_per_peer: 64,
            max_streams_per_connection: 16,
            max_robot_streams: 512,
            hello_timeout_ms: 5000,
            idle_timeout_ms: 30_000,
            keepalive_interval_ms: 10_000,
            keepalive_timeout_ms: 10_000,
            max_observation_rate_hz: 400.0,
            max_history_per_robot: 512,
            max_robots: 1024,
            robot_retention_s: 600.0,
            max_state_entries: 256,
            log_interval_s: 10.0,
        }
    }
}

impl ServerConfig {
    /// Checks the values; errors name the key within `[server]`.
    pub fn validate(&self) -> Result<(), ValidationError> {
        let bad = |field: &str, value: f64, range: &'static str| {
            Err(ValidationError::new(field, Problem::OutOfRange { value, range }))
        };
        for (field, v, lo, hi, range) in [
            ("max_connections", self.max_connections, 1, 1_000_000, "[1, 1000000]"),
            ("max_connections_per_peer", self.max_connections_per_peer, 1, 1_000_000, "[1, 1000000]"),
            ("max_streams_per_connection", self.max_streams_per_connection as usize, 1, 10_000, "[1, 10000]"),
            ("max_robot_streams", self.max_robot_streams, 1, 100_000, "[1, 100000]"),
            ("max_history_per_robot", self.max_history_per_robot, 8, 1_000_000, "[8, 1000000]"),
            ("max_robots", self.max_robots, 1, 1_000_000, "[1, 1000000]"),
            ("max_state_entries", self.max_state_entries, 1, 100_000, "[1, 100000]"),
        ] {
            if !(lo..=hi).contains(&v) {
                return bad(field, v as f64, range);
            }
        }
        // Durations in ms: at least 1 ms, at most a day (no overflow in ns).
        for (field, v) in [
            ("hello_timeout_ms", self.hello_timeout_ms),
            ("idle_timeout_ms", self.idle_timeout_ms),
            ("keepalive_interval_ms", self.keepalive_interval_ms),
            ("keepalive_timeout_ms", self.keepalive_timeout_ms),
        ] {
            if !(1..=86_400_000).contains(&v) {
                return bad(field, v as f64, "[1, 86400000] ms");
            }
        }
        if !(self.max_observation_rate_hz.is_finite()
            && (1.0..=100_000.0).contains(&self.max_observation_rate_hz))
        {
            return bad("max_observation_rate_hz", self.max_observation_rate_hz, "[1, 100000] Hz");
        }
        if !(self.robot_retention_s.is_finite() && (1.0..=1e7).contains(&self.robot_retention_s)) {
            return bad("robot_retention_s", self.robot_retention_s, "[1, 1e7] s");
        }
        if !(self.log_interval_s.is_finite() && (0.1..=86_400.0).contains(&self.log_interval_s)) {
            return bad("log_interval_s", self.log_interval_s, "[0.1, 86400] s");
        }
        Ok(())
    }
}

/// `[state]`: where the coordinator keeps what survives a restart.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StateConfig {
    /// Directory of the state store (`soundmap-state.redb` in it). `None`: the
    /// coordinator runs in memory and says so at start.
    pub dir: Option<PathBuf>,
    /// Shortest interval between two snapshots written (ms). Default 200.
    pub snapshot_period_ms: u64,
}

impl Default for StateConfig {
    fn default() -> Self {
        StateConfig { dir: None, snapshot_period_ms: 200 }
    }
}

impl StateConfig {
    /// Checks the values; errors name the key within `[state]`.
    pub fn validate(&self) -> Result<(), ValidationError> {
        if !(10..=600_000).contains(&self.snapshot_period_ms) {
            return Err(ValidationError::new(
                "snapshot_period_ms",
                Problem::OutOfRange { value: self.snapshot_period_ms as f64, range: "[10, 600000] ms" },
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_values_are_named() {
        ServerConfig::default().validate().unwrap();
        StateConfig::default().validate().unwrap();
        let c = ServerConfig { max_connections: 0, ..ServerConfig::default() };
        assert_eq!(c.validate().unwrap_err().field, "max_connections");
        let c = ServerConfig { hello_timeout_ms: u64::MAX, ..ServerConfig::default() };
        assert_eq!(c.validate().unwrap_err().field, "hello_timeout_ms");
        let c = ServerConfig { max_observation_rate_hz: f64::NAN, ..ServerConfig::default() };
        assert_eq!(c.validate().unwrap_err().field, "max_observation_rate_hz");
        let s = StateConfig { snapshot_period_ms: 0, ..StateConfig::default() };
        assert_eq!(s.validate().unwrap_err().field, "snapshot_period_ms");
    }
}

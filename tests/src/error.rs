//! The simulation crate's error enum.
//!
//! Bad configuration and inputs the simulation cannot honour (a microphone
//! outside the room, a block of the wrong size) are errors; everything a
//! simulated robot may legitimately experience (a goal it has not reached yet)
//! is an outcome returned by the API, not an error.

use nalgebra::Point3;

/// Everything that can go wrong in `soundmap-sim`.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SimError {
    /// A configuration value is out of its valid range.
    #[error("invalid {field}: {reason}")]
    InvalidConfig {
        /// The offending field, e.g. `room.size_m`.
        field: &'static str,
        /// Why it is invalid, with the value.
        reason: String,
    },
    /// A point that must lie inside the room does not.
    #[error("{what} at ({:.3}, {:.3}, {:.3}) m is outside the room", position.x, position.y, position.z)]
    OutsideRoom {
        /// What the point is, e.g. `microphone 3`, `source 0`.
        what: String,
        /// The point, map frame (m).
        position: Point3<f64>,
    },
    /// A slice has the wrong number of elements.
    #[error("{what}: expected {expected} elements, got {got}")]
    WrongLength {
        /// What the slice holds.
        what: &'static str,
        /// Required length.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// A scenario file (or built-in scenario) is malformed or invalid.
    #[error("{path}: {field}: {message}")]
    Scenario {
        /// The file, or `<built-in NAME>`.
        path: String,
        /// Dotted key, e.g. `robots[1].start`.
        field: String,
        /// What is wrong.
        message: String,
    },
    /// A file could not be read or written.
    #[error("{path}: {message}")]
    Io {
        /// The file or directory.
        path: String,
        /// The underlying error, as text.
        message: String,
    },
    /// The robot agent library failed (audio, poses, link, pipeline).
    #[error("agent: {0}")]
    Agent(String),
    /// The coordinator failed to start or stop.
    #[error("coordinator: {0}")]
    Coordinator(String),
    /// A replay's inputs do not fit together (lengths, time ranges, gaps).
    #[error("replay: {0}")]
    Replay(String),
}

impl SimError {
    /// An I/O error about `path`.
    pub fn io(path: impl std::fmt::Display, e: impl std::fmt::Display) -> Self {
        SimError::Io { path: path.to_string(), message: e.to_string() }
    }

    /// Shorthand for [`SimError::InvalidConfig`].
    pub fn invalid(field: &'static str, reason: impl Into<String>) -> Self {
        SimError::InvalidConfig { field, reason: reason.into() }
    }
}

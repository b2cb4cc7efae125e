//! The simulation crate's error enum.
//!
//! Bad configuration and inputs the simulation cannot honour (a microphone
//! outside the room, a block of the wrong size) are errors; everything a
//! simulated robot may legitimately experience (a goal it has not reached yet)
//! is an outcome returned by the API, not an error.

use std::path::PathBuf;

use nalgebra::Point3;

/// Everything that can go wrong in `soundmap-sim`.
///
/// Errors of other crates are wrapped with their source kept (`#[from]` or
/// `#[source]`), not flattened to text.
#[derive(Debug, thiserror::Error)]
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
    /// A file or directory could not be read or written.
    #[error("{}: {source}", path.display())]
    File {
        /// The file or directory.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A WAV file could not be written or read.
    #[error("{}: {source}", path.display())]
    Wav {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: hound::Error,
    },
    /// A JSON document could not be written.
    #[error("{what}: {source}")]
    Json {
        /// What was being written (a file name or a description).
        what: String,
        /// The underlying error.
        #[source]
        source: serde_json::Error,
    },
    /// A figure could not be drawn (plotters' backends have different error
    /// types, so its error comes as text).
    #[error("{}: {message}", path.display())]
    Plot {
        /// The image file being drawn.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The async runtime could not be started.
    #[error("tokio runtime: {0}")]
    Runtime(#[source] std::io::Error),
    /// A loopback socket could not be bound or used.
    #[error("{addr}: {source}")]
    Net {
        /// The address.
        addr: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The robot agent library failed (array, audio, poses, link, pipeline).
    #[error("agent: {0}")]
    Agent(#[from] soundmap_agent::AgentError),
    /// The coordinator library failed (configuration, start, stop).
    #[error("coordinator: {0}")]
    Server(#[from] soundmap_server::ServerError),
    /// A value failed the shared domain types' validation (e.g. a robot id).
    #[error(transparent)]
    Validation(#[from] soundmap_proto::ValidationError),
    /// The coordinator ran but the run is not a correct one: it refused some
    /// of the agents' messages (stream errors), or the recorder lost
    /// estimates. Not another crate's error: failures of the coordinator
    /// library itself are [`SimError::Server`].
    #[error("coordinator: {0}")]
    Coordinator(String),
    /// A replay's inputs do not fit together (lengths, time ranges, gaps).
    #[error("replay: {0}")]
    Replay(String),
}

impl SimError {
    /// A [`SimError::File`]: `source` while reading or writing `path`.
    pub fn file(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SimError::File { path: path.into(), source }
    }

    /// Shorthand for [`SimError::InvalidConfig`].
    pub fn invalid(field: &'static str, reason: impl Into<String>) -> Self {
        SimError::InvalidConfig { field, reason: reason.into() }
    }
}

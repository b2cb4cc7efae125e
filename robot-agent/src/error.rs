//! The agent's error type. Every variant names the file, field or stream it is about.

use std::path::PathBuf;

/// Errors of the robot agent library.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    /// A file could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A configuration or array file is malformed or has an invalid field.
    #[error("{path}: {field}: {message}")]
    Config {
        /// The file (or `<preset NAME>` / `<inline>` for non-file sources).
        path: PathBuf,
        /// The field at fault, dotted (e.g. `microphones[3].position_m`).
        field: String,
        /// What is wrong.
        message: String,
    },
    /// Audio input is truncated, has the wrong shape or an unsupported format.
    #[error("{path}: {message}")]
    Audio {
        /// The audio file or stream (`-` for standard input).
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A pose input is malformed or cannot give a pose at a stamp.
    #[error("{source_name}: {message}")]
    Pose {
        /// The pose file or feed.
        source_name: String,
        /// What is wrong.
        message: String,
    },
    /// Invalid arguments to a pure-core constructor (array, localization or tracker settings).
    #[error("{field}: {message}")]
    InvalidParameter {
        /// The parameter at fault.
        field: String,
        /// What is wrong.
        message: String,
    },
    /// ODAS SST output is malformed.
    #[error("{source_name}: {message}")]
    Odas {
        /// The SST file (`name:line`) or socket.
        source_name: String,
        /// What is wrong.
        message: String,
    },
    /// The link to the coordinator failed.
    #[error("coordinator link: {0}")]
    Link(String),
    /// A message failed validation.
    #[error(transparent)]
    Validation(#[from] soundmap_proto::ValidationError),
}

//! The coordinator's error type. Each variant maps to one gRPC status code in
//! [`crate::service::status`].

use std::path::PathBuf;

use soundmap_proto::{RobotId, ValidationError};

/// Errors of the coordinator library.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// A message field is invalid (INVALID_ARGUMENT).
    #[error(transparent)]
    Invalid(#[from] ValidationError),
    /// A message that needs a hello arrived before it (FAILED_PRECONDITION).
    #[error("{0} before hello: the first message of a stream must be a hello")]
    NoHello(&'static str),
    /// A second hello on a stream (FAILED_PRECONDITION).
    #[error("hello: this stream already said hello as {0}")]
    SecondHello(RobotId),
    /// A command id the coordinator never issued to this robot (NOT_FOUND).
    #[error("{field}: unknown command {command_id}")]
    UnknownCommand {
        /// Field path.
        field: &'static str,
        /// The id given.
        command_id: u64,
    },
    /// Another live stream holds the robot id (ALREADY_EXISTS).
    #[error("robot {0} is already connected on a live stream")]
    AlreadyConnected(RobotId),
    /// Missing or unknown credentials (UNAUTHENTICATED).
    #[error("{0}")]
    Unauthenticated(String),
    /// Known credentials used beyond their rights (PERMISSION_DENIED).
    #[error("{0}")]
    PermissionDenied(String),
    /// Credentials for another robot (PERMISSION_DENIED).
    #[error("hello.robot_id: {claimed} does not match the authenticated identity {authenticated}")]
    IdentityMismatch {
        /// Id in the hello.
        claimed: RobotId,
        /// Id of the credentials.
        authenticated: RobotId,
    },
    /// A configuration file is invalid: the key's dotted path from the
    /// document's root and what is wrong with it.
    #[error("{path}: {error}")]
    Config {
        /// The file (or `<config>` for a configuration built in code).
        path: PathBuf,
        /// The key and its problem.
        error: ValidationError,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// A resource bound of `[server]` is reached (RESOURCE_EXHAUSTED).
    #[error("{0}")]
    Exhausted(String),
    /// The coordinator task has stopped (UNAVAILABLE).
    #[error("coordinator is shutting down")]
    ShuttingDown,
}

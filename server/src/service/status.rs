//! The one place where gRPC statuses and in-band stream errors are built:
//! every `tonic::Status` of the server comes from a function of this module.
//! Domain errors ([`ServerError`]) map to one code each ([`code`]); a few
//! transport-level endings (a stream without a hello, a stream taken over)
//! have their own named function.

use soundmap_proto::wire;
use tonic::{Code, Status};

use crate::error::ServerError;

/// The gRPC code of an error.
pub fn code(e: &ServerError) -> Code {
    match e {
        ServerError::Invalid(_) => Code::InvalidArgument,
        ServerError::NoHello(_) | ServerError::SecondHello(_) => Code::FailedPrecondition,
        ServerError::UnknownCommand { .. } => Code::NotFound,
        ServerError::AlreadyConnected(_) => Code::AlreadyExists,
        ServerError::Unauthenticated(_) => Code::Unauthenticated,
        ServerError::IdentityMismatch { .. } | ServerError::PermissionDenied(_) => Code::PermissionDenied,
        ServerError::Config { .. } | ServerError::Io { .. } => Code::Internal,
        ServerError::ShuttingDown => Code::Unavailable,
        ServerError::Exhausted(_) => Code::ResourceExhausted,
    }
}

/// A status ending a stream or call.
pub fn to_status(e: &ServerError) -> Status {
    Status::new(code(e), e.to_string())
}

/// The coordinator task has stopped: UNAVAILABLE, so that clients retry later.
pub fn shutting_down() -> Status {
    to_status(&ServerError::ShuttingDown)
}

/// A robot stream closed before its first message (INVALID_ARGUMENT, field `msg`).
pub fn closed_before_hello() -> Status {
    Status::invalid_argument("msg: stream closed before its hello")
}

/// A robot stream whose first message is not a hello (INVALID_ARGUMENT, field `msg`).
pub fn first_message_not_hello() -> Status {
    Status::invalid_argument("msg: the first message of a stream must be a hello")
}

/// The end of a robot stream that a newer connection of the same robot took over (ABORTED).
pub fn replaced_by_newer_connection() -> Status {
    Status::aborted("this stream was replaced by a newer connection of the same robot")
}

/// The end of a robot stream whose inbound side failed: a message that does
/// not decode is INVALID_ARGUMENT, one over the size limit RESOURCE_EXHAUSTED
/// (tonic reports them as INTERNAL and OUT_OF_RANGE); anything else (the peer
/// reset the stream) keeps its code.
pub fn inbound_failed(s: &Status) -> Status {
    match s.code() {
        Code::Internal => Status::invalid_argument(format!("msg: undecodable message: {}", s.message())),
        Code::OutOfRange => Status::resource_exhausted(format!("msg: {}", s.message())),
        _ => s.clone(),
    }
}

/// The field an error is about, when it names one.
pub fn field(e: &ServerError) -> String {
    match e {
        ServerError::Invalid(v) => v.field.clone(),
        ServerError::UnknownCommand { field, .. } => (*field).into(),
        ServerError::NoHello(what) => (*what).into(),
        ServerError::SecondHello(_) => "hello".into(),
        ServerError::IdentityMismatch { .. } => "hello.robot_id".into(),
        _ => String::new(),
    }
}

/// An in-band error report: the stream stays open.
pub fn to_stream_error(e: &ServerError, sequence: u64) -> wire::CoordinatorMessage {
    wire::CoordinatorMessage {
        msg: Some(wire::coordinator_message::Msg::Error(wire::StreamError {
            code: code(e) as i32,
            field: field(e),
            message: e.to_string(),
            sequence,
        })),
    }
}

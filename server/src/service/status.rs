//! The one place where domain errors become gRPC statuses and in-band stream errors.

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
        ServerError::IdentityMismatch { .. } => Code::PermissionDenied,
        ServerError::Config { .. } | ServerError::Io { .. } => Code::Internal,
        ServerError::ShuttingDown => Code::Unavailable,
    }
}

/// A status ending a stream or call.
pub fn to_status(e: &ServerError) -> Status {
    Status::new(code(e), e.to_string())
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

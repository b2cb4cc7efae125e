//! soundmap's gRPC contract and the validated domain types both sides share.
//!
//! - [`wire`]: the generated prost/tonic types of package `soundmap.v1`
//!   (`proto/soundmap/v1/*.proto`). Clients and servers of other languages use
//!   the `.proto` files directly.
//! - Domain types ([`Hello`], [`Observation`], [`RepositionCommand`], …) carry
//!   nalgebra types and are valid by construction: converting from the wire
//!   checks every field and names the first bad one in a [`ValidationError`].
//! - [`monitoring`]: domain types of the `Monitoring` service (liveness,
//!   planner status, active positioning) and their wire conversions.
//! - [`Stamp`]: the fleet timebase (Unix time in nanoseconds).
//! - [`ratelog`]: rate-limited warnings ([`warn_limited!`]) for both sides.
//!
//! Frames, units and time conventions are those of the `.proto` files: `map`,
//! `base`, `array` frames; SI units; transforms named `a_from_b`.

pub mod error;
pub mod geometry;
pub mod messages;
pub mod monitoring;
pub mod ratelog;
pub mod robot_id;
pub mod stamp;

pub use error::{Problem, ValidationError};
pub use geometry::{Limits, aperture_m, pose_from_wire, pose_to_wire, vec3_to_wire};
pub use messages::{
    ArrayInfo, BaseLimits, CommandAck, CommandProgress, CommandState, Hello, Observation, PROTOCOL_VERSION,
    RepositionCommand, RepositionReason, RobotInput, TrackedDoa,
};
pub use robot_id::RobotId;
pub use stamp::Stamp;

/// The encoded `FileDescriptorSet` of package `soundmap.v1` (with its imports):
/// the protobuf schema of every `soundmap.v1` message, for recordings (MCAP)
/// and gRPC server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/soundmap_v1_descriptor.bin"));

/// The generated types of package `soundmap.v1`.
#[allow(missing_docs, clippy::all, missing_debug_implementations)]
pub mod wire {
    include!(concat!(env!("OUT_DIR"), "/soundmap.v1.rs"));
}

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
}

impl SimError {
    /// Shorthand for [`SimError::InvalidConfig`].
    pub fn invalid(field: &'static str, reason: impl Into<String>) -> Self {
        SimError::InvalidConfig { field, reason: reason.into() }
    }
}

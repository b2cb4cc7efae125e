//! Validation errors: every one names the field it is about.

/// A message field that failed validation.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{field}: {problem}")]
pub struct ValidationError {
    /// Path of the field, e.g. `observation.doas[1].direction_in_array`.
    pub field: String,
    /// What is wrong with it.
    pub problem: Problem,
}

impl ValidationError {
    /// An error about `field`.
    pub fn new(field: impl Into<String>, problem: Problem) -> Self {
        ValidationError { field: field.into(), problem }
    }

    /// The same error with its field path inside `parent` (`parent.field`):
    /// a section validated on its own is placed in its document this way, once.
    pub fn within(mut self, parent: &str) -> Self {
        self.field = if self.field.is_empty() { parent.into() } else { format!("{parent}.{}", self.field) };
        self
    }
}

/// What is wrong with a field.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Problem {
    /// A required field is absent.
    #[error("missing")]
    Missing,
    /// A text or list is empty where it must not be.
    #[error("empty")]
    Empty,
    /// A text is longer than allowed.
    #[error("too long ({len} characters, at most {max})")]
    TooLong {
        /// Length found.
        len: usize,
        /// Longest accepted.
        max: usize,
    },
    /// A character outside the allowed set.
    #[error("invalid character {0:?} (allowed: A-Z a-z 0-9 _ . -)")]
    InvalidCharacter(char),
    /// NaN or infinite.
    #[error("not finite ({0})")]
    NonFinite(f64),
    /// A direction whose norm is too far from 1.
    #[error("not a unit vector (norm {norm}, accepted within {tolerance} of 1)")]
    NotUnitVector {
        /// Norm found.
        norm: f64,
        /// Accepted deviation from 1.
        tolerance: f64,
    },
    /// A quaternion with zero norm.
    #[error("zero quaternion (all components 0)")]
    ZeroQuaternion,
    /// A quaternion whose norm is too far from 1 to be a rotation sent in good faith.
    #[error("not a unit quaternion (norm {norm}, accepted within {tolerance} of 1)")]
    NotUnitQuaternion {
        /// Norm found.
        norm: f64,
        /// Accepted deviation from 1.
        tolerance: f64,
    },
    /// A value outside its allowed range.
    #[error("{value} out of range {range}")]
    OutOfRange {
        /// Value found.
        value: f64,
        /// The allowed range, as text (e.g. "[0, 1]").
        range: &'static str,
    },
    /// A list with the wrong number of elements.
    #[error("must have {expected} values, got {got}")]
    WrongLength {
        /// Number expected.
        expected: usize,
        /// Number found.
        got: usize,
    },
    /// A covariance that is not symmetric.
    #[error("not symmetric (entry ({row},{col}) differs from ({col},{row}))")]
    NotSymmetric {
        /// Row of the first asymmetric entry.
        row: usize,
        /// Column of the first asymmetric entry.
        col: usize,
    },
    /// A time stamp too far ahead of the receiver's clock.
    #[error("stamp {stamp_ns} ns is {ahead_ms:.1} ms ahead of the receiver clock (at most {max_ms} ms)")]
    InFuture {
        /// Stamp found.
        stamp_ns: i64,
        /// How far ahead it is.
        ahead_ms: f64,
        /// Largest accepted lead.
        max_ms: u64,
    },
    /// A time stamp too far behind the receiver's clock.
    #[error("stamp {stamp_ns} ns is {behind_ms:.1} ms behind the receiver clock (at most {max_ms} ms)")]
    TooOld {
        /// Stamp found.
        stamp_ns: i64,
        /// How far behind it is.
        behind_ms: f64,
        /// Largest accepted age.
        max_ms: u64,
    },
    /// A time stamp before the Unix epoch.
    #[error("negative stamp {0} ns (stamps are Unix nanoseconds)")]
    NegativeStamp(i64),
    /// A time stamp older than one already received.
    #[error("stamp {stamp_ns} ns is older than the previous stamp {previous_ns} ns")]
    OutOfOrder {
        /// Stamp found.
        stamp_ns: i64,
        /// The latest stamp already received.
        previous_ns: i64,
    },
    /// A sequence number that does not increase.
    #[error("sequence {sequence} does not increase (previous {previous})")]
    SequenceNotIncreasing {
        /// Sequence found.
        sequence: u64,
        /// The previous one.
        previous: u64,
    },
    /// An enum value not in the contract.
    #[error("unknown value {0}")]
    UnknownEnum(i32),
    /// Anything else, described in words.
    #[error("{0}")]
    Invalid(String),
}

//! Rate-limited warnings ([`soundmap_proto::ratelog`], shared with the robot
//! agent): the first event of a kind in an interval is logged in full, the
//! next line after the interval says how many were folded.

pub use soundmap_proto::ratelog::{RateLog, Verdict};

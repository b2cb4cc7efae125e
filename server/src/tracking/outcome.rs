//! What became of one DoA given to the tracker.

use super::filter::Unusable;

/// What became of one DoA given to [`SourceTracker::update`](super::SourceTracker::update).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum UpdateOutcome {
    /// Passed the gate and updated the track.
    Applied {
        /// Its normalized innovation squared (χ², 2 dof).
        nis: f64,
    },
    /// Failed the χ² gate: counted, not applied.
    Gated {
        /// Its NIS.
        nis: f64,
        /// The gate it exceeded (χ² 2 dof at the association or maintenance probability).
        threshold: f64,
    },
    /// The geometry or the numbers make the DoA useless (counted, not applied).
    Unusable(Unusable),
    /// Older than the fixed lag: dropped and counted.
    TooLate,
    /// Stamped at or before the track's initialization: dropped and counted.
    BeforeTrack,
    /// There is no active track (none yet, or lost).
    NoTrack,
}

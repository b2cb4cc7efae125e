//! Silence filtering: which hops become observations. Pure.

use soundmap_proto::TrackedDoa;

/// Observations are sent while tracks exist, plus one empty observation when
/// they end (so the coordinator learns that the robot hears nothing); further
/// silent hops send nothing (the link's heartbeats keep the stream alive).
///
/// The filter sees hops *after* their pose is attached, so a hop dropped for
/// want of a pose does not count as sent.
#[derive(Clone, Debug)]
pub struct SilenceFilter {
    previous_empty: bool,
}

impl Default for SilenceFilter {
    fn default() -> Self {
        SilenceFilter::new()
    }
}

impl SilenceFilter {
    /// A filter that starts silent: nothing is sent until a track appears.
    pub fn new() -> Self {
        SilenceFilter { previous_empty: true }
    }

    /// Whether a hop with these DoAs is sent.
    pub fn keep(&mut self, doas: &[TrackedDoa]) -> bool {
        let keep = !(doas.is_empty() && self.previous_empty);
        self.previous_empty = doas.is_empty();
        keep
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Unit, Vector3};

    use super::*;

    fn doa() -> TrackedDoa {
        TrackedDoa {
            track_id: 1,
            direction_in_array: Unit::new_normalize(Vector3::x()),
            activity: 1.0,
            angular_sigma_rad: None,
            signature: None,
        }
    }

    #[test]
    fn sends_tracks_and_one_empty_hop_after_them() {
        let mut f = SilenceFilter::new();
        let pattern: Vec<bool> = [vec![], vec![doa()], vec![doa()], vec![], vec![], vec![doa()], vec![]]
            .iter()
            .map(|d| f.keep(d))
            .collect();
        assert_eq!(pattern, vec![false, true, true, true, false, true, true]);
    }
}

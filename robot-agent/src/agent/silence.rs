//! Silence filtering: which hops become observations. Pure.

use soundmap_proto::{Stamp, TrackedDoa};

/// Longest gap between two observations of a robot that hears nothing (ns).
pub const SILENT_REPORT_INTERVAL_NS: i64 = 500_000_000;

/// Observations are sent while tracks exist, plus one empty observation when
/// they end (so the coordinator learns that the robot hears nothing); further
/// silent hops send one empty observation every
/// `SILENT_REPORT_INTERVAL_NS` (0.5 s), from the first hop on: a robot that
/// hears nothing still tells the coordinator where it is, so the planner can
/// move it (a deaf robot is sent where it can hear) and its commands reach it.
///
/// The filter sees hops *after* their pose is attached, so a hop dropped for
/// want of a pose does not count as sent.
#[derive(Clone, Debug)]
pub struct SilenceFilter {
    previous_empty: bool,
    last_sent: Option<Stamp>,
}

impl Default for SilenceFilter {
    fn default() -> Self {
        SilenceFilter::new()
    }
}

impl SilenceFilter {
    /// A filter that starts silent: its first hop is sent (empty or not),
    /// then silent hops every 0.5 s until a track appears.
    pub fn new() -> Self {
        SilenceFilter { previous_empty: true, last_sent: None }
    }

    /// Whether a hop stamped `stamp` with these DoAs is sent.
    pub fn keep(&mut self, doas: &[TrackedDoa], stamp: Stamp) -> bool {
        let due = self.last_sent.is_none_or(|t| stamp - t >= SILENT_REPORT_INTERVAL_NS);
        let keep = !doas.is_empty() || !self.previous_empty || due;
        self.previous_empty = doas.is_empty();
        if keep {
            self.last_sent = Some(stamp);
        }
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
            coherence: None,
            floor_fit_range_m: None,
        }
    }

    #[test]
    fn sends_tracks_one_empty_hop_after_them_and_silence_twice_a_second() {
        let mut f = SilenceFilter::new();
        // Hops every 100 ms.
        let hops = [vec![], vec![], vec![doa()], vec![doa()], vec![], vec![], vec![doa()], vec![]];
        let pattern: Vec<bool> =
            hops.iter().enumerate().map(|(i, d)| f.keep(d, Stamp::from_ns(i as i64 * 100_000_000))).collect();
        assert_eq!(pattern, vec![true, false, true, true, true, false, true, true]);
        // Then silence: one hop every 0.5 s.
        let silent: Vec<usize> =
            (8..30).filter(|&i| f.keep(&[], Stamp::from_ns(i as i64 * 100_000_000))).collect();
        assert_eq!(silent, vec![12, 17, 22, 27]);
    }
}

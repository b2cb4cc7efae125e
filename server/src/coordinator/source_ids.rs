//! Source ids of the single-source tracker, kept across restarts.
//!
//! The tracker numbers its tracks 1, 2, … from its start. The coordinator
//! publishes a *source id* instead: the next id never given, or, for a track
//! that starts within `sources.reuse_radius_m` of a source recorded before a
//! restart (and heard within `sources.memory_s`), that source's id. Without a
//! restart the two numberings are the same.

use nalgebra::Point3;
use soundmap_proto::Stamp;

use super::records::SourceRecord;
use crate::tracking::TrackEstimate;

/// The live track's source: (track id, source id, first heard).
type Current = (u64, u64, Stamp);

/// Source ids given to the tracker's tracks.
#[derive(Debug)]
pub struct SourceIds {
    next: u64,
    current: Option<Current>,
    remembered: Vec<SourceRecord>,
    reuse_radius_m: f64,
}

impl Default for SourceIds {
    fn default() -> Self {
        SourceIds { next: 1, current: None, remembered: Vec::new(), reuse_radius_m: 0.0 }
    }
}

impl SourceIds {
    /// Track `track_id` started at `position` (when known) at `stamp`: its source id.
    pub fn started(&mut self, track_id: u64, position: Option<Point3<f64>>, stamp: Stamp) -> u64 {
        let reuse = position.and_then(|p| {
            self.remembered
                .iter()
                .enumerate()
                .map(|(i, r)| (i, (r.position_in_map - p).norm()))
                .filter(|(_, d)| *d <= self.reuse_radius_m)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(i, _)| i)
        });
        let (id, first) = match reuse {
            Some(i) => {
                let r = self.remembered.swap_remove(i);
                (r.id, r.first_heard)
            }
            None => {
                self.next += 1;
                (self.next - 1, stamp)
            }
        };
        self.current = Some((track_id, id, first));
        id
    }

    /// The source id of track `track_id`.
    pub fn source_of(&self, track_id: u64) -> Option<u64> {
        self.current.filter(|c| c.0 == track_id).map(|c| c.1)
    }

    /// The next id to give.
    pub fn next(&self) -> u64 {
        self.next
    }

    /// The sources as they survive a restart: the track's (from `estimate`)
    /// and the recorded ones heard within `memory_ns` of `now`.
    pub fn export(&self, estimate: Option<&TrackEstimate>, now: Stamp, memory_ns: i64) -> Vec<SourceRecord> {
        let current =
            self.current.zip(estimate).filter(|(c, e)| c.0 == e.track_id).map(|(c, e)| SourceRecord {
                id: c.1,
                position_in_map: e.position_in_map,
                covariance: e.position_covariance(),
                first_heard: c.2,
                last_heard: e.stamp,
            });
        let kept = self.remembered.iter().filter(|r| now - r.last_heard <= memory_ns).cloned();
        current.into_iter().chain(kept).collect()
    }

    /// After a restart: the recorded sources may be taken back by tracks that
    /// start within `reuse_radius_m`; ids start at `next` at least.
    pub fn restore(&mut self, records: &[SourceRecord], next: u64, reuse_radius_m: f64) {
        self.next = self.next.max(next).max(records.iter().map(|r| r.id + 1).max().unwrap_or(1));
        self.reuse_radius_m = reuse_radius_m;
        self.remembered = records.to_vec();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    #[test]
    fn ids_follow_tracks_and_a_recorded_source_is_taken_back_nearby() {
        let t = Stamp::from_ns(1_000_000_000);
        let mut ids = SourceIds::default();
        assert_eq!(ids.started(1, Some(Point3::origin()), t), 1);
        assert_eq!(ids.started(2, None, t), 2);
        assert_eq!(ids.source_of(2), Some(2));
        let rec = SourceRecord {
            id: 7,
            position_in_map: Point3::new(2.0, 3.0, 1.0),
            covariance: Matrix3::zeros(),
            first_heard: t,
            last_heard: t,
        };
        let mut after = SourceIds::default();
        after.restore(&[rec], 9, 1.0);
        // Far away: a new id, never one given before the restart.
        assert_eq!(after.started(1, Some(Point3::new(9.0, 9.0, 1.0)), t), 9);
        // Near the recorded source: its id.
        assert_eq!(after.started(2, Some(Point3::new(2.3, 3.0, 1.0)), t), 7);
        assert_eq!(after.next(), 10);
    }
}

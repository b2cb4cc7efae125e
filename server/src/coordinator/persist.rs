//! Taking and putting back what survives a restart ([`super::records`]).
//!
//! Export reads the registry, the sources and the settings (no copy of
//! histories or trackers: a few hundred bytes per robot and per source).
//! Restore puts the robots back as disconnected (they resume when they
//! reconnect, with the same tracker index), every source as remembered (a
//! track that starts within `sources.reuse_radius_m` of one takes back its id)
//! and the operator's settings as they were; ids continue from the record's
//! next id.

use soundmap_proto::Stamp;
use soundmap_proto::monitoring::{Liveness, PositioningUpdate};

use super::Coordinator;
use super::records::{CoordinatorRecord, RobotRecord, SettingsRecord};
use super::robots::{IndexPool, RobotEntry};
use crate::error::ServerError;

impl Coordinator {
    /// What survives a restart, at `now`.
    pub fn export_state(&self, now: Stamp) -> CoordinatorRecord {
        let p = self.positioning.settings();
        let settings = SettingsRecord {
            active_positioning: p.enabled,
            theta_min_deg: p.theta_min_deg,
            theta_max_deg: p.theta_max_deg,
            focus_source_id: self.focus,
        };
        let (sources, next_source_id) = match &self.sound_map {
            Some(map) => map.export(),
            None => {
                let memory_ns = (self.config.sources.memory_s * 1e9) as i64;
                let track =
                    self.tracking.track_estimate().filter(|_| self.tracking.live_track_id().is_some());
                (self.tracking.ids.export(track.as_ref(), now, memory_ns), self.tracking.ids.next())
            }
        };
        let robots = self
            .robots
            .values()
            .map(|e| RobotRecord {
                hello: e.hello.clone(),
                index: e.index,
                last_seen: e.last_seen,
                last_stamp: e.last_stamp,
                last_map_from_base: e.last_map_from_base,
                accepted: e.accepted,
                rejected: e.rejected,
            })
            .collect();
        CoordinatorRecord { next_source_id, settings, sources, robots }
    }

    /// The next source id to give.
    pub fn next_source_id(&self) -> u64 {
        match &self.sound_map {
            Some(map) => map.export().1,
            None => self.tracking.ids.next(),
        }
    }

    /// Puts back what `record` holds into a coordinator that has no robots yet.
    /// Robots beyond `server.max_robots` (the most recently seen are kept) and
    /// settings the configuration no longer allows are left out, with a warning.
    pub fn restore_state(&mut self, record: &CoordinatorRecord) -> Result<(), ServerError> {
        let reuse = self.config.sources.reuse_radius_m;
        match self.sound_map.as_mut() {
            Some(map) => map.restore(&record.sources, record.next_source_id),
            None => self.tracking.ids.restore(&record.sources, record.next_source_id, reuse),
        }
        let mut robots: Vec<&RobotRecord> = record.robots.iter().collect();
        robots.sort_by_key(|r| std::cmp::Reverse(r.last_seen));
        robots.truncate(self.config.server.max_robots);
        let mut seen = std::collections::BTreeSet::new();
        for r in robots {
            // Two records with one index cannot both be right: the older one goes.
            if !seen.insert(r.index) {
                continue;
            }
            let mut e = RobotEntry::new(r.hello.clone(), r.index, 0, r.last_seen);
            e.conn = None;
            e.last_stamp = r.last_stamp;
            e.last_map_from_base = r.last_map_from_base;
            e.accepted = r.accepted;
            e.rejected = r.rejected;
            let id = r.hello.robot_id.clone();
            self.liveness.insert(id.clone(), Liveness::Disconnected);
            self.robots.insert(id, e);
        }
        self.indices = IndexPool::with_used(self.robots.values().map(|e| e.index));
        let s = record.settings;
        let update = PositioningUpdate {
            enabled: Some(s.active_positioning),
            theta_min_deg: Some(s.theta_min_deg),
            theta_max_deg: Some(s.theta_max_deg),
        };
        if let Err(e) = self.positioning.update(&update) {
            tracing::warn!(
                "the saved active positioning settings are not valid any more ({e}): the configuration's apply"
            );
        }
        if let Err(e) = self.set_focus(s.focus_source_id) {
            tracing::warn!("the saved focus is not valid any more ({e}): all sources are served");
        }
        Ok(())
    }
}

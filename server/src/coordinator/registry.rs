//! The bounds of the robot registry (see [`super::robots`]): robots gone
//! longer than `server.robot_retention_s` are forgotten at each tick, and a
//! new robot beyond `server.max_robots` replaces the one disconnected longest
//! (or is refused with RESOURCE_EXHAUSTED when every known robot is connected).

use soundmap_proto::{RobotId, Stamp};

use super::Coordinator;
use crate::error::ServerError;

impl Coordinator {
    /// Makes room for the new robot `id` under `server.max_robots`.
    pub(super) fn make_room(&mut self, id: &RobotId) -> Result<(), ServerError> {
        if self.robots.len() < self.config.server.max_robots {
            return Ok(());
        }
        let oldest = self
            .robots
            .iter()
            .filter(|(_, e)| e.conn.is_none())
            .min_by_key(|(_, e)| e.last_seen)
            .map(|(id, _)| id.clone());
        match oldest {
            Some(old) => {
                self.forget(&old);
                Ok(())
            }
            None => {
                self.counters.robots_refused += 1;
                Err(ServerError::Exhausted(format!(
                    "hello.robot_id: {id}: the coordinator already follows server.max_robots = {} \
                     connected robots",
                    self.config.server.max_robots
                )))
            }
        }
    }

    /// Forgets robots disconnected longer than `server.robot_retention_s` before `now`.
    pub(super) fn forget_gone(&mut self, now: Stamp) {
        let retention_ns = (self.config.server.robot_retention_s * 1e9) as i64;
        let gone: Vec<RobotId> = self
            .robots
            .iter()
            .filter(|(_, e)| e.gone_longer_than(now, retention_ns))
            .map(|(id, _)| id.clone())
            .collect();
        for id in gone {
            self.forget(&id);
        }
    }

    fn forget(&mut self, id: &RobotId) {
        if let Some(e) = self.robots.remove(id) {
            if let Some(conn) = e.conn {
                self.connections.remove(&conn);
            }
            self.indices.give_back(e.index);
            self.liveness.remove(id);
            self.counters.robots_forgotten += 1;
            tracing::debug!(robot = %id, "robot forgotten");
        }
    }
}

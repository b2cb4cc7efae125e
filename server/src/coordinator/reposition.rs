//! A planning cycle of the coordinator, and the operator's switch.
//!
//! On an estimate, when active positioning is on and a cycle is due (the
//! planner's [`cadence`](crate::planner::cadence) alone decides that):
//! 1. the source: the confirmed track, else a usable triangulation
//!    ([`Estimate::planning_source`]);
//! 2. the robots: every live robot with a known pose (its last pose, its
//!    array, σ of its last DoAs or the configured default, and the goal of a
//!    command it is still executing);
//! 3. [`Planner::plan`](crate::planner::Planner::plan); each goal becomes a
//!    [`RepositionCommand`](soundmap_proto::RepositionCommand) queued for the
//!    robot's stream, unless the robot refused or failed that same goal
//!    recently (`active_positioning.retry_after_s`, `retry_distance_m`).

use soundmap_proto::Stamp;

use super::commands::{Outbound, Outgoing};
use super::positioning::{PositioningSettings, PositioningUpdate};
use super::{Coordinator, Estimate, Liveness};
use crate::error::ServerError;
use crate::planner::{PlanOutcome, PlannerInput, RobotState};

impl Coordinator {
    /// Runs one planning cycle for `estimate` at `now` (see the module docs).
    pub(super) fn reposition(&mut self, now: Stamp, estimate: &Estimate) {
        let source = match estimate.planning_source(&self.config.triangulation) {
            Ok(s) => s,
            Err(why) => {
                self.positioning.no_source(now, why);
                return;
            }
        };
        let stale_after_ns = self.stale_after_ns();
        let default_sigma = self.config.doa.default_sigma_deg.to_radians();
        let robots: Vec<RobotState> = self
            .robots
            .iter()
            .filter(|(_, e)| e.liveness(now, stale_after_ns) == Liveness::Live)
            .filter_map(|(id, e)| {
                Some(RobotState {
                    id: id.clone(),
                    map_from_base: e.last_map_from_base?,
                    base_from_array: e.hello.array.base_from_array,
                    sigma_rad: e.last_sigma_rad.unwrap_or(default_sigma),
                    active_goal: e.commands.active_goal(now),
                })
            })
            .collect();
        let input = PlannerInput { source, robots };
        let PlanOutcome::Planned(goals) = self.positioning.plan(now, &input) else { return };
        let ap = self.positioning.config().clone();
        let retry_ns = (ap.retry_after_s * 1e9) as i64;
        let mut skipped = Vec::new();
        for goal in &goals {
            let Some(entry) = self.robots.get_mut(&goal.robot_id) else { continue };
            let Some(conn) = entry.conn else { continue };
            let goal_t = goal.map_from_base.translation.vector;
            if let Some(r) = &entry.commands.refused
                && now - r.at < retry_ns
                && (r.goal_map_from_base.translation.vector - goal_t).xy().norm() <= ap.retry_distance_m
            {
                skipped.push(format!(
                    "{} not re-sent the goal it refused as command {} ({})",
                    goal.robot_id, r.command_id, r.reason
                ));
                continue;
            }
            let mut command = self.positioning.command(now, goal, estimate.theta_deg());
            if let Some(serving) = &self.serving {
                command.detail = format!("{serving}: {}", command.detail);
            }
            entry.commands.issue(command.clone());
            self.outbox.push(Outgoing {
                conn,
                robot_id: goal.robot_id.clone(),
                message: Outbound::Reposition(command),
            });
        }
        if !skipped.is_empty() {
            self.positioning.annotate(&skipped.join("; "));
        }
    }

    /// Applies the operator's update of active positioning (checked first:
    /// errors name `theta_min_deg`, `theta_max_deg`). Switching it off cancels
    /// the commands robots are still executing.
    pub fn set_active_positioning(
        &mut self,
        _now: Stamp,
        update: &PositioningUpdate,
    ) -> Result<PositioningSettings, ServerError> {
        let was_enabled = self.positioning.settings().enabled;
        let settings = self.positioning.update(update)?;
        if was_enabled && !settings.enabled {
            for (id, e) in &mut self.robots {
                let (Some(conn), Some(command_id)) = (e.conn, e.commands.cancellable()) else { continue };
                e.commands.cancel();
                self.outbox.push(Outgoing {
                    conn,
                    robot_id: id.clone(),
                    message: Outbound::Cancel {
                        command_id,
                        reason: "active positioning switched off".into(),
                    },
                });
            }
        }
        Ok(settings)
    }
}

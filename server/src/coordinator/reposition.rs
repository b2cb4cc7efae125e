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
//!
//! Without a usable source (no estimate for [`BEARINGS_AFTER_S`], or one the
//! planner cannot use) the cycle plans from bearings instead
//! ([`crate::planner::start`]): each live robot with its last pose (or none),
//! the most active DoA of its newest observation when that is at most
//! [`HEARD_WITHIN_S`] old, and the latest estimate's position as a hint when
//! it is recent.

use nalgebra::Point2;
use soundmap_proto::{RepositionCommand, RobotId, Stamp};

use super::commands::{Outbound, Outgoing};
use super::positioning::{PositioningSettings, PositioningUpdate};
use super::{Coordinator, Estimate, Liveness};
use crate::error::ServerError;
use crate::planner::{Heard, PlanOutcome, PlannerInput, RobotState, StartRobot};
use crate::tracking::TrackState;

/// Planning from bearings takes over when the latest usable estimate is older than this (s).
pub const BEARINGS_AFTER_S: f64 = 2.0;
/// A robot whose newest DoA is older than this hears nothing (s).
pub const HEARD_WITHIN_S: f64 = 1.0;
/// The latest estimate's position guides planning from bearings while younger than this (s).
const HINT_WITHIN_S: f64 = 3.0;

impl Coordinator {
    /// Runs one planning cycle for `estimate` at `now` (see the module docs);
    /// `others` are the batch's other estimates, whose confirmed sources every
    /// goal keeps out of.
    pub(super) fn reposition(&mut self, now: Stamp, estimate: &Estimate, others: &[Estimate]) {
        self.positioning.estimate_seen();
        let source = match estimate.planning_source(&self.config.triangulation) {
            Ok(s) => s,
            Err(why) => {
                self.plan_from_bearings(now, &why);
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
                    base: e.hello.base_limits,
                })
            })
            .collect();
        let others = others
            .iter()
            .filter(|e| e.filtered.as_ref().is_some_and(|f| f.state == TrackState::Confirmed))
            .filter_map(|e| e.planning_source(&self.config.triangulation).ok())
            .collect();
        let input = PlannerInput { source, robots, others };
        let PlanOutcome::Planned(goals) = self.positioning.plan(now, &input) else { return };
        let mut skipped = Vec::new();
        for goal in &goals {
            if !self.may_send(now, &goal.robot_id, &goal.map_from_base.translation.vector.xy(), &mut skipped)
            {
                continue;
            }
            let command = self.positioning.command(now, goal, estimate.theta_deg());
            self.send_command(&goal.robot_id, command);
        }
        if !skipped.is_empty() {
            self.positioning.annotate(&skipped.join("; "));
        }
    }

    /// A planning cycle without an estimate at `now`, when active positioning is
    /// on and due and no usable estimate came for [`BEARINGS_AFTER_S`].
    pub(super) fn reposition_without_estimate(&mut self, now: Stamp) {
        let recent = |e: &super::Estimate| (now - e.stamp) as f64 * 1e-9 < BEARINGS_AFTER_S;
        let why = match self.last_estimate.as_ref().filter(|e| recent(e)) {
            Some(e) => match e.planning_source(&self.config.triangulation) {
                // The estimates' own cycles plan around it.
                Ok(_) => return,
                Err(why) => why,
            },
            // Nothing yet: the first estimate may be one observation away (the
            // other robot's); wait as long as after a stale one.
            None if self.positioning.seconds_without_estimate(now) < BEARINGS_AFTER_S => return,
            None => "no position yet".to_owned(),
        };
        self.plan_from_bearings(now, &why);
    }

    /// Plans from what the robots hear (see the module doc) and sends the commands.
    fn plan_from_bearings(&mut self, now: Stamp, why_no_source: &str) {
        let stale_after_ns = self.stale_after_ns();
        let heard_ns = (HEARD_WITHIN_S * 1e9) as i64;
        let robots: Vec<StartRobot> = self
            .robots
            .iter()
            .filter(|(_, e)| e.liveness(now, stale_after_ns) == Liveness::Live && e.conn.is_some())
            .map(|(id, e)| {
                let heard = e.history.back().filter(|o| now - o.received <= heard_ns).and_then(|o| {
                    let t = o.rays.iter().max_by(|a, b| a.activity.total_cmp(&b.activity))?;
                    Some(Heard {
                        origin_in_map: t.ray.origin_in_map,
                        direction_in_map: t.ray.direction_in_map,
                        activity: t.activity,
                    })
                });
                let xy = |m: &nalgebra::Isometry3<f64>| Point2::new(m.translation.x, m.translation.y);
                StartRobot {
                    id: id.clone(),
                    base_xy: e.last_map_from_base.as_ref().map(xy),
                    heard,
                    active_goal: e.commands.active_goal(now).as_ref().map(xy),
                }
            })
            .collect();
        let hint = self
            .last_estimate
            .as_ref()
            .filter(|e| (now - e.stamp) as f64 * 1e-9 < HINT_WITHIN_S)
            .and_then(|e| e.position());
        let goals = self.positioning.plan_from_bearings(now, &robots, hint, why_no_source);
        let mut skipped = Vec::new();
        for goal in &goals {
            if !self.may_send(now, &goal.robot_id, &goal.map_from_base.translation.vector.xy(), &mut skipped)
            {
                continue;
            }
            let command = self.positioning.start_command(now, goal);
            self.send_command(&goal.robot_id, command);
        }
        if !skipped.is_empty() {
            self.positioning.annotate(&skipped.join("; "));
        }
    }

    /// Whether a goal may be sent to `robot_id`: it has a stream, and did not
    /// refuse or fail a goal this close recently (else a note goes to `skipped`).
    fn may_send(
        &self,
        now: Stamp,
        robot_id: &RobotId,
        goal_xy: &nalgebra::Vector2<f64>,
        skipped: &mut Vec<String>,
    ) -> bool {
        let ap = self.positioning.config();
        let retry_ns = (ap.retry_after_s * 1e9) as i64;
        let Some(entry) = self.robots.get(robot_id) else { return false };
        if entry.conn.is_none() {
            return false;
        }
        if let Some(r) = &entry.commands.refused
            && now - r.at < retry_ns
            && (r.goal_map_from_base.translation.vector.xy() - goal_xy).norm() <= ap.retry_distance_m
        {
            skipped.push(format!(
                "{robot_id} not re-sent the goal it refused as command {} ({})",
                r.command_id, r.reason
            ));
            return false;
        }
        true
    }

    /// Queues `command` for `robot_id`'s stream and records it as issued.
    fn send_command(&mut self, robot_id: &RobotId, mut command: RepositionCommand) {
        if let Some(serving) = &self.serving {
            command.detail = format!("{serving}: {}", command.detail);
        }
        let Some(entry) = self.robots.get_mut(robot_id) else { return };
        let Some(conn) = entry.conn else { return };
        entry.commands.issue(command.clone());
        self.outbox.push(Outgoing {
            conn,
            robot_id: robot_id.clone(),
            message: Outbound::Reposition(command),
        });
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

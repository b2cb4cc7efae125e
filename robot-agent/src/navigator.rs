//! Executing reposition commands.
//!
//! [`Navigator`] is what the link drives: it submits commands (answered with a
//! [`CommandAck`]), cancels them, feeds the robot's pose, and collects
//! [`CommandProgress`] reports; the [agent core](crate::agent) drives it
//! ([`Agent::exchange_with`](crate::agent::Agent::exchange_with)).
//! [`JsonLinesNavigator`] hands goals to a real navigation stack as JSON lines;
//! the simulator's robots implement it with their simulated drive;
//! [`DecliningNavigator`] refuses every command (replays of recordings).
//!
//! Conventions: a newer command replaces an older one (the older one is reported
//! `Canceled`); a command whose `deadline` has passed is refused or failed.
//! A deadline of 0 means none.

use std::io::Write;
use std::path::Path;

use serde::Serialize;
use soundmap_proto::{CommandAck, CommandProgress, CommandState, RepositionCommand, Stamp};

use crate::AgentError;
use crate::pose::StampedPose;

/// Executes reposition commands for the agent core.
pub trait Navigator: Send + std::fmt::Debug {
    /// A new command: accept (and start) it, or refuse it with a reason.
    fn submit(&mut self, command: &RepositionCommand, now: Stamp) -> CommandAck;
    /// The coordinator cancels `command_id` (ignored when it is not the active one).
    fn cancel(&mut self, command_id: u64, reason: &str, now: Stamp);
    /// The robot's latest pose, for navigators that watch for arrival.
    fn observe_pose(&mut self, _pose: &StampedPose) {}
    /// Appends the progress reports produced since the last call, in order.
    fn poll_progress(&mut self, now: Stamp, out: &mut Vec<CommandProgress>);
}

/// One line written by [`JsonLinesNavigator`].
///
/// `{"type":"goal","command_id":7,"stamp_ns":…,"x":…,"y":…,"z":…,"qx":…,"qy":…,"qz":…,"qw":…,
/// "look_at_x":…,"look_at_y":…,"look_at_z":…,"deadline_ns":…,"detail":"…"}` for a goal of
/// the base in the map frame (metres, quaternion with `qw` scalar), and
/// `{"type":"cancel","command_id":7,"stamp_ns":…,"detail":"…"}` to stop.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum GoalLine {
    /// Drive to this pose.
    Goal {
        /// Coordinator's command id.
        command_id: u64,
        /// When the goal was issued to the navigation stack, Unix ns.
        stamp_ns: i64,
        /// Goal position of the base in the map, metres.
        x: f64,
        /// Goal position of the base in the map, metres.
        y: f64,
        /// Goal position of the base in the map, metres.
        z: f64,
        /// Goal orientation (vector part).
        qx: f64,
        /// Goal orientation (vector part).
        qy: f64,
        /// Goal orientation (vector part).
        qz: f64,
        /// Goal orientation (scalar part).
        qw: f64,
        /// Point to face, map frame, metres.
        look_at_x: f64,
        /// Point to face, map frame, metres.
        look_at_y: f64,
        /// Point to face, map frame, metres.
        look_at_z: f64,
        /// Give up after this time, Unix ns (0: none).
        deadline_ns: i64,
        /// Why, for operators.
        detail: String,
    },
    /// Stop driving to the goal of `command_id`.
    Cancel {
        /// The command stopped.
        command_id: u64,
        /// When, Unix ns.
        stamp_ns: i64,
        /// Why.
        detail: String,
    },
}

/// Writes goals as JSON lines for the robot's navigation stack and reports them
/// accepted. It reports `Succeeded` when the observed pose comes within
/// `arrival_tolerance_m` of the goal position (straight-line distance, which is
/// also the `distance_remaining_m` it reports), and `Failed` at the deadline.
pub struct JsonLinesNavigator {
    name: String,
    out: Box<dyn Write + Send>,
    arrival_tolerance_m: f64,
    active: Option<RepositionCommand>,
    pose: Option<StampedPose>,
    pending: Vec<CommandProgress>,
}

impl std::fmt::Debug for JsonLinesNavigator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JsonLinesNavigator")
            .field("name", &self.name)
            .field("active", &self.active.as_ref().map(|c| c.command_id))
            .finish_non_exhaustive()
    }
}

impl JsonLinesNavigator {
    /// Writes to `out`; `name` is used in messages.
    pub fn new(name: &str, out: Box<dyn Write + Send>, arrival_tolerance_m: f64) -> Self {
        JsonLinesNavigator {
            name: name.to_owned(),
            out,
            arrival_tolerance_m,
            active: None,
            pose: None,
            pending: Vec::new(),
        }
    }

    /// Appends to the file at `path`, or writes to standard output for `-`.
    pub fn open(path: &Path, arrival_tolerance_m: f64) -> Result<Self, AgentError> {
        if path == Path::new("-") {
            return Ok(Self::new("-", Box::new(std::io::stdout()), arrival_tolerance_m));
        }
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|source| AgentError::Io { path: path.to_path_buf(), source })?;
        Ok(Self::new(&path.display().to_string(), Box::new(file), arrival_tolerance_m))
    }

    fn write(&mut self, line: &GoalLine) -> std::io::Result<()> {
        let mut text = serde_json::to_string(line).map_err(std::io::Error::other)?;
        text.push('\n');
        self.out.write_all(text.as_bytes())?;
        self.out.flush()
    }

    fn distance_m(&self, c: &RepositionCommand) -> Option<f64> {
        self.pose
            .as_ref()
            .map(|p| (p.map_from_base.translation.vector - c.goal_map_from_base.translation.vector).norm())
    }

    fn finish(&mut self, state: CommandState, detail: String, now: Stamp, write_cancel: bool) {
        if let Some(c) = self.active.take() {
            if write_cancel {
                let line = GoalLine::Cancel {
                    command_id: c.command_id,
                    stamp_ns: now.as_ns(),
                    detail: detail.clone(),
                };
                if let Err(e) = self.write(&line) {
                    tracing::warn!("{}: cannot write cancel of command {}: {e}", self.name, c.command_id);
                }
            }
            self.pending.push(CommandProgress {
                command_id: c.command_id,
                state,
                distance_remaining_m: self.distance_m(&c),
                detail,
            });
        }
    }
}

fn deadline_passed(c: &RepositionCommand, now: Stamp) -> bool {
    c.deadline.as_ns() != 0 && now > c.deadline
}

impl Navigator for JsonLinesNavigator {
    fn submit(&mut self, c: &RepositionCommand, now: Stamp) -> CommandAck {
        let refuse = |reason: String| CommandAck { command_id: c.command_id, accepted: false, reason };
        if deadline_passed(c, now) {
            return refuse(format!("deadline {} already passed (now {now})", c.deadline));
        }
        let t = c.goal_map_from_base.translation.vector;
        let q = c.goal_map_from_base.rotation.quaternion();
        let line = GoalLine::Goal {
            command_id: c.command_id,
            stamp_ns: now.as_ns(),
            x: t.x,
            y: t.y,
            z: t.z,
            qx: q.i,
            qy: q.j,
            qz: q.k,
            qw: q.w,
            look_at_x: c.look_at_in_map.x,
            look_at_y: c.look_at_in_map.y,
            look_at_z: c.look_at_in_map.z,
            deadline_ns: c.deadline.as_ns(),
            detail: c.detail.clone(),
        };
        if let Err(e) = self.write(&line) {
            return refuse(format!("cannot hand the goal to the navigation stack ({}): {e}", self.name));
        }
        self.finish(CommandState::Canceled, format!("replaced by command {}", c.command_id), now, false);
        self.active = Some(c.clone());
        self.pending.push(CommandProgress {
            command_id: c.command_id,
            state: CommandState::Executing,
            distance_remaining_m: self.distance_m(c),
            detail: format!("goal written to {}", self.name),
        });
        CommandAck { command_id: c.command_id, accepted: true, reason: String::new() }
    }

    fn cancel(&mut self, command_id: u64, reason: &str, now: Stamp) {
        if self.active.as_ref().is_some_and(|c| c.command_id == command_id) {
            self.finish(CommandState::Canceled, format!("canceled by the coordinator: {reason}"), now, true);
        }
    }

    fn observe_pose(&mut self, pose: &StampedPose) {
        self.pose = Some(pose.clone());
    }

    fn poll_progress(&mut self, now: Stamp, out: &mut Vec<CommandProgress>) {
        if let Some(c) = &self.active {
            let arrived = self.distance_m(c).is_some_and(|d| d <= self.arrival_tolerance_m);
            if arrived {
                let detail = format!("within {} m of the goal", self.arrival_tolerance_m);
                self.finish(CommandState::Succeeded, detail, now, false);
            } else if deadline_passed(c, now) {
                let detail = format!("deadline {} passed before arrival", c.deadline);
                self.finish(CommandState::Failed, detail, now, true);
            }
        }
        out.append(&mut self.pending);
    }
}

/// A navigator for a robot that cannot move (a replayed recording, a fixed
/// array): every command is refused with `reason`.
#[derive(Clone, Debug)]
pub struct DecliningNavigator {
    reason: String,
}

impl DecliningNavigator {
    /// Refuses every command with `reason`.
    pub fn new(reason: impl Into<String>) -> Self {
        DecliningNavigator { reason: reason.into() }
    }
}

impl Navigator for DecliningNavigator {
    fn submit(&mut self, c: &RepositionCommand, _now: Stamp) -> CommandAck {
        CommandAck { command_id: c.command_id, accepted: false, reason: self.reason.clone() }
    }
    fn cancel(&mut self, _command_id: u64, _reason: &str, _now: Stamp) {}
    fn poll_progress(&mut self, _now: Stamp, _out: &mut Vec<CommandProgress>) {}
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use nalgebra::{Isometry3, Point3};
    use soundmap_proto::RepositionReason;

    use super::*;

    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn command(id: u64, x: f64, deadline_ns: i64) -> RepositionCommand {
        RepositionCommand {
            command_id: id,
            goal_map_from_base: Isometry3::translation(x, 1.0, 0.0),
            look_at_in_map: Point3::new(5.0, 5.0, 1.0),
            reason: RepositionReason::ThetaOutOfBand,
            detail: "theta 12°".into(),
            deadline: Stamp::from_ns(deadline_ns),
            issued: Stamp::from_ns(1),
        }
    }

    fn at(x: f64) -> StampedPose {
        StampedPose {
            stamp: Stamp::from_ns(5),
            map_from_base: Isometry3::translation(x, 1.0, 0.0),
            covariance: None,
        }
    }

    #[test]
    fn goals_are_written_acked_replaced_and_finished() {
        let buf = Shared::default();
        let mut nav = JsonLinesNavigator::new("goals", Box::new(buf.clone()), 0.2);
        let mut progress = vec![];
        nav.observe_pose(&at(0.0));
        let ack = nav.submit(&command(7, 3.0, 0), Stamp::from_ns(10));
        assert!(ack.accepted);
        let ack = nav.submit(&command(8, 4.0, 0), Stamp::from_ns(20));
        assert!(ack.accepted);
        nav.poll_progress(Stamp::from_ns(30), &mut progress);
        let states: Vec<(u64, CommandState)> = progress.iter().map(|p| (p.command_id, p.state)).collect();
        assert_eq!(
            states,
            vec![(7, CommandState::Executing), (7, CommandState::Canceled), (8, CommandState::Executing)]
        );
        assert_eq!(progress[2].distance_remaining_m, Some(4.0));
        progress.clear();
        nav.observe_pose(&at(3.9));
        nav.poll_progress(Stamp::from_ns(40), &mut progress);
        assert_eq!(progress.len(), 1);
        assert_eq!(progress[0].state, CommandState::Succeeded);
        let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
        let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0]["type"], "goal");
        assert_eq!(lines[1]["command_id"], 8);
        assert_eq!(lines[1]["x"], 4.0);
        assert_eq!(lines[1]["qw"], 1.0);
        assert_eq!(lines[1]["look_at_x"], 5.0);
    }

    #[test]
    fn cancel_and_deadlines() {
        let buf = Shared::default();
        let mut nav = JsonLinesNavigator::new("goals", Box::new(buf.clone()), 0.2);
        let mut progress = vec![];
        let refused = nav.submit(&command(1, 3.0, 100), Stamp::from_ns(200));
        assert!(!refused.accepted && refused.reason.contains("deadline"), "{refused:?}");
        assert!(nav.submit(&command(2, 3.0, 0), Stamp::from_ns(200)).accepted);
        nav.cancel(99, "not active", Stamp::from_ns(210));
        nav.cancel(2, "source lost", Stamp::from_ns(220));
        assert!(nav.submit(&command(3, 3.0, 500), Stamp::from_ns(300)).accepted);
        nav.poll_progress(Stamp::from_ns(501), &mut progress);
        let states: Vec<(u64, CommandState)> = progress.iter().map(|p| (p.command_id, p.state)).collect();
        assert_eq!(
            states,
            vec![
                (2, CommandState::Executing),
                (2, CommandState::Canceled),
                (3, CommandState::Executing),
                (3, CommandState::Failed)
            ]
        );
        assert!(progress[1].detail.contains("source lost"));
        let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
        let types: Vec<String> = text
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["type"].as_str().unwrap().to_owned()
            })
            .collect();
        assert_eq!(types, vec!["goal", "cancel", "goal", "cancel"]);
    }
}

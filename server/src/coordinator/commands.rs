//! Reposition commands as the coordinator tracks them per robot: the latest
//! one and the robot's reports on it, the ids of earlier ones (whose late
//! reports are accepted and ignored), and the last goal the robot refused or
//! failed to reach (not re-sent blindly).

use std::collections::VecDeque;

use nalgebra::Isometry3;
use soundmap_proto::{CommandAck, CommandProgress, CommandState, RepositionCommand, RobotId, Stamp};

use crate::error::ServerError;

/// Identifies one stream (connection) of a robot.
pub type ConnId = u64;

/// Earlier command ids remembered per robot.
const RECENT_COMMANDS: usize = 16;

/// Something the coordinator sends a robot besides acknowledgements.
#[derive(Clone, Debug, PartialEq)]
pub enum Outbound {
    /// Drive to a goal (replaces the robot's current command).
    Reposition(RepositionCommand),
    /// Stop executing a command.
    Cancel {
        /// The command.
        command_id: u64,
        /// Why, for operators.
        reason: String,
    },
}

/// A message for a robot's stream, queued by the coordinator for the shell to send.
#[derive(Clone, Debug, PartialEq)]
pub struct Outgoing {
    /// The robot's current stream.
    pub conn: ConnId,
    /// The robot.
    pub robot_id: RobotId,
    /// What to send.
    pub message: Outbound,
}

/// A goal a robot refused (ack `accepted = false`) or reported `FAILED`.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// The command.
    pub command_id: u64,
    /// Its goal pose (map frame).
    pub goal_map_from_base: Isometry3<f64>,
    /// Coordinator clock when the robot said so.
    pub at: Stamp,
    /// The robot's words.
    pub reason: String,
}

/// Commands of one robot.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CommandLog {
    /// The latest command sent and the robot's last report on it (`None`:
    /// not yet acknowledged).
    pub current: Option<(RepositionCommand, Option<CommandState>)>,
    /// Ids of earlier commands, newest last.
    recent: VecDeque<u64>,
    /// The last goal refused or failed.
    pub refused: Option<Refusal>,
}

impl CommandLog {
    /// Records a command as sent; it replaces the current one.
    pub fn issue(&mut self, command: RepositionCommand) {
        if let Some((old, _)) = self.current.take() {
            self.recent.push_back(old.command_id);
            if self.recent.len() > RECENT_COMMANDS {
                self.recent.pop_front();
            }
        }
        self.current = Some((command, None));
    }

    /// The goal of the current command while the robot is (or will be) driving
    /// to it: not refused, not finished, deadline not passed.
    pub fn active_goal(&self, now: Stamp) -> Option<Isometry3<f64>> {
        match &self.current {
            Some((c, None | Some(CommandState::Executing))) if now <= c.deadline => {
                Some(c.goal_map_from_base)
            }
            _ => None,
        }
    }

    /// The current command if the robot may still be executing it (for cancellation).
    pub fn cancellable(&self) -> Option<u64> {
        match &self.current {
            Some((c, None | Some(CommandState::Executing))) => Some(c.command_id),
            _ => None,
        }
    }

    fn known(&self, command_id: u64) -> bool {
        self.recent.contains(&command_id)
    }

    fn refuse(&mut self, now: Stamp, reason: String) {
        if let Some((c, state)) = &mut self.current {
            *state = Some(CommandState::Failed);
            self.refused = Some(Refusal {
                command_id: c.command_id,
                goal_map_from_base: c.goal_map_from_base,
                at: now,
                reason,
            });
        }
    }

    /// Marks the current command canceled, unless it already ended.
    pub fn cancel(&mut self) {
        if let Some((_, state @ (None | Some(CommandState::Executing)))) = &mut self.current {
            *state = Some(CommandState::Canceled);
        }
    }

    /// The robot answers a command: accepted (now executing) or refused
    /// (remembered). Answers to earlier commands are accepted and change nothing.
    pub fn acknowledge(&mut self, now: Stamp, ack: &CommandAck) -> Result<(), ServerError> {
        let current = self.current.as_ref().is_some_and(|(c, _)| c.command_id == ack.command_id);
        if current {
            if !ack.accepted {
                let reason = if ack.reason.is_empty() { "refused".into() } else { ack.reason.clone() };
                self.refuse(now, reason);
            } else if let Some((_, state @ None)) = &mut self.current {
                *state = Some(CommandState::Executing);
            }
            return Ok(());
        }
        if self.known(ack.command_id) {
            return Ok(());
        }
        Err(ServerError::UnknownCommand { field: "command_ack.command_id", command_id: ack.command_id })
    }

    /// The robot reports progress. Reports on earlier commands (e.g. `CANCELED`
    /// when a newer one replaced them) are accepted and change nothing.
    pub fn progress(&mut self, now: Stamp, p: &CommandProgress) -> Result<(), ServerError> {
        let current = self.current.as_ref().is_some_and(|(c, _)| c.command_id == p.command_id);
        if current {
            if p.state == CommandState::Failed {
                let reason = if p.detail.is_empty() { "failed".into() } else { p.detail.clone() };
                self.refuse(now, reason);
            } else if let Some((_, state)) = &mut self.current {
                *state = Some(p.state);
            }
            return Ok(());
        }
        if self.known(p.command_id) {
            return Ok(());
        }
        Err(ServerError::UnknownCommand { field: "command_progress.command_id", command_id: p.command_id })
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;
    use soundmap_proto::RepositionReason;

    use super::*;

    fn command(id: u64, x: f64) -> RepositionCommand {
        RepositionCommand {
            command_id: id,
            goal_map_from_base: Isometry3::translation(x, 0.0, 0.0),
            look_at_in_map: Point3::origin(),
            reason: RepositionReason::ThetaOutOfBand,
            detail: String::new(),
            deadline: Stamp::from_ns(10_000),
            issued: Stamp::ZERO,
        }
    }

    fn ack(id: u64, accepted: bool) -> CommandAck {
        CommandAck { command_id: id, accepted, reason: String::new() }
    }

    fn report(id: u64, state: CommandState) -> CommandProgress {
        CommandProgress { command_id: id, state, distance_remaining_m: None, detail: "stuck".into() }
    }

    #[test]
    fn reports_follow_the_current_command_and_earlier_ones_are_ignored() {
        let mut log = CommandLog::default();
        let now = Stamp::from_ns(100);
        assert!(log.acknowledge(now, &ack(1, true)).is_err(), "never issued");
        log.issue(command(1, 1.0));
        assert_eq!(log.active_goal(now).map(|g| g.translation.x), Some(1.0), "sent, not yet acked");
        log.acknowledge(now, &ack(1, true)).unwrap();
        assert_eq!(log.current.as_ref().unwrap().1, Some(CommandState::Executing));
        log.issue(command(2, 2.0));
        // The replaced command ends CANCELED on the robot: accepted, changes nothing.
        log.progress(now, &report(1, CommandState::Canceled)).unwrap();
        assert_eq!(log.current.as_ref().unwrap().1, None);
        assert_eq!(log.active_goal(now).map(|g| g.translation.x), Some(2.0));
        assert!(log.active_goal(Stamp::from_ns(10_001)).is_none(), "deadline passed");
        log.progress(now, &report(2, CommandState::Succeeded)).unwrap();
        assert!(log.active_goal(now).is_none());
        assert!(log.cancellable().is_none());
        assert!(matches!(
            log.progress(now, &report(7, CommandState::Executing)),
            Err(ServerError::UnknownCommand { field: "command_progress.command_id", command_id: 7 })
        ));
    }

    #[test]
    fn refusals_and_failures_are_remembered() {
        let mut log = CommandLog::default();
        log.issue(command(1, 1.0));
        log.acknowledge(Stamp::from_ns(5), &ack(1, false)).unwrap();
        let r = log.refused.clone().unwrap();
        assert_eq!((r.command_id, r.at, r.reason.as_str()), (1, Stamp::from_ns(5), "refused"));
        assert!(log.active_goal(Stamp::from_ns(6)).is_none());
        log.issue(command(2, 3.0));
        log.progress(Stamp::from_ns(9), &report(2, CommandState::Failed)).unwrap();
        let r = log.refused.clone().unwrap();
        assert_eq!((r.command_id, r.goal_map_from_base.translation.x, r.reason.as_str()), (2, 3.0, "stuck"));
        assert_eq!(log.current.as_ref().unwrap().1, Some(CommandState::Failed));
    }
}

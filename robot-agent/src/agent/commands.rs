//! Command bookkeeping of the agent core: which reposition command the robot
//! executes, what the coordinator is told about each, and what the navigator is
//! asked to do. Pure.
//!
//! Rules:
//! - a command whose deadline has passed on arrival is refused here, without
//!   bothering the navigator; an invalid one likewise;
//! - any other command goes to the navigator, whose answer (accept or refuse) is
//!   relayed as the command's acknowledgement;
//! - a newer accepted command replaces the active one (the navigator reports the
//!   older one `Canceled`);
//! - a cancel names the active command, or it is ignored (and reported);
//! - progress is relayed only for commands the navigator accepted, so a confused
//!   navigator cannot report on commands the coordinator never sent.

use std::collections::VecDeque;

use soundmap_proto::{CommandAck, CommandProgress, CommandState, RepositionCommand, Stamp};

/// Accepted commands remembered for progress reports (the active one and the
/// ones it replaced, whose final `Canceled` may still come).
const REMEMBERED: usize = 16;

/// What the bookkeeping decided for one input.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Decision {
    /// Tell the coordinator.
    Reply(CommandAck),
    /// Ask the navigator to drive to this goal.
    Start(RepositionCommand),
    /// Ask the navigator to stop this command.
    Cancel { command_id: u64, reason: String },
    /// Relay this progress.
    Progress(CommandProgress),
    /// Nothing to do; why, for the log.
    Ignore(String),
}

/// Commands in flight.
#[derive(Clone, Debug, Default)]
pub(crate) struct CommandBook {
    /// Handed to the navigator, awaiting its answer.
    awaiting: Option<u64>,
    /// The command being executed.
    active: Option<u64>,
    /// Accepted commands, newest last.
    accepted: VecDeque<u64>,
}

impl CommandBook {
    /// A reposition command from the coordinator.
    pub(crate) fn command(&mut self, cmd: RepositionCommand, now: Stamp) -> Decision {
        if cmd.deadline.as_ns() != 0 && now > cmd.deadline {
            return Decision::Reply(CommandAck {
                command_id: cmd.command_id,
                accepted: false,
                reason: format!("deadline {} already passed (now {now})", cmd.deadline),
            });
        }
        self.awaiting = Some(cmd.command_id);
        Decision::Start(cmd)
    }

    /// A command that failed validation.
    pub(crate) fn invalid(&mut self, command_id: u64, error: &str) -> Decision {
        Decision::Reply(CommandAck {
            command_id,
            accepted: false,
            reason: format!("invalid command: {error}"),
        })
    }

    /// The navigator's answer to a started command.
    pub(crate) fn answer(&mut self, ack: CommandAck) -> Decision {
        if self.awaiting != Some(ack.command_id) {
            return Decision::Ignore(format!(
                "the navigator answered command {}, which it was not asked to start",
                ack.command_id
            ));
        }
        self.awaiting = None;
        if ack.accepted {
            self.active = Some(ack.command_id);
            if self.accepted.len() == REMEMBERED {
                self.accepted.pop_front();
            }
            self.accepted.push_back(ack.command_id);
        }
        Decision::Reply(ack)
    }

    /// The coordinator cancels a command.
    pub(crate) fn cancel(&mut self, command_id: u64, reason: String) -> Decision {
        if self.active == Some(command_id) {
            Decision::Cancel { command_id, reason }
        } else {
            Decision::Ignore(format!(
                "cancel of command {command_id} ignored: it is not the active command ({})",
                self.active.map_or("none".to_owned(), |a| a.to_string())
            ))
        }
    }

    /// Progress from the navigator. Unknown distances (non-finite or negative) become `None`.
    pub(crate) fn progress(&mut self, mut p: CommandProgress) -> Decision {
        if !self.accepted.contains(&p.command_id) {
            return Decision::Ignore(format!(
                "progress of command {} ignored: the navigator never accepted it",
                p.command_id
            ));
        }
        p.distance_remaining_m = p.distance_remaining_m.filter(|d| d.is_finite() && *d >= 0.0);
        if p.state != CommandState::Executing && self.active == Some(p.command_id) {
            self.active = None;
        }
        Decision::Progress(p)
    }

    /// The command being executed.
    pub(crate) fn active(&self) -> Option<u64> {
        self.active
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Point3};
    use soundmap_proto::RepositionReason;

    use super::*;

    fn cmd(id: u64, deadline_ns: i64) -> RepositionCommand {
        RepositionCommand {
            command_id: id,
            goal_map_from_base: Isometry3::translation(1.0, 2.0, 0.0),
            look_at_in_map: Point3::new(3.0, 3.0, 1.0),
            reason: RepositionReason::ThetaOutOfBand,
            detail: String::new(),
            deadline: Stamp::from_ns(deadline_ns),
            issued: Stamp::from_ns(1),
        }
    }

    fn progress(id: u64, state: CommandState, d: f64) -> CommandProgress {
        CommandProgress { command_id: id, state, distance_remaining_m: Some(d), detail: String::new() }
    }

    #[test]
    fn late_commands_are_refused_without_the_navigator() {
        let mut b = CommandBook::default();
        let Decision::Reply(a) = b.command(cmd(1, 100), Stamp::from_ns(200)) else { panic!() };
        assert!(!a.accepted && a.reason.contains("deadline"), "{a:?}");
        assert_eq!(b.active(), None);
    }

    #[test]
    fn accepted_replaced_cancelled_and_finished() {
        let mut b = CommandBook::default();
        assert!(matches!(b.command(cmd(1, 0), Stamp::from_ns(5)), Decision::Start(_)));
        let ok = |id| CommandAck { command_id: id, accepted: true, reason: String::new() };
        assert_eq!(b.answer(ok(1)), Decision::Reply(ok(1)));
        assert!(matches!(b.answer(ok(1)), Decision::Ignore(_)), "answered twice");
        assert_eq!(b.active(), Some(1));
        assert!(matches!(b.command(cmd(2, 0), Stamp::from_ns(6)), Decision::Start(_)));
        b.answer(ok(2));
        // The replaced command's final report still goes through.
        assert!(matches!(b.progress(progress(1, CommandState::Canceled, 1.0)), Decision::Progress(_)));
        assert_eq!(b.active(), Some(2));
        assert!(matches!(b.cancel(1, "old".into()), Decision::Ignore(_)));
        assert!(matches!(b.cancel(2, "lost".into()), Decision::Cancel { command_id: 2, .. }));
        let Decision::Progress(p) = b.progress(progress(2, CommandState::Canceled, f64::NAN)) else {
            panic!()
        };
        assert_eq!(p.distance_remaining_m, None, "unknown distance");
        assert_eq!(b.active(), None);
        assert!(matches!(b.progress(progress(9, CommandState::Executing, 1.0)), Decision::Ignore(_)));
    }

    #[test]
    fn refusals_by_the_navigator_are_relayed() {
        let mut b = CommandBook::default();
        b.command(cmd(3, 0), Stamp::from_ns(5));
        let no = CommandAck { command_id: 3, accepted: false, reason: "recorded robot".into() };
        assert_eq!(b.answer(no.clone()), Decision::Reply(no));
        assert_eq!(b.active(), None);
        assert!(matches!(b.progress(progress(3, CommandState::Executing, 1.0)), Decision::Ignore(_)));
    }
}

//! The agent core: what a robot sends the coordinator and what it does with
//! the coordinator's answers, with no I/O (in the style of quinn-proto's
//! `Connection`).
//!
//! Inputs are handled, outputs are polled, and time is passed in: nothing here
//! reads a clock, a socket or a file. The live agent (`soundmap-agent run`),
//! the simulator's robots and the replay all drive this one core, so what the
//! simulation measures is the stream a robot sends.
//!
//! | input | from |
//! |---|---|
//! | [`Agent::handle_hop`] | a hop's tracked DoAs (own pipeline or ODAS), stamped |
//! | [`Agent::handle_pose`] | a SLAM pose (`map_from_base`), stamped |
//! | [`Agent::handle_coordinator`] | the stream: connected, acknowledgements, commands, cancels, errors |
//! | [`Agent::handle_navigation`] | the navigator: its answer to a goal, its progress |
//! | [`Agent::handle_timeout`] | time passing (see [`Agent::poll_timeout`]) |
//!
//! | output | to |
//! |---|---|
//! | [`Agent::poll_observation`] | the next observation to send on the current stream (sequenced) |
//! | [`Agent::poll_reply`] | command acknowledgements and progress for the coordinator |
//! | [`Agent::poll_goal`] | goals, cancels and the latest pose for the navigator |
//! | [`Agent::poll_event`] | what the operator should know (dropped hops, ignored messages) |
//! | [`Agent::poll_timeout`] | when to call [`Agent::handle_timeout`] next |
//!
//! What the core owns:
//! - **the σ floor**: each DoA's angular σ is combined in quadrature with the
//!   floor (a DoA without σ, e.g. from ODAS, keeps none);
//! - **pose attachment**: a hop waits until the pose at its stamp can be
//!   interpolated (linear + SLERP), at most `max_pose_wait_s` after its stamp;
//!   a hop that cannot get a pose (gap, outside the poses) is dropped and
//!   reported;
//! - **silence filtering** ([`SilenceFilter`]), after attachment;
//! - **sequence numbers and the unacknowledged buffer** ([`ObservationBuffer`]):
//!   a new stream resends everything unacknowledged, oldest first;
//! - **command bookkeeping** (accept / refuse / progress / cancel; see
//!   `commands` rules);
//! - **the hello** the link opens each stream with.

mod buffer;
mod commands;
mod silence;

use std::collections::VecDeque;

use soundmap_proto::{
    ArrayInfo, CommandAck, CommandProgress, Hello, Observation, RepositionCommand, RobotId, Stamp,
    TrackedDoa, ValidationError,
};

pub use buffer::ObservationBuffer;
pub use silence::SilenceFilter;

use crate::AgentError;
use crate::array::{ArrayGeometry, presets};
use crate::navigator::Navigator;
use crate::pose::{Attached, Attacher, PoseBuffer, PoseBufferConfig, PoseLookupError, StampedPose};
use commands::{CommandBook, Decision};

/// Replies and events kept while nobody polls them; the oldest go beyond.
const QUEUE_LIMIT: usize = 1024;

/// Settings of the core.
#[derive(Clone, Debug, PartialEq)]
pub struct CoreConfig {
    /// Poses kept and how they are interpolated.
    pub pose_buffer: PoseBufferConfig,
    /// Longest a hop waits for the pose after its stamp, measured as `now − stamp` (s).
    pub max_pose_wait_s: f64,
    /// Most hops waiting for their pose; the oldest is dropped beyond it.
    pub max_waiting_hops: usize,
    /// Most observations kept unacknowledged; the oldest is dropped beyond it.
    pub buffer_capacity: usize,
    /// Floor of the DoAs' angular σ, combined in quadrature (rad).
    pub doa_sigma_floor_rad: f64,
}

impl Default for CoreConfig {
    /// Pose buffer defaults, 0.5 s pose wait, 4096 waiting hops, 1024 unacknowledged
    /// observations, σ floor 1°.
    fn default() -> Self {
        CoreConfig {
            pose_buffer: PoseBufferConfig::default(),
            max_pose_wait_s: 0.5,
            max_waiting_hops: 4096,
            buffer_capacity: 1024,
            doa_sigma_floor_rad: 1f64.to_radians(),
        }
    }
}

/// A message from the coordinator other than welcome and acknowledgements.
#[derive(Clone, Debug, PartialEq)]
pub enum CoordinatorEvent {
    /// Drive the base to a goal (replaces any older command).
    Reposition(RepositionCommand),
    /// A reposition command that failed validation (the robot should refuse it).
    InvalidReposition {
        /// Its id.
        command_id: u64,
        /// What is wrong with it.
        error: ValidationError,
    },
    /// Stop executing a command.
    Cancel {
        /// The command.
        command_id: u64,
        /// Why.
        reason: String,
    },
    /// The coordinator dropped one of our messages.
    StreamError(StreamErrorReport),
}

/// A `StreamError` from the coordinator.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StreamErrorReport {
    /// google.rpc.Code value (3 INVALID_ARGUMENT, 9 FAILED_PRECONDITION, 11 OUT_OF_RANGE, …).
    pub code: i32,
    /// Path of the offending field, e.g. `observation.doas[1].direction_in_array`.
    pub field: String,
    /// What is wrong.
    pub message: String,
    /// Sequence of the offending observation, when it was one.
    pub sequence: Option<u64>,
}

/// A message from the coordinator's side of the stream, as the core sees it.
#[derive(Clone, Debug, PartialEq)]
pub enum FromCoordinator {
    /// A new stream is open (welcome received): everything unacknowledged is sent again.
    Connected,
    /// Observations up to this sequence are acknowledged.
    Ack {
        /// Highest acknowledged sequence.
        up_to_sequence: u64,
    },
    /// A command, a cancel, a rejected command or a stream error.
    Event(CoordinatorEvent),
}

/// What the coordinator is told about commands.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    /// Accepted or refused.
    Ack(CommandAck),
    /// Progress of an accepted command.
    Progress(CommandProgress),
}

/// What the navigator is asked to do, or told.
#[derive(Clone, Debug, PartialEq)]
pub enum NavigatorInput {
    /// Start driving to this goal (replacing any older one); answer with
    /// [`Navigation::Answer`].
    Start(RepositionCommand),
    /// Stop driving to this command's goal.
    Cancel {
        /// The command.
        command_id: u64,
        /// Why.
        reason: String,
    },
    /// The robot's latest pose (every pose the core received, newest only).
    Pose(StampedPose),
}

/// What the navigator reports.
#[derive(Clone, Debug, PartialEq)]
pub enum Navigation {
    /// Its answer to a [`NavigatorInput::Start`].
    Answer(CommandAck),
    /// Progress of an accepted command.
    Progress(CommandProgress),
}

/// Something the operator should know; drivers log or count these.
#[derive(Clone, Debug, PartialEq)]
pub enum AgentEvent {
    /// A hop got no pose and was not sent.
    HopWithoutPose {
        /// The hop's DoA stamp.
        stamp: Stamp,
        /// Why.
        reason: PoseLookupError,
    },
    /// A message was ignored (a cancel of another command, progress of an unknown one…).
    Ignored(String),
    /// The coordinator refused one of the robot's messages.
    StreamError(StreamErrorReport),
    /// A command was refused (by the core or the navigator).
    CommandRefused {
        /// The command.
        command_id: u64,
        /// Why.
        reason: String,
    },
}

/// Counters of the core.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CoreStats {
    /// Hops handled.
    pub hops: u64,
    /// Hops that got a pose.
    pub hops_with_pose: u64,
    /// Hops dropped for want of a pose.
    pub hops_without_pose: u64,
    /// Silent hops not sent.
    pub silent_hops: u64,
    /// Observations produced (sequenced).
    pub observations: u64,
    /// Observations sent for the first time.
    pub sent: u64,
    /// Observations acknowledged.
    pub acknowledged: u64,
    /// Observations awaiting acknowledgement.
    pub pending: usize,
    /// Observations dropped because the unacknowledged buffer was full.
    pub dropped: u64,
    /// Observations sent again on a new stream.
    pub resent: u64,
    /// Reposition commands received (valid or not).
    pub commands: u64,
    /// Stream errors received.
    pub stream_errors: u64,
}

/// The hello an agent opens each stream with. The array's preset name is
/// given when the array is a preset. It declares no track layout (no
/// signature bands, no `max_tracks`, as for ODAS input); an agent running its
/// own pipeline declares it with
/// [`PipelineConfig::declare_tracks`](crate::pipeline::PipelineConfig::declare_tracks).
pub fn hello(robot_id: RobotId, array: &ArrayGeometry, software_version: String) -> Hello {
    Hello {
        robot_id,
        array: ArrayInfo {
            base_from_array: array.base_from_array,
            microphone_count: array.channels() as u32,
            preset: presets::NAMES.contains(&array.name.as_str()).then(|| array.name.clone()),
            microphone_positions: array.positions().collect(),
            srp_band_hz: None,
            direct_path_elevations: false,
        },
        software_version,
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    }
}

/// The agent core (see the [module docs](self)).
#[derive(Debug)]
pub struct Agent {
    hello: Hello,
    config: CoreConfig,
    attacher: Attacher<Vec<TrackedDoa>>,
    attached: Vec<Attached<Vec<TrackedDoa>>>,
    silence: SilenceFilter,
    buffer: ObservationBuffer,
    /// Highest sequence ever sent (to count resends).
    highest_sent: u64,
    commands: CommandBook,
    replies: VecDeque<Reply>,
    goals: VecDeque<NavigatorInput>,
    /// The newest pose not yet handed to the navigator.
    pose_for_navigator: Option<StampedPose>,
    events: VecDeque<AgentEvent>,
    stats: CoreStats,
}

impl Agent {
    /// A core for the robot that says `hello`; `pose_source` names the pose
    /// feed in errors (e.g. `agent.toml: pose`).
    pub fn new(hello: Hello, config: CoreConfig, pose_source: &str) -> Result<Self, AgentError> {
        let buffer = PoseBuffer::new(pose_source, config.pose_buffer)?;
        Ok(Agent {
            hello,
            attacher: Attacher::new(buffer, config.max_pose_wait_s, config.max_waiting_hops),
            attached: Vec::new(),
            silence: SilenceFilter::new(),
            buffer: ObservationBuffer::new(config.buffer_capacity),
            highest_sent: 0,
            commands: CommandBook::default(),
            replies: VecDeque::new(),
            goals: VecDeque::new(),
            pose_for_navigator: None,
            events: VecDeque::new(),
            stats: CoreStats::default(),
            config,
        })
    }

    /// The hello each stream opens with.
    pub fn hello(&self) -> &Hello {
        &self.hello
    }

    /// The robot's id.
    pub fn robot_id(&self) -> &RobotId {
        &self.hello.robot_id
    }

    /// Counters.
    pub fn stats(&self) -> CoreStats {
        CoreStats { pending: self.buffer.len(), dropped: self.buffer.dropped(), ..self.stats }
    }

    /// The pose buffer (for drivers that report the poses' extent).
    pub fn poses(&self) -> &PoseBuffer {
        self.attacher.buffer()
    }

    /// The command being executed, if any.
    pub fn active_command(&self) -> Option<u64> {
        self.commands.active()
    }

    // ------------------------------------------------------------ inputs

    /// A hop's tracked DoAs at `stamp` (the DoA stamp). The σ floor is applied
    /// here, and σ kept within the contract's range; the hop waits for its pose.
    pub fn handle_hop(&mut self, now: Stamp, stamp: Stamp, mut doas: Vec<TrackedDoa>) {
        self.stats.hops += 1;
        let floor = self.config.doa_sigma_floor_rad.max(0.0);
        let (min_sigma, max_sigma) = soundmap_proto::messages::ANGULAR_SIGMA_RANGE_RAD;
        for d in &mut doas {
            d.angular_sigma_rad = d
                .angular_sigma_rad
                .map(|s| s.hypot(floor))
                .filter(|s| s.is_finite() && *s > 0.0)
                .map(|s| s.clamp(min_sigma, max_sigma));
        }
        self.attacher.push_frame(stamp, doas, &mut self.attached);
        self.handle_timeout(now);
    }

    /// A SLAM pose of the base. Stamps must increase; an out-of-order pose is an
    /// error naming the pose source (the core keeps its state).
    pub fn handle_pose(&mut self, now: Stamp, pose: StampedPose) -> Result<(), AgentError> {
        self.attacher.push_pose(pose.clone())?;
        self.pose_for_navigator = Some(pose);
        self.handle_timeout(now);
        Ok(())
    }

    /// A whole recorded trajectory (e.g. a TUM file): every pose, then no more.
    pub fn handle_trajectory(&mut self, now: Stamp, poses: Vec<StampedPose>) -> Result<(), AgentError> {
        for p in poses {
            self.handle_pose(now, p)?;
        }
        self.finish_poses(now);
        Ok(())
    }

    /// No more poses will come (the end of a recorded trajectory): hops after
    /// the last pose are dropped instead of waiting.
    pub fn finish_poses(&mut self, now: Stamp) {
        self.attacher.finish_poses();
        self.handle_timeout(now);
    }

    /// A message from the coordinator's side of the stream.
    pub fn handle_coordinator(&mut self, now: Stamp, message: FromCoordinator) {
        match message {
            FromCoordinator::Connected => {
                self.buffer.restart();
                // Replies belonged to the previous stream's commands.
                self.replies.clear();
            }
            FromCoordinator::Ack { up_to_sequence } => {
                self.stats.acknowledged += self.buffer.ack(up_to_sequence) as u64;
            }
            FromCoordinator::Event(CoordinatorEvent::Reposition(cmd)) => {
                self.stats.commands += 1;
                let d = self.commands.command(cmd, now);
                self.apply(d);
            }
            FromCoordinator::Event(CoordinatorEvent::InvalidReposition { command_id, error }) => {
                self.stats.commands += 1;
                let d = self.commands.invalid(command_id, &error.to_string());
                self.apply(d);
            }
            FromCoordinator::Event(CoordinatorEvent::Cancel { command_id, reason }) => {
                let d = self.commands.cancel(command_id, reason);
                self.apply(d);
            }
            FromCoordinator::Event(CoordinatorEvent::StreamError(e)) => {
                self.stats.stream_errors += 1;
                push_bounded(&mut self.events, AgentEvent::StreamError(e));
            }
        }
    }

    /// A report of the navigator.
    pub fn handle_navigation(&mut self, _now: Stamp, report: Navigation) {
        let d = match report {
            Navigation::Answer(ack) => self.commands.answer(ack),
            Navigation::Progress(p) => self.commands.progress(p),
        };
        self.apply(d);
    }

    /// Time passed: hops whose pose wait is over are resolved.
    pub fn handle_timeout(&mut self, now: Stamp) {
        self.attacher.poll(now, &mut self.attached);
        for a in std::mem::take(&mut self.attached) {
            match a {
                Attached::Ready { pose, payload } => {
                    self.stats.hops_with_pose += 1;
                    if !self.silence.keep(&payload, pose.stamp) {
                        self.stats.silent_hops += 1;
                        continue;
                    }
                    self.stats.observations += 1;
                    self.buffer.push(Observation {
                        sequence: 0,
                        stamp: pose.stamp,
                        map_from_base: pose.map_from_base,
                        pose_covariance: pose.covariance,
                        doas: payload,
                    });
                }
                Attached::Dropped { stamp, reason, .. } => {
                    self.stats.hops_without_pose += 1;
                    push_bounded(&mut self.events, AgentEvent::HopWithoutPose { stamp, reason });
                }
            }
        }
    }

    fn apply(&mut self, d: Decision) {
        match d {
            Decision::Reply(ack) => {
                if !ack.accepted {
                    let e =
                        AgentEvent::CommandRefused { command_id: ack.command_id, reason: ack.reason.clone() };
                    push_bounded(&mut self.events, e);
                }
                push_bounded(&mut self.replies, Reply::Ack(ack));
            }
            Decision::Start(cmd) => self.goals.push_back(NavigatorInput::Start(cmd)),
            Decision::Cancel { command_id, reason } => {
                self.goals.push_back(NavigatorInput::Cancel { command_id, reason })
            }
            Decision::Progress(p) => push_bounded(&mut self.replies, Reply::Progress(p)),
            Decision::Ignore(why) => push_bounded(&mut self.events, AgentEvent::Ignored(why)),
        }
    }

    // ------------------------------------------------------------ outputs

    /// The next observation to send on the current stream (oldest unsent first),
    /// with its sequence number; it counts as sent.
    pub fn poll_observation(&mut self) -> Option<Observation> {
        let obs = self.buffer.next_unsent()?.clone();
        self.buffer.mark_sent(obs.sequence);
        if obs.sequence <= self.highest_sent {
            self.stats.resent += 1;
        } else {
            self.highest_sent = obs.sequence;
            self.stats.sent += 1;
        }
        Some(obs)
    }

    /// The next acknowledgement or progress report for the coordinator.
    pub fn poll_reply(&mut self) -> Option<Reply> {
        self.replies.pop_front()
    }

    /// The next input for the navigator: goals and cancels in order, then the
    /// newest pose received since the last call.
    pub fn poll_goal(&mut self) -> Option<NavigatorInput> {
        self.goals.pop_front().or_else(|| self.pose_for_navigator.take().map(NavigatorInput::Pose))
    }

    /// The next event for the operator.
    pub fn poll_event(&mut self) -> Option<AgentEvent> {
        self.events.pop_front()
    }

    /// When a waiting hop's pose wait ends: call [`Agent::handle_timeout`] then.
    pub fn poll_timeout(&self) -> Option<Stamp> {
        self.attacher.next_deadline()
    }

    /// Hops waiting for their pose.
    pub fn waiting_hops(&self) -> usize {
        self.attacher.pending()
    }

    /// True when nothing awaits acknowledgement.
    pub fn all_acknowledged(&self) -> bool {
        self.buffer.is_empty()
    }

    /// Hands goals and poses to `navigator` and its answers and progress back
    /// to the core: the one way every driver connects its navigator.
    pub fn exchange_with(&mut self, navigator: &mut dyn Navigator, now: Stamp) {
        while let Some(input) = self.poll_goal() {
            match input {
                NavigatorInput::Start(cmd) => {
                    let ack = navigator.submit(&cmd, now);
                    self.handle_navigation(now, Navigation::Answer(ack));
                }
                NavigatorInput::Cancel { command_id, reason } => navigator.cancel(command_id, &reason, now),
                NavigatorInput::Pose(p) => navigator.observe_pose(&p),
            }
        }
        let mut progress = Vec::new();
        navigator.poll_progress(now, &mut progress);
        for p in progress {
            self.handle_navigation(now, Navigation::Progress(p));
        }
    }
}

fn push_bounded<T>(q: &mut VecDeque<T>, item: T) {
    if q.len() == QUEUE_LIMIT {
        q.pop_front();
    }
    q.push_back(item);
}

#[cfg(test)]
mod tests;

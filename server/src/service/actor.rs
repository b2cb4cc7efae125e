//! The one task that owns the [`Coordinator`]. It runs on its own OS thread
//! (its work is CPU-bound and must not queue behind hundreds of stream tasks).
//! Handlers send it requests over a channel; it processes them in batches (so
//! that under load one estimate covers many observations), publishes
//! estimates, and answers each stream in order: stream errors, then commands,
//! then the acknowledgement.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use soundmap_proto::{CommandAck, CommandProgress, CommandState, Hello, Observation, RobotId, Stamp, wire};
use tokio::sync::{broadcast, mpsc, oneshot};

use super::convert::estimate_to_wire;
use super::metrics::Metrics;
use super::status::to_stream_error;
use super::telemetry::{PlannerLabel, RejectLabel, RobotLabel, StateLabel, reject_reason};
use crate::clock::Clock;
use crate::coordinator::{
    ConnId, Coordinator, Outbound, PlanKind, PlannerStatus, PositioningSettings, PositioningUpdate, Welcome,
};
use crate::error::ServerError;

/// Most requests handled before an estimate is computed.
const MAX_BATCH: usize = 1024;
/// A planner decision that repeats the previous one is logged at most this often.
const PLANNER_LOG_PERIOD: Duration = Duration::from_secs(10);

/// What handlers ask of the coordinator task.
#[derive(Debug)]
pub enum Request {
    /// A stream said hello; `outbound` carries everything sent back to it.
    Connect {
        /// The validated hello.
        hello: Hello,
        /// Identity proven by the transport.
        identity: Option<RobotId>,
        /// The stream's outbound channel.
        outbound: mpsc::Sender<wire::CoordinatorMessage>,
        /// Where the answer goes.
        reply: oneshot::Sender<Result<Welcome, ServerError>>,
    },
    /// A validated observation.
    Observation {
        /// Stream.
        conn: ConnId,
        /// The observation.
        obs: Observation,
        /// When the handler received it.
        received: Instant,
    },
    /// A message that failed validation (or a second hello).
    Rejected {
        /// Stream.
        conn: ConnId,
        /// Its sequence number, when it was an observation.
        sequence: Option<u64>,
        /// What was wrong.
        error: ServerError,
    },
    /// A heartbeat.
    Heartbeat {
        /// Stream.
        conn: ConnId,
    },
    /// A command acknowledgement.
    CommandAck {
        /// Stream.
        conn: ConnId,
        /// The ack.
        ack: CommandAck,
    },
    /// Command progress.
    CommandProgress {
        /// Stream.
        conn: ConnId,
        /// The report.
        progress: CommandProgress,
    },
    /// The stream closed.
    Disconnect {
        /// Stream.
        conn: ConnId,
    },
    /// Monitoring snapshot.
    GetState {
        /// Where the answer goes.
        reply: oneshot::Sender<wire::CoordinatorState>,
    },
    /// The operator changes active positioning.
    SetActivePositioning {
        /// Fields to change.
        update: PositioningUpdate,
        /// Where the new settings (or the error) go.
        reply: oneshot::Sender<Result<PositioningSettings, ServerError>>,
    },
    /// Choose the source active positioning serves (0: all).
    SetFocus {
        /// The source.
        source_id: u64,
        /// The focus in force, or why not.
        reply: oneshot::Sender<Result<u64, ServerError>>,
    },
    /// Housekeeping (liveness) is due.
    Tick,
    /// Finish the requests already queued, then stop.
    Stop,
}

/// Per-stream bookkeeping of the task.
struct Stream {
    outbound: mpsc::Sender<wire::CoordinatorMessage>,
    /// Highest observation sequence handled since the last acknowledgement.
    to_ack: Option<u64>,
}

/// The coordinator task.
pub struct Actor {
    coordinator: Coordinator,
    clock: Arc<dyn Clock>,
    streams: HashMap<ConnId, Stream>,
    estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
    sink: Option<mpsc::UnboundedSender<Arc<wire::SourceEstimate>>>,
    /// Lines of accepted observations (`output.observations_jsonl`), written before their acknowledgements.
    observation_log: Option<super::sink::LineFile>,
    /// Snapshots for the state store, bound counters, rate-limited warnings.
    upkeep: super::state_upkeep::Upkeep,
    /// The live view and recording (`[foxglove]`, `[record]`).
    viz: Option<crate::viz::VizSender>,
    metrics: Arc<Metrics>,
    /// Receipt times of observations waiting for an estimate.
    receipts: Vec<Instant>,
    /// The planner decision last logged: (kind, reason key, when).
    planner_logged: Option<(PlanKind, &'static str, Instant)>,
    /// The planner decision last counted in the metrics: (decided, kind, reason key).
    planner_counted: Option<(Stamp, PlanKind, &'static str)>,
    /// Source tracks (born, restarted) last counted in the metrics.
    tracks_counted: (u64, u64),
}

impl std::fmt::Debug for Actor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Actor").field("streams", &self.streams.len()).finish_non_exhaustive()
    }
}

impl Actor {
    /// A task around `coordinator`.
    pub fn new(
        coordinator: Coordinator,
        clock: Arc<dyn Clock>,
        estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
        sink: Option<mpsc::UnboundedSender<Arc<wire::SourceEstimate>>>,
        metrics: Arc<Metrics>,
    ) -> Self {
        Actor {
            coordinator,
            clock,
            streams: HashMap::new(),
            estimates,
            sink,
            observation_log: None,
            upkeep: super::state_upkeep::Upkeep::new(
                None,
                Duration::from_secs(1),
                metrics.clone(),
                Arc::new(super::ratelog::RateLog::new(Duration::from_secs(10))),
            ),
            viz: None,
            metrics,
            receipts: Vec::new(),
            planner_logged: None,
            planner_counted: None,
            tracks_counted: (0, 0),
        }
    }

    /// Also writes every accepted observation as a line to `log`.
    pub fn with_observation_log(mut self, log: Option<super::sink::LineFile>) -> Self {
        self.observation_log = log;
        self
    }

    /// Writes snapshots, counts bounds and rate-limits warnings with `upkeep`.
    pub fn with_upkeep(mut self, upkeep: super::state_upkeep::Upkeep) -> Self {
        self.upkeep = upkeep;
        self
    }

    /// Also feeds the live view and recording.
    pub fn with_viz(mut self, viz: Option<crate::viz::VizSender>) -> Self {
        self.viz = viz;
        self
    }

    /// Tells the live view what robot `conn` sent (accepted hellos, observations, command replies).
    fn viz_from(&self, now: Stamp, conn: ConnId, input: impl FnOnce() -> soundmap_proto::RobotInput) {
        if let (Some(v), Some(id)) = (&self.viz, self.coordinator.robot_of(conn)) {
            match input() {
                soundmap_proto::RobotInput::Hello(h) => v.hello(now, h),
                soundmap_proto::RobotInput::Observation(o) => v.observation(now, id.clone(), o),
                other => v.from_robot(now, id.clone(), other),
            }
        }
    }

    /// Runs on the calling thread until every request sender is gone or a
    /// [`Request::Stop`] arrives (requests queued before it are handled).
    pub fn run(mut self, mut requests: mpsc::Receiver<Request>) {
        let mut batch = Vec::with_capacity(MAX_BATCH);
        let mut stopping = false;
        while !stopping {
            let Some(first) = requests.blocking_recv() else { break };
            batch.push(first);
            while batch.len() < MAX_BATCH {
                match requests.try_recv() {
                    Ok(r) => batch.push(r),
                    Err(_) => break,
                }
            }
            let now = self.clock.now();
            let started = Instant::now();
            for r in batch.drain(..) {
                match r {
                    Request::Stop => stopping = true,
                    Request::Tick => self.housekeeping(),
                    r => self.handle(now, r),
                }
            }
            self.publish(now);
            self.dispatch();
            // Acknowledged observations are in the log first.
            if let Some(log) = self.observation_log.as_mut() {
                log.flush();
            }
            self.acknowledge();
            self.upkeep.after_batch(&self.coordinator, now);
            if stopping {
                self.upkeep.finish(&self.coordinator, now);
            }
            self.metrics.telemetry.batch_seconds.observe(started.elapsed().as_secs_f64());
            self.metrics.robot_streams.store(self.streams.len(), std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// A task that sends [`Request::Tick`] every `period` until the channel closes.
    pub async fn ticker(requests: mpsc::Sender<Request>, period: Duration) {
        let mut i = tokio::time::interval(period);
        i.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            i.tick().await;
            if requests.send(Request::Tick).await.is_err() {
                return;
            }
        }
    }

    fn housekeeping(&mut self) {
        let now = self.clock.now();
        for change in self.coordinator.tick(now) {
            tracing::info!(robot = %change.robot_id, liveness = ?change.liveness, "robot liveness changed");
        }
    }

    fn send(&mut self, conn: ConnId, msg: wire::CoordinatorMessage) {
        if let Some(s) = self.streams.get(&conn)
            && let Err(e) = s.outbound.try_send(msg)
        {
            super::metrics::LimitCounters::bump(&self.metrics.limits.outbound_dropped);
            soundmap_proto::warn_limited!(
                self.upkeep.ratelog,
                "outbound_full",
                "stream {conn}: outbound queue full or closed: {e}"
            );
        }
    }

    fn handle(&mut self, now: Stamp, request: Request) {
        match request {
            Request::Connect { hello, identity, outbound, reply } => {
                let viz_hello = self.viz.as_ref().map(|_| hello.clone());
                let result = self.coordinator.connect(now, hello, identity.as_ref());
                if let Ok(w) = &result {
                    if let Some(h) = viz_hello {
                        self.viz_from(now, w.conn, || soundmap_proto::RobotInput::Hello(h));
                    }
                    // A taken-over stale stream loses its outbound channel, which ends it.
                    self.streams.retain(|c, _| self.coordinator.is_current(*c));
                    let welcome = wire::CoordinatorMessage {
                        msg: Some(wire::coordinator_message::Msg::Welcome(wire::Welcome {
                            robot_id: w.robot_id.to_string(),
                            coordinator_version: concat!("soundmap-coordinator ", env!("CARGO_PKG_VERSION"))
                                .into(),
                            stale_after_ms: w.stale_after_ms,
                            resumed: w.resumed,
                        })),
                    };
                    // Queued before anything else can be sent on this stream.
                    let _ = outbound.try_send(welcome);
                    self.streams.insert(w.conn, Stream { outbound, to_ack: None });
                    tracing::info!(robot = %w.robot_id, conn = w.conn, resumed = w.resumed, "robot connected");
                }
                let _ = reply.send(result);
            }
            Request::Observation { conn, obs, received } => {
                let seq = obs.sequence;
                let line = match (&self.observation_log, self.coordinator.robot_of(conn)) {
                    (Some(_), Some(id)) => Some(super::sink::observation_line(id.as_str(), &obs)),
                    _ => None,
                };
                let robot = self.robot_label(conn);
                let viz_obs = self.viz.as_ref().map(|_| obs.clone());
                match self.coordinator.observe(now, conn, obs) {
                    Ok(()) => {
                        if let Some(o) = viz_obs {
                            self.viz_from(now, conn, || soundmap_proto::RobotInput::Observation(o));
                        }
                        self.metrics.telemetry.observations_accepted.get_or_create(&robot).inc();
                        self.receipts.push(received);
                        if let (Some(log), Some(line)) = (self.observation_log.as_mut(), line) {
                            log.push(&line);
                        }
                    }
                    Err(e) => {
                        self.count_rejected(robot, &e);
                        self.send(conn, to_stream_error(&e, seq));
                    }
                }
                self.mark_ack(conn, seq);
            }
            Request::Rejected { conn, sequence, error } => {
                if sequence.is_some() {
                    self.count_rejected(self.robot_label(conn), &error);
                    self.coordinator.note_rejected(now, conn);
                } else {
                    let _ = self.coordinator.heartbeat(now, conn);
                }
                self.send(conn, to_stream_error(&error, sequence.unwrap_or(0)));
                if let Some(seq) = sequence {
                    self.mark_ack(conn, seq);
                }
            }
            Request::Heartbeat { conn } => {
                if let Err(e) = self.coordinator.heartbeat(now, conn) {
                    self.send(conn, to_stream_error(&e, 0));
                }
            }
            Request::CommandAck { conn, ack } => {
                let state = if ack.accepted { "accepted" } else { "refused" };
                self.metrics.telemetry.commands.get_or_create(&StateLabel { state }).inc();
                if let Err(e) = self.coordinator.command_ack(now, conn, &ack) {
                    self.send(conn, to_stream_error(&e, 0));
                }
                self.viz_from(now, conn, || soundmap_proto::RobotInput::CommandAck(ack));
            }
            Request::CommandProgress { conn, progress } => {
                let state = match progress.state {
                    CommandState::Executing => "executing",
                    CommandState::Succeeded => "succeeded",
                    CommandState::Failed => "failed",
                    CommandState::Canceled => "canceled",
                };
                self.metrics.telemetry.commands.get_or_create(&StateLabel { state }).inc();
                if let Err(e) = self.coordinator.command_progress(now, conn, &progress) {
                    self.send(conn, to_stream_error(&e, 0));
                }
                self.viz_from(now, conn, || soundmap_proto::RobotInput::CommandProgress(progress));
            }
            Request::Disconnect { conn } => {
                if let Some(id) = self.coordinator.robot_of(conn) {
                    tracing::info!(robot = %id, conn, "robot stream closed");
                }
                self.coordinator.disconnect(now, conn);
                self.streams.remove(&conn);
            }
            Request::GetState { reply } => {
                let max = self.coordinator.config().server.max_state_entries;
                let _ = reply.send(self.upkeep.bound_state(self.snapshot(now), max));
            }
            Request::SetFocus { source_id, reply } => {
                let result = self.coordinator.set_focus(source_id);
                if result.is_ok() {
                    tracing::info!(source_id, "active positioning focus set (0: all sources)");
                }
                let _ = reply.send(result);
            }
            Request::SetActivePositioning { update, reply } => {
                let result = self.coordinator.set_active_positioning(now, &update);
                if let Ok(s) = &result {
                    tracing::info!(
                        enabled = s.enabled,
                        theta_min_deg = s.theta_min_deg,
                        theta_max_deg = s.theta_max_deg,
                        "active positioning set"
                    );
                }
                let _ = reply.send(result);
            }
            Request::Tick | Request::Stop => unreachable!("handled by run"),
        }
    }

    /// The robot of a stream, as a metrics label (empty before its hello).
    fn robot_label(&self, conn: ConnId) -> RobotLabel {
        RobotLabel { robot: self.coordinator.robot_of(conn).map(|id| id.to_string()).unwrap_or_default() }
    }

    fn count_rejected(&self, robot: RobotLabel, error: &ServerError) {
        let label = RejectLabel { robot: robot.robot, reason: reject_reason(error) };
        self.metrics.telemetry.observations_rejected.get_or_create(&label).inc();
    }

    fn mark_ack(&mut self, conn: ConnId, seq: u64) {
        if let Some(s) = self.streams.get_mut(&conn) {
            s.to_ack = Some(s.to_ack.map_or(seq, |a| a.max(seq)));
        }
    }

    fn publish(&mut self, now: Stamp) {
        let estimates = self.coordinator.estimate(now);
        let events = self.coordinator.source_track_events();
        if events != self.tracks_counted {
            let tracks = &self.metrics.telemetry.source_tracks;
            let (born, restarted) = (
                events.0.saturating_sub(self.tracks_counted.0),
                events.1.saturating_sub(self.tracks_counted.1),
            );
            tracks.get_or_create(&StateLabel { state: "born" }).inc_by(born);
            tracks.get_or_create(&StateLabel { state: "restarted" }).inc_by(restarted);
            self.tracks_counted = events;
        }
        if estimates.is_empty() {
            return;
        }
        self.metrics.telemetry.estimates_published.inc_by(estimates.len() as u64);
        for estimate in &estimates {
            let wire = Arc::new(estimate_to_wire(estimate));
            // No watcher is not an error.
            let _ = self.estimates.send(wire.clone());
            if let Some(v) = &self.viz {
                v.estimate(now, wire.clone());
            }
            if let Some(sink) = &self.sink {
                let _ = sink.send(wire);
            }
        }
        if !self.receipts.is_empty() {
            let published = Instant::now();
            let mut h = self.metrics.latency.lock().unwrap_or_else(|p| p.into_inner());
            for r in self.receipts.drain(..) {
                let latency = published.duration_since(r);
                h.record(latency);
                self.metrics.telemetry.estimate_latency.observe(latency.as_secs_f64());
            }
        }
    }

    /// Sends the commands and cancellations of this batch (before its acknowledgements).
    fn dispatch(&mut self) {
        for out in self.coordinator.take_outgoing() {
            let msg = match out.message {
                Outbound::Reposition(c) => {
                    tracing::info!(
                        robot = %out.robot_id,
                        command_id = c.command_id,
                        x = c.goal_map_from_base.translation.vector.x,
                        y = c.goal_map_from_base.translation.vector.y,
                        "reposition: {}",
                        c.detail
                    );
                    self.metrics.telemetry.commands.get_or_create(&StateLabel { state: "sent" }).inc();
                    wire::coordinator_message::Msg::Reposition(c.to_wire())
                }
                Outbound::Cancel { command_id, reason } => {
                    tracing::info!(robot = %out.robot_id, command_id, "cancel: {reason}");
                    self.metrics.telemetry.commands.get_or_create(&StateLabel { state: "cancel_sent" }).inc();
                    wire::coordinator_message::Msg::Cancel(wire::CancelCommand { command_id, reason })
                }
            };
            let msg = wire::CoordinatorMessage { msg: Some(msg) };
            if let Some(v) = &self.viz {
                v.to_robot(self.clock.now(), &out.robot_id, &msg);
            }
            self.send(out.conn, msg);
        }
        self.log_planner();
    }

    /// Logs holds and infeasibilities when they change, and a repeated one at
    /// most every [`PLANNER_LOG_PERIOD`].
    fn log_planner(&mut self) {
        let Some(s) = self.coordinator.planner_status() else { return };
        if self.planner_counted != Some((s.decided, s.kind, s.key)) {
            self.planner_counted = Some((s.decided, s.kind, s.key));
            let outcome = match s.kind {
                PlanKind::Planned => "planned",
                PlanKind::Hold => "hold",
                PlanKind::Infeasible => "infeasible",
            };
            let label = PlannerLabel { outcome, reason: s.key };
            self.metrics.telemetry.planner_decisions.get_or_create(&label).inc();
        }
        if s.kind == PlanKind::Planned {
            self.planner_logged = Some((s.kind, s.key, Instant::now()));
            return;
        }
        let repeated = self
            .planner_logged
            .is_some_and(|(k, key, at)| k == s.kind && key == s.key && at.elapsed() < PLANNER_LOG_PERIOD);
        if repeated {
            return;
        }
        match s.kind {
            PlanKind::Infeasible => tracing::warn!(reason = s.key, "planner: infeasible: {}", s.detail),
            _ => tracing::info!(reason = s.key, "planner: hold: {}", s.detail),
        }
        self.planner_logged = Some((s.kind, s.key, Instant::now()));
    }

    fn acknowledge(&mut self) {
        // Observations that led to no estimate (e.g. a lone robot) are not latency samples.
        self.receipts.clear();
        for s in self.streams.values_mut() {
            if let Some(seq) = s.to_ack.take() {
                let ack = wire::CoordinatorMessage {
                    msg: Some(wire::coordinator_message::Msg::ObservationAck(wire::ObservationAck {
                        up_to_sequence: seq,
                    })),
                };
                // Acks are cumulative: a dropped one is covered by the next.
                let _ = s.outbound.try_send(ack);
            }
        }
    }

    fn snapshot(&self, now: Stamp) -> wire::CoordinatorState {
        wire::CoordinatorState {
            now_ns: now.as_ns(),
            robots: self
                .coordinator
                .robots()
                .map(|(id, e)| {
                    e.status(self.coordinator.liveness_of(id, now).expect("known robot")).to_wire()
                })
                .collect(),
            sources: self.coordinator.latest_estimates().into_iter().map(estimate_to_wire).collect(),
            active_positioning: Some(self.coordinator.positioning().to_wire()),
            planner: self.coordinator.planner_status().map(PlannerStatus::to_wire),
            focus_source_id: self.coordinator.focus(),
            sound_map: self.coordinator.sound_map().map(mapped_sources).unwrap_or_default(),
        }
    }
}

/// The sound map as the Monitoring service shows it: live sources, then remembered ones.
fn mapped_sources(map: &crate::coordinator::sound_map::SoundMap) -> Vec<wire::MappedSource> {
    let vec3 = |p: nalgebra::Point3<f64>| soundmap_proto::wire::Vec3 { x: p.x, y: p.y, z: p.z };
    let live = map.sources().filter_map(|(id, first, last, e)| {
        let e = e?;
        Some(wire::MappedSource {
            source_id: id,
            position_m: Some(vec3(e.position_in_map)),
            covariance_m2: e.position_covariance().transpose().iter().copied().collect(),
            first_heard_ns: first.as_ns(),
            last_heard_ns: last.as_ns(),
            live: true,
        })
    });
    let remembered = map.remembered().map(|(id, p, first, last)| wire::MappedSource {
        source_id: id,
        position_m: Some(vec3(p)),
        covariance_m2: vec![],
        first_heard_ns: first.as_ns(),
        last_heard_ns: last.as_ns(),
        live: false,
    });
    live.chain(remembered).collect()
}

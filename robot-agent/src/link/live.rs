//! The live agent's shell around the [agent core](crate::agent): one tokio
//! task owns the core, the stream to the coordinator (reconnecting with
//! backoff, heartbeats when idle) and the navigator. Hops and poses arrive on
//! channels; the task hands them to the core with the wall clock as `now`, and
//! sends whatever the core has to say.

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use soundmap_proto::{Stamp, TrackedDoa};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::{LinkClient, LinkConfig};
use crate::AgentError;
use crate::agent::{Agent, AgentEvent, CoreStats, FromCoordinator, Reply};
use crate::navigator::Navigator;
use crate::pose::StampedPose;

/// One hop's tracked DoAs, at its DoA stamp.
#[derive(Clone, Debug, PartialEq)]
pub struct Hop {
    /// DoA stamp.
    pub stamp: Stamp,
    /// Tracked DoAs (confirmed tracks; may be empty).
    pub doas: Vec<TrackedDoa>,
}

/// Counters of a [`Link`], for logs and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Streams opened (welcome received).
    pub connects: u64,
    /// Failed connection attempts.
    pub connect_failures: u64,
    /// True while a stream is open.
    pub connected: bool,
    /// Observations sent for the first time.
    pub sent: u64,
    /// Observations sent again on a new stream because they were not acknowledged.
    pub resent: u64,
    /// Observations acknowledged.
    pub acked: u64,
    /// Observations dropped (oldest first) because the buffer was full.
    pub dropped: u64,
    /// Observations awaiting acknowledgement.
    pub pending: usize,
    /// `StreamError`s received.
    pub stream_errors: u64,
    /// Heartbeats sent.
    pub heartbeats: u64,
    /// Reposition commands received (valid or not).
    pub commands: u64,
    /// Hops dropped for want of a pose.
    pub hops_without_pose: u64,
}

impl LinkStats {
    fn with_core(self, c: CoreStats) -> Self {
        LinkStats {
            sent: c.sent,
            resent: c.resent,
            acked: c.acknowledged,
            dropped: c.dropped,
            pending: c.pending,
            stream_errors: c.stream_errors,
            commands: c.commands,
            hops_without_pose: c.hops_without_pose,
            ..self
        }
    }
}

#[derive(Debug)]
struct Shared {
    stats: Mutex<LinkStats>,
    shutdown: watch::Sender<bool>,
    idle: watch::Sender<bool>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Watches and stops a running [`Link`]. Cheap to clone.
#[derive(Clone, Debug)]
pub struct LinkHandle {
    shared: Arc<Shared>,
}

impl LinkHandle {
    /// Current counters.
    pub fn stats(&self) -> LinkStats {
        *lock(&self.shared.stats)
    }

    /// Waits until every observation produced so far is acknowledged, at most
    /// `timeout`. Returns whether that happened.
    pub async fn flush(&self, timeout: Duration) -> bool {
        let mut idle = self.shared.idle.subscribe();
        tokio::time::timeout(timeout, idle.wait_for(|&i| i)).await.is_ok_and(|r| r.is_ok())
    }

    /// Stops the link task now (closing the stream).
    pub fn shutdown(&self) {
        let _ = self.shared.shutdown.send(true);
    }
}

/// Where a running link gets its inputs.
#[derive(Debug)]
pub struct LinkInputs {
    /// Hops, in stamp order. When every sender is gone, the link resolves the
    /// hops still waiting for poses, waits for the acknowledgements (at most
    /// `drain_timeout`), and ends.
    pub hops: mpsc::Receiver<Hop>,
    /// Live SLAM poses, in stamp order (none for a replayed trajectory already in the core).
    pub poses: Option<mpsc::Receiver<StampedPose>>,
    /// The hops are a recording read as fast as possible (`pace = "asap"`):
    /// the link takes a hop only while its buffer has room, so the recording
    /// waits for acknowledgements instead of losing its oldest observations.
    /// Live inputs leave it `false`: they cannot wait, and the buffer keeps
    /// the newest.
    pub lossless: bool,
}

/// The live agent's link to the coordinator (see the module docs).
#[derive(Debug)]
pub struct Link;

impl Link {
    /// Starts the link task on the current tokio runtime. It runs until its hop
    /// input ends and everything is acknowledged (or `drain_timeout` passes), or
    /// until [`LinkHandle::shutdown`]; connection failures are retried with backoff.
    /// The task returns the final counters.
    pub fn spawn(
        config: LinkConfig,
        core: Agent,
        navigator: Box<dyn Navigator>,
        inputs: LinkInputs,
        drain_timeout: Duration,
    ) -> (LinkHandle, JoinHandle<LinkStats>) {
        let shared = Arc::new(Shared {
            stats: Mutex::new(LinkStats::default()),
            shutdown: watch::Sender::new(false),
            idle: watch::Sender::new(true),
        });
        let task = Task {
            shared: shared.clone(),
            config,
            core,
            navigator,
            conn: None,
            connecting: None,
            retry_at: None,
            last_send: Instant::now(),
            stats: LinkStats::default(),
        };
        let join = tokio::spawn(task.run(inputs, drain_timeout));
        (LinkHandle { shared }, join)
    }
}

type Connecting = Pin<Box<dyn Future<Output = Result<LinkClient, AgentError>> + Send>>;

struct Task {
    shared: Arc<Shared>,
    config: LinkConfig,
    core: Agent,
    navigator: Box<dyn Navigator>,
    conn: Option<LinkClient>,
    connecting: Option<Connecting>,
    retry_at: Option<Instant>,
    last_send: Instant,
    stats: LinkStats,
}

/// Reads one message from the stream, or waits forever without one.
async fn receive(conn: &mut Option<LinkClient>) -> Result<(), AgentError> {
    match conn {
        Some(c) => c.receive().await,
        None => std::future::pending().await,
    }
}

async fn at(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d.into()).await,
        None => std::future::pending().await,
    }
}

async fn maybe<T>(f: &mut Option<Pin<Box<dyn Future<Output = T> + Send>>>) -> T {
    match f {
        Some(f) => f.await,
        None => std::future::pending().await,
    }
}

/// The instant of a stamp on the wall clock.
fn instant_of(stamp: Stamp) -> Instant {
    Instant::now() + Duration::from_nanos((stamp - Stamp::now()).max(0) as u64)
}

impl Task {
    async fn run(mut self, mut inputs: LinkInputs, drain_timeout: Duration) -> LinkStats {
        let mut shutdown = self.shared.shutdown.subscribe();
        let tick_period =
            (self.config.heartbeat_interval / 2).clamp(Duration::from_millis(10), Duration::from_millis(100));
        let mut tick = tokio::time::interval(tick_period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut backoff = self.config.backoff_initial;
        self.connecting = Some(self.connect());
        let mut drain_until: Option<Instant> = None;
        loop {
            self.flush_outputs().await;
            if let Some(until) = drain_until {
                let done = self.core.waiting_hops() == 0 && self.core.all_acknowledged();
                if done || Instant::now() >= until {
                    if !done {
                        tracing::warn!(
                            "{} observation(s) not acknowledged and {} hop(s) still waiting for a pose at shutdown",
                            self.core.stats().pending,
                            self.core.waiting_hops()
                        );
                    }
                    break;
                }
            }
            let timeout = self.core.poll_timeout().map(instant_of);
            tokio::select! {
                // Poses before hops: a hop then finds its pose without waiting.
                biased;
                _ = shutdown.changed() => break,
                pose = recv_pose(&mut inputs.poses) => match pose {
                    Some(p) => {
                        if let Err(e) = self.core.handle_pose(Stamp::now(), p) {
                            tracing::warn!("{e}");
                        }
                    }
                    None => inputs.poses = None,
                },
                hop = inputs.hops.recv(), if drain_until.is_none() && self.has_room(inputs.lossless) => match hop {
                    Some(h) => self.core.handle_hop(Stamp::now(), h.stamp, h.doas),
                    None => drain_until = Some(Instant::now() + drain_timeout),
                },
                r = receive(&mut self.conn) => match r {
                    Ok(()) => self.take_coordinator_messages(),
                    Err(e) => {
                        self.conn = None;
                        lock(&self.shared.stats).connected = false;
                        self.stats.connected = false;
                        tracing::warn!("{e}; reconnecting in {:.1} s", backoff.as_secs_f64());
                        self.retry_at = Some(Instant::now() + backoff);
                    }
                },
                c = maybe(&mut self.connecting) => {
                    self.connecting = None;
                    match c {
                        Ok(client) => {
                            self.on_connected(client);
                            backoff = self.config.backoff_initial;
                        }
                        Err(e) => {
                            self.stats.connect_failures += 1;
                            tracing::warn!("{e}; retrying in {:.1} s", backoff.as_secs_f64());
                            self.retry_at = Some(Instant::now() + backoff);
                            backoff = (backoff * 2).min(self.config.backoff_max);
                        }
                    }
                },
                _ = at(self.retry_at), if self.connecting.is_none() && self.conn.is_none() => {
                    self.retry_at = None;
                    self.connecting = Some(self.connect());
                },
                _ = at(timeout) => self.core.handle_timeout(Stamp::now()),
                _ = tick.tick() => {
                    self.core.handle_timeout(Stamp::now());
                    self.heartbeat().await;
                },
            }
        }
        self.flush_outputs().await;
        self.stats.with_core(self.core.stats())
    }

    /// Whether a hop may be taken now (see [`LinkInputs::lossless`]).
    fn has_room(&self, lossless: bool) -> bool {
        !lossless || self.core.stats().pending + self.core.waiting_hops() < self.config.buffer_capacity
    }

    fn connect(&self) -> Connecting {
        let endpoint = self.config.endpoint.clone();
        let hello = self.core.hello().clone();
        let token = self.config.token.clone();
        let timeout = self.config.connect_timeout;
        let tls = self.config.tls.clone();
        Box::pin(
            async move { LinkClient::connect_secure(&endpoint, &hello, token, tls.as_ref(), timeout).await },
        )
    }

    fn on_connected(&mut self, client: LinkClient) {
        let w = client.welcome();
        tracing::info!(
            "connected to {} as {} ({}{})",
            self.config.endpoint,
            w.robot_id,
            w.coordinator_version,
            if w.resumed { ", resumed" } else { "" }
        );
        self.conn = Some(client);
        self.stats.connects += 1;
        self.stats.connected = true;
        self.core.handle_coordinator(Stamp::now(), FromCoordinator::Connected);
    }

    fn take_coordinator_messages(&mut self) {
        let Some(c) = self.conn.as_mut() else { return };
        let now = Stamp::now();
        if let Some(up_to_sequence) = c.acked() {
            self.core.handle_coordinator(now, FromCoordinator::Ack { up_to_sequence });
        }
        while let Some(e) = c.try_event() {
            self.core.handle_coordinator(now, FromCoordinator::Event(e));
        }
    }

    async fn heartbeat(&mut self) {
        if self.last_send.elapsed() < self.config.heartbeat_interval {
            return;
        }
        if let Some(c) = self.conn.as_mut() {
            match c.send_heartbeat(Stamp::now()).await {
                Ok(()) => {
                    self.stats.heartbeats += 1;
                    self.last_send = Instant::now();
                }
                Err(e) => self.lost(e),
            }
        }
    }

    fn lost(&mut self, e: AgentError) {
        tracing::warn!("{e}; reconnecting");
        self.conn = None;
        self.stats.connected = false;
        self.retry_at = Some(Instant::now() + self.config.backoff_initial);
    }

    /// Navigator exchange, events to the log, and everything the core has to send.
    async fn flush_outputs(&mut self) {
        let now = Stamp::now();
        self.core.exchange_with(self.navigator.as_mut(), now);
        while let Some(e) = self.core.poll_event() {
            log_event(&e);
        }
        if let Err(e) = self.send_all().await {
            self.lost(e);
        }
        let stats = self.stats.with_core(self.core.stats());
        *lock(&self.shared.stats) = stats;
        let idle = self.core.all_acknowledged();
        self.shared.idle.send_if_modified(|i| std::mem::replace(i, idle) != idle);
    }

    async fn send_all(&mut self) -> Result<(), AgentError> {
        let Some(c) = self.conn.as_mut() else { return Ok(()) };
        while let Some(obs) = self.core.poll_observation() {
            c.send_sequenced_observation(obs).await?;
            self.last_send = Instant::now();
        }
        while let Some(r) = self.core.poll_reply() {
            match r {
                Reply::Ack(a) => c.send_command_ack(&a).await?,
                Reply::Progress(p) => c.send_command_progress(&p).await?,
            }
            self.last_send = Instant::now();
        }
        Ok(())
    }
}

async fn recv_pose(poses: &mut Option<mpsc::Receiver<StampedPose>>) -> Option<StampedPose> {
    match poses {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

fn log_event(e: &AgentEvent) {
    match e {
        AgentEvent::HopWithoutPose { stamp, reason } => {
            soundmap_proto::warn_limited!(
                crate::WARNINGS,
                "hop_without_pose",
                "DoA hop at {stamp} dropped: {reason}"
            )
        }
        AgentEvent::Ignored(why) => tracing::warn!("{why}"),
        AgentEvent::StreamError(_) => {} // logged by the client with its field
        AgentEvent::CommandRefused { command_id, reason } => {
            tracing::info!("reposition command {command_id} refused: {reason}")
        }
    }
}

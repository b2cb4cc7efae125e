//! The live agent's link: reconnection, bounded buffering, heartbeats and the
//! navigator, in one tokio task fed through a [`LinkHandle`].

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use soundmap_proto::{CommandAck, Hello, Observation, Stamp};
use tokio::sync::{Notify, watch};
use tokio::task::JoinHandle;

use super::{CoordinatorEvent, LinkClient, LinkConfig, ObservationBuffer};
use crate::AgentError;
use crate::navigator::Navigator;
use crate::pose::StampedPose;

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
}

#[derive(Debug)]
struct Shared {
    buffer: Mutex<ObservationBuffer>,
    stats: Mutex<LinkStats>,
    pose: Mutex<Option<StampedPose>>,
    wake: Notify,
    shutdown: watch::Sender<bool>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The producer side of a running [`Link`]. Cheap to clone; never blocks.
#[derive(Clone, Debug)]
pub struct LinkHandle {
    shared: Arc<Shared>,
}

impl LinkHandle {
    /// Queues an observation (its sequence number is assigned here and returned).
    /// When the buffer is full the oldest observation is dropped and counted.
    pub fn send(&self, obs: Observation) -> u64 {
        let seq = lock(&self.shared.buffer).push(obs);
        self.shared.wake.notify_one();
        seq
    }

    /// The robot's latest pose, passed on to the navigator.
    pub fn observe_pose(&self, pose: StampedPose) {
        *lock(&self.shared.pose) = Some(pose);
        self.shared.wake.notify_one();
    }

    /// Current counters.
    pub fn stats(&self) -> LinkStats {
        let (pending, dropped) = {
            let b = lock(&self.shared.buffer);
            (b.len(), b.dropped())
        };
        LinkStats { pending, dropped, ..*lock(&self.shared.stats) }
    }

    /// Waits until every queued observation is acknowledged, at most `timeout`.
    /// Returns whether the buffer emptied.
    pub async fn flush(&self, timeout: Duration) -> bool {
        let until = Instant::now() + timeout;
        while Instant::now() < until {
            if lock(&self.shared.buffer).is_empty() {
                return true;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        lock(&self.shared.buffer).is_empty()
    }

    /// Stops the link task (closing the stream).
    pub fn shutdown(&self) {
        let _ = self.shared.shutdown.send(true);
    }
}

/// The live agent's link to the coordinator (see the [module docs](super)).
#[derive(Debug)]
pub struct Link;

impl Link {
    /// Starts the link task on the current tokio runtime. It runs until
    /// [`LinkHandle::shutdown`]; connection failures are retried with backoff.
    pub fn spawn(
        config: LinkConfig,
        hello: Hello,
        navigator: Box<dyn Navigator>,
    ) -> (LinkHandle, JoinHandle<()>) {
        let shared = Arc::new(Shared {
            buffer: Mutex::new(ObservationBuffer::new(config.buffer_capacity)),
            stats: Mutex::new(LinkStats::default()),
            pose: Mutex::new(None),
            wake: Notify::new(),
            shutdown: watch::Sender::new(false),
        });
        let task = tokio::spawn(run(shared.clone(), config, hello, navigator));
        (LinkHandle { shared }, task)
    }
}

async fn run(shared: Arc<Shared>, config: LinkConfig, hello: Hello, mut navigator: Box<dyn Navigator>) {
    let mut shutdown = shared.shutdown.subscribe();
    let mut backoff = config.backoff_initial;
    let mut highest_sent = 0u64;
    loop {
        if *shutdown.borrow() {
            return;
        }
        let attempt = LinkClient::connect_with_timeout(
            &config.endpoint,
            &hello,
            config.token.clone(),
            config.connect_timeout,
        );
        let result = tokio::select! {
            r = attempt => r,
            _ = shutdown.changed() => return,
        };
        match result {
            Err(e) => {
                lock(&shared.stats).connect_failures += 1;
                tracing::warn!("{e}; retrying in {:.1} s", backoff.as_secs_f64());
            }
            Ok(client) => {
                let w = client.welcome();
                tracing::info!(
                    "connected to {} as {} ({}{})",
                    config.endpoint,
                    w.robot_id,
                    w.coordinator_version,
                    if w.resumed { ", resumed" } else { "" }
                );
                backoff = config.backoff_initial;
                lock(&shared.buffer).restart();
                {
                    let mut s = lock(&shared.stats);
                    s.connects += 1;
                    s.connected = true;
                }
                let end =
                    session(&shared, &config, client, navigator.as_mut(), &mut shutdown, &mut highest_sent)
                        .await;
                lock(&shared.stats).connected = false;
                match end {
                    Ok(()) => return,
                    Err(e) => tracing::warn!("{e}; reconnecting in {:.1} s", backoff.as_secs_f64()),
                }
            }
        }
        tokio::select! {
            _ = tokio::time::sleep(backoff) => {}
            _ = shutdown.changed() => return,
        }
        backoff = (backoff * 2).min(config.backoff_max);
    }
}

/// Runs one stream until it fails (`Err`) or the link shuts down (`Ok`).
async fn session(
    shared: &Shared,
    config: &LinkConfig,
    mut client: LinkClient,
    navigator: &mut dyn Navigator,
    shutdown: &mut watch::Receiver<bool>,
    highest_sent: &mut u64,
) -> Result<(), AgentError> {
    let tick_period =
        (config.heartbeat_interval / 2).clamp(Duration::from_millis(10), Duration::from_millis(100));
    let mut tick = tokio::time::interval(tick_period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut last_send = Instant::now();
    let mut progress = Vec::new();
    loop {
        // Everything not yet sent on this stream, oldest first.
        loop {
            let next = lock(&shared.buffer).next_unsent().cloned();
            let Some(obs) = next else { break };
            let seq = client.send_sequenced_observation(obs).await?;
            lock(&shared.buffer).mark_sent(seq);
            let mut s = lock(&shared.stats);
            if seq <= *highest_sent {
                s.resent += 1;
            } else {
                s.sent += 1;
                *highest_sent = seq;
            }
            last_send = Instant::now();
        }
        let pose = lock(&shared.pose).take();
        if let Some(p) = pose {
            navigator.observe_pose(&p);
        }
        navigator.poll_progress(Stamp::now(), &mut progress);
        for p in progress.drain(..) {
            client.send_command_progress(&p).await?;
            last_send = Instant::now();
        }

        tokio::select! {
            _ = shutdown.changed() => return Ok(()),
            r = client.receive() => r?,
            _ = shared.wake.notified() => {}
            _ = tick.tick() => {
                if last_send.elapsed() >= config.heartbeat_interval {
                    client.send_heartbeat(Stamp::now()).await?;
                    lock(&shared.stats).heartbeats += 1;
                    last_send = Instant::now();
                }
            }
        }

        if let Some(up_to) = client.acked() {
            let n = lock(&shared.buffer).ack(up_to);
            lock(&shared.stats).acked += n as u64;
        }
        while let Some(event) = client.try_event() {
            match event {
                CoordinatorEvent::Reposition(cmd) => {
                    lock(&shared.stats).commands += 1;
                    let ack = navigator.submit(&cmd, Stamp::now());
                    tracing::info!(
                        "reposition command {} {}",
                        cmd.command_id,
                        if ack.accepted { "accepted".to_owned() } else { format!("refused: {}", ack.reason) }
                    );
                    client.send_command_ack(&ack).await?;
                    last_send = Instant::now();
                }
                CoordinatorEvent::InvalidReposition { command_id, error } => {
                    lock(&shared.stats).commands += 1;
                    let ack = CommandAck {
                        command_id,
                        accepted: false,
                        reason: format!("invalid command: {error}"),
                    };
                    client.send_command_ack(&ack).await?;
                    last_send = Instant::now();
                }
                CoordinatorEvent::Cancel { command_id, reason } => {
                    navigator.cancel(command_id, &reason, Stamp::now())
                }
                CoordinatorEvent::StreamError(_) => lock(&shared.stats).stream_errors += 1,
            }
        }
    }
}

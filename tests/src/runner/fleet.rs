//! The coordinator and one gRPC link per robot, on loopback, driven in
//! lockstep on simulated (or event) time.
//!
//! Lockstep makes a run deterministic: each observation is sent and its
//! acknowledgement awaited before the next one, so the coordinator handles
//! exactly one observation per batch, in a fixed order. The coordinator sends
//! every command caused by an observation before that observation's ack, so
//! once the ack arrives the robot has all its commands.

use std::sync::Arc;

use soundmap_agent::link::{CoordinatorEvent, LinkClient};
use soundmap_proto::{CommandAck, CommandProgress, Hello, Observation, Stamp, wire};
use soundmap_server::CoordinatorConfig;
use soundmap_server::clock::ManualClock;
use soundmap_server::service::{self, RunningCoordinator};
use tokio::sync::broadcast;

use crate::error::SimError;

/// A coordinator with its robots connected.
#[derive(Debug)]
pub struct Fleet {
    coordinator: RunningCoordinator,
    clock: ManualClock,
    links: Vec<LinkClient>,
    estimates: broadcast::Receiver<Arc<wire::SourceEstimate>>,
}

impl Fleet {
    /// Starts a coordinator on 127.0.0.1 (an ephemeral port) with its clock at
    /// `t0` and no housekeeping ticker, and connects one link per hello.
    pub async fn start(mut config: CoordinatorConfig, hellos: &[Hello], t0: Stamp) -> Result<Self, SimError> {
        config.liveness.tick_ms = 0;
        config.output.estimates_jsonl = None;
        // Simulated and replayed time runs faster than the wall clock: the
        // wall-clock guard on a live robot's observation rate does not apply.
        config.server.max_observation_rate_hz = 100_000.0;
        let clock = ManualClock::new(t0);
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(|source| SimError::Net { addr: "127.0.0.1:0".into(), source })?;
        let coordinator = service::start(config, Arc::new(clock.clone()), listener).await?;
        let estimates = coordinator.subscribe();
        let endpoint = format!("http://{}", coordinator.local_addr);
        let mut links = Vec::with_capacity(hellos.len());
        for hello in hellos {
            links.push(LinkClient::connect(&endpoint, hello, None).await?);
        }
        Ok(Fleet { coordinator, clock, links, estimates })
    }

    /// The coordinator's live view and recording, when configured.
    pub fn viz(&self) -> Option<soundmap_server::viz::VizSender> {
        self.coordinator.viz()
    }

    /// Sets the coordinator's clock.
    pub fn set_time(&self, now: Stamp) {
        self.clock.set(now);
    }

    /// Sends robot `robot`'s observation, waits for its acknowledgement, and
    /// returns the coordinator messages that came before it (commands, errors).
    pub async fn observe(
        &mut self,
        robot: usize,
        obs: Observation,
    ) -> Result<Vec<CoordinatorEvent>, SimError> {
        let link = &mut self.links[robot];
        let seq = link.send_observation(obs).await?;
        link.wait_acked(seq).await?;
        let mut events = Vec::new();
        while let Some(e) = link.try_event() {
            events.push(e);
        }
        Ok(events)
    }

    /// Answers a command.
    pub async fn command_ack(&mut self, robot: usize, ack: &CommandAck) -> Result<(), SimError> {
        Ok(self.links[robot].send_command_ack(ack).await?)
    }

    /// Reports a command's progress.
    pub async fn command_progress(&mut self, robot: usize, p: &CommandProgress) -> Result<(), SimError> {
        Ok(self.links[robot].send_command_progress(p).await?)
    }

    /// Estimates published since the last call.
    pub fn drain_estimates(&mut self) -> Result<Vec<Arc<wire::SourceEstimate>>, SimError> {
        let mut out = Vec::new();
        loop {
            match self.estimates.try_recv() {
                Ok(e) => out.push(e),
                Err(broadcast::error::TryRecvError::Empty) => return Ok(out),
                Err(broadcast::error::TryRecvError::Lagged(n)) => {
                    return Err(SimError::Coordinator(format!("{n} estimates lost by the recorder")));
                }
                Err(broadcast::error::TryRecvError::Closed) => return Ok(out),
            }
        }
    }

    /// Stream errors the robots received (a correct run has none).
    pub fn stream_errors(&self) -> u64 {
        self.links.iter().map(LinkClient::stream_errors).sum()
    }

    /// Closes the links and stops the coordinator.
    pub async fn shutdown(self) -> Result<(), SimError> {
        drop(self.links);
        Ok(self.coordinator.shutdown().await?)
    }
}

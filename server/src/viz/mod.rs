//! The live view and the recordings: what the coordinator hears and decides,
//! served over the Foxglove WebSocket protocol (`foxglove.websocket.v1`,
//! `[foxglove] listen`) and written to an MCAP file (`[record] mcap`).
//!
//! Both are sinks of one Foxglove context, so a recording holds exactly the
//! channels a live viewer sees (see [`publisher`] for the topics), plus the raw
//! `soundmap.v1` messages (protobuf, with the package's descriptor set as
//! schema) from which `soundmap-sim replay-mcap` re-runs a coordinator.
//!
//! The coordinator task never waits for a viewer: it pushes events into a
//! bounded [`queue::DropOldest`] (cost: a clone and a lock per event) and the
//! `viz` thread does the encoding, the drawing and the MCAP writing. When that
//! thread falls behind by [`QUEUE_CAPACITY`] events the oldest are dropped (and
//! counted in a warning); a slow WebSocket client only loses its own oldest
//! messages (`[foxglove] backlog_messages`), never the recording's.
//!
//! MCAP files are chunked (1 MiB) and zstd-compressed as they are written:
//! memory stays at one chunk plus the index, whatever the length of the run.
//! Log times are the coordinator clock (simulated time in the simulator).

pub mod publisher;
pub mod queue;
pub mod scene;

use std::io::BufWriter;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Point3;
use serde::Deserialize;
use soundmap_proto::{Hello, Observation, RobotId, RobotInput, Stamp, ValidationError, wire};

use crate::error::ServerError;
use crate::planner::free_space::FreeSpaceConfig;

/// Events queued toward the viewer thread before the oldest are dropped.
pub const QUEUE_CAPACITY: usize = 65_536;

/// `[foxglove]`: the live view.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FoxgloveConfig {
    /// Address of the Foxglove WebSocket server, e.g. `127.0.0.1:8765` (port 0:
    /// any free port). None (default): no live view.
    pub listen: Option<SocketAddr>,
    /// Messages queued per viewer before its oldest are dropped, in [1, 1 000 000]. Default 1024.
    pub backlog_messages: usize,
    /// The live view has no authentication of its own (a Foxglove WebSocket
    /// client sends no credential): when the coordinator has credentials
    /// (`[auth]`, or mutual TLS), `listen` must be a loopback address (reach
    /// it through an SSH tunnel or an authenticating proxy) unless this says
    /// that anyone who can reach the address may watch. Default false.
    pub allow_anonymous_viewers: bool,
}

impl Default for FoxgloveConfig {
    fn default() -> Self {
        FoxgloveConfig { listen: None, backlog_messages: 1024, allow_anonymous_viewers: false }
    }
}

impl FoxgloveConfig {
    /// Checks the values; errors name the key within `[foxglove]`.
    pub fn validate(&self) -> Result<(), ValidationError> {
        if !(1..=1_000_000).contains(&self.backlog_messages) {
            return Err(ValidationError::new(
                "backlog_messages",
                soundmap_proto::Problem::OutOfRange {
                    value: self.backlog_messages as f64,
                    range: "[1, 1000000]",
                },
            ));
        }
        Ok(())
    }

    /// With credentials configured (`closed`), an anonymous live view only
    /// on loopback unless `allow_anonymous_viewers`.
    pub fn validate_access(&self, closed: bool) -> Result<(), ValidationError> {
        match self.listen {
            Some(addr) if closed && !addr.ip().is_loopback() && !self.allow_anonymous_viewers => {
                Err(ValidationError::new(
                    "listen",
                    soundmap_proto::Problem::Invalid(format!(
                        "{addr} is reachable from the network, and the live view has no authentication \
                         while the coordinator requires credentials: listen on loopback (e.g. \
                         127.0.0.1:{}) and reach it through a tunnel, or set allow_anonymous_viewers = true",
                        addr.port()
                    )),
                ))
            }
            _ => Ok(()),
        }
    }
}

/// `[record]`: the MCAP recording.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordConfig {
    /// Write the live view's channels and the raw `soundmap.v1` messages to this
    /// MCAP file (replaced if it exists; its directory is made if missing).
    /// None (default): no recording.
    pub mcap: Option<PathBuf>,
}

/// What the coordinator tells the viewer thread.
#[derive(Debug)]
pub(crate) enum Event {
    Hello { now: Stamp, hello: Hello },
    Observation { now: Stamp, robot: RobotId, obs: Observation },
    FromRobot { now: Stamp, robot: RobotId, input: RobotInput },
    ToRobot { now: Stamp, robot: RobotId, msg: wire::CoordinatorMessage },
    Estimate { now: Stamp, estimate: Arc<wire::SourceEstimate> },
    Truth { now: Stamp, sources: Vec<(Point3<f64>, bool)> },
}

/// Feeds the viewer thread; cheap to clone, never blocks.
#[derive(Clone, Debug)]
pub struct VizSender(Arc<queue::DropOldest<Event>>);

impl VizSender {
    /// A robot connected with `hello`.
    pub fn hello(&self, now: Stamp, hello: Hello) {
        self.0.push(Event::Hello { now, hello });
    }

    /// The coordinator accepted `obs` from `robot`.
    pub fn observation(&self, now: Stamp, robot: RobotId, obs: Observation) {
        self.0.push(Event::Observation { now, robot, obs });
    }

    /// `robot` answered a command (ack or progress).
    pub fn from_robot(&self, now: Stamp, robot: RobotId, input: RobotInput) {
        self.0.push(Event::FromRobot { now, robot, input });
    }

    /// The coordinator sent `robot` a command or a cancellation.
    pub fn to_robot(&self, now: Stamp, robot: &RobotId, msg: &wire::CoordinatorMessage) {
        self.0.push(Event::ToRobot { now, robot: robot.clone(), msg: msg.clone() });
    }

    /// The coordinator published `estimate`.
    pub fn estimate(&self, now: Stamp, estimate: Arc<wire::SourceEstimate>) {
        self.0.push(Event::Estimate { now, estimate });
    }

    /// The true sources (simulation, or a scored replay): position in `map`
    /// and whether each is playing. Enables `rse_m` on `/soundmap/quality`.
    pub fn truth(&self, now: Stamp, sources: Vec<(Point3<f64>, bool)>) {
        self.0.push(Event::Truth { now, sources });
    }
}

/// The running live view and/or recording.
#[derive(Debug)]
pub struct Viz {
    queue: Arc<queue::DropOldest<Event>>,
    thread: Option<std::thread::JoinHandle<()>>,
    local_addr: Option<SocketAddr>,
}

impl Viz {
    /// Starts the WebSocket server and opens the MCAP file as configured;
    /// `None` when neither is.
    pub async fn start(
        foxglove: &FoxgloveConfig,
        record: &RecordConfig,
        free_space: &FreeSpaceConfig,
    ) -> Result<Option<Viz>, ServerError> {
        if foxglove.listen.is_none() && record.mcap.is_none() {
            return Ok(None);
        }
        let ctx = foxglove::Context::new();
        let mcap = match &record.mcap {
            Some(path) => {
                let io = |source| ServerError::Io { path: path.clone(), source };
                // Its directory is made as an output directory would be.
                if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                    std::fs::create_dir_all(dir)
                        .map_err(|source| ServerError::Io { path: dir.to_path_buf(), source })?;
                }
                let file = std::fs::File::create(path).map_err(io)?;
                let writer = ctx
                    .mcap_writer_with_options(foxglove::McapWriteOptions::default().profile(""))
                    .create(BufWriter::new(file))
                    .map_err(|e| io(std::io::Error::other(e)))?;
                Some((path.clone(), writer))
            }
            None => None,
        };
        let (server, local_addr) = match foxglove.listen {
            Some(addr) => {
                let server = ctx
                    .websocket_server()
                    .name(concat!("soundmap-coordinator ", env!("CARGO_PKG_VERSION")))
                    .bind(addr.ip().to_string(), addr.port())
                    .capabilities([foxglove::websocket::Capability::Time])
                    .message_backlog_size(foxglove.backlog_messages)
                    .start()
                    .await
                    .map_err(|e| ServerError::Io {
                        path: format!("<foxglove server {addr}>").into(),
                        source: std::io::Error::other(e),
                    })?;
                let local = SocketAddr::new(addr.ip(), server.port());
                tracing::info!("Foxglove live view on ws://{local}");
                (Some(server), Some(local))
            }
            None => (None, None),
        };
        let queue = Arc::new(queue::DropOldest::new(QUEUE_CAPACITY));
        let free = (free_space.room.clone(), free_space.obstacles.clone());
        let q = queue.clone();
        let thread = std::thread::Builder::new()
            .name("viz".into())
            .spawn(move || run(ctx, free, q, server, mcap))
            .map_err(|source| ServerError::Io { path: "<viz thread>".into(), source })?;
        Ok(Some(Viz { queue, thread: Some(thread), local_addr }))
    }

    /// Where the Foxglove server listens, when it runs.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.local_addr
    }

    /// The sender the coordinator (and a simulator) feeds.
    pub fn sender(&self) -> VizSender {
        VizSender(self.queue.clone())
    }

    /// Publishes what is queued, closes the recording and stops the server.
    pub fn stop(mut self) {
        self.queue.close();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Viz {
    fn drop(&mut self) {
        self.queue.close();
    }
}

type Mcap = (PathBuf, foxglove::McapWriterHandle<BufWriter<std::fs::File>>);

/// The viewer thread: publishes events in batches until the queue closes.
fn run(
    ctx: Arc<foxglove::Context>,
    free_space: (Vec<[f64; 2]>, Vec<Vec<[f64; 2]>>),
    queue: Arc<queue::DropOldest<Event>>,
    server: Option<foxglove::WebSocketServerHandle>,
    mcap: Option<Mcap>,
) {
    let mut publisher = publisher::Publisher::new(ctx, free_space);
    let mut batch = Vec::new();
    let mut dropped = 0;
    while queue.pop_all(&mut batch) {
        let mut latest = None;
        for event in batch.drain(..) {
            latest = Some(event_time(&event));
            publisher.handle(event);
        }
        if let (Some(server), Some(t)) = (&server, latest) {
            server.broadcast_time(t.as_ns().max(0) as u64);
        }
        let d = queue.dropped();
        if d > dropped {
            tracing::warn!("live view: {} event(s) dropped (the viewer thread fell behind)", d - dropped);
            dropped = d;
        }
    }
    if let Some((path, writer)) = mcap
        && let Err(e) = writer.close()
    {
        tracing::error!("{}: closing the recording: {e}", path.display());
    }
    if let Some(server) = server {
        server.stop().detach_all();
    }
}

fn event_time(e: &Event) -> Stamp {
    match e {
        Event::Hello { now, .. }
        | Event::Observation { now, .. }
        | Event::FromRobot { now, .. }
        | Event::ToRobot { now, .. }
        | Event::Estimate { now, .. }
        | Event::Truth { now, .. } => *now,
    }
}

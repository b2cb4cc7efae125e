//! Watching a simulation or a replay: the coordinator's Foxglove live view and
//! MCAP recording (see `soundmap_server::viz`), switched on from the command
//! line, and pacing to wall-clock time so a person can follow it.
//!
//! Neither changes what is computed: the coordinator feeds the viewer thread
//! through a queue that never blocks it, and pacing only sleeps between the
//! lockstep exchanges (simulated time is unchanged).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use nalgebra::Point3;
use soundmap_proto::Stamp;
use soundmap_server::CoordinatorConfig;
use soundmap_server::viz::VizSender;

use crate::report::SourceTruth;

/// `--foxglove ADDR [--realtime] [--mcap FILE.mcap]`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ViewArgs {
    /// Serve the Foxglove live view (WebSocket) on ADDR while running, e.g. 127.0.0.1:8765.
    #[arg(long, value_name = "ADDR")]
    pub foxglove: Option<SocketAddr>,
    /// Pace the run to wall-clock time (simulated seconds take real seconds).
    #[arg(long)]
    pub realtime: bool,
    /// Record the live view's channels and the raw soundmap.v1 messages to this
    /// MCAP file. A simulated run also writes the coordinator settings to replay
    /// it with beside it, as FILE.coordinator.toml (`replay-mcap --config`),
    /// its active positioning included.
    #[arg(long, value_name = "FILE.mcap")]
    pub mcap: Option<PathBuf>,
}

impl ViewArgs {
    /// Sets `[foxglove] listen` and `[record] mcap` in `config` when given.
    pub fn apply(&self, config: &mut CoordinatorConfig) {
        if let Some(addr) = self.foxglove {
            config.foxglove.listen = Some(addr);
        }
        if let Some(path) = &self.mcap {
            config.record.mcap = Some(path.clone());
        }
    }

    /// A pacer from `t0` (the start of the run's time).
    pub fn pacer(&self, t0: Stamp) -> Pacer {
        Pacer { enabled: self.realtime, t0, started: Instant::now() }
    }
}

/// Sleeps so that run time `now` is reached no earlier than `now − t0` after the start.
#[derive(Debug)]
pub struct Pacer {
    enabled: bool,
    t0: Stamp,
    started: Instant,
}

impl Pacer {
    /// Waits until wall-clock time catches up with `now` (no-op unless `--realtime`).
    pub async fn wait(&self, now: Stamp) {
        if !self.enabled {
            return;
        }
        let due = self.started + Duration::from_secs_f64(now.seconds_since(self.t0).max(0.0));
        tokio::time::sleep_until(due.into()).await;
    }
}

/// Tells the live view where the true sources are, at most every 0.1 s of run time.
#[derive(Debug)]
pub struct TruthFeed {
    viz: Option<VizSender>,
    t0: Stamp,
    next: Stamp,
}

impl TruthFeed {
    /// Period between two truth messages (ns).
    const PERIOD_NS: i64 = 100_000_000;

    /// A feed into `viz` (nothing when `None`) for run time counted from `t0`.
    pub fn new(viz: Option<VizSender>, t0: Stamp) -> Self {
        TruthFeed { viz, t0, next: t0 }
    }

    /// Sends the true sources' positions at `now` when a period has passed.
    pub fn at(&mut self, now: Stamp, truths: &[SourceTruth]) {
        let Some(viz) = &self.viz else { return };
        if now < self.next {
            return;
        }
        self.next = Stamp::from_ns(now.as_ns().saturating_add(Self::PERIOD_NS));
        let t_s = now.seconds_since(self.t0);
        let sources: Vec<(Point3<f64>, bool)> =
            truths.iter().filter_map(|t| Some((t.position_at(t_s)?, t.active_at(t_s)))).collect();
        if !sources.is_empty() {
            viz.truth(now, sources);
        }
    }
}

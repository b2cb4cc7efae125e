//! For tests that check the live agent against the replay: a real
//! coordinator on a loopback socket that logs every observation it accepts
//! (`output.observations_jsonl`), live agents run against it, and that log
//! read back per robot.
//!
//! Live agents sending a recording as fast as they can far exceed a robot's
//! live rate, which the coordinator bounds per stream in real seconds
//! (`server.max_observation_rate_hz`), so the bound is lifted here.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use soundmap_agent::config::AgentConfig;
use soundmap_agent::live::LivePlan;
use soundmap_server::CoordinatorConfig;
use soundmap_server::clock::Clock;
use soundmap_server::service::RunningCoordinator;

use crate::replay::{ReplayArgs, RobotRecording, replay};

/// A running coordinator that logs the observations it accepts.
#[derive(Debug)]
pub struct LoggingCoordinator {
    runtime: tokio::runtime::Runtime,
    running: RunningCoordinator,
    /// The observation log.
    pub log: PathBuf,
}

impl LoggingCoordinator {
    /// Starts one on `clock`, logging to `log`, with the per-stream rate bound lifted.
    pub fn start(log: PathBuf, clock: Arc<dyn Clock>) -> Self {
        let runtime =
            tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
        let mut config = CoordinatorConfig::default();
        config.output.observations_jsonl = Some(log.clone());
        config.server.max_observation_rate_hz = 100_000.0;
        let running = runtime.block_on(async {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
            soundmap_server::service::start(config, clock, listener).await.unwrap()
        });
        LoggingCoordinator { runtime, running, log }
    }

    /// The endpoint agents connect to.
    pub fn endpoint(&self) -> String {
        format!("http://{}", self.running.local_addr)
    }

    /// Stops it (the log is complete afterwards).
    pub fn shutdown(self) {
        self.runtime.block_on(self.running.shutdown()).unwrap();
    }
}

/// Runs one live agent per configuration file (`soundmap-agent run`'s code,
/// each on its own thread) until its input ends, and checks that each ended
/// with everything acknowledged, nothing dropped and no stream error.
pub fn run_agents(configs: Vec<PathBuf>) {
    let agents: Vec<_> = configs
        .into_iter()
        .map(|path| {
            std::thread::spawn(move || {
                let config = AgentConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
                LivePlan::prepare(config).unwrap().run().unwrap()
            })
        })
        .collect();
    for a in agents {
        let stats = a.join().unwrap();
        assert_eq!((stats.pending, stats.dropped, stats.stream_errors), (0, 0, 0), "{stats:?}");
    }
}

/// Runs `soundmap-sim replay` of `robots` (output under `dir/replay`) with
/// its coordinator logging every observation it accepts; returns the log.
pub fn replay_logging(robots: Vec<RobotRecording>, dir: &Path) -> PathBuf {
    let log = dir.join("replay-observations.jsonl");
    let coordinator_toml = dir.join("coordinator.toml");
    std::fs::write(&coordinator_toml, format!("[output]\nobservations_jsonl = \"{}\"\n", log.display()))
        .unwrap();
    let args = ReplayArgs {
        robots,
        truths: vec![],
        out: dir.join("replay"),
        coordinator_config: Some(coordinator_toml),
        pipeline: None,
        max_pose_gap_s: 0.5,
        view: Default::default(),
        rosbag: None,
    };
    replay(&args).unwrap();
    log
}

/// An observation log's lines per robot, in the order the coordinator accepted them.
pub fn observations_by_robot(path: &Path) -> BTreeMap<String, Vec<serde_json::Value>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut out: BTreeMap<String, Vec<serde_json::Value>> = BTreeMap::new();
    for line in text.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        out.entry(v["robot_id"].as_str().unwrap().to_owned()).or_default().push(v);
    }
    out
}

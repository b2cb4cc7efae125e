//! The live agent and the replay send the coordinator the same stream.
//!
//! A simulated trial is recorded (WAV + TUM per robot). The same recording is
//! then fed (1) through the live agent: the code `soundmap-agent run` runs
//! (`soundmap_agent::live::LivePlan`, here in-process, one per robot, each with its own agent
//! config: WAV + TUM, real gRPC on loopback) against a real coordinator on the
//! wall clock, and (2) through `soundmap-sim replay`. Both coordinators log
//! every observation they accept (`output.observations_jsonl`); the two logs
//! must hold the same observations per robot: same sequence numbers, stamps,
//! poses, DoAs and silences.

use std::path::Path;
use std::sync::Arc;

use soundmap_sim::live_check::{LoggingCoordinator, observations_by_robot, replay_logging, run_agents};
use soundmap_sim::replay::parse_robot;
use soundmap_sim::runner::{RunOptions, SIM_EPOCH, run};
use soundmap_sim::scenario::Scenario;

/// A scratch directory for one test, removed when dropped.
fn scratch(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-{name}-")).tempdir().unwrap()
}

fn agent_toml(id: &str, endpoint: &str, dir: &Path, array: &str) -> String {
    format!(
        r#"robot_id = "{id}"
[coordinator]
endpoint = "{endpoint}"
[array]
preset = "{array}"
[doa]
source = "own"
[audio]
source = "wav"
path = "{dir}/{id}.wav"
start_ns = {start}
pace = "asap"
[pose]
source = "tum"
path = "{dir}/{id}.tum"
start_s = 0.0
[navigator]
path = "{dir}/{id}-goals.jsonl"
arrival_tolerance_m = 0.25
"#,
        dir = dir.display(),
        start = SIM_EPOCH.as_ns(),
    )
}

/// A clock that runs in real time from `epoch`.
#[derive(Debug)]
struct WallClockFrom {
    epoch: soundmap_proto::Stamp,
    started: std::time::Instant,
}

impl soundmap_server::clock::Clock for WallClockFrom {
    fn now(&self) -> soundmap_proto::Stamp {
        self.epoch.plus_ns(self.started.elapsed().as_nanos() as i64)
    }
}

#[test]
fn live_agent_and_replay_send_the_same_observations() {
    let mut scenario = Scenario::load("smoke").unwrap();
    // The source pauses: the stream holds the end of a track and a silence.
    scenario.sources[0].active = vec![[0.0, 1.8], [2.6, 4.0]];
    let tmp = scratch("live-equivalence");
    let dir = tmp.path();
    let rec = dir.join("recording");
    run(&scenario, &RunOptions { record_dir: Some(rec.clone()), ..RunOptions::default() }).unwrap();

    // (2) soundmap-sim replay, with the coordinator logging what it accepts.
    let replay_log = replay_logging(
        scenario
            .robots
            .iter()
            .map(|r| {
                parse_robot(&format!(
                    "id={id},audio={d}/{id}.wav,poses={d}/{id}.tum,array={a}",
                    id = r.id,
                    d = rec.display(),
                    a = r.array
                ))
                .unwrap()
            })
            .collect(),
        dir,
    );

    // (1) the live agents against a real coordinator on a wall clock (one that
    // reads a minute after the recording's epoch at the start and runs in real
    // time: the coordinator refuses stamps older than `limits.max_past_ms` or
    // ahead of its clock, and the agents send the recording as fast as they can).
    let clock =
        WallClockFrom { epoch: SIM_EPOCH.plus_ns(60_000_000_000), started: std::time::Instant::now() };
    let coordinator = LoggingCoordinator::start(dir.join("live-observations.jsonl"), Arc::new(clock));
    let endpoint = coordinator.endpoint();
    let configs = scenario
        .robots
        .iter()
        .map(|r| {
            let path = dir.join(format!("{}.toml", r.id));
            std::fs::write(&path, agent_toml(&r.id, &endpoint, &rec, &r.array)).unwrap();
            path
        })
        .collect();
    run_agents(configs);
    let live_log = coordinator.log.clone();
    coordinator.shutdown();

    let live = observations_by_robot(&live_log);
    let replayed = observations_by_robot(&replay_log);
    assert_eq!(live.keys().collect::<Vec<_>>(), replayed.keys().collect::<Vec<_>>());
    for (id, l) in &live {
        let r = &replayed[id];
        let empty = l.iter().filter(|o| o["doas"].as_array().unwrap().is_empty()).count();
        println!(
            "{id}: {} observations live, {} replayed, {empty} of them empty (end of a track)",
            l.len(),
            r.len()
        );
        assert!(l.len() > 100, "{id}: only {} observations", l.len());
        assert!(empty > 0 && empty < l.len(), "{id}: silences are part of the stream");
        assert_eq!(l.len(), r.len(), "{id}: observation counts differ");
        for (a, b) in l.iter().zip(r) {
            assert_eq!(a, b, "{id}: first difference");
        }
    }
}

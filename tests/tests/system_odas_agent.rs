//! The live agent's ODAS bridge, as a user of ODAS runs it: each robot's
//! `soundmap-agent run` (`soundmap_agent::live::LivePlan`, in-process, one per robot, real gRPC on
//! loopback) reads the SST file ODAS wrote, with `pace = "asap"` and no
//! `start_ns`, and poses from a TUM file, against a real coordinator on the
//! system clock. The same files go through `soundmap-sim replay`. The two
//! coordinators' observation logs must hold the same observations per robot:
//! the same DoAs in the same order, the same poses, and stamps that differ by
//! one constant per robot (the live agent places the recording so that it
//! ends when it starts: the clock rule of `soundmap_agent::odas`).
//!
//! `cargo test -p soundmap-sim --test system_odas_agent -- --nocapture`
//! prints how long the live agents took for the 60 s files.

use std::sync::Arc;
use std::time::Instant;

use soundmap_server::clock::SystemClock;
use soundmap_sim::live_check::{LoggingCoordinator, observations_by_robot, replay_logging, run_agents};
use soundmap_sim::odas_like::trial::{OdasTrialSpec, write_trial};
use soundmap_sim::replay::parse_robot;

/// A scratch directory for one test, removed when dropped.
fn scratch(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-{name}-")).tempdir().unwrap()
}

#[test]
fn live_agents_send_odas_files_asap_as_the_replay_does() {
    let tmp = scratch("odas-agent");
    let dir = tmp.path();
    let trial = write_trial(dir, &OdasTrialSpec { seed: 3, ..OdasTrialSpec::default() }).unwrap();

    // (1) soundmap-sim replay of the SST files.
    let replay_log =
        replay_logging(trial.robots.iter().map(|r| parse_robot(&r.to_argument()).unwrap()).collect(), dir);

    // (2) the live agents, asap, against a coordinator on the system clock.
    // 7,500 observations per robot in well under a second (the coordinator's
    // per-stream rate bound lifted).
    let coordinator = LoggingCoordinator::start(dir.join("live-observations.jsonl"), Arc::new(SystemClock));
    let endpoint = coordinator.endpoint();
    let t0 = Instant::now();
    let configs = trial
        .robots
        .iter()
        .map(|r| {
            let path = dir.join(format!("{}.toml", r.id));
            let toml = format!(
                "robot_id = \"{id}\"\n[coordinator]\nendpoint = \"{endpoint}\"\n[array]\npreset = \"{array}\"\n\
                 [doa]\nsource = \"odas\"\nfile = \"{sst}\"\npace = \"asap\"\n\
                 [pose]\nsource = \"tum\"\npath = \"{tum}\"\nstart_s = {start}\n\
                 [navigator]\npath = \"{dir}/{id}-goals.jsonl\"\n",
                id = r.id,
                array = r.array,
                sst = r.odas.as_ref().unwrap().path.display(),
                tum = r.poses.display(),
                start = r.start_s,
                dir = dir.display(),
            );
            std::fs::write(&path, toml).unwrap();
            path
        })
        .collect();
    run_agents(configs);
    let live_s = t0.elapsed().as_secs_f64();
    let live_log = coordinator.log.clone();
    coordinator.shutdown();

    let live = observations_by_robot(&live_log);
    let replayed = observations_by_robot(&replay_log);
    assert_eq!(live.keys().collect::<Vec<_>>(), vec!["r1", "r2"]);
    assert_eq!(live.keys().collect::<Vec<_>>(), replayed.keys().collect::<Vec<_>>());
    for (id, l) in &live {
        let r = &replayed[id];
        println!("{id}: {} observations live, {} replayed", l.len(), r.len());
        assert!(l.len() > 7000, "{id}: {} of the 60 s file's 7,500 hops", l.len());
        assert_eq!(l.len(), r.len(), "{id}: observation counts differ");
        let stamp = |o: &serde_json::Value| o["stamp_ns"].as_i64().unwrap();
        let offset = stamp(&l[0]) - stamp(&r[0]);
        for (k, (a, b)) in l.iter().zip(r).enumerate() {
            assert_eq!(a["doas"], b["doas"], "{id}: observation {k}");
            assert_eq!(stamp(a) - stamp(b), offset, "{id}: observation {k} is not on the same clock offset");
            let (pa, pb) = (a["map_from_base"].as_array().unwrap(), b["map_from_base"].as_array().unwrap());
            for (x, y) in pa.iter().zip(pb) {
                assert!(
                    (x.as_f64().unwrap() - y.as_f64().unwrap()).abs() < 1e-6,
                    "{id}: pose {k}: {pa:?} {pb:?}"
                );
            }
        }
        // The recording lies in the past: it ends by the time the agent started.
        let end = stamp(l.last().unwrap());
        assert!(end <= soundmap_proto::Stamp::now().as_ns(), "{id}: the last stamp is ahead of the clock");
    }
    println!("two live agents sent the 60 s ODAS files (asap) in {live_s:.2} s");
}

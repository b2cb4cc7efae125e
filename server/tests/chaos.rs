//! Restarts under load: the real `soundmap-coordinator` binary with a state
//! directory, four robots streaming over loopback gRPC (reconnecting on their
//! own), killed with SIGKILL mid-stream and started again on the same state
//! directory, several times. Then:
//! - every observation the coordinator acknowledged is in its observations log;
//! - every line of both JSON-lines files is whole JSON;
//! - the estimates file has one restart marker per restart, and the source
//!   keeps one id across all of them (never another id for the same source).
//!
//! `chaos_three_kills` runs in CI; `chaos_twenty_kills` is the long run
//! (`cargo test -p soundmap-server --release --test integration chaos:: -- --ignored`).

use std::collections::BTreeSet;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use soundmap_server::loadgen::{RobotLog, RobotSpec, SOURCE, StampMode, run_robot};

const ROBOTS: usize = 4;
const RATE_HZ: f64 = 50.0;

fn free_port() -> std::net::SocketAddr {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap()
}

fn start(dir: &Path, addr: std::net::SocketAddr) -> Child {
    Command::new(env!("CARGO_BIN_EXE_soundmap-coordinator"))
        .arg("--listen")
        .arg(addr.to_string())
        .arg("--state-dir")
        .arg(dir.join("state"))
        .arg("--estimates-jsonl")
        .arg(dir.join("estimates.jsonl"))
        .arg("--observations-jsonl")
        .arg(dir.join("observations.jsonl"))
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("the coordinator binary starts")
}

fn json_lines(path: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.is_empty() || text.ends_with('\n'), "{}: ends in a partial line", path.display());
    text.lines()
        .enumerate()
        .map(|(i, l)| {
            serde_json::from_str(l)
                .unwrap_or_else(|e| panic!("{}:{}: torn line {l:?}: {e}", path.display(), i + 1))
        })
        .collect()
}

async fn chaos(kills: usize) {
    let tmp = tempfile::Builder::new().prefix(&format!("soundmap-chaos-{kills}-")).tempdir().unwrap();
    let dir = tmp.path();
    let addr = free_port();
    let mut child = start(dir, addr);
    // Robots stream for the whole run; the coordinator is killed under them.
    let run = Duration::from_secs_f64(2.0 + 1.6 * kills as f64);
    let until = Instant::now() + run;
    let logs: Vec<Arc<Mutex<RobotLog>>> = (0..ROBOTS).map(|_| Arc::default()).collect();
    let specs: Vec<RobotSpec> = (0..ROBOTS).map(|i| RobotSpec::on_ring("chaos", i, ROBOTS, 3.0)).collect();
    let robots: Vec<_> = specs
        .iter()
        .zip(&logs)
        .map(|(s, l)| tokio::spawn(run_robot(addr, s.clone(), RATE_HZ, StampMode::Now, until, l.clone())))
        .collect();
    tokio::time::sleep(Duration::from_millis(1500)).await;
    for _ in 0..kills {
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        child = start(dir, addr);
        tokio::time::sleep(Duration::from_millis(1500)).await;
    }
    for r in robots {
        r.await.unwrap();
    }
    child.kill().unwrap();
    child.wait().unwrap();

    // Every acknowledged observation was processed (it is in the log).
    let mut logged: BTreeSet<(String, u64)> = BTreeSet::new();
    for l in json_lines(&dir.join("observations.jsonl")) {
        logged.insert((l["robot_id"].as_str().unwrap().to_owned(), l["sequence"].as_u64().unwrap()));
    }
    let mut acked_total = 0;
    for (spec, log) in specs.iter().zip(&logs) {
        let log = log.lock().unwrap();
        assert!(
            log.connections as usize > kills,
            "{}: {} connections for {kills} restarts",
            spec.id,
            log.connections
        );
        for s in 1..=log.sent {
            if log.acked(s) {
                acked_total += 1;
                assert!(
                    logged.contains(&(spec.id.clone(), s)),
                    "{} #{s} acknowledged but not processed",
                    spec.id
                );
            }
        }
    }
    assert!(
        acked_total as f64 > 0.5 * RATE_HZ * ROBOTS as f64 * run.as_secs_f64(),
        "only {acked_total} acked"
    );

    // One marker per restart; the source keeps its id through every one.
    let estimates = json_lines(&dir.join("estimates.jsonl"));
    let markers: Vec<_> = estimates.iter().filter(|l| l.get("event").is_some()).collect();
    assert_eq!(markers.len(), kills, "one restart marker per restart");
    assert!(markers.iter().all(|m| m["state"] == "restored"), "{markers:?}");
    let mut ids = BTreeSet::new();
    let mut per_run = vec![BTreeSet::new()];
    for l in &estimates {
        if l.get("event").is_some() {
            per_run.push(BTreeSet::new());
            continue;
        }
        let id = l["source_id"].as_u64().unwrap();
        if id != 0 {
            let p = nalgebra::Point3::new(
                l["x"].as_f64().unwrap(),
                l["y"].as_f64().unwrap(),
                l["z"].as_f64().unwrap(),
            );
            assert!(
                (p - SOURCE).norm() < 0.5,
                "source {id} published {:.2} m from the source",
                (p - SOURCE).norm()
            );
            ids.insert(id);
            per_run.last_mut().unwrap().insert(id);
        }
    }
    assert_eq!(ids.len(), 1, "one source, one id across {kills} restarts: {ids:?}");
    let resumed = per_run.iter().filter(|r| !r.is_empty()).count();
    assert!(
        resumed >= kills,
        "the source was published (with its id) after only {resumed} of {} runs",
        kills + 1
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chaos_three_kills() {
    chaos(3).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "long run (~35 s): cargo test -p soundmap-server --release --test integration chaos:: -- --ignored"]
async fn chaos_twenty_kills() {
    chaos(20).await;
}

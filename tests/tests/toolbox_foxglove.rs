//! The live view and the recordings, checked with the tools a roboticist uses:
//! a `websockets` client speaking `foxglove.websocket.v1` watches a simulated
//! run, the `mcap` Python reader opens its recording, and `replay-mcap`
//! re-runs the coordinator on it. Watching and recording change nothing.

use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;

use serde_json::Value;
use soundmap_sim::mcap_replay::{ReplayMcapArgs, replay_mcap};
use soundmap_sim::pytools;
use soundmap_sim::report::write_reports;
use soundmap_sim::runner::{RunOptions, run};
use soundmap_sim::scenario::Scenario;
use soundmap_sim::viewer::ViewArgs;

/// A scratch directory for one test, removed when dropped.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-foxglove-{name}-")).tempdir().unwrap()
}

fn free_port() -> SocketAddr {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap()
}

fn topic<'a>(v: &'a Value, t: &str) -> &'a Value {
    &v["topics"][t]
}

#[test]
fn live_view_and_recording_change_nothing_and_replay_mcap_reproduces_the_run() {
    let scenario = Scenario::load("smoke").unwrap();
    let tmp = temp_dir("run");
    let dir = tmp.path();
    let seed = Some(11);
    let plain = run(&scenario, &RunOptions { seed, ..RunOptions::default() }).unwrap();

    // The same run, watched live (paced to wall-clock time) and recorded.
    let addr = free_port();
    // In a directory that does not exist yet: the recording makes it.
    let mcap = dir.join("rec/run.mcap");
    let url = format!("ws://{addr}");
    // The Python environment first: built inside the watcher's thread, it can
    // take longer than the 4 s run on a loaded machine, and the client would
    // then find the view already closed.
    pytools::python();
    let watcher =
        std::thread::spawn(move || pytools::run("tests/python/foxglove_live_check.py", [url.as_str(), "30"]));
    let view = ViewArgs { foxglove: Some(addr), realtime: true, mcap: Some(mcap.clone()) };
    let viewed = run(&scenario, &RunOptions { seed, view, ..RunOptions::default() }).unwrap();
    let live: Value = serde_json::from_str(&watcher.join().unwrap().stdout).unwrap();

    // Same seed, same summary.json with and without the viewer and the recording.
    let a = write_reports(&plain, &dir.join("plain")).unwrap();
    let b = write_reports(&viewed, &dir.join("viewed")).unwrap();
    assert_eq!(serde_json::to_value(&a).unwrap(), serde_json::to_value(&b).unwrap());
    assert_eq!(
        std::fs::read_to_string(dir.join("plain/summary.json")).unwrap(),
        std::fs::read_to_string(dir.join("viewed/summary.json")).unwrap()
    );

    // What the Foxglove client saw and decoded.
    println!("live view: {live}");
    // The Foxglove SDK negotiates the protocol under its current name.
    assert_eq!(live["subprotocol"], "foxglove.sdk.v1");
    assert!(live["server"].as_str().unwrap().starts_with("soundmap-coordinator"));
    assert!(live["time_messages"].as_u64().unwrap() > 0, "no server time broadcast");
    for (t, schema) in [
        ("/tf", "foxglove.FrameTransforms"),
        ("/soundmap/doas", "foxglove.SceneUpdate"),
        ("/soundmap/sources", "foxglove.SceneUpdate"),
        ("/soundmap/estimates", "soundmap.v1.SourceEstimate"),
        ("/soundmap/robots/pioneer/observation", "soundmap.v1.Observation"),
    ] {
        assert_eq!(topic(&live, t)["schema"], schema, "{t}");
        assert!(topic(&live, t)["count"].as_u64().unwrap() > 10, "{t}: {}", topic(&live, t));
    }
    assert_eq!(topic(&live, "/soundmap/quality")["encoding"], "json");
    let frames = live["frames"].as_array().unwrap();
    for robot in ["pioneer", "turtlebot"] {
        assert!(frames.contains(&serde_json::json!(["map", format!("{robot}/base")])), "{frames:?}");
        assert!(frames.contains(&serde_json::json!([format!("{robot}/base"), format!("{robot}/array")])));
    }
    let ids: Vec<&str> = live["entity_ids"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    for id in ["doa/pioneer", "doa/turtlebot", "source/1", "truth/0", "path/pioneer", "room"] {
        assert!(ids.contains(&id), "{id} not in {ids:?}");
    }
    let fields = live["quality_fields"].as_array().unwrap();
    for f in ["theta_deg", "gdop", "rse_m", "source_id", "trusted"] {
        assert!(fields.contains(&Value::from(f)), "{f} not in {fields:?}");
    }
    let rse: Vec<f64> = live["rse_m"].as_array().unwrap().iter().filter_map(Value::as_f64).collect();
    assert!(!rse.is_empty() && rse.iter().all(|r| *r < 0.5), "{rse:?}");
    let e = &live["estimate"];
    let d = ((e["x"].as_f64().unwrap()).powi(2)
        + (e["y"].as_f64().unwrap() - 0.2).powi(2)
        + (e["z"].as_f64().unwrap() - 1.2).powi(2))
    .sqrt();
    assert!(d < 0.5, "decoded estimate {e} is {d} m from the source");

    // The layout in deploy/ shows topics the live view serves.
    let layout =
        std::fs::read_to_string(pytools::repo_root().join("deploy/foxglove/soundmap-layout.json")).unwrap();
    let layout: Value = serde_json::from_str(&layout).unwrap();
    let panels = layout["configById"].as_object().unwrap();
    assert!(panels.keys().any(|k| k.starts_with("3D!")) && panels.keys().any(|k| k.starts_with("Plot!")));
    for (id, panel) in panels {
        let topics =
            panel["topics"].as_object().map(|t| t.keys().cloned().collect::<Vec<_>>()).unwrap_or_default();
        let plotted = panel["paths"].as_array().into_iter().flatten().filter_map(|p| p["value"].as_str());
        for t in topics.iter().map(String::as_str).chain(plotted.map(|p| p.split('.').next().unwrap())) {
            assert!(live["topics"].get(t).is_some(), "{id} shows {t}, which the live view does not serve");
        }
    }

    // The recording, read with the mcap Python reader.
    let out = pytools::run("tests/python/mcap_check.py", [mcap.to_str().unwrap()]);
    let rec: Value = serde_json::from_str(&out.stdout).unwrap();
    println!("recording: {rec}");
    assert_eq!(rec["compression"], serde_json::json!(["zstd"]));
    assert_eq!(rec["monotonic"], true);
    for (name, encoding) in [
        ("soundmap.v1.Observation", "protobuf"),
        ("soundmap.v1.Hello", "protobuf"),
        ("soundmap.v1.SourceEstimate", "protobuf"),
        ("foxglove.SceneUpdate", "protobuf"),
        ("foxglove.FrameTransforms", "protobuf"),
    ] {
        assert_eq!(rec["schemas"][name], encoding, "{name}");
    }
    assert_eq!(rec["channels"]["/soundmap/quality"]["encoding"], "json");
    let count = |t: &str| rec["counts"][t].as_u64().unwrap_or(0) as usize;
    assert_eq!(count("/soundmap/estimates"), plain.rows.len(), "every published estimate is recorded");
    assert_eq!(count("/soundmap/quality"), plain.rows.len());
    assert_eq!(count("/soundmap/robots/pioneer/hello"), 1);
    assert!(count("/soundmap/robots/pioneer/observation") >= plain.rows.len() / 2);
    assert_eq!(
        count("/tf"),
        count("/soundmap/robots/pioneer/observation") + count("/soundmap/robots/turtlebot/observation")
    );
    let span_s =
        (rec["last_log_time"].as_u64().unwrap() - rec["first_log_time"].as_u64().unwrap()) as f64 / 1e9;
    assert!((span_s - scenario.duration_s).abs() < 0.1, "log times span {span_s} s");
    assert!(rec["observation"]["doas"].as_u64().unwrap() >= 1);

    // replay-mcap: the same estimates, scored against the recorded truth, with
    // the coordinator settings the run wrote beside its recording (the room's ceiling).
    let config = soundmap_sim::runner::mcap_replay_config(&mcap);
    assert_eq!(config, dir.join("rec/run.coordinator.toml"));
    let written = std::fs::read_to_string(&config).unwrap();
    assert!(written.contains("ceiling_height_m"), "{written}");
    let args = ReplayMcapArgs {
        file: mcap.clone(),
        out: dir.join("replayed"),
        config: Some(config),
        view: ViewArgs::default(),
    };
    let replayed = replay_mcap(&args).unwrap();
    assert_eq!(replayed.rows.len(), plain.rows.len());
    for (r, p) in replayed.rows.iter().zip(&plain.rows) {
        let (r, p) = (r.estimate_in_map.unwrap(), p.estimate_in_map.unwrap());
        assert!((r - p).norm() < 1e-9, "{r} vs {p}");
    }
    let rs = write_reports(&replayed, &args.out).unwrap();
    let (rs, ps) = (serde_json::to_value(&rs).unwrap(), serde_json::to_value(&a).unwrap());
    println!("replay-mcap summary: {rs}");
    assert_eq!(rs["estimates"], ps["estimates"]);
    let (r95, p95) = (rs["rse_p95_m"].as_f64(), ps["rse_p95_m"].as_f64());
    assert!(r95.is_some() && (r95.unwrap() - p95.unwrap()).abs() < 1e-3, "{r95:?} vs {p95:?}");

    // A recording cut short while it was written (the coordinator killed, the
    // disk full) replays up to its last complete record, with the same
    // estimates as the run up to there; one cut before any robot's hello
    // says so by name.
    let bytes = std::fs::read(&mcap).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let replayed = replay_mcap(&ReplayMcapArgs { file: cut.clone(), ..args.clone() }).unwrap();
    let n = replayed.rows.len();
    assert!(n > 0 && n < plain.rows.len(), "{n} of {} estimates", plain.rows.len());
    for (r, p) in replayed.rows.iter().zip(&plain.rows) {
        let (r, p) = (r.estimate_in_map.unwrap(), p.estimate_in_map.unwrap());
        assert!((r - p).norm() < 1e-9, "{r} vs {p}");
    }
    std::fs::write(&cut, &bytes[..200]).unwrap();
    let e = replay_mcap(&ReplayMcapArgs { file: cut, ..args }).unwrap_err().to_string();
    assert!(e.contains("cut.mcap") && e.contains("cut short") && e.contains("hello"), "{e}");
}

#[test]
fn replay_mcap_refuses_what_is_not_a_soundmap_recording() {
    let tmp = temp_dir("bad");
    let dir = tmp.path();
    let junk = dir.join("junk.mcap");
    std::fs::write(&junk, b"not an mcap file at all").unwrap();
    let args = |file: PathBuf| ReplayMcapArgs {
        file,
        out: dir.join("out"),
        config: None,
        view: ViewArgs::default(),
    };
    let e = replay_mcap(&args(junk.clone())).unwrap_err().to_string();
    assert!(e.contains("junk.mcap") && e.contains("MCAP"), "{e}");
    let e = replay_mcap(&args(dir.join("missing.mcap"))).unwrap_err().to_string();
    assert!(e.contains("missing.mcap"), "{e}");
}

/// A recorded run with active positioning on writes it into the settings to
/// replay it with, and the replay's planner then takes the run's first
/// decisions on the same estimates: the same goals, listed in `goals.csv`
/// with their distance to the true source (the replayed robots do not move,
/// so later goals part from the run's).
#[test]
fn replay_mcap_of_an_active_run_plans_as_the_run_did() {
    let mut scenario = Scenario::load("corner-start").unwrap();
    scenario.duration_s = 2.0;
    let tmp = temp_dir("active");
    let dir = tmp.path();
    let mcap = dir.join("run.mcap");
    let view = ViewArgs { mcap: Some(mcap.clone()), ..ViewArgs::default() };
    let live = run(&scenario, &RunOptions { seed: Some(5), view, ..RunOptions::default() }).unwrap();
    let config = soundmap_sim::runner::mcap_replay_config(&mcap);
    let written = std::fs::read_to_string(&config).unwrap();
    assert!(written.contains("[active_positioning]") && written.contains("enabled = true"), "{written}");
    assert!(written.contains("[planner.free_space]") && written.contains("[10.0, 8.0]"), "{written}");
    let args = ReplayMcapArgs {
        file: mcap,
        out: dir.join("replayed"),
        config: Some(config),
        view: ViewArgs::default(),
    };
    let replayed = replay_mcap(&args).unwrap();
    write_reports(&replayed, &args.out).unwrap();
    let first = |r: &soundmap_sim::report::RunRecord| {
        r.robots
            .iter()
            .flat_map(|p| p.goals.iter().map(move |g| (g.0, p.id.clone(), g.1, g.2)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
    };
    let (a, b) = (first(&live).expect("the run planned"), first(&replayed).expect("the replay planned"));
    assert_eq!(a.1, b.1);
    assert!(
        (a.0 - b.0).abs() < 0.1 && (a.2 - b.2).abs() < 1e-6 && (a.3 - b.3).abs() < 1e-6,
        "{a:?} vs {b:?}"
    );
    let goals = std::fs::read_to_string(args.out.join("goals.csv")).unwrap();
    let line = goals.lines().nth(1).unwrap();
    assert!(line.starts_with(&format!("{:.3},{},{:.3},{:.3},", b.0, b.1, b.2, b.3)), "{line}");
    let range: f64 = line.rsplit(',').next().unwrap().parse().unwrap();
    assert!(range > 1.0 && range < 12.0, "{line}");
}

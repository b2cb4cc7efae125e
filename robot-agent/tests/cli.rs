//! The `soundmap-agent` binary end to end: `localize` on generated WAV and raw
//! recordings, `run` against a fake coordinator on loopback, and the errors a
//! user sees.

use crate::synth;

use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use nalgebra::Vector3;
use soundmap_agent::array::ArrayGeometry;
use soundmap_proto::wire::{self, coordinator_message::Msg as Out, robot_message::Msg as In};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};

const BIN: &str = env!("CARGO_BIN_EXE_soundmap-agent");
const FS: u32 = 16_000;
const FRAMES: usize = 16_384;

/// A scratch directory for one test, removed when dropped.
fn temp_dir(test: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-cli-{test}-")).tempdir().unwrap()
}

/// Azimuth 60°, elevation 30°: in respeaker-4's upper-hemisphere search region.
fn truth() -> Vector3<f64> {
    let (az, el) = (60f64.to_radians(), 30f64.to_radians());
    Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
}

/// A white-noise plane wave from `truth()` at respeaker-4's microphones, 16-bit samples, interleaved.
fn recording(channels_out: usize) -> Vec<i16> {
    let array = ArrayGeometry::load("respeaker-4").unwrap();
    let mut rng = synth::rng(7);
    let mut x = synth::plane_wave(&synth::positions(&array), &truth(), FS as f64, FRAMES, &mut rng);
    synth::add_sensor_noise(&mut x, 20.0, &mut rng);
    let mut out = Vec::with_capacity(FRAMES * channels_out);
    for t in 0..FRAMES {
        for c in 0..channels_out {
            out.push((x[c % 4][t] * 0.1 * 32_767.0).round().clamp(-32_768.0, 32_767.0) as i16);
        }
    }
    out
}

fn write_wav(path: &Path, channels: usize) {
    let spec = hound::WavSpec {
        channels: channels as u16,
        sample_rate: FS,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for s in recording(channels) {
        w.write_sample(s).unwrap();
    }
    w.finalize().unwrap();
}

fn agent(args: &[&str], stdin: Option<Vec<u8>>) -> Output {
    let mut child = Command::new(BIN)
        .args(args)
        .stdin(if stdin.is_some() { Stdio::piped() } else { Stdio::null() })
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    if let Some(bytes) = stdin {
        let mut s = child.stdin.take().unwrap();
        std::thread::spawn(move || {
            let _ = s.write_all(&bytes);
        });
    }
    child.wait_with_output().unwrap()
}

fn lines(text: &str) -> Vec<serde_json::Value> {
    text.lines().map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}"))).collect()
}

fn direction(v: &serde_json::Value) -> Vector3<f64> {
    Vector3::new(v["x"].as_f64().unwrap(), v["y"].as_f64().unwrap(), v["z"].as_f64().unwrap())
}

#[test]
fn localize_writes_one_line_per_hop_with_the_source_direction() {
    let dir = temp_dir("localize");
    let wav = dir.path().join("rec.wav");
    write_wav(&wav, 4);
    let out_path = dir.path().join("out.jsonl");
    let o = agent(
        &[
            "localize",
            "--array",
            "respeaker-4",
            "--input",
            wav.to_str().unwrap(),
            "--start-ns",
            "1000000000",
            "--out",
            out_path.to_str().unwrap(),
            "--potentials",
        ],
        None,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let hops = lines(&std::fs::read_to_string(&out_path).unwrap());
    assert_eq!(hops.len(), FRAMES / 128);
    let stamps: Vec<i64> = hops.iter().map(|h| h["stamp_ns"].as_i64().unwrap()).collect();
    for (k, s) in stamps.iter().enumerate() {
        // Hop k starts at sample 128·k (8 ms); the DoA is stamped at the middle of the
        // 256-sample frame that ends with it: 128·k + 128 − 128 samples after sample 0.
        assert_eq!(*s, 1_000_000_000 + k as i64 * 8_000_000, "hop {k}");
    }
    let with_sources: Vec<&serde_json::Value> =
        hops.iter().filter(|h| !h["sources"].as_array().unwrap().is_empty()).collect();
    assert!(
        with_sources.len() > hops.len() / 2,
        "{} of {} hops have a confirmed source",
        with_sources.len(),
        hops.len()
    );
    for h in &with_sources {
        let s = &h["sources"][0];
        let d = direction(s);
        assert!((d.norm() - 1.0).abs() < 1e-9);
        assert!(synth::angle_deg(&d, &truth()) < 5.0, "{h}");
        assert!((0.0..=1.0).contains(&s["activity"].as_f64().unwrap()));
        assert!(s["id"].as_u64().is_some());
        // No floor-reflection fit by default, so no range it was fitted at.
        assert!(s.get("floor_fit_range_m").is_none(), "{h}");
    }
    for h in &hops[2..] {
        let p = h["potentials"].as_array().unwrap();
        assert!(!p.is_empty() && p[0]["energy"].as_f64().is_some(), "{h}");
    }
}

#[test]
fn localize_reads_raw_pcm_from_stdin_like_the_wav() {
    let dir = temp_dir("stdin");
    let wav = dir.path().join("rec.wav");
    write_wav(&wav, 4);
    let from_wav = agent(&["localize", "--array", "respeaker-4", "--input", wav.to_str().unwrap()], None);
    assert!(from_wav.status.success(), "{}", String::from_utf8_lossy(&from_wav.stderr));
    let raw: Vec<u8> = recording(4).iter().flat_map(|s| s.to_le_bytes()).collect();
    let args = [
        "localize",
        "--array",
        "respeaker-4",
        "--input",
        "-",
        "--format",
        "s16le",
        "--channels",
        "4",
        "--rate",
        "16000",
    ];
    let from_stdin = agent(&args, Some(raw));
    assert!(from_stdin.status.success(), "{}", String::from_utf8_lossy(&from_stdin.stderr));
    assert!(!from_wav.stdout.is_empty());
    assert_eq!(from_wav.stdout, from_stdin.stdout);
    // Six channels in the stream, the array's four picked (reordered back) by a channel map.
    let raw6: Vec<u8> = recording(4)
        .chunks(4)
        .flat_map(|f| [0, f[3], f[0], f[1], f[2], 0])
        .flat_map(|s: i16| s.to_le_bytes())
        .collect();
    let args = [
        "localize",
        "--array",
        "respeaker-4",
        "--input",
        "-",
        "--format",
        "s16le",
        "--channels",
        "6",
        "--rate",
        "16000",
        "--channel-map",
        "2,3,4,1",
    ];
    let mapped = agent(&args, Some(raw6));
    assert!(mapped.status.success(), "{}", String::from_utf8_lossy(&mapped.stderr));
    assert_eq!(from_wav.stdout, mapped.stdout);
}

#[test]
fn localize_errors_name_the_file_and_problem() {
    let dir = temp_dir("errors");
    let wav = dir.path().join("three.wav");
    write_wav(&wav, 3);
    let cases: Vec<(Vec<String>, Vec<String>)> = vec![
        (
            vec!["--array".into(), "respeaker-4".into(), "--input".into(), wav.display().to_string()],
            vec![wav.display().to_string(), "3 channels, expected 4".into()],
        ),
        (
            vec![
                "--array".into(),
                "respeaker-4".into(),
                "--input".into(),
                "x.raw".into(),
                "--rate".into(),
                "16000".into(),
            ],
            vec!["x.raw".into(), "needs --format, --channels and --rate".into()],
        ),
        (
            vec!["--array".into(), "no-such-array".into(), "--input".into(), wav.display().to_string()],
            vec!["unknown array preset".into()],
        ),
        (
            vec![
                "--array".into(),
                "respeaker-4".into(),
                "--input".into(),
                "y.raw".into(),
                "--format".into(),
                "s16le".into(),
                "--channels".into(),
                "4".into(),
                "--rate".into(),
                "16000".into(),
            ],
            vec!["y.raw".into()],
        ),
    ];
    for (args, wanted) in cases {
        let mut all = vec!["localize".to_owned()];
        all.extend(args);
        let refs: Vec<&str> = all.iter().map(String::as_str).collect();
        let o = agent(&refs, None);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{all:?} succeeded");
        for w in wanted {
            assert!(stderr.contains(&w), "{all:?}: {stderr}");
        }
    }
    let o = agent(&["localize", "--array", "respeaker-4", "--input", "a.raw", "--format", "s8"], None);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown raw sample format"));
}

// ---------------------------------------------------------------- run

#[derive(Debug, Default)]
struct Seen {
    hello: Option<wire::Hello>,
    observations: Vec<wire::Observation>,
    acks: Vec<wire::CommandAck>,
}

#[derive(Clone, Default)]
struct Coordinator(Arc<Mutex<Seen>>);

#[tonic::async_trait]
impl wire::robot_link_server::RobotLink for Coordinator {
    type ConnectStream = ReceiverStream<Result<wire::CoordinatorMessage, Status>>;

    async fn connect(
        &self,
        request: Request<tonic::Streaming<wire::RobotMessage>>,
    ) -> Result<Response<Self::ConnectStream>, Status> {
        let mut inbound = request.into_inner();
        let Some(wire::RobotMessage { msg: Some(In::Hello(hello)) }) = inbound.message().await? else {
            return Err(Status::invalid_argument("hello first"));
        };
        let (tx, rx) = mpsc::channel(64);
        let welcome = wire::Welcome { robot_id: hello.robot_id.clone(), ..Default::default() };
        tx.send(Ok(wire::CoordinatorMessage { msg: Some(Out::Welcome(welcome)) })).await.unwrap();
        self.0.lock().unwrap().hello = Some(hello);
        let seen = self.0.clone();
        tokio::spawn(async move {
            while let Ok(Some(wire::RobotMessage { msg: Some(m) })) = inbound.message().await {
                match m {
                    In::Observation(o) => {
                        let first = seen.lock().unwrap().observations.is_empty();
                        let seq = o.sequence;
                        seen.lock().unwrap().observations.push(o);
                        if first {
                            let c = wire::RepositionCommand {
                                command_id: 9,
                                goal_map_from_base: Some(soundmap_proto::pose_to_wire(
                                    &nalgebra::Isometry3::translation(2.0, 1.0, 0.0),
                                )),
                                look_at_in_map_m: Some(wire::Vec3 { x: 3.0, y: 3.0, z: 1.0 }),
                                reason: wire::RepositionReason::GdopHigh as i32,
                                ..Default::default()
                            };
                            let _ =
                                tx.send(Ok(wire::CoordinatorMessage { msg: Some(Out::Reposition(c)) })).await;
                        }
                        let ack = wire::ObservationAck { up_to_sequence: seq };
                        let _ = tx
                            .send(Ok(wire::CoordinatorMessage { msg: Some(Out::ObservationAck(ack)) }))
                            .await;
                    }
                    In::CommandAck(a) => seen.lock().unwrap().acks.push(a),
                    _ => {}
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn run_streams_tracked_doas_with_interpolated_poses_to_the_coordinator() {
    let dir = temp_dir("run");
    write_wav(&dir.path().join("rec.wav"), 4);
    // The robot drives along x at 1 m/s; file time 10.0 s is audio sample 0.
    let mut tum = String::from("# t tx ty tz qx qy qz qw\n");
    for k in 0..=30 {
        let t = 10.0 + k as f64 * 0.05;
        tum += &format!("{t:.2} {:.3} 0 0 0 0 0 1\n", k as f64 * 0.05);
    }
    std::fs::write(dir.path().join("traj.tum"), tum).unwrap();
    let coordinator = Coordinator::default();
    let (addr, server) = serve(coordinator.clone()).await;
    let start_ns: i64 = 1_700_000_000_000_000_000;
    let config = format!(
        r#"robot_id = "cli-robot"
[coordinator]
endpoint = "http://{addr}"
[array]
preset = "respeaker-4"
[audio]
source = "wav"
path = "rec.wav"
start_ns = {start_ns}
pace = "asap"
[pose]
source = "tum"
path = "traj.tum"
start_s = 10.0
[navigator]
path = "goals.jsonl"
max_speed_m_per_s = 0.22
max_turn_rate_deg_per_s = 160.0
[link]
heartbeat_interval_ms = 100
"#
    );
    run_agent(dir.path(), &config).await;
    server.abort();

    let seen = coordinator.0.lock().unwrap();
    let hello = seen.hello.as_ref().expect("hello");
    assert_eq!(hello.robot_id, "cli-robot");
    // The base's limits from [navigator] travel in the hello.
    let limits = hello.base_limits.as_ref().expect("declared");
    assert_eq!((limits.max_speed_m_per_s, limits.max_turn_rate_deg_per_s), (0.22, 160.0));
    let array = hello.array.as_ref().unwrap();
    assert_eq!((array.microphone_count, array.preset.as_str()), (4, "respeaker-4"));
    assert_eq!(array.microphone_positions_m.len(), 4);
    let obs = &seen.observations;
    assert!(obs.len() > 40, "{} observations", obs.len());
    for (k, o) in obs.iter().enumerate() {
        assert_eq!(o.sequence, k as u64 + 1);
        // The pose is the trajectory interpolated at the DoA stamp: x = 1 m/s · t.
        let t = (o.stamp_ns - start_ns) as f64 * 1e-9;
        let x = o.map_from_base.as_ref().unwrap().translation_m.as_ref().unwrap().x;
        assert!((x - t).abs() < 1e-6, "observation {k}: x {x} at t {t}");
        if let Some(d) = o.doas.first() {
            let v = d.direction_in_array.as_ref().unwrap();
            assert!(synth::angle_deg(&Vector3::new(v.x, v.y, v.z), &truth()) < 5.0);
        }
    }
    assert!(obs.windows(2).all(|w| w[0].stamp_ns < w[1].stamp_ns));
    assert!(obs.iter().filter(|o| !o.doas.is_empty()).count() > 40);
    // The command sent after the first observation reached the navigator and was acknowledged.
    assert_eq!(seen.acks.len(), 1);
    assert!(seen.acks[0].accepted && seen.acks[0].command_id == 9);
    let goals = lines(&std::fs::read_to_string(dir.path().join("goals.jsonl")).unwrap());
    assert_eq!(goals[0]["type"], "goal");
    assert_eq!((goals[0]["command_id"].as_u64(), goals[0]["x"].as_f64()), (Some(9), Some(2.0)));
}

/// Runs `soundmap-agent run` on `config`, written as `dir/agent.toml`, and checks that it succeeds.
async fn run_agent(dir: &Path, config: &str) -> Output {
    let cfg = dir.join("agent.toml");
    std::fs::write(&cfg, config).unwrap();
    let out = tokio::task::spawn_blocking(move || agent(&["run", "--config", cfg.to_str().unwrap()], None));
    let out = tokio::time::timeout(Duration::from_secs(60), out).await.expect("agent run timed out").unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    out
}

/// `dir/rec.wav` (4 channels, 1.024 s) and `dir/traj.tum`: a robot standing still for 5 s.
fn write_still_recording(dir: &Path) {
    write_wav(&dir.join("rec.wav"), 4);
    let tum: String = (0..=100).map(|k| format!("{:.2} 0 0 0 0 0 0 1\n", k as f64 * 0.05)).collect();
    std::fs::write(dir.join("traj.tum"), tum).unwrap();
}

/// Starts the fake coordinator on a free loopback port.
async fn serve(coordinator: Coordinator) -> (std::net::SocketAddr, tokio::task::JoinHandle<()>) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let incoming =
        futures::stream::unfold(listener, |l| async move { Some((l.accept().await.map(|(s, _)| s), l)) });
    let server = tonic::transport::Server::builder()
        .add_service(wire::robot_link_server::RobotLinkServer::new(coordinator))
        .serve_with_incoming(incoming);
    (addr, tokio::spawn(async move { server.await.unwrap() }))
}

#[tokio::test(flavor = "multi_thread")]
async fn run_bridges_odas_output_with_poses_from_standard_input() {
    let dir = temp_dir("run-odas");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/odas_sst_tracked.json");
    let coordinator = Coordinator::default();
    let (addr, server) = serve(coordinator.clone()).await;
    let start_ns: i64 = 1_700_000_000_000_000_000;
    let config = format!(
        r#"robot_id = "odas-robot"
[coordinator]
endpoint = "http://{addr}"
[array]
preset = "respeaker-4"
[doa]
source = "odas"
file = "{}"
hop_len = 128
sample_rate_hz = 16000
start_ns = {start_ns}
[pose]
source = "jsonl_stdin"
[navigator]
path = "goals.jsonl"
"#,
        fixture.display()
    );
    std::fs::write(dir.path().join("agent.toml"), config).unwrap();
    // The robot turns in place at 1 rad/s, a pose every 10 ms around the ODAS hops.
    let mut poses = String::new();
    for k in -10..=20 {
        let yaw = k as f64 * 0.01;
        let (s, c) = (yaw / 2.0).sin_cos();
        poses += &format!(
            "{{\"stamp_ns\": {}, \"x\": 1.0, \"y\": 2.0, \"z\": 0.0, \"qx\": 0.0, \"qy\": 0.0, \"qz\": {s}, \"qw\": {c}}}\n",
            start_ns + k * 10_000_000
        );
    }
    let cfg = dir.path().join("agent.toml");
    let out = tokio::task::spawn_blocking(move || {
        agent(&["run", "--config", cfg.to_str().unwrap()], Some(poses.into_bytes()))
    });
    let out = tokio::time::timeout(Duration::from_secs(60), out).await.expect("agent run timed out").unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    server.abort();
    let seen = coordinator.0.lock().unwrap();
    // Hops 2–6 of the fixture have tracks; hop k is at (k−1)·8 ms. Hop 1 is
    // silent: it is sent empty (a robot's first hop tells where it is) when its
    // pose has arrived from standard input in time, and dropped otherwise.
    let (silent, heard): (Vec<_>, Vec<_>) = seen.observations.iter().partition(|o| o.doas.is_empty());
    assert!(silent.iter().all(|o| o.stamp_ns == start_ns) && silent.len() <= 1, "{silent:?}");
    let stamps: Vec<i64> = heard.iter().map(|o| o.stamp_ns - start_ns).collect();
    assert_eq!(stamps, vec![8_000_000, 16_000_000, 24_000_000, 32_000_000, 40_000_000]);
    let counts: Vec<usize> = heard.iter().map(|o| o.doas.len()).collect();
    assert_eq!(counts, vec![1, 1, 2, 2, 2]);
    for o in heard {
        let q = o.map_from_base.as_ref().unwrap().rotation.unwrap();
        let yaw = 2.0 * q.z.atan2(q.w);
        let t = (o.stamp_ns - start_ns) as f64 * 1e-9;
        assert!((yaw - t).abs() < 1e-9, "yaw {yaw} at {t} s");
        assert_eq!(o.doas[0].track_id, 1);
    }
}

#[test]
fn run_config_errors_name_the_file_and_field() {
    let dir = temp_dir("run-errors");
    let bad = dir.path().join("agent.toml");
    let example =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/agent.example.toml"))
            .unwrap()
            .replacen("\npace = \"realtime\"", "\npace = \"realtime\"\nchannels = 16", 1);
    std::fs::write(&bad, example).unwrap();
    let o = agent(&["run", "--config", bad.to_str().unwrap()], None);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains(&format!("{}: audio.channels: not used for WAV", bad.display())), "{stderr}");
    // A valid config whose audio file is missing fails before anything starts.
    let example =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/agent.example.toml"))
            .unwrap();
    std::fs::write(&bad, example).unwrap();
    let o = agent(&["run", "--config", bad.to_str().unwrap()], None);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("recordings/pioneer-1.wav"), "{stderr}");
}

/// `[odas_out]`: what the agent sends is also written as ODAS's SST JSON, to a
/// file and to a tool that listens for it (as odas_web does), and the SST reader
/// of the ODAS bridge reads it back as the same tracks.
#[tokio::test(flavor = "multi_thread")]
async fn run_writes_its_tracks_as_odas_sst_to_a_file_and_a_listening_tool() {
    let dir = temp_dir("run-odas-out");
    // No start_ns: sample 0 is the agent's start. The file is read in real
    // time, as a live robot's audio comes (with `asap` the tool would miss the
    // objects it cannot take at once, by design).
    write_still_recording(dir.path());
    let coordinator = Coordinator::default();
    let (addr, server) = serve(coordinator.clone()).await;
    // The ODAS tool: listens, and reads until the agent closes the connection.
    let tool = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let tool_addr = tool.local_addr().unwrap();
    let received = tokio::spawn(async move {
        use tokio::io::AsyncReadExt;
        let (mut s, _) = tool.accept().await.unwrap();
        let mut bytes = Vec::new();
        s.read_to_end(&mut bytes).await.unwrap();
        bytes
    });
    let config = format!(
        r#"robot_id = "sst-robot"
[coordinator]
endpoint = "http://{addr}"
[array]
preset = "respeaker-4"
[audio]
source = "wav"
path = "rec.wav"
pace = "realtime"
[pose]
source = "tum"
path = "traj.tum"
start_s = 0.0
[navigator]
path = "goals.jsonl"
[odas_out]
connect = "{tool_addr}"
file = "out.json"
"#
    );
    run_agent(dir.path(), &config).await;
    server.abort();
    let from_socket = tokio::time::timeout(Duration::from_secs(10), received).await.unwrap().unwrap();
    let from_file = std::fs::read(dir.path().join("out.json")).unwrap();
    assert_eq!(from_socket, from_file, "the socket and the file carry the same objects");

    let obs = coordinator.0.lock().unwrap().observations.clone();
    let mut parser = soundmap_agent::odas::SstParser::new();
    let objects: Vec<_> = parser.feed(&from_file).into_iter().map(Result::unwrap).collect();
    assert!(!parser.has_partial());
    // One object per hop (the 1.024 s WAV holds 128 hops of 8 ms), empty ones
    // included, as ODAS writes them; the coordinator gets the same tracks (the
    // agent sends a run of empty hops once).
    assert_eq!(objects.len(), 128);
    let timing = soundmap_agent::odas::OdasTiming {
        hop_len: 128,
        sample_rate_hz: 16_000,
        start: soundmap_proto::Stamp::ZERO,
    };
    let heard: Vec<_> =
        objects.iter().map(|o| o.to_frame(&timing).unwrap()).filter(|f| !f.doas.is_empty()).collect();
    let sent: Vec<_> = obs.iter().filter(|o| !o.doas.is_empty()).collect();
    assert!(heard.len() > 40, "{} hops with tracks", heard.len());
    assert_eq!(heard.len(), sent.len());
    for (k, (f, sent)) in heard.iter().zip(&sent).enumerate() {
        assert_eq!(f.doas.len(), sent.doas.len(), "hop {k} with tracks");
        for d in &f.doas {
            let s = sent.doas.iter().find(|s| s.track_id == d.track_id).expect("the same track ids");
            let v = s.direction_in_array.as_ref().unwrap();
            let angle = synth::angle_deg(&d.direction_in_array.into_inner(), &Vector3::new(v.x, v.y, v.z));
            assert!(angle < 0.2, "hop {k}: {angle}° from what was sent (3 printed decimals)");
        }
    }
    assert!(objects.iter().all(|o| o.src.len() == 4), "ODAS's default four slots");
    assert!(objects.iter().enumerate().all(|(k, o)| o.time_stamp == k as u64 + 1), "timeStamp counts hops");
    assert!(objects.iter().any(|o| o.src.iter().any(|s| s.id != 0)), "some tracks");
}

/// `pace = "asap"` without `start_ns`: the recording is placed to end when
/// the agent starts, so every stamp is in the past and none is lost.
#[tokio::test(flavor = "multi_thread")]
async fn run_places_an_asap_recording_before_its_start() {
    let dir = temp_dir("run-asap");
    write_still_recording(dir.path());
    let coordinator = Coordinator::default();
    let (addr, server) = serve(coordinator.clone()).await;
    let config = format!(
        "robot_id = \"asap-robot\"\n[coordinator]\nendpoint = \"http://{addr}\"\n[array]\npreset = \"respeaker-4\"\n\
         [audio]\nsource = \"wav\"\npath = \"rec.wav\"\npace = \"asap\"\n\
         [pose]\nsource = \"tum\"\npath = \"traj.tum\"\nstart_s = 0.0\n[navigator]\npath = \"goals.jsonl\"\n"
    );
    let before = soundmap_proto::Stamp::now().as_ns();
    let out = run_agent(dir.path(), &config).await;
    server.abort();
    let after = soundmap_proto::Stamp::now().as_ns();
    let obs = coordinator.0.lock().unwrap().observations.clone();
    assert!(obs.len() > 40, "{} observations", obs.len());
    let (first, last) = (obs[0].stamp_ns, obs.last().unwrap().stamp_ns);
    // The 1.024 s file ends at the agent's start (between `before` and `after`).
    assert!(last <= after, "the last hop is ahead of the clock");
    assert!(first >= before - 1_100_000_000 && first <= after - 1_000_000_000, "first hop at {first}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("0 dropped by the link"));
}

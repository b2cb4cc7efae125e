//! The link to the coordinator against a fake coordinator served by tonic on a
//! real loopback socket (the real coordinator has its own end-to-end tests).

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use nalgebra::{Isometry3, Unit, Vector3};
use soundmap_agent::agent::{Agent, CoreConfig};
use soundmap_agent::link::{
    CoordinatorEvent, Hop, Link, LinkClient, LinkConfig, LinkHandle, LinkInputs, LinkStats,
};
use soundmap_agent::navigator::{JsonLinesNavigator, Navigator};
use soundmap_agent::pose::StampedPose;
use soundmap_proto::wire::{self, coordinator_message::Msg as Out, robot_message::Msg as In};
use soundmap_proto::{
    ArrayInfo, CommandAck, CommandProgress, CommandState, Hello, Observation, RepositionCommand, RobotId,
    Stamp, TrackedDoa,
};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};

const WAIT: Duration = Duration::from_secs(10);

/// What the fake coordinator received, in order.
#[derive(Clone, Debug, PartialEq)]
enum Got {
    Hello { robot_id: String, authorization: Option<String> },
    Observation(u64),
    Heartbeat,
    CommandAck(wire::CommandAck),
    CommandProgress(wire::CommandProgress),
}

struct FakeState {
    got: mpsc::UnboundedSender<Got>,
    /// Acknowledge observations.
    ack: AtomicBool,
    /// Send a StreamError (before the ack) for this sequence.
    error_on: AtomicU64,
    next_command: AtomicU64,
    /// Send a reposition command for each observation with DoAs.
    command_on_doas: AtomicBool,
    /// Set to end every open stream with UNAVAILABLE.
    kill: watch::Sender<bool>,
}

#[derive(Clone)]
struct Fake(Arc<FakeState>);

impl Fake {
    fn new(ack: bool) -> (Fake, mpsc::UnboundedReceiver<Got>) {
        let (tx, rx) = mpsc::unbounded_channel();
        let state = FakeState {
            got: tx,
            ack: AtomicBool::new(ack),
            error_on: AtomicU64::new(0),
            next_command: AtomicU64::new(100),
            command_on_doas: AtomicBool::new(true),
            kill: watch::Sender::new(false),
        };
        (Fake(Arc::new(state)), rx)
    }
}

fn msg(m: Out) -> Result<wire::CoordinatorMessage, Status> {
    Ok(wire::CoordinatorMessage { msg: Some(m) })
}

fn command(id: u64) -> wire::RepositionCommand {
    RepositionCommand {
        command_id: id,
        goal_map_from_base: Isometry3::translation(1.0, 2.0, 0.0),
        look_at_in_map: nalgebra::Point3::new(4.0, 4.0, 1.0),
        reason: soundmap_proto::RepositionReason::ThetaOutOfBand,
        detail: "test".into(),
        deadline: Stamp::ZERO,
        issued: Stamp::now(),
    }
    .to_wire()
}

#[tonic::async_trait]
impl wire::robot_link_server::RobotLink for Fake {
    type ConnectStream = ReceiverStream<Result<wire::CoordinatorMessage, Status>>;

    async fn connect(
        &self,
        request: Request<tonic::Streaming<wire::RobotMessage>>,
    ) -> Result<Response<Self::ConnectStream>, Status> {
        let authorization =
            request.metadata().get("authorization").map(|v| v.to_str().unwrap_or("<binary>").to_owned());
        let mut inbound = request.into_inner();
        let hello = match inbound.message().await? {
            Some(wire::RobotMessage { msg: Some(In::Hello(h)) }) => h,
            _ => return Err(Status::invalid_argument("first message must be a hello")),
        };
        if hello.robot_id == "intruder" {
            return Err(Status::permission_denied("robot id does not match the token"));
        }
        let state = self.0.clone();
        let _ = state.got.send(Got::Hello { robot_id: hello.robot_id.clone(), authorization });
        let (tx, rx) = mpsc::channel(64);
        let welcome = wire::Welcome {
            robot_id: hello.robot_id,
            coordinator_version: "fake 0".into(),
            stale_after_ms: 5000,
            resumed: false,
        };
        tx.send(msg(Out::Welcome(welcome))).await.unwrap();
        let mut kill = state.kill.subscribe();
        tokio::spawn(async move {
            loop {
                let m = tokio::select! {
                    m = inbound.message() => m,
                    _ = kill.changed() => {
                        let _ = tx.send(Err(Status::unavailable("coordinator restarting"))).await;
                        return;
                    }
                };
                let Ok(Some(wire::RobotMessage { msg: Some(m) })) = m else { return };
                match m {
                    In::Observation(o) => {
                        let _ = state.got.send(Got::Observation(o.sequence));
                        if !o.doas.is_empty() && state.command_on_doas.load(Ordering::SeqCst) {
                            // A command caused by this observation, sent before its ack.
                            let id = state.next_command.fetch_add(1, Ordering::SeqCst);
                            let _ = tx.send(msg(Out::Reposition(command(id)))).await;
                        }
                        if state.error_on.load(Ordering::SeqCst) == o.sequence {
                            let e = wire::StreamError {
                                code: 3,
                                field: "observation.doas[0].activity".into(),
                                message: "1.5 out of range [0, 1]".into(),
                                sequence: o.sequence,
                            };
                            let _ = tx.send(msg(Out::Error(e))).await;
                        }
                        if state.ack.load(Ordering::SeqCst) {
                            let a = wire::ObservationAck { up_to_sequence: o.sequence };
                            let _ = tx.send(msg(Out::ObservationAck(a))).await;
                        }
                    }
                    In::Heartbeat(_) => {
                        let _ = state.got.send(Got::Heartbeat);
                    }
                    In::CommandAck(a) => {
                        let _ = state.got.send(Got::CommandAck(a));
                    }
                    In::CommandProgress(p) => {
                        let _ = state.got.send(Got::CommandProgress(p));
                    }
                    In::Hello(_) => {}
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }
}

/// Serves `fake` on `addr` (port 0: any free port).
async fn serve(fake: Fake, addr: SocketAddr) -> (SocketAddr, JoinHandle<()>) {
    let listener = tokio::net::TcpListener::bind(addr).await.unwrap();
    let addr = listener.local_addr().unwrap();
    let incoming =
        futures::stream::unfold(listener, |l| async move { Some((l.accept().await.map(|(s, _)| s), l)) });
    let task = tokio::spawn(async move {
        tonic::transport::Server::builder()
            .add_service(wire::robot_link_server::RobotLinkServer::new(fake))
            .serve_with_incoming(incoming)
            .await
            .unwrap();
    });
    (addr, task)
}

fn any_port() -> SocketAddr {
    "127.0.0.1:0".parse().unwrap()
}

fn hello(id: &str) -> Hello {
    Hello {
        robot_id: RobotId::parse(id, "robot_id").unwrap(),
        array: ArrayInfo {
            base_from_array: Isometry3::translation(0.0, 0.0, 0.5),
            microphone_count: 4,
            preset: None,
            microphone_positions: vec![],
            srp_band_hz: None,
            direct_path_elevations: false,
        },
        software_version: "test".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    }
}

fn observation(with_doa: bool) -> Observation {
    Observation {
        sequence: 0,
        stamp: Stamp::now(),
        map_from_base: Isometry3::identity(),
        pose_covariance: None,
        doas: if with_doa {
            vec![TrackedDoa {
                track_id: 1,
                direction_in_array: Unit::new_normalize(Vector3::new(1.0, 0.0, 0.0)),
                activity: 0.9,
                angular_sigma_rad: None,
                signature: None,
                coherence: None,
                floor_fit_range_m: None,
            }]
        } else {
            vec![]
        },
    }
}

async fn next(rx: &mut mpsc::UnboundedReceiver<Got>) -> Got {
    tokio::time::timeout(WAIT, rx.recv()).await.expect("fake coordinator got nothing").unwrap()
}

/// Next message that is not a heartbeat.
async fn next_non_heartbeat(rx: &mut mpsc::UnboundedReceiver<Got>) -> Got {
    loop {
        match next(rx).await {
            Got::Heartbeat => continue,
            g => return g,
        }
    }
}

#[tokio::test]
async fn client_lockstep_sees_every_command_once_its_ack_returns() {
    let (fake, mut got) = Fake::new(true);
    fake.0.error_on.store(3, Ordering::SeqCst);
    let (addr, _server) = serve(fake, any_port()).await;
    let endpoint = format!("http://{addr}");
    let mut c = LinkClient::connect(&endpoint, &hello("r1"), Some("s3cret".into())).await.unwrap();
    assert_eq!(c.welcome().robot_id, "r1");
    assert_eq!(
        next(&mut got).await,
        Got::Hello { robot_id: "r1".into(), authorization: Some("Bearer s3cret".into()) }
    );
    for k in 1..=20u64 {
        let with_doa = k % 2 == 0;
        let seq = c.send_observation(observation(with_doa)).await.unwrap();
        assert_eq!(seq, k);
        c.wait_acked(seq).await.unwrap();
        assert_eq!(c.acked(), Some(k));
        // The command caused by this observation is already here, without waiting.
        let mut events = vec![];
        while let Some(e) = c.try_event() {
            events.push(e);
        }
        let commands = events.iter().filter(|e| matches!(e, CoordinatorEvent::Reposition(_))).count();
        assert_eq!(commands, with_doa as usize, "observation {k}: {events:?}");
        if k == 3 {
            let CoordinatorEvent::StreamError(r) = &events[0] else { panic!("{events:?}") };
            assert_eq!((r.code, r.field.as_str(), r.sequence), (3, "observation.doas[0].activity", Some(3)));
            assert!(r.message.contains("out of range"));
        }
    }
    assert_eq!(c.stream_errors(), 1);
    // Command feedback and heartbeats reach the coordinator in order.
    c.send_command_ack(&CommandAck { command_id: 101, accepted: true, reason: String::new() }).await.unwrap();
    let p = CommandProgress {
        command_id: 101,
        state: CommandState::Executing,
        distance_remaining_m: None,
        detail: "on the way".into(),
    };
    c.send_command_progress(&p).await.unwrap();
    c.send_heartbeat(Stamp::now()).await.unwrap();
    for k in 1..=20 {
        assert_eq!(next(&mut got).await, Got::Observation(k));
    }
    let Got::CommandAck(a) = next(&mut got).await else { panic!() };
    assert_eq!((a.command_id, a.accepted), (101, true));
    let Got::CommandProgress(p) = next(&mut got).await else { panic!() };
    assert_eq!(
        (p.command_id, p.state, p.distance_remaining_m),
        (101, wire::CommandState::Executing as i32, -1.0)
    );
    assert_eq!(next(&mut got).await, Got::Heartbeat);
    // Misuse is an error, not a hang.
    assert!(c.wait_acked(99).await.is_err());
    let mut o = observation(false);
    o.sequence = 5;
    assert!(c.send_sequenced_observation(o).await.unwrap_err().to_string().contains("does not increase"));
}

#[tokio::test]
async fn refused_streams_and_unreachable_coordinators_are_errors() {
    let (fake, _got) = Fake::new(true);
    let (addr, _server) = serve(fake, any_port()).await;
    let e = LinkClient::connect(&format!("http://{addr}"), &hello("intruder"), None).await.unwrap_err();
    assert!(e.to_string().contains("PermissionDenied"), "{e}");
    let free = tokio::net::TcpListener::bind(any_port()).await.unwrap().local_addr().unwrap();
    let e = LinkClient::connect(&format!("http://{free}"), &hello("r1"), None).await.unwrap_err();
    assert!(e.to_string().contains("cannot connect"), "{e}");
    let e = LinkClient::connect("not a uri", &hello("r1"), None).await.unwrap_err();
    assert!(e.to_string().contains("bad endpoint"), "{e}");
}

fn config(addr: SocketAddr, capacity: usize) -> LinkConfig {
    LinkConfig {
        buffer_capacity: capacity,
        heartbeat_interval: Duration::from_millis(100),
        backoff_initial: Duration::from_millis(20),
        backoff_max: Duration::from_millis(200),
        connect_timeout: Duration::from_secs(2),
        ..LinkConfig::new(format!("http://{addr}"))
    }
}

/// Records what the link hands it.
#[derive(Debug, Default, Clone)]
struct RecordingNavigator {
    submitted: Arc<Mutex<Vec<u64>>>,
    pending: Vec<CommandProgress>,
}

impl Navigator for RecordingNavigator {
    fn submit(&mut self, c: &RepositionCommand, _now: Stamp) -> CommandAck {
        self.submitted.lock().unwrap().push(c.command_id);
        self.pending.push(CommandProgress {
            command_id: c.command_id,
            state: CommandState::Executing,
            distance_remaining_m: Some(2.5),
            detail: String::new(),
        });
        CommandAck { command_id: c.command_id, accepted: true, reason: String::new() }
    }
    fn cancel(&mut self, _id: u64, _reason: &str, _now: Stamp) {}
    fn poll_progress(&mut self, _now: Stamp, out: &mut Vec<CommandProgress>) {
        out.append(&mut self.pending);
    }
}

async fn eventually(what: &str, mut f: impl FnMut() -> bool) {
    let until = std::time::Instant::now() + WAIT;
    while !f() {
        assert!(std::time::Instant::now() < until, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// A live link around a fresh core, fed through its channels.
struct Running {
    link: LinkHandle,
    task: JoinHandle<LinkStats>,
    hops: mpsc::Sender<Hop>,
    poses: mpsc::Sender<StampedPose>,
    /// Stamp of the next hop (100 ms apart from now on).
    next: Stamp,
}

impl Running {
    fn start(addr: SocketAddr, capacity: usize, id: &str, navigator: Box<dyn Navigator>) -> Running {
        let core_config = CoreConfig { buffer_capacity: capacity, ..CoreConfig::default() };
        let core = Agent::new(hello(id), core_config, "test poses").unwrap();
        let (hops, hops_rx) = mpsc::channel(64);
        let (poses, poses_rx) = mpsc::channel(64);
        let inputs = LinkInputs { hops: hops_rx, poses: Some(poses_rx), lossless: false };
        let (link, task) = Link::spawn(config(addr, capacity), core, navigator, inputs, WAIT);
        Running { link, task, hops, poses, next: Stamp::now() }
    }

    /// A pose at `x` (m) just after the next hop's stamp, then the hop.
    async fn hop_at(&mut self, x: f64, with_doa: bool) {
        let pose = StampedPose {
            stamp: self.next.plus_ns(1_000_000),
            map_from_base: Isometry3::translation(x, 0.0, 0.0),
            covariance: None,
        };
        self.poses.send(pose).await.unwrap();
        let o = observation(with_doa);
        self.hops.send(Hop { stamp: self.next, doas: o.doas }).await.unwrap();
        self.next = self.next.plus_ns(100_000_000);
    }

    async fn hop(&mut self, with_doa: bool) {
        self.hop_at(0.0, with_doa).await
    }

    async fn stop(self) -> LinkStats {
        self.link.shutdown();
        tokio::time::timeout(WAIT, self.task).await.unwrap().unwrap()
    }
}

#[tokio::test]
async fn link_buffers_while_the_coordinator_is_down_and_drops_the_oldest() {
    // A port with nothing listening yet.
    let addr = tokio::net::TcpListener::bind(any_port()).await.unwrap().local_addr().unwrap();
    let mut r = Running::start(addr, 3, "r1", Box::<RecordingNavigator>::default());
    for _ in 0..5 {
        r.hop(true).await;
    }
    eventually("five observations", || r.link.stats().dropped == 2).await;
    let s = r.link.stats();
    assert_eq!((s.dropped, s.pending, s.connected), (2, 3, false));
    eventually("a failed connection attempt", || r.link.stats().connect_failures >= 1).await;
    // The coordinator comes up on that port: the three newest arrive, in order.
    let (fake, mut got) = Fake::new(true);
    fake.0.command_on_doas.store(false, Ordering::SeqCst);
    let (_, _server) = serve(fake, addr).await;
    assert!(matches!(next(&mut got).await, Got::Hello { .. }));
    for seq in 3..=5 {
        assert_eq!(next_non_heartbeat(&mut got).await, Got::Observation(seq));
    }
    assert!(r.link.flush(WAIT).await);
    let s = r.stop().await;
    assert_eq!((s.acked, s.sent, s.dropped, s.pending, s.connects), (3, 3, 2, 0, 1));
}

#[tokio::test]
async fn link_reconnects_after_a_restart_and_resends_what_was_not_acknowledged() {
    let (fake_a, mut got_a) = Fake::new(false); // receives, never acknowledges
    fake_a.0.command_on_doas.store(false, Ordering::SeqCst);
    let (addr, server_a) = serve(fake_a.clone(), any_port()).await;
    let mut r = Running::start(addr, 100, "r1", Box::<RecordingNavigator>::default());
    for _ in 0..3 {
        r.hop(true).await;
    }
    assert!(matches!(next(&mut got_a).await, Got::Hello { .. }));
    for seq in 1..=3 {
        assert_eq!(next_non_heartbeat(&mut got_a).await, Got::Observation(seq));
    }
    assert_eq!(r.link.stats().pending, 3);
    // Restart the coordinator on the same port.
    fake_a.0.kill.send(true).unwrap();
    server_a.abort();
    let _ = server_a.await;
    let (fake_b, mut got_b) = Fake::new(true);
    fake_b.0.command_on_doas.store(false, Ordering::SeqCst);
    let (_, _server_b) = serve(fake_b, addr).await;
    assert!(matches!(next(&mut got_b).await, Got::Hello { .. }));
    for seq in 1..=3 {
        assert_eq!(next_non_heartbeat(&mut got_b).await, Got::Observation(seq), "resent in order");
    }
    r.hop(true).await;
    assert_eq!(next_non_heartbeat(&mut got_b).await, Got::Observation(4));
    assert!(r.link.flush(WAIT).await);
    let s = r.stop().await;
    assert_eq!((s.connects, s.sent, s.resent, s.acked, s.dropped), (2, 4, 3, 4, 0));
}

#[tokio::test]
async fn link_relays_commands_counts_stream_errors_and_sends_heartbeats() {
    let (fake, mut got) = Fake::new(true);
    fake.0.error_on.store(2, Ordering::SeqCst);
    let (addr, _server) = serve(fake, any_port()).await;
    let nav = RecordingNavigator::default();
    let submitted = nav.submitted.clone();
    let mut r = Running::start(addr, 100, "r7", Box::new(nav));
    assert!(matches!(next(&mut got).await, Got::Hello { .. }));
    r.hop(true).await; // causes command 100
    assert_eq!(next_non_heartbeat(&mut got).await, Got::Observation(1));
    let Got::CommandAck(a) = next_non_heartbeat(&mut got).await else { panic!() };
    assert_eq!((a.command_id, a.accepted), (100, true));
    let Got::CommandProgress(p) = next_non_heartbeat(&mut got).await else { panic!() };
    assert_eq!(
        (p.command_id, p.state, p.distance_remaining_m),
        (100, wire::CommandState::Executing as i32, 2.5)
    );
    assert_eq!(*submitted.lock().unwrap(), vec![100]);
    // A StreamError does not break the link. The hop after the last DoA is sent
    // empty (the robot hears nothing), silent hops after it are not.
    r.hop(false).await;
    r.hop(false).await;
    r.hop(false).await;
    assert_eq!(next_non_heartbeat(&mut got).await, Got::Observation(2));
    assert!(r.link.flush(WAIT).await);
    eventually("the stream error to be counted", || r.link.stats().stream_errors == 1).await;
    // Idle: heartbeats, and no further observation.
    let mut heartbeats = 0;
    while heartbeats < 2 {
        match next(&mut got).await {
            Got::Heartbeat => heartbeats += 1,
            other => panic!("silent hops sent {other:?}"),
        }
    }
    let s = r.stop().await;
    assert_eq!((s.connects, s.commands, s.stream_errors, s.sent), (1, 1, 1, 2));
    assert!(s.heartbeats >= 2);
}

/// While nothing is heard only one empty observation per 0.5 s is sent, yet the
/// navigator must still see the robot arrive from the pose feed and report the
/// command done.
#[tokio::test]
async fn a_command_succeeds_while_the_robot_hears_nothing() {
    let (fake, mut got) = Fake::new(true);
    let (addr, _server) = serve(fake, any_port()).await;
    let dir = tempfile::Builder::new().prefix("soundmap-link-silent-").tempdir().unwrap();
    let goals = dir.path().join("goals.jsonl");
    let nav = JsonLinesNavigator::open(&goals, 0.2).unwrap();
    let mut r = Running::start(addr, 100, "r3", Box::new(nav));
    assert!(matches!(next(&mut got).await, Got::Hello { .. }));
    r.hop_at(0.0, true).await; // heard once: the fake sends command 100 to (1, 2)
    assert_eq!(next_non_heartbeat(&mut got).await, Got::Observation(1));
    let Got::CommandAck(a) = next_non_heartbeat(&mut got).await else { panic!() };
    assert!(a.accepted);
    // The source falls silent; the robot drives to the goal.
    for k in 1..=10 {
        let x = k as f64 * 0.1;
        r.poses
            .send(StampedPose {
                stamp: r.next.plus_ns(1_000_000),
                map_from_base: Isometry3::translation(x, 2.0 * x, 0.0),
                covariance: None,
            })
            .await
            .unwrap();
        r.hops.send(Hop { stamp: r.next, doas: vec![] }).await.unwrap();
        r.next = r.next.plus_ns(100_000_000);
    }
    let mut states = vec![];
    loop {
        match next_non_heartbeat(&mut got).await {
            Got::CommandProgress(p) => {
                states.push(p.state);
                if p.state == wire::CommandState::Succeeded as i32 {
                    break;
                }
            }
            Got::Observation(_) => {} // the empty observations of the silence
            other => panic!("unexpected {other:?}"),
        }
    }
    assert_eq!(states.first(), Some(&(wire::CommandState::Executing as i32)));
    let s = r.stop().await;
    // Silent hops run from 0.1 to 1.0 s after the DoA: the empty one after it
    // (0.1 s) and one more 0.5 s later (0.6 s), which tells where the robot is.
    assert_eq!(s.sent, 3, "the DoA, one empty after it, one empty 0.5 s into the silence");
    let text = std::fs::read_to_string(&goals).unwrap();
    assert!(text.contains("\"command_id\":100"), "{text}");
}

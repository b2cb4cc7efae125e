//! A minimal robot client for the coordinator's end-to-end tests: real gRPC
//! over a real loopback socket, using the generated client directly.

#![allow(dead_code)]

pub mod fleet;

use std::sync::Arc;
use std::time::Duration;

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use soundmap_proto::wire::coordinator_message::Msg as Down;
use soundmap_proto::wire::robot_link_client::RobotLinkClient;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{ArrayInfo, Hello, Observation, RobotId, Stamp, TrackedDoa, wire};
use soundmap_server::CoordinatorConfig;
use soundmap_server::clock::ManualClock;
use soundmap_server::service::{self, RunningCoordinator};
use tokio::sync::mpsc;
use tonic::Streaming;

/// Start of simulated time in the tests (2026-01-01T00:00:00Z).
pub const T0: Stamp = Stamp::from_ns(1_767_225_600_000_000_000);

/// A coordinator on 127.0.0.1 with a manual clock and no ticker.
pub async fn start(mut config: CoordinatorConfig) -> (RunningCoordinator, ManualClock) {
    config.liveness.tick_ms = 0;
    let clock = ManualClock::new(T0);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let running = service::start(config, Arc::new(clock.clone()), listener).await.unwrap();
    (running, clock)
}

/// The array every test robot carries: 0.48 m above the base.
pub fn array() -> ArrayInfo {
    ArrayInfo {
        base_from_array: Isometry3::translation(0.0, 0.0, 0.48),
        microphone_count: 16,
        preset: Some("16soundsusb-pioneer".into()),
        microphone_positions: vec![],
        srp_band_hz: None,
        direct_path_elevations: false,
    }
}

/// The array of the in-process coordinator tests' robots: 16 microphones
/// 0.48 m above the base, no preset, positions or band declared.
pub fn undeclared_array() -> ArrayInfo {
    ArrayInfo { preset: None, ..array() }
}

/// A hello with `id` as given (not validated here: tests send bad ids too).
pub fn hello(id: &str) -> wire::RobotMessage {
    let mut h = Hello {
        robot_id: RobotId::parse("x", "id").unwrap(),
        array: array(),
        software_version: "test".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    }
    .to_wire();
    h.robot_id = id.into();
    wire::RobotMessage { msg: Some(Up::Hello(h)) }
}

/// One robot's stream.
pub struct Robot {
    pub tx: mpsc::Sender<wire::RobotMessage>,
    pub rx: Streaming<wire::CoordinatorMessage>,
    pub seq: u64,
    pub welcome: wire::Welcome,
}

/// A gRPC channel to `addr`. (The generated clients have no `connect`
/// constructor: the RPC `RobotLink.Connect` takes that name.)
pub async fn grpc(addr: std::net::SocketAddr) -> tonic::transport::Channel {
    tonic::transport::Endpoint::from_shared(format!("http://{addr}")).unwrap().connect().await.unwrap()
}

pub async fn channel(addr: std::net::SocketAddr) -> RobotLinkClient<tonic::transport::Channel> {
    RobotLinkClient::new(grpc(addr).await)
}

pub async fn monitoring(
    addr: std::net::SocketAddr,
) -> soundmap_proto::wire::monitoring_client::MonitoringClient<tonic::transport::Channel> {
    soundmap_proto::wire::monitoring_client::MonitoringClient::new(grpc(addr).await)
}

/// Opens a stream and sends `first`; returns the stream or the status that ended it.
pub async fn open(
    addr: std::net::SocketAddr,
    first: wire::RobotMessage,
    token: Option<&str>,
) -> Result<Robot, tonic::Status> {
    let (tx, rx) = mpsc::channel(1024);
    tx.send(first).await.unwrap();
    let mut request = tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx));
    if let Some(t) = token {
        request.metadata_mut().insert("authorization", format!("Bearer {t}").parse().unwrap());
    }
    let response = channel(addr).await.connect(request).await?;
    let mut robot = Robot { tx, rx: response.into_inner(), seq: 0, welcome: wire::Welcome::default() };
    match robot.next().await? {
        Down::Welcome(w) => {
            robot.welcome = w;
            Ok(robot)
        }
        other => panic!("expected a welcome, got {other:?}"),
    }
}

/// Connects a robot by id and waits for its welcome.
pub async fn connect(addr: std::net::SocketAddr, id: &str) -> Robot {
    open(addr, hello(id), None).await.unwrap()
}

impl Robot {
    /// Next message from the coordinator (5 s timeout).
    pub async fn next(&mut self) -> Result<Down, tonic::Status> {
        let m = tokio::time::timeout(Duration::from_secs(5), self.rx.message())
            .await
            .expect("coordinator answered within 5 s")?;
        Ok(m.expect("stream open").msg.expect("message set"))
    }

    /// Sends a raw message.
    pub async fn send(&self, msg: Up) {
        self.tx.send(wire::RobotMessage { msg: Some(msg) }).await.unwrap();
    }

    /// Sends an observation with the next sequence number; returns it.
    pub async fn observe(&mut self, mut obs: wire::Observation) -> u64 {
        self.seq += 1;
        obs.sequence = self.seq;
        self.send(Up::Observation(obs)).await;
        self.seq
    }

    /// Waits for the ack of `seq`, collecting stream errors and commands on the way.
    pub async fn until_acked(&mut self, seq: u64) -> Vec<Down> {
        let mut others = Vec::new();
        loop {
            match self.next().await.unwrap() {
                Down::ObservationAck(a) if a.up_to_sequence >= seq => return others,
                Down::ObservationAck(_) => {}
                m => others.push(m),
            }
        }
    }
}

/// An observation of `source` by a robot whose base is at `base` (yaw given), with
/// the DoA perturbed by `doa_error` (a rotation applied in the array frame).
pub fn observation_of(
    stamp: Stamp,
    base: Point3<f64>,
    yaw: f64,
    source: &Point3<f64>,
    doa_error: Option<nalgebra::UnitQuaternion<f64>>,
    sigma_rad: f64,
) -> wire::Observation {
    let map_from_base = Isometry3::new(base.coords, Vector3::z() * yaw);
    let map_from_array = map_from_base * array().base_from_array;
    let d = map_from_array.inverse() * source;
    let mut d = d.coords.normalize();
    if let Some(q) = doa_error {
        d = q * d;
    }
    Observation {
        sequence: 0,
        stamp,
        map_from_base,
        pose_covariance: None,
        doas: vec![TrackedDoa {
            track_id: 1,
            direction_in_array: Unit::new_normalize(d),
            activity: 0.9,
            angular_sigma_rad: Some(sigma_rad),
            signature: None,
            coherence: None,
            floor_fit_range_m: None,
        }],
    }
    .to_wire()
}

/// Receives the next estimate from an in-process subscription (5 s timeout).
pub async fn next_estimate(
    rx: &mut tokio::sync::broadcast::Receiver<Arc<wire::SourceEstimate>>,
) -> Arc<wire::SourceEstimate> {
    tokio::time::timeout(Duration::from_secs(5), rx.recv()).await.expect("estimate within 5 s").unwrap()
}

pub fn position(e: &wire::SourceEstimate) -> Point3<f64> {
    let p = e.position_in_map_m.as_ref().expect("estimate has a position");
    Point3::new(p.x, p.y, p.z)
}

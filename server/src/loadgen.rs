//! Simulated robots over real gRPC, for the load benchmark (`soundmap-load`)
//! and the restart (chaos) tests: each robot streams exact bearings of one
//! source at a fixed rate, reconnects whenever its stream ends, and records
//! which of its observations the coordinator acknowledged.
//!
//! Acknowledgements are cumulative per stream: on a stream whose first
//! observation had sequence `a` and whose last ack said `up_to`, sequences
//! `a..=up_to` were acknowledged. Sequences grow across reconnections, so the
//! acknowledged set is the union of those ranges ([`RobotLog::acked`]).

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use soundmap_proto::wire::coordinator_message::Msg as Down;
use soundmap_proto::wire::robot_link_client::RobotLinkClient;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{ArrayInfo, Hello, Observation, RobotId, Stamp, TrackedDoa, wire};
use tokio::sync::mpsc;

/// The source every simulated robot hears (map frame, m).
pub const SOURCE: Point3<f64> = Point3::new(2.0, 3.0, 1.12);

/// Which stamps a robot puts on its observations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StampMode {
    /// The wall clock when sent (what a real robot does).
    Now,
    /// Always the same stamp (the identical-stamp flood).
    Fixed(Stamp),
}

/// One simulated robot.
#[derive(Clone, Debug)]
pub struct RobotSpec {
    /// Its id.
    pub id: String,
    /// Where its base stands (map frame).
    pub base: Point3<f64>,
    /// Its heading (rad).
    pub yaw: f64,
}

impl RobotSpec {
    /// Robot `i` of `n` on a circle of `radius` m around [`SOURCE`] (floor level).
    pub fn on_ring(prefix: &str, i: usize, n: usize, radius: f64) -> Self {
        let a = std::f64::consts::TAU * i as f64 / n.max(1) as f64;
        RobotSpec {
            id: format!("{prefix}-{i}"),
            base: Point3::new(SOURCE.x + radius * a.cos(), SOURCE.y + radius * a.sin(), 0.0),
            yaw: 0.3 * i as f64,
        }
    }
}

/// The array every simulated robot carries: 0.48 m above its base.
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

/// The hello of robot `id`.
pub fn hello(id: &str) -> Result<wire::RobotMessage, soundmap_proto::ValidationError> {
    let h = Hello {
        robot_id: RobotId::parse(id, "robot_id")?,
        array: array(),
        software_version: "soundmap-load".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    };
    Ok(wire::RobotMessage { msg: Some(Up::Hello(h.to_wire())) })
}

/// An observation of [`SOURCE`] by `spec` (exact bearing, σ 0.05 rad).
pub fn observation(spec: &RobotSpec, sequence: u64, stamp: Stamp) -> wire::RobotMessage {
    let map_from_base = Isometry3::new(spec.base.coords, Vector3::z() * spec.yaw);
    let map_from_array = map_from_base * array().base_from_array;
    let d = (map_from_array.inverse() * SOURCE).coords;
    let obs = Observation {
        sequence,
        stamp,
        map_from_base,
        pose_covariance: None,
        doas: vec![TrackedDoa {
            track_id: 1,
            direction_in_array: Unit::new_normalize(d),
            activity: 0.9,
            angular_sigma_rad: Some(0.05),
            signature: None,
            coherence: None,
            floor_fit_range_m: None,
        }],
    };
    wire::RobotMessage { msg: Some(Up::Observation(obs.to_wire())) }
}

/// The wall clock as a stamp.
pub fn wall_clock() -> Stamp {
    let ns = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    Stamp::from_ns(ns as i64)
}

/// What one robot sent and what was acknowledged.
#[derive(Clone, Debug, Default)]
pub struct RobotLog {
    /// Last sequence sent.
    pub sent: u64,
    /// Per stream: (first sequence sent on it, highest acknowledged).
    pub streams: Vec<(u64, u64)>,
    /// Streams opened (welcomes received).
    pub connections: u64,
    /// In-band errors received (rejected observations and others).
    pub errors: u64,
}

impl RobotLog {
    /// Whether sequence `s` was acknowledged.
    pub fn acked(&self, s: u64) -> bool {
        self.streams.iter().any(|(a, b)| (*a..=*b).contains(&s))
    }

    /// Sequences acknowledged.
    pub fn acked_count(&self) -> u64 {
        self.streams.iter().map(|(a, b)| (b + 1).saturating_sub(*a)).sum()
    }
}

/// A gRPC channel to `addr` (plaintext, loopback).
pub async fn channel(
    addr: std::net::SocketAddr,
) -> Result<tonic::transport::Channel, tonic::transport::Error> {
    tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .expect("a valid URI")
        .connect_timeout(Duration::from_secs(2))
        .connect()
        .await
}

/// Runs robot `spec` against `addr` at `rate_hz` until `until` (reconnecting
/// whenever its stream ends), then waits up to 2 s for the last
/// acknowledgements. Its log is kept up to date in `log`.
pub async fn run_robot(
    addr: std::net::SocketAddr,
    spec: RobotSpec,
    rate_hz: f64,
    stamps: StampMode,
    until: Instant,
    log: Arc<Mutex<RobotLog>>,
) {
    let period = Duration::from_secs_f64(1.0 / rate_hz.max(0.1));
    let Ok(hello) = hello(&spec.id) else { return };
    let mut seq = 0u64;
    while Instant::now() < until {
        let Ok(ch) = channel(addr).await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let (tx, rx) = mpsc::channel(1024);
        let _ = tx.try_send(hello.clone());
        let request = tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx));
        let Ok(response) = RobotLinkClient::new(ch).connect(request).await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let mut inbound = response.into_inner();
        match tokio::time::timeout(Duration::from_secs(2), inbound.message()).await {
            Ok(Ok(Some(wire::CoordinatorMessage { msg: Some(Down::Welcome(_)) }))) => {}
            _ => {
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        }
        let first = seq + 1;
        let slot = {
            let mut l = log.lock().unwrap_or_else(|p| p.into_inner());
            l.connections += 1;
            l.streams.push((first, 0));
            l.streams.len() - 1
        };
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut draining: Option<Instant> = None;
        loop {
            tokio::select! {
                _ = tick.tick(), if draining.is_none() => {
                    if Instant::now() >= until {
                        draining = Some(Instant::now() + Duration::from_secs(2));
                        continue;
                    }
                    let stamp = match stamps { StampMode::Now => wall_clock(), StampMode::Fixed(s) => s };
                    if tx.try_send(observation(&spec, seq + 1, stamp)).is_ok() {
                        seq += 1;
                        log.lock().unwrap_or_else(|p| p.into_inner()).sent = seq;
                    }
                }
                _ = tokio::time::sleep(Duration::from_millis(20)), if draining.is_some() => {
                    let acked = log.lock().unwrap_or_else(|p| p.into_inner()).streams[slot].1;
                    if acked >= seq || draining.is_some_and(|d| Instant::now() >= d) {
                        return;
                    }
                }
                m = inbound.message() => match m {
                    Ok(Some(wire::CoordinatorMessage { msg: Some(Down::ObservationAck(a)) })) => {
                        let mut l = log.lock().unwrap_or_else(|p| p.into_inner());
                        let s = &mut l.streams[slot];
                        s.1 = s.1.max(a.up_to_sequence.min(seq));
                    }
                    Ok(Some(wire::CoordinatorMessage { msg: Some(Down::Error(_)) })) => {
                        log.lock().unwrap_or_else(|p| p.into_inner()).errors += 1;
                    }
                    Ok(Some(_)) => {}
                    Ok(None) | Err(_) => break,
                }
            }
        }
        if draining.is_some() {
            return;
        }
    }
}

/// Resident set size of process `pid` (Linux `/proc`), bytes.
pub fn rss_bytes(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

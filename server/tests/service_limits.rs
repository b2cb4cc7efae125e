//! The service's bounds seen by real gRPC clients over loopback: a stream that
//! says no hello is ended with `DEADLINE_EXCEEDED`; idle connections from one
//! address fill only that address's places (a robot from another address
//! still connects at once); a robot over its observation rate gets in-band
//! `RESOURCE_EXHAUSTED` errors for the excess, its stream stays open and every
//! observation is acknowledged.

use crate::common;

use std::time::{Duration, Instant};

use common::{T0, connect, hello, observation_of, open, start};
use nalgebra::Point3;
use soundmap_proto::wire;
use soundmap_proto::wire::coordinator_message::Msg as Down;
use soundmap_server::CoordinatorConfig;
use tonic::Code;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_without_a_hello_is_ended_after_the_hello_timeout() {
    let mut config = CoordinatorConfig::default();
    config.server.hello_timeout_ms = 300;
    let (coordinator, _clock) = start(config).await;
    let (tx, rx) = tokio::sync::mpsc::channel::<wire::RobotMessage>(4);
    let mut link = common::channel(coordinator.local_addr).await;
    let started = Instant::now();
    let reply = link.connect(tokio_stream::wrappers::ReceiverStream::new(rx)).await;
    let status = match reply {
        Err(status) => status,
        Ok(response) => {
            let mut stream = response.into_inner();
            let next =
                tokio::time::timeout(Duration::from_secs(5), stream.message()).await.expect("ended in time");
            next.expect_err("no message before the hello")
        }
    };
    let waited = started.elapsed();
    assert_eq!(status.code(), Code::DeadlineExceeded, "{status:?}");
    assert!(status.message().contains("hello"), "{status:?}");
    assert!(waited >= Duration::from_millis(250) && waited < Duration::from_secs(3), "{waited:?}");
    drop(tx);
    // The coordinator still welcomes a robot that does say hello.
    connect(coordinator.local_addr, "after").await;
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_from_one_address_do_not_keep_out_another() {
    let mut config = CoordinatorConfig::default();
    config.server.max_connections_per_peer = 4;
    let (coordinator, _clock) = start(config).await;
    let addr = coordinator.local_addr;
    // 12 idle TCP connections from 127.0.0.2: at most 4 are kept.
    let mut idle = Vec::new();
    for _ in 0..12 {
        let socket = tokio::net::TcpSocket::new_v4().unwrap();
        socket.bind("127.0.0.2:0".parse().unwrap()).unwrap();
        idle.push(socket.connect(addr).await.unwrap());
    }
    // A robot from 127.0.0.1 connects at once.
    let started = Instant::now();
    let robot = tokio::time::timeout(Duration::from_secs(2), open(addr, hello("robot"), None))
        .await
        .expect("welcomed within 2 s")
        .unwrap();
    assert!(started.elapsed() < Duration::from_secs(2));
    // A gRPC client from 127.0.0.2 finds no place: its connection is closed.
    let from_idle = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .unwrap()
        .local_address(Some("127.0.0.2".parse().unwrap()))
        .connect_timeout(Duration::from_secs(2));
    let refused = async {
        let channel = from_idle.connect().await.map_err(|e| e.to_string())?;
        let mut m = soundmap_proto::wire::monitoring_client::MonitoringClient::new(channel);
        m.get_state(wire::GetStateRequest::default()).await.map_err(|e| e.to_string()).map(|_| ())
    };
    let r = tokio::time::timeout(Duration::from_secs(5), refused).await.expect("answered within 5 s");
    assert!(r.is_err(), "a fifth connection from 127.0.0.2 was served");
    let limits = coordinator.metrics.limits.snapshot();
    println!("limits after the idle connections: {limits:?}");
    drop(robot);
    drop(idle);
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn observations_over_the_rate_are_rejected_in_band_and_acknowledged() {
    let mut config = CoordinatorConfig::default();
    config.server.max_observation_rate_hz = 20.0;
    let (coordinator, clock) = start(config).await;
    let mut robot = connect(coordinator.local_addr, "fast").await;
    let source = Point3::new(2.0, 1.0, 1.2);
    let mut last = 0;
    for k in 0..100 {
        let stamp = T0.plus_secs(0.001 * k as f64);
        last = robot.observe(observation_of(stamp, Point3::origin(), 0.0, &source, None, 0.02)).await;
    }
    let others = robot.until_acked(last).await;
    let exhausted = others
        .iter()
        .filter(|m| matches!(m, Down::Error(e) if e.code == Code::ResourceExhausted as i32))
        .count();
    // A burst of one second's worth (20) passes; the coordinator's (manual)
    // clock stands still, so the other 80 are rejected.
    assert_eq!(exhausted, 80, "{others:?}");
    // The stream is still open: an observation a second later is acknowledged.
    // (The rate is counted on the coordinator's clock, here a manual one.)
    clock.set(T0.plus_secs(1.1));
    let seq =
        robot.observe(observation_of(T0.plus_secs(1.0), Point3::origin(), 0.0, &source, None, 0.02)).await;
    let others = robot.until_acked(seq).await;
    assert!(others.iter().all(|m| !matches!(m, Down::Error(_))), "{others:?}");
    coordinator.shutdown().await.unwrap();
}

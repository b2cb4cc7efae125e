//! Liveness, reconnection and authentication over a real socket.

use crate::common;

use std::time::Duration;

use common::*;
use nalgebra::Point3;
use soundmap_proto::wire;
use soundmap_server::CoordinatorConfig;
use tonic::Code;

const SOURCE: Point3<f64> = Point3::new(2.0, 3.0, 1.12);
const BASES: [Point3<f64>; 3] =
    [Point3::new(-1.0, 3.0, 0.0), Point3::new(2.0, 0.0, 0.0), Point3::new(5.0, 4.0, 0.0)];

async fn liveness_of(addr: std::net::SocketAddr, id: &str) -> i32 {
    let state = monitoring(addr).await.get_state(wire::GetStateRequest {}).await.unwrap().into_inner();
    state.robots.iter().find(|r| r.robot_id == id).map(|r| r.liveness).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_robot_goes_stale_leaves_triangulation_and_resumes() {
    let (coordinator, clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut robots = vec![connect(addr, "a").await, connect(addr, "b").await, connect(addr, "c").await];
    let send = async |robots: &mut [Robot], which: &[usize], t| {
        for &i in which {
            let s = robots[i].observe(observation_of(t, BASES[i], 0.0, &SOURCE, None, 0.05)).await;
            robots[i].until_acked(s).await;
        }
    };
    clock.set(T0);
    send(&mut robots, &[0, 1, 2], T0).await;
    let mut last = next_estimate(&mut estimates).await;
    while last.robots.len() < 3 {
        last = next_estimate(&mut estimates).await;
    }
    // c falls silent for longer than the stale timeout (2 s).
    let t = T0.plus_secs(3.0);
    clock.set(t);
    send(&mut robots, &[0, 1], t).await;
    let e = next_estimate(&mut estimates).await;
    assert_eq!(e.robots, vec!["a".to_string(), "b".to_string()], "stale c must leave triangulation");
    assert_eq!(liveness_of(addr, "c").await, wire::Liveness::Stale as i32);
    assert_eq!(liveness_of(addr, "a").await, wire::Liveness::Live as i32);
    // c speaks again and is back.
    let t = T0.plus_secs(3.05);
    clock.set(t);
    send(&mut robots, &[2], t).await;
    let e = next_estimate(&mut estimates).await;
    assert_eq!(e.robots.len(), 3);
    assert_eq!(liveness_of(addr, "c").await, wire::Liveness::Live as i32);
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconnecting_with_the_same_id_resumes() {
    let (coordinator, clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    assert!(!b.welcome.resumed);
    clock.set(T0);
    let s = a.observe(observation_of(T0, BASES[0], 0.0, &SOURCE, None, 0.05)).await;
    a.until_acked(s).await;
    let s = b.observe(observation_of(T0, BASES[1], 0.0, &SOURCE, None, 0.05)).await;
    b.until_acked(s).await;
    next_estimate(&mut estimates).await;
    // b's stream closes: it is reported disconnected and leaves triangulation.
    drop(b);
    let mut tries = 0;
    while liveness_of(addr, "b").await != wire::Liveness::Disconnected as i32 {
        tries += 1;
        assert!(tries < 100, "b never reported disconnected");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let t = T0.plus_secs(0.5);
    clock.set(t);
    let s = a.observe(observation_of(t, BASES[0], 0.0, &SOURCE, None, 0.05)).await;
    a.until_acked(s).await;
    // A live robot's id cannot be taken …
    let refused = open(addr, hello("a"), None).await.err().expect("a is live");
    assert_eq!(refused.code(), Code::AlreadyExists);
    // … but b reconnects and resumes, with a fresh sequence on its new stream.
    let mut b = connect(addr, "b").await;
    assert!(b.welcome.resumed);
    let s = b.observe(observation_of(t, BASES[1], 0.0, &SOURCE, None, 0.05)).await;
    assert!(b.until_acked(s).await.is_empty());
    let e = next_estimate(&mut estimates).await;
    assert_eq!(e.robots.len(), 2);
    assert_eq!(e.stamp_ns, t.as_ns());
    // A stale stream can be taken over by a new connection with the same id.
    clock.set(T0.plus_secs(5.0));
    let a2 = open(addr, hello("a"), None).await.expect("stale stream taken over");
    assert!(a2.welcome.resumed);
    let ended = a.next().await.expect_err("old stream of a ended");
    assert_eq!(ended.code(), Code::Aborted, "{ended:?}");
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_tokens_prove_identity() {
    let mut config = CoordinatorConfig::default();
    config.auth.required = true;
    config.auth.tokens.insert("a".into(), "token-of-robot-a-0123".into());
    config.auth.tokens.insert("b".into(), "token-of-robot-b-4567".into());
    let (coordinator, _clock) = start(config).await;
    let addr = coordinator.local_addr;
    let missing = open(addr, hello("a"), None).await.err().unwrap();
    assert_eq!(missing.code(), Code::Unauthenticated, "{missing:?}");
    let wrong = open(addr, hello("a"), Some("not-a-token-at-all!!")).await.err().unwrap();
    assert_eq!(wrong.code(), Code::Unauthenticated, "{wrong:?}");
    let other = open(addr, hello("a"), Some("token-of-robot-b-4567")).await.err().unwrap();
    assert_eq!(other.code(), Code::PermissionDenied, "{other:?}");
    assert!(other.message().contains("hello.robot_id"), "{other:?}");
    let ok = open(addr, hello("a"), Some("token-of-robot-a-0123")).await;
    assert!(ok.is_ok(), "{:?}", ok.err());
    coordinator.shutdown().await.unwrap();
}

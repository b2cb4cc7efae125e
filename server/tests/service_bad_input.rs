//! Bad input over a real socket: each malformed message class gets a specific
//! error naming the field, the stream stays open, other robots are unaffected,
//! and the coordinator keeps running with the data it had.

use crate::common;

use common::*;
use nalgebra::Point3;
use soundmap_proto::wire::coordinator_message::Msg as Down;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{Stamp, wire};
use soundmap_server::CoordinatorConfig;
use tonic::Code;

const SOURCE: Point3<f64> = Point3::new(2.0, 3.0, 1.12);
const BASE_A: Point3<f64> = Point3::new(-1.0, 3.0, 0.0);
const BASE_B: Point3<f64> = Point3::new(2.0, 0.0, 0.0);

fn good(t: Stamp, base: Point3<f64>) -> wire::Observation {
    observation_of(t, base, 0.0, &SOURCE, None, 0.05)
}

/// A malformed observation, the field its error must name, and the expected code.
fn malformed(t: Stamp) -> Vec<(&'static str, wire::Observation, &'static str)> {
    let mut cases = Vec::new();
    let mut o = good(t, BASE_A);
    o.doas[0].direction_in_array.as_mut().unwrap().x = f64::NAN;
    cases.push(("NaN direction", o, "observation.doas[0].direction_in_array.x"));
    let mut o = good(t, BASE_A);
    o.doas[0].direction_in_array = Some(wire::Vec3 { x: 1.0, y: 1.0, z: 0.0 });
    cases.push(("non-unit direction", o, "observation.doas[0].direction_in_array"));
    let mut o = good(t, BASE_A);
    o.doas[0].direction_in_array = None;
    cases.push(("missing direction", o, "observation.doas[0].direction_in_array"));
    let mut o = good(t, BASE_A);
    o.map_from_base.as_mut().unwrap().rotation = Some(wire::Quaternion { w: 0.0, x: 0.0, y: 0.0, z: 0.0 });
    cases.push(("zero quaternion", o, "observation.map_from_base.rotation"));
    let mut o = good(t, BASE_A);
    o.map_from_base.as_mut().unwrap().rotation = Some(wire::Quaternion { w: 0.1, x: 0.2, y: 0.3, z: 3.0 });
    cases.push(("non-unit quaternion", o, "observation.map_from_base.rotation"));
    let mut o = good(t, BASE_A);
    o.map_from_base.as_mut().unwrap().translation_m.as_mut().unwrap().y = f64::INFINITY;
    cases.push(("infinite position", o, "observation.map_from_base.translation_m.y"));
    let mut o = good(t, BASE_A);
    o.map_from_base = None;
    cases.push(("missing pose", o, "observation.map_from_base"));
    let mut o = good(t, BASE_A);
    o.stamp_ns = t.plus_secs(3600.0).as_ns();
    cases.push(("stamp an hour ahead", o, "observation.stamp_ns"));
    let mut o = good(t, BASE_A);
    o.stamp_ns = -5;
    cases.push(("negative stamp", o, "observation.stamp_ns"));
    let mut o = good(t, BASE_A);
    o.doas[0].activity = 2.0;
    cases.push(("activity above 1", o, "observation.doas[0].activity"));
    let mut o = good(t, BASE_A);
    o.doas[0].angular_sigma_rad = f64::NAN;
    cases.push(("NaN sigma", o, "observation.doas[0].angular_sigma_rad"));
    let mut o = good(t, BASE_A);
    o.map_from_base_covariance = Some(wire::PoseCovariance { values: vec![0.1; 7] });
    cases.push(("covariance of 7 values", o, "observation.map_from_base_covariance.values"));
    cases
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_malformed_message_gets_invalid_argument_naming_the_field() {
    let (coordinator, clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    let mut k = 0;
    let step = |k: &mut i64| {
        *k += 1;
        let t = T0.plus_secs(0.1 * *k as f64);
        clock.set(t);
        t
    };
    for (what, obs, field) in malformed(T0) {
        // The bad message is reported on the stream, by sequence, naming the field …
        let t = step(&mut k);
        let mut obs = obs;
        obs.stamp_ns = if what.contains("stamp") { obs.stamp_ns } else { t.as_ns() };
        let bad = a.observe(obs).await;
        let reports = a.until_acked(bad).await;
        let [Down::Error(err)] = &reports[..] else {
            panic!("{what}: expected one stream error, got {reports:?}")
        };
        assert_eq!(err.code, Code::InvalidArgument as i32, "{what}: {err:?}");
        assert_eq!(err.field, field, "{what}");
        assert_eq!(err.sequence, bad, "{what}");
        assert!(err.message.starts_with(field), "{what}: message {:?} does not name the field", err.message);
        // … the same stream goes on, and the other robot is unaffected.
        let s = a.observe(good(t, BASE_A)).await;
        assert!(a.until_acked(s).await.is_empty(), "{what}: the next good observation was refused");
        let s = b.observe(good(t, BASE_B)).await;
        assert!(b.until_acked(s).await.is_empty());
        let e = next_estimate(&mut estimates).await;
        // The first good observation of a pairs with b's previous one (0.1 s old, outside the window) → no estimate;
        // b's then pairs with a's: one estimate per step, from both robots.
        assert_eq!(e.robots.len(), 2, "{what}");
        assert!((position(&e) - SOURCE).norm() < 1e-6, "{what}");
    }
    // Stateful checks: out-of-order stamps and non-increasing sequences.
    let t = step(&mut k);
    let s = a.observe(good(t, BASE_A)).await;
    a.until_acked(s).await;
    let mut old = good(t.plus_secs(-0.5), BASE_A);
    a.seq += 1;
    old.sequence = a.seq;
    a.send(Up::Observation(old)).await;
    let reports = a.until_acked(a.seq).await;
    let [Down::Error(err)] = &reports[..] else { panic!("{reports:?}") };
    assert_eq!(
        (err.code, err.field.as_str()),
        (Code::InvalidArgument as i32, "observation.stamp_ns"),
        "{err:?}"
    );
    let mut replay = good(t, BASE_A);
    replay.sequence = a.seq - 1;
    a.send(Up::Observation(replay)).await;
    let s = a.observe(good(t, BASE_A)).await;
    let reports = a.until_acked(s).await;
    let [Down::Error(err)] = &reports[..] else { panic!("{reports:?}") };
    assert_eq!(
        (err.code, err.field.as_str()),
        (Code::InvalidArgument as i32, "observation.sequence"),
        "{err:?}"
    );
    // An empty envelope, a second hello, and feedback on a command never issued.
    a.send(Up::Heartbeat(wire::Heartbeat { stamp_ns: t.as_ns() })).await;
    a.tx.send(wire::RobotMessage { msg: None }).await.unwrap();
    a.tx.send(hello("a")).await.unwrap();
    a.send(Up::CommandAck(wire::CommandAck { command_id: 77, accepted: true, reason: String::new() })).await;
    let expected = [
        (Code::InvalidArgument, "msg"),
        (Code::FailedPrecondition, "hello"),
        (Code::NotFound, "command_ack.command_id"),
    ];
    for (code, field) in expected {
        let Down::Error(err) = a.next().await.unwrap() else { panic!("expected an error") };
        assert_eq!((err.code, err.field.as_str()), (code as i32, field), "{err:?}");
    }
    // The coordinator kept everything: counts in GetState, both robots live.
    let state = monitoring(addr).await.get_state(wire::GetStateRequest {}).await.unwrap().into_inner();
    let ra = state.robots.iter().find(|r| r.robot_id == "a").unwrap();
    let n_bad = malformed(T0).len() as u64 + 2;
    assert_eq!(ra.observations_rejected, n_bad);
    assert_eq!(ra.observations_accepted, malformed(T0).len() as u64 + 2);
    assert!(state.robots.iter().all(|r| r.liveness == wire::Liveness::Live as i32));
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_hellos_end_the_stream_with_a_status_and_others_carry_on() {
    let (coordinator, _clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let _a = connect(addr, "a").await;
    let cases: Vec<(wire::RobotMessage, Code, &str)> = vec![
        (hello(""), Code::InvalidArgument, "hello.robot_id"),
        (hello(&"x".repeat(65)), Code::InvalidArgument, "hello.robot_id"),
        (hello("robot one"), Code::InvalidArgument, "hello.robot_id"),
        (
            {
                let mut h = hello("c");
                if let Some(Up::Hello(h)) = &mut h.msg {
                    h.array.as_mut().unwrap().microphone_count = 1;
                }
                h
            },
            Code::InvalidArgument,
            "hello.array.microphone_count",
        ),
        (
            {
                let mut h = hello("c");
                if let Some(Up::Hello(h)) = &mut h.msg {
                    h.base_limits =
                        Some(wire::BaseLimits { max_speed_m_per_s: f64::NAN, max_turn_rate_deg_per_s: 0.0 });
                }
                h
            },
            Code::InvalidArgument,
            "hello.base_limits.max_speed_m_per_s",
        ),
        (
            wire::RobotMessage { msg: Some(Up::Heartbeat(wire::Heartbeat { stamp_ns: 1 })) },
            Code::InvalidArgument,
            "msg",
        ),
        (hello("a"), Code::AlreadyExists, "a"),
    ];
    for (first, code, mention) in cases {
        let status = open(addr, first, None).await.err().expect("refused");
        assert_eq!(status.code(), code, "{status:?}");
        assert!(status.message().contains(mention), "{status:?} should mention {mention}");
    }
    // The coordinator still serves.
    let _c = connect(addr, "c").await;
    coordinator.shutdown().await.unwrap();
}

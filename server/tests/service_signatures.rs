//! Tracks with spectral signatures over a real socket: observations are
//! checked against the hello of their stream (declared signature bands and
//! `max_tracks`, distinct track ids). A bad one is rejected with a stream
//! error naming the field; the stream goes on and other robots are unaffected.

use crate::common;

use common::*;
use nalgebra::Point3;
use soundmap_proto::wire::coordinator_message::Msg as Down;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{Stamp, wire};
use soundmap_server::CoordinatorConfig;
use tonic::Code;

const SOURCE: Point3<f64> = Point3::new(2.0, 3.0, 1.12);
const OTHER: Point3<f64> = Point3::new(0.5, 1.0, 1.6);
const BASE_A: Point3<f64> = Point3::new(-1.0, 3.0, 0.0);
const BASE_B: Point3<f64> = Point3::new(2.0, 0.0, 0.0);
const EDGES_HZ: [f64; 4] = [100.0, 800.0, 2500.0, 7200.0];

/// A hello declaring three signature bands and at most two tracks.
fn hello_with_signatures(id: &str) -> wire::RobotMessage {
    let mut m = hello(id);
    if let Some(Up::Hello(h)) = &mut m.msg {
        h.signature_bands = Some(wire::SignatureBands { band_edges_hz: EDGES_HZ.to_vec() });
        h.max_tracks = 2;
    }
    m
}

/// Two tracks (ids 1 and 2) with three-band signatures.
fn good(t: Stamp, base: Point3<f64>) -> wire::Observation {
    let mut o = observation_of(t, base, 0.0, &SOURCE, None, 0.05);
    let mut second = observation_of(t, base, 0.0, &OTHER, None, 0.05).doas.remove(0);
    second.track_id = 2;
    o.doas.push(second);
    o.doas[0].signature_db = vec![-12.0, -20.5, -41.0];
    o.doas[1].signature_db = vec![-45.0, -18.0, -9.5];
    o
}

fn plain(t: Stamp, base: Point3<f64>) -> wire::Observation {
    observation_of(t, base, 0.0, &SOURCE, None, 0.05)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn observations_must_match_the_layout_their_hello_declared() {
    let (coordinator, clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let mut a = open(addr, hello_with_signatures("a"), None).await.unwrap();
    let mut b = connect(addr, "b").await;
    let mut cases: Vec<(&str, wire::Observation, &str)> = Vec::new();
    let mut o = good(T0, BASE_A);
    o.doas[1].signature_db.push(-3.0);
    cases.push(("four bands of three", o, "observation.doas[1].signature_db"));
    let mut o = good(T0, BASE_A);
    o.doas[0].signature_db.pop();
    cases.push(("two bands of three", o, "observation.doas[0].signature_db"));
    let mut o = good(T0, BASE_A);
    o.doas[0].signature_db[1] = f32::NAN;
    cases.push(("NaN in a signature", o, "observation.doas[0].signature_db[1]"));
    let mut o = good(T0, BASE_A);
    o.doas[1].signature_db[2] = 1e9;
    cases.push(("signature value out of range", o, "observation.doas[1].signature_db[2]"));
    let mut o = good(T0, BASE_A);
    let third = o.doas[0].clone();
    o.doas.push(wire::TrackedDoa { track_id: 3, ..third });
    cases.push(("more tracks than max_tracks", o, "observation.doas"));
    let mut o = good(T0, BASE_A);
    o.doas[1].track_id = 1;
    cases.push(("duplicate track id", o, "observation.doas[1].track_id"));

    for (k, (what, mut obs, field)) in cases.into_iter().enumerate() {
        let t = T0.plus_secs(0.1 * (k + 1) as f64);
        clock.set(t);
        obs.stamp_ns = t.as_ns();
        let bad = a.observe(obs).await;
        let reports = a.until_acked(bad).await;
        let [Down::Error(err)] = &reports[..] else {
            panic!("{what}: expected one stream error, got {reports:?}")
        };
        assert_eq!(
            (err.code, err.field.as_str(), err.sequence),
            (Code::InvalidArgument as i32, field, bad),
            "{what}"
        );
        assert!(err.message.starts_with(field), "{what}: message {:?} does not name the field", err.message);
        // The same stream goes on with a good observation (signatures and all) …
        let s = a.observe(good(t, BASE_A)).await;
        assert!(a.until_acked(s).await.is_empty(), "{what}: the next good observation was refused");
        // … and the other robot, which declared nothing, is unaffected.
        let s = b.observe(plain(t, BASE_B)).await;
        assert!(b.until_acked(s).await.is_empty(), "{what}: robot b was refused");
    }

    // A robot that declared no bands may not send signatures, and has no track limit but 64.
    let t = T0.plus_secs(0.8);
    clock.set(t);
    let mut o = plain(t, BASE_B);
    o.doas[0].signature_db = vec![-10.0, -10.0, -10.0];
    let bad = b.observe(o).await;
    let reports = b.until_acked(bad).await;
    let [Down::Error(err)] = &reports[..] else { panic!("{reports:?}") };
    assert_eq!(err.field, "observation.doas[0].signature_db");
    let mut o = good(t, BASE_B);
    o.doas.iter_mut().for_each(|d| d.signature_db.clear());
    let s = b.observe(o).await;
    assert!(b.until_acked(s).await.is_empty(), "two tracks without signatures are fine for b");

    let state = monitoring(addr).await.get_state(wire::GetStateRequest {}).await.unwrap().into_inner();
    let ra = state.robots.iter().find(|r| r.robot_id == "a").unwrap();
    assert_eq!((ra.observations_rejected, ra.observations_accepted), (6, 6));
    assert!(state.robots.iter().all(|r| r.liveness == wire::Liveness::Live as i32));
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hello_with_bad_signature_bands_is_refused_naming_the_field() {
    let (coordinator, _clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let _a = open(addr, hello_with_signatures("a"), None).await.unwrap();
    let with = |edges: Vec<f64>, max_tracks: u32| {
        let mut m = hello("c");
        if let Some(Up::Hello(h)) = &mut m.msg {
            h.signature_bands = Some(wire::SignatureBands { band_edges_hz: edges });
            h.max_tracks = max_tracks;
        }
        m
    };
    let cases = [
        (with(vec![100.0, 50.0], 0), "hello.signature_bands.band_edges_hz[1]"),
        (with(vec![f64::INFINITY, 500.0], 0), "hello.signature_bands.band_edges_hz[0]"),
        (with(vec![100.0], 0), "hello.signature_bands.band_edges_hz"),
        (with(EDGES_HZ.to_vec(), 65), "hello.max_tracks"),
    ];
    for (first, field) in cases {
        let status = open(addr, first, None).await.err().expect("refused");
        assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
        assert!(status.message().contains(field), "{status:?} should name {field}");
    }
    let _c = open(addr, with(EDGES_HZ.to_vec(), 4), None).await.unwrap();
    coordinator.shutdown().await.unwrap();
}

//! The contract's ranges and the stream's end statuses, over real gRPC on
//! loopback, and the configuration's ranges: σ outside the physical range and
//! stamps older than the coordinator's horizon are refused naming the field;
//! a robot's normal close ends its stream with OK, an undecodable message
//! with INVALID_ARGUMENT, one over 4 MiB with RESOURCE_EXHAUSTED; values that
//! would overflow at run time are configuration errors naming the key, and
//! `--check` refuses an unwritable output file and a listen address in use.

use crate::common;

use std::path::Path;
use std::process::Command;

use common::{T0, connect, hello, observation_of, start};
use nalgebra::Point3;
use soundmap_proto::wire::{self, coordinator_message::Msg as Down, robot_message::Msg as Up};
use soundmap_proto::{Observation, Stamp};
use soundmap_server::CoordinatorConfig;
use tokio::sync::mpsc;
use tonic::Code;

const SOURCE: Point3<f64> = Point3::new(2.0, 1.0, 1.0);

/// The in-band error for observation `seq`, after its ack.
async fn error_for(robot: &mut common::Robot, obs: wire::Observation) -> wire::StreamError {
    let seq = robot.observe(obs).await;
    let others = robot.until_acked(seq).await;
    match others.into_iter().next() {
        Some(Down::Error(e)) => e,
        other => panic!("expected a StreamError, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tiny_sigma_and_ancient_stamps_are_refused_naming_the_field() {
    let (coordinator, _clock) = start(CoordinatorConfig::default()).await;
    let mut robot = connect(coordinator.local_addr, "r1").await;
    let base = Point3::new(0.0, 0.0, 0.0);
    for sigma in [1e-300, 1e-5, 4.0, f64::MAX] {
        let e = error_for(&mut robot, observation_of(T0, base, 0.0, &SOURCE, None, sigma)).await;
        assert_eq!(e.code, Code::InvalidArgument as i32, "σ = {sigma}: {e:?}");
        assert_eq!(e.field, "observation.doas[0].angular_sigma_rad", "{e:?}");
    }
    for stamp in [Stamp::from_ns(1_000_000_000), T0.plus_secs(-301.0)] {
        let e = error_for(&mut robot, observation_of(stamp, base, 0.0, &SOURCE, None, 0.05)).await;
        assert_eq!(e.code, Code::InvalidArgument as i32, "{e:?}");
        assert_eq!(e.field, "observation.stamp_ns", "{e:?}");
        assert!(e.message.contains("behind the receiver clock"), "{e:?}");
    }
    // In range: accepted without an error.
    let seq = robot.observe(observation_of(T0.plus_secs(-200.0), base, 0.0, &SOURCE, None, 1e-4)).await;
    assert!(robot.until_acked(seq).await.is_empty());
    coordinator.shutdown().await.unwrap();
}

#[test]
fn sigma_range_holds_in_the_contract() {
    let obs = observation_of(T0, Point3::origin(), 0.0, &SOURCE, None, 1e-300);
    let e = Observation::from_wire(&obs, &soundmap_proto::Limits::at(T0)).unwrap_err();
    assert_eq!(e.field, "observation.doas[0].angular_sigma_rad");
    let mut unknown = observation_of(T0, Point3::origin(), 0.0, &SOURCE, None, 0.05);
    unknown.doas[0].angular_sigma_rad = 0.0;
    assert!(Observation::from_wire(&unknown, &soundmap_proto::Limits::at(T0)).is_ok());
}

/// A robot message whose fields may be wrong on the wire: tag 1 is the
/// hello as in `RobotMessage`; tag 2 (an observation there) as a varint
/// does not decode; tag 15 is padding.
#[derive(Clone, PartialEq, prost::Message)]
struct RawRobotMessage {
    #[prost(message, optional, tag = "1")]
    hello: Option<wire::Hello>,
    #[prost(uint64, optional, tag = "2")]
    bad_observation: Option<u64>,
    #[prost(bytes = "vec", tag = "15")]
    padding: Vec<u8>,
}

/// Opens a stream with a valid hello, sends `then` (if any) or closes, and
/// returns how the coordinator ended the stream after its welcome.
async fn ending_after(addr: std::net::SocketAddr, then: Option<RawRobotMessage>) -> tonic::Status {
    let Some(Up::Hello(h)) = hello("r1").msg else { unreachable!() };
    let (tx, rx) = mpsc::channel(4);
    tx.send(RawRobotMessage { hello: Some(h), ..Default::default() }).await.unwrap();
    let mut grpc = tonic::client::Grpc::new(common::grpc(addr).await);
    grpc.ready().await.unwrap();
    let codec = tonic_prost::ProstCodec::<RawRobotMessage, wire::CoordinatorMessage>::default();
    let request = tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx));
    let path = "/soundmap.v1.RobotLink/Connect".parse().unwrap();
    let mut inbound = grpc.streaming(request, path, codec).await.unwrap().into_inner();
    let first = inbound.message().await.unwrap().and_then(|m| m.msg);
    assert!(matches!(first, Some(Down::Welcome(_))), "{first:?}");
    match then {
        Some(m) => tx.send(m).await.unwrap(),
        None => drop(tx),
    }
    let deadline = std::time::Duration::from_secs(5);
    loop {
        match tokio::time::timeout(deadline, inbound.message()).await.expect("stream ends within 5 s") {
            Ok(Some(_)) => {}
            Ok(None) => return tonic::Status::ok(""),
            Err(s) => return s,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_end_with_the_status_of_what_happened() {
    let (coordinator, _clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let closed = ending_after(addr, None).await;
    assert_eq!(closed.code(), Code::Ok, "a normal close is not an error: {closed:?}");
    let bad = RawRobotMessage { bad_observation: Some(7), ..Default::default() };
    let undecodable = ending_after(addr, Some(bad)).await;
    assert_eq!(undecodable.code(), Code::InvalidArgument, "{undecodable:?}");
    let big = RawRobotMessage { padding: vec![0; 5 << 20], ..Default::default() };
    let oversize = ending_after(addr, Some(big)).await;
    assert_eq!(oversize.code(), Code::ResourceExhausted, "{oversize:?}");
    // The coordinator still serves.
    connect(addr, "r2").await;
    coordinator.shutdown().await.unwrap();
}

#[test]
fn values_that_would_overflow_are_config_errors_naming_the_key() {
    for (section, key, value) in [
        ("limits", "max_future_ms", "18446744073709551615"),
        ("limits", "max_past_ms", "0"),
        ("liveness", "stale_after_ms", "9223372036854775807"),
        ("alignment", "history_ms", "18446744073709551615"),
        ("alignment", "window_ms", "18446744073709551615"),
        ("liveness", "tick_ms", "9223372036854775807"),
        ("active_positioning", "evaluate_period_ms", "18446744073709551615"),
        ("active_positioning", "command_deadline_s", "1e300"),
    ] {
        let text = format!("[{section}]\n{key} = {value}\n");
        let e = CoordinatorConfig::from_toml(&text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.starts_with(&format!("c.toml: {section}.{key}: ")), "{text}: {e}");
    }
}

fn check(config: &str) -> (bool, String) {
    let dir = tempfile::Builder::new().prefix("soundmap-check-").tempdir().unwrap();
    let file = dir.path().join(format!("c{}.toml", config.len()));
    std::fs::write(&file, config).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_soundmap-coordinator"))
        .arg("--config")
        .arg(&file)
        .arg("--check")
        .output()
        .unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn check_refuses_unwritable_outputs_and_a_busy_port() {
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = busy.local_addr().unwrap().port();
    let (ok, stderr) = check(&format!("listen = \"127.0.0.1:{port}\"\n"));
    assert!(!ok && stderr.contains("listen: cannot bind"), "{stderr}");
    let (ok, stderr) =
        check("listen = \"127.0.0.1:0\"\n[output]\nestimates_jsonl = \"/nonexistent-dir/e.jsonl\"\n");
    assert!(
        !ok && stderr.contains("output.estimates_jsonl: /nonexistent-dir/e.jsonl is not writable"),
        "{stderr}"
    );
    let (ok, stderr) = check("listen = \"127.0.0.1:0\"\n[output]\nobservations_jsonl = \"/proc/o.jsonl\"\n");
    assert!(!ok && stderr.contains("output.observations_jsonl"), "{stderr}");
    let (ok, stderr) = check("listen = \"127.0.0.1:0\"\n");
    assert!(ok, "{stderr}");
}

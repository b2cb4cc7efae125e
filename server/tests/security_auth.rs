//! Who may do what, over real gRPC on loopback: once any credential is
//! configured nothing is anonymous (robot link and monitoring alike), roles
//! separate reading from control, and a robot id that has a token cannot be
//! taken by a client without it, even with `required = false`. The Prometheus
//! endpoint and gRPC reflection answer only operators that may read.

use crate::common;

use std::path::Path;

use common::{hello, monitoring, open, start};
use soundmap_proto::wire;
use soundmap_server::CoordinatorConfig;
use soundmap_server::config::{OperatorConfig, Role};
use tonic::{Code, Request};

const ROBOT_A: &str = "token-of-robot-a-0123";
const READER: &str = "token-of-the-reader-01";
const CONTROLLER: &str = "token-of-controller-0123";

fn config() -> CoordinatorConfig {
    let mut config = CoordinatorConfig::default();
    assert!(!config.auth.required, "the default is required = false");
    config.auth.tokens.insert("a".into(), ROBOT_A.into());
    config
        .auth
        .operators
        .insert("viewer".into(), OperatorConfig { token: Some(READER.into()), role: Role::Read });
    config
        .auth
        .operators
        .insert("lead".into(), OperatorConfig { token: Some(CONTROLLER.into()), role: Role::Control });
    config
}

fn with_token<T>(message: T, token: Option<&str>) -> Request<T> {
    let mut r = Request::new(message);
    if let Some(t) = token {
        r.metadata_mut().insert("authorization", format!("Bearer {t}").parse().unwrap());
    }
    r
}

fn enable() -> wire::SetActivePositioningRequest {
    wire::SetActivePositioningRequest { enabled: Some(true), ..Default::default() }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn anonymous_and_read_only_operators_cannot_control() {
    let (coordinator, _clock) = start(config()).await;
    let mut m = monitoring(coordinator.local_addr).await;
    for (token, code) in [
        (None, Code::Unauthenticated),
        (Some("no-such-token-anywhere"), Code::Unauthenticated),
        (Some(ROBOT_A), Code::PermissionDenied),
        (Some(READER), Code::PermissionDenied),
    ] {
        let e = m.set_active_positioning(with_token(enable(), token)).await.unwrap_err();
        assert_eq!(e.code(), code, "{token:?}: {e:?}");
        let e = m.set_focus(with_token(wire::SetFocusRequest { source_id: 0 }, token)).await.unwrap_err();
        assert_eq!(e.code(), code, "{token:?}: {e:?}");
    }
    // Nothing changed: the lead reads positioning still off, then turns it on.
    let state = m.get_state(with_token(wire::GetStateRequest::default(), Some(READER))).await.unwrap();
    assert_eq!(state.into_inner().active_positioning.map(|p| p.enabled), Some(false));
    let on = m.set_active_positioning(with_token(enable(), Some(CONTROLLER))).await.unwrap();
    assert!(on.into_inner().enabled);
    // Reading needs a credential too.
    let e = m.get_state(with_token(wire::GetStateRequest::default(), None)).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let e = m.watch_estimates(with_token(wire::WatchEstimatesRequest::default(), None)).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    m.watch_estimates(with_token(wire::WatchEstimatesRequest::default(), Some(READER))).await.unwrap();
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_protected_robot_id_is_not_taken_without_its_token() {
    let (coordinator, clock) = start(config()).await;
    let addr = coordinator.local_addr;
    // a connects with its token, then goes silent past stale_after_ms.
    let a = open(addr, hello("a"), Some(ROBOT_A)).await.expect("a with its token");
    clock.set(common::T0.plus_secs(10.0));
    let e = open(addr, hello("a"), None).await.err().expect("takeover without a token refused");
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    // Nor with another principal's token, nor as a new anonymous robot.
    let e = open(addr, hello("a"), Some(CONTROLLER)).await.err().unwrap();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    let e = open(addr, hello("newcomer"), None).await.err().unwrap();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    drop(a);
    coordinator.shutdown().await.unwrap();
}

#[test]
fn duplicate_tokens_and_clashing_names_are_config_errors() {
    let parse =
        |text: &str| CoordinatorConfig::from_toml(text, Path::new("c.toml")).map_err(|e| e.to_string());
    let e =
        parse("[auth.tokens]\nr1 = \"shared-token-0123456\"\nr2 = \"shared-token-0123456\"\n").unwrap_err();
    assert!(e.starts_with("c.toml: auth.tokens.r2: the same token as auth.tokens.r1"), "{e}");
    assert!(!e.contains("shared-token"), "the error must not print the token: {e}");
    let e = parse(
        "[auth.tokens]\nr1 = \"shared-token-0123456\"\n\
         [auth.operators.ops]\ntoken = \"shared-token-0123456\"\nrole = \"control\"\n",
    )
    .unwrap_err();
    assert!(e.starts_with("c.toml: auth.operators.ops.token: the same token as auth.tokens.r1"), "{e}");
    let e = parse("[auth.operators.ops]\ntoken = \"token-of-ops-01234\"\nrole = \"admin\"\n").unwrap_err();
    assert!(e.starts_with("c.toml: auth.operators.ops.role: "), "{e}");
    let e = parse("[auth.operators.ops]\nrole = \"read\"\n").unwrap_err();
    assert!(e.starts_with("c.toml: auth.operators.ops.token: missing"), "{e}");
    let e = parse(
        "[auth.tokens]\nops = \"token-of-robot-0123\"\n[auth.operators.ops]\ntoken = \"token-of-ops-01234\"\nrole = \"read\"\n",
    )
    .unwrap_err();
    assert!(e.starts_with("c.toml: auth.operators.ops: "), "{e}");
    let e = parse("[auth.tokens]\nr1 = \"short\"\n").unwrap_err();
    assert!(e.starts_with("c.toml: auth.tokens.r1: "), "{e}");
    let ok = parse(
        "[auth]\nrequired = false\n[auth.tokens]\nr1 = \"token-of-robot-r1-01\"\n\
         [auth.operators.ops]\ntoken = \"token-of-ops-01234\"\nrole = \"read\"\n",
    )
    .unwrap();
    assert_eq!(ok.auth.operators["ops"].role, Role::Read);
}

/// `GET /metrics` over plain HTTP with an optional bearer token: the status code.
async fn scrape(addr: std::net::SocketAddr, token: Option<&str>) -> u16 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    let request = format!("GET /metrics HTTP/1.1\r\nHost: soundmap\r\n{auth}Connection: close\r\n\r\n");
    s.write_all(request.as_bytes()).await.unwrap();
    let mut reply = String::new();
    s.read_to_string(&mut reply).await.unwrap();
    reply.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0)
}

/// One reflection request (list services) with an optional bearer token.
async fn list_services(addr: std::net::SocketAddr, token: Option<&str>) -> Result<(), tonic::Status> {
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::{ServerReflectionRequest, server_reflection_request::MessageRequest};
    let channel =
        tonic::transport::Endpoint::from_shared(format!("http://{addr}")).unwrap().connect().await.unwrap();
    let mut client = ServerReflectionClient::new(channel);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut replies = client
        .server_reflection_info(with_token(futures::stream::iter([request]), token))
        .await?
        .into_inner();
    replies.message().await?.expect("a reply");
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_and_reflection_need_a_reader_once_credentials_exist() {
    let mut closed = config();
    closed.metrics.listen = Some("127.0.0.1:0".parse().unwrap());
    let (coordinator, _clock) = start(closed).await;
    let metrics = coordinator.metrics_addr.expect("metrics served");
    assert_eq!(scrape(metrics, None).await, 401);
    assert_eq!(scrape(metrics, Some("no-such-token-anywhere")).await, 401);
    assert_eq!(scrape(metrics, Some(ROBOT_A)).await, 403);
    assert_eq!(scrape(metrics, Some(READER)).await, 200);
    assert_eq!(scrape(metrics, Some(CONTROLLER)).await, 200);
    let addr = coordinator.local_addr;
    assert_eq!(list_services(addr, None).await.unwrap_err().code(), Code::Unauthenticated);
    assert_eq!(list_services(addr, Some(ROBOT_A)).await.unwrap_err().code(), Code::PermissionDenied);
    list_services(addr, Some(READER)).await.unwrap();
    coordinator.shutdown().await.unwrap();

    // With no credential configured both stay open, as before.
    let mut open_config = CoordinatorConfig::default();
    open_config.metrics.listen = Some("127.0.0.1:0".parse().unwrap());
    let (coordinator, _clock) = start(open_config).await;
    assert_eq!(scrape(coordinator.metrics_addr.unwrap(), None).await, 200);
    list_services(coordinator.local_addr, None).await.unwrap();
    coordinator.shutdown().await.unwrap();
}

#[test]
fn an_anonymous_live_view_stays_on_loopback_once_credentials_exist() {
    let parse =
        |text: &str| CoordinatorConfig::from_toml(text, Path::new("c.toml")).map_err(|e| e.to_string());
    let tokens = "[auth.tokens]\nr1 = \"token-of-robot-r1-01\"\n";
    let e = parse(&format!("{tokens}[foxglove]\nlisten = \"0.0.0.0:8765\"\n")).unwrap_err();
    assert!(e.starts_with("c.toml: foxglove.listen: "), "{e}");
    assert!(e.contains("allow_anonymous_viewers"), "{e}");
    parse(&format!("{tokens}[foxglove]\nlisten = \"127.0.0.1:8765\"\n")).unwrap();
    parse(&format!("{tokens}[foxglove]\nlisten = \"0.0.0.0:8765\"\nallow_anonymous_viewers = true\n"))
        .unwrap();
    // Without credentials nothing is protected, and the view may listen anywhere.
    parse("[foxglove]\nlisten = \"0.0.0.0:8765\"\n").unwrap();
}

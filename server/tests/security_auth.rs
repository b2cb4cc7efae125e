//! Who may do what, over real gRPC on loopback: once any credential is
//! configured nothing is anonymous (robot link and monitoring alike), roles
//! separate reading from control, and a robot id that has a token cannot be
//! taken by a client without it, even with `required = false`.

mod common;

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

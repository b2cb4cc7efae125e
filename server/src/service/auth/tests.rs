use tonic::metadata::MetadataMap;

use super::*;
use crate::config::OperatorConfig;

const ROBOT_A: &str = "token-of-robot-a-0123";
const READER: &str = "token-of-reader-0123";
const CONTROLLER: &str = "token-of-controller-01";

fn config() -> AuthConfig {
    let mut auth = AuthConfig::default();
    auth.tokens.insert("a".into(), ROBOT_A.into());
    auth.operators.insert("ops".into(), OperatorConfig { token: Some(READER.into()), role: Role::Read });
    auth.operators
        .insert("boss".into(), OperatorConfig { token: Some(CONTROLLER.into()), role: Role::Control });
    auth.operators.insert("desk".into(), OperatorConfig { token: None, role: Role::Control });
    auth
}

fn bearer(token: &str) -> MetadataMap {
    let mut m = MetadataMap::new();
    m.insert("authorization", format!("Bearer {token}").parse().unwrap());
    m
}

fn request(token: Option<&str>) -> Request<()> {
    let mut r = Request::new(());
    if let Some(t) = token {
        *r.metadata_mut() = bearer(t);
    }
    r
}

fn id(s: &str) -> RobotId {
    RobotId::parse(s, "id").unwrap()
}

#[test]
fn open_without_credentials_closed_with_any() {
    let open = Authenticator::new(&AuthConfig::default(), &TlsConfig::default());
    assert!(!open.is_closed());
    assert_eq!(open.identify_parts(&MetadataMap::new(), None).unwrap(), None);
    assert_eq!(open.authorize_robot(None, &id("x")).unwrap(), None);
    assert!(open.authorize_operator(&request(None), Role::Control).is_ok());

    // One robot token, `required = false`: nothing is anonymous any more.
    let mut only_robot = AuthConfig::default();
    only_robot.tokens.insert("a".into(), ROBOT_A.into());
    let auth = Authenticator::new(&only_robot, &TlsConfig::default());
    assert!(auth.is_closed());
    let e = auth.identify_parts(&MetadataMap::new(), None).unwrap_err();
    assert!(matches!(e, ServerError::Unauthenticated(_)), "{e}");
    let e = auth.authorize_operator(&request(None), Role::Read).unwrap_err();
    assert!(matches!(e, ServerError::Unauthenticated(_)), "{e}");
    let e = auth.authorize_robot(None, &id("a")).unwrap_err();
    assert!(matches!(e, ServerError::Unauthenticated(_)), "{e}");

    let tls = TlsConfig { client_ca: Some("ca.pem".into()), ..TlsConfig::default() };
    assert!(Authenticator::new(&AuthConfig::default(), &tls).is_closed());
}

#[test]
fn tokens_resolve_to_principals_and_unknown_ones_are_refused() {
    let auth = Authenticator::new(&config(), &TlsConfig::default());
    assert_eq!(auth.identify_parts(&bearer(ROBOT_A), None).unwrap(), Some(Principal::Robot(id("a"))));
    assert_eq!(
        auth.identify_parts(&bearer(READER), None).unwrap(),
        Some(Principal::Operator { name: "ops".into(), role: Role::Read })
    );
    for bad in ["token-of-robot-a-012", "token-of-robot-a-01234", "", "x"] {
        let e = auth.identify_parts(&bearer(bad), None).unwrap_err();
        assert!(matches!(e, ServerError::Unauthenticated(_)), "{bad:?}: {e}");
    }
    let mut basic = MetadataMap::new();
    basic.insert("authorization", "Basic abc".parse().unwrap());
    assert!(matches!(auth.identify_parts(&basic, None), Err(ServerError::Unauthenticated(_))));
}

#[test]
fn roles_and_identities_are_enforced() {
    let auth = Authenticator::new(&config(), &TlsConfig::default());
    assert!(auth.authorize_operator(&request(Some(READER)), Role::Read).is_ok());
    assert!(auth.authorize_operator(&request(Some(CONTROLLER)), Role::Control).is_ok());
    for (token, role) in [(READER, Role::Control), (ROBOT_A, Role::Read)] {
        let e = auth.authorize_operator(&request(Some(token)), role).unwrap_err();
        assert!(matches!(e, ServerError::PermissionDenied(_)), "{e}");
    }
    let robot = Principal::Robot(id("a"));
    assert_eq!(auth.authorize_robot(Some(&robot), &id("a")).unwrap(), Some(id("a")));
    assert!(matches!(
        auth.authorize_robot(Some(&robot), &id("b")),
        Err(ServerError::IdentityMismatch { .. })
    ));
    let op = Principal::Operator { name: "boss".into(), role: Role::Control };
    assert!(matches!(auth.authorize_robot(Some(&op), &id("boss")), Err(ServerError::PermissionDenied(_))));
}

#[test]
fn certificates_name_robots_or_operators() {
    let tls = TlsConfig { client_ca: Some("ca.pem".into()), ..TlsConfig::default() };
    let auth = Authenticator::new(&config(), &tls);
    let names = |n: &[&str]| Some(n.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    let who = auth.identify_parts(&MetadataMap::new(), names(&["r7"])).unwrap().unwrap();
    assert_eq!(auth.authorize_robot(Some(&who), &id("r7")).unwrap(), Some(id("r7")));
    let e = auth.authorize_robot(Some(&who), &id("r8")).unwrap_err();
    assert!(matches!(e, ServerError::PermissionDenied(_)), "{e}");
    // A certificate naming an operator is that operator, even without a token.
    let who = auth.identify_parts(&MetadataMap::new(), names(&["desk"])).unwrap();
    assert_eq!(who, Some(Principal::Operator { name: "desk".into(), role: Role::Control }));
    // A token and a certificate of different principals.
    let e = auth.identify_parts(&bearer(ROBOT_A), names(&["r7"])).unwrap_err();
    assert!(matches!(e, ServerError::PermissionDenied(_)), "{e}");
    assert!(auth.identify_parts(&bearer(ROBOT_A), names(&["a"])).is_ok());
}

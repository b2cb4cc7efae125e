//! TLS and mutual TLS of the coordinator over real loopback sockets, with a
//! CA and certificates made in the test (rcgen): a plaintext client cannot
//! talk to a TLS coordinator, a client that trusts the CA can; under mutual
//! TLS the robot's identity comes from its certificate (a hello for another
//! id is PERMISSION_DENIED), an operator's certificate carries its role, and
//! bad PEM files are configuration errors naming the file and the key.

use crate::common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use common::hello;
use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};
use soundmap_proto::wire::monitoring_client::MonitoringClient;
use soundmap_proto::wire::robot_link_client::RobotLinkClient;
use soundmap_proto::wire::{self, coordinator_message::Msg as Down};
use soundmap_server::clock::ManualClock;
use soundmap_server::config::{OperatorConfig, Role, TlsConfig};
use soundmap_server::service::{self, RunningCoordinator};
use soundmap_server::{CoordinatorConfig, ServerError};
use tokio::sync::mpsc;
use tonic::Code;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint, Identity};

/// A CA and the PEM files it signed, in a temporary directory.
struct Pki {
    dir: tempfile::TempDir,
    ca: CertifiedIssuer<'static, KeyPair>,
}

impl Pki {
    fn new(name: &str) -> Pki {
        let dir = tempfile::Builder::new().prefix(&format!("soundmap-tls-{name}-")).tempdir().unwrap();
        let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, "soundmap test fleet CA");
        let ca = CertifiedIssuer::self_signed(params, KeyPair::generate().unwrap()).unwrap();
        std::fs::write(dir.path().join("ca.pem"), ca.pem()).unwrap();
        Pki { dir, ca }
    }

    fn path(&self, file: &str) -> PathBuf {
        self.dir.path().join(file)
    }

    /// Writes `NAME.pem` and `NAME.key` for a certificate with these DNS names.
    fn issue(&self, name: &str, dns: &[&str]) -> (PathBuf, PathBuf) {
        let key = KeyPair::generate().unwrap();
        let mut params =
            CertificateParams::new(dns.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
        params.distinguished_name.push(DnType::CommonName, name);
        let cert = params.signed_by(&key, &self.ca).unwrap();
        let (c, k) = (self.path(&format!("{name}.pem")), self.path(&format!("{name}.key")));
        std::fs::write(&c, cert.pem()).unwrap();
        std::fs::write(&k, key.serialize_pem()).unwrap();
        (c, k)
    }

    fn tls_config(&self, mutual: bool) -> TlsConfig {
        let (cert, key) = self.issue("coordinator", &["localhost"]);
        TlsConfig { cert: Some(cert), key: Some(key), client_ca: mutual.then(|| self.path("ca.pem")) }
    }

    fn client(&self, identity: Option<&str>) -> ClientTlsConfig {
        let ca = std::fs::read(self.path("ca.pem")).unwrap();
        let mut tls =
            ClientTlsConfig::new().ca_certificate(Certificate::from_pem(ca)).domain_name("localhost");
        if let Some(name) = identity {
            let cert = std::fs::read(self.path(&format!("{name}.pem"))).unwrap();
            let key = std::fs::read(self.path(&format!("{name}.key"))).unwrap();
            tls = tls.identity(Identity::from_pem(cert, key));
        }
        tls
    }
}

async fn start(config: CoordinatorConfig) -> RunningCoordinator {
    let mut config = config;
    config.liveness.tick_ms = 0;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    service::start(config, Arc::new(ManualClock::new(common::T0)), listener).await.unwrap()
}

async fn tls_channel(coordinator: &RunningCoordinator, tls: ClientTlsConfig) -> Result<Channel, String> {
    let port = coordinator.local_addr.port();
    let ep = Endpoint::from_shared(format!("https://127.0.0.1:{port}")).unwrap().tls_config(tls).unwrap();
    ep.connect().await.map_err(|e| format!("{e:?}"))
}

/// Opens a robot stream with `hello(id)` on `channel`; the welcome or the status.
async fn say_hello(channel: Channel, id: &str, token: Option<&str>) -> Result<wire::Welcome, tonic::Status> {
    let (tx, rx) = mpsc::channel(8);
    tx.send(hello(id)).await.unwrap();
    let mut request = tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx));
    if let Some(t) = token {
        request.metadata_mut().insert("authorization", format!("Bearer {t}").parse().unwrap());
    }
    let mut inbound = RobotLinkClient::new(channel).connect(request).await?.into_inner();
    match inbound.message().await?.and_then(|m| m.msg) {
        Some(Down::Welcome(w)) => Ok(w),
        other => panic!("expected a welcome, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_handshake_with_the_fleet_ca_and_no_plaintext() {
    let pki = Pki::new("server");
    let config = CoordinatorConfig { tls: pki.tls_config(false), ..CoordinatorConfig::default() };
    let coordinator = start(config).await;
    let channel = tls_channel(&coordinator, pki.client(None)).await.expect("TLS handshake");
    let welcome = say_hello(channel, "r1", None).await.expect("welcome over TLS");
    assert_eq!(welcome.robot_id, "r1");
    // Plaintext HTTP/2 to the TLS port gets no gRPC answer.
    let plain = Endpoint::from_shared(format!("http://{}", coordinator.local_addr)).unwrap();
    let plain = plain.connect_timeout(std::time::Duration::from_secs(2));
    if let Ok(channel) = plain.connect().await {
        let e = say_hello(channel, "r2", None).await.expect_err("plaintext refused");
        assert_ne!(e.code(), Code::Ok);
    }
    // A client that trusts another CA fails the handshake.
    let other = Pki::new("other");
    assert!(tls_channel(&coordinator, other.client(None)).await.is_err());
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mutual_tls_identity_comes_from_the_certificate() {
    let pki = Pki::new("mutual");
    pki.issue("r1", &["r1"]);
    pki.issue("desk", &[]);
    let mut config = CoordinatorConfig { tls: pki.tls_config(true), ..CoordinatorConfig::default() };
    config.auth.operators.insert("desk".into(), OperatorConfig { token: None, role: Role::Read });
    let coordinator = start(config).await;

    let as_r1 = || tls_channel(&coordinator, pki.client(Some("r1")));
    let welcome = say_hello(as_r1().await.unwrap(), "r1", None).await.expect("r1 by its certificate");
    assert_eq!(welcome.robot_id, "r1");
    let e = say_hello(as_r1().await.unwrap(), "r2", None).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert!(e.message().contains("hello.robot_id"), "{e:?}");
    // No certificate and no token: nothing is anonymous under mutual TLS.
    let e =
        say_hello(tls_channel(&coordinator, pki.client(None)).await.unwrap(), "r3", None).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    // A robot's certificate does not open Monitoring; the operator's (role read) does, for reading.
    let mut robot = MonitoringClient::new(as_r1().await.unwrap());
    let e = robot.get_state(wire::GetStateRequest::default()).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    let mut desk = MonitoringClient::new(tls_channel(&coordinator, pki.client(Some("desk"))).await.unwrap());
    desk.get_state(wire::GetStateRequest::default()).await.expect("desk reads");
    let e = desk.set_focus(wire::SetFocusRequest { source_id: 0 }).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    // A certificate from another CA fails the handshake (or the first call).
    let other = Pki::new("intruder");
    other.issue("r1", &["r1"]);
    let mut client_tls = other.client(Some("r1"));
    client_tls = client_tls.ca_certificate(Certificate::from_pem(std::fs::read(pki.path("ca.pem")).unwrap()));
    if let Ok(channel) = tls_channel(&coordinator, client_tls).await {
        assert!(say_hello(channel, "r1", None).await.is_err());
    }
    coordinator.shutdown().await.unwrap();
}

fn tls_error(tls: TlsConfig) -> String {
    let config = CoordinatorConfig { tls, ..CoordinatorConfig::default() };
    config
        .validate(Path::new("c.toml"))
        .map_err(|e| e.to_string())
        .and(
            soundmap_server::tls::server_config(&config.tls)
                .map(|_| ())
                .map_err(|e: ServerError| e.to_string()),
        )
        .unwrap_err()
}

#[test]
fn bad_pem_files_name_the_file_and_the_key() {
    let pki = Pki::new("files");
    let good = pki.tls_config(false);
    let missing = pki.path("missing.pem");
    let e = tls_error(TlsConfig { cert: Some(missing.clone()), ..good.clone() });
    assert!(e.starts_with(&format!("{}: tls.cert: cannot read", missing.display())), "{e}");
    let junk = pki.path("junk.pem");
    std::fs::write(&junk, "not a certificate\n").unwrap();
    let e = tls_error(TlsConfig { cert: Some(junk.clone()), ..good.clone() });
    assert!(e.starts_with(&format!("{}: tls.cert: ", junk.display())), "{e}");
    let e = tls_error(TlsConfig { key: Some(junk.clone()), ..good.clone() });
    assert!(e.starts_with(&format!("{}: tls.key: no PEM private key", junk.display())), "{e}");
    let e = tls_error(TlsConfig { client_ca: Some(junk.clone()), ..good.clone() });
    assert!(e.starts_with(&format!("{}: tls.client_ca: ", junk.display())), "{e}");
    // A key that is not the certificate's.
    let (_, other_key) = pki.issue("other", &["x"]);
    let e = tls_error(TlsConfig { key: Some(other_key.clone()), ..good.clone() });
    assert!(e.contains("tls.key: does not match tls.cert"), "{e}");
    let e = tls_error(TlsConfig { key: None, ..good.clone() });
    assert!(e.starts_with("c.toml: tls.key: missing"), "{e}");
    let e = tls_error(TlsConfig { cert: None, key: None, client_ca: Some(pki.path("ca.pem")) });
    assert!(e.starts_with("c.toml: tls.client_ca: "), "{e}");
}

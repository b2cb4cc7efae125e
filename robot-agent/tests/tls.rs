//! The link over TLS, against a small coordinator served by tonic with TLS on
//! a real loopback socket, with a CA and certificates made in the test
//! (rcgen): the agent verifies the coordinator against the configured CA,
//! presents its own certificate for mutual TLS, never speaks plaintext to an
//! `https://` endpoint, and names the file and the key of a bad TLS setting.
//! Also: arbitrary text never panics the agent's configuration parser.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use proptest::prelude::*;
use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};
use soundmap_agent::config::AgentConfig;
use soundmap_agent::link::{ClientTls, LinkClient};
use soundmap_proto::wire::{self, coordinator_message::Msg as Out, robot_message::Msg as In};
use soundmap_proto::{ArrayInfo, Hello, RobotId};
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::{Certificate, Identity, Server, ServerTlsConfig};
use tonic::{Request, Response, Status};

const WAIT: Duration = Duration::from_secs(5);

/// A scratch directory for one test, removed when dropped.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-agent-tls-{name}-")).tempdir().unwrap()
}

/// A fleet CA in `dir/ca.pem`; `issue` writes `NAME.pem` and `NAME.key`.
struct Pki {
    dir: tempfile::TempDir,
    ca: CertifiedIssuer<'static, KeyPair>,
}

impl Pki {
    fn new(name: &str) -> Pki {
        let dir = temp_dir(name);
        let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, "soundmap test fleet CA");
        let ca = CertifiedIssuer::self_signed(params, KeyPair::generate().unwrap()).unwrap();
        std::fs::write(dir.path().join("ca.pem"), ca.pem()).unwrap();
        Pki { dir, ca }
    }

    fn issue(&self, name: &str, dns: &[&str]) -> (PathBuf, PathBuf) {
        let key = KeyPair::generate().unwrap();
        let mut params =
            CertificateParams::new(dns.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
        params.distinguished_name.push(DnType::CommonName, name);
        let cert = params.signed_by(&key, &self.ca).unwrap();
        let (c, k) =
            (self.dir.path().join(format!("{name}.pem")), self.dir.path().join(format!("{name}.key")));
        std::fs::write(&c, cert.pem()).unwrap();
        std::fs::write(&k, key.serialize_pem()).unwrap();
        (c, k)
    }

    fn ca(&self) -> PathBuf {
        self.dir.path().join("ca.pem")
    }
}

/// A coordinator that welcomes every robot and records how many client
/// certificates each stream came with.
#[derive(Clone, Default)]
struct Coordinator(Arc<Mutex<Vec<(String, usize)>>>);

#[tonic::async_trait]
impl wire::robot_link_server::RobotLink for Coordinator {
    type ConnectStream = ReceiverStream<Result<wire::CoordinatorMessage, Status>>;

    async fn connect(
        &self,
        request: Request<tonic::Streaming<wire::RobotMessage>>,
    ) -> Result<Response<Self::ConnectStream>, Status> {
        let certs = request.peer_certs().map_or(0, |c| c.len());
        let mut inbound = request.into_inner();
        let Some(wire::RobotMessage { msg: Some(In::Hello(hello)) }) = inbound.message().await? else {
            return Err(Status::invalid_argument("hello first"));
        };
        self.0.lock().unwrap().push((hello.robot_id.clone(), certs));
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let welcome = wire::Welcome { robot_id: hello.robot_id, ..Default::default() };
        tx.send(Ok(wire::CoordinatorMessage { msg: Some(Out::Welcome(welcome)) })).await.unwrap();
        tokio::spawn(async move {
            while let Ok(Some(_)) = inbound.message().await {}
            drop(tx);
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }
}

async fn serve(coordinator: Coordinator, tls: Option<ServerTlsConfig>) -> SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let mut server = Server::builder();
    if let Some(tls) = tls {
        server = server.tls_config(tls).unwrap();
    }
    let incoming = tonic::transport::server::TcpIncoming::from(listener);
    tokio::spawn(
        server
            .add_service(wire::robot_link_server::RobotLinkServer::new(coordinator))
            .serve_with_incoming(incoming),
    );
    addr
}

fn server_tls(pki: &Pki, client_ca: bool) -> ServerTlsConfig {
    let (cert, key) = pki.issue("coordinator", &["localhost"]);
    let mut tls = ServerTlsConfig::new()
        .identity(Identity::from_pem(std::fs::read(cert).unwrap(), std::fs::read(key).unwrap()));
    if client_ca {
        tls = tls.client_ca_root(Certificate::from_pem(std::fs::read(pki.ca()).unwrap()));
    }
    tls
}

fn hello(id: &str) -> Hello {
    Hello {
        robot_id: RobotId::parse(id, "id").unwrap(),
        array: ArrayInfo {
            base_from_array: nalgebra::Isometry3::identity(),
            microphone_count: 4,
            preset: Some("respeaker-4".into()),
            microphone_positions: vec![],
            srp_band_hz: None,
            direct_path_elevations: false,
        },
        software_version: "test".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    }
}

fn client_tls(pki: &Pki, identity: Option<&str>) -> ClientTls {
    let files =
        identity.map(|n| (pki.dir.path().join(format!("{n}.pem")), pki.dir.path().join(format!("{n}.key"))));
    ClientTls::from_files(
        &pki.ca(),
        files.as_ref().map(|f| f.0.as_path()),
        files.as_ref().map(|f| f.1.as_path()),
        Some("localhost".into()),
    )
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_and_mutual_tls_to_the_coordinator() {
    let pki = Pki::new("link");
    let seen = Coordinator::default();
    let addr = serve(seen.clone(), Some(server_tls(&pki, false))).await;
    let endpoint = format!("https://127.0.0.1:{}", addr.port());
    let tls = client_tls(&pki, None);
    let client = LinkClient::connect_secure(&endpoint, &hello("r1"), None, Some(&tls), WAIT).await.unwrap();
    assert_eq!(client.welcome().robot_id, "r1");
    // A CA that did not sign the coordinator's certificate: the handshake fails.
    let other = Pki::new("link-other");
    let e = LinkClient::connect_secure(&endpoint, &hello("r1"), None, Some(&client_tls(&other, None)), WAIT)
        .await
        .unwrap_err();
    assert!(e.to_string().contains("cannot connect"), "{e}");

    // Mutual TLS: the robot's certificate reaches the coordinator.
    pki.issue("r2", &["r2"]);
    let mutual = Coordinator::default();
    let addr = serve(mutual.clone(), Some(server_tls(&pki, true))).await;
    let endpoint = format!("https://127.0.0.1:{}", addr.port());
    LinkClient::connect_secure(&endpoint, &hello("r2"), None, Some(&client_tls(&pki, Some("r2"))), WAIT)
        .await
        .unwrap();
    assert_eq!(*mutual.0.lock().unwrap(), vec![("r2".to_string(), 1)]);
    let without = LinkClient::connect_secure(&endpoint, &hello("r2"), None, Some(&tls), WAIT).await;
    assert!(without.is_err(), "a coordinator requiring client certificates refuses one without");
    assert_eq!(seen.0.lock().unwrap().len(), 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_plaintext_to_an_https_endpoint() {
    // A plaintext coordinator on the port: had the agent spoken plaintext, it would have said hello.
    let seen = Coordinator::default();
    let addr = serve(seen.clone(), None).await;
    let https = format!("https://127.0.0.1:{}", addr.port());
    for connect in [
        LinkClient::connect(&https, &hello("r1"), Some("token-of-robot-r1-0123".into())).await,
        LinkClient::connect_secure(&https, &hello("r1"), None, None, WAIT).await,
    ] {
        let e = connect.unwrap_err().to_string();
        assert!(e.contains("refusing to connect without TLS"), "{e}");
    }
    // TLS settings with an http:// endpoint are refused as well.
    let pki = Pki::new("plain");
    let http = format!("http://{addr}");
    let e = LinkClient::connect_secure(&http, &hello("r1"), None, Some(&client_tls(&pki, None)), WAIT)
        .await
        .unwrap_err();
    assert!(e.to_string().contains("not https://"), "{e}");
    assert!(seen.0.lock().unwrap().is_empty(), "nothing reached the plaintext coordinator");
}

fn agent_toml(coordinator: &str) -> String {
    format!(
        "robot_id = \"r1\"\n[coordinator]\n{coordinator}\n[array]\npreset = \"respeaker-4\"\n\
         [doa]\nsource = \"odas\"\nfile = \"sst.json\"\nhop_len = 128\nsample_rate_hz = 16000\n\
         [pose]\nsource = \"jsonl_stdin\"\n"
    )
}

fn config_error(dir: &Path, coordinator: &str) -> String {
    AgentConfig::parse(&agent_toml(coordinator), &dir.join("agent.toml")).unwrap_err().to_string()
}

#[test]
fn tls_settings_errors_name_the_file_and_the_key() {
    let pki = Pki::new("config");
    let dir = pki.dir.path();
    pki.issue("r1", &["r1"]);
    std::fs::write(dir.join("junk.pem"), "not PEM at all\n").unwrap();
    let at = |key: &str| format!("{}: coordinator.{key}: ", dir.join("agent.toml").display());
    for (coordinator, key, also) in [
        ("endpoint = \"https://c:50051\"", "ca_file", "refusing to connect without TLS"),
        ("endpoint = \"http://c:50051\"\nca_file = \"ca.pem\"", "endpoint", "not https://"),
        ("endpoint = \"https://c:50051\"\nca_file = \"missing.pem\"", "ca_file", "missing.pem: cannot read"),
        (
            "endpoint = \"https://c:50051\"\nca_file = \"junk.pem\"",
            "ca_file",
            "junk.pem: no \"BEGIN CERTIFICATE\"",
        ),
        (
            "endpoint = \"https://c:50051\"\nca_file = \"ca.pem\"\ncert_file = \"r1.pem\"",
            "key_file",
            "missing",
        ),
        (
            "endpoint = \"https://c:50051\"\nca_file = \"ca.pem\"\ncert_file = \"r1.pem\"\nkey_file = \"junk.pem\"",
            "key_file",
            "junk.pem: no PEM private key",
        ),
        ("endpoint = \"http://c:50051\"\ncert_file = \"r1.pem\"", "cert_file", "needs coordinator.ca_file"),
    ] {
        let e = config_error(dir, coordinator);
        assert!(e.starts_with(&at(key)) && e.contains(also), "{coordinator}: {e}");
    }
    let ok = AgentConfig::parse(
        &agent_toml("endpoint = \"https://c:50051\"\nca_file = \"ca.pem\"\ncert_file = \"r1.pem\"\nkey_file = \"r1.key\""),
        &dir.join("agent.toml"),
    )
    .unwrap();
    assert!(ok.link.tls.as_ref().is_some_and(|t| t.identity.is_some()));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Arbitrary text, and valid files with one line replaced by arbitrary
    /// text, give a config or an error, never a panic.
    #[test]
    fn agent_config_parser_never_panics(text in "\\PC{0,300}", line in 0usize..12, junk in "\\PC{0,40}") {
        let dir = std::env::temp_dir();
        let _ = AgentConfig::parse(&text, &dir.join("fuzz.toml"));
        let valid = agent_toml("endpoint = \"http://c:50051\"");
        let mut lines: Vec<&str> = valid.lines().collect();
        let i = line % lines.len();
        lines[i] = &junk;
        let _ = AgentConfig::parse(&lines.join("\n"), &dir.join("fuzz.toml"));
    }
}

//! The gRPC shell around the coordinator: handlers validate and convert, one
//! task owns the state ([`actor`]), and [`status`] is the one place where
//! domain errors become gRPC statuses.

pub mod actor;
pub mod auth;
pub mod convert;
pub mod limits;
pub mod metrics;
pub mod metrics_http;
pub mod monitoring;
pub mod ratelog;
pub mod robot_link;
pub mod sink;
pub mod state_upkeep;
pub mod status;
pub mod telemetry;

use std::net::SocketAddr;
use std::sync::Arc;

use soundmap_proto::wire;
use soundmap_proto::wire::monitoring_server::MonitoringServer;
use soundmap_proto::wire::robot_link_server::RobotLinkServer;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::task::JoinHandle;
use tonic::service::interceptor::InterceptedService;

pub use metrics::{LatencyHistogram, Metrics};

use crate::clock::Clock;
use crate::config::CoordinatorConfig;
use crate::coordinator::Coordinator;
use crate::error::ServerError;

/// Requests queued toward the coordinator task before handlers wait.
const REQUEST_CAPACITY: usize = 65_536;
/// Estimates a watcher may fall behind before it loses the oldest.
const WATCH_CAPACITY: usize = 4096;
/// How long shutdown waits for open calls.
pub const SHUTDOWN_GRACE: std::time::Duration = std::time::Duration::from_secs(3);

/// A coordinator serving on a socket.
#[derive(Debug)]
pub struct RunningCoordinator {
    /// The address it listens on.
    pub local_addr: SocketAddr,
    /// Its metrics.
    pub metrics: Arc<Metrics>,
    /// Where `GET /metrics` is served (`[metrics] listen`), when it is.
    pub metrics_addr: Option<SocketAddr>,
    estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
    stopping: tokio::sync::watch::Sender<bool>,
    shutdown: Option<oneshot::Sender<()>>,
    server: JoinHandle<Result<(), tonic::transport::Error>>,
    requests: mpsc::Sender<actor::Request>,
    actor: Option<std::thread::JoinHandle<()>>,
    ticker: Option<JoinHandle<()>>,
    sink: Option<std::thread::JoinHandle<()>>,
    /// Where the Foxglove live view is served (`[foxglove] listen`), when it is.
    pub foxglove_addr: Option<SocketAddr>,
    viz: Option<crate::viz::Viz>,
}

impl RunningCoordinator {
    /// Subscribes to published estimates in-process (as `WatchEstimates` does over gRPC).
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<wire::SourceEstimate>> {
        self.estimates.subscribe()
    }

    /// Feeds the live view and recording (e.g. with the true sources of a
    /// simulation), when `[foxglove]` or `[record]` is configured.
    pub fn viz(&self) -> Option<crate::viz::VizSender> {
        self.viz.as_ref().map(crate::viz::Viz::sender)
    }

    /// Stops serving: ends every open stream (robots get UNAVAILABLE, watchers
    /// see their stream end), waits up to [`SHUTDOWN_GRACE`] for calls to
    /// finish, lets the coordinator task finish, and flushes the sink.
    pub async fn shutdown(mut self) -> Result<(), ServerError> {
        let _ = self.stopping.send(true);
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        let served = match tokio::time::timeout(SHUTDOWN_GRACE, &mut self.server).await {
            Ok(r) => r,
            Err(_) => {
                tracing::warn!("calls still open after {SHUTDOWN_GRACE:?}: closing them");
                self.server.abort();
                Ok(Ok(()))
            }
        };
        if let Some(t) = self.ticker.take() {
            t.abort();
        }
        let _ = self.requests.send(actor::Request::Stop).await;
        if let Some(actor) = self.actor.take() {
            let _ = tokio::task::spawn_blocking(move || actor.join()).await;
        }
        if let Some(viz) = self.viz.take() {
            let _ = tokio::task::spawn_blocking(move || viz.stop()).await;
        }
        if let Some(sink) = self.sink.take() {
            let _ = tokio::task::spawn_blocking(move || sink.join()).await;
        }
        match served {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => {
                Err(ServerError::Io { path: "<grpc server>".into(), source: std::io::Error::other(e) })
            }
            Err(e) => Err(ServerError::Io { path: "<grpc server>".into(), source: std::io::Error::other(e) }),
        }
    }

    /// Waits until the server stops on its own (it only does on error).
    pub async fn wait(mut self) -> Result<(), ServerError> {
        let served = (&mut self.server).await;
        self.shutdown.take();
        match served {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => {
                Err(ServerError::Io { path: "<grpc server>".into(), source: std::io::Error::other(e) })
            }
            Err(e) => Err(ServerError::Io { path: "<grpc server>".into(), source: std::io::Error::other(e) }),
        }
    }
}

/// Starts the coordinator on `listener` with time from `clock`: the robot
/// link, monitoring and gRPC health services, the coordinator task, and the
/// estimates file when configured.
pub async fn start(
    config: CoordinatorConfig,
    clock: Arc<dyn Clock>,
    listener: TcpListener,
) -> Result<RunningCoordinator, ServerError> {
    // Validated before anything starts.
    let mut coordinator = Coordinator::new(config.clone())?;
    let tls = crate::tls::server_config(&config.tls)?;
    let authenticator = auth::Authenticator::new(&config.auth, &config.tls);
    log_access(&config, tls.is_some());
    let local_addr =
        listener.local_addr().map_err(|source| ServerError::Io { path: "<listener>".into(), source })?;
    let (requests, requests_rx) = mpsc::channel(REQUEST_CAPACITY);
    let (estimates, _) = broadcast::channel(WATCH_CAPACITY);
    let metrics = Arc::new(Metrics::default());
    let log_interval = std::time::Duration::from_secs_f64(config.server.log_interval_s);
    let ratelog = Arc::new(ratelog::RateLog::new(log_interval));
    let (upkeep, state_word) =
        state_upkeep::open_state(&config, &mut coordinator, clock.now(), metrics.clone(), ratelog.clone())?;
    let marker = sink::restart_marker(clock.now().as_ns(), state_word, coordinator.next_source_id());
    let (sink_tx, sink) = match &config.output.estimates_jsonl {
        Some(path) => {
            let (tx, handle) = sink::spawn_jsonl_sink(path.clone(), Some(marker))?;
            (Some(tx), Some(handle))
        }
        None => (None, None),
    };
    let observation_log =
        config.output.observations_jsonl.as_deref().map(sink::LineFile::open).transpose()?;
    let viz = crate::viz::Viz::start(&config.foxglove, &config.record, &config.planner.free_space).await?;
    let (stopping, stop_rx) = tokio::sync::watch::channel(false);
    let link = robot_link::RobotLinkService::new(&config, requests.clone(), clock.clone(), stop_rx.clone())
        .with_bounds(&config.server, metrics.clone(), ratelog.clone());
    let monitoring = monitoring::MonitoringService::new(requests.clone(), estimates.clone(), stop_rx.clone())
        .with_auth(authenticator.clone());
    let ticker = match config.liveness.tick_ms {
        0 => None,
        ms => {
            Some(tokio::spawn(actor::Actor::ticker(requests.clone(), std::time::Duration::from_millis(ms))))
        }
    };
    let actor = actor::Actor::new(coordinator, clock, estimates.clone(), sink_tx, metrics.clone())
        .with_observation_log(observation_log)
        .with_upkeep(upkeep)
        .with_viz(viz.as_ref().map(crate::viz::Viz::sender));
    let actor = std::thread::Builder::new()
        .name("coordinator".into())
        .spawn(move || actor.run(requests_rx))
        .map_err(|source| ServerError::Io { path: "<coordinator thread>".into(), source })?;
    let metrics_addr = match config.metrics.listen {
        Some(addr) => Some(
            start_metrics(addr, &metrics, &requests, &estimates, authenticator.clone(), stop_rx.clone())
                .await?,
        ),
        None => None,
    };
    // Reflection answers whoever may read the monitoring service.
    let reflection_v1 = InterceptedService::new(
        reflection().build_v1().map_err(reflection_error)?,
        read_role(authenticator.clone()),
    );
    let reflection_v1alpha = InterceptedService::new(
        reflection().build_v1alpha().map_err(reflection_error)?,
        read_role(authenticator),
    );
    let (health_reporter, health) = tonic_health::server::health_reporter();
    health_reporter.set_serving::<RobotLinkServer<robot_link::RobotLinkService>>().await;
    health_reporter.set_serving::<MonitoringServer<monitoring::MonitoringService>>().await;
    let (shutdown_tx, shutdown_rx) = oneshot::channel::<()>();
    let incoming = limits::bounded_incoming(listener, &config.server, metrics.clone(), ratelog.clone());
    let server = tokio::spawn(
        limits::serving_options(server_builder(tls)?, &config.server)
            .add_service(health)
            .add_service(reflection_v1)
            .add_service(reflection_v1alpha)
            .add_service(RobotLinkServer::new(link))
            .add_service(MonitoringServer::new(monitoring))
            .serve_with_incoming_shutdown(incoming, async {
                let _ = shutdown_rx.await;
            }),
    );
    Ok(RunningCoordinator {
        local_addr,
        metrics_addr,
        metrics,
        estimates,
        stopping,
        shutdown: Some(shutdown_tx),
        server,
        requests,
        actor: Some(actor),
        ticker,
        sink,
        foxglove_addr: viz.as_ref().and_then(crate::viz::Viz::local_addr),
        viz,
    })
}

/// An interceptor that lets through calls an operator with the read role (or,
/// with no credential configured, anyone) may make.
fn read_role(
    auth: auth::Authenticator,
) -> impl FnMut(tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> + Clone {
    move |request| {
        auth.authorize_operator(&request, crate::config::Role::Read).map_err(|e| status::to_status(&e))?;
        Ok(request)
    }
}

/// Binds `addr` and serves the Prometheus endpoint there until `stop`.
async fn start_metrics(
    addr: SocketAddr,
    metrics: &Arc<Metrics>,
    requests: &mpsc::Sender<actor::Request>,
    estimates: &broadcast::Sender<Arc<wire::SourceEstimate>>,
    auth: auth::Authenticator,
    stop: tokio::sync::watch::Receiver<bool>,
) -> Result<SocketAddr, ServerError> {
    let io = |source| ServerError::Io { path: format!("[metrics] listen {addr}").into(), source };
    let listener = TcpListener::bind(addr).await.map_err(io)?;
    let bound = listener.local_addr().map_err(io)?;
    let endpoint = metrics_http::MetricsEndpoint {
        metrics: metrics.clone(),
        requests: requests.clone(),
        estimates: estimates.clone(),
        auth,
    };
    tokio::spawn(endpoint.serve(listener, stop));
    tracing::info!("Prometheus metrics at http://{bound}/metrics");
    Ok(bound)
}

/// gRPC server reflection (`grpc.reflection.v1` and `v1alpha`): every service
/// served here (soundmap.v1, health, reflection itself) described from the
/// descriptor sets compiled with the protos, so reflection clients (grpcurl,
/// grpcui, Postman, `grpcio-reflection`) list and call them without the files.
fn reflection() -> tonic_reflection::server::Builder<'static> {
    tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(soundmap_proto::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
}

fn reflection_error(e: tonic_reflection::server::Error) -> ServerError {
    ServerError::Io { path: "<reflection descriptors>".into(), source: std::io::Error::other(e) }
}

/// A gRPC server builder, with TLS when `[tls]` gives a certificate.
fn server_builder(
    tls: Option<tonic::transport::ServerTlsConfig>,
) -> Result<tonic::transport::Server, ServerError> {
    let builder = tonic::transport::Server::builder();
    match tls {
        Some(tls) => builder
            .tls_config(tls)
            .map_err(|e| ServerError::Io { path: "[tls]".into(), source: std::io::Error::other(e) }),
        None => Ok(builder),
    }
}

/// Says at start who may connect, and warns about a monitoring service no one can use.
fn log_access(config: &CoordinatorConfig, tls: bool) {
    let auth = &config.auth;
    let mtls = config.tls.client_ca.is_some();
    if auth::Authenticator::new(auth, &config.tls).is_closed() {
        tracing::info!(
            tls,
            mutual_tls = mtls,
            robot_tokens = auth.tokens.len(),
            operators = auth.operators.len(),
            "authentication on: every call needs a credential"
        );
        if auth.operators.is_empty() && !mtls {
            tracing::warn!(
                "no [auth.operators]: Monitoring (GetState, WatchEstimates, control) refuses every call"
            );
        }
    } else {
        tracing::warn!(tls, "no credentials configured: anyone who reaches the port may use every service");
    }
}

//! `GET /metrics`: the Prometheus endpoint (`--metrics ADDR`, `[metrics] listen`).
//!
//! A plain HTTP/1.1 server (hyper, already under tonic) on its own socket, so
//! a scraper needs no gRPC: it serves counters and states, no positions. Each scrape asks the coordinator task
//! for its snapshot (as `GetState` does, waiting at most [`STATE_TIMEOUT`]; a
//! busy coordinator yields `soundmap_up 0` and the event series only) and
//! answers with [`super::telemetry::Telemetry::render`] as
//! `application/openmetrics-text`. Other paths get 404, other methods 405.
//!
//! When any credential is configured (the coordinator is closed, see
//! [`super::auth`]), a scrape needs an operator's token with the read role,
//! as `Authorization: Bearer TOKEN` (Prometheus: `authorization: { credentials:
//! TOKEN }` in the scrape config); without one it gets 401, with a robot's
//! token 403. Counters name robots and say what they do, which is not for
//! anyone on the network once the fleet has credentials.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use bytes::Bytes;
use http_body_util::Full;
use hyper::body::Incoming;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::TokioIo;
use soundmap_proto::wire;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc, oneshot, watch};

use super::actor;
use super::auth::Authenticator;
use super::metrics::Metrics;
use super::telemetry::ScrapeState;
use crate::config::Role;
use crate::error::ServerError;

/// Longest a scrape waits for the coordinator's snapshot.
pub const STATE_TIMEOUT: Duration = Duration::from_secs(2);
/// The OpenMetrics text content type.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// What the endpoint reads.
#[derive(Clone, Debug)]
pub struct MetricsEndpoint {
    /// The service's metrics.
    pub metrics: Arc<Metrics>,
    /// The coordinator task, for its snapshot.
    pub requests: mpsc::Sender<actor::Request>,
    /// The estimates channel, whose receivers are the open watchers.
    pub estimates: broadcast::Sender<Arc<wire::SourceEstimate>>,
    /// Who may scrape.
    pub auth: Authenticator,
}

impl MetricsEndpoint {
    /// Serves `listener` until `stop` turns true.
    pub async fn serve(self, listener: TcpListener, mut stop: watch::Receiver<bool>) {
        loop {
            let accepted = tokio::select! {
                a = listener.accept() => a,
                _ = stop.wait_for(|s| *s) => return,
            };
            let (stream, _) = match accepted {
                Ok(conn) => conn,
                Err(e) => {
                    tracing::warn!("metrics endpoint: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            let endpoint = self.clone();
            let mut stop = stop.clone();
            tokio::spawn(async move {
                let service = hyper::service::service_fn(move |req| endpoint.clone().answer(req));
                let conn = hyper::server::conn::http1::Builder::new()
                    .serve_connection(TokioIo::new(stream), service);
                tokio::select! {
                    r = conn => if let Err(e) = r {
                        tracing::debug!("metrics endpoint connection: {e}");
                    },
                    _ = stop.wait_for(|s| *s) => {}
                }
            });
        }
    }

    async fn answer(self, req: Request<Incoming>) -> Result<Response<Full<Bytes>>, Infallible> {
        let reply = |status: StatusCode, content_type: &str, body: String| {
            let mut response = Response::new(Full::new(Bytes::from(body)));
            *response.status_mut() = status;
            if let Ok(value) = content_type.parse() {
                response.headers_mut().insert(hyper::header::CONTENT_TYPE, value);
            }
            Ok(response)
        };
        if req.uri().path() != "/metrics" {
            return reply(
                StatusCode::NOT_FOUND,
                "text/plain",
                "not found: the metrics are at /metrics\n".into(),
            );
        }
        if req.method() != Method::GET && req.method() != Method::HEAD {
            return reply(StatusCode::METHOD_NOT_ALLOWED, "text/plain", "use GET\n".into());
        }
        let authorization = req.headers().get(hyper::header::AUTHORIZATION).map(|v| v.as_bytes());
        if let Err(e) = self.auth.authorize_http(authorization, Role::Read) {
            let status = match e {
                ServerError::PermissionDenied(_) => StatusCode::FORBIDDEN,
                _ => StatusCode::UNAUTHORIZED,
            };
            let mut response = reply(status, "text/plain", format!("{e}\n"))?;
            if status == StatusCode::UNAUTHORIZED {
                response
                    .headers_mut()
                    .insert(hyper::header::WWW_AUTHENTICATE, "Bearer".parse().expect("a header"));
            }
            return Ok(response);
        }
        let state = self.state().await;
        let scrape = ScrapeState {
            state: state.as_ref(),
            robot_streams: self.metrics.robot_streams(),
            watchers: self.estimates.receiver_count(),
            limits: self.metrics.limits.snapshot(),
        };
        match self.metrics.telemetry.render(&scrape) {
            Ok(text) => reply(StatusCode::OK, CONTENT_TYPE, text),
            Err(e) => {
                reply(StatusCode::INTERNAL_SERVER_ERROR, "text/plain", format!("encoding failed: {e}\n"))
            }
        }
    }

    async fn state(&self) -> Option<wire::CoordinatorState> {
        let (reply, answer) = oneshot::channel();
        let asked = tokio::time::timeout(STATE_TIMEOUT, async {
            self.requests.send(actor::Request::GetState { reply }).await.ok()?;
            answer.await.ok()
        });
        asked.await.ok().flatten()
    }
}

//! `soundmap.v1.RobotLink`: one bidirectional stream per robot.

use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use futures::Stream;
use soundmap_proto::wire::robot_link_server::RobotLink;
use soundmap_proto::wire::robot_message::Msg;
use soundmap_proto::{Hello, Limits, RobotInput, wire};
use tokio::sync::{mpsc, oneshot};
use tonic::{Request, Response, Status, Streaming};

use super::actor;
use super::auth::Authenticator;
use super::limits::LinkBounds;
use super::metrics::Metrics;
use super::ratelog::RateLog;
use super::status::{self, to_status};
use crate::clock::Clock;
use crate::config::CoordinatorConfig;
use crate::coordinator::ConnId;
use crate::error::ServerError;
use crate::resources::ServerConfig;

/// Messages queued toward one robot before the stream counts as not reading.
const OUTBOUND_CAPACITY: usize = 4096;

/// The robot-link service.
#[derive(Debug, Clone)]
pub struct RobotLinkService {
    requests: mpsc::Sender<actor::Request>,
    clock: Arc<dyn Clock>,
    auth: Authenticator,
    limits: Limits,
    stopping: tokio::sync::watch::Receiver<bool>,
    bounds: LinkBounds,
}

impl RobotLinkService {
    /// A service feeding the coordinator task through `requests`.
    pub fn new(
        config: &CoordinatorConfig,
        requests: mpsc::Sender<actor::Request>,
        clock: Arc<dyn Clock>,
        stopping: tokio::sync::watch::Receiver<bool>,
    ) -> Self {
        let limits = Limits {
            now: soundmap_proto::Stamp::ZERO,
            max_future_ns: config.limits.max_future_ms as i64 * 1_000_000,
            max_past_ns: config.limits.max_past_ms as i64 * 1_000_000,
            unit_vector_tolerance: config.limits.unit_vector_tolerance,
            quaternion_tolerance: config.limits.quaternion_tolerance,
        };
        let auth = Authenticator::new(&config.auth, &config.tls);
        RobotLinkService { requests, clock, auth, limits, stopping, bounds: LinkBounds::new(&config.server) }
    }

    /// Counts and logs the bounds of `[server]` in `metrics` and through `ratelog`.
    pub fn with_bounds(
        mut self,
        config: &ServerConfig,
        metrics: Arc<Metrics>,
        ratelog: Arc<RateLog>,
    ) -> Self {
        self.bounds = LinkBounds::shared(config, metrics, ratelog);
        self
    }

    fn limits(&self) -> Limits {
        Limits { now: self.clock.now(), ..self.limits }
    }
}

type ConnectStream = Pin<Box<dyn Stream<Item = Result<wire::CoordinatorMessage, Status>> + Send>>;

#[tonic::async_trait]
impl RobotLink for RobotLinkService {
    type ConnectStream = ConnectStream;

    async fn connect(
        &self,
        request: Request<Streaming<wire::RobotMessage>>,
    ) -> Result<Response<Self::ConnectStream>, Status> {
        let principal = self.auth.identify(&request).map_err(|e| to_status(&e))?;
        let slot = self.bounds.take_slot()?;
        let mut inbound = request.into_inner();
        let first_message = self.bounds.before_hello(inbound.message());
        let first = first_message.await?.map_err(|s| status::inbound_failed(&s))?;
        let first = first.ok_or_else(status::closed_before_hello)?;
        let hello = match &first.msg {
            Some(Msg::Hello(h)) => Hello::from_wire(h, &self.limits()).map_err(|e| to_status(&e.into()))?,
            _ => return Err(status::first_message_not_hello()),
        };
        let identity =
            self.auth.authorize_robot(principal.as_ref(), &hello.robot_id).map_err(|e| to_status(&e))?;
        let (outbound, rx) = mpsc::channel(OUTBOUND_CAPACITY);
        let (reply, answer) = oneshot::channel();
        let stream_hello = hello.clone();
        let svc = RobotLinkService { bounds: self.bounds.holding(slot), ..self.clone() };
        self.requests
            .send(actor::Request::Connect { hello, identity, outbound, reply })
            .await
            .map_err(|_| status::shutting_down())?;
        let welcome = answer.await.map_err(|_| status::shutting_down())?.map_err(|e| to_status(&e))?;
        let ending = StreamEnd::default();
        tokio::spawn(read_stream(inbound, welcome.conn, stream_hello, svc, ending.clone()));
        // Queued messages go out first; on shutdown the stream ends with
        // UNAVAILABLE so that the robot reconnects later.
        let state = (rx, Some(self.stopping.clone()), ending);
        let stream = futures::stream::unfold(state, |(mut rx, stop, ending)| async move {
            let mut stop = stop?;
            let next = tokio::select! {
                biased;
                m = rx.recv() => Some(m),
                _ = stop.wait_for(|s| *s) => None,
            };
            match next {
                Some(Some(m)) => Some((Ok(m), (rx, Some(stop), ending))),
                // The coordinator dropped this stream: the robot's own stream
                // ended (as it did), or a newer connection took the robot over.
                Some(None) if !*stop.borrow() => match ending.take() {
                    Some(Ok(())) => None,
                    Some(Err(s)) => Some((Err(s), (rx, None, ending))),
                    None => Some((Err(status::replaced_by_newer_connection()), (rx, None, ending))),
                },
                _ => Some((Err(status::shutting_down()), (rx, None, ending))),
            }
        });
        Ok(Response::new(Box::pin(stream)))
    }
}

/// How the robot's side of a stream ended, set by [`read_stream`] before it
/// tells the coordinator: `Ok` for a normal close (the answer then ends with
/// OK), the status to end with otherwise. Unset when the coordinator dropped
/// the stream for a newer connection.
#[derive(Clone, Debug, Default)]
struct StreamEnd(Arc<Mutex<Option<Result<(), Status>>>>);

impl StreamEnd {
    fn set(&self, end: Result<(), Status>) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(end);
    }

    fn take(&self) -> Option<Result<(), Status>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// Reads one robot's stream until it ends: validates each message here (on
/// the stream's own task, so validation runs in parallel across robots),
/// observations also against the stream's `hello` (declared `max_tracks`
/// and signature bands, distinct track ids), and hands it to the coordinator
/// task, which answers in order on the stream (a rejected message becomes a
/// `StreamError` and the stream goes on).
async fn read_stream(
    mut inbound: Streaming<wire::RobotMessage>,
    conn: ConnId,
    hello: Hello,
    svc: RobotLinkService,
    ending: StreamEnd,
) {
    let mut stop = svc.stopping.clone();
    let mut bucket = svc.bounds.bucket();
    loop {
        let next = tokio::select! {
            m = inbound.message() => m,
            _ = stop.wait_for(|s| *s) => return,
        };
        let msg = match next {
            Ok(Some(m)) => m,
            Ok(None) => {
                ending.set(Ok(()));
                break;
            }
            Err(s) => {
                tracing::debug!(conn, "robot stream ended: {s}");
                ending.set(Err(status::inbound_failed(&s)));
                break;
            }
        };
        let received = Instant::now();
        let sequence = match &msg.msg {
            Some(Msg::Observation(o)) => Some(o.sequence),
            _ => None,
        };
        if sequence.is_some()
            && let Err(error) = svc.bounds.admit_observation(&mut bucket, conn, svc.clock.now())
        {
            if svc.requests.send(actor::Request::Rejected { conn, sequence, error }).await.is_err() {
                return;
            }
            continue;
        }
        let request = match RobotInput::from_wire(&msg, &svc.limits()) {
            Ok(RobotInput::Observation(obs)) => match obs.check_against(&hello) {
                Ok(()) => actor::Request::Observation { conn, obs, received },
                Err(e) => actor::Request::Rejected { conn, sequence, error: e.into() },
            },
            Ok(RobotInput::Heartbeat(_)) => actor::Request::Heartbeat { conn },
            Ok(RobotInput::CommandAck(ack)) => actor::Request::CommandAck { conn, ack },
            Ok(RobotInput::CommandProgress(progress)) => actor::Request::CommandProgress { conn, progress },
            Ok(RobotInput::Hello(h)) => {
                actor::Request::Rejected { conn, sequence: None, error: ServerError::SecondHello(h.robot_id) }
            }
            Err(e) => actor::Request::Rejected { conn, sequence, error: e.into() },
        };
        if svc.requests.send(request).await.is_err() {
            return;
        }
    }
    let _ = svc.requests.send(actor::Request::Disconnect { conn }).await;
}

//! One `RobotLink.Connect` stream, driven step by step.

use std::collections::VecDeque;
use std::time::Duration;

use soundmap_proto::wire::{self, coordinator_message::Msg as In, robot_message::Msg as Out};
use soundmap_proto::{
    CommandAck, CommandProgress, Hello, Limits, Observation, RepositionCommand, RobotInput, Stamp,
};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;

use super::tls::{ClientTls, check_scheme};
use super::{CoordinatorEvent, StreamErrorReport};
use crate::AgentError;

/// Outbound messages queued toward tonic before `send` waits.
const OUTBOUND_QUEUE: usize = 64;

/// A connected stream to the coordinator.
///
/// Everything the coordinator sends is read in order: acknowledgements update
/// [`acked`](Self::acked), everything else is queued as a [`CoordinatorEvent`].
/// Every method that reads ([`wait_acked`](Self::wait_acked),
/// [`next_event`](Self::next_event), [`receive`](Self::receive)) is cancel-safe.
#[derive(Debug)]
pub struct LinkClient {
    tx: mpsc::Sender<wire::RobotMessage>,
    inbound: tonic::Streaming<wire::CoordinatorMessage>,
    welcome: wire::Welcome,
    next_sequence: u64,
    last_sent: Option<u64>,
    acked: Option<u64>,
    events: VecDeque<CoordinatorEvent>,
    stream_errors: u64,
}

impl LinkClient {
    /// Connects to `endpoint` (e.g. `http://127.0.0.1:50051`), sends `hello` and
    /// waits for the coordinator's `Welcome`. A `token` is sent as
    /// `authorization: Bearer <token>`. Fails with the coordinator's status when it
    /// refuses the stream (bad hello, authentication, robot id already connected).
    pub async fn connect(endpoint: &str, hello: &Hello, token: Option<String>) -> Result<Self, AgentError> {
        Self::connect_with_timeout(endpoint, hello, token, Duration::from_secs(10)).await
    }

    /// [`connect`](Self::connect) with a limit on the time to the welcome.
    pub async fn connect_with_timeout(
        endpoint: &str,
        hello: &Hello,
        token: Option<String>,
        timeout: Duration,
    ) -> Result<Self, AgentError> {
        Self::connect_secure(endpoint, hello, token, None, timeout).await
    }

    /// [`connect_with_timeout`](Self::connect_with_timeout) over TLS when
    /// `tls` is given, which must be exactly when `endpoint` is `https://`
    /// (no plaintext to an `https://` endpoint, see [`super::tls`]).
    pub async fn connect_secure(
        endpoint: &str,
        hello: &Hello,
        token: Option<String>,
        tls: Option<&ClientTls>,
        timeout: Duration,
    ) -> Result<Self, AgentError> {
        let link = |m: String| AgentError::Link(format!("{endpoint}: {m}"));
        check_scheme(endpoint, tls).map_err(link)?;
        let mut ep = tonic::transport::Endpoint::from_shared(endpoint.to_owned())
            .map_err(|e| link(format!("bad endpoint: {e}")))?
            .connect_timeout(timeout);
        if let Some(tls) = tls {
            ep = ep
                .tls_config(tls.to_tonic())
                .map_err(|e| link(format!("TLS settings: {}", source_chain(&e))))?;
        }
        let attempt = async {
            let channel =
                ep.connect().await.map_err(|e| link(format!("cannot connect: {}", source_chain(&e))))?;
            let (tx, rx) = mpsc::channel(OUTBOUND_QUEUE);
            tx.send(RobotInput::Hello(hello.clone()).to_wire())
                .await
                .map_err(|_| link("stream closed before the hello".into()))?;
            let mut request = tonic::Request::new(ReceiverStream::new(rx));
            if let Some(token) = token {
                let value = format!("Bearer {token}")
                    .parse()
                    .map_err(|_| link("the token is not valid in an HTTP header".into()))?;
                request.metadata_mut().insert("authorization", value);
            }
            let mut client = wire::robot_link_client::RobotLinkClient::new(channel);
            let mut inbound = client.connect(request).await.map_err(|s| link(status_text(&s)))?.into_inner();
            let welcome = match inbound.message().await.map_err(|s| link(status_text(&s)))? {
                Some(wire::CoordinatorMessage { msg: Some(In::Welcome(w)) }) => w,
                Some(other) => return Err(link(format!("expected a welcome, got {other:?}"))),
                None => return Err(link("the coordinator closed the stream before its welcome".into())),
            };
            Ok(LinkClient {
                tx,
                inbound,
                welcome,
                next_sequence: 1,
                last_sent: None,
                acked: None,
                events: VecDeque::new(),
                stream_errors: 0,
            })
        };
        tokio::time::timeout(timeout, attempt)
            .await
            .map_err(|_| link(format!("no welcome within {:.1} s", timeout.as_secs_f64())))?
    }

    /// The coordinator's welcome.
    pub fn welcome(&self) -> &wire::Welcome {
        &self.welcome
    }

    async fn send(&mut self, msg: Out) -> Result<(), AgentError> {
        self.tx
            .send(wire::RobotMessage { msg: Some(msg) })
            .await
            .map_err(|_| AgentError::Link("the stream to the coordinator is closed".into()))
    }

    /// Sends `obs` with the next sequence number (1, 2, … unless
    /// [`send_sequenced_observation`](Self::send_sequenced_observation) moved it) and returns it.
    pub async fn send_observation(&mut self, mut obs: Observation) -> Result<u64, AgentError> {
        obs.sequence = self.next_sequence;
        self.send_sequenced_observation(obs).await
    }

    /// Sends `obs` with its own sequence number, which must be greater than any
    /// sent on this stream. Later [`send_observation`](Self::send_observation)s continue after it.
    pub async fn send_sequenced_observation(&mut self, obs: Observation) -> Result<u64, AgentError> {
        let seq = obs.sequence;
        if let Some(last) = self.last_sent
            && seq <= last
        {
            return Err(AgentError::Link(format!(
                "observation sequence {seq} does not increase (last sent {last})"
            )));
        }
        self.send(Out::Observation(obs.to_wire())).await?;
        self.last_sent = Some(seq);
        self.next_sequence = seq + 1;
        Ok(seq)
    }

    /// Sends a heartbeat with the robot's clock.
    pub async fn send_heartbeat(&mut self, now: Stamp) -> Result<(), AgentError> {
        self.send(Out::Heartbeat(wire::Heartbeat { stamp_ns: now.as_ns() })).await
    }

    /// Answers a command.
    pub async fn send_command_ack(&mut self, ack: &CommandAck) -> Result<(), AgentError> {
        self.send(Out::CommandAck(wire::CommandAck {
            command_id: ack.command_id,
            accepted: ack.accepted,
            reason: ack.reason.clone(),
        }))
        .await
    }

    /// Reports a command's progress.
    pub async fn send_command_progress(&mut self, progress: &CommandProgress) -> Result<(), AgentError> {
        self.send(Out::CommandProgress(wire::CommandProgress {
            command_id: progress.command_id,
            state: progress.state.to_wire() as i32,
            distance_remaining_m: progress.distance_remaining_m.unwrap_or(-1.0),
            detail: progress.detail.clone(),
        }))
        .await
    }

    /// Highest sequence acknowledged on this stream.
    pub fn acked(&self) -> Option<u64> {
        self.acked
    }

    /// Highest sequence sent on this stream.
    pub fn last_sent(&self) -> Option<u64> {
        self.last_sent
    }

    /// `StreamError`s received on this stream.
    pub fn stream_errors(&self) -> u64 {
        self.stream_errors
    }

    /// Reads until an acknowledgement covers `seq`. Commands read meanwhile are
    /// queued, so afterwards [`try_event`](Self::try_event) returns every command
    /// the coordinator sent before that acknowledgement.
    pub async fn wait_acked(&mut self, seq: u64) -> Result<(), AgentError> {
        if self.last_sent.is_none_or(|last| seq > last) {
            return Err(AgentError::Link(format!(
                "waiting for the ack of sequence {seq}, which was not sent (last sent {:?})",
                self.last_sent
            )));
        }
        while self.acked.is_none_or(|a| a < seq) {
            self.receive().await?;
        }
        Ok(())
    }

    /// The next queued event, without reading the stream.
    pub fn try_event(&mut self) -> Option<CoordinatorEvent> {
        self.events.pop_front()
    }

    /// The next event, reading the stream as needed. `Ok(None)` when the
    /// coordinator ended the stream with status OK.
    pub async fn next_event(&mut self) -> Result<Option<CoordinatorEvent>, AgentError> {
        loop {
            if let Some(e) = self.events.pop_front() {
                return Ok(Some(e));
            }
            if !self.read_one().await? {
                return Ok(None);
            }
        }
    }

    /// Reads one message from the coordinator and records it (ack or queued event).
    /// Errors when the stream ends or fails.
    pub async fn receive(&mut self) -> Result<(), AgentError> {
        if self.read_one().await? {
            Ok(())
        } else {
            Err(AgentError::Link("the coordinator ended the stream".into()))
        }
    }

    /// Reads one message; `false` at a clean end of stream.
    async fn read_one(&mut self) -> Result<bool, AgentError> {
        let msg = match self.inbound.message().await {
            Ok(Some(m)) => m,
            Ok(None) => return Ok(false),
            Err(s) => return Err(AgentError::Link(format!("stream failed: {}", status_text(&s)))),
        };
        match msg.msg {
            Some(In::ObservationAck(a)) => {
                self.acked = Some(self.acked.map_or(a.up_to_sequence, |p| p.max(a.up_to_sequence)));
            }
            Some(In::Reposition(c)) => {
                let limits = Limits::at(Stamp::now());
                self.events.push_back(match RepositionCommand::from_wire(&c, &limits) {
                    Ok(cmd) => CoordinatorEvent::Reposition(cmd),
                    Err(error) => {
                        tracing::warn!(
                            "coordinator sent an invalid reposition command {}: {error}",
                            c.command_id
                        );
                        CoordinatorEvent::InvalidReposition { command_id: c.command_id, error }
                    }
                });
            }
            Some(In::Cancel(c)) => {
                self.events.push_back(CoordinatorEvent::Cancel { command_id: c.command_id, reason: c.reason })
            }
            Some(In::Error(e)) => {
                self.stream_errors += 1;
                soundmap_proto::warn_limited!(
                    crate::WARNINGS,
                    "stream_error",
                    "coordinator dropped message {}: {}: {}",
                    e.sequence,
                    e.field,
                    e.message
                );
                self.events.push_back(CoordinatorEvent::StreamError(StreamErrorReport {
                    code: e.code,
                    field: e.field,
                    message: e.message,
                    sequence: (e.sequence != 0).then_some(e.sequence),
                }));
            }
            Some(In::Welcome(w)) => {
                tracing::warn!("unexpected second welcome ({}); ignored", w.coordinator_version)
            }
            None => tracing::warn!("empty message from the coordinator; ignored"),
        }
        Ok(true)
    }
}

fn status_text(s: &tonic::Status) -> String {
    if s.message().is_empty() {
        format!("{:?}", s.code())
    } else {
        format!("{:?}: {}", s.code(), s.message())
    }
}

fn source_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cur = e.source();
    while let Some(s) = cur {
        text.push_str(": ");
        text.push_str(&s.to_string());
        cur = s.source();
    }
    text
}

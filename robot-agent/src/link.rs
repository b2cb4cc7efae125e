//! The link to the coordinator: a client of `soundmap.v1.RobotLink/Connect`.
//!
//! - [`LinkClient`]: one stream, driven step by step. A simulator that steps time
//!   uses it directly: send observations, [`LinkClient::wait_acked`], read the
//!   commands. It keeps the coordinator's order (see below).
//! - [`Link`]: the live agent's link, a tokio task around `LinkClient` that
//!   reconnects with exponential backoff, keeps a bounded buffer of observations
//!   (oldest dropped and counted when full), resends unacknowledged observations
//!   after a reconnect, sends heartbeats when idle, and hands reposition commands
//!   to a [`Navigator`](crate::navigator::Navigator), relaying its acks and progress.
//!
//! **Ordering guarantee.** The coordinator sends the commands caused by an
//! observation before the acknowledgement that covers it, on the same stream.
//! `LinkClient` reads the stream in order and queues every command it reads
//! while waiting for an ack, so once `wait_acked(seq)` returns, every command
//! caused by observations `≤ seq` is already in the client's event queue
//! ([`LinkClient::try_event`] returns it without waiting).
//!
//! `StreamError`s (one bad message; the stream stays open) are logged with their
//! field and message, counted, and surfaced as [`CoordinatorEvent::StreamError`].

mod client;
mod live;
pub mod tls;

use std::time::Duration;

pub use client::LinkClient;
pub use live::{Hop, Link, LinkHandle, LinkInputs, LinkStats};
pub use tls::ClientTls;

pub use crate::agent::{CoordinatorEvent, StreamErrorReport};

/// Settings of the live [`Link`].
#[derive(Clone, Debug, PartialEq)]
pub struct LinkConfig {
    /// Coordinator address, e.g. `http://10.0.0.2:50051`.
    pub endpoint: String,
    /// Bearer token sent as `authorization: Bearer …`, when the coordinator requires one.
    pub token: Option<String>,
    /// TLS settings, exactly when `endpoint` is `https://`.
    pub tls: Option<ClientTls>,
    /// Most observations kept while unacknowledged; the oldest is dropped beyond it.
    pub buffer_capacity: usize,
    /// A heartbeat is sent after this long without sending anything.
    pub heartbeat_interval: Duration,
    /// First wait before reconnecting; doubled after each failure.
    pub backoff_initial: Duration,
    /// Longest wait before reconnecting.
    pub backoff_max: Duration,
    /// Longest wait for the TCP connection and the coordinator's welcome.
    pub connect_timeout: Duration,
}

impl LinkConfig {
    /// Defaults for `endpoint`: 1024 observations, 1 s heartbeats, backoff 0.2 s → 10 s, 5 s connect timeout.
    pub fn new(endpoint: impl Into<String>) -> Self {
        LinkConfig {
            endpoint: endpoint.into(),
            token: None,
            tls: None,
            buffer_capacity: 1024,
            heartbeat_interval: Duration::from_secs(1),
            backoff_initial: Duration::from_millis(200),
            backoff_max: Duration::from_secs(10),
            connect_timeout: Duration::from_secs(5),
        }
    }
}

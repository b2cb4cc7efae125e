//! Connection bounds at the socket: an accept loop that caps open
//! connections in total and per peer address, closes connections idle too
//! long, and survives running out of descriptors; and the per-stream rate
//! limit of observations.
//!
//! **Why at accept.** A TCP connection costs a descriptor and a task before
//! any gRPC code sees it. Counting at accept sheds the excess at once (accept,
//! then close: the peer sees a reset) and never lets the process reach its
//! descriptor limit, where `accept` fails in a loop. With the defaults (1,024
//! in total, 64 per address), 1,500 idle connections from one address hold 64
//! slots and the other 1,436 are closed at once; a robot from another address
//! still connects. When `accept` does fail (EMFILE), the loop pauses 50 ms
//! instead of spinning, and logs it at most once per interval.
//!
//! **Idle.** A connection from which nothing was read for
//! `server.idle_timeout_ms` is closed. Healthy HTTP/2 peers are never idle that
//! long: the server pings every `keepalive_interval_ms` and they answer.
//!
//! **Rate.** A token bucket per robot stream: `rate` tokens per second, at most
//! `rate` banked (a one-second burst); an observation without a token is
//! rejected in-band with RESOURCE_EXHAUSTED and acknowledged, so a robot over
//! the limit learns it and loses nothing silently.

use std::collections::HashMap;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio::time::{Instant, Sleep};
use tonic::transport::server::{Connected, TcpConnectInfo};

use super::metrics::{LimitCounters, Metrics};
use super::ratelog::RateLog;
use crate::resources::ServerConfig;
use soundmap_proto::warn_limited;

/// Descriptors kept free for files, the state store and the runtime when the
/// connection cap is lowered to the process's limit.
const DESCRIPTOR_RESERVE: u64 = 64;

/// Open connections, in total and per peer address.
#[derive(Debug, Default)]
struct Counts {
    total: usize,
    by_peer: HashMap<IpAddr, usize>,
}

/// The connection counter shared by the accept loop and the connections' guards.
#[derive(Debug)]
pub struct ConnectionLimits {
    max_total: usize,
    max_per_peer: usize,
    counts: Mutex<Counts>,
}

/// Why a connection was not admitted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refused {
    /// `max_connections` open.
    Total,
    /// `max_connections_per_peer` open from its address.
    Peer,
}

/// Holds one connection's place; frees it when dropped.
#[derive(Debug)]
pub struct ConnectionGuard {
    limits: Arc<ConnectionLimits>,
    peer: IpAddr,
}

impl Drop for ConnectionGuard {
    fn drop(&mut self) {
        let mut c = self.limits.counts.lock().unwrap_or_else(|p| p.into_inner());
        c.total = c.total.saturating_sub(1);
        if let Some(n) = c.by_peer.get_mut(&self.peer) {
            *n -= 1;
            if *n == 0 {
                c.by_peer.remove(&self.peer);
            }
        }
    }
}

impl ConnectionLimits {
    /// At most `max_total` connections, `max_per_peer` from one address.
    pub fn new(max_total: usize, max_per_peer: usize) -> Arc<Self> {
        Arc::new(ConnectionLimits { max_total, max_per_peer, counts: Mutex::default() })
    }

    /// A place for a connection from `peer`, or why not.
    pub fn admit(self: &Arc<Self>, peer: IpAddr) -> Result<ConnectionGuard, Refused> {
        let mut c = self.counts.lock().unwrap_or_else(|p| p.into_inner());
        if c.total >= self.max_total {
            return Err(Refused::Total);
        }
        let n = c.by_peer.entry(peer).or_insert(0);
        if *n >= self.max_per_peer {
            return Err(Refused::Peer);
        }
        *n += 1;
        c.total += 1;
        Ok(ConnectionGuard { limits: self.clone(), peer })
    }

    /// Connections open now.
    pub fn open(&self) -> usize {
        self.counts.lock().unwrap_or_else(|p| p.into_inner()).total
    }
}

/// The soft limit of open descriptors of this process (Linux: `/proc/self/limits`).
pub fn descriptor_limit() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = text.lines().find(|l| l.starts_with("Max open files"))?;
    line.split_whitespace().nth(3)?.parse().ok()
}

/// `max_connections` lowered, with a warning, so that connections cannot
/// exhaust the process's descriptors.
pub fn effective_max_connections(config: &ServerConfig) -> usize {
    let Some(limit) = descriptor_limit() else { return config.max_connections };
    let room = limit.saturating_sub(DESCRIPTOR_RESERVE).max(1) as usize;
    if config.max_connections > room {
        tracing::warn!(
            "server.max_connections = {} but the descriptor limit is {limit}: at most {room} \
             connections (raise LimitNOFILE, as the shipped systemd unit does)",
            config.max_connections
        );
        room
    } else {
        config.max_connections
    }
}

/// A connection admitted by the accept loop: closes itself after `idle` without a read.
#[derive(Debug)]
pub struct LimitedConn {
    inner: TcpStream,
    _guard: ConnectionGuard,
    idle: Duration,
    last_read: Instant,
    timer: Pin<Box<Sleep>>,
    counters: Arc<Metrics>,
}

impl LimitedConn {
    fn new(inner: TcpStream, guard: ConnectionGuard, idle: Duration, counters: Arc<Metrics>) -> Self {
        let now = Instant::now();
        LimitedConn {
            inner,
            _guard: guard,
            idle,
            last_read: now,
            timer: Box::pin(tokio::time::sleep_until(now + idle)),
            counters,
        }
    }
}

impl Connected for LimitedConn {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.inner.connect_info()
    }
}

impl AsyncRead for LimitedConn {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = &mut *self;
        match Pin::new(&mut this.inner).poll_read(cx, buf) {
            Poll::Ready(r) => {
                this.last_read = Instant::now();
                Poll::Ready(r)
            }
            Poll::Pending => {
                // The timer is moved only when it fires: reads stay cheap.
                while this.timer.as_mut().poll(cx).is_ready() {
                    let deadline = this.last_read + this.idle;
                    if Instant::now() >= deadline {
                        LimitCounters::bump(&this.counters.limits.connections_idle_closed);
                        return Poll::Ready(Err(io::Error::new(
                            io::ErrorKind::TimedOut,
                            "connection idle longer than server.idle_timeout_ms",
                        )));
                    }
                    this.timer.as_mut().reset(deadline);
                }
                Poll::Pending
            }
        }
    }
}

impl AsyncWrite for LimitedConn {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

/// Accepts connections from `listener` within the bounds of `config` and hands
/// them to the server through the returned stream; stops when it is dropped.
pub fn bounded_incoming(
    listener: TcpListener,
    config: &ServerConfig,
    metrics: Arc<Metrics>,
    ratelog: Arc<RateLog>,
) -> tokio_stream::wrappers::ReceiverStream<io::Result<LimitedConn>> {
    let limits = ConnectionLimits::new(effective_max_connections(config), config.max_connections_per_peer);
    let idle = Duration::from_millis(config.idle_timeout_ms);
    let (tx, rx) = mpsc::channel(64);
    tokio::spawn(async move {
        loop {
            let accepted = tokio::select! {
                a = listener.accept() => a,
                _ = tx.closed() => return,
            };
            match accepted {
                Ok((stream, peer)) => {
                    if let Some(conn) = admit(&limits, stream, peer, idle, &metrics, &ratelog)
                        && tx.send(Ok(conn)).await.is_err()
                    {
                        return;
                    }
                }
                Err(e) => {
                    LimitCounters::bump(&metrics.limits.accept_errors);
                    warn_limited!(ratelog, "accept_error", "accepting a connection failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
            }
        }
    });
    tokio_stream::wrappers::ReceiverStream::new(rx)
}

fn admit(
    limits: &Arc<ConnectionLimits>,
    stream: TcpStream,
    peer: SocketAddr,
    idle: Duration,
    metrics: &Arc<Metrics>,
    ratelog: &RateLog,
) -> Option<LimitedConn> {
    match limits.admit(peer.ip()) {
        Ok(guard) => {
            let _ = stream.set_nodelay(true);
            Some(LimitedConn::new(stream, guard, idle, metrics.clone()))
        }
        Err(Refused::Total) => {
            LimitCounters::bump(&metrics.limits.connections_refused_total);
            warn_limited!(
                ratelog,
                "connections_total",
                "connection from {peer} closed: server.max_connections open"
            );
            None
        }
        Err(Refused::Peer) => {
            LimitCounters::bump(&metrics.limits.connections_refused_peer);
            warn_limited!(
                ratelog,
                "connections_peer",
                "connection from {peer} closed: server.max_connections_per_peer open from {}",
                peer.ip()
            );
            None
        }
    }
}

/// The HTTP/2 options of `[server]` on a server builder: keepalive pings and
/// their timeout, concurrent streams per connection.
pub fn serving_options(builder: tonic::transport::Server, config: &ServerConfig) -> tonic::transport::Server {
    builder
        .http2_keepalive_interval(Some(Duration::from_millis(config.keepalive_interval_ms)))
        .http2_keepalive_timeout(Some(Duration::from_millis(config.keepalive_timeout_ms)))
        .max_concurrent_streams(Some(config.max_streams_per_connection))
}

/// A token bucket: `rate` per second, at most `rate` banked. Time is the
/// coordinator's clock (ns), so a simulation driving it faster than real time
/// sees the rate in its own time.
#[derive(Clone, Copy, Debug)]
pub struct TokenBucket {
    rate: f64,
    tokens: f64,
    at: Option<i64>,
}

impl TokenBucket {
    /// A full bucket.
    pub fn new(rate: f64) -> Self {
        TokenBucket { rate, tokens: rate, at: None }
    }

    /// Takes a token at `now_ns` if there is one.
    pub fn take_at(&mut self, now_ns: i64) -> bool {
        let dt = self.at.map_or(0.0, |at| now_ns.saturating_sub(at).max(0) as f64 * 1e-9);
        self.at = Some(self.at.map_or(now_ns, |at| at.max(now_ns)));
        self.tokens = (self.tokens + dt * self.rate).min(self.rate);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// Robot streams open now, bounded by `server.max_robot_streams`.
#[derive(Debug)]
pub struct StreamSlots {
    max: usize,
    open: std::sync::atomic::AtomicUsize,
}

/// One robot stream's slot; freed when dropped.
#[derive(Debug)]
pub struct StreamSlot(Arc<StreamSlots>);

impl Drop for StreamSlot {
    fn drop(&mut self) {
        self.0.open.fetch_sub(1, std::sync::atomic::Ordering::AcqRel);
    }
}

impl StreamSlots {
    /// At most `max` at once.
    pub fn new(max: usize) -> Arc<Self> {
        Arc::new(StreamSlots { max, open: std::sync::atomic::AtomicUsize::new(0) })
    }

    /// A slot, if one is free.
    pub fn take(self: &Arc<Self>) -> Option<StreamSlot> {
        use std::sync::atomic::Ordering;
        let mut n = self.open.load(Ordering::Acquire);
        loop {
            if n >= self.max {
                return None;
            }
            match self.open.compare_exchange_weak(n, n + 1, Ordering::AcqRel, Ordering::Acquire) {
                Ok(_) => return Some(StreamSlot(self.clone())),
                Err(now) => n = now,
            }
        }
    }
}

/// The bounds of the robot-link service: streams open, hello timeout, observation rate.
#[derive(Clone, Debug)]
pub struct LinkBounds {
    slots: Arc<StreamSlots>,
    /// The slot this stream holds (a clone of the service per stream carries it).
    _slot: Option<Arc<StreamSlot>>,
    hello_timeout: Duration,
    rate_hz: f64,
    metrics: Arc<Metrics>,
    ratelog: Arc<RateLog>,
}

impl LinkBounds {
    /// Bounds from `config` with their own counters.
    pub fn new(config: &ServerConfig) -> Self {
        let ratelog = Arc::new(RateLog::new(Duration::from_secs_f64(config.log_interval_s)));
        Self::shared(config, Arc::default(), ratelog)
    }

    /// Bounds from `config` counting in `metrics` and logging through `ratelog`.
    pub fn shared(config: &ServerConfig, metrics: Arc<Metrics>, ratelog: Arc<RateLog>) -> Self {
        LinkBounds {
            slots: StreamSlots::new(config.max_robot_streams),
            _slot: None,
            hello_timeout: Duration::from_millis(config.hello_timeout_ms),
            rate_hz: config.max_observation_rate_hz,
            metrics,
            ratelog,
        }
    }

    /// A stream's place under `server.max_robot_streams`, or RESOURCE_EXHAUSTED.
    pub fn take_slot(&self) -> Result<Arc<StreamSlot>, tonic::Status> {
        match self.slots.take() {
            Some(s) => Ok(Arc::new(s)),
            None => {
                LimitCounters::bump(&self.metrics.limits.robot_streams_refused);
                warn_limited!(
                    self.ratelog,
                    "robot_streams",
                    "robot stream refused: server.max_robot_streams open"
                );
                Err(tonic::Status::resource_exhausted(format!(
                    "the coordinator has server.max_robot_streams = {} robot streams open; retry later",
                    self.slots.max
                )))
            }
        }
    }

    /// These bounds holding `slot` (for the stream's own copy of the service).
    pub fn holding(&self, slot: Arc<StreamSlot>) -> Self {
        LinkBounds { _slot: Some(slot), ..self.clone() }
    }

    /// The first message of a stream, or DEADLINE_EXCEEDED after `server.hello_timeout_ms`.
    pub async fn before_hello<T>(
        &self,
        first: impl std::future::Future<Output = T>,
    ) -> Result<T, tonic::Status> {
        match tokio::time::timeout(self.hello_timeout, first).await {
            Ok(m) => Ok(m),
            Err(_) => {
                LimitCounters::bump(&self.metrics.limits.hello_timeouts);
                warn_limited!(
                    self.ratelog,
                    "hello_timeout",
                    "robot stream closed: no hello within server.hello_timeout_ms"
                );
                Err(tonic::Status::deadline_exceeded(format!(
                    "msg: no hello within server.hello_timeout_ms = {} ms",
                    self.hello_timeout.as_millis()
                )))
            }
        }
    }

    /// A full token bucket for one stream's observations.
    pub fn bucket(&self) -> TokenBucket {
        TokenBucket::new(self.rate_hz)
    }

    /// Whether the stream `conn` may send one more observation now; the error when not.
    pub fn admit_observation(
        &self,
        bucket: &mut TokenBucket,
        conn: u64,
        now: soundmap_proto::Stamp,
    ) -> Result<(), crate::ServerError> {
        if bucket.take_at(now.as_ns()) {
            return Ok(());
        }
        LimitCounters::bump(&self.metrics.limits.observations_rate_limited);
        warn_limited!(
            self.ratelog,
            "observation_rate",
            "stream {conn}: observations over server.max_observation_rate_hz rejected"
        );
        Err(crate::ServerError::Exhausted(format!(
            "observation: more than server.max_observation_rate_hz = {} observations per second",
            self.rate_hz
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caps_in_total_and_per_peer_and_frees_on_drop() {
        let limits = ConnectionLimits::new(3, 2);
        let a: IpAddr = "127.0.0.2".parse().unwrap();
        let b: IpAddr = "127.0.0.1".parse().unwrap();
        let g1 = limits.admit(a).unwrap();
        let _g2 = limits.admit(a).unwrap();
        assert_eq!(limits.admit(a).unwrap_err(), Refused::Peer);
        let _g3 = limits.admit(b).unwrap();
        assert_eq!(limits.admit(b).unwrap_err(), Refused::Total);
        drop(g1);
        assert_eq!(limits.open(), 2);
        limits.admit(a).unwrap();
    }

    #[test]
    fn bucket_allows_the_rate_and_a_one_second_burst() {
        let t0 = 1_767_225_600_000_000_000i64;
        let mut b = TokenBucket::new(100.0);
        let burst = (0..1000).filter(|_| b.take_at(t0)).count();
        assert_eq!(burst, 100);
        // Then 100 per second: 10 s at 1 kHz lets ~1,000 through.
        let passed = (1..=10_000).filter(|i| b.take_at(t0 + 1_000_000 * i)).count();
        assert!((990..=1010).contains(&passed), "{passed}");
    }

    #[test]
    fn stream_slots_are_bounded() {
        let s = StreamSlots::new(2);
        let a = s.take().unwrap();
        let _b = s.take().unwrap();
        assert!(s.take().is_none());
        drop(a);
        assert!(s.take().is_some());
    }
}

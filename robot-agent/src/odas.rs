//! DoAs from a running ODAS instead of our own localization: a bridge for
//! ODAS's SST (sound source tracking) JSON output.
//!
//! ODAS writes one JSON object per hop, pretty-printed over several lines and
//! concatenated with no separator (not one object per line):
//!
//! ```text
//! {
//!     "timeStamp": 42,
//!     "src": [
//!         { "id": 3, "tag": "dynamic", "x": 0.812, "y": -0.401, "z": 0.424, "activity": 0.973 },
//!         { "id": 0, "tag": "", "x": 0.000, "y": 0.000, "z": 0.000, "activity": 0.000 }
//!     ]
//! }
//! ```
//!
//! - `timeStamp` counts hops of ODAS's processing (its `general.size.hopSize` at
//!   `general.samplerate.mu`), starting at 1 for the first hop; the frame is
//!   stamped `start + (timeStamp − 1) · hop_len / sample_rate_hz`.
//! - `src` holds a fixed number of slots; empty slots have id 0 and a zero vector
//!   and are skipped. `(x, y, z)` is a unit vector in the frame ODAS's microphone
//!   positions are given in, which must be our array frame; ODAS prints 3 decimals,
//!   so the vector is renormalized (norms further than 0.05 from 1 are rejected).
//!
//! - ODAS sends no uncertainty. Each DoA gets the prior σ of ODAS's DoAs,
//!   [`PRIOR_SIGMA_DEG`] per tangent axis: one spacing of its level-4 scan grid
//!   (2562 points, ≈ 4° apart), the order of its quantization plus the
//!   reflections' pull in a furnished room. The coordinator learns each
//!   robot's real noise from there (it only ever inflates the prior).
//!
//! ODAS's socket sink connects out as a TCP client to `ip:port` of its `tracked`
//! interface, so the bridge listens there ([`serve_tcp`]): start the agent
//! first (it says where it listens), then ODAS. Files written by its file sink
//! are read whole with [`read_sst_file`] (a finished recording, sent at the pace
//! of its stamps or as fast as possible), or followed as ODAS appends to them
//! with [`follow_file`].
//!
//! # The clock rule
//!
//! A hop's stamp is `start + (timeStamp − 1)·hop_len/sample_rate_hz`; what
//! `start` is depends on the input:
//!
//! - `doa.start_ns` given: that, always (ODAS's first sample in Unix ns).
//! - socket: the agent's clock when a connection's first object arrives (so
//!   stamps lag the sound by ODAS's latency, tens of ms); each connection is
//!   anchored anew, since a restarted ODAS counts from 1 again. With a fixed
//!   start, a connection whose counter went backwards is re-anchored the same
//!   way, with a warning.
//! - followed file: objects already in the file are skipped and the newest
//!   is taken as written now; if the file is empty, the first object to
//!   appear is anchored on arrival. A file that shrinks (ODAS restarted and
//!   rewrote it) is read again from its start and re-anchored.
//! - finished file, `pace = "realtime"`: the agent's start; `"asap"`: the
//!   agent's start minus the recording's length, so the whole recording lies
//!   in the past and no stamp runs ahead of the coordinator's clock (which
//!   accepts stamps up to `limits.max_past_ms`, 5 min by default, old).
//!
//! Poses from a TUM file with `pose.start_s` are placed on the same `start`,
//! so a live ODAS (socket or followed file) with such poses needs
//! `doa.start_ns`: the configuration refuses to guess.
//!
//! Live hops stamped ahead of the agent's clock (ODAS fed from a file at full
//! speed, or a start in the future) are held until due, with a rate-limited
//! warning, instead of being sent early for the coordinator to reject one by
//! one; holding stops reading, so TCP slows ODAS down to real time. A hop
//! more than [`MAX_HOLD_NS`] (10 s) ahead is skipped with a warning instead:
//! a wrong `start_ns` or counter must not stall the bridge.

use std::path::{Path, PathBuf};
use std::time::Duration;

use nalgebra::{Unit, Vector3};
use serde::Deserialize;
use soundmap_proto::{Stamp, TrackedDoa, warn_limited};
use tokio::io::{AsyncReadExt, AsyncSeekExt};
use tokio::net::TcpListener;
use tokio::sync::mpsc;

use crate::{AgentError, WARNINGS};

pub mod out;

/// How often a followed file is checked for new objects.
pub const FOLLOW_POLL: Duration = Duration::from_millis(20);

/// How long the bridge waits for ODAS before it says again that it is waiting.
pub const WAIT_REPORT: Duration = Duration::from_secs(30);

/// A hop further ahead of the agent's clock than this is worth a warning.
const AHEAD_WARN_NS: i64 = 50_000_000;

/// A live hop further ahead than this is not held but skipped: a broken
/// counter or `start_ns` must not stall the bridge (ns).
pub const MAX_HOLD_NS: i64 = 10_000_000_000;

/// Accepted deviation of an SST direction's norm from 1 (3-decimal printing).
pub const NORM_TOLERANCE: f64 = 0.05;

/// Prior 1-σ per tangent axis of an ODAS DoA (degrees): one spacing of
/// ODAS's level-4 scan grid (see the module documentation).
pub const PRIOR_SIGMA_DEG: f64 = 4.0;

/// How ODAS hop counts map to fleet time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OdasTiming {
    /// ODAS's `general.size.hopSize`, samples.
    pub hop_len: u32,
    /// ODAS's `general.samplerate.mu`, Hz.
    pub sample_rate_hz: u32,
    /// Time of the first sample of hop 1.
    pub start: Stamp,
}

impl OdasTiming {
    /// Stamp of the hop numbered `time_stamp` (1-based, as ODAS counts).
    pub fn stamp(&self, time_stamp: u64) -> Stamp {
        crate::audio::stamp_of_frame(
            self.start,
            time_stamp.saturating_sub(1) * self.hop_len as u64,
            self.sample_rate_hz,
        )
    }

    /// The start that puts hop `time_stamp` at `now` (anchoring a live stream to the clock).
    pub fn anchored(hop_len: u32, sample_rate_hz: u32, time_stamp: u64, now: Stamp) -> Self {
        let probe = OdasTiming { hop_len, sample_rate_hz, start: Stamp::ZERO };
        OdasTiming { start: now.plus_ns(-probe.stamp(time_stamp).as_ns()), ..probe }
    }
}

/// One SST object as ODAS writes it.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct SstFrame {
    /// Hop count, from 1.
    #[serde(rename = "timeStamp")]
    pub time_stamp: u64,
    /// Track slots.
    pub src: Vec<SstSource>,
}

/// One track slot.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct SstSource {
    /// Track id; 0 for an empty slot.
    pub id: u64,
    /// ODAS's tag (e.g. `dynamic`), unused.
    #[serde(default)]
    pub tag: String,
    /// Direction, ODAS array frame.
    pub x: f64,
    /// Direction, ODAS array frame.
    pub y: f64,
    /// Direction, ODAS array frame.
    pub z: f64,
    /// Activity in [0, 1].
    pub activity: f64,
}

/// Tracked DoAs of one ODAS hop.
#[derive(Clone, Debug, PartialEq)]
pub struct OdasFrame {
    /// ODAS's hop count.
    pub time_stamp: u64,
    /// Fleet time of the hop.
    pub stamp: Stamp,
    /// Non-empty slots as tracked DoAs (σ: [`PRIOR_SIGMA_DEG`]).
    pub doas: Vec<TrackedDoa>,
}

impl SstFrame {
    /// Converts to tracked DoAs, skipping empty slots; an error says which slot is bad.
    pub fn to_frame(&self, timing: &OdasTiming) -> Result<OdasFrame, String> {
        let mut doas = Vec::with_capacity(self.src.len());
        for (i, s) in self.src.iter().enumerate() {
            let v = Vector3::new(s.x, s.y, s.z);
            if s.id == 0 || v == Vector3::zeros() {
                continue;
            }
            if !(v.iter().all(|c| c.is_finite()) && s.activity.is_finite()) {
                return Err(format!("src[{i}] (id {}): non-finite value", s.id));
            }
            let norm = v.norm();
            if (norm - 1.0).abs() > NORM_TOLERANCE {
                return Err(format!(
                    "src[{i}] (id {}): direction ({}, {}, {}) has norm {norm:.3}, not a unit vector",
                    s.id, s.x, s.y, s.z
                ));
            }
            if !(-1e-3..=1.0 + 1e-3).contains(&s.activity) {
                return Err(format!("src[{i}] (id {}): activity {} outside [0, 1]", s.id, s.activity));
            }
            doas.push(TrackedDoa {
                track_id: s.id,
                direction_in_array: Unit::new_normalize(v),
                activity: s.activity.clamp(0.0, 1.0),
                angular_sigma_rad: Some(PRIOR_SIGMA_DEG.to_radians()),
                signature: None,
                coherence: None,
                floor_fit_range_m: None,
            });
        }
        Ok(OdasFrame { time_stamp: self.time_stamp, stamp: timing.stamp(self.time_stamp), doas })
    }
}

/// Incremental parser of a concatenated SST object stream, fed with arbitrary chunks.
#[derive(Debug, Default)]
pub struct SstParser {
    buf: Vec<u8>,
    /// Lines consumed before `buf` (for error positions).
    lines_before: usize,
}

impl SstParser {
    /// An empty parser.
    pub fn new() -> Self {
        SstParser::default()
    }

    /// Appends bytes and returns the complete objects now available, in order. A
    /// malformed object is returned as `Err((line, message))` (1-based line of the
    /// stream); parsing resumes at the next line that starts with `{`.
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<Result<SstFrame, (usize, String)>> {
        self.buf.extend_from_slice(bytes);
        let mut out = Vec::new();
        let mut consumed = 0;
        loop {
            let rest = &self.buf[consumed..];
            let mut it = serde_json::Deserializer::from_slice(rest).into_iter::<SstFrame>();
            match it.next() {
                None => {
                    consumed = self.buf.len();
                    break;
                }
                Some(Ok(frame)) => {
                    consumed += it.byte_offset();
                    out.push(Ok(frame));
                }
                Some(Err(e)) if e.is_eof() => break,
                Some(Err(e)) => {
                    let line = self.lines_before + count_lines(&self.buf[..consumed]) + e.line();
                    out.push(Err((line, e.to_string())));
                    // Resynchronize at the next line starting with `{`, from the line of
                    // the error on (a truncated object is often followed by a good one),
                    // always moving forward.
                    let from = line_start(rest, e.line()).max(1).min(rest.len());
                    match find_object_start(&rest[from..]) {
                        Some(k) => consumed += from + k,
                        None => {
                            consumed = self.buf.len();
                            break;
                        }
                    }
                }
            }
        }
        self.lines_before += count_lines(&self.buf[..consumed]);
        self.buf.drain(..consumed);
        out
    }

    /// True when a partial object is pending (the stream ended inside an object).
    pub fn has_partial(&self) -> bool {
        self.buf.iter().any(|b| !b.is_ascii_whitespace())
    }
}

fn count_lines(b: &[u8]) -> usize {
    b.iter().filter(|&&c| c == b'\n').count()
}

/// Byte offset of the start of 1-based line `line`.
fn line_start(b: &[u8], line: usize) -> usize {
    if line <= 1 {
        return 0;
    }
    b.iter().enumerate().filter(|&(_, &c)| c == b'\n').nth(line - 2).map_or(b.len(), |(i, _)| i + 1)
}

/// Offset of the next line that begins with `{`.
fn find_object_start(b: &[u8]) -> Option<usize> {
    if b.first() == Some(&b'{') {
        return Some(0);
    }
    b.windows(2).position(|w| w == b"\n{").map(|k| k + 1)
}

/// Reads an SST file written by ODAS's file sink. Errors name the file and line.
pub fn read_sst_file(path: &Path, timing: &OdasTiming) -> Result<Vec<OdasFrame>, AgentError> {
    let bytes = std::fs::read(path).map_err(|source| AgentError::Io { path: path.to_path_buf(), source })?;
    let name = path.display().to_string();
    let mut parser = SstParser::new();
    let mut frames = Vec::new();
    let mut line = 1;
    for r in parser.feed(&bytes) {
        match r {
            Ok(f) => {
                frames.push(f.to_frame(timing).map_err(|message| AgentError::Odas {
                    source_name: format!("{name}: timeStamp {}", f.time_stamp),
                    message,
                })?);
            }
            Err((l, message)) => {
                return Err(AgentError::Odas { source_name: format!("{name}:{l}"), message });
            }
        }
        line = parser.lines_before + 1;
    }
    if parser.has_partial() {
        return Err(AgentError::Odas {
            source_name: format!("{name}:{line}"),
            message: "the file ends inside an SST object (truncated)".into(),
        });
    }
    Ok(frames)
}

/// Where the start time of a live ODAS stream comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LiveStart {
    /// A known start (the time ODAS's first sample was captured).
    Fixed(Stamp),
    /// Anchor each connection to the wall clock when its first object arrives
    /// (stamps then lag the sound by ODAS's processing and transport latency).
    AtFirstFrame,
}

/// Holds a live hop until its stamp is due on the agent's clock (see the
/// module documentation); returns at once for a hop that is not ahead, and
/// `false` (skip it) for one more than [`MAX_HOLD_NS`] ahead.
async fn hold_until_due(name: &str, frame: &OdasFrame) -> bool {
    let ahead_ns = frame.stamp - Stamp::now();
    if ahead_ns <= 0 {
        return true;
    }
    if ahead_ns > MAX_HOLD_NS {
        warn_limited!(
            WARNINGS,
            "odas_far_ahead",
            "{name}: timeStamp {} is {:.1} s ahead of this clock (a wrong doa.start_ns or hop \
             counter?); skipped",
            frame.time_stamp,
            ahead_ns as f64 * 1e-9
        );
        return false;
    }
    if ahead_ns > AHEAD_WARN_NS {
        warn_limited!(
            WARNINGS,
            "odas_ahead",
            "{name}: timeStamp {} is {:.0} ms ahead of this clock (is ODAS reading a file faster than \
             real time?); its hops are held until due",
            frame.time_stamp,
            ahead_ns as f64 * 1e-6
        );
    }
    tokio::time::sleep(Duration::from_nanos(ahead_ns as u64)).await;
    true
}

/// One live stream (a socket connection, a followed file): how its hop
/// counter maps to time, and what it has sent.
struct LiveStream<'a> {
    name: String,
    hop_len: u32,
    sample_rate_hz: u32,
    /// `None` until anchored at the next object (see the clock rule).
    timing: Option<OdasTiming>,
    sent: u64,
    last_hop: Option<u64>,
    tx: &'a mpsc::Sender<OdasFrame>,
}

impl<'a> LiveStream<'a> {
    fn new(name: String, hop_len: u32, sample_rate_hz: u32, tx: &'a mpsc::Sender<OdasFrame>) -> Self {
        LiveStream { name, hop_len, sample_rate_hz, timing: None, sent: 0, last_hop: None, tx }
    }

    /// Times hop 1 at `start`.
    fn start_at(&mut self, start: Stamp) {
        self.timing = Some(OdasTiming { hop_len: self.hop_len, sample_rate_hz: self.sample_rate_hz, start });
    }

    /// Times hop `time_stamp` at now.
    fn anchor_now(&mut self, time_stamp: u64) {
        self.timing = Some(OdasTiming::anchored(self.hop_len, self.sample_rate_hz, time_stamp, Stamp::now()));
    }

    /// Converts and sends parsed objects, anchoring the timing at the first
    /// one when it is not set and holding hops until due. Returns `false` once
    /// the receiver is gone.
    async fn forward(&mut self, parsed: Vec<Result<SstFrame, (usize, String)>>) -> bool {
        let name = &self.name;
        for r in parsed {
            let sst = match r {
                Ok(f) => f,
                Err((line, message)) => {
                    warn_limited!(
                        WARNINGS,
                        "odas_malformed",
                        "{name}: line {line}: {message}; object skipped"
                    );
                    continue;
                }
            };
            let (hop_len, sample_rate_hz) = (self.hop_len, self.sample_rate_hz);
            let timing = *self.timing.get_or_insert_with(|| {
                OdasTiming::anchored(hop_len, sample_rate_hz, sst.time_stamp, Stamp::now())
            });
            match sst.to_frame(&timing) {
                Ok(frame) => {
                    if !hold_until_due(name, &frame).await {
                        continue;
                    }
                    self.last_hop = Some(frame.time_stamp);
                    self.sent += 1;
                    if self.tx.send(frame).await.is_err() {
                        return false;
                    }
                }
                Err(message) => warn_limited!(
                    WARNINGS,
                    "odas_invalid",
                    "{name}: timeStamp {}: {message}; skipped",
                    sst.time_stamp
                ),
            }
        }
        true
    }
}

/// Listens for ODAS's tracked-sources socket sink and forwards converted frames to
/// `tx`. Connections are served one after another: when ODAS disconnects the
/// bridge says so and waits for it to reconnect, and while nothing is
/// connected it says every [`WAIT_REPORT`] that it is still waiting. Timing
/// follows the module's clock rule; malformed objects are skipped with
/// rate-limited warnings. Returns when `tx` is closed.
pub async fn serve_tcp(
    listener: TcpListener,
    hop_len: u32,
    sample_rate_hz: u32,
    start: LiveStart,
    tx: mpsc::Sender<OdasFrame>,
) -> Result<(), AgentError> {
    let local = listener.local_addr().map(|a| a.to_string()).unwrap_or_else(|_| "ODAS socket".into());
    tracing::info!(
        "listening for ODAS on {local}: start ODAS now (its sst tracked interface, type \"socket\", \
         connects to this address)"
    );
    let mut chunk = vec![0u8; 16 * 1024];
    let mut last_hop: Option<u64> = None;
    let mut waiting_since = std::time::Instant::now();
    while !tx.is_closed() {
        let (mut stream, peer) = match tokio::time::timeout(WAIT_REPORT, listener.accept()).await {
            Ok(Ok(accepted)) => accepted,
            Ok(Err(e)) => {
                // A failed accept (an aborted connection, no descriptor left) is not the end of the bridge.
                warn_limited!(
                    WARNINGS,
                    "odas_accept",
                    "{local}: cannot accept a connection: {e}; still listening"
                );
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
            Err(_) => {
                tracing::warn!(
                    "no ODAS connected on {local} for {:.0} s; still listening",
                    waiting_since.elapsed().as_secs_f64()
                );
                continue;
            }
        };
        let mut live = LiveStream::new(format!("ODAS {peer}"), hop_len, sample_rate_hz, &tx);
        let name = live.name.clone();
        tracing::info!("{name}: connected");
        let mut parser = SstParser::new();
        loop {
            let n = match stream.read(&mut chunk).await {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) => {
                    tracing::warn!("{name}: {e}");
                    break;
                }
            };
            let parsed = parser.feed(&chunk[..n]);
            if live.timing.is_none()
                && let (LiveStart::Fixed(start), Some(first)) =
                    (start, parsed.iter().find_map(|r| r.as_ref().ok()))
            {
                // A restarted ODAS counts from 1 again: its counter no longer matches `start`.
                if last_hop.is_some_and(|p| first.time_stamp <= p) {
                    tracing::warn!(
                        "{name}: timeStamp went back from {} to {} (ODAS restarted): doa.start_ns no \
                         longer holds, this connection is timed from its first object",
                        last_hop.unwrap_or(0),
                        first.time_stamp
                    );
                } else {
                    live.start_at(start);
                }
            }
            if !live.forward(parsed).await {
                return Ok(());
            }
        }
        last_hop = live.last_hop.or(last_hop);
        tracing::warn!(
            "{name}: ODAS disconnected after {} objects (last timeStamp {}); listening on {local} for it \
             to reconnect",
            live.sent,
            last_hop.map_or("none".into(), |t| t.to_string())
        );
        waiting_since = std::time::Instant::now();
    }
    Ok(())
}

/// Follows an SST file that ODAS's file sink is writing (`doa.follow = true`):
/// waits for the file to exist, then forwards each object as it is appended,
/// until `tx` is closed. Timing follows the module's clock rule (with
/// [`LiveStart::AtFirstFrame`], what is already in the file is skipped and its
/// newest object is taken as written now). A file that shrinks is read again
/// from its start.
pub async fn follow_file(
    path: PathBuf,
    hop_len: u32,
    sample_rate_hz: u32,
    start: LiveStart,
    tx: mpsc::Sender<OdasFrame>,
) -> Result<(), AgentError> {
    let name = path.display().to_string();
    let io = |source| AgentError::Io { path: path.clone(), source };
    let mut reported = false;
    let mut file = loop {
        match tokio::fs::File::open(&path).await {
            Ok(f) => break f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                if !reported {
                    tracing::info!("{name}: not there yet; waiting for ODAS to create it");
                    reported = true;
                }
                if tx.is_closed() {
                    return Ok(());
                }
                tokio::time::sleep(FOLLOW_POLL).await;
            }
            Err(e) => return Err(io(e)),
        }
    };
    let mut live = LiveStream::new(name.clone(), hop_len, sample_rate_hz, &tx);
    let mut parser = SstParser::new();
    let mut pos = 0u64;
    match start {
        LiveStart::Fixed(start) => live.start_at(start),
        LiveStart::AtFirstFrame => {
            // Skip what is there; its newest object was written just now.
            let mut existing = Vec::new();
            file.read_to_end(&mut existing).await.map_err(io)?;
            pos = existing.len() as u64;
            if let Some(f) = parser.feed(&existing).into_iter().filter_map(Result::ok).next_back() {
                live.anchor_now(f.time_stamp);
                tracing::info!(
                    "{name}: following from timeStamp {} (the objects before it are skipped)",
                    f.time_stamp
                );
            }
        }
    }
    tracing::info!("{name}: following the file as ODAS writes it");
    let mut chunk = vec![0u8; 64 * 1024];
    while !tx.is_closed() {
        let len = file.metadata().await.map_err(io)?.len();
        if len < pos {
            tracing::warn!(
                "{name}: the file shrank from {pos} to {len} bytes (ODAS restarted?); reading it again from \
                 its start"
            );
            file.seek(std::io::SeekFrom::Start(0)).await.map_err(io)?;
            (pos, parser, live.timing) = (0, SstParser::new(), None);
        }
        let n = file.read(&mut chunk).await.map_err(io)?;
        if n == 0 {
            tokio::time::sleep(FOLLOW_POLL).await;
            continue;
        }
        pos += n as u64;
        let parsed = parser.feed(&chunk[..n]);
        if !live.forward(parsed).await {
            break;
        }
    }
    Ok(())
}

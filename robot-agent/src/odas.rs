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
//! interface, so the bridge listens there ([`serve_tcp`]). Files written by its
//! file sink are read with [`read_sst_file`].

use std::path::Path;

use nalgebra::{Unit, Vector3};
use serde::Deserialize;
use soundmap_proto::{Stamp, TrackedDoa};
use tokio::io::AsyncReadExt;
use tokio::net::TcpListener;
use tokio::sync::mpsc;

use crate::AgentError;

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

/// Listens for ODAS's tracked-sources socket sink and forwards converted frames to
/// `tx`. Connections are served one after another (a restarted ODAS reconnects);
/// malformed objects are logged and skipped. Returns when `tx` is closed.
pub async fn serve_tcp(
    listener: TcpListener,
    hop_len: u32,
    sample_rate_hz: u32,
    start: LiveStart,
    tx: mpsc::Sender<OdasFrame>,
) -> Result<(), AgentError> {
    let local = listener.local_addr().map(|a| a.to_string()).unwrap_or_else(|_| "ODAS socket".into());
    let mut chunk = vec![0u8; 16 * 1024];
    while !tx.is_closed() {
        let (mut stream, peer) = listener
            .accept()
            .await
            .map_err(|source| AgentError::Io { path: local.clone().into(), source })?;
        let name = format!("ODAS {peer}");
        tracing::info!("{name}: connected");
        let mut parser = SstParser::new();
        let mut timing = match start {
            LiveStart::Fixed(start) => Some(OdasTiming { hop_len, sample_rate_hz, start }),
            LiveStart::AtFirstFrame => None,
        };
        loop {
            let n = match stream.read(&mut chunk).await {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) => {
                    tracing::warn!("{name}: {e}");
                    break;
                }
            };
            for r in parser.feed(&chunk[..n]) {
                let sst = match r {
                    Ok(f) => f,
                    Err((line, message)) => {
                        tracing::warn!("{name}: line {line}: {message}; object skipped");
                        continue;
                    }
                };
                let t = *timing.get_or_insert_with(|| {
                    OdasTiming::anchored(hop_len, sample_rate_hz, sst.time_stamp, Stamp::now())
                });
                match sst.to_frame(&t) {
                    Ok(frame) => {
                        if tx.send(frame).await.is_err() {
                            return Ok(());
                        }
                    }
                    Err(message) => {
                        tracing::warn!("{name}: timeStamp {}: {message}; skipped", sst.time_stamp)
                    }
                }
            }
        }
        tracing::info!("{name}: closed");
    }
    Ok(())
}

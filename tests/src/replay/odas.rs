//! Replayed robots whose DoAs come from an ODAS SST file instead of audio:
//! the file is read with the agent's own SST reader (the one `[doa] source =
//! "odas"` uses), each object is one hop stamped from its `timeStamp`
//! (`start + (timeStamp − 1)·hop_len/sample_rate_hz`, `start` the pose-file
//! time given by the robot's `start=`), and the hops go through the same agent
//! core (pose attachment, the ODAS prior σ the bridge attaches) and the same
//! coordinator as audio replays.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};

use soundmap_agent::odas::{OdasFrame, OdasTiming, read_sst_file};
use soundmap_proto::Stamp;

use crate::error::SimError;

/// ODAS's default hop (`general.size.hopSize`), samples.
pub const DEFAULT_HOP_LEN: u32 = 128;
/// ODAS's default sample rate (`general.samplerate.mu`), Hz.
pub const DEFAULT_SAMPLE_RATE_HZ: u32 = 16_000;

/// An SST recording and how its hop counter maps to time.
#[derive(Clone, Debug, PartialEq)]
pub struct OdasRecording {
    /// The SST JSON file.
    pub path: PathBuf,
    /// ODAS's hop length (samples).
    pub hop_len: u32,
    /// ODAS's sample rate (Hz).
    pub sample_rate_hz: u32,
}

impl OdasRecording {
    /// A file at ODAS's default hop and rate.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        OdasRecording { path: path.into(), hop_len: DEFAULT_HOP_LEN, sample_rate_hz: DEFAULT_SAMPLE_RATE_HZ }
    }
}

/// The hops of one SST file, in order.
#[derive(Debug)]
pub(crate) struct OdasHops {
    frames: VecDeque<OdasFrame>,
    hop_s: f64,
}

impl OdasHops {
    /// Reads the file (errors name the file and line, or the object).
    pub(crate) fn open(r: &OdasRecording, start: Stamp) -> Result<Self, SimError> {
        if r.hop_len == 0 || r.sample_rate_hz == 0 {
            return Err(SimError::Replay(format!(
                "{}: odas_hop and odas_rate must be > 0",
                r.path.display()
            )));
        }
        let timing = OdasTiming { hop_len: r.hop_len, sample_rate_hz: r.sample_rate_hz, start };
        let frames = read_sst_file(Path::new(&r.path), &timing)?;
        if frames.is_empty() {
            return Err(SimError::Replay(format!("{}: no SST objects", r.path.display())));
        }
        if let Some(w) = frames.windows(2).find(|w| w[1].time_stamp <= w[0].time_stamp) {
            return Err(SimError::Replay(format!(
                "{}: timeStamp {} follows {}: hop counts must increase",
                r.path.display(),
                w[1].time_stamp,
                w[0].time_stamp
            )));
        }
        Ok(OdasHops { frames: frames.into(), hop_s: r.hop_len as f64 / r.sample_rate_hz as f64 })
    }

    /// Stamp of the next hop.
    pub(crate) fn next_stamp(&self) -> Option<Stamp> {
        self.frames.front().map(|f| f.stamp)
    }

    /// The next hop and the coordinator's clock for it (the end of the hop).
    pub(crate) fn take(&mut self) -> Option<(OdasFrame, Stamp)> {
        let f = self.frames.pop_front()?;
        let now = f.stamp.plus_secs(self.hop_s);
        Some((f, now))
    }
}

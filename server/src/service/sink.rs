//! The JSON-lines files: estimates, and (optionally) the observations accepted.
//!
//! **Never a torn line.** Each file is written in whole lines only: a batch
//! of lines is formatted first and handed to the kernel in one `write` (a
//! process killed with SIGKILL loses the lines not yet written, never half of
//! one). A file that ends in a partial line anyway (a full disk, a power cut)
//! is cut back to its last complete line when it is opened again, with a warning.
//!
//! **Restart marker.** When the coordinator appends to an estimates file that
//! already holds lines, it first writes one marker line, told apart from
//! estimates by its `event` key:
//! `{"event": "restart", "started_ns", "state": "restored" | "empty" | "in_memory", "next_source_id"}`
//! (`state`: whether a state store was loaded, found empty, or not configured).
//! Source ids after the marker continue those before it (see `crate::state`).
//!
//! **Observations are logged before they are acknowledged.** The coordinator
//! task writes the lines of a batch's accepted observations ([`LineFile`])
//! before it sends the batch's acknowledgements: an acknowledged observation is
//! in the file even if the process is killed right after.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use soundmap_proto::wire;
use tokio::sync::mpsc;

use super::convert::estimate_to_json_line;
use crate::error::ServerError;

/// Opens `path` for appending, cutting a trailing partial line. Returns the
/// file and whether it holds lines.
fn open_append(path: &Path) -> Result<(std::fs::File, bool), ServerError> {
    let err = |source| ServerError::Io { path: path.into(), source };
    let mut file =
        std::fs::OpenOptions::new().create(true).read(true).append(true).open(path).map_err(err)?;
    let len = file.metadata().map_err(err)?.len();
    if len == 0 {
        return Ok((file, false));
    }
    // Find the last newline within the tail (lines are short; read back in 64 KiB steps).
    let mut end = len;
    let mut cut = None;
    while end > 0 && cut.is_none() {
        let start = end.saturating_sub(65_536);
        let mut buf = vec![0u8; (end - start) as usize];
        file.seek(SeekFrom::Start(start)).map_err(err)?;
        file.read_exact(&mut buf).map_err(err)?;
        if end == len && buf.last() == Some(&b'\n') {
            return Ok((file, true));
        }
        cut = buf.iter().rposition(|b| *b == b'\n').map(|i| start + i as u64 + 1);
        end = start;
    }
    let keep = cut.unwrap_or(0);
    tracing::warn!(
        "{}: ends in a partial line: cut back to its last complete line ({} bytes dropped)",
        path.display(),
        len - keep
    );
    file.set_len(keep).map_err(err)?;
    Ok((file, keep > 0))
}

/// A JSON-lines file written in whole lines by its owner's thread.
#[derive(Debug)]
pub struct LineFile {
    path: PathBuf,
    file: std::fs::File,
    pending: String,
}

impl LineFile {
    /// Opens (appends to) `path`.
    pub fn open(path: &Path) -> Result<Self, ServerError> {
        let (file, _) = open_append(path)?;
        Ok(LineFile { path: path.into(), file, pending: String::new() })
    }

    /// Queues one line (without its newline).
    pub fn push(&mut self, line: &str) {
        self.pending.push_str(line);
        self.pending.push('\n');
    }

    /// Writes the queued lines in one write.
    pub fn flush(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        if let Err(e) = self.file.write_all(self.pending.as_bytes()) {
            tracing::error!("{}: {e}", self.path.display());
        }
        self.pending.clear();
        if self.pending.capacity() > 1 << 20 {
            self.pending.shrink_to(1 << 16);
        }
    }
}

/// Opens (appends to) `path` and returns the channel that feeds it and the
/// writer thread's handle. When the file already holds lines, `marker` is
/// written first. The thread writes whenever the channel runs dry and ends
/// when the sender is dropped.
pub fn spawn_jsonl_sink(
    path: PathBuf,
    marker: Option<String>,
) -> Result<(mpsc::UnboundedSender<Arc<wire::SourceEstimate>>, std::thread::JoinHandle<()>), ServerError> {
    let (file, has_lines) = open_append(&path)?;
    let mut out = LineFile { path: path.clone(), file, pending: String::new() };
    if let (true, Some(m)) = (has_lines, marker) {
        out.push(&m);
        out.flush();
    }
    let (tx, mut rx) = mpsc::unbounded_channel::<Arc<wire::SourceEstimate>>();
    let handle = std::thread::Builder::new()
        .name("estimates-jsonl".into())
        .spawn(move || {
            while let Some(e) = rx.blocking_recv() {
                let mut next = Some(e);
                while let Some(e) = next {
                    if let Some(line) = estimate_to_json_line(&e) {
                        out.push(&line);
                    }
                    next = rx.try_recv().ok();
                }
                out.flush();
            }
        })
        .map_err(|source| ServerError::Io { path: "<estimates-jsonl thread>".into(), source })?;
    Ok((tx, handle))
}

/// The restart marker line (see the module docs).
pub fn restart_marker(started_ns: i64, state: &str, next_source_id: u64) -> String {
    serde_json::json!({
        "event": "restart",
        "started_ns": started_ns,
        "state": state,
        "next_source_id": next_source_id,
    })
    .to_string()
}

/// The JSON line of an accepted observation (see `output.observations_jsonl`).
pub fn observation_line(robot_id: &str, obs: &soundmap_proto::Observation) -> String {
    let t = obs.map_from_base.translation.vector;
    let q = obs.map_from_base.rotation.quaternion();
    let doas: Vec<serde_json::Value> = obs
        .doas
        .iter()
        .map(|d| {
            let v = d.direction_in_array;
            serde_json::json!({
                "track_id": d.track_id, "x": v.x, "y": v.y, "z": v.z,
                "activity": d.activity, "angular_sigma_rad": d.angular_sigma_rad,
                "coherence": d.coherence,
            })
        })
        .collect();
    serde_json::json!({
        "robot_id": robot_id,
        "sequence": obs.sequence,
        "stamp_ns": obs.stamp.as_ns(),
        "map_from_base": [t.x, t.y, t.z, q.i, q.j, q.k, q.w],
        "doas": doas,
    })
    .to_string()
}

//! The JSON-lines files: estimates, and (optionally) the observations accepted.

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

use soundmap_proto::wire;
use tokio::sync::mpsc;

use super::convert::estimate_to_json_line;
use crate::error::ServerError;

/// Opens (appends to) `path` and returns the channel that feeds it and the
/// writer thread's handle. The thread flushes whenever the channel runs dry
/// and ends when the sender is dropped.
pub fn spawn_jsonl_sink(
    path: PathBuf,
) -> Result<(mpsc::UnboundedSender<Arc<wire::SourceEstimate>>, std::thread::JoinHandle<()>), ServerError> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(|source| ServerError::Io { path: path.clone(), source })?;
    let (tx, mut rx) = mpsc::unbounded_channel::<Arc<wire::SourceEstimate>>();
    let handle = std::thread::Builder::new()
        .name("estimates-jsonl".into())
        .spawn(move || {
            let mut out = std::io::BufWriter::new(file);
            while let Some(e) = rx.blocking_recv() {
                let mut next = Some(e);
                while let Some(e) = next {
                    if let Some(line) = estimate_to_json_line(&e)
                        && let Err(err) = writeln!(out, "{line}")
                    {
                        tracing::error!("{}: {err}", path.display());
                    }
                    next = rx.try_recv().ok();
                }
                if let Err(err) = out.flush() {
                    tracing::error!("{}: {err}", path.display());
                }
            }
        })
        .map_err(|source| ServerError::Io { path: "<estimates-jsonl thread>".into(), source })?;
    Ok((tx, handle))
}

/// Opens (appends to) `path` and returns the channel of ready-made lines that
/// feeds it and the writer thread's handle (flushes when the channel runs dry).
pub fn spawn_lines_sink(
    path: PathBuf,
    thread_name: &str,
) -> Result<(mpsc::UnboundedSender<String>, std::thread::JoinHandle<()>), ServerError> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(|source| ServerError::Io { path: path.clone(), source })?;
    let (tx, mut rx) = mpsc::unbounded_channel::<String>();
    let handle = std::thread::Builder::new()
        .name(thread_name.into())
        .spawn(move || {
            let mut out = std::io::BufWriter::new(file);
            while let Some(line) = rx.blocking_recv() {
                let mut next = Some(line);
                while let Some(line) = next {
                    if let Err(err) = writeln!(out, "{line}") {
                        tracing::error!("{}: {err}", path.display());
                    }
                    next = rx.try_recv().ok();
                }
                if let Err(err) = out.flush() {
                    tracing::error!("{}: {err}", path.display());
                }
            }
        })
        .map_err(|source| ServerError::Io { path: format!("<{thread_name} thread>").into(), source })?;
    Ok((tx, handle))
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

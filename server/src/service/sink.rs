//! The estimates JSON-lines file.

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

//! What the coordinator task does besides its batches: hands snapshots of
//! its state to the state writer (at most once per `state.snapshot_period_ms`),
//! copies the registry's bound counters into the metrics, and bounds the
//! `GetState` answer.
//!
//! **`GetState` bound.** The answer lists at most `server.max_state_entries`
//! robots (live ones first, then the most recently seen), sources and
//! sound-map entries (live first), and is cut further until its encoding is
//! under [`MAX_STATE_BYTES`] (3 MiB, below the 4 MiB a gRPC client accepts by
//! default). A robot's entry is ~0.3–1 KB (its array geometry is the largest
//! part), so 256 entries of each kind take well under 1 MiB. An answer that
//! left entries out is counted (`state_truncated`) and logged at most once per
//! interval; the full registry's size is in the coordinator's log and metrics.

use std::sync::Arc;
use std::time::{Duration, Instant};

use prost::Message;
use soundmap_proto::{Stamp, wire};

use super::metrics::Metrics;
use super::ratelog::RateLog;
use crate::coordinator::Coordinator;
use crate::state::StateWriter;
use soundmap_proto::warn_limited;

/// Largest `GetState` answer (bytes of its encoding).
pub const MAX_STATE_BYTES: usize = 3 << 20;

/// The coordinator task's upkeep (see the module docs).
#[derive(Debug)]
pub struct Upkeep {
    writer: Option<StateWriter>,
    period: Duration,
    last: Option<Instant>,
    metrics: Arc<Metrics>,
    /// Rate-limited warnings of the coordinator task.
    pub ratelog: Arc<RateLog>,
}

impl Upkeep {
    /// Upkeep writing snapshots to `writer` (if any) at most every `period`.
    pub fn new(
        writer: Option<StateWriter>,
        period: Duration,
        metrics: Arc<Metrics>,
        ratelog: Arc<RateLog>,
    ) -> Self {
        Upkeep { writer, period, last: None, metrics, ratelog }
    }

    /// After a batch: counters, and a snapshot when one is due.
    pub fn after_batch(&mut self, coordinator: &Coordinator, now: Stamp) {
        use std::sync::atomic::Ordering::Relaxed;
        let c = coordinator.counters();
        let l = &self.metrics.limits;
        l.history_trimmed.store(c.history_trimmed, Relaxed);
        l.robots_forgotten.store(c.robots_forgotten, Relaxed);
        l.robots_refused.store(c.robots_refused, Relaxed);
        let Some(writer) = &self.writer else { return };
        if self.last.is_some_and(|t| t.elapsed() < self.period) {
            return;
        }
        self.last = Some(Instant::now());
        writer.submit(coordinator.export_state(now));
    }

    /// At a clean stop: writes the last snapshot and waits for it.
    pub fn finish(&mut self, coordinator: &Coordinator, now: Stamp) {
        if let Some(w) = self.writer.take() {
            w.finish(coordinator.export_state(now));
        }
    }

    /// `state` within the bounds of the module docs.
    pub fn bound_state(
        &self,
        mut state: wire::CoordinatorState,
        max_entries: usize,
    ) -> wire::CoordinatorState {
        let (robots, sources, mapped) = (state.robots.len(), state.sources.len(), state.sound_map.len());
        let live = wire::Liveness::Live as i32;
        if state.robots.len() > max_entries {
            state.robots.sort_by_key(|r| (r.liveness != live, std::cmp::Reverse(r.last_seen_ns)));
            state.robots.truncate(max_entries);
        }
        state.sources.truncate(max_entries);
        state.sound_map.truncate(max_entries);
        while state.encoded_len() > MAX_STATE_BYTES && !state.robots.is_empty() {
            let keep = state.robots.len() / 2;
            state.robots.truncate(keep);
        }
        let cut =
            (robots - state.robots.len(), sources - state.sources.len(), mapped - state.sound_map.len());
        if cut != (0, 0, 0) {
            super::metrics::LimitCounters::bump(&self.metrics.limits.state_truncated);
            warn_limited!(
                self.ratelog,
                "state_truncated",
                "GetState left out {} of {robots} robots, {} of {sources} sources and {} of {mapped} \
                 sound-map entries (server.max_state_entries = {max_entries})",
                cut.0,
                cut.1,
                cut.2
            );
        }
        state
    }
}

/// Opens the state store of `[state] dir` (when set), puts what it holds
/// back into `coordinator`, and returns the upkeep writing to it with the
/// word the restart marker uses for it (`restored`, `empty`, `in_memory`).
pub fn open_state(
    config: &crate::CoordinatorConfig,
    coordinator: &mut Coordinator,
    now: Stamp,
    metrics: Arc<Metrics>,
    ratelog: Arc<RateLog>,
) -> Result<(Upkeep, &'static str), crate::ServerError> {
    let period = Duration::from_millis(config.state.snapshot_period_ms);
    let Some(dir) = &config.state.dir else {
        tracing::warn!(
            "no state directory ([state] dir or --state-dir): running in memory; sources, known robots \
             and the operator's settings are lost at a restart"
        );
        return Ok((Upkeep::new(None, period, metrics, ratelog), "in_memory"));
    };
    let mut store = crate::state::StateStore::open(dir)?;
    let word = match store.load(&coordinator.limits(now))? {
        Some(record) => {
            coordinator.restore_state(&record)?;
            tracing::info!(
                store = %store.path().display(),
                robots = record.robots.len(),
                sources = record.sources.len(),
                next_source_id = record.next_source_id,
                active_positioning = record.settings.active_positioning,
                "state restored"
            );
            "restored"
        }
        None => {
            tracing::info!(store = %store.path().display(), "state store empty: starting afresh");
            "empty"
        }
    };
    let (m, log) = (metrics.clone(), ratelog.clone());
    let report: crate::state::WriteReport = Box::new(move |r| {
        use super::metrics::LimitCounters;
        match r {
            Ok(took) => {
                LimitCounters::bump(&m.limits.state_writes);
                m.limits
                    .state_write_us
                    .fetch_add(took.as_micros() as u64, std::sync::atomic::Ordering::Relaxed);
            }
            Err(e) => {
                LimitCounters::bump(&m.limits.state_write_errors);
                warn_limited!(log, "state_write", "writing the state store failed: {e}");
            }
        }
    });
    let writer = StateWriter::spawn(store, report)?;
    Ok((Upkeep::new(Some(writer), period, metrics, ratelog), word))
}

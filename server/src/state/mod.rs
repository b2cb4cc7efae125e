//! State that survives a restart: `soundmap-state.redb` in `[state] dir`
//! (`--state-dir`), an embedded store whose committed transactions survive a
//! crash (redb: copy-on-write B-trees, a commit is durable once it returns).
//!
//! **What.** The sources (ids, positions, covariances, first and last heard),
//! the robot registry (hello, tracker index, last pose and counters), the
//! operator's settings (active positioning on/off, θ band, focus) and the next
//! source id ([`crate::coordinator::records`]).
//!
//! **When, and at what cost.** The coordinator task takes a record (no
//! history, no tracker state: ~0.3 KB per robot and per source) at most once per
//! `state.snapshot_period_ms` (200 ms) and only after a batch that changed
//! something, and hands it to a writer thread through a one-slot mailbox: a
//! record not yet written is replaced by the newer one, so a slow disk delays
//! the state but never the coordinator or its memory. The writer writes only
//! the rows that changed (a robot's row when its hello or index changes, or
//! at most every 10 s for its pose and counters), in one transaction.
//!
//! **Source ids are never given twice.** Besides the next id, the store keeps
//! a *reservation*: ids below it may have been given. It is kept at least 32
//! ahead of the next id, 64 ahead when renewed, and written before the ids are
//! used up in practice. After a crash the coordinator starts from the
//! reservation (a gap of at most 64 ids); after a clean stop, from the next id.
//!
//! **What a restart looks like.** Robots are back as disconnected and resume
//! when they reconnect; every source is remembered, and a track that starts
//! within `sources.reuse_radius_m` of one (within `sources.memory_s`) takes
//! back its id; the operator's settings are as they were left.

pub mod codec;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use redb::{Database, ReadableDatabase, ReadableTable, TableDefinition};
use soundmap_proto::Limits;

use crate::coordinator::records::{CoordinatorRecord, SettingsRecord};
use crate::error::ServerError;
use codec::{SettingsRow, SourceRow};

/// File name of the store in the state directory.
pub const FILE_NAME: &str = "soundmap-state.redb";

const META: TableDefinition<&str, &[u8]> = TableDefinition::new("meta");
const SOURCES: TableDefinition<u64, &[u8]> = TableDefinition::new("sources");
const ROBOTS: TableDefinition<&str, &[u8]> = TableDefinition::new("robots");

/// Ids kept ahead of the next source id in the reservation.
const RESERVE_MIN: u64 = 32;
/// Ids reserved ahead when the reservation is renewed.
const RESERVE_BLOCK: u64 = 64;
/// A robot's pose and counters are rewritten at most this often.
const ROBOT_REFRESH: Duration = Duration::from_secs(10);

/// The open store.
#[derive(Debug)]
pub struct StateStore {
    db: Database,
    path: PathBuf,
    /// Rows written: robot id → (row, when).
    robots: HashMap<String, (Vec<u8>, Instant)>,
    sources: HashMap<u64, Vec<u8>>,
    settings: Option<Vec<u8>>,
    next_source_id: u64,
    reserved: u64,
}

fn io(path: &Path, e: impl std::fmt::Display) -> ServerError {
    ServerError::Io { path: path.into(), source: std::io::Error::other(e.to_string()) }
}

fn u64_of(bytes: Option<redb::AccessGuard<'_, &[u8]>>) -> u64 {
    bytes.and_then(|b| b.value().try_into().ok().map(u64::from_le_bytes)).unwrap_or(0)
}

impl StateStore {
    /// Opens (or creates) the store in `dir`. Fails when another process has it open.
    pub fn open(dir: &Path) -> Result<Self, ServerError> {
        std::fs::create_dir_all(dir).map_err(|source| ServerError::Io { path: dir.into(), source })?;
        let path = dir.join(FILE_NAME);
        let db = Database::create(&path).map_err(|e| io(&path, e))?;
        Ok(StateStore {
            db,
            path,
            robots: HashMap::new(),
            sources: HashMap::new(),
            settings: None,
            next_source_id: 0,
            reserved: 0,
        })
    }

    /// Its file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Reads what the store holds (`None` when empty), robots' hellos validated
    /// with `limits` (rows that fail are skipped with a warning), and renews the
    /// source-id reservation before any id is given.
    pub fn load(&mut self, limits: &Limits) -> Result<Option<CoordinatorRecord>, ServerError> {
        let path = self.path.clone();
        let txn = self.db.begin_read().map_err(|e| io(&path, e))?;
        let meta = match txn.open_table(META) {
            Ok(t) => t,
            Err(redb::TableError::TableDoesNotExist(_)) => return Ok(None),
            Err(e) => return Err(io(&path, e)),
        };
        let next = u64_of(meta.get("next_source_id").map_err(|e| io(&path, e))?);
        let reserved = u64_of(meta.get("source_id_reserved").map_err(|e| io(&path, e))?);
        let settings: Option<SettingsRow> = meta
            .get("settings")
            .map_err(|e| io(&path, e))?
            .and_then(|b| serde_json::from_slice(b.value()).ok());
        let mut sources = Vec::new();
        if let Ok(t) = txn.open_table(SOURCES) {
            for row in t.iter().map_err(|e| io(&path, e))? {
                let (_, v) = row.map_err(|e| io(&path, e))?;
                match serde_json::from_slice::<SourceRow>(v.value()).ok().and_then(|r| r.record()) {
                    Some(r) => sources.push(r),
                    None => tracing::warn!("{}: a source row does not decode; skipped", path.display()),
                }
            }
        }
        let mut robots = Vec::new();
        if let Ok(t) = txn.open_table(ROBOTS) {
            for row in t.iter().map_err(|e| io(&path, e))? {
                let (k, v) = row.map_err(|e| io(&path, e))?;
                match codec::decode_robot(v.value(), limits) {
                    Ok(r) => robots.push(r),
                    Err(e) => tracing::warn!("{}: robot {}: {e}; skipped", path.display(), k.value()),
                }
            }
        }
        drop(meta);
        drop(txn);
        let Some(settings) = settings else { return Ok(None) };
        // After a crash, ids up to the reservation may have been given.
        let next_source_id = next.max(reserved).max(1);
        self.next_source_id = next_source_id;
        self.renew_reservation(next_source_id)?;
        Ok(Some(CoordinatorRecord {
            next_source_id,
            settings: SettingsRecord::from(settings),
            sources,
            robots,
        }))
    }

    fn renew_reservation(&mut self, next: u64) -> Result<(), ServerError> {
        let path = self.path.clone();
        let reserved = next + RESERVE_BLOCK;
        let txn = self.db.begin_write().map_err(|e| io(&path, e))?;
        {
            let mut meta = txn.open_table(META).map_err(|e| io(&path, e))?;
            meta.insert("source_id_reserved", reserved.to_le_bytes().as_slice()).map_err(|e| io(&path, e))?;
        }
        txn.commit().map_err(|e| io(&path, e))?;
        self.reserved = reserved;
        Ok(())
    }

    /// Writes the rows of `record` that changed; `clean` (a clean stop) sets
    /// the reservation to the next id. Returns whether anything was written.
    pub fn write(&mut self, record: &CoordinatorRecord, clean: bool) -> Result<bool, ServerError> {
        let path = self.path.clone();
        let now = Instant::now();
        let mut robot_rows = Vec::new();
        for r in &record.robots {
            let id = r.hello.robot_id.to_string();
            let row = codec::encode_robot(r);
            let due = match self.robots.get(&id) {
                None => true,
                Some((old, _)) if old == &row => false,
                Some((old, at)) => {
                    // Hello or index changed: now; pose and counters: every ROBOT_REFRESH.
                    let n = |b: &[u8]| u32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as usize;
                    let hello_changed = old[..4 + n(old)] != row[..4 + n(&row)];
                    let index_changed = codec::robot_status(old).map(|s| s.index) != Some(r.index);
                    hello_changed || index_changed || at.elapsed() >= ROBOT_REFRESH
                }
            };
            if due {
                robot_rows.push((id, row));
            }
        }
        let present: std::collections::HashSet<String> =
            record.robots.iter().map(|r| r.hello.robot_id.to_string()).collect();
        let gone_robots: Vec<String> =
            self.robots.keys().filter(|k| !present.contains(*k)).cloned().collect();
        let source_rows: HashMap<u64, Vec<u8>> = record
            .sources
            .iter()
            .map(|s| (s.id, serde_json::to_vec(&SourceRow::from(s)).expect("plain struct")))
            .collect();
        let changed_sources: Vec<(u64, &Vec<u8>)> = source_rows
            .iter()
            .filter(|(id, row)| self.sources.get(id) != Some(row))
            .map(|(i, r)| (*i, r))
            .collect();
        let gone_sources: Vec<u64> =
            self.sources.keys().filter(|k| !source_rows.contains_key(k)).copied().collect();
        let settings = serde_json::to_vec(&SettingsRow::from(record.settings)).expect("plain struct");
        let settings_changed = self.settings.as_ref() != Some(&settings);
        let next = record.next_source_id;
        let reserved = if clean {
            next
        } else if self.reserved < next + RESERVE_MIN {
            next + RESERVE_BLOCK
        } else {
            self.reserved
        };
        let nothing = robot_rows.is_empty()
            && gone_robots.is_empty()
            && changed_sources.is_empty()
            && gone_sources.is_empty()
            && !settings_changed
            && next == self.next_source_id
            && reserved == self.reserved;
        if nothing {
            return Ok(false);
        }
        let txn = self.db.begin_write().map_err(|e| io(&path, e))?;
        {
            let mut meta = txn.open_table(META).map_err(|e| io(&path, e))?;
            meta.insert("settings", settings.as_slice()).map_err(|e| io(&path, e))?;
            meta.insert("next_source_id", next.to_le_bytes().as_slice()).map_err(|e| io(&path, e))?;
            meta.insert("source_id_reserved", reserved.to_le_bytes().as_slice()).map_err(|e| io(&path, e))?;
            let mut robots = txn.open_table(ROBOTS).map_err(|e| io(&path, e))?;
            for (id, row) in &robot_rows {
                robots.insert(id.as_str(), row.as_slice()).map_err(|e| io(&path, e))?;
            }
            for id in &gone_robots {
                robots.remove(id.as_str()).map_err(|e| io(&path, e))?;
            }
            let mut sources = txn.open_table(SOURCES).map_err(|e| io(&path, e))?;
            for (id, row) in &changed_sources {
                sources.insert(*id, row.as_slice()).map_err(|e| io(&path, e))?;
            }
            for id in &gone_sources {
                sources.remove(*id).map_err(|e| io(&path, e))?;
            }
        }
        txn.commit().map_err(|e| io(&path, e))?;
        for (id, row) in robot_rows {
            self.robots.insert(id, (row, now));
        }
        for id in gone_robots {
            self.robots.remove(&id);
        }
        self.sources = source_rows;
        self.settings = Some(settings);
        self.next_source_id = next;
        self.reserved = reserved;
        Ok(true)
    }
}

/// The mailbox between the coordinator task and the writer thread.
#[derive(Debug, Default)]
struct Mailbox {
    record: Option<CoordinatorRecord>,
    stop: bool,
}

/// The writer thread of a [`StateStore`].
#[derive(Debug)]
pub struct StateWriter {
    shared: Arc<(Mutex<Mailbox>, Condvar)>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// What the writer reports after each snapshot: how long the write took, or its error.
pub type WriteReport = Box<dyn Fn(Result<Duration, String>) + Send>;

impl StateWriter {
    /// Starts the thread that writes the records given to [`StateWriter::submit`].
    pub fn spawn(mut store: StateStore, report: WriteReport) -> Result<Self, ServerError> {
        let shared = Arc::new((Mutex::new(Mailbox::default()), Condvar::new()));
        let inbox = shared.clone();
        let handle = std::thread::Builder::new()
            .name("state-writer".into())
            .spawn(move || {
                loop {
                    let (record, stop) = {
                        let (lock, cv) = &*inbox;
                        let mut m = lock.lock().unwrap_or_else(|p| p.into_inner());
                        while m.record.is_none() && !m.stop {
                            m = cv.wait(m).unwrap_or_else(|p| p.into_inner());
                        }
                        (m.record.take(), m.stop)
                    };
                    if let Some(r) = record {
                        let started = Instant::now();
                        match store.write(&r, stop) {
                            Ok(true) => report(Ok(started.elapsed())),
                            Ok(false) => {}
                            Err(e) => report(Err(e.to_string())),
                        }
                    }
                    if stop {
                        return;
                    }
                }
            })
            .map_err(|source| ServerError::Io { path: "<state-writer thread>".into(), source })?;
        Ok(StateWriter { shared, handle: Some(handle) })
    }

    /// Hands `record` to the writer, replacing one it has not written yet.
    pub fn submit(&self, record: CoordinatorRecord) {
        let (lock, cv) = &*self.shared;
        lock.lock().unwrap_or_else(|p| p.into_inner()).record = Some(record);
        cv.notify_one();
    }

    /// Writes `last` as the state of a clean stop and waits for the thread.
    pub fn finish(mut self, last: CoordinatorRecord) {
        {
            let (lock, cv) = &*self.shared;
            let mut m = lock.lock().unwrap_or_else(|p| p.into_inner());
            m.record = Some(last);
            m.stop = true;
            cv.notify_one();
        }
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for StateWriter {
    /// A writer dropped without [`StateWriter::finish`] writes what it holds and stops.
    fn drop(&mut self) {
        let (lock, cv) = &*self.shared;
        lock.lock().unwrap_or_else(|p| p.into_inner()).stop = true;
        cv.notify_one();
    }
}

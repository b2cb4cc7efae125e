//! ODAS out: the tracks this agent sends to the coordinator, also written in
//! ODAS's SST JSON (`[odas_out]`), so tools built for ODAS (odas_web,
//! odas_ros) show soundmap's DoAs.
//!
//! The format is ODAS's own, as the bridge reads it (see [`crate::odas`]):
//! one pretty-printed object per hop, concatenated; `timeStamp` counts the
//! agent's hops from 1; `src` holds a fixed number of slots (`slots`, ODAS's
//! `sst.N`, 4 by default), each `{ "id", "tag", "x", "y", "z", "activity" }`
//! with the direction in the array frame printed to 3 decimals, and empty
//! slots with id 0 and a zero vector. As in ODAS, a track keeps its slot for
//! its lifetime; when there are more tracks than slots, the most active fill
//! the free ones. Track ids are the agent's (from 1), tagged `dynamic`.
//!
//! Sinks: a file (written and flushed object by object, as ODAS's file sink
//! does, so a tool can follow it) and a TCP connection to a tool that listens
//! for SST (as ODAS's socket sink connects out). A tool already listening is
//! connected before the first hop; otherwise the connection is retried
//! every second. Objects produced while it is down or slow (more than 64
//! behind, as a file read `asap` easily is) are dropped
//! (counted in a rate-limited warning): a viewer wants the latest, and the
//! stream to the coordinator never waits for it.

use std::fmt::Write as _;
use std::io::Write as _;
use std::net::SocketAddr;
use std::time::Duration;

use soundmap_proto::{TrackedDoa, warn_limited};
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

use crate::config::OdasOutConfig;
use crate::{AgentError, WARNINGS};

/// Source slots per object by default (ODAS's `sst.N`).
pub const DEFAULT_SLOTS: usize = 4;
/// Most slots per object.
pub const MAX_SLOTS: usize = 64;
/// Wait between connection attempts.
pub const RECONNECT: Duration = Duration::from_secs(1);
/// Objects queued toward the socket (about half a second of hops).
const SOCKET_QUEUE: usize = 64;

/// Formats hops as SST objects, keeping each track in its slot.
#[derive(Debug)]
pub struct SstWriter {
    slots: Vec<Option<u64>>,
    hops: u64,
    text: String,
}

impl SstWriter {
    /// A writer with `slots` source slots per object.
    pub fn new(slots: usize) -> Self {
        SstWriter { slots: vec![None; slots.max(1)], hops: 0, text: String::new() }
    }

    /// The next hop's object (its `timeStamp` is the hop count, from 1).
    pub fn object(&mut self, doas: &[TrackedDoa]) -> &str {
        self.hops += 1;
        // Free the slots of tracks that are gone; place new tracks, most active first.
        for s in &mut self.slots {
            if s.is_some_and(|id| !doas.iter().any(|d| d.track_id == id)) {
                *s = None;
            }
        }
        let mut new: Vec<&TrackedDoa> =
            doas.iter().filter(|d| !self.slots.contains(&Some(d.track_id)) && d.track_id != 0).collect();
        new.sort_by(|a, b| b.activity.total_cmp(&a.activity));
        for d in new {
            match self.slots.iter_mut().find(|s| s.is_none()) {
                Some(free) => *free = Some(d.track_id),
                None => break,
            }
        }
        let t = &mut self.text;
        t.clear();
        let _ = write!(t, "{{\n    \"timeStamp\": {},\n    \"src\": [\n", self.hops);
        for (k, slot) in self.slots.iter().enumerate() {
            let sep = if k + 1 < self.slots.len() { "," } else { "" };
            match slot.and_then(|id| doas.iter().find(|d| d.track_id == id)) {
                Some(d) => {
                    let v = d.direction_in_array;
                    let _ = writeln!(
                        t,
                        "        {{ \"id\": {}, \"tag\": \"dynamic\", \"x\": {:.3}, \"y\": {:.3}, \"z\": {:.3}, \
                         \"activity\": {:.3} }}{sep}",
                        d.track_id, v.x, v.y, v.z, d.activity
                    );
                }
                None => {
                    let _ = writeln!(
                        t,
                        "        {{ \"id\": 0, \"tag\": \"\", \"x\": 0.000, \"y\": 0.000, \"z\": 0.000, \
                         \"activity\": 0.000 }}{sep}"
                    );
                }
            }
        }
        t.push_str("    ]\n}\n");
        &self.text
    }
}

/// The sinks of `[odas_out]`, opened (the file is created or truncated).
#[derive(Debug)]
pub struct OdasOut {
    writer: SstWriter,
    file: Option<(String, std::io::BufWriter<std::fs::File>)>,
    connect: Option<SocketAddr>,
    /// The connection made at start, when the tool was already listening.
    connected: Option<std::net::TcpStream>,
}

impl OdasOut {
    /// Creates the file, if any; errors name it.
    pub fn open(config: &OdasOutConfig) -> Result<Self, AgentError> {
        let file = match &config.file {
            Some(path) => {
                let f = std::fs::File::create(path)
                    .map_err(|source| AgentError::Io { path: path.clone(), source })?;
                Some((path.display().to_string(), std::io::BufWriter::new(f)))
            }
            None => None,
        };
        // A tool already listening is connected before the first hop, so it
        // sees every object from the first.
        let connected = config.connect.and_then(|addr| {
            std::net::TcpStream::connect_timeout(&addr, RECONNECT)
                .and_then(|s| s.set_nonblocking(true).map(|()| s))
                .inspect_err(|e| {
                    tracing::warn!("odas_out: cannot connect to {addr} ({e}); retrying every second")
                })
                .ok()
        });
        Ok(OdasOut { writer: SstWriter::new(config.slots), file, connect: config.connect, connected })
    }

    /// Writes every hop's tracks until `hops` closes (spawn it on the runtime).
    pub async fn run(mut self, mut hops: mpsc::Receiver<Vec<TrackedDoa>>) {
        let first = self.connected.take().and_then(|s| tokio::net::TcpStream::from_std(s).ok());
        let mut socket = self.connect.map(|addr| {
            let (tx, rx) = mpsc::channel::<String>(SOCKET_QUEUE);
            (addr, tx, tokio::spawn(serve_socket(addr, first, rx)))
        });
        while let Some(doas) = hops.recv().await {
            let object = self.writer.object(&doas);
            if let Some((name, f)) = &mut self.file
                && let Err(e) = f.write_all(object.as_bytes()).and_then(|()| f.flush())
            {
                warn_limited!(WARNINGS, "odas_out_file", "odas_out: {name}: {e}");
            }
            if let Some((addr, tx, _)) = &socket
                && tx.try_send(object.to_owned()).is_err()
            {
                warn_limited!(
                    WARNINGS,
                    "odas_out_dropped",
                    "odas_out: {addr} is not connected or not reading; SST objects dropped"
                );
            }
        }
        // The input has ended: what is queued toward the socket goes out first.
        if let Some((_, tx, task)) = socket.take() {
            drop(tx);
            let _ = tokio::time::timeout(RECONNECT, task).await;
        }
    }
}

/// Writes the objects to `addr` over `first`, else connecting (retrying every
/// [`RECONNECT`]).
async fn serve_socket(
    addr: SocketAddr,
    mut first: Option<tokio::net::TcpStream>,
    mut objects: mpsc::Receiver<String>,
) {
    let mut reported = first.is_none();
    loop {
        let connection = match first.take() {
            Some(s) => Ok(s),
            None => tokio::net::TcpStream::connect(addr).await,
        };
        let mut stream = match connection {
            Ok(s) => s,
            Err(e) => {
                if !reported {
                    tracing::warn!("odas_out: cannot connect to {addr} ({e}); retrying every second");
                    reported = true;
                }
                // Keep the queue fresh while nobody listens.
                let wait = tokio::time::sleep(RECONNECT);
                tokio::pin!(wait);
                loop {
                    tokio::select! {
                        _ = &mut wait => break,
                        o = objects.recv() => if o.is_none() { return },
                    }
                }
                continue;
            }
        };
        tracing::info!("odas_out: connected to {addr}");
        reported = false;
        while let Some(o) = objects.recv().await {
            if let Err(e) = stream.write_all(o.as_bytes()).await {
                tracing::warn!("odas_out: {addr}: {e}; reconnecting");
                break;
            }
        }
        if objects.is_closed() && objects.is_empty() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Unit, Vector3};

    use super::*;
    use crate::odas::{OdasTiming, SstParser};

    fn doa(id: u64, x: f64, y: f64, z: f64, activity: f64) -> TrackedDoa {
        TrackedDoa {
            track_id: id,
            direction_in_array: Unit::new_normalize(Vector3::new(x, y, z)),
            activity,
            angular_sigma_rad: Some(0.01),
            signature: None,
            coherence: None,
            floor_fit_range_m: None,
        }
    }

    #[test]
    fn objects_are_odas_sst_and_tracks_keep_their_slots() {
        let mut w = SstWriter::new(3);
        let a = w.object(&[]).to_owned();
        assert_eq!(
            a,
            "{\n    \"timeStamp\": 1,\n    \"src\": [\n\
             \x20       { \"id\": 0, \"tag\": \"\", \"x\": 0.000, \"y\": 0.000, \"z\": 0.000, \"activity\": 0.000 },\n\
             \x20       { \"id\": 0, \"tag\": \"\", \"x\": 0.000, \"y\": 0.000, \"z\": 0.000, \"activity\": 0.000 },\n\
             \x20       { \"id\": 0, \"tag\": \"\", \"x\": 0.000, \"y\": 0.000, \"z\": 0.000, \"activity\": 0.000 }\n\
             \x20   ]\n}\n"
        );
        let b = w.object(&[doa(5, 1.0, 0.0, 0.0, 0.4), doa(7, 0.0, 1.0, 0.0, 0.9)]).to_owned();
        let c = w.object(&[doa(5, 1.0, 0.0, 0.0, 0.4)]).to_owned();
        // Four tracks for three slots: 5 keeps slot 1 (the second), the most active new ones fill the rest.
        let d = w
            .object(&[
                doa(9, 0.0, 0.0, 1.0, 0.2),
                doa(5, 1.0, 0.0, 0.0, 0.4),
                doa(8, 0.6, 0.8, 0.0, 0.7),
                doa(3, 0.0, -1.0, 0.0, 0.5),
            ])
            .to_owned();
        // The bridge's own parser reads it back.
        let mut p = SstParser::new();
        let frames: Vec<_> =
            p.feed(format!("{a}{b}{c}{d}").as_bytes()).into_iter().map(Result::unwrap).collect();
        let ids = |k: usize| frames[k].src.iter().map(|s| s.id).collect::<Vec<_>>();
        assert_eq!(frames.iter().map(|f| f.time_stamp).collect::<Vec<_>>(), vec![1, 2, 3, 4]);
        assert_eq!(ids(1), vec![7, 5, 0]);
        assert_eq!(ids(2), vec![0, 5, 0]);
        assert_eq!(ids(3), vec![8, 5, 3]);
        assert!(!p.has_partial());
        let timing = OdasTiming { hop_len: 128, sample_rate_hz: 16_000, start: soundmap_proto::Stamp::ZERO };
        let f = frames[3].to_frame(&timing).unwrap();
        let v = f.doas[0].direction_in_array;
        assert!((v.x - 0.6).abs() < 1e-3 && (v.y - 0.8).abs() < 1e-3);
        assert!(b.contains(
            "\"id\": 7, \"tag\": \"dynamic\", \"x\": 0.000, \"y\": 1.000, \"z\": 0.000, \"activity\": 0.900 }"
        ));
    }
}

//! The live pose feed: JSON lines from a SLAM bridge, over a local TCP socket
//! (the agent listens, the bridge connects) or standard input.
//!
//! One JSON object per line, UTF-8, `\n`-terminated:
//!
//! ```json
//! {"stamp_ns": 1700000000123456789, "x": 1.0, "y": 2.0, "z": 0.0, "qx": 0.0, "qy": 0.0, "qz": 0.7071068, "qw": 0.7071068}
//! ```
//!
//! - `stamp_ns`: when the robot was at this pose, Unix nanoseconds (the fleet
//!   timebase; the bridge converts from its SLAM clock);
//! - `x`, `y`, `z`: position of the base in the map, metres;
//! - `qx`, `qy`, `qz`, `qw`: orientation of the base in the map (Hamilton, `qw`
//!   scalar), within 1e-2 of unit norm;
//! - `covariance` (optional): 36 values, row-major 6×6 over (x, y, z, rx, ry, rz),
//!   m², m·rad, rad² (the ROS `PoseWithCovariance` convention).
//!
//! Other fields are rejected so that typos do not pass silently. Stamps must
//! increase. A bad line is logged with its line number and skipped; the feed goes on.

use serde::{Deserialize, Serialize};
use soundmap_proto::{Stamp, wire};
use tokio::io::{AsyncBufRead, AsyncBufReadExt};
use tokio::net::TcpListener;
use tokio::sync::mpsc;

use super::{StampedPose, pose_from_components};
use crate::AgentError;

/// One line of the pose feed (see the module documentation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseLine {
    /// Unix nanoseconds.
    pub stamp_ns: i64,
    /// Position of the base in the map, metres.
    pub x: f64,
    /// Position of the base in the map, metres.
    pub y: f64,
    /// Position of the base in the map, metres.
    pub z: f64,
    /// Orientation quaternion, vector part.
    pub qx: f64,
    /// Orientation quaternion, vector part.
    pub qy: f64,
    /// Orientation quaternion, vector part.
    pub qz: f64,
    /// Orientation quaternion, scalar part.
    pub qw: f64,
    /// Optional 6×6 row-major covariance over (x, y, z, rx, ry, rz).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Vec<f64>>,
}

impl PoseLine {
    /// The line for a pose (for bridges and simulators written in Rust).
    pub fn from_pose(p: &StampedPose) -> Self {
        let t = p.map_from_base.translation.vector;
        let q = p.map_from_base.rotation.quaternion();
        PoseLine {
            stamp_ns: p.stamp.as_ns(),
            x: t.x,
            y: t.y,
            z: t.z,
            qx: q.i,
            qy: q.j,
            qz: q.k,
            qw: q.w,
            covariance: p.covariance.map(|c| (0..36).map(|k| c[(k / 6, k % 6)]).collect()),
        }
    }
}

/// Parses one feed line; errors are [`AgentError::Pose`] naming `source:line`.
pub fn parse_pose_line(line: &str, source_name: &str, line_no: u64) -> Result<StampedPose, AgentError> {
    let err = |message: String| AgentError::Pose { source_name: format!("{source_name}:{line_no}"), message };
    let l: PoseLine = serde_json::from_str(line).map_err(|e| err(format!("malformed pose line: {e}")))?;
    let map_from_base = pose_from_components([l.x, l.y, l.z], [l.qx, l.qy, l.qz, l.qw]).map_err(err)?;
    let covariance = match l.covariance {
        None => None,
        Some(values) => soundmap_proto::geometry::pose_covariance_from_wire(
            &Some(wire::PoseCovariance { values }),
            "covariance",
        )
        .map_err(|e| err(e.to_string()))?,
    };
    Ok(StampedPose { stamp: Stamp::from_ns(l.stamp_ns), map_from_base, covariance })
}

/// Counts of one feed connection.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FeedStats {
    /// Poses forwarded.
    pub poses: u64,
    /// Lines rejected (logged).
    pub rejected: u64,
}

/// Reads pose lines until the end of `reader` (or until `tx` is closed), sending
/// each valid pose to `tx`. Bad lines and non-increasing stamps are logged with
/// `name:line` and skipped.
pub async fn read_feed<R: AsyncBufRead + Unpin>(
    mut reader: R,
    name: &str,
    tx: &mpsc::Sender<StampedPose>,
) -> Result<FeedStats, AgentError> {
    let mut stats = FeedStats::default();
    let mut line = String::new();
    let mut line_no = 0u64;
    let mut last: Option<Stamp> = None;
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .await
            .map_err(|source| AgentError::Io { path: name.into(), source })?;
        if n == 0 {
            return Ok(stats);
        }
        line_no += 1;
        if line.trim().is_empty() {
            continue;
        }
        match parse_pose_line(line.trim_end(), name, line_no) {
            Ok(p) if last.is_some_and(|l| p.stamp <= l) => {
                stats.rejected += 1;
                tracing::warn!(
                    source = %format!("{name}:{line_no}"),
                    "pose stamp {} does not increase (previous {}); line skipped",
                    p.stamp,
                    last.unwrap_or_default()
                );
            }
            Ok(p) => {
                last = Some(p.stamp);
                stats.poses += 1;
                if tx.send(p).await.is_err() {
                    return Ok(stats);
                }
            }
            Err(e) => {
                stats.rejected += 1;
                soundmap_proto::warn_limited!(crate::WARNINGS, "pose_line", "{e}; line skipped");
            }
        }
    }
}

/// Accepts SLAM-bridge connections on `listener`, one at a time (a bridge that
/// reconnects is served again), and forwards their poses to `tx`. Returns when
/// `tx` is closed.
pub async fn serve_tcp(listener: TcpListener, tx: mpsc::Sender<StampedPose>) -> Result<(), AgentError> {
    let local = listener.local_addr().map(|a| a.to_string()).unwrap_or_else(|_| "pose socket".into());
    while !tx.is_closed() {
        let (stream, peer) = match listener.accept().await {
            Ok(accepted) => accepted,
            Err(e) => {
                // A failed accept (an aborted connection, no descriptor left) is not the end of the feed.
                soundmap_proto::warn_limited!(
                    crate::WARNINGS,
                    "pose_accept",
                    "{local}: cannot accept a connection: {e}; still listening"
                );
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        let name = format!("pose feed {peer}");
        tracing::info!("{name}: connected");
        match read_feed(tokio::io::BufReader::new(stream), &name, &tx).await {
            Ok(s) => tracing::info!("{name}: closed after {} poses ({} lines rejected)", s.poses, s.rejected),
            Err(e) => tracing::warn!("{e}"),
        }
    }
    Ok(())
}

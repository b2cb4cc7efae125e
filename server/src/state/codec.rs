//! Rows of the state store: JSON for the small records (sources, settings,
//! a robot's status), the robot's hello as its protobuf encoding (the
//! contract's own form, validated again when read back).

use nalgebra::{Isometry3, Matrix3, Point3, Quaternion, Translation3, UnitQuaternion};
use prost::Message;
use serde::{Deserialize, Serialize};
use soundmap_proto::{Hello, Limits, Stamp, wire};

use crate::coordinator::records::{RobotRecord, SettingsRecord, SourceRecord};

/// A source row.
#[derive(Debug, Serialize, Deserialize)]
pub struct SourceRow {
    id: u64,
    position_m: [f64; 3],
    covariance_m2: [f64; 9],
    first_heard_ns: i64,
    last_heard_ns: i64,
}

impl From<&SourceRecord> for SourceRow {
    fn from(r: &SourceRecord) -> Self {
        let p = r.position_in_map;
        let mut cov = [0.0; 9];
        cov.copy_from_slice(r.covariance.transpose().as_slice());
        SourceRow {
            id: r.id,
            position_m: [p.x, p.y, p.z],
            covariance_m2: cov,
            first_heard_ns: r.first_heard.as_ns(),
            last_heard_ns: r.last_heard.as_ns(),
        }
    }
}

impl SourceRow {
    /// The record, when its numbers are finite.
    pub fn record(&self) -> Option<SourceRecord> {
        if !self.position_m.iter().chain(&self.covariance_m2).all(|v| v.is_finite()) {
            return None;
        }
        let [x, y, z] = self.position_m;
        Some(SourceRecord {
            id: self.id,
            position_in_map: Point3::new(x, y, z),
            // Row-major in the row: read back as such.
            covariance: Matrix3::from_row_slice(&self.covariance_m2),
            first_heard: Stamp::from_ns(self.first_heard_ns),
            last_heard: Stamp::from_ns(self.last_heard_ns),
        })
    }
}

/// The operator's settings row.
#[derive(Debug, Serialize, Deserialize)]
pub struct SettingsRow {
    active_positioning: bool,
    theta_min_deg: f64,
    theta_max_deg: f64,
    focus_source_id: u64,
}

impl From<SettingsRecord> for SettingsRow {
    fn from(s: SettingsRecord) -> Self {
        SettingsRow {
            active_positioning: s.active_positioning,
            theta_min_deg: s.theta_min_deg,
            theta_max_deg: s.theta_max_deg,
            focus_source_id: s.focus_source_id,
        }
    }
}

impl From<SettingsRow> for SettingsRecord {
    fn from(s: SettingsRow) -> Self {
        SettingsRecord {
            active_positioning: s.active_positioning,
            theta_min_deg: s.theta_min_deg,
            theta_max_deg: s.theta_max_deg,
            focus_source_id: s.focus_source_id,
        }
    }
}

/// A robot's status (the part of its row besides its hello).
#[derive(Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotStatusRow {
    /// Tracker index.
    pub index: u32,
    /// Coordinator clock when last heard from (ns).
    pub last_seen_ns: i64,
    last_stamp_ns: Option<i64>,
    /// `[x, y, z, qx, qy, qz, qw]` of its last pose.
    pose: Option<[f64; 7]>,
    accepted: u64,
    rejected: u64,
}

/// A robot row: 4 bytes of hello length (LE), the hello's protobuf, the status JSON.
pub fn encode_robot(r: &RobotRecord) -> Vec<u8> {
    let hello = r.hello.to_wire().encode_to_vec();
    let status = RobotStatusRow {
        index: r.index,
        last_seen_ns: r.last_seen.as_ns(),
        last_stamp_ns: r.last_stamp.map(|s| s.as_ns()),
        pose: r.last_map_from_base.map(|p| {
            let (t, q) = (p.translation.vector, p.rotation.quaternion());
            [t.x, t.y, t.z, q.i, q.j, q.k, q.w]
        }),
        accepted: r.accepted,
        rejected: r.rejected,
    };
    let mut out = Vec::with_capacity(4 + hello.len() + 128);
    out.extend_from_slice(&(hello.len() as u32).to_le_bytes());
    out.extend_from_slice(&hello);
    serde_json::to_writer(&mut out, &status).expect("a plain struct serializes");
    out
}

/// The status part of a robot row, without decoding its hello.
pub fn robot_status(bytes: &[u8]) -> Option<RobotStatusRow> {
    let n = u32::from_le_bytes(bytes.get(..4)?.try_into().ok()?) as usize;
    serde_json::from_slice(bytes.get(4 + n..)?).ok()
}

/// A robot row read back; its hello is validated with `limits`.
pub fn decode_robot(bytes: &[u8], limits: &Limits) -> Result<RobotRecord, String> {
    let n =
        u32::from_le_bytes(bytes.get(..4).ok_or("short row")?.try_into().map_err(|_| "short row")?) as usize;
    let hello = bytes.get(4..4 + n).ok_or("short row")?;
    let hello = wire::Hello::decode(hello).map_err(|e| format!("hello: {e}"))?;
    let hello = Hello::from_wire(&hello, limits).map_err(|e| format!("hello: {e}"))?;
    let s = robot_status(bytes).ok_or("status: not valid JSON")?;
    let pose = match s.pose {
        Some([x, y, z, i, j, k, w]) if [x, y, z, i, j, k, w].iter().all(|v| v.is_finite()) => {
            let q = UnitQuaternion::from_quaternion(Quaternion::new(w, i, j, k));
            Some(Isometry3::from_parts(Translation3::new(x, y, z), q))
        }
        _ => None,
    };
    Ok(RobotRecord {
        hello,
        index: s.index,
        last_seen: Stamp::from_ns(s.last_seen_ns),
        last_stamp: s.last_stamp_ns.map(Stamp::from_ns),
        last_map_from_base: pose,
        accepted: s.accepted,
        rejected: s.rejected,
    })
}

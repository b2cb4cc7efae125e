//! What of the coordinator survives a restart, as plain data: the sources
//! (ids, positions, covariances, when heard), the robot registry, the
//! operator's settings and the next source id. [`super::Coordinator::export_state`]
//! takes it, [`super::Coordinator::restore_state`] puts it back, and
//! `crate::state` stores it.

use nalgebra::{Isometry3, Matrix3, Point3};
use soundmap_proto::{Hello, Stamp};

/// A source as remembered: where it was and how sure, and when it was heard.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceRecord {
    /// Its id (never given to another source).
    pub id: u64,
    /// Last position, map frame (m).
    pub position_in_map: Point3<f64>,
    /// Its covariance (m²); zero when unknown.
    pub covariance: Matrix3<f64>,
    /// First heard (acoustic stamp).
    pub first_heard: Stamp,
    /// Last heard (acoustic stamp).
    pub last_heard: Stamp,
}

/// A known robot.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotRecord {
    /// Its hello (identity, array, software).
    pub hello: Hello,
    /// Its index for the trackers.
    pub index: u32,
    /// Coordinator clock when last heard from.
    pub last_seen: Stamp,
    /// Stamp of its last accepted observation.
    pub last_stamp: Option<Stamp>,
    /// Pose at that observation.
    pub last_map_from_base: Option<Isometry3<f64>>,
    /// Observations accepted since it was first seen.
    pub accepted: u64,
    /// Observations rejected since it was first seen.
    pub rejected: u64,
}

/// The operator's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SettingsRecord {
    /// Active positioning on or off.
    pub active_positioning: bool,
    /// The θ band's lower edge (degrees).
    pub theta_min_deg: f64,
    /// The θ band's upper edge (degrees).
    pub theta_max_deg: f64,
    /// The source active positioning serves; 0: all.
    pub focus_source_id: u64,
}

/// Everything that survives a restart.
#[derive(Clone, Debug, PartialEq)]
pub struct CoordinatorRecord {
    /// The next source id to give (every id below it was given).
    pub next_source_id: u64,
    /// The operator's settings.
    pub settings: SettingsRecord,
    /// Sources, live and remembered.
    pub sources: Vec<SourceRecord>,
    /// Known robots.
    pub robots: Vec<RobotRecord>,
}

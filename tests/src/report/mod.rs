//! Reports of a run: `timeline.csv`, `theta_bins.csv`, `summary.json`, plots.

pub mod record;

pub use record::{RobotPath, RoomOutline, RunRecord, TimelineRow};

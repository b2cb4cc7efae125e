//! Simulated ground robots: how the microphone arrays move.
//!
//! - [`diff_drive`]: differential-drive kinematics with limits, fixed time step.
//! - [`steering`]: turn-then-drive steering toward a point or heading.
//! - [`waypoints`]: following timed or untimed waypoints.
//! - [`navigator`]: driving to a commanded goal pose, with progress and arrival.
//! - [`trajectory`]: sampled trajectories, interpolated at any time.
//!
//! Poses are `map_from_base` (base x forward, y left, z up; ground robots at
//! z = 0); internally a planar [`Pose2`]. Time is simulated seconds.

pub mod diff_drive;
pub mod navigator;
pub mod steering;
pub mod trajectory;
pub mod waypoints;

pub use diff_drive::{DiffDriveRobot, DriveLimits, Pose2, Twist, wrap_angle};
pub use navigator::{NavProgress, Navigator, NavigatorConfig};
pub use steering::SteeringConfig;
pub use trajectory::SampledTrajectory;
pub use waypoints::{FollowStatus, FollowerConfig, Waypoint, WaypointFollower};

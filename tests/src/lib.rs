//! soundmap simulation and replay: the whole system exercised and measured
//! the way the published trials measured it.
//!
//! - [`acoustics`]: shoebox rooms, image-source impulse responses, source signals,
//!   sensor and diffuse noise, moving sources and arrays.
//! - [`kinematics`]: differential-drive robots, waypoint trajectories, a navigator.
//! - [`slam_noise`]: the pose error a SLAM system adds (noise and slow drift).
//! - [`scenario`]: scenarios in TOML, and the built-in ones.
//! - [`runner`]: a scenario end to end over gRPC in simulated time.
//! - [`pytools`]: the Python client libraries the system tests drive soundmap with.
//! - [`replay`]: recorded trials (audio + poses + truth) through the same code path.
//! - [`rosbag`]: ROS 2 bags (MCAP, CDR: audio_common audio, tf) converted for the replay.
//! - [`viewer`]: the Foxglove live view, MCAP recording and real-time pacing of a run.
//! - [`mcap_replay`]: a coordinator re-run on the observations of an MCAP recording.
//! - [`live_check`]: a logging coordinator for tests of the live agent against the replay.
//! - [`report`]: what a run records, and its CSV/JSON reports and plots.
//! - [`error`]: the crate's error enum, [`SimError`].

pub mod acoustics;
pub mod error;
pub mod kinematics;
pub mod live_check;
pub mod mcap_replay;
pub mod odas_like;
pub mod pytools;
pub mod replay;
pub mod report;
pub mod rosbag;
pub mod runner;
pub mod scenario;
pub mod slam_noise;
pub mod viewer;

pub use error::SimError;

//! soundmap coordinator: turns robots' bearings into source positions in the
//! shared map, with honest uncertainty, and keeps the robots in a good geometry.
//!
//! Pure core (no sockets, files or clocks; fed `(now, input)`):
//! - [`ray`]: bearing rays in the map frame from a DoA and a pose.
//! - [`triangulation`]: the paper's ray pair, weighted N-ray least squares,
//!   Levenberg–Marquardt refinement, gate decisions.
//! - [`uncertainty`]: Fisher information, covariance, GDOP, θ, conditioning.
//! - [`stats`]: χ² quantiles for gates.
//! - [`tracking`]: 3D constant-velocity Kalman tracking of a source from DoAs.
//! - [`association`]: which rays belong to which source (assignment, births).
//! - [`planner`]: where robots should go to keep θ in band (Clarabel).
//! - [`coordinator`]: the state machine tying robots, alignment and estimates together.
//!
//! Shell:
//! - [`service`]: the gRPC services (robot link, monitoring, health) around one
//!   task that owns the [`coordinator::Coordinator`].
//! - [`config`]: `coordinator.toml`. [`clock`]: system or driven time.
//! - [`error`]: the crate's error type.

pub mod association;
pub mod clock;
pub mod config;
pub mod coordinator;
pub mod error;
pub mod floor_image;
pub mod loadgen;
pub mod planner;
pub mod ray;
pub mod resources;
pub mod service;
pub mod state;
pub mod stats;
pub mod tls;
pub mod tracking;
pub mod triangulation;
pub mod uncertainty;
pub mod viz;

pub use config::CoordinatorConfig;
pub use error::ServerError;
pub use ray::Ray;
pub use triangulation::{Triangulation, TriangulationConfig, triangulate, triangulate_from};

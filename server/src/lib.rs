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
//! - [`planner`]: where robots should go to keep θ in band (Clarabel).

pub mod planner;
pub mod ray;
pub mod stats;
pub mod tracking;
pub mod triangulation;
pub mod uncertainty;

pub use ray::Ray;
pub use triangulation::{Triangulation, TriangulationConfig, triangulate};

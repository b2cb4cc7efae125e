//! The coordinator's integration tests, one module per file beside this one
//! (`cargo test -p soundmap-server --test integration MODULE::`).
//!
//! They are one test binary, not one per file: each binary links the whole
//! gRPC stack and instantiates its generic code again, which made the
//! suite's build several minutes longer on two cores.

mod common;

mod bounds;
mod chaos;
mod config_files;
mod coordinator;
mod planner;
mod security_auth;
mod security_contract;
mod security_fuzz;
mod security_tls;
mod service_bad_input;
mod service_estimates;
mod service_limits;
mod service_liveness;
mod service_positioning;
mod service_signatures;
mod service_sources;
mod service_tracking;
mod sound_map;
mod tracking;
mod triangulation;

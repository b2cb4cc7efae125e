//! The robot agent's integration tests, one module per file beside this one
//! (`cargo test -p soundmap-agent --test integration MODULE::`).
//!
//! They are one test binary, not one per file: each binary links the whole
//! agent and its gRPC link again, which made the suite's build minutes
//! longer on two cores.

#[path = "data/synth.rs"]
mod synth;

mod array_files;
mod audio_input;
mod cli;
mod free_field;
mod fuzz_parsers;
mod link;
mod odas_bridge;
mod pose_input;
mod signatures;
mod tls;
mod tracking;

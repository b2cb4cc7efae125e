//! soundmap robot agent: hears directions of arrival on board and streams
//! them, with the robot's SLAM pose, to the coordinator.
//!
//! Pure core (no sockets, files or clocks):
//! - [`mod@array`]: microphone array geometry, presets, TOML files.
//! - [`stft`]: framing, windowing and real FFTs of multichannel audio.
//! - [`srp`]: SRP-PHAT on a hierarchical sphere grid with sub-grid refinement.
//! - [`doa_tracker`]: Kalman tracking of DoAs on the sphere (ids, activity).
//! - [`signature`]: per-track spectral signatures (band energies of the array steered at each track).
//! - [`pipeline`]: STFT → SRP-PHAT → tracker → signatures, one hop at a time, allocation-free.
//!
//! - [`agent`]: the agent core: hops and poses in; observations, command
//!   replies and navigation goals out (no I/O; the live agent, the simulator and
//!   the replay all drive it).
//!
//! Shell:
//! - [`audio`]: WAV, raw PCM, standard input and live capture, stamped blocks.
//! - [`pose`]: TUM trajectories and live pose feeds, interpolation at a stamp.
//! - [`odas`]: DoAs from a running ODAS (SST JSON) instead of our own localization.
//! - [`link`]: the gRPC stream to the coordinator (reconnection, bounded buffer).
//! - [`navigator`]: executes reposition commands.
//! - [`live`]: the live agent (`soundmap-agent run`) around the core.
//! - [`localize`]: the pipeline over a recording, one JSON line per hop.
//! - [`config`] — the agent configuration file, `agent.toml`.

pub mod agent;
pub mod array;
pub mod audio;
pub mod config;
pub mod doa_tracker;
pub mod error;
mod fastmath;
pub mod link;
pub mod live;
pub mod localize;
pub mod navigator;
pub mod odas;
pub mod pipeline;
pub mod pose;
pub mod signature;
mod simd;
pub mod srp;
pub mod stft;

pub use error::AgentError;

/// The agent's rate-limited warnings (one line per kind per 10 s, with the
/// count of those folded into it): a flood of bad input cannot flood the log.
pub(crate) static WARNINGS: std::sync::LazyLock<soundmap_proto::ratelog::RateLog> =
    std::sync::LazyLock::new(|| soundmap_proto::ratelog::RateLog::new(std::time::Duration::from_secs(10)));

//! `agent.toml`: the agent's configuration, parsed with unknown fields rejected
//! and validated before anything starts. Every error is an
//! [`AgentError::Config`] naming the file and the dotted field
//! (`agent.toml: audio.channels: …`).
//!
//! Relative paths in the file are relative to the file's directory.
//! See `deploy/agent.example.toml` for every section and field.

mod file;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use soundmap_proto::{RobotId, Stamp};

use crate::AgentError;
use crate::audio::AudioInput;
use crate::link::LinkConfig;
use crate::pipeline::PipelineConfig;
use crate::pose::PoseBufferConfig;

/// A validated agent configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct AgentConfig {
    /// The file it came from.
    pub path: PathBuf,
    /// This robot's identity.
    pub robot_id: RobotId,
    /// Where the coordinator is.
    pub coordinator: CoordinatorConfig,
    /// Array preset name or path to an array `.toml` (resolved against the config's directory).
    pub array: String,
    /// Where the DoAs come from.
    pub doa: DoaSource,
    /// Where the poses come from.
    pub pose: PoseConfig,
    /// Reposition commands.
    pub navigator: NavigatorConfig,
    /// Link settings (endpoint and token from `coordinator`).
    pub link: LinkConfig,
    /// This robot's tracks in ODAS's SST JSON, for ODAS tools (`[odas_out]`).
    pub odas_out: Option<OdasOutConfig>,
}

/// `[odas_out]`: the tracks the agent sends, also written as ODAS's SST JSON
/// (see [`crate::odas::out`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OdasOutConfig {
    /// Connect to a tool that listens for SST (odas_web, odas_ros), as ODAS's socket sink does.
    pub connect: Option<SocketAddr>,
    /// Write SST objects to this file, as ODAS's file sink does.
    pub file: Option<PathBuf>,
    /// Source slots per object (ODAS's `sst.N`), empty ones with id 0.
    pub slots: usize,
}

/// `[coordinator]`.
#[derive(Clone, Debug, PartialEq)]
pub struct CoordinatorConfig {
    /// gRPC endpoint, `http://host:port` or `https://…`.
    pub endpoint: String,
    /// Bearer token (from `token` or the contents of `token_file`).
    pub token: Option<String>,
    /// TLS settings (`ca_file`, optional `cert_file` + `key_file`, `tls_domain`), required for `https://`.
    pub tls: Option<crate::link::ClientTls>,
}

/// Where tracked DoAs come from.
#[derive(Clone, Debug, PartialEq)]
pub enum DoaSource {
    /// Our own localization: audio through the DSP pipeline.
    Own {
        /// The audio.
        audio: AudioConfig,
        /// STFT / SRP-PHAT / tracker settings (`[pipeline]`).
        pipeline: PipelineConfig,
    },
    /// A running ODAS's SST output.
    Odas(OdasConfig),
}

/// `[audio]`.
#[derive(Clone, Debug, PartialEq)]
pub struct AudioConfig {
    /// The input.
    pub input: AudioInput,
    /// Input channel of each array microphone, when not the identity.
    pub channel_map: Option<Vec<usize>>,
    /// Time of sample 0; `None`: when the agent starts reading (`realtime`),
    /// or so that the file ends then (`asap`: no stamp runs ahead of the clock).
    pub start: Option<Stamp>,
    /// For files: feed blocks at the pace of their stamps (`true`) or as fast as possible.
    pub realtime: bool,
}

/// `[doa]` with `source = "odas"`.
#[derive(Clone, Debug, PartialEq)]
pub struct OdasConfig {
    /// Socket ODAS's tracked sink connects to, or its output file.
    pub input: OdasInput,
    /// ODAS's `general.size.hopSize`, samples.
    pub hop_len: u32,
    /// ODAS's `general.samplerate.mu`, Hz.
    pub sample_rate_hz: u32,
    /// Time of ODAS's first sample; `None`: see [`crate::odas`]'s clock rule
    /// (socket and followed file: anchored to the agent's clock when objects
    /// first arrive; file read `realtime`: the agent's start; `asap`: placed so
    /// that the recording ends when the agent starts).
    pub start: Option<Stamp>,
    /// For a file that is not followed: send hops at the pace of their stamps
    /// (`true`) or as fast as possible (`pace = "asap"`).
    pub realtime: bool,
}

/// Where ODAS's SST JSON comes from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OdasInput {
    /// Listen on this address (ODAS connects to it).
    Listen(SocketAddr),
    /// Read a file written by ODAS's file sink.
    File {
        /// The file.
        path: PathBuf,
        /// Keep reading as ODAS appends to it (`follow = true`), until stopped.
        follow: bool,
    },
}

/// `[pose]`.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseConfig {
    /// Where poses come from.
    pub source: PoseSource,
    /// Buffer limits.
    pub buffer: PoseBufferConfig,
    /// How long a DoA frame waits for the pose at its stamp, seconds.
    pub max_wait_s: f64,
}

/// Where poses come from.
#[derive(Clone, Debug, PartialEq)]
pub enum PoseSource {
    /// A TUM trajectory replayed with the audio.
    Tum {
        /// The file.
        path: PathBuf,
        /// Time of audio sample 0 in the file's clock, seconds; `None`: file times are Unix seconds.
        start_s: Option<f64>,
    },
    /// JSON lines from a SLAM bridge that connects to this address.
    JsonlTcp(SocketAddr),
    /// JSON lines on standard input.
    JsonlStdin,
}

/// `[navigator]`.
#[derive(Clone, Debug, PartialEq)]
pub struct NavigatorConfig {
    /// Where goals are written as JSON lines (`-`: standard output).
    pub path: PathBuf,
    /// Distance to the goal at which a command counts as done, metres.
    pub arrival_tolerance_m: f64,
    /// The base's speed and turn rate (`max_speed_m_per_s`,
    /// `max_turn_rate_deg_per_s`), declared in the hello so that the
    /// coordinator plans each robot's goals for its own base.
    pub base_limits: soundmap_proto::BaseLimits,
}

impl AgentConfig {
    /// Reads and validates `path`.
    pub fn load(path: &Path) -> Result<Self, AgentError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| AgentError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses and validates `text`; `path` names the file in errors and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Self, AgentError> {
        let raw: file::AgentFile = from_toml(text, path)?;
        raw.validate(path)
    }
}

/// Reads a pipeline settings file (the fields of `[pipeline]` at top level), for
/// `soundmap-agent localize --pipeline FILE`. Errors name the file and field.
pub fn load_pipeline(path: &Path) -> Result<PipelineConfig, AgentError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| AgentError::Io { path: path.to_path_buf(), source })?;
    from_toml(&text, path)
}

/// Deserializes TOML `text` (from the file `path`) into `T`. A syntax error names
/// the key at its position; a type error names the dotted key through
/// `serde_path_to_error` (`audio.channels`, `microphones[3].position_m`); a missing
/// key is named itself, with the message `missing`.
pub(crate) fn from_toml<T: serde::de::DeserializeOwned>(text: &str, path: &Path) -> Result<T, AgentError> {
    let de = toml::Deserializer::parse(text).map_err(|e| {
        let field = e.span().map(|s| field_at(text, s.start)).filter(|f| !f.is_empty());
        config_error(path, field.as_deref().unwrap_or("(document)"), e.message().trim())
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let at = e.path().to_string();
        let message = e.into_inner().message().trim().replace('\n', " ");
        let (field, message) = match missing_field(&message) {
            Some(key) if at == "." || at.is_empty() => (key.to_owned(), "missing".to_owned()),
            Some(key) => (format!("{at}.{key}"), "missing".to_owned()),
            None if at == "." => ("(document)".to_owned(), message),
            None => (at, message),
        };
        config_error(path, &field, message)
    })
}

/// The key named by serde's "missing field `KEY`" message.
fn missing_field(message: &str) -> Option<&str> {
    message.strip_prefix("missing field `")?.split('`').next()
}

pub(crate) fn config_error(path: &Path, field: &str, message: impl Into<String>) -> AgentError {
    AgentError::Config { path: path.to_path_buf(), field: field.to_owned(), message: message.into() }
}

/// The dotted key at byte `offset` of a TOML text: the enclosing `[table]` header
/// and the key on that line (or just the table when `offset` is on its header).
fn field_at(text: &str, offset: usize) -> String {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next().unwrap_or("");
    let header = |l: &str| {
        let l = l.trim();
        l.starts_with('[')
            .then(|| l.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_owned())
    };
    if let Some(h) = header(line) {
        return h;
    }
    let table = text[..line_start].lines().rev().find_map(header);
    let key = line.split('=').next().unwrap_or("").trim().trim_matches('"');
    match (table, key.is_empty()) {
        (Some(t), false) => format!("{t}.{key}"),
        (Some(t), true) => t,
        (None, _) => key.to_owned(),
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod field_tests {
    use super::*;

    #[test]
    fn field_paths_from_offsets() {
        let t = "robot_id = \"a\"\n[audio]\nsource = \"wav\"\nchannels = 3\n[pipeline.srp]\nfoo = 1\n";
        assert_eq!(field_at(t, 3), "robot_id");
        assert_eq!(field_at(t, t.find("[audio]").unwrap() + 1), "audio");
        assert_eq!(field_at(t, t.find("3").unwrap()), "audio.channels");
        assert_eq!(field_at(t, t.find("foo").unwrap()), "pipeline.srp.foo");
    }
}

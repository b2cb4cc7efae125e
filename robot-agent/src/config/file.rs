//! The file form of `agent.toml` (serde, unknown fields rejected) and its validation.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;
use soundmap_proto::{BaseLimits, RobotId, Stamp};

use super::{
    AgentConfig, AudioConfig, CoordinatorConfig, DoaSource, NavigatorConfig, OdasConfig, OdasInput,
    OdasOutConfig, PoseConfig, PoseSource, config_error,
};
use crate::AgentError;
use crate::audio::{AudioInput, RawFormat, RawLayout};
use crate::link::LinkConfig;
use crate::pipeline::PipelineConfig;
use crate::pose::PoseBufferConfig;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AgentFile {
    robot_id: String,
    coordinator: CoordinatorFile,
    array: ArrayFile,
    #[serde(default)]
    audio: Option<AudioFile>,
    pose: PoseFile,
    #[serde(default)]
    doa: DoaFile,
    #[serde(default)]
    pipeline: PipelineConfig,
    #[serde(default)]
    navigator: NavigatorFile,
    #[serde(default)]
    link: LinkFile,
    #[serde(default)]
    odas_out: Option<OdasOutFile>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct OdasOutFile {
    connect: Option<String>,
    file: Option<PathBuf>,
    slots: Option<usize>,
}

impl OdasOutFile {
    fn validate(self, c: &Check) -> Result<OdasOutConfig, AgentError> {
        if self.connect.is_none() && self.file.is_none() {
            return Err(c.err("odas_out", "give `connect = \"host:port\"`, `file = \"PATH\"` or both"));
        }
        let connect = self.connect.map(|a| c.socket(&a, "odas_out.connect")).transpose()?;
        let slots = self.slots.unwrap_or(crate::odas::out::DEFAULT_SLOTS);
        if !(1..=crate::odas::out::MAX_SLOTS).contains(&slots) {
            return Err(c.err(
                "odas_out.slots",
                format!("{slots}: must be 1 to {} (ODAS's sst.N, 4 by default)", crate::odas::out::MAX_SLOTS),
            ));
        }
        Ok(OdasOutConfig { connect, file: self.file.map(|f| c.resolve(f)), slots })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CoordinatorFile {
    endpoint: String,
    token: Option<String>,
    token_file: Option<PathBuf>,
    ca_file: Option<PathBuf>,
    cert_file: Option<PathBuf>,
    key_file: Option<PathBuf>,
    tls_domain: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArrayFile {
    preset: Option<String>,
    file: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum AudioKind {
    Wav,
    Raw,
    Stdin,
    Live,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum Pace {
    #[default]
    Realtime,
    Asap,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AudioFile {
    source: AudioKind,
    path: Option<PathBuf>,
    format: Option<RawFormat>,
    channels: Option<usize>,
    sample_rate_hz: Option<u32>,
    device: Option<String>,
    channel_map: Option<Vec<usize>>,
    start_ns: Option<i64>,
    #[serde(default)]
    pace: Pace,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum PoseKind {
    Tum,
    JsonlTcp,
    JsonlStdin,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseFile {
    source: PoseKind,
    path: Option<PathBuf>,
    start_s: Option<f64>,
    listen: Option<String>,
    capacity: Option<usize>,
    max_gap_s: Option<f64>,
    extrapolation_tolerance_s: Option<f64>,
    max_wait_s: Option<f64>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum DoaKind {
    #[default]
    Own,
    Odas,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct DoaFile {
    #[serde(default)]
    source: DoaKind,
    listen: Option<String>,
    file: Option<PathBuf>,
    hop_len: Option<u32>,
    sample_rate_hz: Option<u32>,
    start_ns: Option<i64>,
    pace: Option<Pace>,
    follow: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct NavigatorFile {
    path: PathBuf,
    arrival_tolerance_m: f64,
    max_speed_m_per_s: Option<f64>,
    max_turn_rate_deg_per_s: Option<f64>,
}

impl Default for NavigatorFile {
    fn default() -> Self {
        NavigatorFile {
            path: PathBuf::from("-"),
            arrival_tolerance_m: 0.25,
            max_speed_m_per_s: None,
            max_turn_rate_deg_per_s: None,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct LinkFile {
    buffer_capacity: usize,
    heartbeat_interval_ms: u64,
    backoff_initial_ms: u64,
    backoff_max_ms: u64,
    connect_timeout_ms: u64,
}

impl Default for LinkFile {
    fn default() -> Self {
        let d = LinkConfig::new("");
        LinkFile {
            buffer_capacity: d.buffer_capacity,
            heartbeat_interval_ms: d.heartbeat_interval.as_millis() as u64,
            backoff_initial_ms: d.backoff_initial.as_millis() as u64,
            backoff_max_ms: d.backoff_max.as_millis() as u64,
            connect_timeout_ms: d.connect_timeout.as_millis() as u64,
        }
    }
}

/// Checks a field against a rule; errors name the file and field.
struct Check<'a> {
    path: &'a Path,
    dir: PathBuf,
}

impl Check<'_> {
    fn err(&self, field: &str, message: impl Into<String>) -> AgentError {
        config_error(self.path, field, message)
    }

    fn required<T>(&self, v: Option<T>, field: &str, when: &str) -> Result<T, AgentError> {
        v.ok_or_else(|| self.err(field, format!("required when {when}")))
    }

    fn absent<T>(&self, v: &Option<T>, field: &str, when: &str) -> Result<(), AgentError> {
        match v {
            Some(_) => Err(self.err(field, format!("not used when {when}; remove it"))),
            None => Ok(()),
        }
    }

    /// Relative paths are relative to the config file's directory (`-` stays `-`).
    fn resolve(&self, p: PathBuf) -> PathBuf {
        if p.is_absolute() || p == Path::new("-") { p } else { self.dir.join(p) }
    }

    fn socket(&self, s: &str, field: &str) -> Result<SocketAddr, AgentError> {
        s.parse().map_err(|_| self.err(field, format!("{s:?} is not an address like 127.0.0.1:9000")))
    }

    fn stamp(&self, ns: Option<i64>, field: &str) -> Result<Option<Stamp>, AgentError> {
        match ns {
            Some(ns) if ns < 0 => {
                Err(self.err(field, format!("{ns}: stamps are Unix nanoseconds, not negative")))
            }
            other => Ok(other.map(Stamp::from_ns)),
        }
    }
}

impl AgentFile {
    pub(super) fn validate(self, path: &Path) -> Result<AgentConfig, AgentError> {
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let c = Check { path, dir };
        let robot_id = RobotId::parse(&self.robot_id, "robot_id")
            .map_err(|e| c.err("robot_id", e.problem.to_string()))?;
        let coordinator = self.coordinator.validate(&c)?;
        let array = match (self.array.preset, self.array.file) {
            (Some(p), None) => p,
            (None, Some(f)) => c.resolve(f).display().to_string(),
            (Some(_), Some(_)) => return Err(c.err("array", "give either `preset` or `file`, not both")),
            (None, None) => return Err(c.err("array", "give `preset = \"NAME\"` or `file = \"ARRAY.toml\"`")),
        };
        let pose = self.pose.validate(&c)?;
        let doa = match self.doa.source {
            DoaKind::Own => {
                for (v, f) in [
                    (self.doa.listen.is_some(), "doa.listen"),
                    (self.doa.file.is_some(), "doa.file"),
                    (self.doa.pace.is_some(), "doa.pace"),
                    (self.doa.follow.is_some(), "doa.follow"),
                ] {
                    if v {
                        return Err(c.err(f, "only for doa.source = \"odas\""));
                    }
                }
                let audio = self.audio.ok_or_else(|| c.err("audio", "required when doa.source = \"own\""))?;
                DoaSource::Own { audio: audio.validate(&c, &self.pipeline)?, pipeline: self.pipeline }
            }
            DoaKind::Odas => {
                if self.audio.is_some() {
                    return Err(c.err(
                        "audio",
                        "not used when doa.source = \"odas\" (ODAS reads the audio); remove it",
                    ));
                }
                DoaSource::Odas(self.doa.validate_odas(&c, &pose)?)
            }
        };
        if pose.source == PoseSource::JsonlStdin
            && matches!(&doa, DoaSource::Own { audio, .. } if matches!(audio.input, AudioInput::Stdin { .. }))
        {
            return Err(c.err(
                "pose.source",
                "jsonl_stdin cannot share standard input with audio.source = \"stdin\"",
            ));
        }
        if !(self.navigator.arrival_tolerance_m.is_finite() && self.navigator.arrival_tolerance_m > 0.0) {
            return Err(c.err("navigator.arrival_tolerance_m", "must be positive"));
        }
        let limit = |v: Option<f64>, field: &str, max: f64, unit: &str| match v {
            Some(v) if !(v > 0.0 && v <= max) => {
                Err(c.err(field, format!("must be in (0, {max}] {unit}, is {v}")))
            }
            v => Ok(v),
        };
        let base_limits = BaseLimits {
            max_speed_m_per_s: limit(
                self.navigator.max_speed_m_per_s,
                "navigator.max_speed_m_per_s",
                BaseLimits::MAX_SPEED_M_PER_S,
                "m/s",
            )?,
            max_turn_rate_deg_per_s: limit(
                self.navigator.max_turn_rate_deg_per_s,
                "navigator.max_turn_rate_deg_per_s",
                BaseLimits::MAX_TURN_RATE_DEG_PER_S,
                "degrees/s",
            )?,
        };
        let navigator = NavigatorConfig {
            path: c.resolve(self.navigator.path),
            arrival_tolerance_m: self.navigator.arrival_tolerance_m,
            base_limits,
        };
        let link = self.link.validate(&c, &coordinator)?;
        let odas_out = self.odas_out.map(|o| o.validate(&c)).transpose()?;
        Ok(AgentConfig {
            path: path.to_path_buf(),
            robot_id,
            coordinator,
            array,
            doa,
            pose,
            navigator,
            link,
            odas_out,
        })
    }
}

impl CoordinatorFile {
    fn validate(self, c: &Check) -> Result<CoordinatorConfig, AgentError> {
        let ok_scheme = self.endpoint.starts_with("http://") || self.endpoint.starts_with("https://");
        if !ok_scheme || tonic::transport::Endpoint::from_shared(self.endpoint.clone()).is_err() {
            return Err(c.err(
                "coordinator.endpoint",
                format!("{:?} is not a URL like http://10.0.0.2:50051", self.endpoint),
            ));
        }
        let token = match (self.token, self.token_file) {
            (Some(_), Some(_)) => {
                return Err(c.err("coordinator.token_file", "give either `token` or `token_file`, not both"));
            }
            (Some(t), None) => Some(t),
            (None, Some(f)) => {
                let f = c.resolve(f);
                let t = std::fs::read_to_string(&f)
                    .map_err(|e| c.err("coordinator.token_file", format!("{}: {e}", f.display())))?;
                Some(t.trim().to_owned())
            }
            (None, None) => None,
        };
        if token.as_ref().is_some_and(|t| t.is_empty() || t.chars().any(|ch| ch.is_control())) {
            return Err(c.err("coordinator.token", "must be non-empty printable text"));
        }
        let tls = match self.ca_file {
            Some(ca) => Some(
                crate::link::ClientTls::from_files(
                    &c.resolve(ca),
                    self.cert_file.map(|f| c.resolve(f)).as_deref(),
                    self.key_file.map(|f| c.resolve(f)).as_deref(),
                    self.tls_domain,
                )
                .map_err(|(field, message)| c.err(field, message))?,
            ),
            None => {
                for (field, set) in [
                    ("coordinator.cert_file", self.cert_file.is_some()),
                    ("coordinator.key_file", self.key_file.is_some()),
                    ("coordinator.tls_domain", self.tls_domain.is_some()),
                ] {
                    if set {
                        return Err(c.err(field, "needs coordinator.ca_file (TLS settings)"));
                    }
                }
                None
            }
        };
        crate::link::tls::check_scheme(&self.endpoint, tls.as_ref()).map_err(|m| {
            c.err(if tls.is_some() { "coordinator.endpoint" } else { "coordinator.ca_file" }, m)
        })?;
        Ok(CoordinatorConfig { endpoint: self.endpoint, token, tls })
    }
}

impl AudioFile {
    fn validate(self, c: &Check, pipeline: &PipelineConfig) -> Result<AudioConfig, AgentError> {
        let when = |k: &str| format!("audio.source = \"{k}\"");
        let layout = |c: &Check, f: &AudioFile, k: &str| -> Result<RawLayout, AgentError> {
            let rate = c.required(f.sample_rate_hz, "audio.sample_rate_hz", &when(k))?;
            if rate != pipeline.sample_rate_hz {
                return Err(c.err(
                    "audio.sample_rate_hz",
                    format!(
                        "{rate} Hz does not match pipeline.sample_rate_hz = {} Hz",
                        pipeline.sample_rate_hz
                    ),
                ));
            }
            let channels = c.required(f.channels, "audio.channels", &when(k))?;
            if channels == 0 {
                return Err(c.err("audio.channels", "must be at least 1"));
            }
            Ok(RawLayout {
                format: c.required(f.format, "audio.format", &when(k))?,
                channels,
                sample_rate_hz: rate,
            })
        };
        let input = match self.source {
            AudioKind::Wav => {
                for (v, f) in [
                    (self.format.is_some(), "audio.format"),
                    (self.channels.is_some(), "audio.channels"),
                    (self.sample_rate_hz.is_some(), "audio.sample_rate_hz"),
                ] {
                    if v {
                        return Err(c.err(f, "not used for WAV files (their header says it); remove it"));
                    }
                }
                c.absent(&self.device, "audio.device", &when("wav"))?;
                AudioInput::Wav {
                    path: c.resolve(c.required(self.path.clone(), "audio.path", &when("wav"))?),
                }
            }
            AudioKind::Raw => {
                c.absent(&self.device, "audio.device", &when("raw"))?;
                let path = c.resolve(c.required(self.path.clone(), "audio.path", &when("raw"))?);
                AudioInput::Raw { path, layout: layout(c, &self, "raw")? }
            }
            AudioKind::Stdin => {
                c.absent(&self.path, "audio.path", &when("stdin"))?;
                c.absent(&self.device, "audio.device", &when("stdin"))?;
                AudioInput::Stdin { layout: layout(c, &self, "stdin")? }
            }
            AudioKind::Live => {
                c.absent(&self.path, "audio.path", &when("live"))?;
                let device = c.required(self.device.clone(), "audio.device", &when("live"))?;
                AudioInput::Live { device, layout: layout(c, &self, "live")? }
            }
        };
        if let Some(map) = &self.channel_map
            && map.is_empty()
        {
            return Err(c.err("audio.channel_map", "empty; omit it to use the channels in order"));
        }
        let start = c.stamp(self.start_ns, "audio.start_ns")?;
        let file = matches!(self.source, AudioKind::Wav | AudioKind::Raw);
        if !file && self.pace == Pace::Asap {
            return Err(c.err("audio.pace", "only files can be read faster than real time"));
        }
        Ok(AudioConfig { input, channel_map: self.channel_map, start, realtime: self.pace == Pace::Realtime })
    }
}

impl PoseFile {
    fn validate(self, c: &Check) -> Result<PoseConfig, AgentError> {
        let when = |k: &str| format!("pose.source = \"{k}\"");
        let source = match self.source {
            PoseKind::Tum => {
                c.absent(&self.listen, "pose.listen", &when("tum"))?;
                let path = c.resolve(c.required(self.path, "pose.path", &when("tum"))?);
                if let Some(s) = self.start_s
                    && !s.is_finite()
                {
                    return Err(c.err("pose.start_s", "must be finite"));
                }
                PoseSource::Tum { path, start_s: self.start_s }
            }
            PoseKind::JsonlTcp => {
                c.absent(&self.path, "pose.path", &when("jsonl_tcp"))?;
                c.absent(&self.start_s, "pose.start_s", &when("jsonl_tcp"))?;
                let listen = c.required(self.listen, "pose.listen", &when("jsonl_tcp"))?;
                PoseSource::JsonlTcp(c.socket(&listen, "pose.listen")?)
            }
            PoseKind::JsonlStdin => {
                c.absent(&self.path, "pose.path", &when("jsonl_stdin"))?;
                c.absent(&self.listen, "pose.listen", &when("jsonl_stdin"))?;
                c.absent(&self.start_s, "pose.start_s", &when("jsonl_stdin"))?;
                PoseSource::JsonlStdin
            }
        };
        let d = PoseBufferConfig::default();
        let buffer = PoseBufferConfig {
            capacity: self.capacity.unwrap_or(d.capacity),
            max_gap_s: self.max_gap_s.unwrap_or(d.max_gap_s),
            extrapolation_tolerance_s: self.extrapolation_tolerance_s.unwrap_or(d.extrapolation_tolerance_s),
        };
        buffer.validate().map_err(|(field, message)| c.err(&format!("pose.{field}"), message))?;
        let max_wait_s = self.max_wait_s.unwrap_or(0.5);
        if !(max_wait_s.is_finite() && max_wait_s >= 0.0) {
            return Err(c.err("pose.max_wait_s", format!("{max_wait_s} s: must be non-negative")));
        }
        Ok(PoseConfig { source, buffer, max_wait_s })
    }
}

impl DoaFile {
    fn validate_odas(self, c: &Check, pose: &PoseConfig) -> Result<OdasConfig, AgentError> {
        let follow = self.follow.unwrap_or(false);
        let input = match (self.listen, self.file) {
            (Some(l), None) => {
                if self.follow.is_some() || self.pace.is_some() {
                    let f = if self.follow.is_some() { "doa.follow" } else { "doa.pace" };
                    return Err(c.err(f, "only for doa.file (a socket delivers at ODAS's own pace)"));
                }
                OdasInput::Listen(c.socket(&l, "doa.listen")?)
            }
            (None, Some(f)) => OdasInput::File { path: c.resolve(f), follow },
            (Some(_), Some(_)) => return Err(c.err("doa.file", "give either `listen` or `file`, not both")),
            (None, None) => {
                return Err(c.err("doa.listen", "required when doa.source = \"odas\" (or give `file`)"));
            }
        };
        if follow && self.pace == Some(Pace::Asap) {
            return Err(c.err(
                "doa.pace",
                "a followed file is read as ODAS writes it; \"asap\" only applies to a finished file",
            ));
        }
        let hop_len = self.hop_len.unwrap_or(128);
        let sample_rate_hz = self.sample_rate_hz.unwrap_or(16_000);
        if hop_len == 0 {
            return Err(c.err("doa.hop_len", "must be at least 1 sample"));
        }
        if sample_rate_hz == 0 {
            return Err(c.err("doa.sample_rate_hz", "must be positive"));
        }
        let start = c.stamp(self.start_ns, "doa.start_ns")?;
        // The clock rule: a live ODAS (socket, followed file) without start_ns is
        // timed from when its objects arrive, which a pose file cannot know.
        let live = matches!(input, OdasInput::Listen(_) | OdasInput::File { follow: true, .. });
        if live && start.is_none() && matches!(pose.source, PoseSource::Tum { start_s: Some(_), .. }) {
            return Err(c.err(
                "doa.start_ns",
                "required when poses come from a TUM file with pose.start_s and ODAS is live \
                 (socket or follow): ODAS's hop counter would be timed from its first object and \
                 the poses from the agent's start; give ODAS's start time in Unix ns",
            ));
        }
        let realtime = self.pace.unwrap_or_default() == Pace::Realtime;
        Ok(OdasConfig { input, hop_len, sample_rate_hz, start, realtime })
    }
}

impl LinkFile {
    fn validate(self, c: &Check, coordinator: &CoordinatorConfig) -> Result<LinkConfig, AgentError> {
        if self.buffer_capacity == 0 {
            return Err(c.err("link.buffer_capacity", "must be at least 1 observation"));
        }
        for (v, f) in [
            (self.heartbeat_interval_ms, "link.heartbeat_interval_ms"),
            (self.backoff_initial_ms, "link.backoff_initial_ms"),
            (self.backoff_max_ms, "link.backoff_max_ms"),
            (self.connect_timeout_ms, "link.connect_timeout_ms"),
        ] {
            if v == 0 {
                return Err(c.err(f, "must be at least 1 ms"));
            }
        }
        if self.backoff_initial_ms > self.backoff_max_ms {
            return Err(c.err(
                "link.backoff_initial_ms",
                format!(
                    "{} ms is more than link.backoff_max_ms = {} ms",
                    self.backoff_initial_ms, self.backoff_max_ms
                ),
            ));
        }
        Ok(LinkConfig {
            endpoint: coordinator.endpoint.clone(),
            token: coordinator.token.clone(),
            tls: coordinator.tls.clone(),
            buffer_capacity: self.buffer_capacity,
            heartbeat_interval: Duration::from_millis(self.heartbeat_interval_ms),
            backoff_initial: Duration::from_millis(self.backoff_initial_ms),
            backoff_max: Duration::from_millis(self.backoff_max_ms),
            connect_timeout: Duration::from_millis(self.connect_timeout_ms),
        })
    }
}

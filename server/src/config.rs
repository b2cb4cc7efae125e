//! `coordinator.toml`: every key optional, unknown keys rejected, values
//! validated before anything starts. Errors name the file and the key.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::ServerError;
use soundmap_proto::{Problem, ValidationError};

use crate::planner::{PlannerConfig, ThetaBand};
pub use crate::resources::{ServerConfig, StateConfig};
use crate::tracking::TrackerConfig;
use crate::triangulation::{RobustLoss, TriangulationConfig};
pub use crate::viz::{FoxgloveConfig, RecordConfig};

/// The coordinator's configuration.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CoordinatorConfig {
    /// Address the gRPC server listens on.
    pub listen: SocketAddr,
    /// When a robot counts as stale.
    pub liveness: LivenessConfig,
    /// How observations of different robots are combined in time.
    pub alignment: AlignmentConfig,
    /// How DoAs become rays.
    pub doa: DoaConfig,
    /// Acceptance limits of incoming messages.
    pub limits: LimitsConfig,
    /// Triangulation and its gate.
    pub triangulation: TriangulationConfig,
    /// Where estimates are written besides the watch stream.
    pub output: OutputConfig,
    /// Who may use the services: robot and operator credentials.
    pub auth: AuthConfig,
    /// TLS for both services (`[tls]`), mutual TLS with `client_ca`.
    pub tls: TlsConfig,
    /// Source tracking (`[tracking]`): the Kalman filter fed with every robot's DoA.
    pub tracking: TrackerConfig,
    /// Active positioning (`[active_positioning]`): on/off, θ band, commands.
    pub active_positioning: ActivePositioningConfig,
    /// The placement planner (`[planner]`), room and obstacles included. Its θ
    /// band comes from `[active_positioning]`.
    pub planner: PlannerConfig,
    /// How many sources are followed (`[sources]`; see the sound map).
    pub sources: SourcesConfig,
    /// Connection, stream, rate and memory bounds (`[server]`, see [`crate::resources`]).
    pub server: ServerConfig,
    /// Where state survives a restart (`[state]`, see [`crate::resources`]).
    pub state: StateConfig,
    /// The Foxglove live view (`[foxglove]`, see [`crate::viz`]).
    pub foxglove: FoxgloveConfig,
    /// The MCAP recording (`[record]`, see [`crate::viz`]).
    pub record: RecordConfig,
    /// The Prometheus endpoint (`[metrics]`).
    pub metrics: MetricsConfig,
}

/// Active positioning: whether the coordinator commands the robots, the θ band
/// it keeps them in, and how commands are issued.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ActivePositioningConfig {
    /// Send reposition commands. Default **false**: moving robots is something
    /// an operator opts into, after describing the room and its obstacles in
    /// `[planner.free_space]` (without a room the planner knows no walls). It can
    /// be switched at run time with `Monitoring.SetActivePositioning`.
    pub enabled: bool,
    /// Lower edge of the acceptable angle θ at the source between robots
    /// (degrees, in [0, 180)). Default 40 (the paper's band).
    pub theta_min_deg: f64,
    /// Upper edge (degrees, in (0, 180]). Default 140.
    pub theta_max_deg: f64,
    /// A command is void this long after it is issued (s): its `deadline_ns`. Default 30.
    pub command_deadline_s: f64,
    /// Shortest time between two planning cycles (ms); cycles run on
    /// estimates, at most this often. Goals are issued at most once per
    /// `planner.planning_period_s` (see `planner::cadence`). Default 100.
    pub evaluate_period_ms: u64,
    /// A goal a robot refused or failed to reach is not sent to it again for
    /// this long (s), unless it differs by more than `retry_distance_m`. Default 10.
    pub retry_after_s: f64,
    /// Goals closer than this to a refused one count as the same goal (m). Default 0.3.
    pub retry_distance_m: f64,
}

impl Default for ActivePositioningConfig {
    fn default() -> Self {
        ActivePositioningConfig {
            enabled: false,
            theta_min_deg: 40.0,
            theta_max_deg: 140.0,
            command_deadline_s: 30.0,
            evaluate_period_ms: 100,
            retry_after_s: 10.0,
            retry_distance_m: 0.3,
        }
    }
}

/// Liveness settings.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LivenessConfig {
    /// A connected robot silent this long is stale and leaves triangulation (ms).
    pub stale_after_ms: u64,
    /// Period of the housekeeping tick (ms); 0 disables it (time then advances
    /// only with incoming messages, as in simulation and replay).
    pub tick_ms: u64,
}

/// Time alignment of observations from different robots.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlignmentConfig {
    /// Observations within this much of the newest stamp are combined (ms).
    pub window_ms: u64,
    /// How much observation history is kept per robot (ms).
    pub history_ms: u64,
}

/// DoA handling.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DoaConfig {
    /// Angular σ per tangent axis used when a DoA carries none (degrees).
    pub default_sigma_deg: f64,
    /// DoAs with lower activity are ignored.
    pub min_activity: f64,
    /// Pressure reflection coefficient of the floor, in [0, 1): how strongly a
    /// planar array hears the floor image that pulls its elevations up
    /// ([`crate::floor_image`]). 0 keeps only the folding of elevations onto the
    /// upper hemisphere. Default 0.6. This is the value for a DoA heard over
    /// the SRP's whole band; see `narrow_band_reflection`.
    pub floor_reflection: f64,
    /// The reflection coefficient for a DoA heard over less than
    /// [`crate::floor_image::NARROW_BAND_FRACTION`] of the SRP's band (a
    /// talker's 300–3400 Hz), in [0, 1); between the two, R goes linearly with
    /// the heard share of the band (from the track's signature; see
    /// [`crate::floor_image::band_reflection`]). Default 0.75. Equal to
    /// `floor_reflection`, the band does not matter.
    pub narrow_band_reflection: f64,
    /// Height of the robots' base frame above the floor (m); 0 for a
    /// `base_footprint`-style frame on the floor.
    pub base_height_m: f64,
    /// Height of the ceiling above the floor (m), when known. A planar array
    /// in a room hears the ceiling's image (and the floor–ceiling images) at
    /// the source's azimuth above the direct path too; band-limited sources
    /// (talkers) merge them into one lobe and are heard up to 1.5 m too high
    /// at 6 m in a 3 m room. With it set, the floor-image model takes the
    /// whole vertical family ([`crate::floor_image`]), and a triangulated point
    /// above the ceiling (beyond its own 3σ and 0.2 m) is not trusted
    /// ([`crate::triangulation::GateReason::OutsideRoom`]; one below the floor
    /// never is). Unset (the default): the floor image alone.
    pub ceiling_height_m: Option<f64>,
    /// Gain of the reflections' pull as the DoA's own coherence reports it:
    /// for DoAs that carry a coherence C, the floor image's weight is
    /// `R² = reverberant_pull · ((1 − C)/C)²` instead of `floor_reflection`²
    /// ([`crate::floor_image::reverberant_reflection`]). 0 (the default)
    /// uses `floor_reflection` for every DoA: the coherence model is
    /// experimental (it fits the distance sweep's rooms, not `paper-static`'s;
    /// see the module docs).
    pub reverberant_pull: f64,
    /// Model that a planar array resolves elevation worse than azimuth: for
    /// robots whose hello declares microphone positions and the SRP band, the
    /// reported σ is taken as the horizontal axis's and the vertical axis's
    /// grows as the source nears the array's plane, from the microphones'
    /// vertical spread ([`crate::ray::Ray::vertical_excess`]). Off (the
    /// default): the same σ on both axes. On, trusted estimates are more
    /// honest but heights less accurate (see [`crate::floor_image`],
    /// "Elevation is resolved worse than azimuth").
    pub planar_elevation_noise: bool,
    /// Keep a source that robots hear through folded rays from arrays at one
    /// height on the upper side of their plane: such arrays hear a source and
    /// its mirror image below their plane alike, and the floor-image term
    /// that tells them apart is too uncertain to choose by (it placed a
    /// source 0.19 m above two arrays at its mirror in 83–100 % of the
    /// estimates). On (the default), a source truly below the arrays (on the
    /// floor) is placed at or above their plane instead; off, the fits and
    /// filters choose by the model (see [`crate::floor_image`], "The fold's
    /// two branches").
    pub upper_branch: bool,
}

/// Acceptance limits of incoming messages.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsConfig {
    /// Largest accepted lead of a stamp over the coordinator clock (ms), in [0, 86 400 000].
    pub max_future_ms: u64,
    /// Largest accepted age of a stamp behind the coordinator clock (ms), in
    /// [1000, 604 800 000]. Default 300 000 (5 min): older observations cannot
    /// be aligned with anything live, and a stamp from 1970 is a broken clock.
    pub max_past_ms: u64,
    /// Accepted deviation of a direction's norm from 1.
    pub unit_vector_tolerance: f64,
    /// Accepted deviation of a quaternion's norm from 1.
    pub quaternion_tolerance: f64,
}

/// Outputs besides the watch stream.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Append every estimate with a position to this JSON-lines file:
    /// `{"stamp_ns", "x", "y", "z", "cov", "gdop", "theta_deg", "robots", …}`.
    pub estimates_jsonl: Option<PathBuf>,
    /// Append every observation the coordinator accepts to this JSON-lines file
    /// (what the robots sent, for debugging a fleet and checking replays):
    /// `{"robot_id", "sequence", "stamp_ns", "map_from_base": [x, y, z, qx, qy, qz, qw],
    /// "doas": [{"track_id", "x", "y", "z", "activity", "angular_sigma_rad", "coherence"}]}`
    /// (metres; DoAs as unit vectors in the array frame; σ in rad or null).
    pub observations_jsonl: Option<PathBuf>,
}

/// `[metrics]`: the Prometheus endpoint.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MetricsConfig {
    /// Serve Prometheus metrics (OpenMetrics text) at `http://ADDR/metrics`,
    /// e.g. `127.0.0.1:9464`. Plain HTTP without credentials on its own port:
    /// counters and states only, no positions. Default: off.
    pub listen: Option<SocketAddr>,
}

/// `[sources]`: how many sources are followed and how they are born and remembered.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SourcesConfig {
    /// Most sources followed at once. Default 1: one source, from each robot's
    /// dominant DoA (the single-source coordinator, which publishes a
    /// triangulation even before a track starts); also when `[tracking]
    /// enabled = false`. More: the sound map (births need a pairing seen in
    /// `birth_rounds` rounds before anything is published).
    pub max_sources: usize,
    /// Consecutive estimate rounds in which the same robot-local tracks must
    /// pair up before a source is born from them.
    pub birth_rounds: u32,
    /// A source born within this distance of a lost one's last position takes
    /// back its id (m).
    pub reuse_radius_m: f64,
    /// How long a lost source is remembered for that (s).
    pub memory_s: f64,
    /// No source is born within this horizontal distance of a live one (m), at
    /// any height: rays there that no source claimed are taken as that
    /// source's outliers or reflections (elevation is the weak coordinate).
    pub exclusion_radius_m: f64,
    /// A candidate of two robots' rays alone is not born while a third robot
    /// that hears something, with an array no smaller than both of theirs and
    /// no farther from it than this × the farther of the two, has no ray
    /// towards it (0: off). See the sound map's docs, "Unheard candidates".
    pub unheard_range_ratio: f64,
}

impl Default for SourcesConfig {
    /// One source; for several: 3 birth rounds, 1 m reuse radius, 120 s memory, 0.5 m exclusion,
    /// unheard candidates vetoed at range ratio 1.5.
    fn default() -> Self {
        SourcesConfig {
            max_sources: 1,
            birth_rounds: 3,
            reuse_radius_m: 1.0,
            memory_s: 120.0,
            exclusion_radius_m: 0.5,
            unheard_range_ratio: 1.5,
        }
    }
}

impl SourcesConfig {
    /// Checks the values; errors name the key within `[sources]`.
    pub fn validate(&self) -> Result<(), ValidationError> {
        let bad = |field: &str, value: f64, range: &'static str| {
            ValidationError::new(field, Problem::OutOfRange { value, range })
        };
        if !(1..=64).contains(&self.max_sources) {
            return Err(bad("max_sources", self.max_sources as f64, "[1, 64]"));
        }
        if !(1..=100).contains(&self.birth_rounds) {
            return Err(bad("birth_rounds", self.birth_rounds as f64, "[1, 100]"));
        }
        for (field, v) in [
            ("reuse_radius_m", self.reuse_radius_m),
            ("memory_s", self.memory_s),
            ("exclusion_radius_m", self.exclusion_radius_m),
            ("unheard_range_ratio", self.unheard_range_ratio),
        ] {
            if !(v.is_finite() && (0.0..=1e6).contains(&v)) {
                return Err(bad(field, v, "[0, 1e6]"));
            }
        }
        Ok(())
    }
}

/// Who may use the services (see `service::auth`): robots by bearer token
/// (`authorization: Bearer TOKEN`) or client certificate, operators by token
/// or certificate with a role. As soon as any credential is configured
/// (a robot token, an operator, or `tls.client_ca`) no call is anonymous.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AuthConfig {
    /// Refuse calls without a known credential. Implied by any configured
    /// credential; `true` without any credential is a configuration error.
    pub required: bool,
    /// Robot id → token. A robot presenting a token is that robot: its hello
    /// must carry the same id.
    pub tokens: BTreeMap<String, String>,
    /// Operator name → token and role (`read`: `GetState`, `WatchEstimates`;
    /// `control`: also `SetActivePositioning`, `SetFocus`).
    pub operators: BTreeMap<String, OperatorConfig>,
}

impl AuthConfig {
    /// Whether any credential is configured, `client_ca` counted by the caller.
    pub fn has_credentials(&self) -> bool {
        !self.tokens.is_empty() || !self.operators.is_empty()
    }

    /// Whether no call may be anonymous: `required`, any credential, or
    /// client certificates (`tls.client_ca`).
    pub fn is_closed(&self, tls: &TlsConfig) -> bool {
        self.required || self.has_credentials() || tls.client_ca.is_some()
    }
}

/// `[auth.operators.NAME]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatorConfig {
    /// Bearer token; without one the operator is known by a client
    /// certificate naming it (needs `tls.client_ca`).
    #[serde(default)]
    pub token: Option<String>,
    /// What the operator may do.
    pub role: Role,
}

/// An operator's role; `control` includes `read`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Read-only monitoring calls.
    Read,
    /// Also the calls that change the coordinator's behaviour.
    Control,
}

/// `[tls]`: the coordinator's certificate and key (PEM) for TLS on both
/// services, and the CA (PEM) that signs client certificates for mutual TLS.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TlsConfig {
    /// Certificate chain, leaf first.
    pub cert: Option<PathBuf>,
    /// Private key (PKCS#8, PKCS#1 or SEC1).
    pub key: Option<PathBuf>,
    /// CA certificates of client certificates: robots and operators may then
    /// authenticate by certificate (its DNS/URI SAN or subject CN is the
    /// robot id or operator name). Clients without one may still use a token.
    pub client_ca: Option<PathBuf>,
}

impl TlsConfig {
    /// Whether TLS is on.
    pub fn enabled(&self) -> bool {
        self.cert.is_some()
    }
}

impl Default for CoordinatorConfig {
    fn default() -> Self {
        CoordinatorConfig {
            listen: "0.0.0.0:50051".parse().expect("valid literal"),
            liveness: LivenessConfig::default(),
            alignment: AlignmentConfig::default(),
            doa: DoaConfig::default(),
            limits: LimitsConfig::default(),
            triangulation: TriangulationConfig::default(),
            output: OutputConfig::default(),
            auth: AuthConfig::default(),
            tls: TlsConfig::default(),
            tracking: TrackerConfig::default(),
            active_positioning: ActivePositioningConfig::default(),
            planner: PlannerConfig::default(),
            sources: SourcesConfig::default(),
            server: ServerConfig::default(),
            state: StateConfig::default(),
            foxglove: FoxgloveConfig::default(),
            record: RecordConfig::default(),
            metrics: MetricsConfig::default(),
        }
    }
}

impl Default for LivenessConfig {
    fn default() -> Self {
        LivenessConfig { stale_after_ms: 2000, tick_ms: 100 }
    }
}

impl Default for AlignmentConfig {
    fn default() -> Self {
        AlignmentConfig { window_ms: 60, history_ms: 2000 }
    }
}

impl Default for DoaConfig {
    fn default() -> Self {
        DoaConfig {
            default_sigma_deg: 3.0,
            min_activity: 0.0,
            floor_reflection: 0.6,
            narrow_band_reflection: 0.75,
            base_height_m: 0.0,
            ceiling_height_m: None,
            reverberant_pull: 0.0,
            planar_elevation_noise: false,
            upper_branch: true,
        }
    }
}

impl Default for LimitsConfig {
    fn default() -> Self {
        LimitsConfig {
            max_future_ms: 1000,
            max_past_ms: 300_000,
            unit_vector_tolerance: 1e-3,
            quaternion_tolerance: 1e-2,
        }
    }
}

impl CoordinatorConfig {
    /// Reads and validates a TOML file.
    pub fn from_file(path: &Path) -> Result<Self, ServerError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ServerError::Io { path: path.into(), source })?;
        Self::from_toml(&text, path)
    }

    /// Parses and validates TOML text; errors name `path` and the key.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ServerError> {
        let de = toml::Deserializer::parse(text).map_err(|e| config_error(path, "", &e.to_string()))?;
        let config: CoordinatorConfig = serde_path_to_error::deserialize(de).map_err(|e| {
            let field = e.path().to_string();
            config_error(path, &field, e.into_inner().message())
        })?;
        config.validate(path)?;
        Ok(config)
    }

    /// Semantic checks the types cannot express.
    pub fn validate(&self, path: &Path) -> Result<(), ServerError> {
        let err = |field: &str, message: String| Err(config_error(path, field, &message));
        let positive = |v: f64| v.is_finite() && v > 0.0;
        self.validate_durations(path)?;
        if self.alignment.history_ms < self.alignment.window_ms {
            return err(
                "alignment.history_ms",
                format!("must be ≥ alignment.window_ms ({})", self.alignment.window_ms),
            );
        }
        if !(positive(self.doa.default_sigma_deg) && self.doa.default_sigma_deg <= 180.0) {
            return err("doa.default_sigma_deg", format!("{} not in (0, 180]", self.doa.default_sigma_deg));
        }
        if !(0.0..=1.0).contains(&self.doa.min_activity) {
            return err("doa.min_activity", format!("{} not in [0, 1]", self.doa.min_activity));
        }
        if !(0.0..1.0).contains(&self.doa.floor_reflection) {
            return err("doa.floor_reflection", format!("{} not in [0, 1)", self.doa.floor_reflection));
        }
        if !(0.0..1.0).contains(&self.doa.narrow_band_reflection) {
            return err(
                "doa.narrow_band_reflection",
                format!("{} not in [0, 1)", self.doa.narrow_band_reflection),
            );
        }
        if !(0.0..=1.0).contains(&self.doa.reverberant_pull) {
            return err("doa.reverberant_pull", format!("{} not in [0, 1]", self.doa.reverberant_pull));
        }
        if !(self.doa.base_height_m.is_finite() && self.doa.base_height_m.abs() <= 10.0) {
            return err("doa.base_height_m", format!("{} not in [-10, 10] m", self.doa.base_height_m));
        }
        if let Some(h) = self.doa.ceiling_height_m.filter(|h| !(h.is_finite() && (1.0..=100.0).contains(h))) {
            return err("doa.ceiling_height_m", format!("{h} not in [1, 100] m"));
        }
        if !positive(self.limits.unit_vector_tolerance) || self.limits.unit_vector_tolerance >= 0.5 {
            return err(
                "limits.unit_vector_tolerance",
                format!("{} not in (0, 0.5)", self.limits.unit_vector_tolerance),
            );
        }
        if !positive(self.limits.quaternion_tolerance) || self.limits.quaternion_tolerance >= 0.5 {
            return err(
                "limits.quaternion_tolerance",
                format!("{} not in (0, 0.5)", self.limits.quaternion_tolerance),
            );
        }
        let t = &self.triangulation;
        for (field, v) in [
            ("triangulation.min_range_m", t.min_range_m),
            ("triangulation.min_ray_angle_deg", t.min_ray_angle_deg),
            ("triangulation.max_condition_number", t.max_condition_number),
            ("triangulation.max_rms_m", t.max_rms_m),
            ("triangulation.max_range_m", t.max_range_m),
            ("triangulation.min_sigma_rad", t.min_sigma_rad),
        ] {
            if !positive(v) {
                return err(field, format!("{v} must be a positive number"));
            }
        }
        if !(t.residual_probability > 0.0 && t.residual_probability < 1.0) {
            return err(
                "triangulation.residual_probability",
                format!("{} not in (0, 1)", t.residual_probability),
            );
        }
        match t.robust_loss {
            RobustLoss::Huber { delta: v } | RobustLoss::Cauchy { c: v } if !positive(v) => {
                return err("triangulation.robust_loss", format!("scale {v} must be positive"));
            }
            _ => {}
        }
        self.validate_auth(path)?;
        self.tracking.validate().map_err(|e| invalid_key(path, e.within("tracking")))?;
        self.sources.validate().map_err(|e| invalid_key(path, e.within("sources")))?;
        self.server.validate().map_err(|e| invalid_key(path, e.within("server")))?;
        self.state.validate().map_err(|e| invalid_key(path, e.within("state")))?;
        self.foxglove.validate().map_err(|e| invalid_key(path, e.within("foxglove")))?;
        let closed = self.auth.is_closed(&self.tls);
        self.foxglove.validate_access(closed).map_err(|e| invalid_key(path, e.within("foxglove")))?;
        self.validate_positioning(path)?;
        Ok(())
    }

    /// Every duration in bounds that convert to nanoseconds without overflow.
    fn validate_durations(&self, path: &Path) -> Result<(), ServerError> {
        const DAY_MS: u64 = 86_400_000;
        for (field, v, lo, hi) in [
            ("liveness.stale_after_ms", self.liveness.stale_after_ms, 1, DAY_MS),
            ("liveness.tick_ms", self.liveness.tick_ms, 0, 60_000),
            ("alignment.window_ms", self.alignment.window_ms, 1, 60_000),
            ("alignment.history_ms", self.alignment.history_ms, 1, 3_600_000),
            ("limits.max_future_ms", self.limits.max_future_ms, 0, DAY_MS),
            ("limits.max_past_ms", self.limits.max_past_ms, 1000, 7 * DAY_MS),
            ("active_positioning.evaluate_period_ms", self.active_positioning.evaluate_period_ms, 1, DAY_MS),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err(config_error(path, field, &format!("{v} not in [{lo}, {hi}] ms")));
            }
        }
        let ap = &self.active_positioning;
        for (field, v) in [
            ("active_positioning.command_deadline_s", ap.command_deadline_s),
            ("active_positioning.retry_after_s", ap.retry_after_s),
        ] {
            if v > 86_400.0 {
                return Err(config_error(path, field, &format!("{v} not in [0, 86400] s")));
            }
        }
        Ok(())
    }

    /// Tokens, operators and their relation to `[tls]`; see [`AuthConfig`].
    fn validate_auth(&self, path: &Path) -> Result<(), ServerError> {
        let err = |field: &str, message: String| Err(config_error(path, field, &message));
        let mut seen: BTreeMap<String, String> = BTreeMap::new();
        let mut check_token = |field: String, token: &str| {
            if token.len() < 16 || !token.bytes().all(|b| b.is_ascii_graphic()) {
                return err(
                    &field,
                    "tokens must be at least 16 visible ASCII characters, without spaces".into(),
                );
            }
            if let Some(first) = seen.insert(token.to_owned(), field.clone()) {
                return err(&field, format!("the same token as {first}: every credential must be unique"));
            }
            Ok(())
        };
        for (robot, token) in &self.auth.tokens {
            if let Err(e) = soundmap_proto::RobotId::parse(robot, &format!("auth.tokens.{robot}")) {
                return Err(invalid_key(path, e));
            }
            check_token(format!("auth.tokens.{robot}"), token)?;
        }
        for (name, op) in &self.auth.operators {
            let field = format!("auth.operators.{name}");
            if let Err(e) = soundmap_proto::RobotId::parse(name, &field) {
                return Err(invalid_key(path, e));
            }
            if self.auth.tokens.contains_key(name) {
                return err(&field, format!("{name} is also a robot id in auth.tokens: names must differ"));
            }
            match &op.token {
                Some(token) => check_token(format!("{field}.token"), token)?,
                None if self.tls.client_ca.is_none() => {
                    return err(
                        &format!("{field}.token"),
                        "missing: without a token the operator needs a client certificate, \
                         so tls.client_ca must be set"
                            .into(),
                    );
                }
                None => {}
            }
        }
        if self.auth.required && !self.auth.has_credentials() && self.tls.client_ca.is_none() {
            return err(
                "auth.required",
                "true, but no credential is configured (auth.tokens, auth.operators, tls.client_ca)".into(),
            );
        }
        match (&self.tls.cert, &self.tls.key) {
            (Some(_), None) => return err("tls.key", "missing: tls.cert needs its key".into()),
            (None, Some(_)) => return err("tls.cert", "missing: tls.key needs its certificate".into()),
            _ => {}
        }
        if self.tls.client_ca.is_some() && self.tls.cert.is_none() {
            return err("tls.client_ca", "mutual TLS needs tls.cert and tls.key".into());
        }
        Ok(())
    }

    fn validate_positioning(&self, path: &Path) -> Result<(), ServerError> {
        let err = |field: &str, message: String| Err(config_error(path, field, &message));
        let ap = &self.active_positioning;
        let default_planner = PlannerConfig::default();
        for (field, set, default, band) in [
            ("theta_min_deg", self.planner.theta_min_deg, default_planner.theta_min_deg, ap.theta_min_deg),
            ("theta_max_deg", self.planner.theta_max_deg, default_planner.theta_max_deg, ap.theta_max_deg),
        ] {
            if set != default && set != band {
                return err(
                    &format!("planner.{field}"),
                    format!("the θ band is set in [active_positioning] ({field} = {band}); remove it here"),
                );
            }
        }
        ThetaBand::new(ap.theta_min_deg, ap.theta_max_deg, self.planner.theta_hysteresis_deg, false)
            .map_err(|e| invalid_key(path, e.within("active_positioning")))?;
        if !(ap.command_deadline_s.is_finite() && ap.command_deadline_s > 0.0) {
            return err(
                "active_positioning.command_deadline_s",
                format!("{} must be > 0", ap.command_deadline_s),
            );
        }
        for (field, v) in [("retry_after_s", ap.retry_after_s), ("retry_distance_m", ap.retry_distance_m)] {
            if !(v.is_finite() && v >= 0.0) {
                return err(&format!("active_positioning.{field}"), format!("{v} must be finite and ≥ 0"));
            }
        }
        self.planner_config().validate().map_err(|e| invalid_key(path, e.within("planner")))
    }

    /// The planner's settings with the θ band of `[active_positioning]`.
    pub fn planner_config(&self) -> PlannerConfig {
        PlannerConfig {
            theta_min_deg: self.active_positioning.theta_min_deg,
            theta_max_deg: self.active_positioning.theta_max_deg,
            ..self.planner.clone()
        }
    }
}

/// A key of the file at `path` that failed validation; `error` names the key
/// from the document's root (a section's own error is placed with
/// [`ValidationError::within`] first).
pub fn invalid_key(path: &Path, error: ValidationError) -> ServerError {
    ServerError::Config { path: path.into(), error }
}

/// A key with a problem described in words (parse errors, relations between keys).
fn config_error(path: &Path, field: &str, message: &str) -> ServerError {
    let field = if field.is_empty() || field == "." { "(document)" } else { field };
    invalid_key(path, ValidationError::new(field, Problem::Invalid(message.trim().replace('\n', " "))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<CoordinatorConfig, String> {
        CoordinatorConfig::from_toml(text, Path::new("c.toml")).map_err(|e| e.to_string())
    }

    #[test]
    fn empty_file_gives_defaults() {
        assert_eq!(parse("").unwrap(), CoordinatorConfig::default());
    }

    #[test]
    fn errors_name_file_and_key() {
        let e = parse("[triangulation]\nmax_rms_m = \"big\"\n").unwrap_err();
        assert!(e.starts_with("c.toml: triangulation.max_rms_m: "), "{e}");
        let e = parse("[alignment]\nwindow_msec = 3\n").unwrap_err();
        assert!(e.contains("c.toml") && e.contains("window_msec"), "{e}");
        let e = parse("[doa]\ndefault_sigma_deg = -1.0\n").unwrap_err();
        assert!(e.starts_with("c.toml: doa.default_sigma_deg: "), "{e}");
        let e = parse("listen = \"nowhere\"\n").unwrap_err();
        assert!(e.starts_with("c.toml: listen: "), "{e}");
        let e = parse("[auth]\nrequired = true\n").unwrap_err();
        assert!(e.starts_with("c.toml: auth.required: "), "{e}");
        let e = parse("[triangulation.robust_loss]\nkind = \"cauchy\"\nc = 0.0\n").unwrap_err();
        assert!(e.starts_with("c.toml: triangulation.robust_loss: "), "{e}");
        let e = parse("[liveness\n").unwrap_err();
        assert!(e.starts_with("c.toml: (document): "), "{e}");
    }

    #[test]
    fn tracking_planner_and_positioning_errors_name_file_and_key() {
        for (text, prefix) in [
            ("[tracking]\nlag = 0.3\n", "c.toml: tracking.lag: unknown field `lag`"),
            ("[doa]\nfloor_reflection = 1.0\n", "c.toml: doa.floor_reflection: 1 not in [0, 1)"),
            ("[doa]\nbase_height_m = nan\n", "c.toml: doa.base_height_m: "),
            ("[doa]\nceiling_height_m = 0.5\n", "c.toml: doa.ceiling_height_m: 0.5 not in [1, 100] m"),
            ("[doa]\nreverberant_pull = -0.1\n", "c.toml: doa.reverberant_pull: -0.1 not in [0, 1]"),
            ("[tracking]\nlag_s = -1.0\n", "c.toml: tracking.lag_s: "),
            ("[tracking]\nconfirm_updates = 40\n", "c.toml: tracking.confirm_updates: "),
            ("[tracking]\nenabled = \"yes\"\n", "c.toml: tracking.enabled: "),
            ("[planner]\nmax_step = 1.0\n", "c.toml: planner.max_step: unknown field `max_step`"),
            ("[planner]\nmin_range_m = 9.0\n", "c.toml: planner.min_range_m: "),
            ("[planner.free_space]\nroom = [[0, 0], [1, 1]]\n", "c.toml: planner.free_space.room: "),
            ("[planner.sampling]\nmax_sweeps = 0\n", "c.toml: planner.sampling.max_sweeps: "),
            ("[planner]\ntheta_min_deg = 30.0\n", "c.toml: planner.theta_min_deg: the θ band is set in"),
            ("[active_positioning]\ntheta_min_deg = 150.0\n", "c.toml: active_positioning.theta_min_deg: "),
            ("[active_positioning]\ntheta_max_deg = 181.0\n", "c.toml: active_positioning.theta_max_deg: "),
            (
                "[active_positioning]\ncommand_deadline_s = 0.0\n",
                "c.toml: active_positioning.command_deadline_s: ",
            ),
            (
                "[active_positioning]\nenable = true\n",
                "c.toml: active_positioning.enable: unknown field `enable`",
            ),
        ] {
            let e = parse(text).unwrap_err();
            assert!(e.starts_with(prefix), "{text:?}: {e}");
        }
        let ok = parse(
            "[tracking]\nenabled = false\n[active_positioning]\nenabled = true\ntheta_min_deg = 30.0\n\
             [planner]\ntheta_min_deg = 30.0\nmax_step_m = 0.5\n",
        )
        .unwrap();
        assert!(!ok.tracking.enabled && ok.active_positioning.enabled);
        assert_eq!(ok.planner_config().theta_min_deg, 30.0);
        assert_eq!(ok.planner_config().theta_max_deg, 140.0);
    }
}

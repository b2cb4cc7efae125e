//! Scenarios: a room, noise, robots, sources, duration and seed, in TOML.
//!
//! Built-in scenarios live in `tests/scenarios/*.toml` and are compiled in
//! ([`builtin`]). Every key is checked: unknown keys are errors, and errors
//! name the file and the key.

pub mod builtin;
mod validate;

use std::path::Path;

use nalgebra::{Point3, Vector3};
use serde::Deserialize;
use soundmap_agent::pipeline::PipelineConfig;
use soundmap_server::CoordinatorConfig;

use crate::acoustics::Waveform;
use crate::error::SimError;

/// A simulated trial.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name, used in reports.
    pub name: String,
    /// What the scenario shows.
    #[serde(default)]
    pub description: String,
    /// Simulated duration (s).
    pub duration_s: f64,
    /// Seed of every random process (signals, noise, SLAM error).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// The room.
    pub room: RoomSpec,
    /// Sensor and diffuse noise.
    #[serde(default)]
    pub noise: NoiseSpec,
    /// SLAM pose error seen by the agents.
    #[serde(default)]
    pub slam: SlamSpec,
    /// The robots (at least two).
    pub robots: Vec<RobotSpec>,
    /// The sound sources (at least one; the first is the one scored).
    pub sources: Vec<SourceSpec>,
    /// Active positioning: whether the coordinator moves the robots.
    #[serde(default)]
    pub active_positioning: ActiveSpec,
    /// Overrides of the agents' localization and tracking settings.
    #[serde(default)]
    pub agent: PipelineConfig,
    /// Overrides of the coordinator's configuration (`listen` is ignored);
    /// `[doa] ceiling_height_m` defaults to the room's height.
    #[serde(default)]
    pub coordinator: CoordinatorConfig,
    /// The `[agent]` and `[coordinator]` tables as written in the scenario,
    /// for the configuration files a recording is replayed with.
    #[serde(skip)]
    pub overrides: Overrides,
}

/// A scenario's own `[agent]` and `[coordinator]` tables (empty when absent).
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// `[agent]`: the agents' pipeline settings.
    pub agent: toml::Table,
    /// `[coordinator]`: the coordinator's settings.
    pub coordinator: toml::Table,
}

fn default_seed() -> u64 {
    1
}

/// A shoebox room.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSpec {
    /// Corner with the smallest coordinates, map frame (m); the floor is at its z.
    pub min_corner_m: [f64; 3],
    /// Size along x, y, z (m).
    pub size_m: [f64; 3],
    /// Reverberation time RT60 (s).
    pub rt60_s: f64,
    /// Obstacles as floor polygons ([x, y] in m, counter-clockwise). They block
    /// robots and planning; acoustically the room stays a shoebox.
    #[serde(default)]
    pub obstacles: Vec<Vec<[f64; 2]>>,
}

impl RoomSpec {
    /// Minimum corner as a point.
    pub fn min_corner(&self) -> Point3<f64> {
        Point3::from(self.min_corner_m)
    }

    /// Size as a vector.
    pub fn size(&self) -> Vector3<f64> {
        Vector3::from(self.size_m)
    }

    /// The floor as a counter-clockwise polygon.
    pub fn floor(&self) -> Vec<[f64; 2]> {
        let [x, y, _] = self.min_corner_m;
        let [w, d, _] = self.size_m;
        vec![[x, y], [x + w, y], [x + w, y + d], [x, y + d]]
    }
}

/// Noise at the microphones.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseSpec {
    /// Independent sensor noise, SNR (dB) relative to the first source's direct
    /// path at `reference_distance_m`.
    pub sensor_snr_db: f64,
    /// Spherically diffuse noise at this SNR (dB), same reference; none when absent.
    pub diffuse_snr_db: Option<f64>,
    /// Distance at which SNRs are defined (m).
    pub reference_distance_m: f64,
}

impl Default for NoiseSpec {
    fn default() -> Self {
        NoiseSpec { sensor_snr_db: 30.0, diffuse_snr_db: None, reference_distance_m: 3.0 }
    }
}

/// SLAM pose error.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlamSpec {
    /// White position noise per horizontal axis (m).
    pub position_white_std_m: f64,
    /// White yaw noise (degrees).
    pub yaw_white_std_deg: f64,
    /// Slow drift (first-order Gauss–Markov) of the position (m).
    pub drift_position_std_m: f64,
    /// Slow drift of the yaw (degrees).
    pub drift_yaw_std_deg: f64,
    /// Time constant of the drift (s).
    pub drift_time_constant_s: f64,
}

impl Default for SlamSpec {
    /// What RTAB-Map gives indoors: 2 cm / 0.5° white, 3 cm / 0.8° drift over 20 s.
    fn default() -> Self {
        SlamSpec {
            position_white_std_m: 0.02,
            yaw_white_std_deg: 0.5,
            drift_position_std_m: 0.03,
            drift_yaw_std_deg: 0.8,
            drift_time_constant_s: 20.0,
        }
    }
}

/// A waypoint of a robot path.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointSpec {
    /// Position, map frame (m).
    pub x_m: f64,
    /// Position, map frame (m).
    pub y_m: f64,
    /// Arrival time (s); the robot waits there if early. Absent: as soon as possible.
    pub t_s: Option<f64>,
}

/// A robot.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Robot id.
    pub id: String,
    /// Array preset name or array file.
    pub array: String,
    /// Start pose: x (m), y (m), yaw (degrees).
    pub start: [f64; 3],
    /// Preset trajectory. Empty: the robot stays put unless the coordinator commands it.
    #[serde(default)]
    pub waypoints: Vec<WaypointSpec>,
    /// Top speed (m/s).
    #[serde(default = "default_speed")]
    pub max_speed_m_per_s: f64,
    /// Top turn rate (degrees/s).
    #[serde(default = "default_turn_rate")]
    pub max_turn_rate_deg_per_s: f64,
}

fn default_speed() -> f64 {
    0.5
}

fn default_turn_rate() -> f64 {
    60.0
}

/// A point of a source path.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathPoint {
    /// Time (s).
    pub t_s: f64,
    /// Position, map frame (m).
    pub x_m: f64,
    /// Position, map frame (m).
    pub y_m: f64,
    /// Height, map frame (m).
    pub z_m: f64,
}

/// What a source plays.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SignalSpec {
    /// White noise (the paper's loudspeaker).
    WhiteNoise,
    /// Noise between two frequencies (Hz).
    BandNoise {
        /// Lower edge (Hz).
        low_hz: f64,
        /// Upper edge (Hz).
        high_hz: f64,
    },
    /// Speech-like: noise from `low_hz` to `high_hz` under a syllabic envelope at
    /// `syllable_hz` (4–6 Hz for speech) with pauses; seeded per source
    /// (`acoustics::signals` describes the envelope). `rms` is the level while voiced.
    Talker {
        /// Lower edge (Hz).
        low_hz: f64,
        /// Upper edge (Hz).
        high_hz: f64,
        /// Syllable rate (Hz).
        #[serde(default = "default_syllable_hz")]
        syllable_hz: f64,
    },
    /// A steady fan: a hum at `hum_hz` and its harmonics plus broadband noise.
    Fan {
        /// Fundamental of the hum (Hz).
        #[serde(default = "default_hum_hz")]
        hum_hz: f64,
    },
    /// A pure tone (Hz).
    Tone {
        /// Frequency (Hz).
        frequency_hz: f64,
    },
}

impl SignalSpec {
    /// The waveform the acoustics render.
    pub fn waveform(&self) -> Waveform {
        match *self {
            SignalSpec::WhiteNoise => Waveform::WhiteNoise,
            SignalSpec::BandNoise { low_hz, high_hz } => Waveform::BandNoise { low_hz, high_hz },
            SignalSpec::Talker { low_hz, high_hz, syllable_hz } => {
                Waveform::Talker { low_hz, high_hz, syllable_hz }
            }
            SignalSpec::Fan { hum_hz } => Waveform::Fan { hum_hz },
            SignalSpec::Tone { frequency_hz } => Waveform::Tone { frequency_hz, phase_rad: 0.0 },
        }
    }
}

/// A sound source.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceSpec {
    /// Signal.
    pub signal: SignalSpec,
    /// RMS level at 1 m (arbitrary full-scale units; 0.1 is a loud loudspeaker).
    #[serde(default = "default_rms")]
    pub rms: f64,
    /// Path: positions at times, linearly interpolated, held before the first and
    /// after the last. One point: a static source.
    pub path: Vec<PathPoint>,
    /// Intervals [start_s, end_s] when the source plays; always when empty.
    #[serde(default)]
    pub active: Vec<[f64; 2]>,
}

fn default_syllable_hz() -> f64 {
    5.0
}

fn default_hum_hz() -> f64 {
    120.0
}

fn default_rms() -> f64 {
    0.1
}

impl SourceSpec {
    /// Position at time `t_s` (m).
    pub fn position_at(&self, t_s: f64) -> Point3<f64> {
        let p = &self.path;
        let at = |q: &PathPoint| Point3::new(q.x_m, q.y_m, q.z_m);
        if t_s <= p[0].t_s || p.len() == 1 {
            return at(&p[0]);
        }
        for w in p.windows(2) {
            if t_s <= w[1].t_s {
                let a = (t_s - w[0].t_s) / (w[1].t_s - w[0].t_s);
                return at(&w[0]) + (at(&w[1]) - at(&w[0])) * a;
            }
        }
        at(&p[p.len() - 1])
    }

    /// The `active` intervals as `(start_s, end_s)` pairs (empty: always).
    pub fn active_intervals(&self) -> Vec<(f64, f64)> {
        self.active.iter().map(|[a, b]| (*a, *b)).collect()
    }

    /// Whether the source plays at `t_s`.
    pub fn active_at(&self, t_s: f64) -> bool {
        self.active.is_empty() || self.active.iter().any(|[a, b]| (*a..*b).contains(&t_s))
    }
}

/// Active positioning settings of a scenario.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ActiveSpec {
    /// Whether the coordinator commands the robots.
    pub enabled: bool,
    /// Acceptable θ band (degrees).
    pub theta_min_deg: f64,
    /// See `theta_min_deg`.
    pub theta_max_deg: f64,
}

impl Default for ActiveSpec {
    fn default() -> Self {
        ActiveSpec { enabled: false, theta_min_deg: 40.0, theta_max_deg: 140.0 }
    }
}

impl Scenario {
    /// Parses and validates TOML; errors name `origin` (a path or `<built-in NAME>`) and the key.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, SimError> {
        let err = |field: String, message: String| SimError::Scenario { path: origin.into(), field, message };
        let de = toml::Deserializer::parse(text)
            .map_err(|e| err("(document)".into(), e.to_string().trim().replace('\n', " ")))?;
        let mut scenario: Scenario = serde_path_to_error::deserialize(de).map_err(|e| {
            let at = e.path().to_string();
            let message = e.into_inner().message().to_string();
            // A missing key is named itself, not its table.
            let missing = message.strip_prefix("missing field `").and_then(|m| m.split('`').next());
            match (missing, at.as_str()) {
                (Some(key), ".") => err(key.into(), "missing".into()),
                (Some(key), _) => err(format!("{at}.{key}"), "missing".into()),
                (None, ".") => err("(document)".into(), message),
                (None, _) => err(at, message),
            }
        })?;
        scenario.validate(origin)?;
        // The text parsed above as a scenario is valid TOML.
        if let Ok(mut raw) = toml::from_str::<toml::Table>(text) {
            let mut table = |key: &str| match raw.remove(key) {
                Some(toml::Value::Table(t)) => t,
                _ => toml::Table::new(),
            };
            scenario.overrides = Overrides { agent: table("agent"), coordinator: table("coordinator") };
        }
        Ok(scenario)
    }

    /// Loads a scenario file, or a built-in scenario by name.
    pub fn load(name_or_path: &str) -> Result<Self, SimError> {
        if let Some(text) = builtin::text(name_or_path) {
            return Self::from_toml(text, &format!("<built-in {name_or_path}>"));
        }
        let path = Path::new(name_or_path);
        if !path.exists() && !name_or_path.ends_with(".toml") {
            return Err(SimError::Scenario {
                path: name_or_path.into(),
                field: "(name)".into(),
                message: format!(
                    "no such file and no built-in scenario of that name (built in: {})",
                    builtin::NAMES.join(", ")
                ),
            });
        }
        let text = std::fs::read_to_string(path).map_err(|e| SimError::file(path, e))?;
        Self::from_toml(&text, &path.display().to_string())
    }
}

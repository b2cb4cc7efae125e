//! Domain forms of the robot-link messages, with checked conversions from the wire.

use nalgebra::{Isometry3, Matrix6, Point3, Unit, Vector3};

use crate::error::{Problem, ValidationError};
use crate::geometry::{
    Limits, direction_from_wire, finite, point_from_wire, pose_covariance_from_wire, pose_covariance_to_wire,
    pose_from_wire, pose_to_wire, vec3_to_wire,
};
use crate::robot_id::RobotId;
use crate::stamp::Stamp;
use crate::wire;

/// Version of the contract this crate implements (`Hello.protocol_version`).
pub const PROTOCOL_VERSION: u32 = 1;

/// Most DoAs accepted in one observation.
pub const MAX_DOAS_PER_OBSERVATION: usize = 64;
/// Longest accepted free-text field, in characters.
pub const MAX_TEXT_LEN: usize = 256;
/// Most bands of a spectral signature (`Hello.signature_bands`).
pub const MAX_SIGNATURE_BANDS: usize = 64;
/// Accepted range of a signature value, dB.
pub const SIGNATURE_DB_RANGE: (f32, f32) = (-200.0, 200.0);
/// Accepted range of a DoA's floor-fit range, m (0 on the wire: none).
pub const FLOOR_FIT_RANGE_M: (f64, f64) = (0.1, 1000.0);

/// Accepted range of a DoA's 1-σ angular uncertainty, radians (0 on the wire
/// means unknown). Below 1e-4 rad (0.006°) no microphone array resolves a
/// direction, and a weight 1/σ² past 1e8 only breaks the solvers; above π
/// the direction says nothing.
pub const ANGULAR_SIGMA_RANGE_RAD: (f64, f64) = (1e-4, std::f64::consts::PI);

/// A robot's microphone array as the coordinator needs it.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayInfo {
    /// Pose of the array frame in the base frame.
    pub base_from_array: Isometry3<f64>,
    /// Number of microphones (≥ 2).
    pub microphone_count: u32,
    /// Preset the array came from, if any.
    pub preset: Option<String>,
    /// Microphone positions in the array frame, metres (may be empty).
    pub microphone_positions: Vec<Point3<f64>>,
    /// Band of the steered-response search behind the DoAs, Hz (`[low, high]`),
    /// when the robot declares it.
    pub srp_band_hz: Option<[f64; 2]>,
    /// Whether the DoAs' elevations are the direct path's (the robot fitted
    /// the floor's reflection), so the coordinator models no pull.
    pub direct_path_elevations: bool,
}

/// First message of a robot's stream.
#[derive(Clone, Debug, PartialEq)]
pub struct Hello {
    /// The robot's identity.
    pub robot_id: RobotId,
    /// Its microphone array.
    pub array: ArrayInfo,
    /// Free text describing the agent software.
    pub software_version: String,
    /// Edges of the bands of the tracks' spectral signatures, Hz: B+1 finite,
    /// positive, strictly increasing values for B bands (1..=64). `None`: the
    /// robot sends no signatures.
    pub signature_bands: Option<Vec<f64>>,
    /// Most DoAs the robot sends in one observation (1..=64), when declared.
    pub max_tracks: Option<u32>,
    /// The base's motion limits, as far as the robot declares them.
    pub base_limits: BaseLimits,
}

/// Motion limits of a robot's base (`None`: not declared).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BaseLimits {
    /// Speed at which the base drives to a goal, m/s, in (0, 10].
    pub max_speed_m_per_s: Option<f64>,
    /// Rate at which the base turns in place, degrees/s, in (0, 3600].
    pub max_turn_rate_deg_per_s: Option<f64>,
}

impl BaseLimits {
    /// Largest accepted speed, m/s.
    pub const MAX_SPEED_M_PER_S: f64 = 10.0;
    /// Largest accepted turn rate, degrees/s.
    pub const MAX_TURN_RATE_DEG_PER_S: f64 = 3600.0;

    fn from_wire(b: &wire::BaseLimits, field: &str) -> Result<Self, ValidationError> {
        let limit = |v: f64, name: &str, max: f64, range: &'static str| {
            let f = format!("{field}.{name}");
            let v = finite(v, &f)?;
            if v == 0.0 {
                Ok(None)
            } else if v > 0.0 && v <= max {
                Ok(Some(v))
            } else {
                Err(ValidationError::new(f, Problem::OutOfRange { value: v, range }))
            }
        };
        Ok(BaseLimits {
            max_speed_m_per_s: limit(
                b.max_speed_m_per_s,
                "max_speed_m_per_s",
                Self::MAX_SPEED_M_PER_S,
                "(0, 10] m/s (0 = unknown)",
            )?,
            max_turn_rate_deg_per_s: limit(
                b.max_turn_rate_deg_per_s,
                "max_turn_rate_deg_per_s",
                Self::MAX_TURN_RATE_DEG_PER_S,
                "(0, 3600] degrees/s (0 = unknown)",
            )?,
        })
    }

    /// Wire form; `None` when nothing is declared.
    pub fn to_wire(self) -> Option<wire::BaseLimits> {
        (self != BaseLimits::default()).then(|| wire::BaseLimits {
            max_speed_m_per_s: self.max_speed_m_per_s.unwrap_or(0.0),
            max_turn_rate_deg_per_s: self.max_turn_rate_deg_per_s.unwrap_or(0.0),
        })
    }
}

/// One tracked direction of arrival.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedDoa {
    /// Robot-local track id.
    pub track_id: u64,
    /// Unit vector toward the source, array frame.
    pub direction_in_array: Unit<Vector3<f64>>,
    /// Activity in [0, 1].
    pub activity: f64,
    /// 1-σ angular uncertainty per tangent axis (rad), when the robot knows it.
    pub angular_sigma_rad: Option<f64>,
    /// Spectral signature of the track's source: mean power per band of the
    /// hello's `signature_bands` of the array steered at the track, dB
    /// (10·log10; 0 dB = unit-variance white noise from that direction),
    /// smoothed over ~100 ms; finite, within [`SIGNATURE_DB_RANGE`]. `None`:
    /// no signature (never an empty vector).
    pub signature: Option<Vec<f32>>,
    /// PHAT coherence of the peaks that fed the track, in (0, 1], when the
    /// robot knows it (see the proto's `TrackedDoa.coherence`).
    pub coherence: Option<f64>,
    /// Range (m) at which the robot fitted the elevation with the floor's
    /// reflection, when it did (see the proto's `TrackedDoa.floor_fit_range_m`).
    pub floor_fit_range_m: Option<f64>,
}

/// A robot's DoAs at one instant with its pose at that instant.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    /// Per-stream sequence number.
    pub sequence: u64,
    /// Acoustic time of the DoAs.
    pub stamp: Stamp,
    /// Pose of the base in the map at `stamp`.
    pub map_from_base: Isometry3<f64>,
    /// Covariance of `map_from_base` over (x, y, z, rx, ry, rz), m² and rad².
    pub pose_covariance: Option<Matrix6<f64>>,
    /// Tracked sources heard at `stamp`.
    pub doas: Vec<TrackedDoa>,
}

/// State of a reposition command as the robot reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandState {
    /// Driving toward the goal.
    Executing,
    /// At the goal.
    Succeeded,
    /// Could not reach the goal.
    Failed,
    /// Replaced or cancelled.
    Canceled,
}

/// A robot's answer to a command.
#[derive(Clone, Debug, PartialEq)]
pub struct CommandAck {
    /// The command answered.
    pub command_id: u64,
    /// Whether the robot will execute it.
    pub accepted: bool,
    /// Why not, when refused.
    pub reason: String,
}

/// Progress of a command.
#[derive(Clone, Debug, PartialEq)]
pub struct CommandProgress {
    /// The command reported on.
    pub command_id: u64,
    /// Its state.
    pub state: CommandState,
    /// Remaining path length (m), when known.
    pub distance_remaining_m: Option<f64>,
    /// Free text.
    pub detail: String,
}

/// Why the coordinator asks a robot to move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RepositionReason {
    /// θ left the band.
    ThetaOutOfBand,
    /// GDOP above threshold.
    GdopHigh,
    /// Predicted improvement worth the motion.
    Improvement,
    /// The formation follows a moving source.
    FollowSource,
    /// The robot is inside the keep-out of the source (or of its path just
    /// ahead) and backs out.
    KeepOut,
}

/// A goal for a robot's base.
#[derive(Clone, Debug, PartialEq)]
pub struct RepositionCommand {
    /// Coordinator-wide command id.
    pub command_id: u64,
    /// Goal pose of the base in the map frame.
    pub goal_map_from_base: Isometry3<f64>,
    /// Point to face on arrival (map frame).
    pub look_at_in_map: Point3<f64>,
    /// Why.
    pub reason: RepositionReason,
    /// Free text for operators.
    pub detail: String,
    /// The command is void after this time.
    pub deadline: Stamp,
    /// When it was issued.
    pub issued: Stamp,
}

/// Any message a robot sends, validated.
#[derive(Clone, Debug, PartialEq)]
pub enum RobotInput {
    /// Stream opening.
    Hello(Hello),
    /// DoAs with pose.
    Observation(Observation),
    /// Sign of life, with the robot's clock.
    Heartbeat(Stamp),
    /// Answer to a command.
    CommandAck(CommandAck),
    /// Progress of a command.
    CommandProgress(CommandProgress),
}

fn text(s: &str, field: &str) -> Result<String, ValidationError> {
    let len = s.chars().count();
    if len > MAX_TEXT_LEN {
        return Err(ValidationError::new(field, Problem::TooLong { len, max: MAX_TEXT_LEN }));
    }
    Ok(s.to_owned())
}

/// Validates signature band edges (B+1 values for 1..=64 bands, finite,
/// positive, strictly increasing, Hz).
fn band_edges(edges: &[f64], field: &str) -> Result<Vec<f64>, ValidationError> {
    if edges.len() < 2 || edges.len() > MAX_SIGNATURE_BANDS + 1 {
        return Err(ValidationError::new(
            field,
            Problem::Invalid(format!(
                "{} edges; 1 to {MAX_SIGNATURE_BANDS} bands need 2 to {} edges",
                edges.len(),
                MAX_SIGNATURE_BANDS + 1
            )),
        ));
    }
    for (i, &e) in edges.iter().enumerate() {
        let f = format!("{field}[{i}]");
        finite(e, &f)?;
        if e <= 0.0 {
            return Err(ValidationError::new(f, Problem::OutOfRange { value: e, range: "(0, ∞) Hz" }));
        }
        if i > 0 && e <= edges[i - 1] {
            return Err(ValidationError::new(
                f,
                Problem::Invalid(format!("{e} Hz does not exceed the previous edge {} Hz", edges[i - 1])),
            ));
        }
    }
    Ok(edges.to_vec())
}

impl ArrayInfo {
    /// The array's aperture (m: the largest distance between two of its
    /// microphones), when its microphone positions are given.
    pub fn aperture_m(&self) -> Option<f64> {
        (self.microphone_positions.len() >= 2)
            .then(|| crate::geometry::aperture_m(&self.microphone_positions))
    }

    /// Validates a wire array description; errors name fields under `field`.
    pub fn from_wire(
        a: &Option<wire::ArrayDescription>,
        field: &str,
        limits: &Limits,
    ) -> Result<Self, ValidationError> {
        let a = a.as_ref().ok_or_else(|| ValidationError::new(field, Problem::Missing))?;
        let base_from_array =
            pose_from_wire(&a.base_from_array, &format!("{field}.base_from_array"), limits)?;
        if a.microphone_count < 2 {
            return Err(ValidationError::new(
                format!("{field}.microphone_count"),
                Problem::OutOfRange { value: a.microphone_count as f64, range: "[2, ∞)" },
            ));
        }
        let microphone_positions = a
            .microphone_positions_m
            .iter()
            .enumerate()
            .map(|(i, p)| point_from_wire(&Some(*p), &format!("{field}.microphone_positions_m[{i}]")))
            .collect::<Result<Vec<_>, _>>()?;
        if !microphone_positions.is_empty() && microphone_positions.len() != a.microphone_count as usize {
            return Err(ValidationError::new(
                format!("{field}.microphone_positions_m"),
                Problem::WrongLength {
                    expected: a.microphone_count as usize,
                    got: microphone_positions.len(),
                },
            ));
        }
        let srp_band_hz = match a.srp_band_hz.as_slice() {
            [] => None,
            &[lo, _] if !(lo > 0.0 && lo < 200_000.0) => {
                return Err(ValidationError::new(
                    format!("{field}.srp_band_hz[0]"),
                    Problem::OutOfRange { value: lo, range: "(0, 200000) Hz" },
                ));
            }
            &[lo, hi] if !(hi > lo && hi <= 200_000.0) => {
                return Err(ValidationError::new(
                    format!("{field}.srp_band_hz[1]"),
                    Problem::OutOfRange { value: hi, range: "(srp_band_hz[0], 200000] Hz" },
                ));
            }
            &[lo, hi] => Some([lo, hi]),
            other => {
                return Err(ValidationError::new(
                    format!("{field}.srp_band_hz"),
                    Problem::WrongLength { expected: 2, got: other.len() },
                ));
            }
        };
        Ok(ArrayInfo {
            srp_band_hz,
            direct_path_elevations: a.direct_path_elevations,
            base_from_array,
            microphone_count: a.microphone_count,
            preset: (!a.preset.is_empty())
                .then(|| text(&a.preset, &format!("{field}.preset")))
                .transpose()?,
            microphone_positions,
        })
    }

    /// Wire form.
    pub fn to_wire(&self) -> wire::ArrayDescription {
        wire::ArrayDescription {
            base_from_array: Some(pose_to_wire(&self.base_from_array)),
            microphone_count: self.microphone_count,
            preset: self.preset.clone().unwrap_or_default(),
            microphone_positions_m: self
                .microphone_positions
                .iter()
                .map(|p| vec3_to_wire(&p.coords))
                .collect(),
            srp_band_hz: self.srp_band_hz.map(Vec::from).unwrap_or_default(),
            direct_path_elevations: self.direct_path_elevations,
        }
    }
}

impl Hello {
    /// Validates a wire hello.
    pub fn from_wire(h: &wire::Hello, limits: &Limits) -> Result<Self, ValidationError> {
        let robot_id = RobotId::parse(&h.robot_id, "hello.robot_id")?;
        let version = if h.protocol_version == 0 { 1 } else { h.protocol_version };
        if version > PROTOCOL_VERSION {
            return Err(ValidationError::new(
                "hello.protocol_version",
                Problem::Invalid(format!(
                    "unsupported protocol version {version} (this side speaks {PROTOCOL_VERSION})"
                )),
            ));
        }
        let max_tracks = match h.max_tracks {
            0 => None,
            n if n as usize > MAX_DOAS_PER_OBSERVATION => {
                return Err(ValidationError::new(
                    "hello.max_tracks",
                    Problem::OutOfRange { value: n as f64, range: "[1, 64] (0 = unspecified)" },
                ));
            }
            n => Some(n),
        };
        Ok(Hello {
            robot_id,
            array: ArrayInfo::from_wire(&h.array, "hello.array", limits)?,
            software_version: text(&h.software_version, "hello.software_version")?,
            signature_bands: h
                .signature_bands
                .as_ref()
                .map(|b| band_edges(&b.band_edges_hz, "hello.signature_bands.band_edges_hz"))
                .transpose()?,
            max_tracks,
            base_limits: h
                .base_limits
                .as_ref()
                .map(|b| BaseLimits::from_wire(b, "hello.base_limits"))
                .transpose()?
                .unwrap_or_default(),
        })
    }

    /// Number of signature bands the robot declared (0 when it sends none).
    pub fn signature_band_count(&self) -> usize {
        self.signature_bands.as_ref().map_or(0, |e| e.len().saturating_sub(1))
    }

    /// Wire form.
    pub fn to_wire(&self) -> wire::Hello {
        wire::Hello {
            robot_id: self.robot_id.to_string(),
            array: Some(self.array.to_wire()),
            software_version: self.software_version.clone(),
            protocol_version: PROTOCOL_VERSION,
            signature_bands: self
                .signature_bands
                .as_ref()
                .map(|e| wire::SignatureBands { band_edges_hz: e.clone() }),
            max_tracks: self.max_tracks.unwrap_or(0),
            base_limits: self.base_limits.to_wire(),
        }
    }
}

/// A wire value where 0 means unknown (`None`) and anything else must be
/// finite and within `[lo, hi]` (`range` says so in the error).
fn unknown_or_within(
    value: f64,
    field: &str,
    (lo, hi): (f64, f64),
    range: &'static str,
) -> Result<Option<f64>, ValidationError> {
    let v = finite(value, field)?;
    if !(v == 0.0 || (lo..=hi).contains(&v)) {
        return Err(ValidationError::new(field.to_string(), Problem::OutOfRange { value: v, range }));
    }
    Ok((v > 0.0).then_some(v))
}

impl TrackedDoa {
    fn from_wire(d: &wire::TrackedDoa, field: &str, limits: &Limits) -> Result<Self, ValidationError> {
        let direction_in_array =
            direction_from_wire(&d.direction_in_array, &format!("{field}.direction_in_array"), limits)?;
        let activity = finite(d.activity, &format!("{field}.activity"))?;
        if !(0.0..=1.0).contains(&activity) {
            return Err(ValidationError::new(
                format!("{field}.activity"),
                Problem::OutOfRange { value: activity, range: "[0, 1]" },
            ));
        }
        let sigma = unknown_or_within(
            d.angular_sigma_rad,
            &format!("{field}.angular_sigma_rad"),
            ANGULAR_SIGMA_RANGE_RAD,
            "0 (unknown) or [1e-4, π] rad",
        )?;
        let coherence = unknown_or_within(
            d.coherence,
            &format!("{field}.coherence"),
            (0.0, 1.0),
            "0 (unknown) or (0, 1]",
        )?;
        let floor_fit_range_m = unknown_or_within(
            d.floor_fit_range_m,
            &format!("{field}.floor_fit_range_m"),
            FLOOR_FIT_RANGE_M,
            "0 (none) or [0.1, 1000] m",
        )?;
        let field = format!("{field}.signature_db");
        let (lo, hi) = SIGNATURE_DB_RANGE;
        for (i, &v) in d.signature_db.iter().enumerate() {
            if !v.is_finite() {
                return Err(ValidationError::new(format!("{field}[{i}]"), Problem::NonFinite(v as f64)));
            }
            if !(lo..=hi).contains(&v) {
                return Err(ValidationError::new(
                    format!("{field}[{i}]"),
                    Problem::OutOfRange { value: v as f64, range: "[-200, 200] dB" },
                ));
            }
        }
        Ok(TrackedDoa {
            track_id: d.track_id,
            direction_in_array,
            activity,
            angular_sigma_rad: sigma,
            signature: (!d.signature_db.is_empty()).then(|| d.signature_db.clone()),
            coherence,
            floor_fit_range_m,
        })
    }

    /// Wire form.
    pub fn to_wire(&self) -> wire::TrackedDoa {
        wire::TrackedDoa {
            track_id: self.track_id,
            direction_in_array: Some(vec3_to_wire(&self.direction_in_array)),
            activity: self.activity,
            angular_sigma_rad: self.angular_sigma_rad.unwrap_or(0.0),
            signature_db: self.signature.clone().unwrap_or_default(),
            coherence: self.coherence.unwrap_or(0.0),
            floor_fit_range_m: self.floor_fit_range_m.unwrap_or(0.0),
        }
    }
}

impl Observation {
    /// Validates a wire observation (stateless checks; ordering is the receiver's job).
    pub fn from_wire(o: &wire::Observation, limits: &Limits) -> Result<Self, ValidationError> {
        let stamp = limits.stamp(o.stamp_ns, "observation.stamp_ns")?;
        let map_from_base = pose_from_wire(&o.map_from_base, "observation.map_from_base", limits)?;
        let pose_covariance =
            pose_covariance_from_wire(&o.map_from_base_covariance, "observation.map_from_base_covariance")?;
        if o.doas.len() > MAX_DOAS_PER_OBSERVATION {
            return Err(ValidationError::new(
                "observation.doas",
                Problem::WrongLength { expected: MAX_DOAS_PER_OBSERVATION, got: o.doas.len() },
            ));
        }
        let doas = o
            .doas
            .iter()
            .enumerate()
            .map(|(i, d)| TrackedDoa::from_wire(d, &format!("observation.doas[{i}]"), limits))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Observation { sequence: o.sequence, stamp, map_from_base, pose_covariance, doas })
    }

    /// Checks an observation against the hello of the stream it came on:
    /// at most the declared `max_tracks` DoAs, distinct track ids, and every
    /// signature with exactly the declared number of bands (none when the
    /// hello declared no bands). Errors name the field
    /// (`observation.doas`, `observation.doas[i].track_id`,
    /// `observation.doas[i].signature_db`).
    pub fn check_against(&self, hello: &Hello) -> Result<(), ValidationError> {
        if let Some(max) = hello.max_tracks
            && self.doas.len() > max as usize
        {
            return Err(ValidationError::new(
                "observation.doas",
                Problem::Invalid(format!(
                    "{} DoAs, more than the {max} the hello declared (hello.max_tracks)",
                    self.doas.len()
                )),
            ));
        }
        let bands = hello.signature_band_count();
        for (i, d) in self.doas.iter().enumerate() {
            if self.doas[..i].iter().any(|e| e.track_id == d.track_id) {
                return Err(ValidationError::new(
                    format!("observation.doas[{i}].track_id"),
                    Problem::Invalid(format!("track id {} appears twice in one observation", d.track_id)),
                ));
            }
            if let Some(s) = &d.signature
                && s.len() != bands
            {
                return Err(ValidationError::new(
                    format!("observation.doas[{i}].signature_db"),
                    if bands == 0 {
                        Problem::Invalid("a signature, but the hello declared no signature_bands".into())
                    } else {
                        Problem::WrongLength { expected: bands, got: s.len() }
                    },
                ));
            }
        }
        Ok(())
    }

    /// Wire form.
    pub fn to_wire(&self) -> wire::Observation {
        wire::Observation {
            sequence: self.sequence,
            stamp_ns: self.stamp.as_ns(),
            map_from_base: Some(pose_to_wire(&self.map_from_base)),
            map_from_base_covariance: self.pose_covariance.as_ref().map(pose_covariance_to_wire),
            doas: self.doas.iter().map(TrackedDoa::to_wire).collect(),
        }
    }
}

impl CommandState {
    /// From the wire enum value.
    pub fn from_wire(v: i32, field: &str) -> Result<Self, ValidationError> {
        match wire::CommandState::try_from(v) {
            Ok(wire::CommandState::Executing) => Ok(CommandState::Executing),
            Ok(wire::CommandState::Succeeded) => Ok(CommandState::Succeeded),
            Ok(wire::CommandState::Failed) => Ok(CommandState::Failed),
            Ok(wire::CommandState::Canceled) => Ok(CommandState::Canceled),
            Ok(wire::CommandState::Unspecified) => Err(ValidationError::new(field, Problem::Missing)),
            Err(_) => Err(ValidationError::new(field, Problem::UnknownEnum(v))),
        }
    }

    /// Wire enum.
    pub fn to_wire(self) -> wire::CommandState {
        match self {
            CommandState::Executing => wire::CommandState::Executing,
            CommandState::Succeeded => wire::CommandState::Succeeded,
            CommandState::Failed => wire::CommandState::Failed,
            CommandState::Canceled => wire::CommandState::Canceled,
        }
    }

    /// True once the command will make no more progress.
    pub fn is_final(self) -> bool {
        !matches!(self, CommandState::Executing)
    }
}

impl RepositionReason {
    /// Wire enum.
    pub fn to_wire(self) -> wire::RepositionReason {
        match self {
            RepositionReason::ThetaOutOfBand => wire::RepositionReason::ThetaOutOfBand,
            RepositionReason::GdopHigh => wire::RepositionReason::GdopHigh,
            RepositionReason::Improvement => wire::RepositionReason::Improvement,
            RepositionReason::FollowSource => wire::RepositionReason::FollowSource,
            RepositionReason::KeepOut => wire::RepositionReason::KeepOut,
        }
    }

    /// From the wire enum value.
    pub fn from_wire(v: i32, field: &str) -> Result<Self, ValidationError> {
        match wire::RepositionReason::try_from(v) {
            Ok(wire::RepositionReason::ThetaOutOfBand) => Ok(RepositionReason::ThetaOutOfBand),
            Ok(wire::RepositionReason::GdopHigh) => Ok(RepositionReason::GdopHigh),
            Ok(wire::RepositionReason::Improvement) => Ok(RepositionReason::Improvement),
            Ok(wire::RepositionReason::FollowSource) => Ok(RepositionReason::FollowSource),
            Ok(wire::RepositionReason::KeepOut) => Ok(RepositionReason::KeepOut),
            Ok(wire::RepositionReason::Unspecified) => Err(ValidationError::new(field, Problem::Missing)),
            Err(_) => Err(ValidationError::new(field, Problem::UnknownEnum(v))),
        }
    }
}

impl RepositionCommand {
    /// Wire form.
    pub fn to_wire(&self) -> wire::RepositionCommand {
        wire::RepositionCommand {
            command_id: self.command_id,
            goal_map_from_base: Some(pose_to_wire(&self.goal_map_from_base)),
            look_at_in_map_m: Some(vec3_to_wire(&self.look_at_in_map.coords)),
            reason: self.reason.to_wire() as i32,
            detail: self.detail.clone(),
            deadline_ns: self.deadline.as_ns(),
            issued_ns: self.issued.as_ns(),
        }
    }

    /// Validates a wire command (agent side). Stamps are not checked against a clock.
    pub fn from_wire(c: &wire::RepositionCommand, limits: &Limits) -> Result<Self, ValidationError> {
        Ok(RepositionCommand {
            command_id: c.command_id,
            goal_map_from_base: pose_from_wire(
                &c.goal_map_from_base,
                "reposition.goal_map_from_base",
                limits,
            )?,
            look_at_in_map: point_from_wire(&c.look_at_in_map_m, "reposition.look_at_in_map_m")?,
            reason: RepositionReason::from_wire(c.reason, "reposition.reason")?,
            detail: c.detail.clone(),
            deadline: Stamp::from_ns(c.deadline_ns),
            issued: Stamp::from_ns(c.issued_ns),
        })
    }
}

impl RobotInput {
    /// Validates any robot message. An empty envelope is an error naming `msg`.
    pub fn from_wire(m: &wire::RobotMessage, limits: &Limits) -> Result<Self, ValidationError> {
        use wire::robot_message::Msg;
        match &m.msg {
            None => Err(ValidationError::new("msg", Problem::Missing)),
            Some(Msg::Hello(h)) => Hello::from_wire(h, limits).map(RobotInput::Hello),
            Some(Msg::Observation(o)) => Observation::from_wire(o, limits).map(RobotInput::Observation),
            Some(Msg::Heartbeat(h)) => {
                limits.stamp(h.stamp_ns, "heartbeat.stamp_ns").map(RobotInput::Heartbeat)
            }
            Some(Msg::CommandAck(a)) => Ok(RobotInput::CommandAck(CommandAck {
                command_id: a.command_id,
                accepted: a.accepted,
                reason: text(&a.reason, "command_ack.reason")?,
            })),
            Some(Msg::CommandProgress(p)) => {
                let d = finite(p.distance_remaining_m, "command_progress.distance_remaining_m")?;
                Ok(RobotInput::CommandProgress(CommandProgress {
                    command_id: p.command_id,
                    state: CommandState::from_wire(p.state, "command_progress.state")?,
                    distance_remaining_m: (d >= 0.0).then_some(d),
                    detail: text(&p.detail, "command_progress.detail")?,
                }))
            }
        }
    }

    /// Wire form.
    pub fn to_wire(&self) -> wire::RobotMessage {
        use wire::robot_message::Msg;
        let msg = match self {
            RobotInput::Hello(h) => Msg::Hello(h.to_wire()),
            RobotInput::Observation(o) => Msg::Observation(o.to_wire()),
            RobotInput::Heartbeat(s) => Msg::Heartbeat(wire::Heartbeat { stamp_ns: s.as_ns() }),
            RobotInput::CommandAck(a) => Msg::CommandAck(wire::CommandAck {
                command_id: a.command_id,
                accepted: a.accepted,
                reason: a.reason.clone(),
            }),
            RobotInput::CommandProgress(p) => Msg::CommandProgress(wire::CommandProgress {
                command_id: p.command_id,
                state: p.state.to_wire() as i32,
                distance_remaining_m: p.distance_remaining_m.unwrap_or(-1.0),
                detail: p.detail.clone(),
            }),
        };
        wire::RobotMessage { msg: Some(msg) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn limits() -> Limits {
        Limits::at(Stamp::from_ns(2_000_000_000_000_000_000))
    }

    fn observation() -> Observation {
        Observation {
            sequence: 7,
            stamp: Stamp::from_ns(1_999_999_999_000_000_000),
            map_from_base: Isometry3::new(Vector3::new(1.0, 2.0, 0.0), Vector3::new(0.0, 0.0, 0.7)),
            pose_covariance: Some(Matrix6::identity() * 1e-4),
            doas: vec![TrackedDoa {
                track_id: 3,
                direction_in_array: Unit::new_normalize(Vector3::new(1.0, 1.0, 0.3)),
                activity: 0.9,
                angular_sigma_rad: Some(0.05),
                signature: Some(vec![-10.0, 3.5, 0.0]),
                coherence: Some(0.3),
                floor_fit_range_m: None,
            }],
        }
    }

    #[test]
    fn observation_round_trip() {
        let o = observation();
        let back = Observation::from_wire(&o.to_wire(), &limits()).unwrap();
        assert_eq!(back.sequence, 7);
        assert_eq!(back.stamp, o.stamp);
        assert!(
            (back.doas[0].direction_in_array.into_inner() - o.doas[0].direction_in_array.into_inner()).norm()
                < 1e-12
        );
        assert_eq!(back.doas[0].angular_sigma_rad, Some(0.05));
        assert_eq!(back.doas[0].coherence, Some(0.3));
        let mut unknown = o.clone();
        unknown.doas[0].coherence = None;
        assert_eq!(Observation::from_wire(&unknown.to_wire(), &limits()).unwrap().doas[0].coherence, None);
        let mut fitted = o.clone();
        fitted.doas[0].floor_fit_range_m = Some(4.5);
        let back = Observation::from_wire(&fitted.to_wire(), &limits()).unwrap();
        assert_eq!(back.doas[0].floor_fit_range_m, Some(4.5));
    }

    #[test]
    fn bad_observation_fields_are_named() {
        let l = limits();
        let mut w = observation().to_wire();
        w.doas[0].activity = 1.5;
        assert_eq!(Observation::from_wire(&w, &l).unwrap_err().field, "observation.doas[0].activity");
        for bad in [f64::NAN, -0.1, 1.5] {
            let mut w = observation().to_wire();
            w.doas[0].coherence = bad;
            assert_eq!(Observation::from_wire(&w, &l).unwrap_err().field, "observation.doas[0].coherence");
        }
        for bad in [f64::NAN, f64::INFINITY, -1.0, 0.05, 2000.0] {
            let mut w = observation().to_wire();
            w.doas[0].floor_fit_range_m = bad;
            assert_eq!(
                Observation::from_wire(&w, &l).unwrap_err().field,
                "observation.doas[0].floor_fit_range_m",
                "{bad}"
            );
        }
        let mut w = observation().to_wire();
        w.map_from_base = None;
        assert_eq!(Observation::from_wire(&w, &l).unwrap_err().field, "observation.map_from_base");
        let mut w = observation().to_wire();
        w.doas[0].angular_sigma_rad = -0.1;
        assert_eq!(
            Observation::from_wire(&w, &l).unwrap_err().field,
            "observation.doas[0].angular_sigma_rad"
        );
        let mut w = observation().to_wire();
        w.stamp_ns = i64::MAX;
        assert_eq!(Observation::from_wire(&w, &l).unwrap_err().field, "observation.stamp_ns");
    }

    #[test]
    fn hello_checks() {
        let l = limits();
        let h = Hello {
            robot_id: RobotId::parse("r1", "id").unwrap(),
            array: ArrayInfo {
                base_from_array: Isometry3::translation(0.0, 0.0, 0.48),
                microphone_count: 16,
                preset: Some("16soundsusb-pioneer".into()),
                microphone_positions: vec![],
                srp_band_hz: None,
                direct_path_elevations: false,
            },
            software_version: "test".into(),
            signature_bands: Some(vec![100.0, 1000.0, 7200.0]),
            max_tracks: Some(4),
            base_limits: Default::default(),
        };
        assert_eq!(Hello::from_wire(&h.to_wire(), &l).unwrap(), h);
        let mut w = h.to_wire();
        w.array.as_mut().unwrap().microphone_count = 1;
        assert_eq!(Hello::from_wire(&w, &l).unwrap_err().field, "hello.array.microphone_count");
        let mut w = h.to_wire();
        w.array = None;
        assert_eq!(Hello::from_wire(&w, &l).unwrap_err().field, "hello.array");
        let mut w = h.to_wire();
        w.protocol_version = 9;
        assert_eq!(Hello::from_wire(&w, &l).unwrap_err().field, "hello.protocol_version");
        // The SRP band: absent, or two values 0 < low < high <= 200 kHz.
        let banded =
            Hello { array: ArrayInfo { srp_band_hz: Some([100.0, 8000.0]), ..h.array.clone() }, ..h.clone() };
        assert_eq!(Hello::from_wire(&banded.to_wire(), &l).unwrap(), banded);
        for (band, field) in [
            (vec![100.0], "hello.array.srp_band_hz"),
            (vec![100.0, 200.0, 300.0], "hello.array.srp_band_hz"),
            (vec![0.0, 8000.0], "hello.array.srp_band_hz[0]"),
            (vec![f64::NAN, 8000.0], "hello.array.srp_band_hz[0]"),
            (vec![8000.0, 100.0], "hello.array.srp_band_hz[1]"),
            (vec![100.0, f64::INFINITY], "hello.array.srp_band_hz[1]"),
        ] {
            let mut w = h.to_wire();
            w.array.as_mut().unwrap().srp_band_hz = band.clone();
            assert_eq!(Hello::from_wire(&w, &l).unwrap_err().field, field, "{band:?}");
        }
    }

    /// A base's declared limits round-trip; 0 (or absent) is unknown, and
    /// values out of range or not finite are refused by name.
    #[test]
    fn hello_base_limits_checks() {
        let l = limits();
        let declared = BaseLimits { max_speed_m_per_s: Some(0.22), max_turn_rate_deg_per_s: Some(160.0) };
        let h = Hello { base_limits: declared, ..hello_with_bands() };
        assert_eq!(Hello::from_wire(&h.to_wire(), &l).unwrap(), h);
        // Unknown: no message on the wire, and zeros read as unknown.
        let plain = hello_with_bands();
        assert!(plain.to_wire().base_limits.is_none());
        let mut w = plain.to_wire();
        w.base_limits = Some(wire::BaseLimits { max_speed_m_per_s: 0.5, max_turn_rate_deg_per_s: 0.0 });
        let read = Hello::from_wire(&w, &l).unwrap().base_limits;
        assert_eq!(read, BaseLimits { max_speed_m_per_s: Some(0.5), max_turn_rate_deg_per_s: None });
        for (speed, turn, field) in [
            (-0.1, 0.0, "hello.base_limits.max_speed_m_per_s"),
            (f64::NAN, 0.0, "hello.base_limits.max_speed_m_per_s"),
            (10.5, 0.0, "hello.base_limits.max_speed_m_per_s"),
            (0.5, f64::INFINITY, "hello.base_limits.max_turn_rate_deg_per_s"),
            (0.5, -30.0, "hello.base_limits.max_turn_rate_deg_per_s"),
            (0.5, 4000.0, "hello.base_limits.max_turn_rate_deg_per_s"),
        ] {
            let mut w = plain.to_wire();
            w.base_limits =
                Some(wire::BaseLimits { max_speed_m_per_s: speed, max_turn_rate_deg_per_s: turn });
            let e = Hello::from_wire(&w, &l).unwrap_err();
            assert_eq!(e.field, field, "{speed} {turn}: {e}");
        }
    }

    fn hello_with_bands() -> Hello {
        Hello {
            robot_id: RobotId::parse("r1", "id").unwrap(),
            array: ArrayInfo {
                base_from_array: Isometry3::identity(),
                microphone_count: 4,
                preset: None,
                microphone_positions: vec![],
                srp_band_hz: None,
                direct_path_elevations: false,
            },
            software_version: String::new(),
            signature_bands: Some(vec![100.0, 1000.0, 3000.0, 7200.0]),
            max_tracks: Some(2),
            base_limits: Default::default(),
        }
    }

    #[test]
    fn signatures_round_trip_and_bad_values_are_named() {
        let l = limits();
        let o = observation();
        assert_eq!(Observation::from_wire(&o.to_wire(), &l).unwrap().doas[0].signature, o.doas[0].signature);
        // Empty on the wire is "no signature".
        let mut w = o.to_wire();
        w.doas[0].signature_db.clear();
        assert_eq!(Observation::from_wire(&w, &l).unwrap().doas[0].signature, None);
        for bad in [f32::NAN, f32::INFINITY, 250.0, -201.0] {
            let mut w = o.to_wire();
            w.doas[0].signature_db[1] = bad;
            assert_eq!(
                Observation::from_wire(&w, &l).unwrap_err().field,
                "observation.doas[0].signature_db[1]",
                "{bad}"
            );
        }
    }

    #[test]
    fn hello_signature_layout_checks() {
        let l = limits();
        let h = hello_with_bands();
        let back = Hello::from_wire(&h.to_wire(), &l).unwrap();
        assert_eq!(back, h);
        assert_eq!(back.signature_band_count(), 3);
        let mut w = h.to_wire();
        w.signature_bands = None;
        w.max_tracks = 0;
        let none = Hello::from_wire(&w, &l).unwrap();
        assert_eq!((none.signature_bands, none.max_tracks), (None, None));
        let field = "hello.signature_bands.band_edges_hz";
        let cases: [(Vec<f64>, String); 6] = [
            (vec![], field.into()),
            (vec![100.0], field.into()),
            ((1..=66).map(|i| i as f64 * 100.0).collect(), field.into()),
            (vec![100.0, f64::NAN, 300.0], format!("{field}[1]")),
            (vec![0.0, 200.0], format!("{field}[0]")),
            (vec![100.0, 300.0, 300.0], format!("{field}[2]")),
        ];
        for (edges, f) in cases {
            let mut w = h.to_wire();
            w.signature_bands = Some(wire::SignatureBands { band_edges_hz: edges.clone() });
            assert_eq!(Hello::from_wire(&w, &l).unwrap_err().field, f, "{edges:?}");
        }
        let mut w = h.to_wire();
        w.signature_bands =
            Some(wire::SignatureBands { band_edges_hz: (1..=65).map(|i| i as f64).collect() });
        assert_eq!(Hello::from_wire(&w, &l).unwrap().signature_band_count(), 64);
        let mut w = h.to_wire();
        w.max_tracks = 65;
        assert_eq!(Hello::from_wire(&w, &l).unwrap_err().field, "hello.max_tracks");
    }

    #[test]
    fn observations_are_checked_against_the_hello() {
        let h = hello_with_bands();
        let doa = |id: u64, bands: Option<usize>| TrackedDoa {
            track_id: id,
            direction_in_array: Vector3::z_axis(),
            activity: 0.5,
            angular_sigma_rad: None,
            signature: bands.map(|b| vec![1.0; b]),
            coherence: None,
            floor_fit_range_m: None,
        };
        let with = |doas: Vec<TrackedDoa>| Observation { doas, ..observation() };
        assert!(with(vec![doa(1, Some(3)), doa(2, None)]).check_against(&h).is_ok());
        assert!(with(vec![]).check_against(&h).is_ok());
        let field = |o: Observation, h: &Hello| o.check_against(h).unwrap_err().field;
        assert_eq!(
            field(with(vec![doa(1, Some(3)), doa(2, Some(4))]), &h),
            "observation.doas[1].signature_db"
        );
        assert_eq!(field(with(vec![doa(1, None), doa(1, None)]), &h), "observation.doas[1].track_id");
        assert_eq!(field(with(vec![doa(1, None), doa(2, None), doa(3, None)]), &h), "observation.doas");
        let plain = Hello { signature_bands: None, max_tracks: None, ..h };
        assert!(with(vec![doa(1, None), doa(2, None), doa(3, None)]).check_against(&plain).is_ok());
        assert_eq!(field(with(vec![doa(1, Some(3))]), &plain), "observation.doas[0].signature_db");
    }

    #[test]
    fn empty_envelope() {
        let e = RobotInput::from_wire(&wire::RobotMessage { msg: None }, &limits()).unwrap_err();
        assert_eq!(e.field, "msg");
    }
}

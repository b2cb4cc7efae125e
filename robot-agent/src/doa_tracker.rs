//! Tracking of directions of arrival on the sphere: ids, activity and honest
//! angular uncertainty.
//!
//! Each track is a constant-velocity Kalman filter on the sphere
//! ([`sphere_kf`]). Births do not look at absolute energy (ODAS's stock model
//! never tracks a clean 20 dB source because its energy model expects other
//! levels): they look at what separates a source from noise under PHAT,
//! whatever the level:
//! - *coherence*: a potential's `energy` is its PHAT coherence (1 for a
//!   noise-free plane wave, ≈ 0 for incoherent noise, ≈ 0.4 for a source at
//!   0 dB SNR); a birth needs at least [`TrackerConfig::birth_min_coherence`],
//!   raised to what diffuse noise alone gives in that direction plus a margin
//!   (diffuse noise is coherent between close microphones: a small planar
//!   array sees it as a source at its zenith, see [`crate::srp::diffuse`]);
//! - *consistency*: the peak must come back within
//!   [`TrackerConfig::birth_gate_deg`] of its previous position in
//!   `birth_min_hits` of `birth_window_frames` consecutive frames. Noise peaks
//!   wander; a source's stay put (or move smoothly).
//!
//! Candidates that pass get an id (monotonic, never reused) as a tentative
//! track (`confirmed = false`), confirmed after `confirm_hits` more
//! associated frames. A track dies after `max_coast_s` without a detection;
//! while it coasts, its angular velocity decays
//! (`coast_velocity_time_constant_s`), so it holds where the source was
//! rather than drifting on a velocity learnt from scattered detections, and
//! it is *reported* only while its last detection is recent
//! (`report_max_silence_s`). Holding and reporting are separate because
//! talkers pause between phrases: the id survives a pause (the same talker
//! resumes under the same id) but nothing stale is sent as a bearing.
//!
//! Several sources: speech is sparse in time, so two talkers mostly alternate
//! from hop to hop (one dominates each 16 ms frame) rather than giving two
//! peaks in the same frame. Each talker's track is fed by its own syllables
//! and coasts through the other's; the birth gate (10°) is wide enough for
//! the hop-to-hop scatter of single-frame peaks in a reverberant room
//! (±5–10° at RT60 0.45 s, 2–3 m), and still far too narrow for noise peaks,
//! which land anywhere on the hemisphere (a 10° cap is 1.5 % of it; six such
//! coincidences in sixteen hops do not happen).
//!
//! Because overlapping talkers alternate, a talker dominates only some of the
//! frames while another speaks: from one robot two talkers 20° apart each won
//! about 40 % of the frames (`two-talkers`, seed 1). Births therefore need
//! 6 hits in 16 frames and confirmation 5 associated frames within 24, not a
//! majority of consecutive frames; with 7 of 10 and 5 of 12 the second talker
//! made a tentative track every few tenths of a second that never confirmed,
//! and was first tracked 5 s after it began, when the first talker paused.
//! Over seeds 1–5 this took `two-talkers` from OSPA 0.37 m to 0.33 m
//! (detection 0.84 → 0.92), with noise alone still never making a track
//! (`tests/tracking.rs`).
//!
//! A weak steady source (a fan 14 dB below two talkers) is heard only in the
//! talkers' pauses, at a PHAT coherence of 0.1–0.18; the birth floor
//! (`birth_min_coherence` 0.08, `diffuse_margin` 0.03 above the modelled
//! diffuse response, plus 4 σ of the noise coherence) admits it, while the
//! strongest peak of incoherent sensor noise on a 16-microphone array stays
//! near 0.03 (0.033 at most over 10 s of white noise) and the
//! hit-consistency rule still has to be met.
//!
//! Masking: a silence is evidence that a source stopped only where it could
//! have been heard. Each track keeps the level at which it is heard (the
//! band's mean power per microphone and bin in the hops of its detections,
//! averaged in dB, [`crate::srp::Srp::band_level_db`]); a hop at least
//! [`TrackerConfig::masking_margin_db`] (6 dB) louder than that *masks* its
//! silence. A confirmed track whose silence was masked except for at most
//! `report_max_silence_s` of it is kept and reported for up to
//! [`TrackerConfig::masked_report_max_silence_s`] (6 s); its direction then
//! coasts and its σ grows with the filter's prediction (≈ 3–4° after 2 s,
//! 6–7° after 6 s for the fan in `cocktail`).
//! Only while the robot stays put: once the base has moved more than
//! [`TrackerConfig::masked_max_travel_m`] (0.1 m) since the track's last
//! detection (positions from the SLAM poses the pipeline follows), it is no
//! longer held (`held_by_masking`) and the pipeline stops reporting it (a
//! bearing heard from elsewhere would make the coordinator's rays meet where
//! nothing is).
//! Why: PHAT coherence is scale-free, so a fan 14 dB below two talkers gives
//! the same coherence (0.12–0.15 at 2–3 m, RT60 0.5 s) as they do when it is
//! heard, but it is heard only in their pauses; while both speak its
//! secondary peaks sink into the noise peaks (coherence 0.02–0.06). Without
//! masking its tracks stopped being reported 0.3 s into every stretch of
//! double talk, and two robots seldom reported it at once. A talker who
//! stops while another speaks at the same level is not masked (the frames
//! are no louder than the level it was heard at) and is dropped after 0.3 s
//! as before. Measured in `cocktail`, seeds 1–5 (`BENCHMARKS.md`, "Masked
//! silences"): the fan's detection 0.57–0.68 → 0.69–0.85, OSPA 0.370 →
//! 0.318 m; `two-talkers` and `crossing` (no weak source) unchanged.
//!
//! The margin is where a source stops being detected, measured: for the fan's
//! confirmed tracks in `cocktail` (Pioneer and TurtleBot, seeds 41 and 42, not
//! among the scored seeds), the share of hops with a detection is 0.69 within
//! 2 dB of the track's level, 0.18 at +2 to +4 dB, 0.025 at +4 to +6 dB,
//! 0.002 at +6 to +8 dB and none of 11,500 hops beyond (seeds 3 and 7: 0.78,
//! 0.21, 0.024, 0.004, 3 in 9,200). A hop 6 dB louder than a steady source's
//! level, the other sounds then carrying three quarters of its power, does
//! not show that source's peak among the hop's potentials, so its silence
//! there is no evidence. With a 10 dB margin the fan's hops at +6 to +10 dB
//! (a fifth of its masked ones) counted as audible silence, and its tracks
//! were dropped 0.3 s into the talkers' quieter syllables. The cost: a
//! talker who stops while another is 6 dB louder at a robot (not 10) is held
//! by that robot while the other keeps its silence masked (in `cocktail`
//! seed 4 the stopped talker stayed published 0.9 s longer: the louder
//! talker's next pause unmasks it). `BENCHMARKS.md`, "The masking margin
//! where a steady source stops being heard".
//!
//! The limit is 6 s because stretches of double talk last longer than 3 s:
//! the fan, heard only where both talkers pause at once, went unheard for
//! 3–6 s at a time in `cocktail`, and with a 3 s limit its tracks ended in
//! the middle of such stretches (seed 7: no robot sent it for 2.8 s at
//! 10.3 s and 5.7 s at 30.7 s). A held bearing stays where the source was
//! heard, so the limit is also how long a robot vouches for a source that
//! might have stopped unheard; the coordinator sees its σ grow meanwhile.
//!
//! Turning robots: tracks are kept in the array frame, and the array turns
//! with the robot. Where the driver gives the base's orientation (SLAM, per
//! hop; [`crate::pipeline::Pipeline::set_base_orientation`]), every track and
//! candidate is re-expressed in the turned frame ([`DoaTracker::change_frame`])
//! once the turn exceeds a dead band (1°, above SLAM's yaw jitter), so a source
//! that stays put in the room keeps its track and id through a turn. Measured
//! in `tests/tracking.rs`: a robot turning 60° and back at 120°/s with abrupt
//! starts, a static source at 10 dB: 4 ids and 235 frames without exactly one
//! track without the orientation; 1 id, median error 0.11° with it. In the
//! `cocktail-active` scenario (three robots driven by the planner while two
//! talkers and a fan play), seeds 1–2: ghosts fell from 0.58–0.70/s to
//! 0.06–0.11/s and id switches from 19–24 to 3–6.
//!
//! Nearly planar arrays ([`TrackerConfig::shaped_measurement_noise`],
//! experimental, off by default): an array measures a direction through the delays `qᵢ·d/c` of
//! its microphones (`qᵢ` about their centroid), so how well it measures a
//! small turn `δ` of the source along a tangent `t` goes with the spread of
//! `qᵢ·t`: the Fisher information of the direction in the tangent plane is
//! proportional to `M = Eᵀ(Σᵢ qᵢqᵢᵀ)E` (`E` the tangent basis). Every
//! preset is (nearly) planar: the 16SoundsUSB rings are 1.5 cm apart in
//! height across 0.49 m. Near the array's plane the elevation tangent
//! projects onto the plane as `sin e`, so elevation is measured `~1/sin e`
//! times worse than azimuth (about 5× at 10° for the Pioneer layout), and
//! in a room the vertical family of reflections (floor, ceiling, their
//! repeats: all at the source's azimuth) moves single-frame peaks along
//! exactly that axis. Each measurement's
//! covariance is therefore `r²·S` with `S ∝ M⁻¹`, 1 along the best-measured
//! axis and at most `max_shape_ratio²` (6² by default) along the worst; the
//! learnt `r²` is that of the best axis (`E[yᵀS⁻¹y]/2 = r² + tr(S⁻¹P)/2`),
//! the gates, `birth_gate_deg` and `merge_deg` measure angles in its units
//! (`√(yᵀS⁻¹y)`). The reported σ is still the filter's per-axis σ,
//! `√(tr P_θθ / 2)`, which now carries the elevation's larger variance (a
//! σ along the best axis alone was tried: it left the elevation
//! over-trusted by the coordinator, and one `corner-start` run's RSE p95
//! went to 1.2 m).
//! Measured on a talker 4–6 m from a Pioneer array 1 m from two walls
//! (RT60 0.5 s, `tests/tests/hearing_reverb.rs`, `corner_sweep`, seeds 1–8):
//! the single-frame peaks' azimuth was right (median error under 1°) but
//! their elevation scattered by ±5–10° and read +6 to +12° high at the
//! median, so the isotropic 10° birth gate kept tentative tracks from
//! confirming (seed 1: three tentative tracks died within 4 s), and in
//! seeds 2 and 3 tracks were confirmed on the ceiling's image 24–37° above
//! the source (86 and 74 % of hops). With the shaped noise, hops with a
//! confirmed track within 10° of the source's azimuth went from
//! 18/96/91/100/100/44/100/65 % to 92/96/92/100/100/92/100/69 % (the 96
//! and 91 were the image tracks), and hops with a track more than 20° from
//! the source from 86, 74 and 19 % in three seeds to at most 6 %. The
//! elevation is still read high by the reflections (what the
//! coordinator's floor-image model is for): within 10° of the direct path,
//! 51.6 → 57.3 % of hops on average in the corner, 70.1 → 67.6 % 2.5 m
//! from the walls (`BENCHMARKS.md`, "A robot in a corner").
//! Why it is off: with static robots it helps (`cocktail`, seeds 1–10: OSPA
//! 0.193 → 0.176 m; `two-talkers` 0.159 → 0.149 m), but with robots that
//! move among several sources it costs detection and adds ghosts
//! (`cocktail-active`: detection 0.894 → 0.862, ghosts 0.037 → 0.069/s, 3
//! id switches in 10 runs instead of 0; `crossing`: OSPA 0.410 → 0.419 m).
//! Why is not known: merging on the plain angle, process variance for the
//! parallax of the robot's own motion, the azimuth's σ reported apart and
//! leaving the ReSpeaker 6 unshaped were each tried and none recovered it
//! (`BENCHMARKS.md`, "Elevation weighed by the array's geometry").
//! One source and active positioning: no change beyond the sweep's noise.
//!
//! Peaks on the region's edge ([`TrackerConfig::edge_peaks_along_edge_only`],
//! experimental, off by default): the search keeps its peaks inside the array's region
//! (the upper hemisphere for every preset), so a maximum that lies beyond
//! it is reported clamped onto the edge, on the horizon. Such a peak says
//! where around the region's axis the source is (its azimuth), and of its
//! elevation only "at the edge or beyond": a low source read low by the
//! plane-wave model, or, in a room, a ridge running down towards the
//! floor's image. Taken at face value it pulls the track to the horizon,
//! and it breaks the birth chain of a source whose peaks alternate between
//! its own elevation and the edge (a 10° gate against a source 9° up). So
//! an edge peak is compared with a track or birth candidate, and updates
//! it, at that track's or candidate's angle from the axis: an azimuth-only
//! measurement. Measured (`BENCHMARKS.md`, "Peaks on the region's edge"):
//! the TurtleBot's reverberant case 1006 confirms from the start instead
//! of after 1.1 s, the distance sweep's 6 m estimates lose their height
//! bias, `corner-start` stays in band more, and a source just above the
//! arrays (`low-source`) is no longer placed at its mirror even without
//! the coordinator's upper branch; the reported DoAs of the reverberant set
//! read higher against the direct path (the clamped peaks had been
//! offsetting the reflections' upward pull), while against what the
//! coordinator's floor-image model expects them to be they are closer.
//! Why it is off: in `cocktail`'s own seed (31; two talkers and a fan) it
//! made 0.44 ghosts/s instead of 0.037 (OSPA 0.164 → 0.247 m), though seeds
//! 1–5 of the same scene were unchanged. One possible cause, not examined:
//! an edge peak gated on its azimuth alone can join the track of another
//! source at that azimuth and another height.
//!
//! Uncertainty: the measurement variance of each track is learnt from its
//! innovations (so it follows the SNR and the array), and the reported σ is
//! the filter's per-axis angular standard deviation. On free-field data it
//! is slightly conservative (mean e²/(2σ²) ≈ 0.4–0.9 for static sources,
//! whose errors the filter's process noise over-allows). It knows nothing of
//! reverberation: reflections bias DoAs consistently for a static geometry,
//! which no single-array innovation can reveal.

pub mod config;
pub mod sphere_kf;

use nalgebra::{Matrix2, Matrix3, Point3, Rotation3, Unit, Vector2, Vector3};

use crate::array::SearchRegion;
use crate::error::AgentError;
use crate::srp::PotentialSource;
pub use crate::srp::diffuse::NoiseModel;
pub use config::TrackerConfig;
use sphere_kf::SphereKf;

/// A potential within this angle of the search region's edge lies on it
/// (the search clamps peaks exactly onto it), radians.
const EDGE_MARGIN_RAD: f64 = 1e-9;

/// Weight of each new hit in a track's average coherence (about the last
/// 20 hits, 0.16 s of a source heard every hop).
pub const COHERENCE_WEIGHT: f64 = 0.05;

/// Largest accepted [`TrackerConfig::max_tracks`].
pub const MAX_TRACKS: usize = 64;

/// How well the array measures each tangent direction: the second moment
/// `C = Σᵢ qᵢqᵢᵀ` of the microphones' positions about their centroid. A
/// displacement `δ` of the source along a tangent `t` moves the arrivals by
/// `qᵢ·t δ/c`, so the Fisher information of the direction in the tangent
/// plane is proportional to `M = Eᵀ C E` (`E` the tangent basis): isotropic
/// for a 3D array, and for a (nearly) planar array near its plane, small
/// along the elevation (`∝ sin² e`). See the module docs, "Nearly planar
/// arrays".
#[derive(Clone, Copy, Debug)]
struct Shape {
    moment: Matrix3<f64>,
    /// Largest variance ratio between the worst and the best axis.
    max_ratio2: f64,
}

impl Shape {
    /// The measurement covariance's shape `S` at the tangent basis
    /// `(e₁, e₂)`, 1 along the best-measured axis (`S ∝ M⁻¹`, its ratio
    /// capped), and its inverse.
    fn at(&self, e1: &Vector3<f64>, e2: &Vector3<f64>) -> (Matrix2<f64>, Matrix2<f64>) {
        let c = &self.moment;
        let off = e1.dot(&(c * e2));
        let m = Matrix2::new(e1.dot(&(c * e1)), off, off, e2.dot(&(c * e2)));
        let eig = m.symmetric_eigen();
        let (l, v) = (eig.eigenvalues, eig.eigenvectors);
        let top = l[0].max(l[1]);
        if !(top > 0.0 && top.is_finite()) {
            return (Matrix2::identity(), Matrix2::identity());
        }
        let ratio = |x: f64| (top / x.max(top / self.max_ratio2)).clamp(1.0, self.max_ratio2);
        let (r0, r1) = (ratio(l[0]), ratio(l[1]));
        let shape = v * Matrix2::new(r0, 0.0, 0.0, r1) * v.transpose();
        let inverse = v * Matrix2::new(1.0 / r0, 0.0, 0.0, 1.0 / r1) * v.transpose();
        (shape, inverse)
    }

    /// The angle from `u` to `v` in units of the best-measured axis:
    /// `√(yᵀ S⁻¹ y)`, `y` the log map of `v` at `u`.
    fn angle(shape: Option<&Shape>, u: &Vector3<f64>, v: &Vector3<f64>) -> f64 {
        let Some(shape) = shape else { return u.angle(v) };
        if u.dot(v) < 0.0 && u.cross(v).norm() < 1e-15 {
            return std::f64::consts::PI; // antipodes: the log map is undefined
        }
        let (e1, e2) = crate::srp::refine::tangent_basis(&Unit::new_unchecked(*u));
        let y = sphere_kf::log_map(u, (&e1, &e2), v);
        let (_, inverse) = shape.at(&e1, &e2);
        shape.length(&y, &inverse)
    }

    /// `√(yᵀ S⁻¹ y)`: the length of tangent vector `y` in units of the
    /// best-measured axis.
    fn length(&self, y: &Vector2<f64>, inverse: &Matrix2<f64>) -> f64 {
        (y.transpose() * inverse * y)[(0, 0)].max(0.0).sqrt()
    }
}

/// One tracked direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackedDirection {
    /// Stable id, monotonic over the tracker's life, never reused.
    pub track_id: u64,
    /// Filtered direction, unit vector, array frame.
    pub direction_in_array: Unit<Vector3<f64>>,
    /// How active the source is, in [0, 1] (smoothed detection rate).
    pub activity: f64,
    /// 1-σ angular uncertainty per tangent axis, radians.
    pub angular_sigma_rad: f64,
    /// Whether the track passed confirmation (tentative tracks are `false`).
    pub confirmed: bool,
    /// Time since the track's last detection, seconds (0 when detected this hop).
    pub silent_s: f64,
    /// The part of `silent_s` in which the track was not masked (hops less
    /// than `masking_margin_db` louder than its own level), seconds.
    pub audible_silent_s: f64,
    /// Silent for longer than `report_max_silence_s` would allow, but held
    /// by masking: its silence was masked except for at most that long, it
    /// is within `masked_report_max_silence_s`, and the base has moved at
    /// most `masked_max_travel_m` since its last detection (see the module
    /// docs, "Masking").
    pub held_by_masking: bool,
    /// PHAT coherence of the potentials that fed the track, averaged over
    /// about its last 20 ([`COHERENCE_WEIGHT`]).
    pub coherence: f64,
}

impl TrackedDirection {
    /// The DoA as the agent sends it to the coordinator: activity clamped to
    /// [0, 1]; σ combined in quadrature with `sigma_floor_rad`, dropped when not
    /// a positive finite number, capped at π.
    pub fn to_doa(&self, sigma_floor_rad: f64) -> soundmap_proto::TrackedDoa {
        let sigma = self.angular_sigma_rad.hypot(sigma_floor_rad.max(0.0));
        soundmap_proto::TrackedDoa {
            track_id: self.track_id,
            direction_in_array: self.direction_in_array,
            activity: self.activity.clamp(0.0, 1.0),
            angular_sigma_rad: (sigma.is_finite() && sigma > 0.0).then_some(sigma.min(std::f64::consts::PI)),
            signature: None,
            coherence: (self.coherence.is_finite() && self.coherence > 0.0)
                .then_some(self.coherence.min(1.0)),
            floor_fit_range_m: None,
        }
    }
}

#[derive(Clone, Debug)]
struct Track {
    id: u64,
    kf: SphereKf,
    /// Learnt measurement variance per axis, rad².
    r2: f64,
    activity: f64,
    /// Average PHAT coherence of the potentials associated with it.
    coherence: f64,
    born_frame: u64,
    last_hit_frame: u64,
    /// Hops since the last detection that were not loud enough to mask it.
    unmasked_silent: u32,
    /// Frame level at its detections, averaged (dB; NaN until known).
    level_db: f64,
    /// Where the base was at its last detection (map, m), if known.
    heard_from: Option<Point3<f64>>,
    hits_since_birth: u32,
    confirmed: bool,
}

#[derive(Clone, Copy, Debug)]
struct Candidate {
    last: Vector3<f64>,
    /// Sum of its hits' coherences.
    coherence_sum: f64,
    first_frame: u64,
    last_frame: u64,
    hits: u32,
}

/// Multi-target DoA tracker. Allocates in [`DoaTracker::new`] only.
#[derive(Debug)]
pub struct DoaTracker {
    config: TrackerConfig,
    dt: f64,
    /// Coherence above the diffuse-noise response a birth needs.
    birth_margin: f64,
    noise: NoiseModel,
    inflation: f64,
    next_id: u64,
    frame: u64,
    tracks: Vec<Track>,
    candidates: Vec<Candidate>,
    /// Scratch: which potentials were used this frame.
    used: Vec<bool>,
    /// Scratch: (cost, track, potential) association candidates.
    pairs: Vec<(f64, usize, usize)>,
    /// The array's measurement shape, when
    /// [`TrackerConfig::shaped_measurement_noise`] is on and the array is known.
    shape: Option<Shape>,
    /// The search region whose edge peaks measure only along it, when
    /// [`TrackerConfig::edge_peaks_along_edge_only`] is on and the region is
    /// not the whole sphere.
    edge: Option<SearchRegion>,
}

impl DoaTracker {
    /// A tracker fed once per hop of `hop_s` seconds with at most
    /// `max_potentials` potentials per frame. `noise` describes the
    /// localizer's coherence under noise alone (see
    /// [`crate::srp::Srp::noise_model`]).
    pub fn new(
        config: &TrackerConfig,
        hop_s: f64,
        max_potentials: usize,
        noise: NoiseModel,
    ) -> Result<Self, AgentError> {
        let bad = |field: &str, message: &str| AgentError::InvalidParameter {
            field: format!("tracker.{field}"),
            message: message.into(),
        };
        let c = config;
        if !(hop_s > 0.0 && hop_s.is_finite()) {
            return Err(bad("hop", "must be positive"));
        }
        if c.birth_min_hits == 0 || c.birth_min_hits > c.birth_window_frames {
            return Err(bad("birth_min_hits", "must be in 1..=birth_window_frames"));
        }
        if c.confirm_hits > c.confirm_window_frames {
            return Err(bad("confirm_hits", "must be <= confirm_window_frames"));
        }
        if c.max_tracks == 0 || c.max_tracks > MAX_TRACKS {
            return Err(bad("max_tracks", "must be in 1..=64"));
        }
        let positive = [
            ("birth_gate_deg", c.birth_gate_deg),
            ("gate_chi2", c.gate_chi2),
            ("measurement_sigma_deg", c.measurement_sigma_deg),
            ("min_measurement_sigma_deg", c.min_measurement_sigma_deg),
            ("activity_time_constant_s", c.activity_time_constant_s),
            ("max_coast_s", c.max_coast_s),
            ("coast_velocity_time_constant_s", c.coast_velocity_time_constant_s),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return Err(bad(name, "must be positive and finite"));
            }
        }
        let non_negative = [
            ("acceleration_noise", c.acceleration_noise),
            ("min_gate_deg", c.min_gate_deg),
            ("max_gate_deg", c.max_gate_deg),
            ("min_sigma_deg", c.min_sigma_deg),
            ("merge_deg", c.merge_deg),
            ("rotation_deadband_deg", c.rotation_deadband_deg),
            ("diffuse_margin", c.diffuse_margin),
            ("noise_sigmas", c.noise_sigmas),
            ("report_max_silence_s", c.report_max_silence_s),
            ("masked_report_max_silence_s", c.masked_report_max_silence_s),
            ("masked_max_travel_m", c.masked_max_travel_m),
        ];
        for (name, v) in non_negative {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(bad(name, "must be non-negative and finite"));
            }
        }
        if !(c.max_shape_ratio >= 1.0 && c.max_shape_ratio.is_finite()) {
            return Err(bad("max_shape_ratio", "must be >= 1 and finite"));
        }
        if !(c.masking_margin_db > 0.0 && c.masking_margin_db.is_finite()) {
            return Err(bad("masking_margin_db", "must be positive and finite"));
        }
        let inflation = c.overlap_inflation;
        if !(inflation >= 1.0 && inflation.is_finite()) {
            return Err(bad("overlap_inflation", "must be >= 1"));
        }
        let cap = c.max_tracks;
        Ok(DoaTracker {
            config: c.clone(),
            dt: hop_s,
            birth_margin: c.diffuse_margin + c.noise_sigmas * noise.sigma,
            noise,
            inflation,
            next_id: 1,
            frame: 0,
            tracks: Vec::with_capacity(cap),
            candidates: Vec::with_capacity(4 * cap),
            used: Vec::with_capacity(max_potentials.max(1)),
            pairs: Vec::with_capacity(cap * max_potentials.max(1)),
            shape: None,
            edge: None,
        })
    }

    /// Tells the tracker the localizer's search region, for
    /// [`TrackerConfig::edge_peaks_along_edge_only`].
    pub fn set_search_region(&mut self, region: &SearchRegion) {
        let bounded = region.max_angle_rad < std::f64::consts::PI;
        self.edge = (self.config.edge_peaks_along_edge_only && bounded).then_some(*region);
    }

    /// What potential direction `z` measures, compared with `reference`: `z`
    /// itself, or for a peak on the search region's edge, the direction at
    /// `z`'s place around the region's axis and `reference`'s angle from it
    /// (module docs, "Peaks on the region's edge").
    fn measured(&self, z: Vector3<f64>, reference: &Vector3<f64>) -> Vector3<f64> {
        let Some(region) = &self.edge else { return z };
        if region.contains(&z, -EDGE_MARGIN_RAD) {
            return z;
        }
        let from_axis = region.axis.dot(reference).clamp(-1.0, 1.0).acos();
        region.at_angle_from_axis(&z, from_axis).unwrap_or(z)
    }

    /// Tells the tracker where the microphones are (array frame, m), for
    /// [`TrackerConfig::shaped_measurement_noise`]; without it (or with the
    /// setting off) every direction is measured alike.
    pub fn set_microphones(&mut self, positions: &[Vector3<f64>]) {
        if !self.config.shaped_measurement_noise || positions.len() < 2 {
            self.shape = None;
            return;
        }
        let centroid = positions.iter().sum::<Vector3<f64>>() / positions.len() as f64;
        let moment = positions.iter().map(|p| (p - centroid) * (p - centroid).transpose()).sum();
        self.shape = Some(Shape { moment, max_ratio2: self.config.max_shape_ratio.powi(2) });
    }

    /// The shape of the measurement covariance at a track and its inverse
    /// (identity when off).
    fn shape_of(&self, kf: &SphereKf) -> (Matrix2<f64>, Matrix2<f64>) {
        match &self.shape {
            Some(shape) => {
                let (e1, e2) = kf.basis();
                shape.at(&e1, &e2)
            }
            None => (Matrix2::identity(), Matrix2::identity()),
        }
    }

    /// The coherence a potential in direction `d` needs to start a track:
    /// `max(birth_min_coherence, diffuse(d) + diffuse_margin + noise_sigmas·σ)`.
    pub fn birth_threshold(&self, d: &Vector3<f64>) -> f64 {
        self.config.birth_min_coherence.max(self.noise.diffuse.at(d) + self.birth_margin)
    }

    /// The array turned: `new_from_old` maps directions in the array frame of
    /// the previous frames to the array frame from now on. Every track and
    /// birth candidate is re-expressed, so a source that stays put in the room
    /// stays put for the tracker while the robot turns (see
    /// [`crate::pipeline::Pipeline::set_base_orientation`]).
    pub fn change_frame(&mut self, new_from_old: &Rotation3<f64>) {
        for t in &mut self.tracks {
            t.kf.change_frame(new_from_old);
        }
        for c in &mut self.candidates {
            c.last = new_from_old * c.last;
        }
    }

    /// Forgets every track and candidate (ids keep increasing).
    pub fn reset(&mut self) {
        self.tracks.clear();
        self.candidates.clear();
    }

    /// Advances one hop with this frame's potentials and writes the current
    /// tracks to `out` (cleared first; no allocation once `out` has
    /// `max_tracks` capacity).
    pub fn update(&mut self, potentials: &[PotentialSource], out: &mut Vec<TrackedDirection>) {
        self.update_at(potentials, f64::NAN, None, out);
    }

    /// [`DoaTracker::update`] for a frame of level `level_db` (the band's
    /// mean power per microphone and bin, dB, [`crate::srp::Srp::band_level_db`];
    /// NaN if unknown) heard with the base at `base_position` (map, m; from
    /// SLAM, if known): silences in frames much louder than a track is heard
    /// at are masked, while the base stays near where it heard the track
    /// (see the module docs).
    pub fn update_at(
        &mut self,
        potentials: &[PotentialSource],
        level_db: f64,
        base_position: Option<Point3<f64>>,
        out: &mut Vec<TrackedDirection>,
    ) {
        self.frame += 1;
        let cfg = &self.config;
        let decay = (-self.dt / cfg.coast_velocity_time_constant_s).exp();
        for t in &mut self.tracks {
            if t.last_hit_frame < self.frame - 1 {
                t.kf.damp_velocity(decay);
            }
            t.kf.predict(self.dt, cfg.acceleration_noise);
        }
        self.associate(potentials, level_db, base_position);
        self.births(potentials, level_db, base_position);
        self.prune();
        out.clear();
        let cfg = &self.config;
        for t in &self.tracks {
            let silent_s = (self.frame - t.last_hit_frame) as f64 * self.dt;
            let audible_silent_s = t.unmasked_silent as f64 * self.dt;
            let travel_m = match (base_position, t.heard_from) {
                (Some(now), Some(then)) => (now - then).norm(),
                _ => 0.0,
            };
            let sigma = t.kf.sigma().max(self.config.min_sigma_deg.to_radians());
            out.push(TrackedDirection {
                track_id: t.id,
                direction_in_array: t.kf.direction(),
                activity: t.activity,
                angular_sigma_rad: sigma,
                confirmed: t.confirmed,
                silent_s,
                audible_silent_s,
                held_by_masking: silent_s <= cfg.masked_report_max_silence_s
                    && audible_silent_s <= cfg.report_max_silence_s
                    && travel_m <= cfg.masked_max_travel_m,
                coherence: t.coherence,
            });
        }
    }

    fn associate(
        &mut self,
        potentials: &[PotentialSource],
        level_db: f64,
        base_position: Option<Point3<f64>>,
    ) {
        let cfg = &self.config;
        self.used.clear();
        self.used.resize(potentials.len().min(self.used.capacity()), false);
        self.pairs.clear();
        let min_gate = cfg.min_gate_deg.to_radians();
        let max_gate = cfg.max_gate_deg.to_radians().max(min_gate);
        // Each track's measurement shape, computed once per hop for its
        // gating and its update (the track does not move in between).
        let mut shapes = [(Matrix2::identity(), Matrix2::identity()); MAX_TRACKS];
        for (ti, t) in self.tracks.iter().enumerate() {
            let (shape, inverse) = self.shape_of(&t.kf);
            if let Some(slot) = shapes.get_mut(ti) {
                *slot = (shape, inverse);
            }
            for (pi, p) in potentials.iter().enumerate().take(self.used.len()) {
                if p.energy < cfg.update_min_coherence {
                    continue;
                }
                let z = self.measured(p.direction_in_array.into_inner(), &t.kf.d);
                let m2 = t.kf.mahalanobis2_of(&z, &(shape * (t.r2 * self.inflation)));
                // The angle, in units of the best-measured axis when shaped.
                let angle = match &self.shape {
                    Some(s) => s.length(&t.kf.residual(&z), &inverse),
                    None => t.kf.d.angle(&z),
                };
                if ((m2 <= cfg.gate_chi2 && angle <= max_gate) || angle <= min_gate)
                    && self.pairs.len() < self.pairs.capacity()
                {
                    self.pairs.push((m2, ti, pi));
                }
            }
        }
        self.pairs.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let alpha = 1.0 - (-self.dt / cfg.activity_time_constant_s).exp();
        let min_r2 = cfg.min_measurement_sigma_deg.to_radians().powi(2);
        let max_r2 = 100.0 * cfg.measurement_sigma_deg.to_radians().powi(2);
        let mut updated = [false; MAX_TRACKS];
        for &(_, ti, pi) in &self.pairs {
            if self.used[pi] || ti >= updated.len() || updated[ti] {
                continue;
            }
            self.used[pi] = true;
            updated[ti] = true;
            let (shape, inverse) = shapes[ti];
            let z = self.measured(potentials[pi].direction_in_array.into_inner(), &self.tracks[ti].kf.d);
            let t = &mut self.tracks[ti];
            // Learn the measurement variance from the innovation (clipped
            // against outliers): E[yᵀS⁻¹y]/2 = r² + tr(S⁻¹P_θθ)/2 (S = I:
            // per axis).
            let y = t.kf.residual(&z);
            let p = t.kf.p.fixed_view::<2, 2>(0, 0).into_owned();
            let predicted = 0.5 * (inverse * p).trace();
            let sample = (0.5 * (y.transpose() * inverse * y)[(0, 0)] - predicted).clamp(0.0, 9.0 * t.r2);
            t.r2 = (0.95 * t.r2 + 0.05 * sample).clamp(min_r2, max_r2);
            t.kf.update_with(&z, &(shape * (t.r2 * self.inflation)));
            t.activity += alpha * (1.0 - t.activity);
            t.coherence += COHERENCE_WEIGHT * (potentials[pi].energy - t.coherence);
            t.last_hit_frame = self.frame;
            t.unmasked_silent = 0;
            t.heard_from = base_position;
            if level_db.is_finite() {
                t.level_db = if t.level_db.is_finite() {
                    t.level_db + COHERENCE_WEIGHT * (level_db - t.level_db)
                } else {
                    level_db
                };
            }
            t.hits_since_birth += 1;
            if !t.confirmed && t.hits_since_birth >= cfg.confirm_hits {
                t.confirmed = true;
            }
        }
        let margin = cfg.masking_margin_db;
        for (ti, t) in self.tracks.iter_mut().enumerate() {
            if !(ti < updated.len() && updated[ti]) {
                t.activity -= alpha * t.activity;
                // A hop much louder than the track is heard at masks it.
                if !(level_db >= t.level_db + margin) {
                    t.unmasked_silent += 1;
                }
            }
        }
    }

    fn births(&mut self, potentials: &[PotentialSource], level_db: f64, base_position: Option<Point3<f64>>) {
        let cfg = &self.config;
        let gate = cfg.birth_gate_deg.to_radians();
        let window = cfg.birth_window_frames as u64;
        // Forget candidates that can no longer reach their hits in their window.
        let frame = self.frame;
        self.candidates.retain(|c| {
            let elapsed = frame - c.first_frame;
            elapsed < window && c.hits + (window - elapsed) as u32 >= cfg.birth_min_hits
        });
        for (pi, p) in potentials.iter().enumerate() {
            let z = p.direction_in_array.into_inner();
            if self.used.get(pi).copied().unwrap_or(true) || p.energy < self.birth_threshold(&z) {
                continue;
            }
            let shape = self.shape.as_ref();
            // Too close to an existing track: it is that track's (ungated) echo, not a new source.
            // (On the plain direction, edge peaks too.)
            if self.tracks.iter().any(|t| Shape::angle(shape, &t.kf.d, &z) < cfg.merge_deg.to_radians()) {
                continue;
            }
            let near = self
                .candidates
                .iter()
                .enumerate()
                .filter(|(_, c)| c.last_frame < frame)
                .map(|(i, c)| (i, Shape::angle(shape, &c.last, &self.measured(z, &c.last))))
                .filter(|&(_, angle)| angle <= gate)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(i, _)| i);
            match near {
                Some(i) => {
                    let last = self.measured(z, &self.candidates[i].last);
                    let c = &mut self.candidates[i];
                    c.hits += 1;
                    c.coherence_sum += p.energy;
                    c.last = last;
                    c.last_frame = frame;
                }
                None if self.candidates.len() < self.candidates.capacity() => {
                    self.candidates.push(Candidate {
                        last: z,
                        coherence_sum: p.energy,
                        first_frame: frame,
                        last_frame: frame,
                        hits: 1,
                    });
                }
                None => {}
            }
        }
        let mut i = 0;
        while i < self.candidates.len() {
            let c = self.candidates[i];
            if c.hits >= cfg.birth_min_hits && self.tracks.len() < cfg.max_tracks {
                let r2 = cfg.measurement_sigma_deg.to_radians().powi(2);
                let mut kf = SphereKf::new(&Unit::new_normalize(c.last), r2, 1.0);
                if self.shape.is_some() {
                    let (shape, _) = self.shape_of(&kf);
                    kf.p.fixed_view_mut::<2, 2>(0, 0).copy_from(&(shape * r2));
                }
                self.tracks.push(Track {
                    id: self.next_id,
                    kf,
                    r2,
                    activity: c.hits as f64 / cfg.birth_window_frames as f64,
                    coherence: c.coherence_sum / c.hits.max(1) as f64,
                    born_frame: frame,
                    last_hit_frame: frame,
                    unmasked_silent: 0,
                    level_db,
                    heard_from: base_position,
                    hits_since_birth: 0,
                    confirmed: cfg.confirm_hits == 0,
                });
                self.next_id += 1;
                self.candidates.swap_remove(i);
            } else {
                i += 1;
            }
        }
    }

    fn prune(&mut self) {
        let cfg = &self.config;
        let frame = self.frame;
        let coast = (cfg.max_coast_s / self.dt).ceil() as u64;
        // A masked track lives as long as it may be reported.
        let masked_coast = (cfg.masked_report_max_silence_s / self.dt).ceil() as u64;
        let audible = (cfg.report_max_silence_s / self.dt).floor() as u32;
        self.tracks.retain(|t| {
            let silent = frame - t.last_hit_frame;
            let alive = silent <= coast || (silent <= masked_coast && t.unmasked_silent <= audible);
            let tentative_expired = !t.confirmed && frame - t.born_frame > cfg.confirm_window_frames as u64;
            alive && !tentative_expired
        });
        // Merge duplicates: the younger (larger id) of two close tracks dies.
        let merge = cfg.merge_deg.to_radians();
        let shape = self.shape;
        let mut i = 0;
        while i < self.tracks.len() {
            let dup = (0..self.tracks.len()).any(|j| {
                j != i
                    && self.tracks[j].id < self.tracks[i].id
                    && Shape::angle(shape.as_ref(), &self.tracks[j].kf.d, &self.tracks[i].kf.d) < merge
            });
            if dup {
                self.tracks.remove(i);
            } else {
                i += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::ArrayGeometry;
    use crate::srp::{Srp, SrpConfig};

    fn tracker(config: &TrackerConfig) -> Result<DoaTracker, AgentError> {
        let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
        let srp = Srp::new(&array, 16000, 256, &SrpConfig::default()).unwrap();
        DoaTracker::new(config, 0.008, 2, srp.noise_model())
    }

    fn peak(d: &Vector3<f64>) -> PotentialSource {
        PotentialSource { direction_in_array: Unit::new_normalize(*d), energy: 0.3, inverse_range_per_m: 0.0 }
    }

    #[test]
    fn masking_settings_are_checked_by_name() {
        for bad in [0.0, -3.0, f64::NAN] {
            let c = TrackerConfig { masking_margin_db: bad, ..TrackerConfig::default() };
            let e = tracker(&c).unwrap_err().to_string();
            assert!(e.contains("tracker.masking_margin_db"), "{e}");
        }
        let c = TrackerConfig { masked_report_max_silence_s: f64::INFINITY, ..TrackerConfig::default() };
        let e = tracker(&c).unwrap_err().to_string();
        assert!(e.contains("tracker.masked_report_max_silence_s"), "{e}");
    }

    /// Silent hops count as audible unless they are `masking_margin_db`
    /// louder than the level the track was heard at; an unknown level masks
    /// nothing; and a masked track outlives `max_coast_s` up to the masked limit.
    #[test]
    fn only_hops_much_louder_than_a_track_mask_its_silence() {
        let config = TrackerConfig::default();
        let mut t = tracker(&config).unwrap();
        let d = Vector3::new(0.5, 0.5, 0.7).normalize();
        let mut out = Vec::new();
        for _ in 0..40 {
            t.update_at(&[peak(&d)], -40.0, None, &mut out);
        }
        assert!(out.len() == 1 && out[0].confirmed);
        let id = out[0].track_id;
        // 5 dB louder: not masked.
        for _ in 0..10 {
            t.update_at(&[], -35.0, None, &mut out);
        }
        assert!(
            (out[0].audible_silent_s - 10.0 * 0.008).abs() < 1e-9 && (out[0].silent_s - 0.08).abs() < 1e-9
        );
        // 7 dB louder: masked, for longer than max_coast_s (1.5 s).
        for _ in 0..250 {
            t.update_at(&[], -33.0, None, &mut out);
        }
        assert_eq!(out.len(), 1, "a masked track lives on");
        assert_eq!(out[0].track_id, id);
        assert!(out[0].silent_s > config.max_coast_s && (out[0].audible_silent_s - 0.08).abs() < 1e-9);
        // Unknown levels mask nothing: after 0.3 s of them the track is past
        // its audible silence, and it dies (silent beyond max_coast_s).
        for _ in 0..40 {
            t.update_at(&[], f64::NAN, None, &mut out);
        }
        assert!(out.is_empty(), "{out:?}");
    }

    /// A Pioneer array's elevation near its plane is measured about 1/sin e
    /// worse than its azimuth: the shape follows the geometry, capped.
    #[test]
    fn a_nearly_planar_array_measures_elevation_worse_near_its_plane() {
        let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
        let positions: Vec<Vector3<f64>> = array.positions().map(|p| p.coords).collect();
        let shaped = TrackerConfig { shaped_measurement_noise: true, ..TrackerConfig::default() };
        let mut t = tracker(&TrackerConfig { max_shape_ratio: 100.0, ..shaped.clone() }).unwrap();
        t.set_microphones(&positions);
        let shape = t.shape.unwrap();
        let (normal, _) = array.best_fit_plane();
        let sigma_ratio = |elevation_deg: f64| {
            // A direction `elevation_deg` above the plane; e₁ along the
            // plane, e₂ toward the normal.
            let e = elevation_deg.to_radians();
            let along = normal.cross(&Vector3::x()).normalize();
            let d = along * e.cos() + normal.into_inner() * e.sin();
            let e1 = normal.cross(&along).normalize();
            let e2 = d.cross(&e1);
            let (s, inverse) = shape.at(&e1, &e2);
            assert!((s * inverse - Matrix2::identity()).norm() < 1e-9);
            (s[(1, 1)] / s[(0, 0)]).sqrt()
        };
        let (at10, at45, at90) = (sigma_ratio(10.0), sigma_ratio(45.0), sigma_ratio(90.0));
        assert!((4.0..7.0).contains(&at10), "{at10}");
        assert!((1.2..1.6).contains(&at45), "{at45}");
        assert!(at90 < 1.2, "{at90}");
        // Capped, and off when the setting is.
        let mut capped = tracker(&shaped).unwrap();
        capped.set_microphones(&positions);
        let e = Vector3::new(0.0, 0.0, 1.0);
        let (s, _) = capped.shape.unwrap().at(&Vector3::x(), &e);
        assert!((s[(1, 1)] - 36.0).abs() < 1e-9, "{s}");
        let mut off = tracker(&TrackerConfig::default()).unwrap();
        off.set_microphones(&positions);
        assert!(off.shape.is_none());
        let e = tracker(&TrackerConfig { max_shape_ratio: 0.5, ..shaped }).unwrap_err();
        assert!(e.to_string().contains("tracker.max_shape_ratio"), "{e}");
    }

    /// Peaks of one source near a planar array's plane that scatter ±12° in
    /// elevation but little in azimuth (a room's vertical reflections) make
    /// one confirmed track on the source's azimuth with the shaped noise;
    /// measured isotropically, most of them fall outside the birth and
    /// association gates.
    #[test]
    fn elevation_scatter_near_the_plane_still_makes_one_track() {
        use rand::{RngExt, SeedableRng};
        let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
        let positions: Vec<Vector3<f64>> = array.positions().map(|p| p.coords).collect();
        let run = |shaped: bool| {
            let config = TrackerConfig { shaped_measurement_noise: shaped, ..TrackerConfig::default() };
            let mut t = tracker(&config).unwrap();
            t.set_microphones(&positions);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
            let (azimuth, elevation) = (0.6f64, 10f64.to_radians());
            let (mut confirmed_hops, mut ids, mut azimuth_errors) =
                (0, std::collections::BTreeSet::new(), vec![]);
            let mut out = Vec::new();
            for _ in 0..250 {
                let a = azimuth + rng.random_range(-1.0f64..1.0).to_radians();
                let e = elevation + rng.random_range(-12.0f64..12.0).to_radians();
                let d = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
                t.update(&[peak(&d)], &mut out);
                for k in out.iter().filter(|k| k.confirmed) {
                    ids.insert(k.track_id);
                    let d = k.direction_in_array;
                    azimuth_errors.push((d.y.atan2(d.x) - azimuth).abs().to_degrees());
                }
                confirmed_hops += out.iter().any(|k| k.confirmed) as usize;
            }
            (confirmed_hops, ids.len(), azimuth_errors.iter().cloned().fold(0.0, f64::max))
        };
        let (hops, ids, worst_azimuth) = run(true);
        assert!(hops >= 220 && ids == 1 && worst_azimuth < 1.5, "{hops} {ids} {worst_azimuth}");
        let (hops_isotropic, _, _) = run(false);
        assert!(hops_isotropic < hops, "{hops_isotropic} {hops}");
    }

    fn at(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
        let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
    }

    /// Elevation (degrees) of `d`.
    fn elevation(d: &Vector3<f64>) -> f64 {
        d.z.clamp(-1.0, 1.0).asin().to_degrees()
    }

    /// A source 12° up whose peaks land on the upper hemisphere's horizon
    /// every other hop (further than the 10° birth gate from its own):
    /// with edge peaks measuring azimuth only, one track is born and holds
    /// 12°, following the azimuth; taken at face value, the edge peaks make
    /// a second track, on the horizon.
    #[test]
    fn peaks_clamped_on_the_horizon_count_for_their_azimuth_only() {
        let run = |along_edge_only: bool| {
            let config =
                TrackerConfig { edge_peaks_along_edge_only: along_edge_only, ..TrackerConfig::default() };
            let mut t = tracker(&config).unwrap();
            t.set_search_region(&SearchRegion::upper_hemisphere());
            let mut out = Vec::new();
            let mut first_confirmed = None;
            for hop in 0..120 {
                let azimuth = 40.0 + 0.05 * hop as f64;
                let d = if hop % 2 == 0 {
                    at(azimuth, 12.0)
                } else {
                    SearchRegion::upper_hemisphere()
                        .clamp(Unit::new_normalize(at(azimuth, -3.0)))
                        .into_inner()
                };
                t.update(&[peak(&d)], &mut out);
                if first_confirmed.is_none() && out.iter().any(|k| k.confirmed) {
                    first_confirmed = Some(hop);
                }
            }
            (first_confirmed, out)
        };
        let (confirmed_at, out) = run(true);
        assert!(confirmed_at.is_some_and(|h| h < 30), "{confirmed_at:?}");
        assert_eq!(out.len(), 1, "{out:?}");
        let d = out[0].direction_in_array.into_inner();
        let azimuth = d.y.atan2(d.x).to_degrees();
        assert!((elevation(&d) - 12.0).abs() < 0.5, "elevation {}", elevation(&d));
        assert!((azimuth - (40.0 + 0.05 * 119.0)).abs() < 0.5, "azimuth {azimuth}");
        // Taken at face value, the edge peaks make a second track on the horizon.
        let (_, out) = run(false);
        let elevations: Vec<f64> = out.iter().map(|k| elevation(&k.direction_in_array)).collect();
        assert!(out.len() == 2 && elevations.iter().any(|e| e.abs() < 0.1), "{elevations:?}");
    }

    /// Only peaks on the edge are re-read: inside the region, and with a
    /// whole-sphere region, every peak keeps its own elevation.
    #[test]
    fn peaks_inside_the_region_keep_their_elevation() {
        let mut t =
            tracker(&TrackerConfig { edge_peaks_along_edge_only: true, ..TrackerConfig::default() }).unwrap();
        let reference = at(10.0, 20.0);
        t.set_search_region(&SearchRegion::upper_hemisphere());
        let inside = at(12.0, 0.5);
        assert_eq!(t.measured(inside, &reference), inside);
        let edge = at(12.0, 0.0);
        let read = t.measured(edge, &reference);
        assert!(
            (elevation(&read) - 20.0).abs() < 1e-9 && (read.y.atan2(read.x).to_degrees() - 12.0).abs() < 1e-9
        );
        t.set_search_region(&SearchRegion::full_sphere());
        assert_eq!(t.measured(edge, &reference), edge);
    }
}

//! Tracker settings (the `[pipeline.tracker]` part of the agent config).
//! Angles in degrees at this edge, times in seconds or frames (hops), as
//! their names say.

/// Tracker settings.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Lowest PHAT coherence of a potential that may start a track.
    pub birth_min_coherence: f64,
    /// Margin above the array's diffuse-noise coherence floor for births.
    pub diffuse_margin: f64,
    /// Further margin for births, in standard deviations of the coherence of
    /// noise at one direction (`1/√(2·pairs·bins)`, large for few microphones).
    pub noise_sigmas: f64,
    /// Frames over which a birth candidate collects its hits.
    pub birth_window_frames: u32,
    /// Hits a candidate needs within its window to become a track.
    pub birth_min_hits: u32,
    /// Largest angle between consecutive hits of a candidate, degrees.
    pub birth_gate_deg: f64,
    /// Associated frames after birth needed to confirm a track.
    pub confirm_hits: u32,
    /// Frames after birth within which a tentative track must confirm.
    pub confirm_window_frames: u32,
    /// Lowest coherence of a potential that may update an existing track.
    pub update_min_coherence: f64,
    /// Association gate, squared Mahalanobis distance (2 dof; 13.8 ≈ 99.9 %).
    pub gate_chi2: f64,
    /// Association gate never narrower than this, degrees.
    pub min_gate_deg: f64,
    /// Association gate never wider than this, degrees. A track's learnt
    /// measurement variance grows in reverberation (and while two sources
    /// alternate in its gate), and with it the χ² gate, until a track can
    /// absorb the peaks of a second source 20–25° away, or jump to it when
    /// its own source stops. Single-frame peaks of one source scatter by
    /// ±5–10° in the rooms simulated here, so 12° keeps them.
    pub max_gate_deg: f64,
    /// White angular-acceleration noise, rad²/s³ per axis.
    pub acceleration_noise: f64,
    /// Measurement σ per axis before a track has learnt its own, degrees.
    pub measurement_sigma_deg: f64,
    /// Floor of the learnt measurement σ, degrees.
    pub min_measurement_sigma_deg: f64,
    /// Floor of the reported σ, degrees.
    pub min_sigma_deg: f64,
    /// Variance inflation of each measurement for the correlation between
    /// overlapping frames (1 = none: with 50 % overlap the reported σ is
    /// already slightly conservative, see the tracking tests).
    pub overlap_inflation: f64,
    /// Time constant of the activity, seconds.
    pub activity_time_constant_s: f64,
    /// A track without detection for this long dies, seconds. Long enough to
    /// hold a talker's id over the pauses between phrases (≈ 0.5–1.5 s).
    pub max_coast_s: f64,
    /// While a track has no detection, its angular velocity decays with this
    /// time constant, seconds (a coasting track holds its direction instead
    /// of extrapolating a velocity learnt from reverberant detections).
    pub coast_velocity_time_constant_s: f64,
    /// A confirmed track is reported only while its last detection is at most
    /// this old, seconds: a coasting track keeps its id but its direction is
    /// a guess, and it is in the array frame, which turns with the robot.
    pub report_max_silence_s: f64,
    /// A confirmed track whose silence was *masked* (hops at least
    /// `masking_margin_db` louder than the level it is heard at) except for
    /// at most `report_max_silence_s` of it is kept and reported for up to
    /// this long, seconds (a value at or below `report_max_silence_s` turns
    /// masking off). A weak steady source (a fan 14 dB below two talkers) is
    /// not heard while louder sources fill the frames: its silence then says
    /// nothing about whether it stopped. See the module docs, "Masking".
    pub masked_report_max_silence_s: f64,
    /// How much louder than a track's own level (the frame level at its
    /// detections, averaged in dB) a hop must be to mask its silence, dB.
    /// At 6 dB (the default) the other sounds carry three quarters of the
    /// hop's power; a steady source is then practically never detected
    /// (module docs, "Masking", for the measured curve).
    pub masking_margin_db: f64,
    /// A track kept only by masking is reported while the base has moved at
    /// most this far since its last detection, m (from the SLAM poses the
    /// pipeline follows): its direction is where the source was heard from
    /// there, and 0.1 m moves the bearing of a source 2 m away by ≤ 3°.
    pub masked_max_travel_m: f64,
    /// Two tracks closer than this merge (the younger dies), degrees.
    pub merge_deg: f64,
    /// Tracks follow the robot's turns (the pipeline re-expresses them when
    /// the base's orientation from SLAM has turned by more than this since the
    /// last re-expression), degrees. The dead band keeps a static robot's pose
    /// jitter out of the tracks; a turn is followed within it.
    pub rotation_deadband_deg: f64,
    /// Most tracks at once.
    pub max_tracks: usize,
    /// Shape each measurement's covariance, and the gates, by how well the
    /// array measures each tangent direction (its microphones' spread
    /// across it): a nearly planar array measures elevation near its plane
    /// poorly, and single-frame peaks there scatter in elevation far more
    /// than in azimuth. Angles in the gates, `birth_gate_deg` and
    /// `merge_deg` are then in units of the best-measured axis. See the
    /// module docs, "Nearly planar arrays". Experimental, off: it helps
    /// static robots (a talker heard from a corner, `cocktail`) and costs
    /// detection and ghosts for robots moving among several sources.
    pub shaped_measurement_noise: bool,
    /// Largest ratio of the worst- to the best-measured axis's σ in the
    /// shaped measurement noise.
    pub max_shape_ratio: f64,
    /// A peak on the edge of the search region (the search stopped there:
    /// the response still rose beyond it) measures only where along the
    /// edge it lies, for the upper hemisphere its azimuth: gates, updates
    /// and births take its angle from the edge from the track or candidate
    /// it is compared with. See the module docs, "Peaks on the region's edge".
    /// Experimental, off: it helps one source heard by moving robots
    /// (`corner-start`) and makes ghosts in `cocktail`'s own seed.
    pub edge_peaks_along_edge_only: bool,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            birth_min_coherence: 0.08,
            diffuse_margin: 0.03,
            noise_sigmas: 4.0,
            birth_window_frames: 16,
            birth_min_hits: 6,
            birth_gate_deg: 10.0,
            confirm_hits: 5,
            confirm_window_frames: 24,
            update_min_coherence: 0.08,
            gate_chi2: 13.8,
            min_gate_deg: 3.0,
            max_gate_deg: 12.0,
            acceleration_noise: 0.05,
            measurement_sigma_deg: 2.0,
            min_measurement_sigma_deg: 0.02,
            min_sigma_deg: 0.02,
            overlap_inflation: 1.0,
            activity_time_constant_s: 0.15,
            max_coast_s: 1.5,
            coast_velocity_time_constant_s: 0.2,
            report_max_silence_s: 0.3,
            masked_report_max_silence_s: 6.0,
            masking_margin_db: 6.0,
            masked_max_travel_m: 0.1,
            merge_deg: 5.0,
            rotation_deadband_deg: 1.0,
            max_tracks: 8,
            shaped_measurement_noise: false,
            max_shape_ratio: 6.0,
            edge_peaks_along_edge_only: false,
        }
    }
}

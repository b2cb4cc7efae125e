//! 3-D constant-velocity Kalman tracking of one sound source from the robots'
//! DoAs (theory §4).
//!
//! - [`filter`]: the CV model and the per-DoA tangent-plane EKF update (Joseph form);
//! - [`imm`]: a still and a moving CV mode mixed by an IMM filter (the published
//!   state is their mixture);
//! - [`lag_buffer`]: the fixed-lag buffer that applies late DoAs exactly;
//! - [`smoother`]: the fixed-lag smoother, the track's state a lag behind the
//!   newest DoA from the DoAs on both sides of it;
//! - [`lifecycle`]: tentative → confirmed → lost;
//! - `step`: what one DoA does to the replayable state of a track;
//! - [`config`]: [`TrackerConfig`] and its validation.
//!
//! [`SourceTracker`] ties them together. It is pure: stamps and `now` are inputs.
//! Use:
//! 1. when there is no active track ([`SourceTracker::needs_track`]), start one
//!    from a triangulation its gate accepted, or found only too uncertain at a
//!    good geometry ([`SourceTracker::initialize_from_triangulation`]),
//!    stamped with the newest stamp of the rays it used: DoAs stamped at or before
//!    it are refused ([`UpdateOutcome::BeforeTrack`]), since their information is
//!    already in the initial covariance;
//! 2. feed every robot's DoA ray for this source, in any order within the lag, to
//!    [`SourceTracker::update`]; each is gated by χ² (2 dof) and applied or counted;
//! 3. call [`SourceTracker::maintain`] with `now` regularly (lifecycle timeouts);
//! 4. publish [`SourceTracker::estimate`] or [`SourceTracker::predict_to`]`(now)`
//!    and, beside it, [`SourceTracker::smoothed`] (the state
//!    [`TrackerConfig::smoothing_lag_s`] earlier, smoothed):
//!    its [`TrackEstimate::trusted`] is false unless the track is confirmed, its
//!    position RMS is within [`TrackerConfig::trusted_max_rms_m`], and a second
//!    robot's DoA was accepted within the confirmation window (one robot's
//!    bearings alone leave the range unobserved).

pub mod config;
pub mod filter;
pub mod imm;
pub mod lag_buffer;
pub mod lifecycle;
pub mod noise;
mod outcome;
pub mod smoother;
mod step;
#[cfg(test)]
mod test_support;

use std::collections::VecDeque;

use nalgebra::{Matrix3, Matrix6, Point3, Vector3};
use soundmap_proto::Stamp;

pub use config::TrackerConfig;
pub use filter::{CvState, ProcessNoise, Unusable};
pub use lifecycle::{LossReason, TrackState};
pub use outcome::UpdateOutcome;

use crate::ray::Ray;
use crate::stats::chi2_quantile;
use crate::triangulation::{Gate, GateReason, Solution, Triangulation};
use imm::ImmState;
use lag_buffer::{Insertion, LagBuffer, Refusal};
use lifecycle::{Confirmation, check_loss};
use noise::Learned;
use smoother::HISTORY_STEP_S;
use step::{Observation, Snapshot, StepParams, step};

/// What became of an initialization.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InitOutcome {
    /// A new tentative track (ids increase from 1).
    Started {
        /// Its id.
        track_id: u64,
    },
    /// Nothing was changed.
    Rejected(InitRejection),
}

/// Why an initialization was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InitRejection {
    /// The position or covariance is not finite.
    NonFinite,
    /// The covariance is not symmetric positive definite.
    NotPositiveDefinite,
    /// The triangulation is degenerate or has no covariance.
    NoSolution,
    /// The triangulation's gate rejected it.
    Untrusted,
}

/// Counts of what happened to the DoAs of a track.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TrackCounts {
    /// Applied updates.
    pub applied: u64,
    /// Gated out by χ².
    pub gated: u64,
    /// Unusable (too close to an array, or not finite).
    pub unusable: u64,
    /// Dropped as older than the lag.
    pub too_late: u64,
    /// Dropped as stamped at or before the initialization.
    pub before_track: u64,
}

/// A track's estimate at one stamp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackEstimate {
    /// Id of the track (changes when re-initialized).
    pub track_id: u64,
    /// Time the estimate refers to.
    pub stamp: Stamp,
    /// Position, map frame (m).
    pub position_in_map: Point3<f64>,
    /// Velocity, map frame (m/s).
    pub velocity_in_map: Vector3<f64>,
    /// Covariance of [x y z vx vy vz] (SI).
    pub covariance: Matrix6<f64>,
    /// √tr of the position covariance (m).
    pub position_rms_m: f64,
    /// Lifecycle state.
    pub state: TrackState,
    /// True only when confirmed and `position_rms_m` ≤ the trusted threshold.
    pub trusted: bool,
    /// NIS of the last DoA evaluated (applied or gated).
    pub last_nis: Option<f64>,
    /// Mean NIS of the applied updates (≈ 2 when the noise model is right; it
    /// is contracted somewhat by the gate).
    pub mean_nis: Option<f64>,
    /// Stamp of the last applied DoA.
    pub last_update: Option<Stamp>,
    /// What happened to the DoAs.
    pub counts: TrackCounts,
    /// θ at the estimate between the robots heard within the support window
    /// (degrees, folded to [0, 90]; 0 with fewer than two).
    pub theta_deg: f64,
    /// Largest learned DoA noise scale λ among the robots (R = λ·R₀, ≥ 1).
    pub noise_scale: f64,
    /// Whether the NIS window is full and consistent with the noise model.
    pub consistent: bool,
    /// DoAs applied at good geometry (θ ≥ `good_geometry_theta_deg`).
    pub good_geometry_updates: u32,
}

impl TrackEstimate {
    /// The 3×3 position covariance (m²).
    pub fn position_covariance(&self) -> Matrix3<f64> {
        self.covariance.fixed_view::<3, 3>(0, 0).into_owned()
    }
}

/// A track's fixed-lag smoothed state (see [`smoother`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SmoothedEstimate {
    /// Id of the track.
    pub track_id: u64,
    /// Time the state refers to: about `lag_s` before the newest applied DoA.
    pub stamp: Stamp,
    /// How far behind the newest applied DoA `stamp` is (s).
    pub lag_s: f64,
    /// Position, map frame (m).
    pub position_in_map: Point3<f64>,
    /// Velocity, map frame (m/s).
    pub velocity_in_map: Vector3<f64>,
    /// Covariance of [x y z vx vy vz] (SI).
    pub covariance: Matrix6<f64>,
}

impl SmoothedEstimate {
    /// The 3×3 position covariance (m²).
    pub fn position_covariance(&self) -> Matrix3<f64> {
        self.covariance.fixed_view::<3, 3>(0, 0).into_owned()
    }
}

#[derive(Clone, Debug)]
struct Track {
    id: u64,
    buffer: LagBuffer<Observation, Snapshot>,
    lost: Option<LossReason>,
    too_late: u64,
    before_track: u64,
    /// θ of the triangulation it started from (degrees), when it did.
    init_theta_deg: Option<f64>,
    /// Filtered states settled out of the lag buffer for the smoother, at
    /// least [`HISTORY_STEP_S`] apart, oldest first (see [`Track::settle`]).
    settled: VecDeque<(Stamp, ImmState)>,
    /// The last smoothed state and the newest filter stamp it was computed at.
    smoothed: Option<(Stamp, SmoothedEstimate)>,
}

impl Track {
    /// Keeps the lag buffer's base for the smoother when it is a new filter
    /// state at least [`HISTORY_STEP_S`] after the last kept, and drops kept
    /// states no longer needed for a state `lag_ns` behind the newest.
    fn settle(&mut self, lag_ns: i64) {
        let (base, _) = self.buffer.base();
        let (t, filter) = (base.filter_stamp, base.filter);
        match self.settled.back_mut() {
            // DoAs applied at one stamp: the later state holds them all.
            Some(last) if last.0 == t => last.1 = filter,
            Some(last) if t.seconds_since(last.0) < HISTORY_STEP_S => {}
            _ => self.settled.push_back((t, filter)),
        }
        let horizon = self.buffer.latest().0.filter_stamp.plus_ns(-lag_ns);
        while self.settled.len() >= 2 && self.settled[1].0 <= horizon {
            self.settled.pop_front();
        }
    }

    /// The smoothed state `lag_ns` behind the newest applied DoA, or `None`
    /// while the track is younger than that.
    fn smooth(&self, lag_ns: i64, modes: &imm::Modes) -> Option<SmoothedEstimate> {
        let (latest, _) = self.buffer.latest();
        let newest = latest.filter_stamp;
        let mut history: Vec<(Stamp, &ImmState)> = Vec::with_capacity(self.settled.len() + 64);
        history.extend(self.settled.iter().map(|(t, s)| (*t, s)));
        // At most one state per HISTORY_STEP_S; of the states at one stamp
        // (DoAs applied at the same time), the last; the newest state always.
        let states = self.buffer.states().map(|(s, _)| (s.filter_stamp, &s.filter));
        for (t, filter) in states.chain(std::iter::once((newest, &latest.filter))) {
            match history.last_mut() {
                Some(last) if last.0 == t => last.1 = filter,
                Some(last) if t.seconds_since(last.0) < HISTORY_STEP_S && t < newest => {}
                _ => history.push((t, filter)),
            }
        }
        let target = newest.plus_ns(-lag_ns);
        let at = history.partition_point(|(t, _)| *t <= target).checked_sub(1)?;
        let state = smoother::smooth(&history, at, modes)?;
        let stamp = history[at].0;
        Some(SmoothedEstimate {
            track_id: self.id,
            stamp,
            lag_s: newest.seconds_since(stamp),
            position_in_map: state.position(),
            velocity_in_map: state.velocity(),
            covariance: state.covariance,
        })
    }
}

/// Tracks one source from DoAs: a CV EKF with per-DoA updates, χ² gating, an
/// exact fixed-lag buffer for late DoAs and a lifecycle (see the module docs).
#[derive(Clone, Debug)]
pub struct SourceTracker {
    config: TrackerConfig,
    params: StepParams,
    track: Option<Track>,
    last_id: u64,
}

impl SourceTracker {
    /// A tracker with no track. `config` should have passed
    /// [`TrackerConfig::validate`]; out-of-range counts are clamped.
    pub fn new(config: TrackerConfig) -> Self {
        let params = StepParams {
            modes: config.modes(),
            doa: config.doa_noise(),
            rules: config.lifecycle(),
            association_gate: chi2_quantile(2, config.association_probability),
            maintenance_gate: chi2_quantile(2, config.maintenance_probability),
            learning: config.learning(),
            good_theta_deg: config.good_geometry_theta_deg,
        };
        SourceTracker { config, params, track: None, last_id: 0 }
    }

    /// The configuration.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// The χ² (2 dof) threshold for associating a DoA to the track by its [`nis`](Self::nis).
    pub fn association_threshold(&self) -> f64 {
        self.params.association_gate
    }

    /// Why the current track was lost, if it was.
    pub fn loss(&self) -> Option<LossReason> {
        self.track.as_ref().and_then(|t| t.lost)
    }

    /// True when there is no track or it is lost: initialize one.
    pub fn needs_track(&self) -> bool {
        self.track.as_ref().is_none_or(|t| t.lost.is_some())
    }

    /// Starts a new tentative track at `stamp` from a position (map frame, m) and
    /// its 3×3 covariance (m², used as given); the velocity starts at zero with
    /// the configured variances. Replaces any current track.
    pub fn initialize(
        &mut self,
        stamp: Stamp,
        position: Point3<f64>,
        covariance: Matrix3<f64>,
    ) -> InitOutcome {
        if !position.iter().chain(covariance.iter()).all(|v| v.is_finite()) {
            return InitOutcome::Rejected(InitRejection::NonFinite);
        }
        let covariance = (covariance + covariance.transpose()) * 0.5;
        if covariance.cholesky().is_none() {
            return InitOutcome::Rejected(InitRejection::NotPositiveDefinite);
        }
        let mut p = Matrix6::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&covariance);
        let (h, v) = (
            self.config.initial_velocity_sigma_horizontal_m_per_s,
            self.config.initial_velocity_sigma_vertical_m_per_s,
        );
        p[(3, 3)] = h * h;
        p[(4, 4)] = h * h;
        p[(5, 5)] = v * v;
        // The robots' noise scales outlive the track; the rest starts afresh.
        let learned = self
            .track
            .as_ref()
            .map_or_else(Learned::default, |t| Learned::scales_of(&t.buffer.latest().0.learned));
        let start = Snapshot {
            stamp,
            filter: ImmState::new(CvState::new(position, Vector3::zeros(), p)),
            filter_stamp: stamp,
            confirmation: Confirmation::default(),
            last_nis: None,
            nis_sum: 0.0,
            applied: 0,
            gated: 0,
            unusable: 0,
            learned,
        };
        self.last_id += 1;
        self.track = Some(Track {
            id: self.last_id,
            buffer: LagBuffer::new(start, stamp, self.config.lag_ns(), self.config.max_buffered),
            lost: None,
            too_late: 0,
            before_track: 0,
            init_theta_deg: None,
            settled: VecDeque::from([(stamp, start.filter)]),
            smoothed: None,
        });
        InitOutcome::Started { track_id: self.last_id }
    }

    /// Whether a track may start from `solution`: its gate accepted it, or
    /// rejected it only as too uncertain (predicted RMS above the gate's) while
    /// its geometry is good (θ at or above
    /// [`TrackerConfig::good_geometry_theta_deg`], so the rays are
    /// well-conditioned and agree) and its RMS is below
    /// [`TrackerConfig::lost_max_rms_m`].
    ///
    /// The second case is noisy DoAs at a good geometry (ODAS's ≈ 4° grid
    /// 3–4 m away: one triangulation's RMS is 0.5–0.6 m at θ ≈ 40°). No single
    /// triangulation of them passes the gate, yet the filter's averaging pins
    /// the source down within a second; the track starts tentative and is
    /// confirmed (and trusted) only once its own RMS and its consistency allow.
    fn may_start_from(&self, solution: &Solution) -> bool {
        match solution.gate {
            Gate::Accepted => true,
            Gate::Rejected(GateReason::Uncertain { rms_m, .. }) => {
                solution.quality.theta_deg.min(180.0 - solution.quality.theta_deg)
                    >= self.config.good_geometry_theta_deg
                    && rms_m < self.config.lost_max_rms_m
            }
            Gate::Rejected(_) => false,
        }
    }

    /// Starts a track from a triangulation whose gate accepted it (or found it
    /// only too uncertain at a good geometry, see `may_start_from`), with its
    /// covariance × [`TrackerConfig::init_covariance_inflation`]. `stamp` should
    /// be the newest stamp of the rays it used.
    pub fn initialize_from_triangulation(
        &mut self,
        stamp: Stamp,
        triangulation: &Triangulation,
    ) -> InitOutcome {
        let Some(solution) = triangulation.solution() else {
            return InitOutcome::Rejected(InitRejection::NoSolution);
        };
        if !self.may_start_from(solution) {
            return InitOutcome::Rejected(InitRejection::Untrusted);
        }
        let Some(covariance) = solution.quality.covariance else {
            return InitOutcome::Rejected(InitRejection::NoSolution);
        };
        let outcome = self.initialize(
            stamp,
            solution.source_in_map,
            covariance * self.config.init_covariance_inflation,
        );
        if let (InitOutcome::Started { .. }, Some(t)) = (outcome, self.track.as_mut()) {
            t.init_theta_deg = Some(solution.quality.theta_deg);
        }
        outcome
    }

    /// True when the live track started from a triangulation whose θ was below
    /// [`TrackerConfig::good_geometry_theta_deg`], has applied no DoA at good
    /// geometry since (see [`TrackerConfig::evidence_updates`]), and
    /// `triangulation` is accepted at a θ at or above it: the biased start
    /// should not be carried on, restart from `triangulation`.
    pub fn should_restart_from(&self, triangulation: &Triangulation) -> bool {
        let Some(track) = self.track.as_ref().filter(|t| t.lost.is_none()) else { return false };
        let good = self.config.good_geometry_theta_deg;
        let bad_start = track.init_theta_deg.is_some_and(|t| t < good);
        let no_evidence = track.buffer.latest().0.learned.good_geometry_updates == 0;
        let better = triangulation.solution().is_some_and(|s| {
            s.gate == Gate::Accepted && s.quality.theta_deg >= good && s.quality.covariance.is_some()
        });
        bad_start && no_evidence && better
    }

    /// Drops the current track.
    pub fn clear(&mut self) {
        self.track = None;
    }

    /// Applies the DoA `ray` (map frame) of robot `robot`, stamped `stamp`: in
    /// order if it is the newest, else inserted and the later DoAs re-run.
    pub fn update(&mut self, stamp: Stamp, robot: u32, ray: &Ray) -> UpdateOutcome {
        let params = self.params;
        let Some(track) = self.track.as_mut().filter(|t| t.lost.is_none()) else {
            return UpdateOutcome::NoTrack;
        };
        let observation = Observation { robot, ray: *ray };
        match track.buffer.insert(stamp, observation, |s, t, o| step(s, t, o, &params)) {
            Insertion::Processed { result, .. } => {
                let lag_ns = self.config.smoothing_lag_ns();
                if lag_ns > 0 {
                    track.settle(lag_ns);
                    let newest = track.buffer.latest().0.filter_stamp;
                    let due = track.smoothed.is_none_or(|(at, _)| newest.seconds_since(at) >= HISTORY_STEP_S);
                    if due && matches!(result, UpdateOutcome::Applied { .. }) {
                        track.smoothed = track.smooth(lag_ns, &params.modes).map(|e| (newest, e));
                    }
                }
                result
            }
            Insertion::Refused(Refusal::TooLate) => {
                track.too_late += 1;
                UpdateOutcome::TooLate
            }
            Insertion::Refused(Refusal::BeforeStart) => {
                track.before_track += 1;
                UpdateOutcome::BeforeTrack
            }
        }
    }

    /// NIS of a DoA against the track at `stamp` without changing anything (for
    /// association: compare with [`association_threshold`](Self::association_threshold)).
    /// `None` when there is no active track, the stamp is outside the lag, or the
    /// DoA is unusable.
    pub fn nis(&self, stamp: Stamp, ray: &Ray) -> Option<f64> {
        let track = self.track.as_ref().filter(|t| t.lost.is_none())?;
        let (before, _) = track.buffer.state_before(stamp)?;
        before.filter_at(stamp, &self.params.modes).innovation(ray, &self.params.doa).ok().map(|i| i.nis)
    }

    /// Declares the track lost if it has been silent too long or its covariance
    /// predicted to `now` is too large (see [`lifecycle`]).
    pub fn maintain(&mut self, now: Stamp) {
        let modes = self.params.modes;
        let rules = self.params.rules;
        let Some(track) = self.track.as_mut().filter(|t| t.lost.is_none()) else {
            return;
        };
        let (s, _) = track.buffer.latest();
        let rms = s.filter_at(now, &modes).combined().position_rms_m();
        // The last applied DoA's stamp, or the start while none was.
        let last = s.filter_stamp;
        let single_since =
            s.confirmation.single_run_start().unwrap_or(track.buffer.start()).max(track.buffer.start());
        track.lost = check_loss(s.confirmation.is_confirmed(), now, last, single_since, rms, &rules);
    }

    /// The estimate at the newest DoA's stamp (or the initialization); `None` without a track.
    pub fn estimate(&self) -> Option<TrackEstimate> {
        let track = self.track.as_ref()?;
        let (s, _) = track.buffer.latest();
        Some(self.describe(track, s, s.stamp, s.filter_at(s.stamp, &self.params.modes).combined()))
    }

    /// The track's fixed-lag smoothed state: about
    /// [`TrackerConfig::smoothing_lag_s`] behind the newest applied DoA,
    /// from the DoAs on both sides of it (see [`smoother`]). Refreshed at
    /// most every [`HISTORY_STEP_S`] of DoA time. `None` without a live
    /// track (none, or lost), with smoothing off, or while the track is
    /// younger than the lag.
    pub fn smoothed(&self) -> Option<SmoothedEstimate> {
        self.track.as_ref().filter(|t| t.lost.is_none())?.smoothed.map(|(_, e)| e)
    }

    /// The estimate predicted to `stamp` without changing the track (a stamp
    /// before the newest DoA gives the newest estimate; its `stamp` says so).
    pub fn predict_to(&self, stamp: Stamp) -> Option<TrackEstimate> {
        let track = self.track.as_ref()?;
        let (s, _) = track.buffer.latest();
        let dt = stamp.seconds_since(s.stamp);
        if dt <= 0.0 {
            return Some(self.describe(
                track,
                s,
                s.stamp,
                s.filter_at(s.stamp, &self.params.modes).combined(),
            ));
        }
        Some(self.describe(track, s, stamp, s.filter_at(stamp, &self.params.modes).combined()))
    }

    fn describe(&self, track: &Track, s: &Snapshot, stamp: Stamp, filter: CvState) -> TrackEstimate {
        let state = match track.lost {
            Some(reason) => TrackState::Lost(reason),
            None if s.confirmation.is_confirmed() => TrackState::Confirmed,
            None => TrackState::Tentative,
        };
        let position_rms_m = filter.position_rms_m();
        let learning = &self.params.learning;
        let theta_deg = s.learned.theta_deg(&filter.position(), s.stamp, self.params.rules.support_window_ns);
        let good_geometry_updates = s.learned.good_geometry_updates;
        let consistent = s.learned.consistent(learning);
        let geometry = theta_deg >= self.config.good_geometry_theta_deg
            || good_geometry_updates >= self.config.evidence_updates;
        TrackEstimate {
            track_id: track.id,
            stamp,
            position_in_map: filter.position(),
            velocity_in_map: filter.velocity(),
            covariance: filter.covariance,
            position_rms_m,
            state,
            trusted: state == TrackState::Confirmed
                && position_rms_m <= self.config.trusted_max_rms_m
                && s.confirmation.is_supported(s.stamp, self.params.rules.support_window_ns)
                && consistent
                && geometry,
            last_nis: s.last_nis,
            mean_nis: (s.applied > 0).then(|| s.nis_sum / s.applied as f64),
            last_update: s.last_update(),
            counts: TrackCounts {
                applied: s.applied,
                gated: s.gated,
                unusable: s.unusable,
                too_late: track.too_late,
                before_track: track.before_track,
            },
            theta_deg,
            noise_scale: s.learned.max_scale(learning),
            consistent,
            good_geometry_updates,
        }
    }
}

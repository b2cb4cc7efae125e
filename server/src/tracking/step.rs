//! What one DoA does to the replayable state of a track: predict to its stamp,
//! linearize, gate, update (theory §4.2 B, §4.3). The lag buffer stores the
//! resulting [`Snapshot`] after every DoA and re-runs [`step`] on replay.

use std::cmp::Ordering;

use soundmap_proto::Stamp;

use super::filter::{DoaNoiseModel, Unusable};
use super::imm::{ImmState, Modes};
use super::lifecycle::{Confirmation, LifecycleRules};
use super::noise::{InnovationSample, Learned, LearningRules};
use super::outcome::UpdateOutcome;
use crate::ray::Ray;

/// A DoA as buffered: the robot it came from and its ray. Ordered by robot
/// then ray numbers (total order), so that equal stamps replay in one order.
#[derive(Clone, Copy, Debug)]
pub(super) struct Observation {
    pub(super) robot: u32,
    pub(super) ray: Ray,
}

impl Observation {
    fn numbers(&self) -> [f64; 8] {
        let (o, d) = (&self.ray.origin_in_map, &self.ray.direction_in_map);
        [o.x, o.y, o.z, d.x, d.y, d.z, self.ray.sigma_rad, self.ray.origin_sigma_m]
    }
}

impl Ord for Observation {
    fn cmp(&self, other: &Self) -> Ordering {
        self.robot.cmp(&other.robot).then_with(|| {
            let (a, b) = (self.numbers(), other.numbers());
            a.iter().zip(&b).map(|(x, y)| x.total_cmp(y)).find(|c| c.is_ne()).unwrap_or(Ordering::Equal)
        })
    }
}

impl PartialOrd for Observation {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Observation {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other).is_eq()
    }
}

impl Eq for Observation {}

/// Everything about a track that depends on the sorted DoA sequence: the
/// filter and the lifecycle's history. The lag buffer stores one after each DoA.
#[derive(Clone, Copy, Debug)]
pub(super) struct Snapshot {
    pub(super) stamp: Stamp,
    pub(super) filter: ImmState,
    /// The stamp `filter` refers to: that of the last applied DoA, or the
    /// track's start while none was applied (see [`Snapshot::last_update`]). A
    /// gated or unusable DoA leaves the filter as it was, so that it changes
    /// nothing (the IMM's mixing at an extra stamp would).
    pub(super) filter_stamp: Stamp,
    pub(super) confirmation: Confirmation,
    pub(super) last_nis: Option<f64>,
    pub(super) nis_sum: f64,
    pub(super) applied: u64,
    pub(super) gated: u64,
    pub(super) unusable: u64,
    /// Learned noise scales, NIS window and robots' positions.
    pub(super) learned: Learned,
}

impl Snapshot {
    /// The filter predicted (mixed) to `stamp`, not before its own stamp.
    pub(super) fn filter_at(&self, stamp: Stamp, modes: &Modes) -> ImmState {
        self.filter.predicted(stamp.seconds_since(self.filter_stamp).max(0.0), modes)
    }

    /// Stamp of the last applied DoA, if any.
    pub(super) fn last_update(&self) -> Option<Stamp> {
        (self.applied > 0).then_some(self.filter_stamp)
    }
}

/// The numbers a DoA step needs.
#[derive(Clone, Copy, Debug)]
pub(super) struct StepParams {
    pub(super) modes: Modes,
    pub(super) doa: DoaNoiseModel,
    pub(super) rules: LifecycleRules,
    pub(super) association_gate: f64,
    pub(super) maintenance_gate: f64,
    pub(super) learning: LearningRules,
    /// θ at or above which an applied update counts as evidence (degrees).
    pub(super) good_theta_deg: f64,
}

impl StepParams {
    /// The DoA noise model for `robot` given what `learned` holds: R = λ·R₀.
    pub(super) fn doa_for(&self, learned: &Learned, robot: u32) -> (DoaNoiseModel, f64) {
        let scale = learned.scale(robot, &self.learning);
        (DoaNoiseModel { variance_inflation: self.doa.variance_inflation * scale, ..self.doa }, scale)
    }
}

/// Predicts `prev` to `stamp` and applies (or gates) one DoA.
pub(super) fn step(
    prev: &Snapshot,
    stamp: Stamp,
    obs: &Observation,
    p: &StepParams,
) -> (Snapshot, UpdateOutcome) {
    let predicted = prev.filter_at(stamp, &p.modes);
    let mut next = Snapshot { stamp, ..*prev };
    let (model, scale) = p.doa_for(&prev.learned, obs.robot);
    let inn = match predicted.innovation(&obs.ray, &model) {
        Ok(inn) => inn,
        Err(u) => {
            next.unusable += 1;
            return (next, UpdateOutcome::Unusable(u));
        }
    };
    let threshold = if prev.confirmation.is_confirmed() { p.maintenance_gate } else { p.association_gate };
    next.last_nis = Some(inn.nis);
    let sample = InnovationSample {
        residual_sq: inn.residual.norm_squared(),
        trace_s: inn.covariance.trace(),
        prior_variance: inn.noise_variance_rad2 / scale,
        scale,
    };
    next.learned.record_nis(inn.nis, &p.learning);
    if !(inn.nis <= threshold) {
        next.gated += 1;
        return (next, UpdateOutcome::Gated { nis: inn.nis, threshold });
    }
    let Some(updated) = predicted.updated(&obs.ray, &model) else {
        next.unusable += 1;
        return (next, UpdateOutcome::Unusable(Unusable::NonFinite));
    };
    next.learned.learn(obs.robot, stamp, sample, &p.learning);
    let upper = obs.ray.fold.is_some_and(|f| f.upper_branch);
    next.learned.accepted(obs.robot, stamp, obs.ray.origin_in_map, upper);
    // Robots that hear the source through folded rays from one height cannot
    // tell it from its mirror below them: keep the upper branch
    // (crate::floor_image, "The fold's two branches"). A straight ray, or one
    // with the rule off, leaves no fold plane: nothing to look up.
    next.filter = match upper.then(|| next.learned.fold_plane(stamp, p.rules.support_window_ns)).flatten() {
        Some((lowest, plane)) => updated.on_upper_branch(lowest, plane),
        None => updated,
    };
    next.filter_stamp = stamp;
    let post = next.filter.combined();
    next.applied += 1;
    next.nis_sum += inn.nis;
    next.confirmation.record(stamp, obs.robot, post.position_rms_m(), &p.rules);
    if next.learned.theta_deg(&post.position(), stamp, p.rules.support_window_ns) >= p.good_theta_deg {
        next.learned.good_geometry_updates = next.learned.good_geometry_updates.saturating_add(1);
    }
    (next, UpdateOutcome::Applied { nis: inn.nis })
}

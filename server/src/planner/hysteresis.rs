//! When to re-task the robots (theory §3.5, step 6): triggers with hysteresis
//! and the memory of the last plan.
//!
//! - A correction *starts* when θ comes within `theta_margin_deg` of an edge of
//!   the band (before it leaves it), the GDOP exceeds its
//!   threshold, or the predicted reduction of √tr J⁻¹ reaches the improvement
//!   threshold (~20 %).
//! - Once started it *continues* until θ is `theta_hysteresis_deg` inside the
//!   band, the GDOP is `gdop_hysteresis` below its threshold and the predicted
//!   gain is under `improvement_release`: a geometry hovering at a threshold
//!   does not toggle the robots.
//! - Robots driving to goals keep them while the goals stay valid and the
//!   source has moved less than `follow_distance_m` from where it was when they
//!   were planned, unless a θ correction is under way and θ at the goals would
//!   still be short of its release (a first step planned to the band's edge
//!   parked three robots at θ 38–40° for 4 s in `three-robots`); the target
//!   pattern is sticky (see [`bearings`](super::bearings)).
//! - An idle robot the source has come closer to than r_min (or left beyond
//!   r_max) is re-tasked even when θ and GDOP are fine.
//! - Re-tasking happens at most once per planning period (see [`cadence`](super::cadence)).

use nalgebra::Point3;
use soundmap_proto::{RepositionReason, RobotId};

use super::config::PlannerConfig;
use super::outcome::HoldReason;

/// What the planner remembers between cycles.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Memory {
    /// The (predicted) source position they were planned for.
    pub planned_source: Option<Point3<f64>>,
    /// The correction in progress, if any.
    pub engaged: Option<RepositionReason>,
    /// Target bearing per robot of the last plan (rad).
    pub bearings: Vec<(RobotId, f64)>,
}

impl Memory {
    /// Previous target bearing of robot `id`.
    pub fn bearing_of(&self, id: &RobotId) -> Option<f64> {
        self.bearings.iter().find(|(r, _)| r == id).map(|b| b.1)
    }
}

/// The facts a decision is made on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Situation {
    /// Best pairwise θ now (degrees).
    pub theta_deg: f64,
    /// Best pairwise θ with every robot at its active goal (or where it is).
    pub destination_theta_deg: f64,
    /// GDOP now.
    pub gdop: f64,
    /// Predicted relative reduction of √tr J⁻¹ at the target pattern (≤ 1).
    pub improvement: f64,
    /// Some robot is driving to a goal.
    pub busy: bool,
    /// Every active goal still meets the constraints for the current source.
    pub goals_valid: bool,
    /// Horizontal distance the source moved since the last plan (m; ∞ when none).
    pub source_moved_m: f64,
    /// A robot without a goal is inside the keep-out radius or beyond r_max
    /// (the source came too close or walked away).
    pub idle_out_of_ring: bool,
}

/// Re-plan (and why) or hold.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Decision {
    /// Plan new goals.
    Replan(RepositionReason),
    /// Leave the robots be.
    Hold(HoldReason),
}

/// The trigger that holds, given the correction in progress.
pub(crate) fn trigger(
    cfg: &PlannerConfig,
    engaged: Option<RepositionReason>,
    s: &Situation,
) -> Option<RepositionReason> {
    let h = if engaged == Some(RepositionReason::ThetaOutOfBand) { cfg.theta_hysteresis_deg } else { 0.0 };
    let (lo, hi) = cfg.trigger_band_deg();
    if !(s.theta_deg >= lo + h && s.theta_deg <= hi - h) {
        return Some(RepositionReason::ThetaOutOfBand);
    }
    let g = if engaged == Some(RepositionReason::GdopHigh) {
        cfg.max_gdop * (1.0 - cfg.gdop_hysteresis)
    } else {
        cfg.max_gdop
    };
    if !(s.gdop <= g) {
        return Some(RepositionReason::GdopHigh);
    }
    let t = if engaged.is_some() { cfg.improvement_release } else { cfg.improvement_threshold };
    // A zero threshold means "always improve": re-plan on any positive gain.
    if s.improvement >= t && s.improvement > 0.0 {
        return Some(RepositionReason::Improvement);
    }
    None
}

/// Decides this cycle.
pub(crate) fn decide(cfg: &PlannerConfig, engaged: Option<RepositionReason>, s: &Situation) -> Decision {
    if s.busy {
        // Goals that would leave a θ correction unfinished are not held: a
        // step planned to the band's edge (the sampling search's nearest
        // feasible spots) would otherwise park the robots just outside it.
        let unfinished = engaged == Some(RepositionReason::ThetaOutOfBand)
            && trigger(cfg, engaged, &Situation { theta_deg: s.destination_theta_deg, ..*s })
                == Some(RepositionReason::ThetaOutOfBand);
        if s.goals_valid && s.source_moved_m < cfg.follow_distance_m && !unfinished {
            return Decision::Hold(HoldReason::GoalsInProgress);
        }
        return Decision::Replan(trigger(cfg, engaged, s).unwrap_or(RepositionReason::FollowSource));
    }
    match trigger(cfg, engaged, s) {
        Some(r) => Decision::Replan(r),
        None if s.idle_out_of_ring => Decision::Replan(RepositionReason::FollowSource),
        None => Decision::Hold(HoldReason::GeometryGood {
            theta_deg: s.theta_deg,
            gdop: s.gdop,
            improvement: s.improvement,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn situation(theta_deg: f64, gdop: f64, improvement: f64) -> Situation {
        Situation {
            theta_deg,
            destination_theta_deg: theta_deg,
            gdop,
            improvement,
            busy: false,
            goals_valid: true,
            source_moved_m: 0.0,
            idle_out_of_ring: false,
        }
    }

    #[test]
    fn band_edges_have_hysteresis() {
        let cfg = PlannerConfig::default();
        assert_eq!(cfg.trigger_band_deg(), (50.0, 130.0));
        // Idle: 42° is inside the band but within the 10° margin: correct now, before it leaves.
        assert_eq!(trigger(&cfg, None, &situation(42.0, 2.0, 0.0)), Some(RepositionReason::ThetaOutOfBand));
        let s = situation(52.0, 2.0, 0.15);
        // Idle: 52° is clear of the margin and 15 % is below 20 %.
        assert_eq!(trigger(&cfg, None, &s), None);
        // During a θ correction, 52° is not yet 5° inside the trigger band.
        assert_eq!(
            trigger(&cfg, Some(RepositionReason::ThetaOutOfBand), &s),
            Some(RepositionReason::ThetaOutOfBand)
        );
        // Past 55°, the correction continues while the gain exceeds the release (10 %).
        let s = situation(60.0, 2.0, 0.15);
        assert_eq!(
            trigger(&cfg, Some(RepositionReason::ThetaOutOfBand), &s),
            Some(RepositionReason::Improvement)
        );
        let s = situation(60.0, 2.0, 0.05);
        assert_eq!(trigger(&cfg, Some(RepositionReason::Improvement), &s), None);
        // A narrow band keeps 90° ± 2h clear of triggers.
        let narrow = PlannerConfig { theta_min_deg: 75.0, theta_max_deg: 105.0, ..PlannerConfig::default() };
        assert_eq!(narrow.trigger_band_deg(), (80.0, 100.0));
        // GDOP: 2.4 ends an idle check but not a GDOP correction (threshold 2.25 then).
        let s = situation(90.0, 2.4, 0.0);
        assert_eq!(trigger(&cfg, None, &s), None);
        assert_eq!(trigger(&cfg, Some(RepositionReason::GdopHigh), &s), Some(RepositionReason::GdopHigh));
        assert_eq!(
            trigger(&cfg, None, &situation(90.0, f64::INFINITY, 0.0)),
            Some(RepositionReason::GdopHigh)
        );
        assert_eq!(
            trigger(&cfg, None, &situation(f64::NAN, 1.0, 0.0)),
            Some(RepositionReason::ThetaOutOfBand)
        );
    }

    #[test]
    fn busy_robots_keep_valid_goals_until_the_source_moves() {
        let cfg = PlannerConfig::default();
        let mut s = situation(20.0, 5.0, 0.5);
        s.busy = true;
        assert_eq!(decide(&cfg, None, &s), Decision::Hold(HoldReason::GoalsInProgress));
        s.source_moved_m = 0.6;
        assert_eq!(decide(&cfg, None, &s), Decision::Replan(RepositionReason::ThetaOutOfBand));
        let mut s = situation(90.0, 1.6, 0.0);
        s.busy = true;
        s.goals_valid = false;
        assert_eq!(decide(&cfg, None, &s), Decision::Replan(RepositionReason::FollowSource));
        // An idle robot the source walked up to must step back although θ is fine.
        let mut s = situation(90.0, 1.6, 0.0);
        assert!(matches!(decide(&cfg, None, &s), Decision::Hold(HoldReason::GeometryGood { .. })));
        s.idle_out_of_ring = true;
        assert_eq!(decide(&cfg, None, &s), Decision::Replan(RepositionReason::FollowSource));
    }

    #[test]
    fn goals_that_leave_theta_short_of_the_band_are_not_held() {
        let cfg = PlannerConfig::default();
        let engaged = Some(RepositionReason::ThetaOutOfBand);
        // Driving to goals whose θ (41°) is inside 40–140° but short of the
        // correction's release (55°): re-plan.
        let short = Situation { busy: true, destination_theta_deg: 41.0, ..situation(38.0, 2.0, 0.0) };
        assert_eq!(decide(&cfg, engaged, &short), Decision::Replan(RepositionReason::ThetaOutOfBand));
        // Goals that finish the correction are kept.
        let enough = Situation { destination_theta_deg: 70.0, ..short };
        assert_eq!(decide(&cfg, engaged, &enough), Decision::Hold(HoldReason::GoalsInProgress));
        // Without a θ correction under way the goals are kept as before.
        let other = Some(RepositionReason::GdopHigh);
        assert_eq!(decide(&cfg, other, &short), Decision::Hold(HoldReason::GoalsInProgress));
    }
}

//! Track lifecycle: tentative → confirmed → lost.
//!
//! - A track starts **tentative** when it is initialized (from a triangulation).
//! - It becomes **confirmed** on an accepted DoA update after which the last
//!   `confirm_updates` accepted updates all fall within `confirm_window`, come
//!   from at least `confirm_min_robots` distinct robots, *and* the position RMS
//!   √tr P_pos is at most `confirm_max_rms_m`. Both are required: a small
//!   covariance alone (an optimistic initialization) is no evidence that the
//!   robots' DoAs agree on a source, and agreement alone says nothing of how
//!   well the point is pinned down. Confirmation is a function of the accepted
//!   update history only, so the fixed-lag replay reproduces it exactly.
//! - It is **lost** (terminal, until re-initialized) when no DoA has been
//!   accepted for `tentative_timeout` (tentative) or `lost_timeout` (confirmed),
//!   or when its position RMS exceeds `lost_max_rms_m` (diverged), or when a
//!   confirmed track has been fed by a single robot for longer than
//!   `single_robot_timeout` (one bearing leaves the range along it unobserved:
//!   the state slides along that ray while its covariance still looks small).
//!   Loss is decided by [`check_loss`] at the caller's `now`.
//! - A confirmed track is **supported** while a second robot's DoA was accepted
//!   within `support_window` of its newest one; only a supported track is trusted.

use soundmap_proto::Stamp;

/// Largest `confirm_updates` the lifecycle can hold.
pub const MAX_CONFIRM_UPDATES: usize = 16;

/// State of a track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TrackState {
    /// Initialized, not yet confirmed by enough DoAs: not to be trusted.
    Tentative,
    /// Confirmed by DoAs from several robots with a small enough covariance.
    Confirmed,
    /// Given up; the estimate is stale. Re-initialize from a new triangulation.
    Lost(LossReason),
}

/// Why a track was lost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LossReason {
    /// No DoA accepted for longer than the timeout.
    Silent {
        /// Time since the last accepted DoA (or the initialization) (s).
        silent_s: f64,
    },
    /// The position covariance grew too large.
    Diverged {
        /// √tr P_pos when it was detected (m).
        position_rms_m: f64,
    },
    /// Only one robot's DoAs were accepted for too long (the others were gated).
    SingleRobot {
        /// Time since a second robot's DoA was last accepted (s).
        single_s: f64,
    },
}

/// The lifecycle thresholds (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LifecycleRules {
    /// Accepted updates needed to confirm, 1..=[`MAX_CONFIRM_UPDATES`].
    pub confirm_updates: usize,
    /// Distinct robots among them.
    pub confirm_min_robots: usize,
    /// Time span they must fit in (ns).
    pub confirm_window_ns: i64,
    /// Largest position RMS at confirmation (m).
    pub confirm_max_rms_m: f64,
    /// Silence that loses a tentative track (s).
    pub tentative_timeout_s: f64,
    /// Silence that loses a confirmed track (s).
    pub lost_timeout_s: f64,
    /// Position RMS that loses any track (m).
    pub lost_max_rms_m: f64,
    /// A second robot's DoA must be this recent for the track to be trusted (ns).
    pub support_window_ns: i64,
    /// Single-robot feeding that loses a confirmed track (s).
    pub single_robot_timeout_s: f64,
}

/// The replayable part of the lifecycle: recent accepted updates and whether
/// the track has been confirmed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Confirmation {
    recent: [(Stamp, u32); MAX_CONFIRM_UPDATES],
    len: usize,
    next: usize,
    confirmed: bool,
    /// The newest accepted update (stamp, robot).
    last: Option<(Stamp, u32)>,
    /// Stamp of the newest accepted update from a robot other than `last`'s.
    other: Option<Stamp>,
    /// Stamp of the first update of the current run of updates from `last`'s
    /// robot alone (a silence between two robots' updates is not one robot
    /// feeding the track).
    run_start: Option<Stamp>,
}

impl Default for Confirmation {
    fn default() -> Self {
        Confirmation {
            recent: [(Stamp::ZERO, 0); MAX_CONFIRM_UPDATES],
            len: 0,
            next: 0,
            confirmed: false,
            last: None,
            other: None,
            run_start: None,
        }
    }
}

impl Confirmation {
    /// True once confirmed (it stays so).
    pub fn is_confirmed(&self) -> bool {
        self.confirmed
    }

    /// Stamp of the newest accepted DoA from a robot other than the newest
    /// one's: the track has two-robot support up to there.
    pub fn second_robot(&self) -> Option<Stamp> {
        self.other
    }

    /// Stamp of the first accepted DoA of the newest one's robot since another
    /// robot's: the track has been fed by that robot alone since then. Unlike
    /// [`Self::second_robot`], a silence (no robot heard the source) before
    /// the run does not count as single-robot feeding.
    pub fn single_run_start(&self) -> Option<Stamp> {
        self.run_start
    }

    /// Whether a second robot's DoA was accepted within `window_ns` of `at`.
    pub fn is_supported(&self, at: Stamp, window_ns: i64) -> bool {
        self.other.is_some_and(|o| at - o <= window_ns)
    }

    /// Records an accepted update from `robot` at `stamp`, after which the
    /// position RMS is `position_rms_m`, and confirms the track if the rules hold.
    pub fn record(&mut self, stamp: Stamp, robot: u32, position_rms_m: f64, rules: &LifecycleRules) {
        match self.last {
            Some((t, r)) if r != robot => {
                self.other = Some(t);
                self.run_start = Some(stamp);
            }
            Some(_) => {}
            None => self.run_start = Some(stamp),
        }
        self.last = Some((stamp, robot));
        let m = rules.confirm_updates.clamp(1, MAX_CONFIRM_UPDATES);
        self.recent[self.next % m] = (stamp, robot);
        self.next = (self.next + 1) % m;
        self.len = (self.len + 1).min(m);
        if self.confirmed || self.len < m || !(position_rms_m <= rules.confirm_max_rms_m) {
            return;
        }
        let recent = &self.recent[..m];
        let oldest = recent.iter().map(|r| r.0).min().unwrap_or(stamp);
        if stamp - oldest > rules.confirm_window_ns {
            return;
        }
        let distinct = (0..m).filter(|&i| recent[..i].iter().all(|r| r.1 != recent[i].1)).count();
        self.confirmed = distinct >= rules.confirm_min_robots;
    }
}

/// Whether a track should be lost at `now`: `last_accepted` is the stamp of its
/// last accepted DoA (or its initialization), `single_since` that of the first
/// accepted DoA of the newest one's robot since another robot's (or the
/// initialization; [`Confirmation::single_run_start`]), and `position_rms_m`
/// its position RMS predicted to `now`.
/// Divergence is checked first, then silence, then single-robot support.
pub fn check_loss(
    confirmed: bool,
    now: Stamp,
    last_accepted: Stamp,
    single_since: Stamp,
    position_rms_m: f64,
    rules: &LifecycleRules,
) -> Option<LossReason> {
    if !(position_rms_m <= rules.lost_max_rms_m) {
        return Some(LossReason::Diverged { position_rms_m });
    }
    let silent_s = now.seconds_since(last_accepted);
    let timeout_s = if confirmed { rules.lost_timeout_s } else { rules.tentative_timeout_s };
    if silent_s > timeout_s {
        return Some(LossReason::Silent { silent_s });
    }
    // Span of DoAs from one robot only, up to the newest accepted one.
    let single_s = last_accepted.seconds_since(single_since);
    (confirmed && single_s > rules.single_robot_timeout_s).then_some(LossReason::SingleRobot { single_s })
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULES: LifecycleRules = LifecycleRules {
        confirm_updates: 4,
        confirm_min_robots: 2,
        confirm_window_ns: 1_000_000_000,
        confirm_max_rms_m: 0.5,
        tentative_timeout_s: 1.0,
        lost_timeout_s: 2.0,
        lost_max_rms_m: 2.0,
        support_window_ns: 500_000_000,
        single_robot_timeout_s: 1.0,
    };

    fn ms(t: i64) -> Stamp {
        Stamp::from_ns(t * 1_000_000)
    }

    #[test]
    fn one_robot_never_confirms() {
        let mut c = Confirmation::default();
        for k in 0..20 {
            c.record(ms(k * 50), 7, 0.1, &RULES);
        }
        assert!(!c.is_confirmed());
    }

    #[test]
    fn confirms_on_the_mth_update_from_two_robots() {
        let mut c = Confirmation::default();
        for k in 0..3 {
            c.record(ms(k * 100), k as u32 % 2, 0.1, &RULES);
            assert!(!c.is_confirmed());
        }
        c.record(ms(300), 1, 0.1, &RULES);
        assert!(c.is_confirmed());
    }

    #[test]
    fn spread_out_or_uncertain_updates_do_not_confirm() {
        let mut c = Confirmation::default();
        for k in 0..8 {
            c.record(ms(k * 600), k as u32 % 2, 0.1, &RULES);
        }
        assert!(!c.is_confirmed(), "4 updates over 1.8 s > 1 s window");
        let mut c = Confirmation::default();
        for k in 0..8 {
            c.record(ms(k * 100), k as u32 % 2, 0.8, &RULES);
        }
        assert!(!c.is_confirmed(), "RMS above the confirmation threshold");
    }

    #[test]
    fn loss_by_silence_divergence_and_single_robot() {
        assert_eq!(check_loss(false, ms(900), ms(0), ms(0), 0.3, &RULES), None);
        assert!(matches!(
            check_loss(false, ms(1100), ms(0), ms(0), 0.3, &RULES),
            Some(LossReason::Silent { .. })
        ));
        assert_eq!(check_loss(true, ms(1100), ms(0), ms(0), 0.3, &RULES), None);
        assert!(matches!(
            check_loss(true, ms(100), ms(0), ms(0), 2.5, &RULES),
            Some(LossReason::Diverged { .. })
        ));
        assert!(matches!(
            check_loss(true, ms(100), ms(0), ms(0), f64::NAN, &RULES),
            Some(LossReason::Diverged { .. })
        ));
        // Fed by one robot only (accepted DoAs keep coming): lost after single_robot_timeout.
        assert_eq!(check_loss(true, ms(1500), ms(1490), ms(600), 0.3, &RULES), None);
        assert!(matches!(
            check_loss(true, ms(1700), ms(1690), ms(600), 0.3, &RULES),
            Some(LossReason::SingleRobot { .. })
        ));
    }

    #[test]
    fn support_needs_a_second_robot_recently() {
        let mut c = Confirmation::default();
        for k in 0..6 {
            c.record(ms(k * 10), k as u32 % 2, 0.1, &RULES);
        }
        assert!(c.is_supported(ms(50), RULES.support_window_ns));
        assert_eq!(c.second_robot(), Some(ms(40)));
        // Robot 1 is gated from now on: only robot 0's updates are accepted.
        for k in 6..200 {
            c.record(ms(k * 10), 0, 0.1, &RULES);
        }
        assert_eq!(c.second_robot(), Some(ms(50)));
        assert!(!c.is_supported(ms(1990), RULES.support_window_ns));
        // Robot 0 alone since its first update after robot 1's last one.
        assert_eq!(c.single_run_start(), Some(ms(60)));
    }

    #[test]
    fn a_silence_is_not_single_robot_feeding() {
        let mut c = Confirmation::default();
        for k in 0..10 {
            c.record(ms(k * 100), k as u32 % 2, 0.1, &RULES);
        }
        // Both robots until 0.9 s (robot 1 last), then 1.5 s of silence, then robot 0.
        c.record(ms(2400), 0, 0.1, &RULES);
        assert_eq!(c.single_run_start(), Some(ms(2400)));
        let single = c.single_run_start().unwrap();
        assert_eq!(check_loss(true, ms(2450), ms(2400), single, 0.3, &RULES), None);
        // Robot 0 alone for 1.1 s after that: lost.
        for k in 1..=11 {
            c.record(ms(2400 + k * 100), 0, 0.1, &RULES);
        }
        let single = c.single_run_start().unwrap();
        assert!(matches!(
            check_loss(true, ms(3550), ms(3500), single, 0.3, &RULES),
            Some(LossReason::SingleRobot { .. })
        ));
    }
}

//! When a planning cycle runs: the one owner of the planning cycle's timing.
//!
//! The coordinator asks [`Planner::cycle_due`](super::Planner::cycle_due)
//! (through `coordinator::positioning`, which adds only the operator's on/off
//! switch) on every published estimate, and runs a cycle when it says so.
//! Nothing else in the coordinator decides when to plan.
//!
//! Two clocks live here, because they limit two different things and merging
//! them would change what the robots do:
//!
//! - **Evaluation** (`[active_positioning] evaluate_period_ms`, default 100 ms):
//!   how often the planner *looks* at the geometry. Estimates arrive at tens of
//!   hertz; a cycle costs a Fisher assessment, a pattern search and possibly a
//!   Clarabel solve. This bounds the cost and sets how quickly a geometry that
//!   goes bad after a hold is acted on (≤ 100 ms by default). Every cycle,
//!   whatever its outcome (a hold, a wait, no usable source), restarts it.
//! - **Re-tasking** (`[planner] planning_period_s`, default 1 s): how often the
//!   robots are *sent new goals*. Only a cycle that issued goals restarts it;
//!   until it has run, a cycle ends in
//!   [`HoldReason::NotDue`](super::HoldReason::NotDue). The step a robot may take
//!   per cycle is derived from it ([`PlannerConfig::step_m`](super::PlannerConfig::step_m)).
//!
//! A single gate could not keep both: at 1 s the coordinator would notice a bad
//! geometry up to a second late after each hold; at 100 ms robots would be
//! re-tasked ten times a second. With the defaults the robots get new goals at
//! most once per `planning_period_s` and the geometry is checked ten times in
//! between. A planner used on its own ([`Planner::new`](super::Planner::new))
//! evaluates on every call and keeps only the re-tasking clock.
//!
//! **Following a walker** (`[planner] follow_retask_travel_m`, default
//! 0.5 m; `follow_retask_max_sigma_m`, default 0.15 m). The re-tasking period
//! is a time only because a source walking at 0.5 m/s moves half a metre in
//! it. A faster source moves further: a walker at 1 m/s has gone a metre
//! between two re-taskings, and in the start scenarios' sweeps θ left the
//! band at its low edge while robots chased a pattern placed a second ago.
//! So, while the estimate is precise (its largest horizontal 1-σ at most
//! `follow_retask_max_sigma_m`), the period for a cycle is the time the
//! source takes to move `follow_retask_travel_m` at its tracked horizontal
//! speed, between half of `planning_period_s` and all of it, and the step
//! shrinks with it ([`PlannerConfig::step_for_period_m`](super::PlannerConfig::step_for_period_m)):
//! 1 m/s → 0.5 s and 0.6 m steps at 0.8 m/s; 0.7 m/s → 0.71 s; 0.5 m/s
//! or slower → the full period. A vague estimate keeps the full period:
//! re-planning around it more often moves robots after the estimate's
//! noise, not the source (0.15 m: the half metre walked is then more than
//! three of its σ). Escapes from the keep-out ignore both clocks.
//! Measured (BENCHMARKS.md, "Re-tasking that follows the walker"): over the
//! start scenarios' 20-seed sweep, runs below 95 % in band 15 → 13 and goals
//! inside the true keep-out 6 → 1; a re-tasking period of 0.5 s for every
//! source (measured before) cleared the white-noise walkers too, but put
//! 15 goals inside the keep-out around the talker's less accurate estimates.
//!
//! Per-goal rules are not cycle gates and live with the goals: a command's
//! deadline (`coordinator::commands`) ends a robot's "busy" state, and a goal a
//! robot refused is not re-sent for `retry_after_s` (`coordinator::reposition`).

use soundmap_proto::Stamp;

/// The planning cycle's two clocks (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Cadence {
    /// Shortest time between two cycles (ns); 0: every call.
    evaluate_period_ns: i64,
    /// Shortest time between two cycles that issue goals (s).
    planning_period_s: f64,
    /// When the last cycle ran.
    last_cycle: Option<Stamp>,
    /// When goals were last issued.
    last_retask: Option<Stamp>,
}

impl Cadence {
    /// Clocks with these periods, neither started.
    pub fn new(evaluate_period_ns: i64, planning_period_s: f64) -> Self {
        Cadence { evaluate_period_ns, planning_period_s, last_cycle: None, last_retask: None }
    }

    /// Whether a cycle is due at `now`: none ran yet, the evaluation period
    /// has elapsed, or the clock went back.
    pub fn cycle_due(&self, now: Stamp) -> bool {
        self.last_cycle.is_none_or(|t| now - t >= self.evaluate_period_ns || now < t)
    }

    /// Records that a cycle ran at `now` (whatever its outcome).
    pub fn cycle_ran(&mut self, now: Stamp) {
        self.last_cycle = Some(now);
    }

    /// Seconds to wait before goals may be issued again, if any.
    pub fn retask_wait_s(&self, now: Stamp) -> Option<f64> {
        self.retask_wait_for_s(now, self.planning_period_s)
    }

    /// As [`Self::retask_wait_s`], with a re-tasking period of `period_s`
    /// for this cycle instead of the configured one.
    pub fn retask_wait_for_s(&self, now: Stamp, period_s: f64) -> Option<f64> {
        let since = now.seconds_since(self.last_retask?);
        (since >= 0.0 && since < period_s).then_some(period_s - since)
    }

    /// Records that goals were issued at `now`.
    pub fn retasked(&mut self, now: Stamp) {
        self.last_retask = Some(now);
    }

    /// Forgets when goals were last issued (the plans they came from are forgotten).
    pub fn forget_retask(&mut self) {
        self.last_retask = None;
    }

    /// Forgets both clocks: the next call is due and may issue goals.
    pub fn restart(&mut self) {
        self.last_cycle = None;
        self.last_retask = None;
    }

    /// When the last cycle ran.
    pub fn last_cycle(&self) -> Option<Stamp> {
        self.last_cycle
    }

    /// The evaluation period (ns).
    pub fn evaluate_period_ns(&self) -> i64 {
        self.evaluate_period_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cycles_are_gated_by_the_evaluation_period() {
        let mut c = Cadence::new(100_000_000, 1.0);
        let t = Stamp::from_secs_f64(10.0);
        assert!(c.cycle_due(t), "first call");
        c.cycle_ran(t);
        assert!(!c.cycle_due(t.plus_ns(99_999_999)));
        assert!(c.cycle_due(t.plus_ns(100_000_000)));
        assert!(c.cycle_due(t.plus_ns(-1)), "clock went back");
        c.restart();
        assert!(c.cycle_due(t));
        let every_call = Cadence::new(0, 1.0);
        assert!(every_call.cycle_due(t));
    }

    #[test]
    fn retasking_is_rate_limited() {
        let mut c = Cadence::new(0, 2.0);
        assert_eq!(c.retask_wait_s(Stamp::ZERO), None);
        c.retasked(Stamp::from_secs_f64(10.0));
        assert!((c.retask_wait_s(Stamp::from_secs_f64(10.5)).unwrap() - 1.5).abs() < 1e-9);
        assert_eq!(c.retask_wait_s(Stamp::from_secs_f64(12.0)), None);
        assert_eq!(c.retask_wait_s(Stamp::from_secs_f64(9.0)), None, "clock went back");
        // A shorter period for one cycle (a source on the move).
        assert!((c.retask_wait_for_s(Stamp::from_secs_f64(10.5), 0.75).unwrap() - 0.25).abs() < 1e-9);
        assert_eq!(c.retask_wait_for_s(Stamp::from_secs_f64(10.75), 0.75), None);
        c.forget_retask();
        assert_eq!(c.retask_wait_s(Stamp::from_secs_f64(10.5)), None);
    }
}

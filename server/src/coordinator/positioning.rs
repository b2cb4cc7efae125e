//! Active positioning inside the coordinator: the operator's switch and θ
//! band, the [`Planner`], and the bookkeeping that turns its goals into
//! reposition commands (ids, deadlines, operator text) and its holds and
//! infeasibilities into a status.

pub use soundmap_proto::monitoring::{PlanKind, PlannerStatus, PositioningSettings, PositioningUpdate};
use soundmap_proto::{RepositionCommand, RepositionReason, Stamp, ValidationError};

use crate::config::{ActivePositioningConfig, CoordinatorConfig, invalid_key};
use crate::error::ServerError;
use crate::planner::{
    Goal, HoldReason, InfeasibleReason, PlanOutcome, Planner, PlannerConfig, PlannerInput, StartGoal,
    StartPlan, StartRobot, ThetaBand,
};

/// Longest operator text of a command (the contract's text limit).
const MAX_DETAIL_CHARS: usize = 256;

/// Active positioning state: settings, planner, command ids and status.
#[derive(Debug)]
pub struct Positioning {
    settings: PositioningSettings,
    config: ActivePositioningConfig,
    /// The `[planner]` section; the band of `settings` replaces its own.
    planner_config: PlannerConfig,
    planner: Planner,
    next_command_id: u64,
    status: Option<PlannerStatus>,
    /// Since when planning cycles have found no estimate at all (planning from
    /// bearings waits `BEARINGS_AFTER_S` of that, as it does after an estimate).
    without_estimate_since: Option<Stamp>,
}

impl Positioning {
    /// From a coordinator configuration (errors name `planner.<field>`).
    pub fn new(config: &CoordinatorConfig) -> Result<Self, ServerError> {
        let ap = &config.active_positioning;
        let planner_config = config.planner_config();
        let planner = Planner::new(planner_config.clone())
            .map_err(|e| invalid_key("<config>".as_ref(), e.within("planner")))?
            .with_evaluate_period_ns(ap.evaluate_period_ms as i64 * 1_000_000);
        Ok(Positioning {
            settings: PositioningSettings {
                enabled: ap.enabled,
                theta_min_deg: ap.theta_min_deg,
                theta_max_deg: ap.theta_max_deg,
            },
            config: ap.clone(),
            planner_config,
            planner,
            next_command_id: 1,
            without_estimate_since: None,
            status: None,
        })
    }

    /// Current settings.
    pub fn settings(&self) -> PositioningSettings {
        self.settings
    }

    /// The planner's latest decision.
    pub fn status(&self) -> Option<&PlannerStatus> {
        self.status.as_ref()
    }

    /// Its command settings.
    pub fn config(&self) -> &ActivePositioningConfig {
        &self.config
    }

    /// Applies an update after checking it; a new band reaches the planner
    /// (whose memory of earlier plans is then reset). Errors name the field.
    pub fn update(&mut self, u: &PositioningUpdate) -> Result<PositioningSettings, ServerError> {
        let min = u.theta_min_deg.unwrap_or(self.settings.theta_min_deg);
        let max = u.theta_max_deg.unwrap_or(self.settings.theta_max_deg);
        let blame_max = u.theta_min_deg.is_none();
        ThetaBand::new(min, max, self.planner_config.theta_hysteresis_deg, blame_max)?;
        if (min, max) != (self.settings.theta_min_deg, self.settings.theta_max_deg) {
            let cfg = PlannerConfig { theta_min_deg: min, theta_max_deg: max, ..self.planner_config.clone() };
            // The band passed ThetaBand, so the planner has nothing else to object to;
            // should it, its error is about the band's edges.
            self.planner = self.planner.reconfigured(cfg.clone()).map_err(|e| {
                let field = if blame_max { "theta_max_deg" } else { "theta_min_deg" };
                ValidationError::new(field, e.problem)
            })?;
            self.planner_config = cfg;
            self.settings.theta_min_deg = min;
            self.settings.theta_max_deg = max;
        }
        if let Some(enabled) = u.enabled {
            if enabled && !self.settings.enabled {
                // Plans from before it was switched off say nothing about now.
                self.planner.reset();
            }
            self.settings.enabled = enabled;
        }
        Ok(self.settings)
    }

    /// Whether a planning cycle should run at `now`: switched on, and due by
    /// the planner's [`cadence`](crate::planner::cadence) (the one gate).
    pub fn due(&self, now: Stamp) -> bool {
        self.settings.enabled && self.planner.cycle_due(now)
    }

    /// Records that no source estimate can be planned around.
    pub fn no_source(&mut self, now: Stamp, why: String) {
        self.planner.skip_cycle(now);
        self.record(now, PlanKind::Hold, "no_source", why);
    }

    /// One planning cycle. `NotDue` waits are returned but not recorded.
    pub fn plan(&mut self, now: Stamp, input: &PlannerInput) -> PlanOutcome {
        let outcome = self.planner.plan(now, input);
        match &outcome {
            PlanOutcome::Planned(goals) => {
                let first = goals.first();
                let detail =
                    format!("{} goal(s): {}", goals.len(), first.map_or("", |g| reason_text(g.reason)));
                self.record(now, PlanKind::Planned, "planned", detail);
                if let Some(s) = self.status.as_mut() {
                    s.last_planned = Some(now);
                    s.predicted_theta_deg = first.map(|g| g.predicted_theta_deg);
                    s.predicted_gdop = first.map(|g| g.predicted_gdop);
                    s.used_fallback = goals.iter().any(|g| g.used_fallback);
                }
            }
            PlanOutcome::Hold(HoldReason::NotDue { .. }) => {}
            PlanOutcome::Hold(h) => self.record(now, PlanKind::Hold, hold_key(h), h.to_string()),
            PlanOutcome::Infeasible(r) => {
                self.record(now, PlanKind::Infeasible, infeasible_key(r), r.to_string())
            }
        }
        outcome
    }

    /// Seconds for which cycles have found no estimate at all, counted from the
    /// first such cycle.
    pub fn seconds_without_estimate(&mut self, now: Stamp) -> f64 {
        let since = *self.without_estimate_since.get_or_insert(now);
        (now - since) as f64 * 1e-9
    }

    /// An estimate came: the count of [`Positioning::seconds_without_estimate`] restarts.
    pub fn estimate_seen(&mut self) {
        self.without_estimate_since = None;
    }

    /// One cycle of planning from bearings (no usable source estimate; see
    /// [`crate::planner::start`]): the goals to send, each saying why.
    /// `why_no_source` says why the Fisher planning could not run.
    pub fn plan_from_bearings(
        &mut self,
        now: Stamp,
        robots: &[StartRobot],
        hint: Option<nalgebra::Point3<f64>>,
        why_no_source: &str,
    ) -> Vec<StartGoal> {
        match self.planner.plan_from_bearings(now, robots, hint) {
            StartPlan::Hold(why) => {
                if !why.starts_with("not due") {
                    self.record(now, PlanKind::Hold, "no_source", format!("{why_no_source}; {why}"));
                }
                Vec::new()
            }
            StartPlan::Goals(goals) => {
                let key = if goals.iter().all(|g| g.why.starts_with("nothing heard")) {
                    "exploring"
                } else {
                    "from_bearings"
                };
                let detail = match goals.first() {
                    Some(g) => format!("{why_no_source}; {} goal(s): {}", goals.len(), g.why),
                    None => format!("{why_no_source}; robots already on their way"),
                };
                self.record(now, PlanKind::Planned, key, truncate(detail));
                if !goals.is_empty()
                    && let Some(s) = self.status.as_mut()
                {
                    s.last_planned = Some(now);
                }
                goals
            }
        }
    }

    /// The command for a goal of planning from bearings, with the next id.
    pub fn start_command(&mut self, now: Stamp, goal: &StartGoal) -> RepositionCommand {
        let id = self.next_command_id;
        self.next_command_id += 1;
        if let Some(s) = self.status.as_mut() {
            s.commands_issued += 1;
        }
        RepositionCommand {
            command_id: id,
            goal_map_from_base: goal.map_from_base,
            look_at_in_map: goal.look_at_in_map,
            reason: RepositionReason::ThetaOutOfBand,
            detail: truncate(goal.why.clone()),
            deadline: now.plus_secs(self.config.command_deadline_s),
            issued: now,
        }
    }

    /// Appends to the detail of the latest decision (e.g. goals not re-sent).
    pub fn annotate(&mut self, text: &str) {
        if let Some(s) = self.status.as_mut() {
            s.detail = format!("{}; {text}", s.detail);
        }
    }

    /// The command for `goal` issued at `now` with the next id. `theta_deg` is
    /// the current θ, for the operator text.
    pub fn command(&mut self, now: Stamp, goal: &Goal, theta_deg: f64) -> RepositionCommand {
        let id = self.next_command_id;
        self.next_command_id += 1;
        if let Some(s) = self.status.as_mut() {
            s.commands_issued += 1;
        }
        let s = &self.settings;
        let mut detail = format!(
            "{}: θ {theta_deg:.1}° (band {}–{}°) → {:.1}°, GDOP → {:.2}",
            reason_text(goal.reason),
            s.theta_min_deg,
            s.theta_max_deg,
            goal.predicted_theta_deg,
            goal.predicted_gdop
        );
        // A plan from the sampling search says so, and why, in the goal's note.
        if let Some(note) = &goal.note {
            detail.push_str("; ");
            detail.push_str(note);
        }
        detail = truncate(detail);
        RepositionCommand {
            command_id: id,
            goal_map_from_base: goal.map_from_base,
            look_at_in_map: goal.look_at_in_map,
            reason: goal.reason,
            detail,
            deadline: now.plus_secs(self.config.command_deadline_s),
            issued: now,
        }
    }

    fn record(&mut self, now: Stamp, kind: PlanKind, key: &'static str, detail: String) {
        tracing::debug!(at_ns = now.as_ns(), key, detail = %detail, "planner decision");
        let previous = self.status.take();
        self.status = Some(PlannerStatus {
            decided: now,
            kind,
            key,
            detail,
            last_planned: previous.as_ref().and_then(|p| p.last_planned),
            commands_issued: previous.as_ref().map_or(0, |p| p.commands_issued),
            predicted_theta_deg: previous.as_ref().and_then(|p| p.predicted_theta_deg),
            predicted_gdop: previous.as_ref().and_then(|p| p.predicted_gdop),
            used_fallback: previous.is_some_and(|p| p.used_fallback),
        });
    }
}

/// `text` cut to the contract's limit.
fn truncate(text: String) -> String {
    if text.chars().count() > MAX_DETAIL_CHARS {
        text.chars().take(MAX_DETAIL_CHARS - 1).collect::<String>() + "…"
    } else {
        text
    }
}

fn reason_text(r: RepositionReason) -> &'static str {
    match r {
        RepositionReason::ThetaOutOfBand => "θ out of band",
        RepositionReason::GdopHigh => "GDOP high",
        RepositionReason::Improvement => "better geometry",
        RepositionReason::FollowSource => "following the source",
        RepositionReason::KeepOut => "inside the keep-out",
    }
}

fn hold_key(h: &HoldReason) -> &'static str {
    match h {
        HoldReason::TooFewRobots { .. } => "too_few_robots",
        HoldReason::SourceUntrusted { .. } => "source_untrusted",
        HoldReason::InvalidInput { .. } => "invalid_input",
        HoldReason::NotDue { .. } => "not_due",
        HoldReason::GeometryGood { .. } => "geometry_good",
        HoldReason::GoalsInProgress => "goals_in_progress",
        HoldReason::AtBestFeasible { .. } => "at_best_feasible",
    }
}

fn infeasible_key(r: &InfeasibleReason) -> &'static str {
    match r {
        InfeasibleReason::NoFreeSpotAroundSource { .. } => "no_free_spot",
        InfeasibleReason::RobotStuck { .. } => "robot_stuck",
        InfeasibleReason::NoJointPlacement { .. } => "no_joint_placement",
    }
}

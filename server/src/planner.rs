//! Active positioning: where the robots should go so that the angle θ at the
//! source between them stays in band (default 40°–140°, ideally 90°) and the
//! GDOP stays low (theory §2.4 and §3).
//!
//! Pure: [`Planner::plan`] takes `now` and a [`PlannerInput`] and returns a
//! [`PlanOutcome`]; the planner keeps only its hysteresis memory and its
//! [`cadence`]: the one owner of when a planning cycle runs and when robots
//! may be re-tasked.
//!
//! One cycle:
//! 1. checks the input (≥ 2 robots, finite numbers, a trusted source) and the
//!    re-tasking clock of the [`cadence`]; predicts the source `source_lead_s` ahead;
//! 2. [`bearings`]: the target pattern from the Fisher information, matched to
//!    the robots with the least travel (and sticky across cycles); blocked
//!    ideal spots are replaced by the nearest free spot in their wedge;
//! 3. `hysteresis`: re-plan only on θ out of band, GDOP high, a worthwhile
//!    predicted improvement, or goals made invalid / left behind by the source;
//! 4. `cycle` + `qp`: this cycle's waypoints from a Clarabel QP/SOCP
//!    (wedges, keep-out chord, range and step cones, convex free region,
//!    linearised separation), else the `sampling` search; the search also
//!    runs when the convex step would leave θ out of the band, and its
//!    placement is kept when θ ends nearer the band;
//! 5. every waypoint is checked against the hard constraints (step, range,
//!    free space with clearance, separation, and the keep-out along the
//!    source's path from where it is to where it is predicted: `cycle::KeepOut`)
//!    before it becomes a [`Goal`]; the sampling search offers only spots that
//!    keep it.
//!
//! A robot inside the keep-out is sent out of it first, whatever the
//! re-tasking clock (`escape`): that cycle issues only those goals; and an
//! ordinary cycle's goal that would leave a robot inside is replaced by the
//! way out.
//!
//! Before any position exists, [`Planner::plan_from_bearings`] moves the
//! robots from what they hear ([`start`]): spread across a heard bearing,
//! approach along it, rescue deaf robots, explore when nobody hears.
//!
//! Submodules: [`start`], [`band`] (the θ band), [`cadence`] (when cycles run), [`config`], [`free_space`], [`bearings`], [`assignment`],
//! [`pose`], `cycle`, `qp`, `sampling`, `waypoints`, `hysteresis`, and the input/outcome types.

pub mod assignment;
pub mod band;
pub mod bearings;
pub mod cadence;
pub mod config;
mod cycle;
mod escape;
pub mod free_space;
mod hysteresis;
mod input;
mod outcome;
pub mod pose;
mod qp;
mod sampling;
pub mod start;
mod waypoints;

use nalgebra::Point2;
use soundmap_proto::{Stamp, ValidationError};

pub use band::ThetaBand;
pub use cadence::Cadence;
pub use config::{PlannerConfig, SamplingConfig};
pub use free_space::{Blocked, FreeSpace, FreeSpaceConfig, HalfPlane};
pub use input::{PlannerInput, RobotState, SourceEstimate};
pub use outcome::{Goal, HoldReason, InfeasibleReason, PlanOutcome};
pub use soundmap_proto::RepositionReason;
pub use start::{Heard, StartGoal, StartPlan, StartRobot};

use bearings::{PatternRobot, PatternSettings, TargetPattern, choose_pattern};
use hysteresis::{Decision, Memory, Situation, decide};
use pose::sensor_at;

use crate::uncertainty::{Sensor, assess};

/// Clearances an ordinary goal's push out of the keep-out tries, from the
/// full margin down to a quarter of it, the first the constraints allow.
const PUSH_TRIES: usize = 4;

/// The placement planner: configuration, free space, hysteresis memory and cadence.
#[derive(Clone, Debug)]
pub struct Planner {
    config: PlannerConfig,
    free: FreeSpace,
    memory: Memory,
    cadence: Cadence,
    explore: start::Explore,
}

/// Per-robot facts of one cycle.
struct RobotCycle {
    p0: Point2<f64>,
    bounds: (f64, f64),
    /// Largest move this cycle at its own speed (m).
    step: f64,
    /// Cost of its travel per metre ([`PlannerConfig::travel_scale`]).
    travel_scale: f64,
    /// Final target spot (free), if one was found in the robot's wedge.
    target: Option<Point2<f64>>,
    note: Option<String>,
}

impl Planner {
    /// A planner with a validated configuration.
    pub fn new(config: PlannerConfig) -> Result<Self, ValidationError> {
        config.validate()?;
        let free = FreeSpace::new(&config.free_space, config.wall_clearance_m());
        let cadence = Cadence::new(0, config.planning_period_s);
        Ok(Planner { config, free, memory: Memory::default(), cadence, explore: start::Explore::default() })
    }

    /// The same planner evaluating at most once per `evaluate_period_ns`
    /// ([`Planner::cycle_due`]); [`Planner::new`] evaluates on every call.
    pub fn with_evaluate_period_ns(mut self, evaluate_period_ns: i64) -> Self {
        self.cadence = Cadence::new(evaluate_period_ns, self.config.planning_period_s);
        self
    }

    /// A planner for `config` that keeps this one's evaluation clock (its
    /// hysteresis memory and re-tasking clock start afresh, as after [`Planner::new`]).
    pub fn reconfigured(&self, config: PlannerConfig) -> Result<Self, ValidationError> {
        let mut cadence = Cadence::new(self.cadence.evaluate_period_ns(), config.planning_period_s);
        if let Some(t) = self.cadence.last_cycle() {
            cadence.cycle_ran(t);
        }
        let mut planner = Planner::new(config)?;
        planner.cadence = cadence;
        Ok(planner)
    }

    /// Whether a planning cycle is due at `now` (see [`cadence`]).
    pub fn cycle_due(&self, now: Stamp) -> bool {
        self.cadence.cycle_due(now)
    }

    /// Records a cycle that ran without calling [`Planner::plan`] (e.g. no
    /// usable source estimate): it restarts the evaluation clock.
    pub fn skip_cycle(&mut self, now: Stamp) {
        self.cadence.cycle_ran(now);
    }

    /// The configuration.
    pub fn config(&self) -> &PlannerConfig {
        &self.config
    }

    /// The free space (with the robots' clearance).
    pub fn free_space(&self) -> &FreeSpace {
        &self.free
    }

    /// Forgets the previous plans (hysteresis state, sticky pattern) and
    /// restarts the cadence: the next call is due and may issue goals.
    pub fn reset(&mut self) {
        self.memory = Memory::default();
        self.explore.clear();
        self.cadence.restart();
    }

    /// One planning cycle at `now`.
    pub fn plan(&mut self, now: Stamp, input: &PlannerInput) -> PlanOutcome {
        self.cadence.cycle_ran(now);
        if let Some(h) = check_input(&self.config, input) {
            return PlanOutcome::Hold(h);
        }
        let escapes = self.escapes(input);
        if !escapes.is_empty() {
            self.cadence.retasked(now);
            return PlanOutcome::Planned(escapes);
        }
        let cfg = &self.config;
        let s = &input.source;
        // A precise estimate of a moving source shortens the re-tasking period
        // (`cadence`, "Following a walker").
        let speed = s.velocity_in_map.map_or(0.0, |v| v.x.hypot(v.y));
        let sigma_h = escape::horizontal_sigma_m(&s.covariance_m2);
        let period = cfg.retask_period_s(speed, sigma_h);
        if let Some(wait_s) = self.cadence.retask_wait_for_s(now, period) {
            return PlanOutcome::Hold(HoldReason::NotDue { wait_s });
        }
        let src = s.predicted(cfg.source_lead_s);
        let centre = Point2::new(src.x, src.y);
        let robots = &input.robots;

        let now_sensors: Vec<Sensor> = robots
            .iter()
            .map(|r| Sensor { origin: r.array_in_map(), sigma_rad: r.sigma_rad, origin_sigma_m: 0.0 })
            .collect();
        let current = assess(&now_sensors, &src);

        // Target pattern: the pure-geometry optimum, then the obstacle-aware choice.
        let pattern_robots: Vec<PatternRobot> = robots
            .iter()
            .map(|r| PatternRobot {
                base_xy: r.base_xy(),
                base_from_array: r.base_from_array,
                sigma_rad: r.sigma_rad,
                // The previous target bearing binds only a robot that is still on its
                // way there (within 45°): one pushed elsewhere starts afresh.
                previous_bearing_rad: self.memory.bearing_of(&r.id).filter(|b| {
                    let d = r.base_xy() - centre;
                    pose::wrap(d.y.atan2(d.x) - b).abs() < std::f64::consts::FRAC_PI_4
                }),
                heading_rad: Some(r.map_from_base.rotation.euler_angles().2),
                travel_scale: cfg.travel_scale(&r.base),
                turn_cost_m_per_rad: cfg.turn_cost_m_per_rad(&r.base),
            })
            .collect();
        let settings = PatternSettings {
            range_m: cfg.range_for_speed_m(speed),
            rotation_step_deg: cfg.pattern_rotation_step_deg,
            switch_weight: cfg.pattern_switch_weight,
            blocked_penalty_m: 0.0,
            info_weight_m: cfg.pattern_info_weight_m,
        };
        let ideal = choose_pattern(&src, &pattern_robots, &settings, None);
        // Penalising blocked spots only raises the cost of candidates with one, so
        // when the pure-geometry optimum has none it is also the obstacle-aware one.
        let ideal_blocked = ideal.spots.iter().any(|g| !self.free.is_free(g));
        let chosen = if cfg.blocked_spot_penalty_m > 0.0 && ideal_blocked {
            let s = PatternSettings { blocked_penalty_m: cfg.blocked_spot_penalty_m, ..settings };
            choose_pattern(&src, &pattern_robots, &s, Some(&self.free))
        } else {
            ideal.clone()
        };
        let half = cfg.wedge_half_width_deg.to_radians().min(0.45 * chosen.min_spacing_rad);
        let per_robot = self.resolve_targets(&centre, robots, &ideal, &chosen, half, period);

        // Decide.
        let target_sensors: Vec<Sensor> = robots
            .iter()
            .zip(&per_robot)
            .map(|(r, c)| sensor_at(&c.target.unwrap_or(c.p0), &src, &r.base_from_array, r.sigma_rad))
            .collect();
        let target_quality = assess(&target_sensors, &src);
        let improvement = if !current.rms_m.is_finite() {
            1.0
        } else if target_quality.rms_m.is_finite() {
            1.0 - target_quality.rms_m / current.rms_m
        } else {
            0.0
        };
        let source_moved_m =
            self.memory.planned_source.map_or(f64::INFINITY, |p| (Point2::new(p.x, p.y) - centre).norm());
        // θ once every robot is where it is driving to.
        let destination_sensors: Vec<Sensor> = robots
            .iter()
            .map(|r| sensor_at(&r.destination_xy(), &src, &r.base_from_array, r.sigma_rad))
            .collect();
        let situation = Situation {
            destination_theta_deg: assess(&destination_sensors, &src).theta_deg,
            theta_deg: current.theta_deg,
            gdop: current.gdop,
            improvement,
            busy: robots.iter().any(|r| r.active_goal.is_some()),
            goals_valid: self.active_goals_valid(&centre, robots),
            idle_out_of_ring: robots.iter().any(|r| {
                let rho = (r.base_xy() - centre).norm();
                r.active_goal.is_none() && !(rho >= cfg.min_range_m && rho <= cfg.max_range_m)
            }),
            source_moved_m,
        };
        let reason = match decide(cfg, self.memory.engaged, &situation) {
            Decision::Hold(h) => {
                if matches!(h, HoldReason::GeometryGood { .. }) {
                    self.memory.engaged = None;
                }
                return PlanOutcome::Hold(h);
            }
            Decision::Replan(r) => r,
        };

        // This cycle's waypoints.
        let keep = escape::keep_out(s, cfg.source_lead_s, cfg.min_range_m);
        let cycle = match self.waypoints(&src, &keep, robots, &per_robot, half) {
            Ok(w) => w,
            Err(reason) => return PlanOutcome::Infeasible(reason),
        };
        let waypoints = &cycle.spots;
        let after: Vec<Sensor> = robots
            .iter()
            .zip(waypoints)
            .map(|(r, w)| sensor_at(w, &src, &r.base_from_array, r.sigma_rad))
            .collect();
        let predicted = assess(&after, &src);
        let goals = self.goals(&src, robots, &per_robot, &cycle, &predicted, reason);
        let goals = self.keep_out_first(input, goals);
        if goals.is_empty() {
            if situation.busy {
                // The goals being driven to are still this cycle's plan: confirm them
                // for the current source so that following starts from here.
                self.memory.planned_source = Some(src);
                return PlanOutcome::Hold(HoldReason::GoalsInProgress);
            }
            self.memory.engaged = None;
            return PlanOutcome::Hold(HoldReason::AtBestFeasible {
                theta_deg: current.theta_deg,
                gdop: current.gdop,
            });
        }
        self.cadence.retasked(now);
        self.memory.planned_source = Some(src);
        self.memory.engaged = Some(reason);
        self.memory.bearings = robots
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let b = if per_robot[i].target.is_some() {
                    chosen.bearings_rad[i]
                } else {
                    let d = waypoints[i] - centre;
                    d.y.atan2(d.x)
                };
                (r.id.clone(), b)
            })
            .collect();
        PlanOutcome::Planned(goals)
    }

    /// One cycle of planning without a source estimate, from what the robots
    /// hear (see [`start`]); `hint` is a recent but unusable source position.
    /// Obeys the same re-tasking clock as [`Planner::plan`].
    pub fn plan_from_bearings(
        &mut self,
        now: Stamp,
        robots: &[StartRobot],
        hint: Option<nalgebra::Point3<f64>>,
    ) -> StartPlan {
        self.cadence.cycle_ran(now);
        if let Some(wait_s) = self.cadence.retask_wait_s(now) {
            return StartPlan::Hold(format!("not due for {wait_s:.1} s"));
        }
        let cfg = &self.config;
        let settings = start::StartSettings {
            preferred_range_m: cfg.preferred_range_m,
            min_range_m: cfg.min_range_m,
            min_separation_m: cfg.min_separation_m,
            array_height_m: 0.5,
        };
        let plan =
            start::plan(now.as_ns() as f64 * 1e-9, &self.free, &settings, &mut self.explore, robots, hint);
        if matches!(&plan, StartPlan::Goals(g) if !g.is_empty()) {
            self.cadence.retasked(now);
            // The Fisher planning that follows starts afresh.
            self.memory = Memory::default();
        }
        plan
    }

    /// Final target per robot: its pattern spot when free, else the nearest free
    /// spot in its wedge, with a note when the pure-geometry ideal was blocked.
    fn resolve_targets(
        &self,
        centre: &Point2<f64>,
        robots: &[RobotState],
        ideal: &TargetPattern,
        chosen: &TargetPattern,
        half: f64,
        period_s: f64,
    ) -> Vec<RobotCycle> {
        let cfg = &self.config;
        robots
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let p0 = r.base_xy();
                // Its step at its own speed.
                let step = cfg.step_of(&r.base, period_s);
                let bounds =
                    cycle::range_bounds((p0 - centre).norm(), cfg.min_range_m, cfg.max_range_m, step);
                let spot = chosen.spots[i];
                let target = if self.free.is_free(&spot) {
                    Some(spot)
                } else {
                    let ring = (cfg.min_range_m, cfg.max_range_m);
                    cycle::nearest_free_in_wedge(
                        &self.free,
                        centre,
                        &spot,
                        chosen.bearings_rad[i],
                        half,
                        ring,
                        None,
                    )
                };
                let note = match (self.free.blocked(&ideal.spots[i]), target) {
                    (Some(why), Some(t)) if (t - ideal.spots[i]).norm() > 0.05 => Some(format!(
                        "ideal spot ({:.2}, {:.2}) is blocked ({why}); heading for free spot ({:.2}, {:.2})",
                        ideal.spots[i].x, ideal.spots[i].y, t.x, t.y
                    )),
                    (_, None) => Some(format!(
                        "target spot ({:.2}, {:.2}) is blocked ({}) and its wedge has no free spot",
                        spot.x,
                        spot.y,
                        self.free.blocked(&spot).map_or("?".into(), |b| b.to_string())
                    )),
                    _ => None,
                };
                RobotCycle { p0, bounds, step, travel_scale: cfg.travel_scale(&r.base), target, note }
            })
            .collect()
    }

    /// Goals out of the keep-outs for the robots inside one whose active goal
    /// (if any) does not already leave them ([`escape`]).
    fn escapes(&self, input: &PlannerInput) -> Vec<Goal> {
        let keeps = self.keep_outs(input);
        let inside: Vec<usize> = (0..input.robots.len())
            .filter(|&i| {
                let r = &input.robots[i];
                let going_out = r.active_goal.is_some_and(|g| escape::clear_of(&keeps, &xy_of(&g), 0.0));
                !escape::clear_of(&keeps, &r.base_xy(), 0.0) && !going_out
            })
            .collect();
        self.escape_goals(input, &inside, &[])
    }

    /// The ordinary plan's `goals`, with those of robots inside a keep-out
    /// that would not take them out of it replaced by the way out, and those
    /// that would take a robot into another source's keep-out moved to the
    /// nearest spot clear of every keep-out.
    fn keep_out_first(&self, input: &PlannerInput, mut goals: Vec<Goal>) -> Vec<Goal> {
        let keeps = self.keep_outs(input);
        let inside: Vec<usize> = goals
            .iter()
            .filter(|g| {
                let r = &input.robots[g.robot];
                !escape::clear_of(&keeps, &r.base_xy(), 0.0)
                    && !escape::clear_of(&keeps, &xy_of(&g.map_from_base), 0.0)
            })
            .map(|g| g.robot)
            .collect();
        if !inside.is_empty() {
            let kept: Vec<Goal> = goals.iter().filter(|g| !inside.contains(&g.robot)).cloned().collect();
            let mut out = self.escape_goals(input, &inside, &kept);
            // A robot with no way out keeps the ordinary goal (no nearer the path).
            goals.retain(|g| out.iter().all(|e| e.robot != g.robot));
            out.extend(goals);
            out.sort_by_key(|g| g.robot);
            goals = out;
        }
        // Ordinary goals keep the served source's keep-out around its
        // estimate, often right at its edge: they are pushed out to the
        // clearance an escape is sent to (r_min plus the margin for the
        // estimate's error, [`escape::escape_clearance_m`]), so that an
        // estimate off by up to about 2σ_h does not put them inside the true
        // source's (see [`escape`]). As far as the cycle's hard constraints
        // allow: the step, the largest range, free space, the other
        // keep-outs and the separation from where the other robots are
        // going. A goal whose straight push would lie beyond the step is
        // drawn back towards the robot first ([`escape::push_out_within`]).
        // Where the full push is refused, the goal slides along the
        // keep-out to the nearest spot around it that has the full
        // clearance and keeps every constraint ([`escape::escape_spot`]
        // centred on the goal); failing that, it is pushed a quarter of the
        // margin less at a time. The step is the
        // configured one even while a walker shortens the cycle's
        // (`cadence`): the push is about the source's safety.
        let cfg = &self.config;
        let (served, full) = keeps[0];
        let margin = full - served.radius_m;
        // Where every robot ends, updated as goals are pushed: a push keeps
        // `min_separation_m` from the other robots' goals as already pushed.
        let mut dest = ends(&input.robots, &goals);
        for g in goals.iter_mut().filter(|g| g.reason != RepositionReason::KeepOut) {
            let q = xy_of(&g.map_from_base);
            let p0 = input.robots[g.robot].base_xy();
            let centre = Point2::new(g.look_at_in_map.x, g.look_at_in_map.y);
            let me = g.robot;
            // The robot's own step over the configured period.
            let step = cfg.step_of(&input.robots[me].base, cfg.planning_period_s);
            // Why a pushed spot is refused (`None`: it is allowed).
            let refusal = |out: &Point2<f64>| {
                if (out - p0).norm() > step {
                    Some("take it beyond the step".to_string())
                } else if (out - centre).norm() > cfg.max_range_m {
                    Some("take it beyond the largest range".to_string())
                } else if let Some(why) = self.free.blocked(out) {
                    Some(format!("put it where it is blocked ({why})"))
                } else if !escape::clear_of(&keeps[1..], out, 0.0) {
                    Some("put it inside another source's keep-out".to_string())
                } else {
                    dest.iter()
                        .enumerate()
                        .find(|&(j, e)| j != me && (out - e).norm() < cfg.min_separation_m)
                        .map(|(j, _)| {
                            format!(
                                "bring it within min_separation_m of {}'s destination",
                                input.robots[j].id
                            )
                        })
                }
            };
            // Straight out where that is within the step (any other straight
            // push is refused by the step), else drawn back first.
            let push = |clearance: f64| escape::push_out_within(&served, &q, clearance, &p0, step);
            let allowed = |out: &Point2<f64>| refusal(out).is_none();
            // Why the full straight push is refused (with no push within the
            // step, the step's refusal of the straight one).
            let full_refused =
                || push(full).or_else(|| escape::push_out(&served, &q, full)).and_then(|out| refusal(&out));
            let straight = push(full).filter(allowed);
            // Where the full straight push is refused, the nearest spot
            // around the goal that keeps every constraint, with every
            // keep-out's clearance (`escape_spot` asks for it): along the
            // keep-out's edge, away from what refused the push (another
            // robot's destination, a wall).
            let slid = if straight.is_none() && served.clearance(&q) < full - 1e-9 {
                let rest: Vec<Point2<f64>> =
                    dest.iter().enumerate().filter(|&(j, _)| j != me).map(|(_, e)| *e).collect();
                escape::escape_spot(&keeps, &self.free, &q, &rest, cfg.min_separation_m, |_| 0.0)
                    .filter(allowed)
            } else {
                None
            };
            let pushed = straight.or(slid).or_else(|| {
                (1..PUSH_TRIES)
                    .map(|k| served.radius_m + margin * (PUSH_TRIES - k) as f64 / PUSH_TRIES as f64)
                    .filter_map(push)
                    .find(allowed)
            });
            let reached = served.clearance(&pushed.unwrap_or(q));
            if let Some(out) = pushed {
                g.map_from_base = pose::facing_pose(&out, &g.look_at_in_map);
            }
            if let Some(spot) = slid {
                g.add_note(format!(
                    "moved {:.2} m along the source's keep-out{}",
                    (spot - q).norm(),
                    full_refused().map_or(String::new(), |w| format!(": straight out would {w}"))
                ));
            }
            // Short of the full margin: the command says why.
            if reached < full - 1e-6
                && let Some(why) = full_refused()
            {
                g.add_note(format!(
                    "{reached:.2} m from the source's path, {full:.2} m wanted: further out would {why}"
                ));
            }
            dest[me] = xy_of(&g.map_from_base);
        }
        // They keep the served source's keep-out by construction, not the
        // others'.
        let others = &keeps[1..];
        let mut dropped = Vec::new();
        for k in 0..goals.len() {
            let g = &goals[k];
            let q0 = xy_of(&g.map_from_base);
            if g.reason == RepositionReason::KeepOut || escape::clear_of(others, &q0, 0.0) {
                continue;
            }
            let mut rest = ends(&input.robots, &goals);
            rest.remove(g.robot);
            let spot = escape::escape_spot(&keeps, &self.free, &q0, &rest, cfg.min_separation_m, |_| 0.0);
            let g = &mut goals[k];
            match spot {
                Some(q) => {
                    g.map_from_base = pose::facing_pose(&q, &g.look_at_in_map);
                    g.add_note(format!(
                        "moved to ({:.2}, {:.2}), out of another source's keep-out",
                        q.x, q.y
                    ));
                }
                None => dropped.push(g.robot),
            }
        }
        goals.retain(|g| !dropped.contains(&g.robot));
        goals
    }

    /// The keep-outs this cycle: the served source's first, then the others',
    /// each around its path over `source_lead_s` (`cycle::KeepOut`), with the
    /// clearance a robot backing out is sent to ([`escape::escape_clearance_m`]).
    fn keep_outs(&self, input: &PlannerInput) -> Vec<(cycle::KeepOut, f64)> {
        let cfg = &self.config;
        std::iter::once(&input.source)
            .chain(&input.others)
            .map(|s| {
                let keep = escape::keep_out(s, cfg.source_lead_s, cfg.min_range_m);
                let want =
                    escape::escape_clearance_m(cfg.min_range_m, cfg.keep_out_margin_m, &s.covariance_m2);
                (keep, want)
            })
            .collect()
    }

    /// Goals out of the keep-outs for the robots `inside`; the others end at
    /// their goal in `planned`, else at their active goal, else where they are.
    fn escape_goals(&self, input: &PlannerInput, inside: &[usize], planned: &[Goal]) -> Vec<Goal> {
        if inside.is_empty() {
            return Vec::new();
        }
        let cfg = &self.config;
        let s = &input.source;
        let robots = &input.robots;
        let keeps = self.keep_outs(input);
        let ahead = s.predicted(cfg.source_lead_s);
        let later = s.predicted(2.0 * cfg.source_lead_s);
        let mut destination = ends(robots, planned);
        let mut spots = Vec::new();
        for &i in inside {
            let others: Vec<Point2<f64>> =
                destination.iter().enumerate().filter(|&(j, _)| j != i).map(|(_, p)| *p).collect();
            let p0 = robots[i].base_xy();
            // θ where the source is predicted a lead ahead and one lead later:
            // a walker that keeps walking must not leave a formation that was
            // just inside the band (a robot backs out because the source is
            // coming at it, so the next lead matters too).
            let outside_band_deg = |q: &Point2<f64>| {
                let mut at = destination.clone();
                at[i] = *q;
                [ahead, later]
                    .iter()
                    .map(|src| self.degrees_out_of_band(src, robots, &at))
                    .fold(0.0, f64::max)
            };
            let sep = cfg.min_separation_m;
            if let Some(q) = escape::escape_spot(&keeps, &self.free, &p0, &others, sep, outside_band_deg) {
                destination[i] = q;
                // The keep-out it was deepest in.
                let (k, from) = keeps
                    .iter()
                    .enumerate()
                    .map(|(k, (keep, _))| (k, keep.clearance(&p0)))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .unwrap_or((0, 0.0));
                spots.push((i, q, k, from));
            }
        }
        let sensors: Vec<Sensor> = robots
            .iter()
            .zip(&destination)
            .map(|(r, d)| sensor_at(d, &ahead, &r.base_from_array, r.sigma_rad))
            .collect();
        let predicted = assess(&sensors, &ahead);
        spots
            .into_iter()
            .map(|(i, q, k, from)| Goal {
                robot: i,
                robot_id: robots[i].id.clone(),
                map_from_base: pose::facing_pose(&q, &ahead),
                look_at_in_map: ahead,
                target_in_map: q,
                predicted_theta_deg: predicted.theta_deg,
                predicted_gdop: predicted.gdop,
                predicted_rms_m: predicted.rms_m,
                reason: RepositionReason::KeepOut,
                used_fallback: false,
                note: Some(format!(
                    "{from:.2} m from {} path (keep-out {:.2} m): backing out to {:.2} m",
                    if k == 0 { "the source's" } else { "another source's" },
                    cfg.min_range_m,
                    keeps[k].1
                )),
            })
            .collect()
    }

    /// Whether every active goal keeps range, free space and separation for the source at `centre`.
    fn active_goals_valid(&self, centre: &Point2<f64>, robots: &[RobotState]) -> bool {
        let cfg = &self.config;
        let tol = 0.05;
        let spot = RobotState::destination_xy;
        let each = robots.iter().filter(|r| r.active_goal.is_some()).all(|r| {
            let g = spot(r);
            let rho = (g - centre).norm();
            rho >= cfg.min_range_m - tol && rho <= cfg.max_range_m + tol && self.free.is_free(&g)
        });
        let pairs = (0..robots.len()).all(|i| {
            ((i + 1)..robots.len()).all(|j| {
                (robots[i].active_goal.is_none() && robots[j].active_goal.is_none())
                    || (spot(&robots[i]) - spot(&robots[j])).norm() >= cfg.min_separation_m - tol
            })
        });
        each && pairs
    }
}

/// The xy position of a pose (m).
fn xy_of(p: &nalgebra::Isometry3<f64>) -> Point2<f64> {
    Point2::new(p.translation.vector.x, p.translation.vector.y)
}

/// Where each robot ends up (map xy, m): its goal in `goals`, else its
/// [`RobotState::destination_xy`].
fn ends(robots: &[RobotState], goals: &[Goal]) -> Vec<Point2<f64>> {
    let mut ends: Vec<Point2<f64>> = robots.iter().map(RobotState::destination_xy).collect();
    for g in goals {
        ends[g.robot] = xy_of(&g.map_from_base);
    }
    ends
}

/// Why the input cannot be planned for, if it cannot.
fn check_input(cfg: &PlannerConfig, input: &PlannerInput) -> Option<HoldReason> {
    let invalid = |detail: String| Some(HoldReason::InvalidInput { detail });
    if input.robots.len() < 2 {
        return Some(HoldReason::TooFewRobots { count: input.robots.len() });
    }
    let s = &input.source;
    let finite = |s: &SourceEstimate| {
        s.position_in_map.coords.iter().all(|v| v.is_finite())
            && s.covariance_m2.iter().all(|v| v.is_finite())
            && s.velocity_in_map.is_none_or(|v| v.iter().all(|x| x.is_finite()))
    };
    if !finite(s) {
        return invalid("source estimate has a non-finite number".into());
    }
    if let Some(k) = input.others.iter().position(|o| !finite(o)) {
        return invalid(format!("other source {k} has a non-finite number"));
    }
    for (i, r) in input.robots.iter().enumerate() {
        if !r.is_valid() {
            return invalid(format!("robot {i} ({}) has a non-finite pose or a σ ≤ 0", r.id));
        }
        if input.robots[..i].iter().any(|o| o.id == r.id) {
            return invalid(format!("robot id {} appears twice", r.id));
        }
    }
    let rms_m = s.rms_m();
    if !(rms_m <= cfg.max_source_rms_m) {
        return Some(HoldReason::SourceUntrusted { rms_m, max_m: cfg.max_source_rms_m });
    }
    None
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Point3};
    use soundmap_proto::RobotId;

    use super::*;

    fn robot(k: usize, x: f64, y: f64, goal: Option<(f64, f64)>) -> RobotState {
        RobotState {
            id: RobotId::parse(&format!("r{k}"), "id").unwrap(),
            map_from_base: Isometry3::translation(x, y, 0.0),
            base_from_array: Isometry3::translation(0.0, 0.0, 0.5),
            sigma_rad: 3f64.to_radians(),
            active_goal: goal.map(|(gx, gy)| Isometry3::translation(gx, gy, 0.0)),
            base: Default::default(),
        }
    }

    fn goal_at(robot: &RobotState, index: usize, x: f64, y: f64, source: Point3<f64>) -> Goal {
        Goal {
            robot: index,
            robot_id: robot.id.clone(),
            map_from_base: pose::facing_pose(&Point2::new(x, y), &source),
            look_at_in_map: source,
            target_in_map: Point2::new(x, y),
            predicted_theta_deg: 90.0,
            predicted_gdop: 1.5,
            predicted_rms_m: 0.1,
            reason: RepositionReason::Improvement,
            used_fallback: false,
            note: None,
        }
    }

    /// The keep-out also covers the way from a lagging track to the newest
    /// fix of the rays: a goal 1.3 m from the track but 0.8 m from the fix
    /// is pushed out to 1.3 m from the fix, and a robot 1.2 m from the track
    /// but 0.7 m from the fix backs out (it would not without the fix).
    #[test]
    fn the_keep_out_covers_the_fix_of_a_lagging_track() {
        let planner = Planner::new(PlannerConfig::default()).unwrap();
        let track = Point3::new(0.0, 0.0, 1.2);
        let fix = Point3::new(0.5, 0.0, 1.2);
        let lagging = SourceEstimate { fix_in_map: Some(fix), ..SourceEstimate::at(track, 0.1) };
        let input = PlannerInput {
            source: lagging.clone(),
            robots: vec![robot(0, 1.8, 0.0, None), robot(1, -1.5, 1.5, None)],
            others: vec![],
        };
        let goals = planner.keep_out_first(&input, vec![goal_at(&input.robots[0], 0, 1.3, 0.0, track)]);
        let q = xy_of(&goals[0].map_from_base);
        assert!((q - Point2::new(1.8, 0.0)).norm() < 1e-9, "{q}");
        let without = PlannerInput { source: SourceEstimate::at(track, 0.1), ..input.clone() };
        let goals = planner.keep_out_first(&without, vec![goal_at(&without.robots[0], 0, 1.3, 0.0, track)]);
        assert!((xy_of(&goals[0].map_from_base) - Point2::new(1.3, 0.0)).norm() < 1e-9);

        let near =
            PlannerInput { robots: vec![robot(0, 1.2, 0.0, None), robot(1, -1.5, 1.5, None)], ..input };
        let out = planner.escapes(&near);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].reason, RepositionReason::KeepOut);
        assert!((xy_of(&out[0].map_from_base) - Point2::new(0.5, 0.0)).norm() >= 1.3 - 1e-9);
        assert!(planner.escapes(&PlannerInput { source: SourceEstimate::at(track, 0.1), ..near }).is_empty());
    }

    /// An ordinary goal at the keep-out's edge is pushed out to the escape's
    /// clearance (1 m + max(0.3 m, 2σ_h) = 1.3 m for σ 0.1 m). Where the
    /// straight push would come within `min_separation_m` of another robot's
    /// destination it slides along the keep-out to the nearest spot that has
    /// the clearance and the separation; hemmed in on both sides it stays,
    /// and its note says how far out it is and why.
    #[test]
    fn a_goal_short_of_the_margin_says_why() {
        let planner = Planner::new(PlannerConfig::default()).unwrap();
        let cfg = PlannerConfig::default();
        let source = Point3::new(0.0, 0.0, 1.2);
        let free = PlannerInput {
            source: SourceEstimate::at(source, 0.1),
            robots: vec![robot(0, 1.05, 0.0, None), robot(1, -1.5, 1.5, None)],
            others: vec![],
        };
        let goals = planner.keep_out_first(&free, vec![goal_at(&free.robots[0], 0, 1.05, 0.0, source)]);
        assert!((xy_of(&goals[0].map_from_base) - Point2::new(1.3, 0.0)).norm() < 1e-9);
        assert_eq!(goals[0].note, None);

        // r1 is driving to (1.5, 0.5): 0.54 m from the straight push's spot
        // (1.3, 0), so the goal slides round, away from r1's destination.
        let crowded = PlannerInput {
            robots: vec![robot(0, 1.05, 0.0, None), robot(1, -1.5, 1.5, Some((1.5, 0.5)))],
            ..free.clone()
        };
        let goals = planner.keep_out_first(&crowded, vec![goal_at(&crowded.robots[0], 0, 1.05, 0.0, source)]);
        let slid = xy_of(&goals[0].map_from_base);
        assert!(slid.coords.norm() >= 1.3 - 1e-9, "{slid}");
        assert!((slid - Point2::new(1.5, 0.5)).norm() >= cfg.min_separation_m, "{slid}");
        assert!((slid - Point2::new(1.05, 0.0)).norm() <= cfg.step_m(), "{slid}");
        assert!(slid.y < 0.0, "away from r1's destination: {slid}");
        let note = goals[0].note.as_deref().unwrap();
        assert!(
            note.starts_with("moved ")
                && note.ends_with(
                    "along the source's keep-out: straight out would bring it within \
                     min_separation_m of r1's destination"
                ),
            "{note}"
        );

        // r2 is driving to (1.5, −0.5): every spot 1.3 m out within the step
        // is within 0.8 m of r1's or r2's destination, and the goal stays.
        let hemmed = PlannerInput {
            robots: vec![
                robot(0, 1.05, 0.0, None),
                robot(1, -1.5, 1.5, Some((1.5, 0.5))),
                robot(2, -1.5, -1.5, Some((1.5, -0.5))),
            ],
            ..free
        };
        let goals = planner.keep_out_first(&hemmed, vec![goal_at(&hemmed.robots[0], 0, 1.05, 0.0, source)]);
        assert!((xy_of(&goals[0].map_from_base) - Point2::new(1.05, 0.0)).norm() < 1e-9);
        assert_eq!(
            goals[0].note.as_deref(),
            Some(
                "1.05 m from the source's path, 1.30 m wanted: further out would bring it within \
                 min_separation_m of r1's destination"
            )
        );
    }
}

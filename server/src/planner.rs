//! Active positioning: where the robots should go so that the angle θ at the
//! source between them stays in band (default 40°–140°, ideally 90°) and the
//! GDOP stays low (theory §2.4 and §3).
//!
//! Pure: [`Planner::plan`] takes `now` and a [`PlannerInput`] and returns a
//! [`PlanOutcome`]; the planner keeps only its hysteresis memory.
//!
//! One cycle:
//! 1. checks the input (≥ 2 robots, finite numbers, a trusted source) and the
//!    planning period; predicts the source `source_lead_s` ahead;
//! 2. [`bearings`]: the target pattern from the Fisher information, matched to
//!    the robots with the least travel (and sticky across cycles); blocked
//!    ideal spots are replaced by the nearest free spot in their wedge;
//! 3. `hysteresis`: re-plan only on θ out of band, GDOP high, a worthwhile
//!    predicted improvement, or goals made invalid / left behind by the source;
//! 4. `cycle` + `qp`: this cycle's waypoints from a Clarabel QP/SOCP
//!    (wedges, keep-out chord, range and step cones, convex free region,
//!    linearised separation), else the `sampling` search;
//! 5. every waypoint is checked against the hard constraints (step, range,
//!    free space with clearance, separation) before it becomes a [`Goal`].
//!
//! Submodules: [`config`], [`free_space`], [`bearings`], [`assignment`],
//! [`pose`], `cycle`, `qp`, `sampling`, `hysteresis`, and the input/outcome types.

pub mod assignment;
pub mod bearings;
pub mod config;
mod cycle;
pub mod free_space;
mod hysteresis;
mod input;
mod outcome;
pub mod pose;
mod qp;
mod sampling;

use nalgebra::{Point2, Point3};
use soundmap_proto::Stamp;

pub use config::{ConfigError, PlannerConfig, SamplingConfig};
pub use free_space::{Blocked, FreeSpace, FreeSpaceConfig, HalfPlane};
pub use input::{PlannerInput, RobotState, SourceEstimate};
pub use outcome::{Goal, HoldReason, InfeasibleReason, PlanOutcome};
pub use soundmap_proto::RepositionReason;

use bearings::{PatternRobot, PatternSettings, TargetPattern, choose_pattern};
use cycle::{CycleRobot, Separation};
use hysteresis::{Decision, Memory, Situation, decide};
use pose::{facing_pose, sensor_at};
use qp::QpOutcome;
use sampling::{SampleOutcome, SampleRobot};

use crate::uncertainty::{GeometryQuality, Sensor, assess};

/// Tolerance of the checks applied to waypoints (m).
const CHECK_TOL_M: f64 = 1e-6;

/// This cycle's checked waypoints.
struct Waypoints {
    /// Per robot (map xy, m).
    spots: Vec<Point2<f64>>,
    /// The separations they were checked against.
    separations: Vec<Separation>,
    used_fallback: bool,
    why_fallback: Option<String>,
}

/// The placement planner: configuration, free space and hysteresis memory.
#[derive(Clone, Debug)]
pub struct Planner {
    config: PlannerConfig,
    free: FreeSpace,
    memory: Memory,
}

/// Per-robot facts of one cycle.
struct RobotCycle {
    p0: Point2<f64>,
    bounds: (f64, f64),
    /// Final target spot (free), if one was found in the robot's wedge.
    target: Option<Point2<f64>>,
    note: Option<String>,
}

impl Planner {
    /// A planner with a validated configuration.
    pub fn new(config: PlannerConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        let free = FreeSpace::new(&config.free_space, config.wall_clearance_m());
        Ok(Planner { config, free, memory: Memory::default() })
    }

    /// The configuration.
    pub fn config(&self) -> &PlannerConfig {
        &self.config
    }

    /// The free space (with the robots' clearance).
    pub fn free_space(&self) -> &FreeSpace {
        &self.free
    }

    /// Forgets the previous plans (hysteresis state, sticky pattern, rate limit).
    pub fn reset(&mut self) {
        self.memory = Memory::default();
    }

    /// One planning cycle at `now`.
    pub fn plan(&mut self, now: Stamp, input: &PlannerInput) -> PlanOutcome {
        if let Some(h) = check_input(&self.config, input) {
            return PlanOutcome::Hold(h);
        }
        if let Some(wait_s) = self.memory.wait_s(now, self.config.planning_period_s) {
            return PlanOutcome::Hold(HoldReason::NotDue { wait_s });
        }
        let cfg = &self.config;
        let s = &input.source;
        let src = s.position_in_map + s.velocity_in_map.unwrap_or_default() * cfg.source_lead_s;
        let centre = Point2::new(src.x, src.y);
        let robots = &input.robots;
        let step = cfg.step_m();

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
            })
            .collect();
        let settings = PatternSettings {
            range_m: cfg.preferred_range_m,
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
        let per_robot = self.resolve_targets(&centre, robots, &ideal, &chosen, half, step);

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
        let situation = Situation {
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
        let cycle = match self.waypoints(&src, robots, &per_robot, half, step) {
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
        self.memory.last_plan_at = Some(now);
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

    /// Final target per robot: its pattern spot when free, else the nearest free
    /// spot in its wedge, with a note when the pure-geometry ideal was blocked.
    fn resolve_targets(
        &self,
        centre: &Point2<f64>,
        robots: &[RobotState],
        ideal: &TargetPattern,
        chosen: &TargetPattern,
        half: f64,
        step: f64,
    ) -> Vec<RobotCycle> {
        let cfg = &self.config;
        robots
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let p0 = r.base_xy();
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
                RobotCycle { p0, bounds, target, note }
            })
            .collect()
    }

    /// Whether every active goal keeps range, free space and separation for the source at `centre`.
    fn active_goals_valid(&self, centre: &Point2<f64>, robots: &[RobotState]) -> bool {
        let cfg = &self.config;
        let tol = 0.05;
        let spot = |r: &RobotState| {
            r.active_goal.map_or(r.base_xy(), |g| Point2::new(g.translation.vector.x, g.translation.vector.y))
        };
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

    /// Waypoints from the convex problem, else the sampling search; checked.
    /// Returns them with `used_fallback` and a remark on why the fallback ran.
    fn waypoints(
        &self,
        src: &Point3<f64>,
        robots: &[RobotState],
        per_robot: &[RobotCycle],
        half: f64,
        step: f64,
    ) -> Result<Waypoints, InfeasibleReason> {
        let cfg = &self.config;
        let centre = Point2::new(src.x, src.y);
        let p0: Vec<Point2<f64>> = per_robot.iter().map(|c| c.p0).collect();
        let mut cycle_robots: Vec<CycleRobot> = Vec::with_capacity(robots.len());
        let mut why_not_qp: Option<String> = None;
        for (i, c) in per_robot.iter().enumerate() {
            let Some(t) = c.target else {
                why_not_qp = Some(format!("robot {i} has no free target spot"));
                break;
            };
            let d = t - centre;
            let (mut via, psi) = cycle::via_point(&centre, &c.p0, d.y.atan2(d.x), d.norm(), c.bounds, step);
            if !self.free.is_free(&via) {
                let reach = Some((&c.p0, 0.9 * step));
                match cycle::nearest_free_in_wedge(&self.free, &centre, &via, psi, half, c.bounds, reach) {
                    Some(q) => via = q,
                    None => {
                        why_not_qp = Some(format!("robot {i}: no free spot on its way within one step"));
                        break;
                    }
                }
            }
            let Some(region) = self.free.convex_region(&via) else {
                why_not_qp = Some(format!("robot {i}: heading point not free"));
                break;
            };
            cycle_robots.push(CycleRobot {
                p0: c.p0,
                target: via,
                wedge_center_rad: psi,
                wedge_half_rad: half,
                range_lo: c.bounds.0,
                range_hi: c.bounds.1,
                step,
                region,
            });
        }
        let heading: Vec<Point2<f64>> = if cycle_robots.len() == robots.len() {
            cycle_robots.iter().map(|c| c.target).collect()
        } else {
            p0.clone()
        };
        let seps = cycle::separations(&p0, &heading, cfg.min_separation_m, step);
        if why_not_qp.is_none() {
            match qp::solve(&centre, &cycle_robots, &seps, cfg.goal_weight) {
                QpOutcome::Solved(w) if self.check(&centre, per_robot, &w, &seps, step) => {
                    return Ok(Waypoints {
                        spots: w,
                        separations: seps,
                        used_fallback: false,
                        why_fallback: None,
                    });
                }
                QpOutcome::Solved(_) => {
                    why_not_qp = Some("convex solution failed the constraint check".into())
                }
                QpOutcome::Infeasible(st) => why_not_qp = Some(format!("convex problem infeasible ({st:?})")),
                QpOutcome::Failed(m) => why_not_qp = Some(format!("convex problem failed: {m}")),
            }
        }
        let sample_robots: Vec<SampleRobot> = robots
            .iter()
            .zip(per_robot)
            .enumerate()
            .map(|(i, (r, c))| SampleRobot {
                p0: c.p0,
                base_from_array: r.base_from_array,
                sigma_rad: r.sigma_rad,
                range: c.bounds,
                step,
                heading: cycle_robots.get(i).map(|cr| cr.target),
            })
            .collect();
        let band = (cfg.theta_min_deg, cfg.theta_max_deg);
        let why = why_not_qp.unwrap_or_default();
        match sampling::search(src, &sample_robots, &seps, &self.free, band, &cfg.sampling) {
            SampleOutcome::Found(w) if self.check(&centre, per_robot, &w, &seps, step) => {
                Ok(Waypoints { spots: w, separations: seps, used_fallback: true, why_fallback: Some(why) })
            }
            SampleOutcome::Found(_) => Err(InfeasibleReason::NoJointPlacement {
                detail: format!("{why}; sampled placement failed the constraint check"),
            }),
            SampleOutcome::NoCandidates(i, detail) => {
                if !self.ring_has_free_spot(&centre) {
                    return Err(InfeasibleReason::NoFreeSpotAroundSource {
                        source_xy: [centre.x, centre.y],
                        ring_m: [cfg.min_range_m, cfg.max_range_m],
                    });
                }
                Err(InfeasibleReason::RobotStuck { robot: i, robot_id: robots[i].id.clone(), detail })
            }
            SampleOutcome::NoJoint => Err(InfeasibleReason::NoJointPlacement {
                detail: format!(
                    "{why}; sampling found no spots keeping {:.2} m separation",
                    cfg.min_separation_m
                ),
            }),
        }
    }

    /// The hard constraints: step, range bounds, free space, separations.
    fn check(
        &self,
        centre: &Point2<f64>,
        per_robot: &[RobotCycle],
        w: &[Point2<f64>],
        seps: &[Separation],
        step: f64,
    ) -> bool {
        w.len() == per_robot.len()
            && w.iter().zip(per_robot).all(|(q, c)| {
                let rho = (q - centre).norm();
                q.x.is_finite()
                    && q.y.is_finite()
                    && (q - c.p0).norm() <= step + CHECK_TOL_M
                    && rho >= c.bounds.0 - CHECK_TOL_M
                    && rho <= c.bounds.1 + CHECK_TOL_M
                    && self.free.is_free(q)
            })
            && seps.iter().all(|s| (w[s.i] - w[s.j]).norm() >= s.min_m - CHECK_TOL_M)
    }

    /// Whether any spot of the polar grid in [r_min, r_max] around `centre` is free.
    fn ring_has_free_spot(&self, centre: &Point2<f64>) -> bool {
        let cfg = &self.config;
        let n_r = ((cfg.max_range_m - cfg.min_range_m) / cfg.sampling.range_step_m).ceil().max(1.0) as usize;
        (0..360).step_by(2).any(|a| {
            (0..=n_r).any(|k| {
                let rho = cfg.min_range_m + (cfg.max_range_m - cfg.min_range_m) * k as f64 / n_r as f64;
                self.free.is_free(&cycle::polar(centre, (a as f64).to_radians(), rho))
            })
        })
    }

    /// Goals for robots that must move (or whose old goal must be replaced).
    fn goals(
        &self,
        src: &Point3<f64>,
        robots: &[RobotState],
        per_robot: &[RobotCycle],
        cycle: &Waypoints,
        predicted: &GeometryQuality,
        reason: RepositionReason,
    ) -> Vec<Goal> {
        let (waypoints, seps) = (&cycle.spots, &cycle.separations);
        let tol = self.config.goal_tolerance_m;
        // Where each robot ends up without a new goal: its active goal, else where it is.
        let destination: Vec<Point2<f64>> = robots
            .iter()
            .zip(per_robot)
            .map(|(r, c)| {
                r.active_goal.map_or(c.p0, |g| Point2::new(g.translation.vector.x, g.translation.vector.y))
            })
            .collect();
        // A goal is sent when the waypoint differs from that destination ...
        let mut send: Vec<bool> =
            (0..robots.len()).map(|i| (waypoints[i] - destination[i]).norm() > tol).collect();
        // ... or when a robot left alone would be too close to another's goal.
        loop {
            let at = |k: usize, send: &[bool]| if send[k] { waypoints[k] } else { destination[k] };
            let short = seps.iter().find(|s| {
                !(send[s.i] && send[s.j]) && (at(s.i, &send) - at(s.j, &send)).norm() < s.min_m - CHECK_TOL_M
            });
            match short {
                Some(s) => {
                    send[s.i] = true;
                    send[s.j] = true;
                }
                None => break,
            }
        }
        let mut goals = Vec::new();
        for (i, r) in robots.iter().enumerate() {
            let w = waypoints[i];
            if !send[i] {
                continue;
            }
            let mut notes: Vec<String> = per_robot[i].note.iter().cloned().collect();
            if cycle.used_fallback {
                notes.push(format!("sampling fallback: {}", cycle.why_fallback.as_deref().unwrap_or("")));
            }
            goals.push(Goal {
                robot: i,
                robot_id: r.id.clone(),
                map_from_base: facing_pose(&w, src),
                look_at_in_map: *src,
                target_in_map: per_robot[i].target.unwrap_or(w),
                predicted_theta_deg: predicted.theta_deg,
                predicted_gdop: predicted.gdop,
                predicted_rms_m: predicted.rms_m,
                reason,
                used_fallback: cycle.used_fallback,
                note: (!notes.is_empty()).then(|| notes.join("; ")),
            });
        }
        goals
    }
}

/// Why the input cannot be planned for, if it cannot.
fn check_input(cfg: &PlannerConfig, input: &PlannerInput) -> Option<HoldReason> {
    let invalid = |detail: String| Some(HoldReason::InvalidInput { detail });
    if input.robots.len() < 2 {
        return Some(HoldReason::TooFewRobots { count: input.robots.len() });
    }
    let s = &input.source;
    if !(s.position_in_map.coords.iter().all(|v| v.is_finite())
        && s.covariance_m2.iter().all(|v| v.is_finite())
        && s.velocity_in_map.is_none_or(|v| v.iter().all(|x| x.is_finite())))
    {
        return invalid("source estimate has a non-finite number".into());
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

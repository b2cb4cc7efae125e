//! This cycle's waypoints: the convex problem, else the sampling search (also
//! consulted when the convex step would leave θ out of the band), each result
//! checked against the hard constraints (step, range bounds, free space with
//! clearance, separations); and the goals built from them.

use nalgebra::{Point2, Point3};
use soundmap_proto::RepositionReason;

use super::cycle::{self, CycleRobot, KeepOut, Separation};
use super::outcome::{Goal, InfeasibleReason};
use super::pose::{facing_pose, sensor_at};
use super::qp::{self, QpOutcome};
use super::sampling::{self, SampleOutcome, SampleRobot};
use super::{Planner, RobotCycle, RobotState};
use crate::uncertainty::{GeometryQuality, assess};

/// Tolerance of the checks applied to waypoints (m).
const CHECK_TOL_M: f64 = 1e-6;

/// This cycle's checked waypoints.
pub(super) struct Waypoints {
    /// Per robot (map xy, m).
    pub spots: Vec<Point2<f64>>,
    /// The separations they were checked against.
    pub separations: Vec<Separation>,
    /// The sampling search produced them.
    pub used_fallback: bool,
    /// Why the convex problem was not used, when it was not.
    pub why_fallback: Option<String>,
}

impl Planner {
    /// Waypoints from the convex problem, else the sampling search; checked.
    pub(super) fn waypoints(
        &self,
        src: &Point3<f64>,
        keep: &KeepOut,
        robots: &[RobotState],
        per_robot: &[RobotCycle],
        half: f64,
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
            let (mut via, psi) = cycle::via_point(&centre, &c.p0, d.y.atan2(d.x), d.norm(), c.bounds, c.step);
            if !self.free.is_free(&via) {
                let reach = Some((&c.p0, 0.9 * c.step));
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
                step: c.step,
                region,
            });
        }
        let heading: Vec<Point2<f64>> = if cycle_robots.len() == robots.len() {
            cycle_robots.iter().map(|c| c.target).collect()
        } else {
            p0.clone()
        };
        let steps: Vec<f64> = per_robot.iter().map(|c| c.step).collect();
        let seps = cycle::separations(&p0, &heading, cfg.min_separation_m, &steps);
        if why_not_qp.is_none() {
            match qp::solve(&centre, &cycle_robots, &seps, cfg.goal_weight) {
                QpOutcome::Solved(w) if self.check(&centre, keep, per_robot, &w, &seps) => {
                    // The way to the target pattern can pass through a poor
                    // geometry (a robot swinging round a source that walked
                    // close to it). Then the sampling search, which scores this
                    // cycle's geometry, decides when it keeps θ nearer the band.
                    let outside = self.degrees_out_of_band(src, robots, &w);
                    if outside > 0.0 {
                        let sample_robots = sample_robots(robots, per_robot, &cycle_robots);
                        let band = (cfg.theta_min_deg, cfg.theta_max_deg);
                        if let SampleOutcome::Found(v) = sampling::search(
                            src,
                            &sample_robots,
                            &seps,
                            &self.free,
                            band,
                            keep,
                            &cfg.sampling,
                        ) && self.check(&centre, keep, per_robot, &v, &seps)
                            && self.degrees_out_of_band(src, robots, &v) < outside
                        {
                            return Ok(Waypoints {
                                spots: v,
                                separations: seps,
                                used_fallback: true,
                                why_fallback: Some(format!(
                                    "the convex waypoints would leave θ {outside:.0}° out of band"
                                )),
                            });
                        }
                    }
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
        let sample_robots = sample_robots(robots, per_robot, &cycle_robots);
        let band = (cfg.theta_min_deg, cfg.theta_max_deg);
        let why = why_not_qp.unwrap_or_default();
        match sampling::search(src, &sample_robots, &seps, &self.free, band, keep, &cfg.sampling) {
            SampleOutcome::Found(w) if self.check(&centre, keep, per_robot, &w, &seps) => {
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

    /// Degrees by which the best pairwise θ at `spots` lies outside the band (0 inside).
    pub(super) fn degrees_out_of_band(
        &self,
        src: &Point3<f64>,
        robots: &[RobotState],
        spots: &[Point2<f64>],
    ) -> f64 {
        let sensors: Vec<_> = robots
            .iter()
            .zip(spots)
            .map(|(r, q)| sensor_at(q, src, &r.base_from_array, r.sigma_rad))
            .collect();
        let theta = assess(&sensors, src).theta_deg;
        if !theta.is_finite() {
            return f64::INFINITY;
        }
        (self.config.theta_min_deg - theta).max(theta - self.config.theta_max_deg).max(0.0)
    }

    /// The hard constraints: step, range bounds, free space, the keep-out
    /// along the source's predicted path, separations.
    fn check(
        &self,
        centre: &Point2<f64>,
        keep: &KeepOut,
        per_robot: &[RobotCycle],
        w: &[Point2<f64>],
        seps: &[Separation],
    ) -> bool {
        w.len() == per_robot.len()
            && w.iter().zip(per_robot).all(|(q, c)| {
                let rho = (q - centre).norm();
                q.x.is_finite()
                    && q.y.is_finite()
                    && (q - c.p0).norm() <= c.step + CHECK_TOL_M
                    && rho >= c.bounds.0 - CHECK_TOL_M
                    && rho <= c.bounds.1 + CHECK_TOL_M
                    && self.free.is_free(q)
                    && keep.allows(&c.p0, q)
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
    pub(super) fn goals(
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

/// The robots' part of the sampling search this cycle.
fn sample_robots(
    robots: &[RobotState],
    per_robot: &[RobotCycle],
    cycle_robots: &[CycleRobot],
) -> Vec<SampleRobot> {
    robots
        .iter()
        .zip(per_robot)
        .enumerate()
        .map(|(i, (r, c))| SampleRobot {
            p0: c.p0,
            base_from_array: r.base_from_array,
            sigma_rad: r.sigma_rad,
            range: c.bounds,
            step: c.step,
            travel_scale: c.travel_scale,
            heading: cycle_robots.get(i).map(|cr| cr.target),
        })
        .collect()
}

//! Sampling fallback (theory §3.5), used when the convex problem is
//! infeasible or fails.
//!
//! Candidates per robot: a polar grid around the source (bearing and range
//! steps from [`SamplingConfig`]), a square grid of step/6 (0.05–0.25 m) over
//! the robot's step disc, its own position and this cycle's heading point,
//! kept when free, within one step and inside the cycle's range bounds. A tuple of spots is scored by
//!
//! ```text
//! ln tr J⁻¹  +  w_travel Σ‖qᵢ − pᵢ⁰‖  +  w_band · (degrees the best pairwise θ lies outside the band)
//! ```
//!
//! with J the 3D Fisher information of the arrays at the spots (facing the
//! source). Separations are hard: a tuple that violates one is rejected.
//! Two robots: exhaustive over all pairs (up to a cap); more: Gauss–Seidel,
//! one robot at a time with the others held (Zhou & Roumeliotis, [13]).

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Vector3};

use super::config::SamplingConfig;
use super::cycle::{KeepOut, Separation, polar};
use super::free_space::FreeSpace;
use super::pose::sensor_at;
use crate::uncertainty::fisher_information;

/// One robot's part of the search.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SampleRobot {
    /// Current base position (m, map xy).
    pub p0: Point2<f64>,
    /// Array on the base.
    pub base_from_array: Isometry3<f64>,
    /// Angular σ (rad).
    pub sigma_rad: f64,
    /// Range bounds this cycle (m).
    pub range: (f64, f64),
    /// Largest move (m).
    pub step: f64,
    /// Its travel's cost per metre relative to a robot at the reference
    /// speed (see [`super::bearings::PatternRobot::travel_scale`]).
    pub travel_scale: f64,
    /// This cycle's heading point, offered as a candidate.
    pub heading: Option<Point2<f64>>,
}

/// What the search found.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum SampleOutcome {
    /// Spots per robot.
    Found(Vec<Point2<f64>>),
    /// Robot `.0` has no candidate spot at all.
    NoCandidates(usize, String),
    /// Candidates exist but no tuple keeps every separation.
    NoJoint,
}

/// Separation shortfall still counted as kept (m), for rounding.
const SEPARATION_TOL_M: f64 = 1e-9;

struct Candidate {
    spot: Point2<f64>,
    fisher: Matrix3<f64>,
    /// Unit vector from the source to the array.
    dir: Vector3<f64>,
    travel: f64,
}

/// Runs the search around `source`.
pub(crate) fn search(
    source: &Point3<f64>,
    robots: &[SampleRobot],
    separations: &[Separation],
    free: &FreeSpace,
    band_deg: (f64, f64),
    keep: &KeepOut,
    cfg: &SamplingConfig,
) -> SampleOutcome {
    let centre = Point2::new(source.x, source.y);
    let mut cands: Vec<Vec<Candidate>> = Vec::with_capacity(robots.len());
    for (i, r) in robots.iter().enumerate() {
        let c = candidates(source, &centre, r, free, keep, cfg);
        if c.is_empty() {
            return SampleOutcome::NoCandidates(
                i,
                format!(
                    "no free spot within its {:.2} m step at {:.2}–{:.2} m from the source",
                    r.step, r.range.0, r.range.1
                ),
            );
        }
        cands.push(c);
    }
    let scorer = Scorer { cands: &cands, separations, band_deg, cfg };
    let picks = if robots.len() == 2 && cands[0].len() * cands[1].len() <= cfg.max_exhaustive_pairs {
        scorer.exhaustive_pair()
    } else {
        scorer.gauss_seidel(robots)
    };
    match picks {
        Some(p) if scorer.separation_violation(&p) <= SEPARATION_TOL_M => {
            SampleOutcome::Found(p.iter().enumerate().map(|(i, &k)| cands[i][k].spot).collect())
        }
        _ => SampleOutcome::NoJoint,
    }
}

fn candidates(
    source: &Point3<f64>,
    centre: &Point2<f64>,
    r: &SampleRobot,
    free: &FreeSpace,
    keep: &KeepOut,
    cfg: &SamplingConfig,
) -> Vec<Candidate> {
    let (lo, hi) = r.range;
    let reach = r.step - 1e-9;
    let n_b = (360.0 / cfg.bearing_step_deg).round().max(1.0) as usize;
    let n_r = ((hi - lo) / cfg.range_step_m).ceil().max(1.0) as usize;
    let mut spots: Vec<Point2<f64>> = Vec::new();
    for a in 0..n_b {
        let phi = (a as f64 * 360.0 / n_b as f64).to_radians();
        for k in 0..=n_r {
            spots.push(polar(centre, phi, lo + (hi - lo) * k as f64 / n_r as f64));
        }
    }
    // A finer square grid over the step disc, so that a robot in a tight spot
    // still has nearby choices (the polar grid is coarse far from the source).
    let h = (r.step / 6.0).clamp(0.05, 0.25);
    let m = (r.step / h).floor() as i32;
    for a in -m..=m {
        for b in -m..=m {
            spots.push(r.p0 + nalgebra::Vector2::new(a as f64 * h, b as f64 * h));
        }
    }
    spots.push(r.p0);
    spots.extend(r.heading);
    spots
        .into_iter()
        .filter(|q| {
            let rho = (q - centre).norm();
            (q - r.p0).norm() <= reach && rho >= lo && rho <= hi && free.is_free(q) && keep.allows(&r.p0, q)
        })
        .map(|spot| {
            let s = sensor_at(&spot, source, &r.base_from_array, r.sigma_rad);
            let d = s.origin - source;
            Candidate {
                spot,
                fisher: fisher_information(&[s], source),
                dir: if d.norm() > 0.0 { d.normalize() } else { Vector3::x() },
                travel: (spot - r.p0).norm() * r.travel_scale,
            }
        })
        .collect()
}

struct Scorer<'a> {
    cands: &'a [Vec<Candidate>],
    separations: &'a [Separation],
    band_deg: (f64, f64),
    cfg: &'a SamplingConfig,
}

impl Scorer<'_> {
    /// Σ of separation shortfalls (m) of a tuple.
    fn separation_violation(&self, picks: &[usize]) -> f64 {
        self.separations
            .iter()
            .map(|s| {
                let d = (self.cands[s.i][picks[s.i]].spot - self.cands[s.j][picks[s.j]].spot).norm();
                (s.min_m - d).max(0.0)
            })
            .sum()
    }

    fn score(&self, picks: &[usize]) -> f64 {
        let mut j = Matrix3::zeros();
        let mut travel = 0.0;
        for (i, &k) in picks.iter().enumerate() {
            j += self.cands[i][k].fisher;
            travel += self.cands[i][k].travel;
        }
        let info = match j.try_inverse() {
            Some(inv) if inv.trace() > 0.0 => inv.trace().ln(),
            _ => 1e6,
        };
        // Best pair: the |cos θ| closest to 0.
        let mut best_cos = 1.0f64;
        for a in 0..picks.len() {
            for b in (a + 1)..picks.len() {
                let c = self.cands[a][picks[a]].dir.dot(&self.cands[b][picks[b]].dir);
                if c.abs() < best_cos.abs() {
                    best_cos = c;
                }
            }
        }
        let theta = best_cos.clamp(-1.0, 1.0).acos().to_degrees();
        let outside = (self.band_deg.0 - theta).max(theta - self.band_deg.1).max(0.0);
        info + self.cfg.travel_weight_per_m * travel
            + self.cfg.band_penalty_per_deg * outside
            + 1e3 * self.separation_violation(picks)
    }

    fn exhaustive_pair(&self) -> Option<Vec<usize>> {
        let mut best: Option<(f64, Vec<usize>)> = None;
        for a in 0..self.cands[0].len() {
            for b in 0..self.cands[1].len() {
                let picks = [a, b];
                if self.separation_violation(&picks) > SEPARATION_TOL_M {
                    continue;
                }
                let s = self.score(&picks);
                if best.as_ref().is_none_or(|x| s < x.0) {
                    best = Some((s, picks.to_vec()));
                }
            }
        }
        best.map(|b| b.1)
    }

    /// Shortfall (m) of the separations between robot `i` at candidate `k` and
    /// the robots `placed` so far.
    fn violation_with(&self, picks: &[usize], placed: &[bool], i: usize, k: usize) -> f64 {
        self.separations
            .iter()
            .filter_map(|s| {
                let other = if s.i == i {
                    s.j
                } else if s.j == i {
                    s.i
                } else {
                    return None;
                };
                placed[other].then(|| {
                    let d = (self.cands[i][k].spot - self.cands[other][picks[other]].spot).norm();
                    (s.min_m - d).max(0.0)
                })
            })
            .sum()
    }

    fn gauss_seidel(&self, robots: &[SampleRobot]) -> Option<Vec<usize>> {
        let n = robots.len();
        // Greedy start: one robot after the other, the candidate nearest its
        // heading point (or itself) among those keeping clear of the robots placed.
        let mut picks = vec![0usize; n];
        let mut placed = vec![false; n];
        for i in 0..n {
            let want = robots[i].heading.unwrap_or(robots[i].p0);
            let key = |k: usize| {
                (self.violation_with(&picks, &placed, i, k), (self.cands[i][k].spot - want).norm())
            };
            picks[i] = (0..self.cands[i].len()).min_by(|&a, &b| {
                let (ka, kb) = (key(a), key(b));
                ka.0.total_cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
            })?;
            placed[i] = true;
        }
        // Sweeps: one robot at a time, the others held; a move may not add a
        // separation shortfall, and lowers the score (or the shortfall).
        let all = vec![true; n];
        for _ in 0..self.cfg.max_sweeps {
            let mut changed = false;
            for i in 0..n {
                let keep = picks[i];
                let mut best = (self.violation_with(&picks, &all, i, keep), self.score(&picks), keep);
                for k in 0..self.cands[i].len() {
                    let v = self.violation_with(&picks, &all, i, k);
                    if v > best.0 + 1e-12 {
                        continue;
                    }
                    picks[i] = k;
                    let s = self.score(&picks);
                    if v < best.0 - 1e-12 || s < best.1 - 1e-12 {
                        best = (v, s, k);
                    }
                }
                picks[i] = best.2;
                changed |= best.2 != keep;
            }
            if !changed {
                break;
            }
        }
        Some(picks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::free_space::FreeSpaceConfig;
    use crate::uncertainty::angle_at_deg;

    /// The keep-out of a still source at the origin.
    const STILL: KeepOut = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(0.0, 0.0), 1.0);

    fn robot(x: f64, y: f64, step: f64) -> SampleRobot {
        SampleRobot {
            p0: Point2::new(x, y),
            base_from_array: Isometry3::identity(),
            sigma_rad: 0.05,
            range: (1.0, 5.0),
            step,
            travel_scale: 1.0,
            heading: None,
        }
    }

    #[test]
    fn two_robots_without_step_limit_reach_ninety_degrees() {
        let free = FreeSpace::new(&FreeSpaceConfig::default(), 0.3);
        let src = Point3::origin();
        let robots = [robot(3.0, 0.25, 10.0), robot(3.0, -0.25, 10.0)];
        let SampleOutcome::Found(p) =
            search(&src, &robots, &[], &free, (40.0, 140.0), &STILL, &SamplingConfig::default())
        else {
            panic!()
        };
        let theta = angle_at_deg(&src, &Point3::new(p[0].x, p[0].y, 0.0), &Point3::new(p[1].x, p[1].y, 0.0));
        assert!((theta - 90.0).abs() <= 5.0, "θ {theta}");
    }

    #[test]
    fn a_robot_boxed_in_has_no_candidates() {
        // A tiny room around the robots, 3 m from the source, but ranges must be ≤ 2 m.
        let cfg = FreeSpaceConfig {
            room: vec![[2.5, -0.5], [3.5, -0.5], [3.5, 0.5], [2.5, 0.5]],
            obstacles: vec![],
        };
        let free = FreeSpace::new(&cfg, 0.4);
        let mut r = robot(3.0, 0.0, 1.0);
        r.range = (1.0, 2.0);
        let robots = [r.clone(), r];
        let out =
            search(&Point3::origin(), &robots, &[], &free, (40.0, 140.0), &STILL, &SamplingConfig::default());
        assert!(matches!(out, SampleOutcome::NoCandidates(0, _)), "{out:?}");
    }

    #[test]
    fn spots_beside_the_walkers_path_are_not_offered() {
        // A walker at (-1, 0) predicted at the origin: spots within 1 m of the
        // segment between are out, even where they are 1 m from the origin.
        let walker = KeepOut::new(Point2::new(-1.0, 0.0), Point2::new(0.0, 0.0), 1.0);
        assert!((walker.clearance(&Point2::new(-0.5, 0.8)) - 0.8).abs() < 1e-12);
        assert!((walker.clearance(&Point2::new(-2.0, 0.0)) - 1.0).abs() < 1e-12);
        assert!(!walker.allows(&Point2::new(-1.0, 2.0), &Point2::new(-0.7, 0.9)));
        // A robot already inside may move, but not nearer the path.
        assert!(walker.allows(&Point2::new(-0.5, 0.5), &Point2::new(-0.5, 0.7)));
        assert!(!walker.allows(&Point2::new(-0.5, 0.5), &Point2::new(-0.5, 0.4)));
        let free = FreeSpace::new(&FreeSpaceConfig::default(), 0.3);
        let robots = [robot(-1.0, 1.6, 1.0), robot(1.5, 0.0, 1.0)];
        let src = Point3::origin();
        let SampleOutcome::Found(p) =
            search(&src, &robots, &[], &free, (40.0, 140.0), &walker, &SamplingConfig::default())
        else {
            panic!()
        };
        assert!(p.iter().all(|q| walker.clearance(q) >= 1.0 - 1e-6), "{p:?}");
    }
}

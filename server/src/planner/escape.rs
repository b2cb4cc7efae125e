//! Backing out of the keep-out: a robot that finds itself closer than
//! `min_range_m` to the source's path (a walker came up to it, or walked
//! through the formation) is sent straight out, whatever the re-tasking clock
//! and before any geometry is considered.
//!
//! The keep-out is the one around the source's predicted path that every other
//! goal keeps (`cycle::KeepOut`: within r_min of the segment from the source's
//! estimate now to its prediction `source_lead_s` ahead, and of the one back
//! to the rays' newest fix, below). The ordinary cycle
//! only forbids a robot inside it to come *nearer*; its waypoints are at most
//! one step long, so a robot 0.2 m from a walker was given goals still inside
//! (measured on the start scenarios' sweep: 40 of 47 goals issued within 1 m
//! of the true source came from robots already inside).
//!
//! The way out is the nearest free spot whose clearance from the path is at
//! least r_min + m, with the margin m = max(`keep_out_margin_m`, 2σ_h) (2σ_h
//! capped at 1 m: a vague estimate does not send robots metres away) and σ_h
//! the estimate's largest horizontal 1-σ: the keep-out is about the true
//! source, and the estimate is off by about σ_h (by 2σ_h in 14 % of cases
//! for a 2D Gaussian, e^{−2}). Worked numbers: r_min 1 m, σ_h 0.1 m → the
//! robot is sent to 1.3 m from the path (1.2 m from the truth in the worst
//! 14 % of cases); σ_h 0.25 m → 1.5 m. Candidates lie on rings around the
//! robot (every 10°, every 0.1 m), nearest first; a spot is taken only when
//! it is free, no nearer than `min_separation_m` to the other robots (waived
//! when nothing else is free), and the straight drive there never comes nearer
//! the path than the robot is now (it does not cross in front of the walker).
//!
//! With several sources (`PlannerInput::others`, the sound map's other
//! confirmed sources) every source has such a keep-out: a robot inside any of
//! them backs out of all, and an ordinary goal the served source's plan puts
//! inside another's keep-out is moved to the nearest spot clear of every
//! keep-out (the served one's plan does not see the others), or dropped when
//! there is none.
//!
//! Ordinary goals, planned around the estimate, often lie right at the
//! keep-out's edge; they are pushed straight out to the clearance a robot
//! backing out is sent to, r_min + m with the same margin m: they then stay
//! outside the true source's keep-out unless the estimate is off by more
//! than m. A goal about a step from its robot (a robot near the source sent
//! round it) would be pushed beyond the step: it is first drawn back along
//! the way from the robot, as little as needed, and pushed out from there
//! ([`push_out_within`]): the same clearance, a little less of the way.
//! Where the other constraints (the largest range, free space, another
//! keep-out, the separation) refuse the push, the goal slides along the
//! keep-out instead: the nearest spot around it (the rings of
//! [`escape_spot`], centred on the goal) that has the full clearance, is
//! free, keeps `min_separation_m` from the other robots' destinations and
//! lies within the step and the largest range; its note says how far it
//! moved and what the straight push would have broken. Only where there is
//! no such spot is the push tried at ¾, ½ and ¼ of the margin before the
//! goal is left where it was. A goal left short of the full clearance
//! carries a note with the clearance it has, the one wanted and what the
//! full push would break. (A goal held by another robot's destination at
//! 1.04 m from an estimate 0.12 m off, 0.92 m from the true talker, was
//! the case that asked for the slide: `corner-start-3` seed 37, session
//! 15.)
//!
//! Why, measured decision by decision (the recorded `corner-start` seeds
//! 1–40 replayed with `soundmap-sim replay-mcap`, which re-runs the planner
//! on the runs' own estimates; BENCHMARKS.md, session 14): the push used to
//! be 2σ_h capped at `keep_out_margin_m`, and of the 7 goals it left within
//! 1 m of the true talker (of 3,687), 3 had their push refused or cut short
//! by the step, 2 were planned around estimates with σ_h 0.6–0.8 m whose
//! push was capped at 0.3 m, and 2 around estimates off by 2–3.5 σ_h. With
//! the escape's clearance and the drawing back, 3 are left: an estimate
//! 1.3 m off with σ_h 0.79 m (beyond the 1 m cap), one 0.53 m off with
//! σ_h 0.15 m, and an escape that ends 1 mm inside. Earlier, a 1-σ push (all
//! or nothing) and then a 2σ_h push capped at 0.3 m took the goals issued
//! within 1 m of the true source over the start scenarios' 20-seed sweep
//! from 18 to 14.
//!
//! The path the keep-out is drawn around also runs back from the estimate
//! to its fix (`SourceEstimate::fix_in_map`: the newest triangulation of the
//! track's rays, when the triangulation gate accepted it): a filter
//! following a walker lags it after a turn or a pause, while the rays
//! already point at where it is. Measured (session 17, `corner-start`
//! seeds 5, 7 and 27): the three goals issued inside the true keep-out were
//! planned around filtered estimates 0.41–0.49 m behind the talker (NEES
//! 7–24) whose fixes were 0.06–0.30 m from it; each goal lay 1.0–1.2 m
//! from the fix. With the fix in the keep-out, `corner-start` seeds 1–80
//! had 1 such goal instead of 4, with θ in band as before (BENCHMARKS.md,
//! "The keep-out runs back to the rays' fix").
//!
//! Among the spots on the nearest ring with a way out and the next three
//! (0.3 m further at most), the planner takes the one whose formation leaves
//! θ least outside the band, each 0.1 m of extra drive counting as 2° of θ.
//! θ is taken where the source is predicted `source_lead_s` ahead *and* one
//! lead later, the worse of the two: a robot backs out because a walker is
//! coming at it, and a spot that leaves θ just inside the band for the first
//! prediction is out of it a second later (`corner-start`, seeds 1–20: time
//! in band after convergence 94.0 % → 96.3 % on average, seeds below 95 %
//! 12 → 6, measured with the ceiling model of `floor_image` on).

use nalgebra::{Matrix2, Matrix3, Point2, Point3};

use super::cycle::KeepOut;
use super::free_space::FreeSpace;
use super::input::SourceEstimate;

/// Ring spacing of the search (m).
const RING_STEP_M: f64 = 0.1;
/// Directions per ring.
const DIRECTIONS: usize = 36;
/// Largest part of the margin the estimate's uncertainty adds (m): a robot
/// is not sent metres away from a vague estimate (the planner accepts
/// sources up to `max_source_rms_m`, 3 m).
const MAX_UNCERTAINTY_MARGIN_M: f64 = 1.0;
/// Farthest the search looks from the robot (m).
const MAX_REACH_M: f64 = 6.0;
/// Rings beyond the nearest with a way out among which the cheapest is taken.
const EXTRA_RINGS: usize = 3;
/// Cost of driving further than the nearest way out, per metre (the cost's
/// unit: degrees of θ outside the band).
const EXTRA_TRAVEL_COST_PER_M: f64 = 20.0;
/// Points checked along the drive to a candidate.
const DRIVE_SAMPLES: usize = 10;
/// Bisections of how far [`push_out_within`] draws a goal back (2⁻²⁰ of the way: µm).
const PUSH_BISECTIONS: usize = 20;

/// The clearance a robot backing out is sent to (m): r_min + max(margin,
/// min(2σ_h, 1 m)).
pub(super) fn escape_clearance_m(radius_m: f64, margin_m: f64, covariance_m2: &Matrix3<f64>) -> f64 {
    let sigma_h = horizontal_sigma_m(covariance_m2);
    radius_m + margin_m.max((2.0 * sigma_h).min(MAX_UNCERTAINTY_MARGIN_M))
}

/// The largest horizontal 1-σ of a 3D position covariance: that of its xy block (m).
pub(super) fn horizontal_sigma_m(covariance_m2: &Matrix3<f64>) -> f64 {
    let xy: Matrix2<f64> = covariance_m2.fixed_view::<2, 2>(0, 0).into_owned();
    let sym = (xy + xy.transpose()) * 0.5;
    sym.symmetric_eigenvalues().max().max(0.0).sqrt()
}

/// `q` moved straight away from the keep-out's path to `clearance` from it,
/// when it is nearer than that (`None` when it is not, or lies on the path).
pub(super) fn push_out(keep: &KeepOut, q: &Point2<f64>, clearance: f64) -> Option<Point2<f64>> {
    let c = keep.nearest_on_path(q);
    let away = q - c;
    let r = away.norm();
    (r < clearance && r > 1e-9).then(|| c + away * (clearance / r))
}

/// `q` moved out to `clearance` from the keep-out's path and within `step`
/// of `p0`: straight out ([`push_out`]) when that is within reach, else
/// first drawn back along the way from `p0` to `q`, as little as needed
/// (by bisection), and pushed straight out from there. `None` when `q` is
/// already that clear, or when even a spot drawn back to `p0` is out of reach.
pub(super) fn push_out_within(
    keep: &KeepOut,
    q: &Point2<f64>,
    clearance: f64,
    p0: &Point2<f64>,
    step: f64,
) -> Option<Point2<f64>> {
    let straight = push_out(keep, q, clearance)?;
    if (straight - p0).norm() <= step {
        return Some(straight);
    }
    let out_at = |t: f64| {
        let qt = q + (p0 - q) * t;
        if keep.clearance(&qt) >= clearance { Some(qt) } else { push_out(keep, &qt, clearance) }
    };
    let reaches = |t: f64| out_at(t).is_some_and(|o| (o - p0).norm() <= step);
    if !reaches(1.0) {
        return None;
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..PUSH_BISECTIONS {
        let mid = 0.5 * (lo + hi);
        if reaches(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    out_at(hi)
}

/// Whether `q` lies at least `extra` beyond every keep-out's radius (with
/// `extra` = 0: outside every keep-out).
pub(super) fn clear_of(keeps: &[(KeepOut, f64)], q: &Point2<f64>, extra: f64) -> bool {
    keeps.iter().all(|(k, _)| k.clearance(q) >= k.radius_m + extra)
}

/// The nearest spot out of every keep-out for a robot at `p0` (see the
/// module docs): each `(keep-out, clearance)` pair asks for that clearance
/// from its path. `None` when no free spot within reach has it.
pub(super) fn escape_spot(
    keeps: &[(KeepOut, f64)],
    free: &FreeSpace,
    p0: &Point2<f64>,
    others: &[Point2<f64>],
    min_separation_m: f64,
    cost: impl Fn(&Point2<f64>) -> f64,
) -> Option<Point2<f64>> {
    let from: Vec<f64> = keeps.iter().map(|(k, _)| k.clearance(p0)).collect();
    // Beyond this every keep-out and its path lies behind the robot.
    let reach = keeps
        .iter()
        .map(|(k, want)| (k.fix - p0).norm() + (k.now - k.fix).norm() + (k.ahead - k.now).norm() + want)
        .fold(0.0, f64::max)
        .min(MAX_REACH_M);
    let rings = (reach / RING_STEP_M).ceil() as usize;
    // The drive there never comes nearer a path than the robot is now, where
    // it is inside that keep-out.
    let drive_ok = |q: &Point2<f64>| {
        (1..=DRIVE_SAMPLES).all(|s| {
            let x = p0 + (q - p0) * (s as f64 / DRIVE_SAMPLES as f64);
            keeps.iter().zip(&from).all(|((k, _), f)| *f >= k.radius_m || k.clearance(&x) >= f - 1e-9)
        })
    };
    let valid = |q: &Point2<f64>, separated: bool| {
        keeps.iter().all(|(k, want)| k.clearance(q) >= *want)
            && free.is_free(q)
            && (!separated || others.iter().all(|o| (q - o).norm() >= min_separation_m))
            && drive_ok(q)
    };
    let ring = |k: usize| {
        let rho = k as f64 * RING_STEP_M;
        (0..DIRECTIONS).map(move |a| {
            let phi = std::f64::consts::TAU * a as f64 / DIRECTIONS as f64;
            p0 + nalgebra::Vector2::new(phi.cos(), phi.sin()) * rho
        })
    };
    for separated in [true, false] {
        let Some(first) = (1..=rings).find(|&k| ring(k).any(|q| valid(&q, separated))) else {
            continue;
        };
        // The nearest ring with a way out and the next few: the cheapest by
        // `cost` plus the extra travel.
        return (first..=(first + EXTRA_RINGS).min(rings))
            .flat_map(|k| ring(k).map(move |q| (k, q)))
            .filter(|(_, q)| valid(q, separated))
            .map(|(k, q)| (cost(&q) + EXTRA_TRAVEL_COST_PER_M * (k - first) as f64 * RING_STEP_M, q))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, q)| q);
    }
    None
}

/// The keep-out of source `s`: around its path from its fix (when it has
/// one) through its estimate to where it is predicted `lead_s` ahead.
pub(super) fn keep_out(s: &SourceEstimate, lead_s: f64, radius_m: f64) -> KeepOut {
    let xy = |p: &Point3<f64>| Point2::new(p.x, p.y);
    let now = xy(&s.position_in_map);
    KeepOut {
        fix: s.fix_in_map.as_ref().map_or(now, xy),
        ..KeepOut::new(now, xy(&s.predicted(lead_s)), radius_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::free_space::FreeSpaceConfig;

    fn open() -> FreeSpace {
        FreeSpace::new(&FreeSpaceConfig::default(), 0.35)
    }

    #[test]
    fn clearance_grows_with_the_estimate_uncertainty() {
        let tight = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.01, 0.0001, 0.5));
        assert!((escape_clearance_m(1.0, 0.3, &tight) - 1.3).abs() < 1e-12);
        let loose = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.0001, 0.0625, 0.5));
        assert!((escape_clearance_m(1.0, 0.3, &loose) - 1.5).abs() < 1e-12);
        let vague = Matrix3::from_diagonal(&nalgebra::Vector3::new(4.0, 4.0, 9.0));
        assert!((escape_clearance_m(1.0, 0.3, &vague) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn push_out_moves_straight_away_from_the_path() {
        let keep = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(1.0, 0.0), 1.0);
        let q = push_out(&keep, &Point2::new(0.5, 1.0), 1.1).unwrap();
        assert!((q - Point2::new(0.5, 1.1)).norm() < 1e-12);
        let q = push_out(&keep, &Point2::new(-0.6, -0.8), 1.1).unwrap();
        assert!((q - Point2::new(-0.66, -0.88)).norm() < 1e-12);
        assert!(push_out(&keep, &Point2::new(0.5, 1.2), 1.1).is_none());
    }

    #[test]
    fn push_out_within_draws_a_goal_back_to_stay_within_the_step() {
        let keep = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(0.0, 0.0), 1.0);
        // Within reach straight out: the same as `push_out`.
        let p0 = Point2::new(2.0, 0.0);
        let q = Point2::new(1.05, 0.0);
        assert_eq!(push_out_within(&keep, &q, 1.3, &p0, 1.0), push_out(&keep, &q, 1.3));
        // A robot 0.9 m from the source, sent 0.97 m round it to the
        // keep-out's edge: straight out, 1.3 m from the source, the goal
        // would be 1.16 m from the robot. Drawn back towards the robot, it
        // ends on the 1.3 m circle exactly one step from the robot.
        let p0 = Point2::new(-0.11, 0.89);
        let q = Point2::new(-0.94, 0.39);
        assert!((push_out(&keep, &q, 1.3).unwrap() - p0).norm() > 1.15);
        let out = push_out_within(&keep, &q, 1.3, &p0, 1.0).unwrap();
        assert!((keep.clearance(&out) - 1.3).abs() < 1e-9, "{out}");
        assert!(((out - p0).norm() - 1.0).abs() < 1e-5, "{out}");
        // Drawn back only as far as needed: a fifth of the way (the other
        // point of the circle a step from the robot lies behind it).
        assert!((out - Point2::new(-1.0926, 0.7044)).norm() < 1e-3, "{out}");
        // Already clear, or out of reach even from the robot's own spot.
        assert!(push_out_within(&keep, &Point2::new(1.4, 0.0), 1.3, &p0, 1.0).is_none());
        let near = Point2::new(0.2, 0.0);
        assert!(push_out_within(&keep, &Point2::new(0.1, 0.1), 1.3, &near, 0.5).is_none());
    }

    #[test]
    fn a_robot_next_to_a_still_source_backs_straight_away() {
        let keep = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(0.0, 0.0), 1.0);
        let p0 = Point2::new(0.3, 0.0);
        let q = escape_spot(&[(keep, 1.3)], &open(), &p0, &[], 0.8, |_| 0.0).unwrap();
        assert!(keep.clearance(&q) >= 1.3);
        assert!((q - p0).norm() < 1.1, "{q}");
        assert!(q.x > 1.2 && q.y.abs() < 0.25, "{q}");
    }

    #[test]
    fn a_robot_in_a_walkers_way_steps_aside_rather_than_ahead() {
        // Walker at the origin heading +x at 1 m/s; the robot stands on its
        // path 0.5 m ahead. Running ahead along the path needs 2.8 m; stepping
        // aside 1.3 m.
        let keep = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(1.0, 0.0), 1.0);
        let p0 = Point2::new(0.5, 0.01);
        let q = escape_spot(&[(keep, 1.3)], &open(), &p0, &[], 0.8, |_| 0.0).unwrap();
        assert!(keep.clearance(&q) >= 1.3);
        assert!(q.y > 1.2 && (q.x - 0.5).abs() < 0.3, "{q}");
    }

    #[test]
    fn the_way_out_does_not_cross_the_path() {
        // A wall 0.5 m behind the robot (y < -0.85 is outside the room with its
        // clearance): it may not leave through the source's side.
        let cfg = FreeSpaceConfig {
            room: vec![[-10.0, -1.2], [10.0, -1.2], [10.0, 10.0], [-10.0, 10.0]],
            obstacles: vec![],
        };
        let free = FreeSpace::new(&cfg, 0.35);
        let keep = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(0.0, 0.0), 1.0);
        let p0 = Point2::new(0.0, -0.6);
        let q = escape_spot(&[(keep, 1.3)], &free, &p0, &[], 0.8, |_| 0.0).unwrap();
        assert!(keep.clearance(&q) >= 1.3 && free.is_free(&q));
        assert!(q.y < -0.5 && q.x.abs() > 1.0, "{q}");
    }

    #[test]
    fn other_robots_are_kept_apart_when_possible() {
        let keep = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(0.0, 0.0), 1.0);
        let p0 = Point2::new(0.3, 0.0);
        let other = Point2::new(1.4, 0.0);
        let q = escape_spot(&[(keep, 1.3)], &open(), &p0, &[other], 0.8, |_| 0.0).unwrap();
        assert!((q - other).norm() >= 0.8 && keep.clearance(&q) >= 1.3, "{q}");
    }
}

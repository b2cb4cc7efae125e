//! Target geometry (theory §2.4, §3.2): the bearings around the source at
//! which the robots' Fisher information is best, matched to the robots with
//! the least travel.
//!
//! Patterns, as bearing offsets around the source's horizontal position:
//! - N = 2: {0, Δφ} with Δφ chosen so that the *3D* angle at the source is 90°
//!   given the arrays' height below/above the source: cos Δφ = −Δz₁Δz₂/ρ²
//!   (Δφ = 90° when the source is at array height);
//! - N ≥ 3: spacing π/N (a fan) and 2π/N (a full circle); both give
//!   Σ e^{j2φᵢ} = 0, the D-optimum in the plane. Which is better in 3D is
//!   left to the score, which evaluates ln det J at the 3D array positions.
//!
//! Every pattern is rotated over a grid (then refined) and the robots are
//! assigned to its slots by minimum-cost matching. The cost of a candidate is
//! Σ (travel (straight line, m) × the robot's travel scale + turn cost × the
//! turn towards the spot before the drive) + switch weight × arc between each robot's new and
//! previous target bearing + penalty × blocked spots − info weight × ln det J.
//!
//! **Turns counted as travel** (experimental, off unless `[planner]
//! robot_turn_rate_deg_per_s` is set). A ground robot's base turns in place
//! before it drives off in a new direction (the simulated bases do when a
//! goal lies more than 34° off their heading): a spot behind a robot costs
//! it a half turn before it moves at all. By travel alone the pattern sends
//! robots behind themselves whenever that is a little shorter, and,
//! re-placed every cycle around a walker, such goals kept changing direction
//! faster than the base turned: in `corner-start-3` seed 8 the pioneer
//! turned about 270° in 4 s and moved 0.4 m while θ fell to 24°
//! (BENCHMARKS.md, session 15). With a turn rate set, the turn towards the
//! spot is priced at what it costs in time, robot speed ÷ turn rate metres
//! per radian (0.38 m/rad at 0.8 m/s and 120°/s); a robot within
//! `AT_SPOT_M` of its spot turns none. The turn on arrival, to face the
//! source, is not counted: a robot is usually re-tasked before it arrives,
//! and counting it made every drive around the source (across the bearing,
//! the drive that changes θ) dearer than a drive along it (`corner-start`
//! 4 → 11 runs below 95 % in band). Measured: the start scenarios' runs
//! below 95 % in band 28 → 19 of 160, but `cocktail-active` (three talkers)
//! 2 → 24 id switches over 20 runs, which is why it is not on by default.

use nalgebra::{Isometry3, Point2, Point3};

use super::assignment::assign;
use super::free_space::FreeSpace;
use super::pose::{sensor_at, unit, wrap};
use crate::uncertainty::{Sensor, fisher_information};

/// A robot this close to a spot is there: it drives no more, and turns none.
const AT_SPOT_M: f64 = 0.2;

/// A robot as the pattern search sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct PatternRobot {
    /// Current base position, map xy (m).
    pub base_xy: Point2<f64>,
    /// Array on the base.
    pub base_from_array: Isometry3<f64>,
    /// Angular σ per tangent axis (rad).
    pub sigma_rad: f64,
    /// Target bearing of the previous plan (rad, map frame, around the source), if any.
    pub previous_bearing_rad: Option<f64>,
    /// Heading of the base (rad, map frame), if known.
    pub heading_rad: Option<f64>,
    /// Its travel's cost per metre: the fleet's reference speed over its
    /// own (1 for a robot as fast as `robot_speed_m_per_s`), so that costs
    /// compare times and a slow robot takes the nearer spot.
    pub travel_scale: f64,
    /// Cost per radian it turns towards its spot before it drives there (m at
    /// the reference speed; reference speed ÷ its turn rate), 0: turns not counted.
    pub turn_cost_m_per_rad: f64,
}

/// How candidates are generated and scored.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatternSettings {
    /// Range of the spots from the source (m, horizontal).
    pub range_m: f64,
    /// Rotation grid (degrees).
    pub rotation_step_deg: f64,
    /// Cost per metre of arc away from a robot's previous target bearing.
    pub switch_weight: f64,
    /// Cost of a spot that is not free (m); 0 ignores free space.
    pub blocked_penalty_m: f64,
    /// Cost per unit of −ln det J (m).
    pub info_weight_m: f64,
}

/// The chosen target pattern.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetPattern {
    /// Target bearing per robot (rad, map frame, from the source toward the robot).
    pub bearings_rad: Vec<f64>,
    /// Ideal spot per robot, map xy (m).
    pub spots: Vec<Point2<f64>>,
    /// Smallest angular spacing between two slots (rad).
    pub min_spacing_rad: f64,
    /// Σ straight-line travel to the spots (m).
    pub travel_m: f64,
    /// Number of spots that are not free (counted only when free space is scored).
    pub blocked: usize,
    /// Total cost of the candidate.
    pub cost: f64,
}

/// Bearing offsets of the candidate patterns for `n` robots. `dz` are the
/// arrays' heights relative to the source (array z − source z, m).
pub fn pattern_offsets(n: usize, dz: &[f64], range_m: f64) -> Vec<Vec<f64>> {
    use std::f64::consts::PI;
    match n {
        0 | 1 => vec![vec![0.0; n]],
        2 => {
            let cos = (-(dz[0] * dz[1]) / (range_m * range_m)).clamp(-1.0, 1.0);
            vec![vec![0.0, cos.acos()]]
        }
        _ => [PI / n as f64, 2.0 * PI / n as f64]
            .iter()
            .map(|step| (0..n).map(|k| k as f64 * step).collect())
            .collect(),
    }
}

/// Chooses the target pattern with the least cost (see the module doc).
/// `free` scores blocked spots when given and `blocked_penalty_m > 0`.
pub fn choose_pattern(
    source_in_map: &Point3<f64>,
    robots: &[PatternRobot],
    settings: &PatternSettings,
    free: Option<&FreeSpace>,
) -> TargetPattern {
    let n = robots.len();
    let dz: Vec<f64> =
        robots.iter().map(|r| r.base_from_array.translation.vector.z - source_in_map.z).collect();
    let mean_dz = if n == 0 { 0.0 } else { dz.iter().sum::<f64>() / n as f64 };
    let offsets = pattern_offsets(n, &vec![mean_dz; n], settings.range_m);
    let step = settings.rotation_step_deg.to_radians();
    let count = (std::f64::consts::TAU / step).ceil() as usize;
    let mut best: Option<TargetPattern> = None;
    for pattern in &offsets {
        let spacing = min_spacing(pattern);
        let mut local: Option<TargetPattern> = None;
        let mut local_rot = 0.0;
        for k in 0..count {
            let rot = k as f64 * step;
            let cand = evaluate(source_in_map, robots, settings, free, pattern, rot, spacing);
            if local.as_ref().is_none_or(|b| cand.cost < b.cost) {
                local = Some(cand);
                local_rot = rot;
            }
        }
        // Refine the rotation by halving around the best grid value.
        let mut d = step / 2.0;
        while d > 0.1f64.to_radians() {
            for rot in [local_rot - d, local_rot + d] {
                let cand = evaluate(source_in_map, robots, settings, free, pattern, rot, spacing);
                if local.as_ref().is_none_or(|b| cand.cost < b.cost) {
                    local = Some(cand);
                    local_rot = rot;
                }
            }
            d /= 2.0;
        }
        if let Some(l) = local
            && best.as_ref().is_none_or(|b| l.cost < b.cost)
        {
            best = Some(l);
        }
    }
    best.unwrap_or(TargetPattern {
        bearings_rad: vec![],
        spots: vec![],
        min_spacing_rad: 0.0,
        travel_m: 0.0,
        blocked: 0,
        cost: 0.0,
    })
}

fn min_spacing(offsets: &[f64]) -> f64 {
    let mut m = std::f64::consts::PI;
    for i in 0..offsets.len() {
        for j in (i + 1)..offsets.len() {
            m = m.min(wrap(offsets[i] - offsets[j]).abs());
        }
    }
    m
}

/// Cost of one rotated pattern with its best assignment.
fn evaluate(
    source: &Point3<f64>,
    robots: &[PatternRobot],
    s: &PatternSettings,
    free: Option<&FreeSpace>,
    offsets: &[f64],
    rotation: f64,
    spacing: f64,
) -> TargetPattern {
    let n = robots.len();
    let centre = Point2::new(source.x, source.y);
    let slot_bearing: Vec<f64> = offsets.iter().map(|o| wrap(o + rotation)).collect();
    let slot_spot: Vec<Point2<f64>> = slot_bearing.iter().map(|b| centre + unit(*b) * s.range_m).collect();
    let mut cost = vec![0.0; n * n];
    for (i, r) in robots.iter().enumerate() {
        for j in 0..n {
            let d = slot_spot[j] - r.base_xy;
            let travel = d.norm();
            let switch = r.previous_bearing_rad.map_or(0.0, |p| wrap(slot_bearing[j] - p).abs() * s.range_m);
            // The turn towards the spot before the drive; not the one to face
            // the source on arrival (see the module docs).
            let turn = match r.heading_rad {
                Some(h) if r.turn_cost_m_per_rad > 0.0 && travel > AT_SPOT_M => {
                    wrap(d.y.atan2(d.x) - h).abs()
                }
                _ => 0.0,
            };
            cost[i * n + j] =
                r.travel_scale * travel + s.switch_weight * switch + r.turn_cost_m_per_rad * turn;
        }
    }
    let (slot, assigned) = assign(&cost, n);
    let spots: Vec<Point2<f64>> = slot.iter().map(|&j| slot_spot[j]).collect();
    let bearings_rad: Vec<f64> = slot.iter().map(|&j| slot_bearing[j]).collect();
    let travel_m = robots.iter().zip(&spots).map(|(r, g)| (g - r.base_xy).norm()).sum();
    let blocked = match free {
        Some(f) if s.blocked_penalty_m > 0.0 => spots.iter().filter(|g| !f.is_free(g)).count(),
        _ => 0,
    };
    let info = if s.info_weight_m > 0.0 {
        let sensors: Vec<Sensor> = robots
            .iter()
            .zip(&spots)
            .map(|(r, g)| sensor_at(g, source, &r.base_from_array, r.sigma_rad))
            .collect();
        let det = fisher_information(&sensors, source).determinant();
        if det > 0.0 { -det.ln() } else { 1e3 }
    } else {
        0.0
    };
    TargetPattern {
        bearings_rad,
        spots,
        min_spacing_rad: spacing,
        travel_m,
        blocked,
        cost: assigned + s.blocked_penalty_m * blocked as f64 + s.info_weight_m * info,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::uncertainty::angle_at_deg;

    fn robot(x: f64, y: f64, h: f64) -> PatternRobot {
        PatternRobot {
            base_xy: Point2::new(x, y),
            base_from_array: Isometry3::translation(0.0, 0.0, h),
            sigma_rad: 0.05,
            previous_bearing_rad: None,
            heading_rad: None,
            travel_scale: 1.0,
            turn_cost_m_per_rad: 0.0,
        }
    }

    fn settings() -> PatternSettings {
        PatternSettings {
            range_m: 2.0,
            rotation_step_deg: 5.0,
            switch_weight: 0.0,
            blocked_penalty_m: 0.0,
            info_weight_m: 0.0,
        }
    }

    #[test]
    fn two_robots_at_source_height_get_ninety_degrees() {
        let src = Point3::new(0.0, 0.0, 0.5);
        let robots = [robot(3.0, 0.25, 0.5), robot(3.0, -0.25, 0.5)];
        let p = choose_pattern(&src, &robots, &settings(), None);
        let (a, b) = (p.spots[0], p.spots[1]);
        let theta = angle_at_deg(&src, &Point3::new(a.x, a.y, 0.5), &Point3::new(b.x, b.y, 0.5));
        assert!((theta - 90.0).abs() < 1e-6, "θ {theta}");
        // Symmetric about the robots' side, upper robot on the upper spot.
        assert!(a.y > 0.0 && b.y < 0.0 && (a.y + b.y).abs() < 0.05, "{a:?} {b:?}");
    }

    #[test]
    fn a_source_above_the_arrays_widens_the_horizontal_spread() {
        // Arrays at 0.5 m, source at 2.0 m: 90° in 3D needs Δφ > 90° in plan view.
        let src = Point3::new(0.0, 0.0, 2.0);
        let off = pattern_offsets(2, &[-1.5, -1.5], 2.0);
        assert!(off[0][1].to_degrees() > 90.0);
        let robots = [robot(3.0, 0.25, 0.5), robot(3.0, -0.25, 0.5)];
        let p = choose_pattern(&src, &robots, &settings(), None);
        let arr = |g: &Point2<f64>| Point3::new(g.x, g.y, 0.5);
        let theta = angle_at_deg(&src, &arr(&p.spots[0]), &arr(&p.spots[1]));
        assert!((theta - 90.0).abs() < 1e-6, "3D θ {theta}");
    }

    /// `corner-start-3` seed 8 at 13.7 s: the walker, predicted at (4.64,
    /// 2.77), walks east away from three robots west of it. By travel alone
    /// the pioneer (heading 62°) is sent south, behind itself (a turn of
    /// about 150° before it drives); with the turns counted (0.8 m/s,
    /// 120°/s) every robot's spot lies ahead of it, for a little more travel.
    #[test]
    fn counted_turns_send_robots_ahead_of_themselves() {
        let src = Point3::new(4.64, 2.77, 1.6);
        let r = |x: f64, y: f64, deg: f64| PatternRobot {
            heading_rad: Some(deg.to_radians()),
            ..robot(x, y, 0.5)
        };
        let robots = [r(3.60, 3.04, 62.0), r(0.91, 3.90, -88.0), r(2.02, 4.26, 21.0)];
        let ahead = |p: &TargetPattern| -> Vec<bool> {
            robots
                .iter()
                .zip(&p.spots)
                .map(|(r, g)| {
                    let d = g - r.base_xy;
                    wrap(d.y.atan2(d.x) - r.heading_rad.unwrap()).abs() < std::f64::consts::FRAC_PI_2
                })
                .collect()
        };
        let by_travel = choose_pattern(&src, &robots, &settings(), None);
        assert_eq!(ahead(&by_travel), [false, true, true], "{by_travel:?}");
        let counted =
            |r: &PatternRobot| PatternRobot { turn_cost_m_per_rad: 0.8 / 120f64.to_radians(), ..r.clone() };
        let turning: Vec<PatternRobot> = robots.iter().map(counted).collect();
        let by_time = choose_pattern(&src, &turning, &settings(), None);
        assert_eq!(ahead(&by_time), [true, true, true], "{by_time:?}");
        assert!(by_time.travel_m > by_travel.travel_m, "{by_time:?} vs {by_travel:?}");
        // Without headings the cost is travel alone, whatever the weight.
        let blind = |r: &PatternRobot| PatternRobot { heading_rad: None, ..r.clone() };
        assert_eq!(
            choose_pattern(&src, &turning.iter().map(blind).collect::<Vec<_>>(), &settings(), None),
            choose_pattern(&src, &robots.iter().map(blind).collect::<Vec<_>>(), &settings(), None)
        );
    }

    /// Costs compare times: of two robots, the slow one takes the spot
    /// nearer to it even when giving it to the fast one would be less
    /// travel in all.
    #[test]
    fn a_slow_robot_takes_the_nearer_spot() {
        let src = Point3::new(0.0, 0.0, 0.5);
        // Spots are 2 m out at two bearings 90° apart; A sits near the first
        // slot ring, B a little beyond, both on the same side.
        let a = robot(1.9, 0.3, 0.5);
        let b = robot(2.6, 0.0, 0.5);
        let even = choose_pattern(&src, &[a.clone(), b.clone()], &settings(), None);
        let slow_b = PatternRobot { travel_scale: 4.0, ..b.clone() };
        let uneven = choose_pattern(&src, &[a.clone(), slow_b], &settings(), None);
        let travel = |p: &TargetPattern, r: &PatternRobot, i: usize| (p.spots[i] - r.base_xy).norm();
        // Equal speeds: the least travel in all.
        assert!(even.travel_m <= uneven.travel_m + 1e-9, "{even:?} vs {uneven:?}");
        // B four times slower: it drives less than before, A more.
        assert!(travel(&uneven, &b, 1) < travel(&even, &b, 1) - 0.05, "{even:?} vs {uneven:?}");
        assert!(travel(&uneven, &a, 0) > travel(&even, &a, 0), "{even:?} vs {uneven:?}");
    }
}

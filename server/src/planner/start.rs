//! Planning before any position is published: start from what robots hear.
//!
//! The Fisher-information planner needs a source estimate; until one exists
//! (fewer than two robots hear the source, or their rays do not make a usable
//! triangulation) this module moves the robots so that one soon does:
//!
//! 1. **Source hypothesis** `S`: a recent estimate (even an untrusted one) when
//!    there is one; else the crossing of two heard bearing lines when they cross
//!    at ≥ 20° in front of both robots; else a point on the best-heard line
//!    (most active DoA) at an *assumed range* — half the distance at which the
//!    line leaves the room, clamped to [`MIN_ASSUMED_RANGE_M`, `MAX_ASSUMED_RANGE_M`].
//!    The range along one line is unobservable; half the room's depth along it
//!    is the median of a source uniformly placed on the line inside the room.
//! 2. **Spread across the bearing**: the other robots (the deaf ones first)
//!    go to the slots of the fan pattern around `S` relative to the hearer's
//!    bearing — offsets k·180°/N (90° for two robots) at the preferred range.
//!    Such a spot lies `preferred_range_m · sin(offset)` away from the heard
//!    line, so it keeps that distance to the source wherever on the line it
//!    really is (the keep-out holds whatever the range error), and its own ray
//!    crosses the heard line at the offset angle. The side (± offsets) is the
//!    one with the least travel. A spot within [`OPEN_MARGIN_M`] of a wall or
//!    obstacle is replaced by the most open free spot near it (bearing ± 60°,
//!    range ± 1 m around the slot): a robot near walls hears the reflections as
//!    loudly as the direct path, which is why it may be deaf.
//! 3. **Approach along the bearing** where the direct-to-reverberant ratio is
//!    poor: the hearer moves towards `S` while the assumed range exceeds the
//!    preferred range by more than 1 m, to a spot beside its line (keep-out
//!    radius + [`APPROACH_OFFSET_M`] from it, on the more open side): the
//!    source lies somewhere on that line, so the goal keeps the keep-out
//!    whatever the true range, and the move adds baseline across the line. In a room the direct and reverberant
//!    energies are equal at the critical distance r_c ≈ 0.057·√(V/RT60)
//!    (1.2 m for 240 m³ at 0.5 s); at 4 m the direct path is ≈ 10 dB under the
//!    reverberation and DoAs come and go. Each step is at most 1 m and at most
//!    a quarter of the assumed range, so that even when `S` is twice too far
//!    the robot stays outside the keep-out radius before the next cycle re-plans.
//! 4. **Nobody hears**: robots explore the free space on a ring of
//!    [`EXPLORE_SLOTS`] spots around the room's centroid, radius 30 % of the
//!    room's smaller side (at least 1 m), each spot moved to the most open free
//!    spot near it. Robots start at slots spread evenly round the ring (the
//!    slot nearest each robot for the first), and each advances one slot
//!    counter-clockwise when it arrives; a robot whose position is unknown (it
//!    has never been heard) is sent to its slot all the same. Exploring starts
//!    only after [`QUIET_BEFORE_EXPLORING_S`] without any robot hearing, so that
//!    robots just connected, or a talker's pause, do not send everyone away.
//!
//! A goal is not re-sent when the robot already drives to a spot within
//! [`RESEND_DISTANCE_M`] of it or stands there.

use std::collections::BTreeMap;
use std::f64::consts::PI;

use nalgebra::{Isometry3, Point2, Point3, Unit, Vector2, Vector3};
use soundmap_proto::RobotId;

use super::assignment::assign;
use super::free_space::FreeSpace;
use super::pose::{facing_pose, unit, wrap};

/// Shortest assumed range along a single heard line (m).
pub const MIN_ASSUMED_RANGE_M: f64 = 2.0;
/// Longest assumed range along a single heard line (m).
pub const MAX_ASSUMED_RANGE_M: f64 = 5.0;
/// A spot this close to a wall or obstacle is not open (m).
pub const OPEN_MARGIN_M: f64 = 1.0;
/// Spots on the exploration ring.
pub const EXPLORE_SLOTS: usize = 8;
/// An approach goal lies this far beyond the keep-out radius beside the heard line (m).
pub const APPROACH_OFFSET_M: f64 = 0.5;
/// Nobody must hear for this long before the robots explore (s).
pub const QUIET_BEFORE_EXPLORING_S: f64 = 3.0;
/// A goal this close to the robot's current goal or position is not re-sent (m).
pub const RESEND_DISTANCE_M: f64 = 0.5;

/// A bearing a robot hears: its most active DoA, as a ray in the map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Heard {
    /// Array centre (map, m).
    pub origin_in_map: Point3<f64>,
    /// Unit direction towards the source (map).
    pub direction_in_map: Unit<Vector3<f64>>,
    /// The DoA's activity in [0, 1].
    pub activity: f64,
}

/// A robot as planning-from-bearings sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct StartRobot {
    /// Robot id.
    pub id: RobotId,
    /// Base position (map xy, m); `None` when the robot has never sent a pose.
    pub base_xy: Option<Point2<f64>>,
    /// What it hears now, if anything.
    pub heard: Option<Heard>,
    /// The goal it is driving to, if any (map xy, m).
    pub active_goal: Option<Point2<f64>>,
}

/// A goal of planning from bearings, with the operator's reason.
#[derive(Clone, Debug, PartialEq)]
pub struct StartGoal {
    /// The robot.
    pub robot_id: RobotId,
    /// Goal pose of the base (map).
    pub map_from_base: Isometry3<f64>,
    /// Where the robot should face on arrival (map, m).
    pub look_at_in_map: Point3<f64>,
    /// Why, for operators ("no position yet: …").
    pub why: String,
}

/// What planning from bearings decided.
#[derive(Clone, Debug, PartialEq)]
pub enum StartPlan {
    /// Goals to send (possibly none: everyone is where it should be).
    Goals(Vec<StartGoal>),
    /// Nothing to do, and why.
    Hold(String),
}

/// Settings taken from the planner's configuration.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StartSettings {
    pub preferred_range_m: f64,
    pub min_range_m: f64,
    pub min_separation_m: f64,
    pub array_height_m: f64,
}

/// Exploration memory: each robot's current ring slot, and since when nobody hears.
#[derive(Clone, Debug, Default)]
pub(crate) struct Explore {
    slots: BTreeMap<RobotId, usize>,
    quiet_since_s: Option<f64>,
}

impl Explore {
    /// Forgets the ring (a source was heard).
    pub fn clear(&mut self) {
        self.slots.clear();
        self.quiet_since_s = None;
    }
}

/// The source hypothesis and the line it was drawn from.
struct Hypothesis {
    source: Point3<f64>,
    /// Index of the robot whose bearing anchors the pattern.
    anchor: usize,
    /// How `source` was obtained, for the operator.
    how: String,
    /// Assumed range from the anchor when the range is a guess (m).
    assumed_range_m: Option<f64>,
}

/// One cycle of planning from bearings (see the module doc). `hint` is a
/// recent, possibly untrusted, source position; `now_s` any monotonic clock (s).
pub(crate) fn plan(
    now_s: f64,
    free: &FreeSpace,
    s: &StartSettings,
    explore: &mut Explore,
    robots: &[StartRobot],
    hint: Option<Point3<f64>>,
) -> StartPlan {
    if robots.is_empty() {
        return StartPlan::Hold("no robot to move".into());
    }
    let Some(h) = hypothesis(free, robots, hint) else {
        let since = *explore.quiet_since_s.get_or_insert(now_s);
        if now_s - since < QUIET_BEFORE_EXPLORING_S {
            return StartPlan::Hold(format!("nobody hears the source yet ({:.1} s)", now_s - since));
        }
        return StartPlan::Goals(explore_goals(free, s, explore, robots));
    };
    explore.clear();
    let mut goals = Vec::new();
    let anchor = &robots[h.anchor];
    let centre = Point2::new(h.source.x, h.source.y);
    let anchor_xy = anchor.base_xy.unwrap_or(centre);
    if let Some(r) = h.assumed_range_m
        && r > s.preferred_range_m + 1.0
    {
        let advance = (r - s.preferred_range_m).min(1.0).min(0.25 * r);
        let dir = (centre - anchor_xy).normalize();
        let side = Vector2::new(-dir.y, dir.x) * (s.min_range_m + APPROACH_OFFSET_M);
        // Beside the line, on the more open side: never on the line the source is on.
        let spot = [1.0, -1.0]
            .map(|k| anchor_xy + dir * advance + side * k)
            .into_iter()
            .filter(|p| free.is_free(p))
            .max_by(|a, b| free.distance_to_edges(a).total_cmp(&free.distance_to_edges(b)));
        if let Some(spot) = spot {
            let why = format!(
                "no position yet: approaching along its bearing ({}; heard poorly beyond {:.1} m)",
                h.how, s.preferred_range_m
            );
            goals.push((h.anchor, spot, why));
        }
    }
    let others: Vec<usize> = (0..robots.len()).filter(|&i| i != h.anchor).collect();
    let spots = spread_spots(free, s, robots, &h, anchor_xy, &others);
    for (i, spot) in others.iter().zip(spots) {
        let Some(spot) = spot else { continue };
        let r = &robots[*i];
        let state = match (r.heard.is_some(), r.base_xy) {
            (false, Some(p)) if free.distance_to_edges(&p) <= OPEN_MARGIN_M + 1e-6 => {
                "hears nothing near a wall"
            }
            (false, _) => "hears nothing",
            (true, _) => "hears it too",
        };
        let why = format!(
            "no position yet: spreading across the bearing from {} at ({:.1}, {:.1}) ({}; {} {state})",
            anchor.id, anchor_xy.x, anchor_xy.y, h.how, r.id
        );
        goals.push((*i, spot, why));
    }
    StartPlan::Goals(finish(robots, goals, &h.source))
}

/// The source hypothesis (see the module doc), or `None` when nobody hears.
fn hypothesis(free: &FreeSpace, robots: &[StartRobot], hint: Option<Point3<f64>>) -> Option<Hypothesis> {
    let heard: Vec<(usize, Heard)> =
        robots.iter().enumerate().filter_map(|(i, r)| Some((i, r.heard?))).collect();
    if let Some(src) = hint {
        // Anchor: the hearer nearest the hint, else the robot nearest it.
        let dist =
            |i: usize| robots[i].base_xy.map_or(f64::INFINITY, |p| (p - Point2::new(src.x, src.y)).norm());
        let anchor = heard
            .iter()
            .map(|(i, _)| *i)
            .min_by(|a, b| dist(*a).total_cmp(&dist(*b)))
            .or_else(|| (0..robots.len()).min_by(|a, b| dist(*a).total_cmp(&dist(*b))))?;
        let how = format!("last estimate ({:.1}, {:.1})", src.x, src.y);
        return Some(Hypothesis { source: src, anchor, how, assumed_range_m: None });
    }
    let (anchor, best) = *heard.iter().max_by(|a, b| a.1.activity.total_cmp(&b.1.activity))?;
    for (j, other) in &heard {
        if *j != anchor
            && let Some(p) = crossing(&best, other)
        {
            let how = format!(
                "bearings of {} and {} cross at ({:.1}, {:.1})",
                robots[anchor].id, robots[*j].id, p.x, p.y
            );
            return Some(Hypothesis { source: p, anchor, how, assumed_range_m: None });
        }
    }
    let o = best.origin_in_map;
    let d = horizontal(&best.direction_in_map)?;
    let exit = exit_distance(free, &Point2::new(o.x, o.y), &d);
    let range = (0.5 * exit).clamp(MIN_ASSUMED_RANGE_M, MAX_ASSUMED_RANGE_M);
    let z = o.z + best.direction_in_map.z / best.direction_in_map.xy().norm().max(0.2) * range;
    let source = Point3::new(o.x + d.x * range, o.y + d.y * range, z.clamp(0.0, 2.5));
    let how = format!("range unknown, assumed {range:.1} m");
    Some(Hypothesis { source, anchor, how, assumed_range_m: Some(range) })
}

/// Horizontal unit direction of a ray, unless it points (nearly) straight up or down.
fn horizontal(d: &Unit<Vector3<f64>>) -> Option<Vector2<f64>> {
    let h = Vector2::new(d.x, d.y);
    (h.norm() > 0.2).then(|| h.normalize())
}

/// Where two heard lines cross in plan view, when they cross at ≥ 20° and
/// in front of both arrays (and not more than 12 m away).
fn crossing(a: &Heard, b: &Heard) -> Option<Point3<f64>> {
    let (da, db) = (horizontal(&a.direction_in_map)?, horizontal(&b.direction_in_map)?);
    let det = da.x * (-db.y) - da.y * (-db.x);
    if det.abs() < 20f64.to_radians().sin() {
        return None;
    }
    let w = b.origin_in_map.xy() - a.origin_in_map.xy();
    let ta = (w.x * (-db.y) - w.y * (-db.x)) / det;
    let tb = (da.x * w.y - da.y * w.x) / det;
    if !(0.3..=12.0).contains(&ta) || !(0.3..=12.0).contains(&tb) {
        return None;
    }
    let p = a.origin_in_map.xy() + da * ta;
    let slope = |h: &Heard| h.direction_in_map.z / h.direction_in_map.xy().norm();
    let z = 0.5 * (a.origin_in_map.z + slope(a) * ta + b.origin_in_map.z + slope(b) * tb);
    Some(Point3::new(p.x, p.y, z.clamp(0.0, 2.5)))
}

/// Distance along `d` from `o` at which the line leaves the room (m, ≤ 12).
fn exit_distance(free: &FreeSpace, o: &Point2<f64>, d: &Vector2<f64>) -> f64 {
    let Some(room) = free.room() else { return 2.0 * MAX_ASSUMED_RANGE_M };
    let mut t = 0.0;
    while t < 12.0 {
        if !super::free_space::contains(room, &(o + d * (t + 0.1))) {
            break;
        }
        t += 0.1;
    }
    t
}

/// Spots for `others` around the hypothesis: fan slots relative to the anchor's bearing.
fn spread_spots(
    free: &FreeSpace,
    s: &StartSettings,
    robots: &[StartRobot],
    h: &Hypothesis,
    anchor_xy: Point2<f64>,
    others: &[usize],
) -> Vec<Option<Point2<f64>>> {
    let n = others.len();
    if n == 0 {
        return vec![];
    }
    let centre = Point2::new(h.source.x, h.source.y);
    let a = anchor_xy - centre;
    let phi = if a.norm() > 1e-6 { a.y.atan2(a.x) } else { 0.0 };
    let step = PI / (n + 1) as f64;
    let mut best: Option<(f64, Vec<Option<Point2<f64>>>)> = None;
    for sign in [1.0, -1.0] {
        // Each slot keeps the separation from the anchor and the slots before it.
        let mut taken = vec![anchor_xy];
        let slots: Vec<Option<Point2<f64>>> = (1..=n)
            .map(|k| {
                let spot = open_spot_near(free, s, &centre, wrap(phi + sign * k as f64 * step), &taken);
                taken.extend(spot);
                spot
            })
            .collect();
        let mut cost = vec![0.0; n * n];
        for (i, r) in others.iter().enumerate() {
            for (j, slot) in slots.iter().enumerate() {
                cost[i * n + j] = match (slot, robots[*r].base_xy) {
                    (None, _) => 1e3,
                    (Some(g), Some(p)) => (g - p).norm(),
                    (Some(_), None) => 0.0,
                };
            }
        }
        let (slot_of, total) = assign(&cost, n);
        if best.as_ref().is_none_or(|b| total < b.0) {
            best = Some((total, slot_of.iter().map(|&j| slots[j]).collect()));
        }
    }
    let mut spots = best.map(|b| b.1).unwrap_or_default();
    // Keep goals apart: a later spot too close to an earlier one is dropped.
    for k in 1..spots.len() {
        if let Some(p) = spots[k]
            && spots[..k].iter().flatten().any(|q| (p - q).norm() < s.min_separation_m)
        {
            spots[k] = None;
        }
    }
    spots
}

/// The most open free spot near the slot at bearing `phi` and the preferred
/// range around `centre`: ± 60° in 10° steps, range ± 1 m in 0.5 m steps (never
/// inside the keep-out radius + 0.5 m), at least the separation from `avoid`.
/// Spots at least [`OPEN_MARGIN_M`] from every edge win, nearest the slot first;
/// else the free spot farthest from the edges.
fn open_spot_near(
    free: &FreeSpace,
    s: &StartSettings,
    centre: &Point2<f64>,
    phi: f64,
    avoid: &[Point2<f64>],
) -> Option<Point2<f64>> {
    let ideal = centre + unit(phi) * s.preferred_range_m;
    let mut best: Option<(f64, Point2<f64>)> = None;
    for dk in -6i32..=6 {
        for dr in [0.0, -0.5, 0.5, -1.0, 1.0] {
            let r = s.preferred_range_m + dr;
            if r < s.min_range_m + 0.5 {
                continue;
            }
            let p = centre + unit(phi + (dk as f64 * 10.0).to_radians()) * r;
            if !free.is_free(&p) || avoid.iter().any(|q| (p - q).norm() < s.min_separation_m) {
                continue;
            }
            let open = free.distance_to_edges(&p).min(OPEN_MARGIN_M);
            // Openness first (in 0.1 m steps), then nearness to the ideal slot.
            let score = (open / 0.1).floor() * 10.0 - (p - ideal).norm();
            if best.is_none_or(|b| score > b.0) {
                best = Some((score, p));
            }
        }
    }
    best.map(|b| b.1)
}

/// Exploration goals when nobody hears (see the module doc).
fn explore_goals(
    free: &FreeSpace,
    s: &StartSettings,
    explore: &mut Explore,
    robots: &[StartRobot],
) -> Vec<StartGoal> {
    let (centre, radius) = match free.room() {
        Some(room) => {
            let n = room.len() as f64;
            let c = Point2::from(room.iter().map(|p| p.coords).sum::<Vector2<f64>>() / n);
            let (lo, hi) = room.iter().fold((c, c), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
            let side = (hi - lo).x.min((hi - lo).y);
            (c, (0.3 * side).max(1.0))
        }
        None => {
            let known: Vec<Point2<f64>> = robots.iter().filter_map(|r| r.base_xy).collect();
            let n = known.len().max(1) as f64;
            (Point2::from(known.iter().map(|p| p.coords).sum::<Vector2<f64>>() / n), 2.0)
        }
    };
    let slot_spot = |k: usize| {
        let phi = k as f64 * 2.0 * PI / EXPLORE_SLOTS as f64;
        let settings = StartSettings { preferred_range_m: radius, min_range_m: 0.0, ..*s };
        open_spot_near(free, &settings, &centre, phi, &[])
    };
    let mut goals = Vec::new();
    let first = robots.iter().find_map(|r| r.base_xy).map_or(0, |p| {
        let d = p - centre;
        ((d.y.atan2(d.x).rem_euclid(2.0 * PI)) / (2.0 * PI) * EXPLORE_SLOTS as f64).round() as usize
    });
    for (i, r) in robots.iter().enumerate() {
        let start = (first + i * EXPLORE_SLOTS / robots.len()) % EXPLORE_SLOTS;
        let slot = *explore.slots.entry(r.id.clone()).or_insert(start);
        let Some(mut spot) = slot_spot(slot) else { continue };
        if r.base_xy.is_some_and(|p| (p - spot).norm() < RESEND_DISTANCE_M) {
            let next = (slot + 1) % EXPLORE_SLOTS;
            explore.slots.insert(r.id.clone(), next);
            let Some(p) = slot_spot(next) else { continue };
            spot = p;
        }
        let why = format!(
            "nothing heard: exploring the free space (ring spot {} of {EXPLORE_SLOTS} around ({:.1}, {:.1}))",
            explore.slots[&r.id] + 1,
            centre.x,
            centre.y
        );
        goals.push((i, spot, why));
    }
    let look = Point3::new(centre.x, centre.y, s.array_height_m);
    finish(robots, goals, &look)
}

/// Goals facing `look_at`, minus those the robot already drives to or stands at.
fn finish(
    robots: &[StartRobot],
    goals: Vec<(usize, Point2<f64>, String)>,
    look_at: &Point3<f64>,
) -> Vec<StartGoal> {
    goals
        .into_iter()
        .filter(|(i, spot, _)| {
            let r = &robots[*i];
            let near = |p: Point2<f64>| (p - spot).norm() < RESEND_DISTANCE_M;
            !(r.active_goal.is_some_and(near) || (r.active_goal.is_none() && r.base_xy.is_some_and(near)))
        })
        .map(|(i, spot, why)| StartGoal {
            robot_id: robots[i].id.clone(),
            map_from_base: facing_pose(&spot, look_at),
            look_at_in_map: *look_at,
            why,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::free_space::FreeSpaceConfig;

    fn room() -> FreeSpace {
        let cfg = FreeSpaceConfig {
            room: vec![[0.0, 0.0], [10.0, 0.0], [10.0, 8.0], [0.0, 8.0]],
            obstacles: vec![],
        };
        FreeSpace::new(&cfg, 0.35)
    }

    fn settings() -> StartSettings {
        StartSettings { preferred_range_m: 2.0, min_range_m: 1.0, min_separation_m: 0.8, array_height_m: 0.5 }
    }

    fn robot(id: &str, x: f64, y: f64, heard: Option<(f64, f64)>) -> StartRobot {
        StartRobot {
            id: RobotId::parse(id, "id").unwrap(),
            base_xy: Some(Point2::new(x, y)),
            heard: heard.map(|(dx, dy)| Heard {
                origin_in_map: Point3::new(x, y, 0.5),
                direction_in_map: Unit::new_normalize(Vector3::new(dx, dy, 0.2)),
                activity: 0.8,
            }),
            active_goal: None,
        }
    }

    fn goals(p: StartPlan) -> Vec<StartGoal> {
        match p {
            StartPlan::Goals(g) => g,
            StartPlan::Hold(h) => panic!("hold: {h}"),
        }
    }

    fn xy(g: &StartGoal) -> Point2<f64> {
        Point2::new(g.map_from_base.translation.x, g.map_from_base.translation.y)
    }

    #[test]
    fn a_deaf_robot_in_the_corner_spreads_across_the_heard_bearing() {
        // The hearer at (1.6, 1.4) hears along +x+y; the deaf robot sits 1 m from two walls.
        let robots = [robot("deaf", 1.0, 1.0, None), robot("ear", 1.6, 1.4, Some((1.0, 0.8)))];
        let free = room();
        let g = goals(plan(0.0, &free, &settings(), &mut Explore::default(), &robots, None));
        let deaf = g.iter().find(|g| g.robot_id.as_str() == "deaf").expect("deaf robot moved");
        let ear = g.iter().find(|g| g.robot_id.as_str() == "ear").expect("hearer approaches");
        assert!(
            deaf.why.starts_with("no position yet: spreading across the bearing from ear"),
            "{}",
            deaf.why
        );
        assert!(deaf.why.contains("hears nothing near a wall"), "{}", deaf.why);
        // The deaf robot's spot is open and sees the heard line at a good angle.
        let p = xy(deaf);
        assert!(free.distance_to_edges(&p) >= OPEN_MARGIN_M - 1e-9, "{p:?}");
        let d = Vector2::new(1.0, 0.8).normalize();
        let o = Point2::new(1.6, 1.4);
        let off_line = ((p - o).x * d.y - (p - o).y * d.x).abs();
        assert!(off_line > 1.0, "spot {p:?} is {off_line} m from the heard line");
        // The hearer moves at most 1 m along its line, and keeps 1.5 m beside it.
        let q = xy(ear);
        let step = q - o;
        let beside = (step.x * d.y - step.y * d.x).abs();
        assert!(step.dot(&d) > 0.0 && step.dot(&d) <= 1.0 + 1e-9, "{q:?}");
        assert!((beside - 1.5).abs() < 1e-9, "{q:?} is {beside} m beside the line");
        assert!(ear.why.contains("approaching along its bearing"), "{}", ear.why);
    }

    #[test]
    fn crossing_bearings_place_the_source_where_they_meet() {
        // Lines from (1, 1) and (5, 1) towards (3, 4).
        let robots = [robot("a", 1.0, 1.0, Some((2.0, 3.0))), robot("b", 5.0, 1.0, Some((-2.0, 3.0)))];
        let h = hypothesis(&room(), &robots, None).unwrap();
        assert!((h.source.xy() - Point2::new(3.0, 4.0)).norm() < 1e-6, "{:?}", h.source);
        assert!(h.assumed_range_m.is_none());
    }

    #[test]
    fn nobody_hears_so_robots_explore_the_ring_and_advance_on_arrival() {
        let free = room();
        let mut explore = Explore::default();
        let mut robots = [robot("a", 1.0, 1.0, None), robot("b", 1.6, 1.0, None)];
        let quiet = plan(0.0, &free, &settings(), &mut explore, &robots, None);
        assert!(matches!(&quiet, StartPlan::Hold(h) if h.starts_with("nobody hears")), "{quiet:?}");
        let g = goals(plan(3.0, &free, &settings(), &mut explore, &robots, None));
        assert_eq!(g.len(), 2);
        assert!(g.iter().all(|g| g.why.starts_with("nothing heard: exploring")), "{g:?}");
        let (a, b) = (xy(&g[0]), xy(&g[1]));
        assert!((a - b).norm() > 2.0, "robots explore apart: {a:?} {b:?}");
        assert!(g.iter().all(|g| free.distance_to_edges(&xy(g)) >= OPEN_MARGIN_M - 1e-9));
        // Robot a arrives: it is sent on to the next spot; b, driving, is not re-sent.
        robots[0].base_xy = Some(a);
        robots[1].active_goal = Some(b);
        let g2 = goals(plan(4.0, &free, &settings(), &mut explore, &robots, None));
        assert_eq!(g2.len(), 1, "{g2:?}");
        assert!((xy(&g2[0]) - a).norm() > 1.0);
    }

    #[test]
    fn a_robot_never_heard_from_is_still_sent_across_the_bearing() {
        let mut deaf = robot("deaf", 0.0, 0.0, None);
        deaf.base_xy = None;
        let robots = [deaf, robot("ear", 2.0, 2.0, Some((1.0, 0.0)))];
        let g = goals(plan(0.0, &room(), &settings(), &mut Explore::default(), &robots, None));
        assert!(g.iter().any(|g| g.robot_id.as_str() == "deaf"), "{g:?}");
    }
}

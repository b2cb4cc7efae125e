//! Free space in the map's xy plane: a room polygon and obstacle polygons,
//! point tests with clearance, and convex free regions for the QP (theory §3.3,
//! "free-space polytope").
//!
//! A point is *free* when a robot base centred there keeps `clearance_m`
//! (robot radius + margin) from every wall and obstacle edge, is inside the
//! room (when one is given) and outside every obstacle.

use std::fmt;

use nalgebra::{Point2, Vector2};
use serde::Deserialize;

/// Polygons describing free space, map frame xy (m). Vertices in order (either
/// orientation), not repeated at the end; polygons must be simple.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FreeSpaceConfig {
    /// Room outline, `[x, y]` (m). Empty: unbounded (no walls).
    pub room: Vec<[f64; 2]>,
    /// Obstacle outlines, each a list of `[x, y]` (m).
    pub obstacles: Vec<Vec<[f64; 2]>>,
}

/// Why a polygon is unusable.
pub fn polygon_problem(vertices: &[[f64; 2]]) -> Option<String> {
    if vertices.len() < 3 {
        return Some(format!("needs at least 3 vertices, has {}", vertices.len()));
    }
    if let Some(i) = vertices.iter().position(|v| !(v[0].is_finite() && v[1].is_finite())) {
        return Some(format!("vertex {i} is not finite"));
    }
    let p: Vec<Point2<f64>> = vertices.iter().map(|v| Point2::new(v[0], v[1])).collect();
    let n = p.len();
    for i in 0..n {
        for j in (i + 1)..n {
            let adjacent = j == i + 1 || (i == 0 && j == n - 1);
            let (a, b, c, d) = (p[i], p[(i + 1) % n], p[j], p[(j + 1) % n]);
            if adjacent {
                // Adjacent edges share a vertex; they must not fold back onto each other.
                let (u, v) = if j == i + 1 { (a - b, d - c) } else { (b - a, c - d) };
                if cross(&u, &v).abs() <= 1e-12 * u.norm() * v.norm() && u.dot(&v) > 0.0 {
                    return Some(format!("edges {i} and {j} overlap"));
                }
            } else if segments_intersect(&a, &b, &c, &d) {
                return Some(format!("is self-intersecting (edges {i} and {j} cross)"));
            }
        }
    }
    let scale = p.iter().map(|v| v.coords.norm()).fold(1.0, f64::max);
    if signed_area(&p).abs() <= 1e-12 * scale * scale {
        return Some("has zero area".into());
    }
    None
}

/// A closed half-plane `normal · p ≤ offset` in the map's xy plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfPlane {
    /// Outward unit normal.
    pub normal: Vector2<f64>,
    /// Offset (m).
    pub offset: f64,
}

impl HalfPlane {
    /// `normal · p − offset`: ≤ 0 inside (m).
    pub fn violation(&self, p: &Point2<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.offset
    }
}

/// Why a point is not free.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Blocked {
    /// Outside the room polygon.
    OutsideRoom,
    /// Inside the room but closer than the clearance to a wall (distance, m).
    NearWall(f64),
    /// Inside obstacle `index`.
    InsideObstacle(usize),
    /// Closer than the clearance to obstacle `index` (distance, m).
    NearObstacle(usize, f64),
}

impl fmt::Display for Blocked {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Blocked::OutsideRoom => write!(f, "outside the room"),
            Blocked::NearWall(d) => write!(f, "{d:.2} m from a wall"),
            Blocked::InsideObstacle(i) => write!(f, "inside obstacle {i}"),
            Blocked::NearObstacle(i, d) => write!(f, "{d:.2} m from obstacle {i}"),
        }
    }
}

/// Validated free space with a clearance.
#[derive(Clone, Debug)]
pub struct FreeSpace {
    room: Option<Vec<Point2<f64>>>,
    obstacles: Vec<Vec<Point2<f64>>>,
    /// Every edge with its owner (`None` = room), for distances and regions.
    edges: Vec<(Point2<f64>, Point2<f64>, Option<usize>)>,
    clearance_m: f64,
}

impl FreeSpace {
    /// From a config already checked by [`polygon_problem`], with the robot's
    /// clearance (radius + margin, m).
    pub fn new(config: &FreeSpaceConfig, clearance_m: f64) -> Self {
        let to_points = |v: &Vec<[f64; 2]>| v.iter().map(|p| Point2::new(p[0], p[1])).collect::<Vec<_>>();
        let room = (!config.room.is_empty()).then(|| to_points(&config.room));
        let obstacles: Vec<Vec<Point2<f64>>> = config.obstacles.iter().map(to_points).collect();
        let mut edges = Vec::new();
        let mut push = |poly: &[Point2<f64>], owner| {
            for i in 0..poly.len() {
                edges.push((poly[i], poly[(i + 1) % poly.len()], owner));
            }
        };
        if let Some(r) = &room {
            push(r, None);
        }
        for (k, o) in obstacles.iter().enumerate() {
            push(o, Some(k));
        }
        FreeSpace { room, obstacles, edges, clearance_m }
    }

    /// Required distance from walls and obstacles (m).
    pub fn clearance_m(&self) -> f64 {
        self.clearance_m
    }

    /// `None` when `p` is free, else why not.
    pub fn blocked(&self, p: &Point2<f64>) -> Option<Blocked> {
        if let Some(room) = &self.room
            && !contains(room, p)
        {
            return Some(Blocked::OutsideRoom);
        }
        if let Some(k) = self.obstacles.iter().position(|o| contains(o, p)) {
            return Some(Blocked::InsideObstacle(k));
        }
        let mut worst: Option<(f64, Option<usize>)> = None;
        for (a, b, owner) in &self.edges {
            let d = (p - closest_on_segment(a, b, p)).norm();
            if d < self.clearance_m && worst.is_none_or(|w| d < w.0) {
                worst = Some((d, *owner));
            }
        }
        worst.map(|(d, owner)| match owner {
            None => Blocked::NearWall(d),
            Some(k) => Blocked::NearObstacle(k, d),
        })
    }

    /// Whether `p` is free.
    pub fn is_free(&self, p: &Point2<f64>) -> bool {
        self.blocked(p).is_none()
    }

    /// Distance from `p` to the nearest wall or obstacle edge (m); infinite
    /// when the free space has no edges.
    pub fn distance_to_edges(&self, p: &Point2<f64>) -> f64 {
        self.edges
            .iter()
            .map(|(a, b, _)| (p - closest_on_segment(a, b, p)).norm())
            .fold(f64::INFINITY, f64::min)
    }

    /// The room's vertices, when a room is known.
    pub fn room(&self) -> Option<&[Point2<f64>]> {
        self.room.as_deref()
    }

    /// A convex region of free space around a free `seed`, as half-planes
    /// (`None` when the seed is not free). Greedy separating lines: edges in
    /// order of distance; an edge not yet kept `clearance_m` away by a line gets
    /// a line through its closest point, shifted by the clearance. Every point
    /// of the region is then free: the region is disjoint from all edges and
    /// contains a free point, so it lies inside the room and outside obstacles.
    pub fn convex_region(&self, seed: &Point2<f64>) -> Option<Vec<HalfPlane>> {
        if !self.is_free(seed) {
            return None;
        }
        let mut by_distance: Vec<(f64, Point2<f64>, usize)> = self
            .edges
            .iter()
            .enumerate()
            .map(|(k, (a, b, _))| {
                let q = closest_on_segment(a, b, seed);
                ((q - seed).norm(), q, k)
            })
            .collect();
        by_distance.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut planes: Vec<HalfPlane> = Vec::new();
        for (d, q, k) in by_distance {
            let (a, b, _) = &self.edges[k];
            let kept_away = planes.iter().any(|h| {
                h.violation(a) >= self.clearance_m - 1e-9 && h.violation(b) >= self.clearance_m - 1e-9
            });
            if kept_away || d <= 0.0 {
                continue;
            }
            let normal = (q - seed) / d;
            // A nanometre inside, so that the boundary passes `is_free` despite rounding.
            planes.push(HalfPlane { normal, offset: normal.dot(&q.coords) - self.clearance_m - 1e-9 });
        }
        Some(planes)
    }
}

/// Twice-signed area / 2 of a polygon (m²), positive counter-clockwise.
fn signed_area(p: &[Point2<f64>]) -> f64 {
    (0..p.len()).map(|i| cross(&p[i].coords, &p[(i + 1) % p.len()].coords)).sum::<f64>() / 2.0
}

fn cross(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Even–odd point-in-polygon test.
pub(crate) fn contains(poly: &[Point2<f64>], p: &Point2<f64>) -> bool {
    let mut inside = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + n - 1) % n]);
        if (a.y > p.y) != (b.y > p.y) {
            let x = a.x + (p.y - a.y) * (b.x - a.x) / (b.y - a.y);
            if p.x < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// Closest point to `p` on segment `ab`.
pub(crate) fn closest_on_segment(a: &Point2<f64>, b: &Point2<f64>, p: &Point2<f64>) -> Point2<f64> {
    let ab = b - a;
    let len2 = ab.norm_squared();
    if len2 == 0.0 {
        return *a;
    }
    let t = ((p - a).dot(&ab) / len2).clamp(0.0, 1.0);
    a + ab * t
}

/// Whether closed segments `ab` and `cd` share a point.
fn segments_intersect(a: &Point2<f64>, b: &Point2<f64>, c: &Point2<f64>, d: &Point2<f64>) -> bool {
    let o = |p: &Point2<f64>, q: &Point2<f64>, r: &Point2<f64>| cross(&(q - p), &(r - p));
    let on = |p: &Point2<f64>, q: &Point2<f64>, r: &Point2<f64>| {
        r.x >= p.x.min(q.x) && r.x <= p.x.max(q.x) && r.y >= p.y.min(q.y) && r.y <= p.y.max(q.y)
    };
    let (d1, d2, d3, d4) = (o(c, d, a), o(c, d, b), o(a, b, c), o(a, b, d));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    (d1 == 0.0 && on(c, d, a))
        || (d2 == 0.0 && on(c, d, b))
        || (d3 == 0.0 && on(a, b, c))
        || (d4 == 0.0 && on(a, b, d))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
        vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    }

    #[test]
    fn polygon_problems_are_named() {
        assert!(polygon_problem(&square(0.0, 0.0, 1.0, 1.0)).is_none());
        assert!(polygon_problem(&[[0.0, 0.0], [1.0, 0.0]]).unwrap().contains("3 vertices"));
        let bowtie = [[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]];
        assert!(polygon_problem(&bowtie).unwrap().contains("self-intersecting"));
        // Degenerate (all on a line): its last edge runs back over the first.
        assert!(polygon_problem(&[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]).unwrap().contains("overlap"));
        assert!(polygon_problem(&[[0.0, 0.0], [f64::NAN, 0.0], [0.0, 1.0]]).unwrap().contains("finite"));
    }

    #[test]
    fn free_points_respect_walls_obstacles_and_clearance() {
        let cfg = FreeSpaceConfig {
            room: square(0.0, 0.0, 10.0, 6.0),
            obstacles: vec![square(4.0, 2.0, 6.0, 4.0)],
        };
        let fs = FreeSpace::new(&cfg, 0.35);
        assert!(fs.is_free(&Point2::new(2.0, 3.0)));
        assert_eq!(fs.blocked(&Point2::new(11.0, 3.0)), Some(Blocked::OutsideRoom));
        assert_eq!(fs.blocked(&Point2::new(5.0, 3.0)), Some(Blocked::InsideObstacle(0)));
        assert!(
            matches!(fs.blocked(&Point2::new(0.2, 3.0)), Some(Blocked::NearWall(d)) if (d - 0.2).abs() < 1e-12)
        );
        assert!(matches!(fs.blocked(&Point2::new(3.8, 3.0)), Some(Blocked::NearObstacle(0, _))));
    }

    #[test]
    fn convex_region_is_free_everywhere() {
        // An L-shaped room with a triangular obstacle: sample the region densely.
        let room = vec![[0.0, 0.0], [8.0, 0.0], [8.0, 3.0], [3.0, 3.0], [3.0, 7.0], [0.0, 7.0]];
        let cfg = FreeSpaceConfig { room, obstacles: vec![vec![[1.0, 1.0], [2.0, 1.0], [1.5, 2.0]]] };
        let fs = FreeSpace::new(&cfg, 0.3);
        for seed in [Point2::new(0.5, 4.0), Point2::new(5.0, 1.5), Point2::new(2.5, 0.5)] {
            let region = fs.convex_region(&seed).expect("free seed");
            assert!(region.iter().all(|h| h.violation(&seed) <= 0.0));
            let mut inside = 0;
            for i in 0..=160 {
                for j in 0..=140 {
                    let p = Point2::new(i as f64 * 0.05, j as f64 * 0.05);
                    if region.iter().all(|h| h.violation(&p) <= 0.0) {
                        inside += 1;
                        assert!(
                            fs.is_free(&p),
                            "{p:?} in region of {seed:?} but blocked: {:?}",
                            fs.blocked(&p)
                        );
                    }
                }
            }
            assert!(inside > 50, "region around {seed:?} too small ({inside} samples)");
        }
        assert!(fs.convex_region(&Point2::new(1.5, 1.3)).is_none());
    }
}

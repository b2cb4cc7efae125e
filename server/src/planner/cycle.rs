//! One planning cycle's per-robot bounds: where each robot should head this
//! cycle (its target spot, or a via point on the way around the source), the
//! wedge and range bounds of the convex problem, and the separations to keep.
//!
//! A robot too far from its target for one step gets a *via* point: the
//! bearing and range are interpolated from where it is toward the target,
//! as far as 0.9 × step allows, so the robot circles the keep-out disc
//! instead of cutting through it. Range bounds are hard, except that a robot
//! already outside [r_min, r_max] must only make half a step of progress
//! toward the ring (it cannot reach it in one step).

use nalgebra::{Point2, Vector2};

use super::free_space::{FreeSpace, HalfPlane};
use super::pose::{unit, wrap};

/// Bounds of one robot in one cycle.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct CycleRobot {
    /// Current base position (m, map xy).
    pub p0: Point2<f64>,
    /// Where it heads this cycle: free, within 0.9 step, in its wedge (m, map xy).
    pub target: Point2<f64>,
    /// Wedge centre bearing around the source (rad).
    pub wedge_center_rad: f64,
    /// Wedge half-width (rad).
    pub wedge_half_rad: f64,
    /// Smallest horizontal range from the source this cycle (m).
    pub range_lo: f64,
    /// Largest horizontal range from the source this cycle (m).
    pub range_hi: f64,
    /// Largest move (m).
    pub step: f64,
    /// Convex free region containing `target`.
    pub region: Vec<HalfPlane>,
}

/// A separation to keep between robots `i` and `j` this cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Separation {
    /// First robot.
    pub i: usize,
    /// Second robot.
    pub j: usize,
    /// Unit direction from j to i, linearised at the current positions.
    pub eta: Vector2<f64>,
    /// Required distance (m): min(d_sep, current + step) for robots already too close.
    pub min_m: f64,
}

/// Range bounds for a robot currently at range `rho0`.
pub(crate) fn range_bounds(rho0: f64, r_min: f64, r_max: f64, step: f64) -> (f64, f64) {
    let lo = if rho0 >= r_min { r_min } else { r_min.min(rho0 + 0.5 * step) };
    let hi = if rho0 <= r_max { r_max } else { r_max.max(rho0 - 0.5 * step) };
    (lo, hi)
}

/// Point at bearing `phi` and range `rho` around `centre`.
pub(crate) fn polar(centre: &Point2<f64>, phi: f64, rho: f64) -> Point2<f64> {
    centre + unit(phi) * rho
}

/// This cycle's heading point and wedge bearing for a robot at `p0` whose
/// target is at bearing `phi_t`, range `rho_t` around `centre`.
pub(crate) fn via_point(
    centre: &Point2<f64>,
    p0: &Point2<f64>,
    phi_t: f64,
    rho_t: f64,
    bounds: (f64, f64),
    step: f64,
) -> (Point2<f64>, f64) {
    let target = polar(centre, phi_t, rho_t);
    let reach = 0.9 * step;
    if (target - p0).norm() <= reach {
        return (target, phi_t);
    }
    let d = p0 - centre;
    let rho0 = d.norm();
    if rho0 < 1e-9 {
        // On top of the source: straight out toward the target bearing.
        return (polar(centre, phi_t, reach), phi_t);
    }
    let phi0 = d.y.atan2(d.x);
    if rho0 < bounds.0 || rho0 > bounds.1 {
        // Outside the ring: radial progress first.
        let rho = rho0 + (rho_t - rho0).clamp(-reach, reach);
        return (polar(centre, phi0, rho), phi0);
    }
    let delta = wrap(phi_t - phi0);
    let at = |f: f64| polar(centre, phi0 + f * delta, rho0 + f * (rho_t - rho0));
    // Largest fraction f whose point is within reach (bisection; the chord
    // grows with f for |Δφ| ≤ π).
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if (at(mid) - p0).norm() <= reach { lo = mid } else { hi = mid }
    }
    (at(lo), wrap(phi0 + lo * delta))
}

/// The free spot nearest to `want` with bearing within `half` of `center`
/// (rad), range in `bounds` and within `reach` of `from` (when given).
pub(crate) fn nearest_free_in_wedge(
    free: &FreeSpace,
    centre: &Point2<f64>,
    want: &Point2<f64>,
    center: f64,
    half: f64,
    bounds: (f64, f64),
    from_reach: Option<(&Point2<f64>, f64)>,
) -> Option<Point2<f64>> {
    let (lo, hi) = bounds;
    let n_b = ((2.0 * half) / 1f64.to_radians()).ceil().max(1.0) as usize;
    let n_r = ((hi - lo) / 0.05).ceil().max(1.0) as usize;
    let mut best: Option<(f64, Point2<f64>)> = None;
    for a in 0..=n_b {
        let phi = center - half + 2.0 * half * a as f64 / n_b as f64;
        for k in 0..=n_r {
            let rho = lo + (hi - lo) * k as f64 / n_r as f64;
            let q = polar(centre, phi, rho);
            if from_reach.is_some_and(|(p, r)| (q - p).norm() > r) {
                continue;
            }
            let d = (q - want).norm();
            if best.is_none_or(|b| d < b.0) && free.is_free(&q) {
                best = Some((d, q));
            }
        }
    }
    best.map(|b| b.1)
}

/// Separations to keep this cycle between robots at `p0` (pairs that could
/// come closer than `d_sep` within one step each; `steps` per robot).
pub(crate) fn separations(
    p0: &[Point2<f64>],
    targets: &[Point2<f64>],
    d_sep: f64,
    steps: &[f64],
) -> Vec<Separation> {
    let mut out = Vec::new();
    for i in 0..p0.len() {
        for j in (i + 1)..p0.len() {
            let d = p0[i] - p0[j];
            let dist = d.norm();
            // Both move at most their steps; `step` is their mean, so that
            // equal steps keep the pair's old bounds exactly.
            let step = 0.5 * (steps[i] + steps[j]);
            if dist > d_sep + 2.0 * step + 1e-6 || d_sep <= 0.0 {
                continue;
            }
            let eta = if dist > 1e-6 {
                d / dist
            } else {
                let t = targets[i] - targets[j];
                if t.norm() > 1e-6 { t.normalize() } else { Vector2::x() }
            };
            out.push(Separation { i, j, eta, min_m: d_sep.min(dist + step) });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn via_point_circles_the_source_within_reach() {
        let c = Point2::origin();
        let p0 = Point2::new(2.0, 0.0);
        // Target on the far side: the via point is one reach along the arc.
        let (v, psi) = via_point(&c, &p0, std::f64::consts::PI, 2.0, (1.0, 5.0), 1.0);
        assert!(((v - p0).norm() - 0.9).abs() < 1e-6, "{v:?}");
        assert!(((v - c).norm() - 2.0).abs() < 1e-9 && psi.abs() > 0.3);
        // Target within reach: it is the heading point.
        let (v, _) = via_point(&c, &p0, 0.3, 2.0, (1.0, 5.0), 1.0);
        assert!((v - polar(&c, 0.3, 2.0)).norm() < 1e-12);
        // Far outside r_max: radial progress first.
        let (v, psi) = via_point(&c, &Point2::new(8.0, 0.0), 1.0, 2.0, range_bounds(8.0, 1.0, 5.0, 1.0), 1.0);
        assert!((v - Point2::new(7.1, 0.0)).norm() < 1e-9 && psi == 0.0);
    }

    #[test]
    fn the_keep_outs_path_runs_back_to_the_fix() {
        let plain = KeepOut::new(Point2::new(0.0, 0.0), Point2::new(1.0, 0.0), 1.0);
        let fixed = KeepOut { fix: Point2::new(0.0, -1.0), ..plain };
        // Ahead and beside the forward segment: the same.
        for q in [Point2::new(2.0, 0.0), Point2::new(0.5, 1.0)] {
            assert_eq!(plain.clearance(&q), fixed.clearance(&q));
        }
        // Behind the track, towards the fix: nearer the back segment.
        let q = Point2::new(0.5, -1.0);
        assert!((plain.clearance(&q) - 1.0).abs() < 1e-12);
        assert!((fixed.clearance(&q) - 0.5).abs() < 1e-12);
        assert_eq!(fixed.nearest_on_path(&q), Point2::new(0.0, -1.0));
    }

    #[test]
    fn range_bounds_relax_only_outside_the_ring() {
        assert_eq!(range_bounds(3.0, 1.0, 5.0, 1.0), (1.0, 5.0));
        assert_eq!(range_bounds(0.2, 1.0, 5.0, 1.0), (0.7, 5.0));
        assert_eq!(range_bounds(8.0, 1.0, 5.0, 1.0), (1.0, 7.5));
    }
}

/// The keep-out around a moving source: every point within `radius_m` of the
/// segment from where the source is estimated now to where it is predicted
/// `source_lead_s` ahead (the planning centre). A disc around the predicted
/// point alone would let a goal lie next to a walker that has not got there
/// yet (1 m ahead at 1 m/s, as far as the keep-out radius).
///
/// The path also runs back from the estimate to `fix`, the newest
/// instantaneous triangulation of the robots' rays (where there is one; else
/// `fix` is `now`): a filter following a walker lags it by up to half a
/// metre after a turn or a pause, while the rays already point at where the
/// walker is (see `SourceEstimate::fix_in_map`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct KeepOut {
    /// The source now (map xy, m).
    pub now: Point2<f64>,
    /// The source predicted (map xy, m).
    pub ahead: Point2<f64>,
    /// The newest triangulation of the rays (map xy, m; `now` when none).
    pub fix: Point2<f64>,
    /// Keep-out radius, r_min (m).
    pub radius_m: f64,
}

impl KeepOut {
    /// The keep-out of a source at `now` predicted at `ahead`, without a fix.
    pub const fn new(now: Point2<f64>, ahead: Point2<f64>, radius_m: f64) -> Self {
        KeepOut { now, ahead, fix: now, radius_m }
    }

    /// The point of the source's path (fix, now, ahead) nearest `q` (map xy, m).
    pub fn nearest_on_path(&self, q: &Point2<f64>) -> Point2<f64> {
        let on_segment = |a: Point2<f64>, b: Point2<f64>| {
            let d = b - a;
            let len2 = d.norm_squared();
            let t = if len2 > 0.0 { ((q - a).dot(&d) / len2).clamp(0.0, 1.0) } else { 0.0 };
            a + d * t
        };
        let forward = on_segment(self.now, self.ahead);
        if self.fix == self.now {
            return forward;
        }
        let back = on_segment(self.now, self.fix);
        if (q - back).norm_squared() < (q - forward).norm_squared() { back } else { forward }
    }

    /// Distance from `q` to the source's path (m).
    pub fn clearance(&self, q: &Point2<f64>) -> f64 {
        (q - self.nearest_on_path(q)).norm()
    }

    /// Whether a robot at `from` may go to `to`: outside the keep-out, or, for
    /// a robot already inside it, no nearer the path than it is.
    pub fn allows(&self, from: &Point2<f64>, to: &Point2<f64>) -> bool {
        self.clearance(to) >= self.radius_m.min(self.clearance(from)) - 1e-6
    }
}

//! Triangulation of a source from bearing rays, with honest uncertainty.
//!
//! - [`pair`]: the paper's ray-to-ray closest point and its weighted form;
//! - [`least_squares`]: N rays, iteratively reweighted least squares;
//! - [`lm`]: Levenberg–Marquardt on angular residuals with a robust loss (N ≥ 3).
//!
//! [`triangulate`] picks the estimator (weighted pair for two rays, LS + LM for
//! more, as theory §1.5 recommends), attaches the covariance (inverse Fisher
//! information at the estimate), GDOP, θ and condition number, and decides a
//! gate. Geometries that give no point are [`Triangulation::Degenerate`]
//! outcomes, never errors and never NaN. Rays from planar arrays on ground
//! robots ([`Ray::fold`]) are fitted on what those arrays measure (LM residuals
//! against the folded, floor-image-pulled direction); with two such rays the
//! closed-form pair point is the start of that fit.
//!
//! Folded rays from arrays at one height cannot tell a source above their
//! plane from its mirror below it; a fit that ends below is taken to the
//! upper branch ([`crate::floor_image`], "The fold's two branches").
//!
//! Folded rays also say where the room is: each array's floor lies
//! `array_height_m` below it, and its ceiling `ceiling_m` above that floor
//! when `[doa] ceiling_height_m` is configured ([`room_of`]). A point below
//! the floor or above the ceiling by more than [`ROOM_TOLERANCE_M`] plus
//! three of its own vertical σ is gated [`GateReason::OutsideRoom`]: it is
//! published, but not trusted, not planned around and no track starts from
//! it. Nearly parallel rays (seen from above) place their point by their
//! elevations, which near-planar arrays read worst: in the start scenarios
//! such pairs were placed up to 12 m high in a 3 m room.
//!
//! # Warm starts
//!
//! A source is triangulated many times a second from rays that barely move
//! between estimates, so [`triangulate_from`] can start Levenberg–Marquardt
//! from the same source's last position (the coordinator passes its last
//! accepted estimate of the past second, the sound map each source's filter
//! predicted to the rays' stamp) instead of the least-squares point. For
//! folded rays the least-squares point, which ignores the floor's pull, lies
//! centimetres from the fit, and the fit takes four or five iterations from
//! it; from a start a centimetre or two off it takes one fewer. The warm fit
//! is kept only when it converged and passes the gate; otherwise the cold
//! fit runs as before, so a hint that leads nowhere trusted costs time, not
//! the answer. Where the rays' cost holds one minimum near the source, both
//! starts end at it to the fit's tolerance (tens of micrometres), so runs
//! with and without warm starts agree to that, though closed-loop
//! simulations diverge from such differences over time; where it holds
//! two (a coherent wrong ray that the robust loss half-follows), the warm
//! fit stays at the one the source was at. Pairs are fitted cold: their closed form is
//! already a start within the fit's reach. So are straight rays: their
//! least-squares point nearly is their fit, and a start 1.5 cm off cost
//! 1.15× the cold fit for 128 of them (`cargo bench -p soundmap-server
//! --bench server -- --only triangulation`; folded, 0.70–0.81×).

pub mod least_squares;
pub mod lm;
pub mod pair;

use std::fmt;

use nalgebra::Point3;
use serde::Deserialize;

pub use lm::RobustLoss;

use crate::ray::Ray;
use crate::stats::chi2_quantile;
use crate::uncertainty::{GeometryQuality, angle_between_deg, assess, condition_number};

/// Settings of [`triangulate`].
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TriangulationConfig {
    /// A closest point nearer than this along any ray (or behind it) is rejected (m).
    pub min_range_m: f64,
    /// Rays closer than this to parallel give no point (degrees).
    pub min_ray_angle_deg: f64,
    /// Gate: largest accepted condition number κ (2/(1 − |cos θ|) for two rays; 30 ⇔ θ ≈ 21°).
    pub max_condition_number: f64,
    /// Gate: largest accepted predicted RMS error √tr(J⁻¹) (m).
    pub max_rms_m: f64,
    /// Gate: residual χ² is tested at this probability (2N − 3 dof).
    pub residual_probability: f64,
    /// Gate: largest accepted distance from any array to the estimate (m).
    pub max_range_m: f64,
    /// IRLS reweighting passes of the least-squares solve.
    pub reweight_iterations: usize,
    /// Iteration cap of the Levenberg–Marquardt refinement (N ≥ 3); 0 disables it.
    pub lm_max_iterations: usize,
    /// Robust loss of the refinement.
    pub robust_loss: RobustLoss,
    /// Angular σ floor (rad), so that no ray gets infinite weight.
    pub min_sigma_rad: f64,
}

impl Default for TriangulationConfig {
    fn default() -> Self {
        TriangulationConfig {
            min_range_m: 0.3,
            min_ray_angle_deg: 0.5,
            max_condition_number: 30.0,
            max_rms_m: 0.5,
            residual_probability: 0.999,
            max_range_m: 50.0,
            reweight_iterations: 3,
            lm_max_iterations: 50,
            robust_loss: RobustLoss::default(),
            min_sigma_rad: 1e-4,
        }
    }
}

/// Which estimator produced a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Two rays: weighted closest point.
    RayPair,
    /// N rays: IRLS least squares (refinement disabled).
    LeastSquares,
    /// N ≥ 3 rays: LS then Levenberg–Marquardt with a robust loss.
    LevenbergMarquardt,
}

/// Why rays give no point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Degeneracy {
    /// Fewer than two rays.
    TooFewRays {
        /// Rays given.
        count: usize,
    },
    /// The rays are (near) parallel: all pairwise angles below the threshold.
    NearParallel {
        /// Largest angle between two ray directions (degrees).
        ray_angle_deg: f64,
    },
    /// The closest point lies behind (or too close in front of) an array.
    BehindArray {
        /// Index of the ray.
        ray: usize,
        /// Distance along that ray to the point (m); negative is behind.
        along_m: f64,
        /// Largest angle between two ray directions (degrees).
        ray_angle_deg: f64,
    },
}

impl fmt::Display for Degeneracy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Degeneracy::TooFewRays { count } => write!(f, "{count} ray(s): at least 2 needed"),
            Degeneracy::NearParallel { ray_angle_deg } => {
                write!(f, "rays near parallel (angle {ray_angle_deg:.2}°)")
            }
            Degeneracy::BehindArray { ray, along_m, .. } => {
                write!(f, "closest point {along_m:.2} m along ray {ray}: behind or at the array")
            }
        }
    }
}

/// Why the gate rejected a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GateReason {
    /// The geometry is ill-conditioned (θ too small or too close to 180°).
    IllConditioned {
        /// κ found.
        kappa: f64,
        /// Largest accepted.
        max: f64,
    },
    /// The predicted RMS error is too large.
    Uncertain {
        /// √tr(J⁻¹) (m).
        rms_m: f64,
        /// Largest accepted (m).
        max: f64,
    },
    /// The rays disagree more than their noise allows.
    Inconsistent {
        /// Residual χ².
        chi2: f64,
        /// Threshold at the configured probability.
        threshold: f64,
        /// Degrees of freedom.
        dof: usize,
    },
    /// The point is further than any plausible source.
    TooFar {
        /// Largest range from an array (m).
        range_m: f64,
        /// Largest accepted (m).
        max: f64,
    },
    /// The point lies below the floor or above the ceiling that the rays'
    /// floor-image model declares (see [`room_of`]), by more than
    /// [`ROOM_TOLERANCE_M`] and three of its own vertical σ.
    OutsideRoom {
        /// Height of the point above the floor (m).
        height_m: f64,
        /// Height of the ceiling above the floor (m), when declared.
        ceiling_m: Option<f64>,
    },
}

/// How far outside the room a point may lie, beyond three of its vertical σ,
/// before the gate calls it outside (m): sources sit on the floor and under
/// the ceiling (a smoke alarm, a ceiling speaker), and their estimates
/// scatter around them.
pub const ROOM_TOLERANCE_M: f64 = 0.2;

/// The room as folded rays declare it ([`Ray::fold`]): the floor's height in
/// the map frame (the lowest of the rays' arrays' floors) and the ceiling's
/// (the highest), the latter only when every folded ray declares one. `None`
/// when no ray is folded.
pub fn room_of(rays: &[Ray]) -> Option<(f64, Option<f64>)> {
    let mut room: Option<(f64, Option<f64>)> = None;
    for (ray, fold) in rays.iter().filter_map(|r| r.fold.map(|f| (r, f))) {
        let floor = ray.origin_in_map.z - fold.array_height_m;
        let ceiling = fold.ceiling_m.map(|c| floor + c);
        room = Some(match room {
            None => (floor, ceiling),
            Some((f, c)) => (f.min(floor), c.zip(ceiling).map(|(a, b)| a.max(b))),
        });
    }
    room
}

impl fmt::Display for GateReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GateReason::IllConditioned { kappa, max } => {
                write!(f, "ill-conditioned geometry (κ {kappa:.1} > {max})")
            }
            GateReason::Uncertain { rms_m, max } => write!(f, "predicted RMS error {rms_m:.2} m > {max} m"),
            GateReason::Inconsistent { chi2, threshold, dof } => {
                write!(f, "rays inconsistent (χ² {chi2:.1} > {threshold:.1}, {dof} dof)")
            }
            GateReason::TooFar { range_m, max } => write!(f, "range {range_m:.1} m > {max} m"),
            GateReason::OutsideRoom { height_m, ceiling_m: Some(c) } => {
                write!(f, "outside the room: {height_m:.2} m above the floor, ceiling at {c:.2} m")
            }
            GateReason::OutsideRoom { height_m, ceiling_m: None } => {
                write!(f, "outside the room: {height_m:.2} m above the floor")
            }
        }
    }
}

/// The gate's decision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Gate {
    /// The point can be trusted to its covariance.
    Accepted,
    /// The point exists but should not be trusted.
    Rejected(GateReason),
}

/// A triangulated point with its uncertainty.
#[derive(Clone, Debug, PartialEq)]
pub struct Solution {
    /// Estimator used.
    pub method: Method,
    /// Estimated source position, map frame (m).
    pub source_in_map: Point3<f64>,
    /// Covariance, GDOP, θ and ranges at the estimate.
    pub quality: GeometryQuality,
    /// Condition number of the equal-weight normalized LS matrix.
    pub condition_number: f64,
    /// Two rays: distance between their closest points (m).
    pub miss_distance_m: Option<f64>,
    /// Residual χ² (2 rays: the miss-distance statistic).
    pub residual_chi2: f64,
    /// Its degrees of freedom, 2N − 3.
    pub residual_dof: usize,
    /// Gate decision.
    pub gate: Gate,
}

/// Outcome of a triangulation.
#[derive(Clone, Debug, PartialEq)]
pub enum Triangulation {
    /// A point was found (trusted or not: see its gate).
    Solved(Solution),
    /// The rays give no point.
    Degenerate(Degeneracy),
}

impl Triangulation {
    /// The solution, if any.
    pub fn solution(&self) -> Option<&Solution> {
        match self {
            Triangulation::Solved(s) => Some(s),
            Triangulation::Degenerate(_) => None,
        }
    }
}

/// Whether some pair of rays is at least `angle_deg` from parallel: O(N) in the
/// usual case (a pair with the first ray), O(N²) only when all rays are close to it.
fn some_pair_apart(rays: &[Ray], angle_deg: f64) -> bool {
    let cos_max = angle_deg.to_radians().cos();
    let d0 = rays[0].direction_in_map;
    rays[1..].iter().any(|r| d0.dot(&r.direction_in_map) <= cos_max) || max_ray_angle_deg(rays) >= angle_deg
}

/// Largest angle between the directions of any two rays (degrees).
fn max_ray_angle_deg(rays: &[Ray]) -> f64 {
    let mut best: f64 = 0.0;
    for i in 0..rays.len() {
        for j in (i + 1)..rays.len() {
            best = best.max(angle_between_deg(&rays[i].direction_in_map, &rays[j].direction_in_map));
        }
    }
    best
}

/// Triangulates a source from `rays` (at least two, from different arrays).
pub fn triangulate(rays: &[Ray], config: &TriangulationConfig) -> Triangulation {
    triangulate_from(rays, config, None)
}

/// [`triangulate`], warm-started from `hint` (the same source's recent
/// position) when there are three rays or more and some are folded: Levenberg–Marquardt then
/// starts from `hint` instead of the least-squares point. The warm fit is
/// kept only when it converged and the gate accepts it (the point it
/// reaches then is a minimum the rays trust, which the cold start's would
/// be too unless the cost holds two); anything else, or a hint behind an
/// array, falls back to the cold fit, so a stale or wrong hint costs time,
/// never the answer. Pairs are always fitted cold: their closed form is
/// already the best start. See "Warm starts" in the module docs.
pub fn triangulate_from(
    rays: &[Ray],
    config: &TriangulationConfig,
    hint: Option<Point3<f64>>,
) -> Triangulation {
    let n = rays.len();
    if n < 2 {
        return Triangulation::Degenerate(Degeneracy::TooFewRays { count: n });
    }
    let floored: Vec<Ray>;
    let rays = if rays.iter().any(|r| r.sigma_rad < config.min_sigma_rad) {
        floored =
            rays.iter().map(|r| Ray { sigma_rad: r.sigma_rad.max(config.min_sigma_rad), ..*r }).collect();
        &floored[..]
    } else {
        rays
    };
    let min_sin2 = config.min_ray_angle_deg.to_radians().sin().powi(2);
    let folded = rays.iter().any(|r| r.fold.is_some());
    let (method, point, miss, chi2) = if n == 2 {
        let cp = match pair::closest_points(&rays[0], &rays[1]) {
            Some(cp) if cp.sin2 >= min_sin2 => cp,
            _ => {
                return Triangulation::Degenerate(Degeneracy::NearParallel {
                    ray_angle_deg: max_ray_angle_deg(rays),
                });
            }
        };
        let (point, chi2) = pair::weighted_pair_point(&rays[0], &rays[1], &cp);
        if folded && behind(rays, &point, config.min_range_m).is_none() {
            // Folded rays do not point at the source: the closed form is only the
            // start, refined on the floor-image model (crate::floor_image).
            let fit = fit_from(rays, point, RobustLoss::None, config.lm_max_iterations);
            (Method::RayPair, fit.point, Some(cp.miss_m), fit.chi2)
        } else {
            (Method::RayPair, point, Some(cp.miss_m), chi2)
        }
    } else {
        if !some_pair_apart(rays, config.min_ray_angle_deg) {
            return Triangulation::Degenerate(Degeneracy::NearParallel {
                ray_angle_deg: max_ray_angle_deg(rays),
            });
        }
        let Some(ls) = least_squares::weighted_least_squares(rays, config.reweight_iterations) else {
            return Triangulation::Degenerate(Degeneracy::NearParallel {
                ray_angle_deg: max_ray_angle_deg(rays),
            });
        };
        if let Some(d) = behind(rays, &ls, config.min_range_m) {
            return Triangulation::Degenerate(d);
        }
        if let Some(warm) = hint.filter(|_| folded).and_then(|h| warm_fit(rays, h, config)) {
            return warm;
        }
        if config.lm_max_iterations > 0 {
            let fit = fit_from(rays, ls, config.robust_loss, config.lm_max_iterations);
            (Method::LevenbergMarquardt, fit.point, None, fit.chi2)
        } else {
            let chi2 = lm::refine(rays, ls, RobustLoss::None, 0).chi2;
            (Method::LeastSquares, ls, None, chi2)
        }
    };
    if let Some(d) = behind(rays, &point, config.min_range_m) {
        return Triangulation::Degenerate(d);
    }
    Triangulation::Solved(solved(rays, method, point, miss, chi2, config))
}

/// The LM fit from `hint`, as a solution, when it converged in front of
/// every array and the gate accepts it ([`triangulate_from`]).
fn warm_fit(rays: &[Ray], hint: Point3<f64>, config: &TriangulationConfig) -> Option<Triangulation> {
    if config.lm_max_iterations == 0 || !hint.coords.iter().all(|c| c.is_finite()) {
        return None;
    }
    behind(rays, &hint, config.min_range_m).is_none().then_some(())?;
    let fit = fit_from(rays, hint, config.robust_loss, config.lm_max_iterations);
    if !fit.converged || !fit.chi2.is_finite() || behind(rays, &fit.point, config.min_range_m).is_some() {
        return None;
    }
    let s = solved(rays, Method::LevenbergMarquardt, fit.point, None, fit.chi2, config);
    (s.gate == Gate::Accepted).then_some(Triangulation::Solved(s))
}

/// The solution at `point`: its covariance, GDOP, θ, condition number and gate.
fn solved(
    rays: &[Ray],
    method: Method,
    point: Point3<f64>,
    miss: Option<f64>,
    chi2: f64,
    config: &TriangulationConfig,
) -> Solution {
    let n = rays.len();
    let quality = assess(rays, &point);
    let condition_number = if n == 2 {
        condition_number(&[rays[0].direction_in_map, rays[1].direction_in_map])
    } else {
        condition_number(&rays.iter().map(|r| r.direction_in_map).collect::<Vec<_>>())
    };
    let dof = 2 * n - 3;
    let gate = gate(rays, &point, &quality, condition_number, chi2, dof, config);
    Solution {
        method,
        source_in_map: point,
        quality,
        condition_number,
        miss_distance_m: miss,
        residual_chi2: chi2,
        residual_dof: dof,
        gate,
    }
}

/// Levenberg–Marquardt from `start`, then kept on the fold's upper branch
/// ([`upper_branch`]).
fn fit_from(rays: &[Ray], start: Point3<f64>, loss: RobustLoss, iterations: usize) -> lm::LmFit {
    upper_branch(rays, lm::refine(rays, start, loss, iterations), loss, iterations)
}

/// The fit on the fold's upper branch ([`crate::floor_image`], "The fold's
/// two branches"): when every ray is folded from arrays at one height and
/// `fit` lies below the lowest of them, the fit again from its mirror image
/// through their mean height; if that one slides back below, the best the
/// upper side holds is on its edge, and the point is taken there (its
/// height set to the lowest array's, with the χ² it has there). Any other
/// fit is returned as it is.
fn upper_branch(rays: &[Ray], fit: lm::LmFit, loss: RobustLoss, iterations: usize) -> lm::LmFit {
    let arrays = rays.iter().map(|r| (r.origin_in_map.z, r.fold.is_some_and(|f| f.upper_branch)));
    let Some((lowest, plane)) = crate::floor_image::fold_plane(arrays) else { return fit };
    if fit.point.z >= lowest {
        return fit;
    }
    let mirror = Point3::new(fit.point.x, fit.point.y, 2.0 * plane - fit.point.z);
    let refit = lm::refine(rays, mirror, loss, iterations);
    if !refit.chi2.is_finite() {
        return fit; // the mirror image lies behind an array
    }
    if refit.point.z >= lowest {
        return refit;
    }
    let edge = lm::refine(rays, Point3::new(refit.point.x, refit.point.y, lowest), loss, 0);
    if edge.chi2.is_finite() { edge } else { fit }
}

/// [`GateReason::OutsideRoom`] when `p` lies below the rays' floor or above
/// their ceiling by more than [`ROOM_TOLERANCE_M`] plus three of its vertical
/// σ (from `q`'s covariance; none without one).
fn outside_room(rays: &[Ray], p: &Point3<f64>, q: &GeometryQuality) -> Option<GateReason> {
    let (floor, ceiling) = room_of(rays)?;
    let sigma_z = q.covariance.map_or(0.0, |c| c[(2, 2)].max(0.0).sqrt());
    let allowance = ROOM_TOLERANCE_M + 3.0 * sigma_z;
    let below = p.z < floor - allowance;
    let above = ceiling.is_some_and(|c| p.z > c + allowance);
    (below || above)
        .then(|| GateReason::OutsideRoom { height_m: p.z - floor, ceiling_m: ceiling.map(|c| c - floor) })
}

fn behind(rays: &[Ray], p: &Point3<f64>, min_range_m: f64) -> Option<Degeneracy> {
    rays.iter().enumerate().find_map(|(i, r)| {
        let s = r.along(p);
        (s < min_range_m).then(|| Degeneracy::BehindArray {
            ray: i,
            along_m: s,
            ray_angle_deg: max_ray_angle_deg(rays),
        })
    })
}

fn gate(
    rays: &[Ray],
    p: &Point3<f64>,
    q: &GeometryQuality,
    kappa: f64,
    chi2: f64,
    dof: usize,
    c: &TriangulationConfig,
) -> Gate {
    let range_m = rays.iter().map(|r| (p - r.origin_in_map).norm()).fold(0.0, f64::max);
    let threshold = chi2_quantile(dof, c.residual_probability);
    let reason = if range_m > c.max_range_m {
        Some(GateReason::TooFar { range_m, max: c.max_range_m })
    } else if let Some(outside) = outside_room(rays, p, q) {
        Some(outside)
    } else if !(kappa <= c.max_condition_number) {
        Some(GateReason::IllConditioned { kappa, max: c.max_condition_number })
    } else if !(q.rms_m <= c.max_rms_m) {
        Some(GateReason::Uncertain { rms_m: q.rms_m, max: c.max_rms_m })
    } else if !(chi2 <= threshold) {
        Some(GateReason::Inconsistent { chi2, threshold, dof })
    } else {
        None
    };
    reason.map_or(Gate::Accepted, Gate::Rejected)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Unit};

    use super::*;
    use crate::floor_image::three_mic_fold;

    /// A ray from an array 0.5 m above the floor at (x, y) toward `target`,
    /// folded with the given ceiling (or straight).
    fn ray(x: f64, y: f64, target: &Point3<f64>, fold: bool, ceiling_m: Option<f64>) -> Ray {
        let origin = Point3::new(x, y, 0.5);
        Ray {
            origin_in_map: origin,
            direction_in_map: Unit::new_normalize(target - origin),
            sigma_rad: 0.01,
            origin_sigma_m: 0.0,
            fold: fold.then(|| crate::floor_image::FloorFold { ceiling_m, ..three_mic_fold(0.6, None) }),
        }
    }

    /// A folded ray from an array 0.5 m up at (x, y) holding what it measures
    /// (folded, floor-pulled) for `source`.
    fn measured(x: f64, y: f64, source: &Point3<f64>) -> Ray {
        let fold = three_mic_fold(0.6, None);
        let origin = Point3::new(x, y, 0.5);
        let direction = fold.measured_direction(&origin, source).unwrap();
        Ray {
            origin_in_map: origin,
            direction_in_map: direction,
            sigma_rad: 0.01,
            origin_sigma_m: 0.0,
            fold: Some(fold),
        }
    }

    #[test]
    fn a_source_below_arrays_at_one_height_is_placed_above_them() {
        let below = Point3::new(0.3, 0.2, 0.2);
        for rays in [
            vec![measured(3.0, 0.0, &below), measured(0.0, 3.0, &below)],
            vec![measured(3.0, 0.0, &below), measured(0.0, 3.0, &below), measured(-2.5, 1.0, &below)],
        ] {
            let s = triangulate(&rays, &TriangulationConfig::default()).solution().cloned().unwrap();
            let p = s.source_in_map;
            // On the upper side: at most at the mirror image through the
            // arrays' plane (0.8 m); the floor term, exact in these rays, holds
            // no minimum above the plane, so the fit ends on it.
            assert!((0.5..0.85).contains(&p.z), "{} rays: {p}", rays.len());
            assert!((p.xy() - below.xy()).norm() < 0.1, "{p}");
        }
        // A source above them stays where it is.
        let above = Point3::new(0.3, 0.2, 0.8);
        let rays = [measured(3.0, 0.0, &above), measured(0.0, 3.0, &above)];
        let p = triangulate(&rays, &TriangulationConfig::default()).solution().unwrap().source_in_map;
        assert!((p - above).norm() < 0.02, "{p}");
    }

    #[test]
    fn folded_rays_declare_the_room() {
        let t = Point3::new(0.0, 0.0, 1.5);
        let three = Some(3.0);
        assert_eq!(room_of(&[ray(3.0, 0.0, &t, false, None), ray(0.0, 3.0, &t, false, None)]), None);
        assert_eq!(
            room_of(&[ray(3.0, 0.0, &t, true, three), ray(0.0, 3.0, &t, false, None)]),
            Some((0.0, three))
        );
        assert_eq!(
            room_of(&[ray(3.0, 0.0, &t, true, three), ray(0.0, 3.0, &t, true, None)]),
            Some((0.0, None))
        );
        let mut high = ray(0.0, 3.0, &t, true, three);
        high.origin_in_map.z = 1.5; // a base 1 m higher: its floor at 1 m, its ceiling at 4 m
        assert_eq!(room_of(&[ray(3.0, 0.0, &t, true, three), high]), Some((0.0, Some(4.0))));
    }

    #[test]
    fn a_point_above_the_ceiling_or_below_the_floor_is_not_trusted() {
        let cfg = TriangulationConfig::default();
        let at = |z: f64, ceiling_m: Option<f64>| {
            let p = Point3::new(0.0, 0.0, z);
            let rays = [ray(3.0, 0.0, &p, true, ceiling_m), ray(0.0, 3.0, &p, true, ceiling_m)];
            let q = assess(&rays, &p);
            gate(&rays, &p, &q, 2.0, 0.0, 1, &cfg)
        };
        let ceiling = Some(3.0);
        // Inside, and just outside within the tolerance: accepted.
        for z in [0.1, 1.5, 2.95, 3.1, -0.1] {
            assert_eq!(at(z, ceiling), Gate::Accepted, "z {z}");
        }
        match at(4.5, ceiling) {
            Gate::Rejected(r @ GateReason::OutsideRoom { height_m, ceiling_m: Some(c) }) => {
                assert!((height_m - 4.5).abs() < 1e-12 && c == 3.0);
                assert!(
                    r.to_string().contains("outside the room: 4.50 m above the floor, ceiling at 3.00 m"),
                    "{r}"
                );
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(at(-1.0, None), Gate::Rejected(GateReason::OutsideRoom { ceiling_m: None, .. })));
        // Without a declared ceiling, any height above the floor.
        assert_eq!(at(4.5, None), Gate::Accepted);
        // Straight rays declare no room.
        let p = Point3::new(0.0, 0.0, -1.0);
        let rays = [ray(3.0, 0.0, &p, false, None), ray(0.0, 3.0, &p, false, None)];
        assert_eq!(gate(&rays, &p, &assess(&rays, &p), 2.0, 0.0, 1, &cfg), Gate::Accepted);
    }

    #[test]
    fn a_vague_point_keeps_three_of_its_sigma() {
        // σ 0.2 rad 3 m away: a vertical σ of ~0.6 m, so 4.5 m is within 3σ + 0.2 m of a 3 m ceiling.
        let p = Point3::new(0.0, 0.0, 4.5);
        let mut rays = [ray(3.0, 0.0, &p, true, Some(3.0)), ray(0.0, 3.0, &p, true, Some(3.0))];
        for r in &mut rays {
            r.sigma_rad = 0.2;
        }
        let q = assess(&rays, &p);
        let sigma_z = q.covariance.unwrap()[(2, 2)].sqrt();
        assert!(3.0 * sigma_z + ROOM_TOLERANCE_M > 1.5, "σ_z {sigma_z}");
        assert_eq!(outside_room(&rays, &p, &q), None);
    }

    /// Eight folded rays from 3 m around `source`, each turned by a few
    /// mrad so that their fit is not the source itself.
    fn around(source: &Point3<f64>) -> Vec<Ray> {
        (0..8)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / 8.0;
                let mut r = measured(source.x + 3.0 * a.cos(), source.y + 3.0 * a.sin(), source);
                let k = i as f64;
                let wobble = nalgebra::Vector3::new((1.3 * k).sin(), (0.7 * k).cos(), 0.2) * 0.004;
                r.direction_in_map = Unit::new_normalize(r.direction_in_map.into_inner() + wobble);
                r
            })
            .collect()
    }

    #[test]
    fn a_warm_start_ends_where_the_cold_fit_does_and_a_hint_it_cannot_use_changes_nothing() {
        let source = Point3::new(0.3, 0.2, 1.2);
        let rays = around(&source);
        let cfg = TriangulationConfig::default();
        let cold = triangulate(&rays, &cfg).solution().cloned().unwrap();
        assert_eq!(cold.gate, Gate::Accepted);
        let near = cold.source_in_map + nalgebra::Vector3::new(0.01, -0.01, 0.005);
        let warm = triangulate_from(&rays, &cfg, Some(near)).solution().cloned().unwrap();
        assert_eq!(warm.gate, Gate::Accepted);
        assert_eq!(warm.method, Method::LevenbergMarquardt);
        assert!(
            (warm.source_in_map - cold.source_in_map).norm() < 1e-4,
            "{} {}",
            warm.source_in_map,
            cold.source_in_map
        );
        assert!((warm.residual_chi2 - cold.residual_chi2).abs() < 1e-3 * (1.0 + cold.residual_chi2));
        // Behind an array, or not a number: the cold fit, to the bit.
        let behind = Point3::new(source.x + 6.0, source.y, 1.2);
        for hint in [behind, Point3::new(f64::NAN, 0.0, 1.0)] {
            assert_eq!(triangulate_from(&rays, &cfg, Some(hint)), triangulate(&rays, &cfg), "{hint}");
        }
        // Far off (high above the room): the same point either way.
        let far = triangulate_from(&rays, &cfg, Some(Point3::new(0.3, 0.2, 30.0)));
        let far = far.solution().unwrap();
        assert!((far.source_in_map - cold.source_in_map).norm() < 1e-4, "{}", far.source_in_map);
        // Pairs are fitted cold, and so are straight rays.
        assert_eq!(triangulate_from(&rays[..2], &cfg, Some(near)), triangulate(&rays[..2], &cfg));
        let straight: Vec<Ray> = rays.iter().map(|r| Ray { fold: None, ..*r }).collect();
        assert_eq!(triangulate_from(&straight, &cfg, Some(near)), triangulate(&straight, &cfg));
    }

    #[test]
    fn a_warm_start_at_the_minimum_needs_no_iterations_the_cold_start_needs() {
        // With one iteration allowed, the cold fit stops short of the minimum
        // (its least-squares start ignores the floor's pull); from the
        // minimum itself the warm fit is done at once.
        let source = Point3::new(0.3, 0.2, 1.2);
        let rays = around(&source);
        let full = triangulate(&rays, &TriangulationConfig::default()).solution().unwrap().source_in_map;
        let one = TriangulationConfig { lm_max_iterations: 1, ..Default::default() };
        let cold = triangulate(&rays, &one).solution().unwrap().source_in_map;
        let warm = triangulate_from(&rays, &one, Some(full)).solution().unwrap().source_in_map;
        let (cold_off, warm_off) = ((cold - full).norm(), (warm - full).norm());
        assert!(
            warm_off < 1e-6 && cold_off > 10.0 * warm_off.max(1e-7),
            "cold {cold_off} m, warm {warm_off} m off"
        );
    }
}

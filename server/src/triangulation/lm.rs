//! Levenberg–Marquardt refinement on angular residuals with a robust loss (theory §1.5, §1.7).
//!
//! The fit stops at a minimum to what can be measured: when the step it
//! would take is below [`NEGLIGIBLE_STEP_SIGMA`] of the point's own 1-σ in
//! the metric of H (the Gauss–Newton Hessian, the fit's Fisher information),
//! without evaluating that step; or when an accepted step is below a
//! micrometre-scale tolerance; or when no step lowers the cost. Ending
//! folded fits at 10⁻² σ instead (a Newton decrement of 10⁻⁴) was tried and
//! not kept: the start scenarios lost the band more often (BENCHMARKS.md,
//! the paragraphs before and at "Stopping at a negligible step").

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Point3, Vector2, Vector3};
use serde::Deserialize;

use crate::ray::{MIN_RANGE_M, Ray, tangent_basis};

/// Robust loss applied to each ray's Mahalanobis residual ρ (theory §1.7).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RobustLoss {
    /// Plain least squares.
    None,
    /// Huber: quadratic up to ρ = δ, linear beyond.
    Huber {
        /// Threshold δ (σ units).
        delta: f64,
    },
    /// Cauchy: redescending, suited to coherent wrong DoAs such as mirror sources.
    Cauchy {
        /// Scale c (σ units).
        c: f64,
    },
}

impl Default for RobustLoss {
    fn default() -> Self {
        RobustLoss::Cauchy { c: 2.4 }
    }
}

impl RobustLoss {
    /// Loss of a squared residual s = ρ².
    fn cost(self, s: f64) -> f64 {
        match self {
            RobustLoss::None => s,
            RobustLoss::Huber { delta } => {
                let r = s.sqrt();
                if r <= delta { s } else { 2.0 * delta * r - delta * delta }
            }
            RobustLoss::Cauchy { c } => c * c * (s / (c * c)).ln_1p(),
        }
    }

    /// IRLS weight of a squared residual s = ρ² (derivative of the loss w.r.t. s).
    fn weight(self, s: f64) -> f64 {
        match self {
            RobustLoss::None => 1.0,
            RobustLoss::Huber { delta } => {
                let r = s.sqrt();
                if r <= delta { 1.0 } else { delta / r }
            }
            RobustLoss::Cauchy { c } => 1.0 / (1.0 + s / (c * c)),
        }
    }
}

/// A step shorter than this many of the point's own σ ends the refinement.
pub const NEGLIGIBLE_STEP_SIGMA: f64 = 1e-3;

/// Result of a refinement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmFit {
    /// Refined point (map frame).
    pub point: Point3<f64>,
    /// Non-robust χ² of the angular residuals, Σ eᵢᵀWᵢeᵢ (2N − 3 dof under the model).
    pub chi2: f64,
    /// Iterations taken.
    pub iterations: usize,
    /// Whether it stopped at a minimum: a step below [`NEGLIGIBLE_STEP_SIGMA`] or the step tolerance, or no step lowering the cost.
    pub converged: bool,
}

/// Per-ray precomputation: tangent basis of the measured direction.
struct Term {
    b: Matrix2x3<f64>,
}

fn residual(ray: &Ray, term: &Term, x: &Point3<f64>) -> Option<(Vector2<f64>, Vector3<f64>, f64)> {
    let v = x - ray.origin_in_map;
    let r = v.norm();
    // Cheirality: the point must lie in front of the array.
    if !(r > 0.0) || ray.direction_in_map.dot(&v) <= 0.0 {
        return None;
    }
    // A folded ray (planar array on a ground robot) is compared with what that
    // array measures for x, not with the straight direction (crate::floor_image).
    let u = match ray.fold.and_then(|f| f.measured_direction(&ray.origin_in_map, x)) {
        Some(d) => d.into_inner(),
        None => v / r,
    };
    Some((term.b * u, u, r))
}

/// The residual's information matrix W = R⁻¹ at range `r`, R the ray's
/// angular covariance on the term's tangent axes ([`Ray::angular_information`]:
/// σ² on both, more along the vertical for an array that resolves elevation
/// worse).
fn weight(ray: &Ray, term: &Term, r: f64) -> Matrix2<f64> {
    ray.angular_information(&term.b.transpose(), r.max(MIN_RANGE_M))
}

/// Robust cost at x, or `None` if x is behind an array.
fn total_cost(rays: &[Ray], terms: &[Term], x: &Point3<f64>, loss: RobustLoss) -> Option<(f64, f64)> {
    let (mut robust, mut chi2) = (0.0, 0.0);
    for (ray, t) in rays.iter().zip(terms) {
        let (e, _, r) = residual(ray, t, x)?;
        let s = (e.transpose() * weight(ray, t, r) * e)[0];
        robust += loss.cost(s);
        chi2 += s;
    }
    Some((robust, chi2))
}

/// Minimizes Σ ρ(eᵢᵀWᵢeᵢ) with eᵢ = Bᵢᵀ(x − oᵢ)/‖x − oᵢ‖ (for a folded ray,
/// Bᵢᵀh(x) with h what its array measures, [`Ray::fold`]) from `init`. The start must be in
/// front of every array; steps that would cross behind one are refused.
pub fn refine(rays: &[Ray], init: Point3<f64>, loss: RobustLoss, max_iterations: usize) -> LmFit {
    let terms: Vec<Term> = rays
        .iter()
        .map(|r| {
            let (b1, b2) = tangent_basis(&r.direction_in_map);
            Term { b: Matrix2x3::from_rows(&[b1.transpose(), b2.transpose()]) }
        })
        .collect();
    // Folded rays' predictions are interpolated from a table: stop at
    // sub-micrometre steps rather than at machine precision.
    let tolerance = if rays.iter().any(|r| r.fold.is_some()) { 1e-7 } else { 1e-10 };
    let mut x = init;
    let Some((mut cost, mut chi2)) = total_cost(rays, &terms, &x, loss) else {
        return LmFit { point: init, chi2: f64::INFINITY, iterations: 0, converged: false };
    };
    let mut mu = 1e-3;
    let mut converged = false;
    let mut iterations = 0;
    while iterations < max_iterations && !converged {
        iterations += 1;
        let mut h = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for (ray, t) in rays.iter().zip(&terms) {
            // A folded ray's prediction and Bᵀ ∂h/∂x come from one evaluation
            // of the floor-image model (FloorFold::measured_with_jacobian).
            let folded = ray.fold.and_then(|f| f.measured_with_jacobian(&ray.origin_in_map, &x));
            let (e, jac, r) = match folded {
                Some((u, dh)) => (t.b * u.into_inner(), t.b * dh, (x - ray.origin_in_map).norm()),
                None => {
                    let (e, u, r) = residual(ray, t, &x).expect("current point is in front of every array");
                    (e, t.b * (Matrix3::identity() - u * u.transpose()) / r, r)
                }
            };
            let w = weight(ray, t, r);
            let omega = w * loss.weight((e.transpose() * w * e)[0]);
            h += jac.transpose() * omega * jac;
            g += jac.transpose() * omega * e;
        }
        let mut improved = false;
        for _ in 0..12 {
            // Isotropic damping scaled by tr H / 3: unlike Marquardt's diag(H) it
            // does not depend on the map's axes, so the iterates (not only the
            // minimum) turn and move with the scene, converged or not.
            let damped = h + Matrix3::identity() * (mu * h.trace() / 3.0);
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-g))) else {
                mu *= 10.0;
                continue;
            };
            // A step shorter than a thousandth of the point's own 1-σ (in the
            // metric of H, the Fisher information of the fit) changes nothing
            // that can be measured: x is the minimum, and the cost of the
            // candidate is not evaluated.
            if step.dot(&(h * step)) < NEGLIGIBLE_STEP_SIGMA * NEGLIGIBLE_STEP_SIGMA {
                converged = true;
                improved = true;
                break;
            }
            let candidate = x + step;
            match total_cost(rays, &terms, &candidate, loss) {
                Some((c, k)) if c < cost => {
                    converged = step.norm() < tolerance * (1.0 + x.coords.norm());
                    x = candidate;
                    cost = c;
                    chi2 = k;
                    mu = (mu / 3.0).max(1e-12);
                    improved = true;
                    break;
                }
                _ => mu *= 4.0,
            }
        }
        if !improved {
            // No step lowers the cost: x is a minimum to working precision.
            converged = true;
        }
    }
    LmFit { point: x, chi2, iterations, converged }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    fn rays_to(s: Point3<f64>, origins: &[[f64; 3]]) -> Vec<Ray> {
        origins
            .iter()
            .map(|o| {
                let origin = Point3::from(*o);
                Ray {
                    origin_in_map: origin,
                    direction_in_map: Unit::new_normalize(s - origin),
                    sigma_rad: 0.05,
                    origin_sigma_m: 0.0,
                    fold: None,
                }
            })
            .collect()
    }

    #[test]
    fn converges_to_the_exact_point() {
        let s = Point3::new(1.0, 2.0, 1.2);
        let rays = rays_to(s, &[[0.0, 0.0, 0.5], [4.0, 0.0, 0.5], [2.0, 5.0, 0.4], [-2.0, 3.0, 0.5]]);
        let fit = refine(&rays, s + Vector3::new(0.3, -0.2, 0.1), RobustLoss::default(), 30);
        // σ = 0.05 rad at 2.3–3.6 m: the point's own σ is over 0.1 m, and the
        // refinement stops within a thousandth of it.
        let err = (fit.point - s).norm();
        assert!(err < NEGLIGIBLE_STEP_SIGMA * 0.1, "{err}");
        assert!(fit.chi2 < NEGLIGIBLE_STEP_SIGMA * NEGLIGIBLE_STEP_SIGMA && fit.converged, "{fit:?}");
    }

    #[test]
    fn a_start_within_a_negligible_step_of_the_minimum_is_kept() {
        // σ = 0.05 rad at 2.3–3.6 m: the point's σ is over 0.1 m, so 10 µm off
        // the minimum is 10⁻⁴ σ. One Gauss–Newton step is computed and found
        // negligible; the start is returned as the minimum.
        let s = Point3::new(1.0, 2.0, 1.2);
        let rays = rays_to(s, &[[0.0, 0.0, 0.5], [4.0, 0.0, 0.5], [2.0, 5.0, 0.4], [-2.0, 3.0, 0.5]]);
        let start = s + Vector3::new(1e-5, 0.0, 0.0);
        let fit = refine(&rays, start, RobustLoss::None, 30);
        assert_eq!((fit.iterations, fit.converged, fit.point), (1, true, start), "{fit:?}");
        // 3 cm off (about 0.2 σ) is not negligible: the fit moves to the minimum.
        let fit = refine(&rays, s + Vector3::new(0.03, 0.0, 0.0), RobustLoss::None, 30);
        assert!(fit.iterations > 1 && (fit.point - s).norm() < NEGLIGIBLE_STEP_SIGMA * 0.1, "{fit:?}");
    }

    #[test]
    fn cauchy_loss_resists_one_wrong_ray() {
        let s = Point3::new(1.0, 2.0, 1.2);
        let mut rays = rays_to(
            s,
            &[[0.0, 0.0, 0.5], [4.0, 0.0, 0.5], [2.0, 5.0, 0.4], [-2.0, 3.0, 0.5], [4.0, 4.0, 0.5]],
        );
        // A mirror-source DoA 30° off for the last robot.
        let rot = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 30f64.to_radians());
        rays[4].direction_in_map = Unit::new_normalize(rot * rays[4].direction_in_map.into_inner());
        let ls = super::super::least_squares::weighted_least_squares(&rays, 3).unwrap();
        let plain = refine(&rays, ls, RobustLoss::None, 50);
        let robust = refine(&rays, ls, RobustLoss::Cauchy { c: 2.4 }, 50);
        assert!(
            (robust.point - s).norm() < 0.5 * (plain.point - s).norm(),
            "robust {} plain {}",
            (robust.point - s).norm(),
            (plain.point - s).norm()
        );
    }

    #[test]
    fn start_behind_an_array_is_reported_not_nan() {
        let s = Point3::new(1.0, 2.0, 1.2);
        let rays = rays_to(s, &[[0.0, 0.0, 0.5], [4.0, 0.0, 0.5], [2.0, 5.0, 0.4]]);
        let fit = refine(&rays, Point3::new(-5.0, -5.0, 0.0), RobustLoss::default(), 10);
        assert!(fit.chi2.is_infinite() && !fit.converged);
    }
}

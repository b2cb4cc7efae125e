//! Weighted least-squares point closest to N lines (theory §1.3).

use nalgebra::{Matrix3, Point3, Vector3};

use crate::ray::{MIN_RANGE_M, Ray};

/// Smallest accepted determinant of the normalized matrix Ā = A/Σw (whose
/// eigenvalues sum to 2): below it the rays are treated as parallel.
const MIN_NORMALIZED_DET: f64 = 1e-12;

/// Solves x̂ = A⁻¹b with A = Σ wᵢ(I − dᵢdᵢᵀ), b = Σ wᵢ(I − dᵢdᵢᵀ)oᵢ, first with weights
/// 1/σᵢ² (equal ranges), then `reweights` times with wᵢ = 1/(σᵢ²rᵢ² + σ_origin,ᵢ²) and
/// rᵢ = ‖x̂ − oᵢ‖ floored at [`MIN_RANGE_M`] (IRLS). `None` when A is singular
/// (fewer than two non-parallel rays).
pub fn weighted_least_squares(rays: &[Ray], reweights: usize) -> Option<Point3<f64>> {
    let mut x = solve(rays, |r| 1.0 / r.sigma_rad.max(1e-9).powi(2))?;
    for _ in 0..reweights {
        x = solve(rays, |r| {
            1.0 / r.lateral_variance((x - r.origin_in_map).norm().max(MIN_RANGE_M)).max(1e-18)
        })?;
    }
    Some(x)
}

/// One weighted solve with weights from `weight`.
fn solve(rays: &[Ray], weight: impl Fn(&Ray) -> f64) -> Option<Point3<f64>> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    let mut wsum = 0.0;
    for r in rays {
        let w = weight(r);
        let p = Matrix3::identity() - r.direction_in_map.into_inner() * r.direction_in_map.transpose();
        a += p * w;
        b += p * r.origin_in_map.coords * w;
        wsum += w;
    }
    if !(wsum > 0.0) || !wsum.is_finite() {
        return None;
    }
    if (a / wsum).determinant() < MIN_NORMALIZED_DET {
        return None;
    }
    let x = a.cholesky()?.solve(&b);
    x.iter().all(|v| v.is_finite()).then(|| Point3::from(x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    #[test]
    fn exact_for_consistent_rays_and_none_for_parallel() {
        let s = Point3::new(1.0, 2.0, 1.5);
        let rays: Vec<Ray> = [[0.0, 0.0, 0.5], [4.0, 0.0, 0.5], [2.0, 5.0, 0.4]]
            .iter()
            .map(|o| {
                let origin = Point3::from(*o);
                Ray {
                    origin_in_map: origin,
                    direction_in_map: Unit::new_normalize(s - origin),
                    sigma_rad: 0.05,
                    origin_sigma_m: 0.01,
                    fold: None,
                }
            })
            .collect();
        let x = weighted_least_squares(&rays, 3).unwrap();
        assert!((x - s).norm() < 1e-12);
        let parallel = [rays[0], Ray { origin_in_map: Point3::new(0.0, 1.0, 0.5), ..rays[0] }];
        assert!(weighted_least_squares(&parallel, 3).is_none());
    }
}

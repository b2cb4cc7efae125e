//! Two rays: the paper's closest point and the weighted form of it (theory §1.2).

use nalgebra::{Point3, Unit, Vector3};

use crate::ray::{MIN_RANGE_M, Ray};

/// The paper's "ray to ray" estimate, exactly as its equation gives it:
///
/// l_S = ½ (l₁ + G₁λ₁ + l₂ + G₂λ₂), with
/// G₁ = ((λ₁·λ₂)(λ₂·(l₁−l₂)) − λ₁·(l₁−l₂)) / (1 − (λ₁·λ₂)²) and
/// G₂ = ((λ₁·λ₂)(λ₁·(l₂−l₁)) − λ₂·(l₂−l₁)) / (1 − (λ₁·λ₂)²),
///
/// where lᵢ is ray i's origin (`origin_*`) and λᵢ its unit direction
/// (`dir_*`), all in the map frame. `None` only when the denominator is 0
/// (parallel rays: 1 − (λ₁·λ₂)² is 0, or below it by rounding); it applies no
/// other check, like the original.
pub fn paper_ray_to_ray(
    origin_1: &Point3<f64>,
    dir_1: &Unit<Vector3<f64>>,
    origin_2: &Point3<f64>,
    dir_2: &Unit<Vector3<f64>>,
) -> Option<Point3<f64>> {
    let (l1, l2) = (origin_1.coords, origin_2.coords);
    let (g1, g2) = paper_gains(&l1, dir_1, &l2, dir_2)?;
    Some(Point3::from((l1 + dir_1.into_inner() * g1 + l2 + dir_2.into_inner() * g2) * 0.5))
}

/// G₁ and G₂ of the paper's equation: the distances along each ray to its closest point.
fn paper_gains(
    l1: &Vector3<f64>,
    d1: &Unit<Vector3<f64>>,
    l2: &Vector3<f64>,
    d2: &Unit<Vector3<f64>>,
) -> Option<(f64, f64)> {
    let c = d1.dot(d2);
    let den = 1.0 - c * c;
    if den <= 0.0 {
        return None;
    }
    let g1 = (c * d2.dot(&(l1 - l2)) - d1.dot(&(l1 - l2))) / den;
    let g2 = (c * d1.dot(&(l2 - l1)) - d2.dot(&(l2 - l1))) / den;
    Some((g1, g2))
}

/// Closest points of two rays' lines and what they say about the pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestPoints {
    /// Distance along ray 0 to its closest point (m); negative means behind the array.
    pub s0: f64,
    /// Distance along ray 1 to its closest point (m).
    pub s1: f64,
    /// Closest point on ray 0.
    pub c0: Point3<f64>,
    /// Closest point on ray 1.
    pub c1: Point3<f64>,
    /// ‖c₁ − c₀‖ (m).
    pub miss_m: f64,
    /// sin² of the angle between the rays (the paper's denominator 1 − (λ₁·λ₂)²).
    pub sin2: f64,
}

/// Closest points of the lines of two rays, or `None` if the rays are exactly parallel.
pub fn closest_points(r0: &Ray, r1: &Ray) -> Option<ClosestPoints> {
    let (s0, s1) = paper_gains(
        &r0.origin_in_map.coords,
        &r0.direction_in_map,
        &r1.origin_in_map.coords,
        &r1.direction_in_map,
    )?;
    let c = r0.direction_in_map.dot(&r1.direction_in_map);
    let (c0, c1) = (r0.at(s0), r1.at(s1));
    Some(ClosestPoints { s0, s1, c0, c1, miss_m: (c1 - c0).norm(), sin2: 1.0 - c * c })
}

/// The statistically weighted closest point (theory §1.2): x = (w₀c₀ + w₁c₁)/(w₀ + w₁)
/// with wᵢ = 1/(σᵢ²sᵢ² + σ_origin,ᵢ²), the minimiser of Σ wᵢ d²(x, Lᵢ). Equal weights give
/// the paper's midpoint. Also returns the miss-distance χ² (1 dof): m²/(1/w₀ + 1/w₁).
pub fn weighted_pair_point(r0: &Ray, r1: &Ray, cp: &ClosestPoints) -> (Point3<f64>, f64) {
    let v0 = r0.lateral_variance(cp.s0.max(MIN_RANGE_M));
    let v1 = r1.lateral_variance(cp.s1.max(MIN_RANGE_M));
    let chi2 = if v0 + v1 > 0.0 { cp.miss_m * cp.miss_m / (v0 + v1) } else { 0.0 };
    if v0 + v1 == 0.0 {
        return (nalgebra::center(&cp.c0, &cp.c1), chi2);
    }
    // w₀/(w₀+w₁) = v₁/(v₀+v₁).
    let t0 = v1 / (v0 + v1);
    (Point3::from(cp.c0.coords * t0 + cp.c1.coords * (1.0 - t0)), chi2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(o: [f64; 3], toward: [f64; 3], sigma: f64) -> Ray {
        let origin = Point3::from(o);
        Ray {
            origin_in_map: origin,
            direction_in_map: Unit::new_normalize(Point3::from(toward) - origin),
            sigma_rad: sigma,
            origin_sigma_m: 0.0,
            fold: None,
        }
    }

    #[test]
    fn paper_formula_meets_at_the_source() {
        let s = [1.0, 2.0, 1.12];
        let a = ray([0.0, 0.0, 0.48], s, 0.05);
        let b = ray([4.0, 0.5, 0.48], s, 0.05);
        let p =
            paper_ray_to_ray(&a.origin_in_map, &a.direction_in_map, &b.origin_in_map, &b.direction_in_map)
                .unwrap();
        assert!((p - Point3::from(s)).norm() < 1e-12);
        let x = Vector3::x_axis();
        assert!(paper_ray_to_ray(&a.origin_in_map, &x, &b.origin_in_map, &x).is_none());
    }

    #[test]
    fn skew_rays_midpoint_and_weights() {
        // Ray 0 along x at z=0, ray 1 along y at z=1 through (2,0,1): closest points (2,0,0) and (2,0,1).
        let r0 = Ray {
            origin_in_map: Point3::origin(),
            direction_in_map: Vector3::x_axis(),
            sigma_rad: 0.01,
            origin_sigma_m: 0.0,
            fold: None,
        };
        let r1 = Ray {
            origin_in_map: Point3::new(2.0, -2.0, 1.0),
            direction_in_map: Vector3::y_axis(),
            sigma_rad: 0.01,
            origin_sigma_m: 0.0,
            fold: None,
        };
        let cp = closest_points(&r0, &r1).unwrap();
        assert!(
            (cp.s0 - 2.0).abs() < 1e-12 && (cp.s1 - 2.0).abs() < 1e-12 && (cp.miss_m - 1.0).abs() < 1e-12
        );
        let (x, chi2) = weighted_pair_point(&r0, &r1, &cp);
        assert!((x - Point3::new(2.0, 0.0, 0.5)).norm() < 1e-12);
        assert!((chi2 - 1.0 / (2.0 * 0.0004)).abs() < 1e-6);
        let paper = paper_ray_to_ray(
            &r0.origin_in_map,
            &r0.direction_in_map,
            &r1.origin_in_map,
            &r1.direction_in_map,
        )
        .unwrap();
        assert!((paper - x).norm() < 1e-12);
        // A less precise ray 1 pulls the point toward ray 0's closest point.
        let noisy = Ray { sigma_rad: 0.03, ..r1 };
        let (x, _) = weighted_pair_point(&r0, &noisy, &cp);
        assert!((x.z - 0.1).abs() < 1e-12, "{x}");
    }
}

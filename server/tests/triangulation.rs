//! Triangulation against exact geometry, the paper's formula, invariances and
//! the Cramér–Rao bound (theory §1–2).

use nalgebra::{Isometry3, Matrix3, Point3, Unit, UnitQuaternion, Vector3};
use proptest::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use soundmap_server::Ray;
use soundmap_server::ray::tangent_basis;
use soundmap_server::triangulation::least_squares::weighted_least_squares;
use soundmap_server::triangulation::pair::paper_ray_to_ray;
use soundmap_server::triangulation::{Gate, Method, Triangulation, TriangulationConfig, triangulate};
use soundmap_server::uncertainty::{Sensor, assess};

fn exact_ray(origin: Point3<f64>, source: &Point3<f64>, sigma: f64) -> Ray {
    Ray {
        origin_in_map: origin,
        direction_in_map: Unit::new_normalize(source - origin),
        sigma_rad: sigma,
        origin_sigma_m: 0.0,
        fold: None,
    }
}

/// Rotates `d` by a random small angle with N(0, σ²) components on both tangent axes.
fn perturb(d: &Unit<Vector3<f64>>, sigma: f64, rng: &mut ChaCha8Rng) -> Unit<Vector3<f64>> {
    let (b1, b2) = tangent_basis(d);
    let a1: f64 = StandardNormal.sample(rng);
    let a2: f64 = StandardNormal.sample(rng);
    let (a1, a2) = (a1 * sigma, a2 * sigma);
    let angle = (a1 * a1 + a2 * a2).sqrt();
    if angle == 0.0 {
        return *d;
    }
    let axis_in_plane = (b1 * a1 + b2 * a2) / angle;
    Unit::new_normalize(d.into_inner() * angle.cos() + axis_in_plane * angle.sin())
}

fn point(v: [f64; 3]) -> Point3<f64> {
    Point3::from(v)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, .. ProptestConfig::default() })]

    /// Noise-free rays from 2–6 arrays meet exactly at the source.
    #[test]
    fn noise_free_rays_give_the_source(
        source in prop::array::uniform3(-5.0f64..5.0),
        origins in prop::collection::vec(prop::array::uniform3(-8.0f64..8.0), 2..7),
    ) {
        let s = point(source);
        let origins: Vec<Point3<f64>> = origins.into_iter().map(point).collect();
        prop_assume!(origins.iter().all(|o| (o - s).norm() > 0.5));
        let rays: Vec<Ray> = origins.iter().map(|o| exact_ray(*o, &s, 0.05)).collect();
        // Skip geometries that are degenerate by construction (all rays within 5° of parallel).
        let max_angle = rays.iter().flat_map(|a| rays.iter().map(move |b| a.direction_in_map.angle(&b.direction_in_map))).fold(0.0, f64::max);
        prop_assume!(max_angle > 5f64.to_radians());
        match triangulate(&rays, &TriangulationConfig::default()) {
            Triangulation::Solved(sol) => {
                prop_assert!((sol.source_in_map - s).norm() < 1e-9, "error {} m", (sol.source_in_map - s).norm());
                prop_assert!(sol.residual_chi2 < 1e-9);
            }
            Triangulation::Degenerate(d) => prop_assert!(false, "degenerate: {d}"),
        }
    }

    /// Moving and turning the whole scene moves and turns the estimate and its
    /// covariance, and leaves GDOP, θ and κ unchanged.
    #[test]
    fn invariant_under_rigid_motion(
        seed in any::<u64>(),
        n in 2usize..6,
        axis in prop::array::uniform3(-1.0f64..1.0),
        angle in -3.1f64..3.1,
        shift in prop::array::uniform3(-20.0f64..20.0),
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s = Point3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(0.5..2.0));
        let rays: Vec<Ray> = (0..n).map(|_| {
            let az: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let r: f64 = rng.random_range(1.5..5.0);
            let o = s + Vector3::new(r * az.cos(), r * az.sin(), -rng.random_range(0.3..1.0));
            let mut ray = exact_ray(o, &s, 0.05);
            ray.direction_in_map = perturb(&ray.direction_in_map, 0.05, &mut rng);
            ray
        }).collect();
        prop_assume!(Vector3::from(axis).norm() > 0.1);
        let t = Isometry3::from_parts(Vector3::from(shift).into(), UnitQuaternion::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), angle));
        let moved: Vec<Ray> = rays.iter().map(|r| Ray { origin_in_map: t * r.origin_in_map, direction_in_map: Unit::new_normalize(t * r.direction_in_map.into_inner()), ..*r }).collect();
        let cfg = TriangulationConfig::default();
        match (triangulate(&rays, &cfg), triangulate(&moved, &cfg)) {
            (Triangulation::Solved(a), Triangulation::Solved(b)) => {
                // Where the geometry is ill-conditioned the cost is flat along the range, and
                // the solver stops anywhere in a rounding-sized stretch of that valley: compare
                // in the estimate's own standard deviations (e.g. θ 2.5°, κ 232: 1.2e-7 m
                // apart, 1e-8 σ), and in metres where the geometry is good.
                let moved_by = t * a.source_in_map - b.source_in_map;
                let cov_b = b.quality.covariance.unwrap();
                let sigmas = cov_b.try_inverse().map_or(f64::INFINITY, |inv| (moved_by.transpose() * inv * moved_by)[0].max(0.0).sqrt());
                prop_assert!(moved_by.norm() < 1e-7 || sigmas < 1e-6, "point moved by {} m = {sigmas} σ", moved_by.norm());
                let r = t.rotation.to_rotation_matrix();
                let ca: Matrix3<f64> = r * a.quality.covariance.unwrap() * r.transpose();
                prop_assert!((ca - b.quality.covariance.unwrap()).abs().max() < 1e-6 * ca.abs().max());
                prop_assert!((a.quality.gdop - b.quality.gdop).abs() < 1e-6 * a.quality.gdop);
                prop_assert!((a.quality.theta_deg - b.quality.theta_deg).abs() < 1e-6);
                prop_assert!((a.condition_number - b.condition_number).abs() < 1e-6 * a.condition_number);
                prop_assert_eq!(std::mem::discriminant(&a.gate), std::mem::discriminant(&b.gate));
            }
            (Triangulation::Degenerate(a), Triangulation::Degenerate(b)) => {
                prop_assert_eq!(std::mem::discriminant(&a), std::mem::discriminant(&b));
            }
            (a, b) => prop_assert!(false, "outcomes differ: {a:?} vs {b:?}"),
        }
    }

    /// The paper's equation and the equal-weight 2-ray least squares are the same estimator.
    #[test]
    fn paper_formula_equals_two_ray_least_squares(seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s = Point3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), 1.12);
        let mk = |rng: &mut ChaCha8Rng| {
            let o = Point3::new(rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0), 0.48);
            let mut r = exact_ray(o, &s, 0.05);
            r.direction_in_map = perturb(&r.direction_in_map, 0.05, rng);
            r
        };
        let (a, b) = (mk(&mut rng), mk(&mut rng));
        prop_assume!(a.direction_in_map.angle(&b.direction_in_map) > 1f64.to_radians());
        let paper = paper_ray_to_ray(&a.origin_in_map, &a.direction_in_map, &b.origin_in_map, &b.direction_in_map).unwrap();
        let ls = weighted_least_squares(&[a, b], 0).unwrap();
        prop_assert!((paper - ls).norm() < 1e-9 * (1.0 + paper.coords.norm()), "paper {paper} ls {ls}");
    }

    /// No input geometry, however degenerate, yields NaN.
    #[test]
    fn degenerate_inputs_are_outcomes_not_nan(
        origins in prop::collection::vec(prop::array::uniform3(-2.0f64..2.0), 0..5),
        dirs in prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), 5),
        collapse in any::<bool>(),
    ) {
        let rays: Vec<Ray> = origins.iter().zip(&dirs).filter_map(|(o, d)| {
            let d = Vector3::from(if collapse { dirs[0] } else { *d });
            (d.norm() > 1e-3).then(|| Ray { origin_in_map: point(*o), direction_in_map: Unit::new_normalize(d), sigma_rad: 0.0, origin_sigma_m: 0.0, fold: None })
        }).collect();
        if let Triangulation::Solved(s) = triangulate(&rays, &TriangulationConfig::default()) {
            prop_assert!(s.source_in_map.iter().all(|v| v.is_finite()));
            prop_assert!(!s.quality.gdop.is_nan() && !s.quality.rms_m.is_nan() && !s.condition_number.is_nan());
            prop_assert!(!s.residual_chi2.is_nan() && !s.quality.theta_deg.is_nan());
        }
    }
}

#[test]
fn parallel_antiparallel_behind_and_single_rays() {
    let cfg = TriangulationConfig::default();
    let s = point([0.0, 3.0, 1.0]);
    let a = exact_ray(point([0.0, 0.0, 0.5]), &s, 0.05);
    // Parallel: a second array beside the first, looking the same way.
    let b = Ray { origin_in_map: point([0.5, 0.0, 0.5]), ..a };
    assert!(matches!(
        triangulate(&[a, b], &cfg),
        Triangulation::Degenerate(soundmap_server::triangulation::Degeneracy::NearParallel { .. })
    ));
    // Antiparallel: the two arrays look away from each other along one line.
    let c = Ray {
        origin_in_map: point([0.0, 6.0, 1.5]),
        direction_in_map: Unit::new_normalize(-a.direction_in_map.into_inner()),
        ..a
    };
    assert!(matches!(triangulate(&[a, c], &cfg), Triangulation::Degenerate(_)));
    // Crossing behind array 1: its ray points away from the other's.
    let d = Ray { origin_in_map: point([3.0, 3.0, 1.0]), direction_in_map: Vector3::x_axis(), ..a };
    assert!(matches!(
        triangulate(&[a, d], &cfg),
        Triangulation::Degenerate(soundmap_server::triangulation::Degeneracy::BehindArray { ray: 1, .. })
    ));
    assert!(matches!(
        triangulate(&[a], &cfg),
        Triangulation::Degenerate(soundmap_server::triangulation::Degeneracy::TooFewRays { count: 1 })
    ));
    // A small angle gives a point, but the gate refuses to trust it.
    let e = exact_ray(point([0.4, 0.0, 0.5]), &s, 0.05);
    match triangulate(&[a, e], &cfg) {
        Triangulation::Solved(sol) => {
            assert!(sol.quality.theta_deg < 10.0);
            assert!(matches!(sol.gate, Gate::Rejected(_)), "{:?}", sol.gate);
        }
        other => panic!("{other:?}"),
    }
}

/// Monte Carlo (theory §5.4): two robots at 3 m, θ = 90°, σ = 3° per tangent axis.
/// The RMS error must be within 10% of the CRLB (0.248 m), and the reported
/// covariance must be consistent with the actual errors (mean NEES ≈ 3).
#[test]
fn monte_carlo_rms_meets_the_crlb_at_90_degrees() {
    let sigma = 3f64.to_radians();
    let s = point([0.0, 0.0, 1.12]);
    let h = 45f64.to_radians();
    let origins = [point([3.0 * h.cos(), 3.0 * h.sin(), 1.12]), point([3.0 * h.cos(), -3.0 * h.sin(), 1.12])];
    let crlb =
        assess(&origins.map(|o| Sensor { origin: o, sigma_rad: sigma, origin_sigma_m: 0.0 }), &s).rms_m;
    assert!((crlb - 0.248).abs() < 0.002, "CRLB {crlb}");
    let mut rng = ChaCha8Rng::seed_from_u64(20_201_025);
    let cfg = TriangulationConfig { max_rms_m: 10.0, ..TriangulationConfig::default() };
    let (mut sq, mut nees, mut n) = (0.0, 0.0, 0usize);
    let trials = 20_000;
    for _ in 0..trials {
        let rays: Vec<Ray> = origins
            .iter()
            .map(|o| {
                let mut r = exact_ray(*o, &s, sigma);
                r.direction_in_map = perturb(&r.direction_in_map, sigma, &mut rng);
                r
            })
            .collect();
        if let Triangulation::Solved(sol) = triangulate(&rays, &cfg) {
            assert_eq!(sol.method, Method::RayPair);
            let e = sol.source_in_map - s;
            sq += e.norm_squared();
            nees += (e.transpose() * sol.quality.covariance.unwrap().try_inverse().unwrap() * e)[0];
            n += 1;
        }
    }
    assert!(n > trials * 99 / 100, "only {n} of {trials} solved");
    let rms = (sq / n as f64).sqrt();
    let mean_nees = nees / n as f64;
    println!("θ=90°, r=3 m, σ=3°: RMS {rms:.4} m vs CRLB {crlb:.4} m; mean NEES {mean_nees:.3} (3 expected)");
    assert!((rms - crlb).abs() / crlb < 0.10, "RMS {rms} vs CRLB {crlb}");
    assert!((mean_nees - 3.0).abs() < 0.3, "mean NEES {mean_nees}");
}

/// N ≥ 3 uses LM, which at 120° spacing reaches the CRLB too (theory §1.5: 0.203 m).
#[test]
fn three_robots_reach_their_bound() {
    let sigma = 3f64.to_radians();
    let s = point([0.0, 0.0, 1.12]);
    let origins: Vec<Point3<f64>> = (0..3)
        .map(|k| {
            let a = (k as f64) * 120f64.to_radians();
            point([3.0 * a.cos(), 3.0 * a.sin(), 1.12])
        })
        .collect();
    let sensors: Vec<Sensor> =
        origins.iter().map(|o| Sensor { origin: *o, sigma_rad: sigma, origin_sigma_m: 0.0 }).collect();
    let crlb = assess(&sensors, &s).rms_m;
    assert!((crlb - 0.203).abs() < 0.002, "{crlb}");
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let cfg = TriangulationConfig {
        max_rms_m: 10.0,
        robust_loss: soundmap_server::triangulation::RobustLoss::None,
        ..Default::default()
    };
    let (mut sq, mut n) = (0.0, 0);
    for _ in 0..5000 {
        let rays: Vec<Ray> = origins
            .iter()
            .map(|o| {
                let mut r = exact_ray(*o, &s, sigma);
                r.direction_in_map = perturb(&r.direction_in_map, sigma, &mut rng);
                r
            })
            .collect();
        if let Triangulation::Solved(sol) = triangulate(&rays, &cfg) {
            assert_eq!(sol.method, Method::LevenbergMarquardt);
            sq += (sol.source_in_map - s).norm_squared();
            n += 1;
        }
    }
    let rms = (sq / n as f64).sqrt();
    println!("3 robots at 120°, r=3 m, σ=3°: RMS {rms:.4} m vs CRLB {crlb:.4} m");
    assert!((rms - crlb).abs() / crlb < 0.10, "RMS {rms} vs CRLB {crlb}");
}

/// A case the property test above found: three rays with a large residual
/// (χ² ≈ 18 on 3 dof), where the Cauchy loss makes Levenberg–Marquardt converge
/// slowly and stop at its iteration limit. The estimate must still turn with
/// the scene: damping that depended on the map's axes made it move by 1.3 µm.
#[test]
fn unconverged_refinement_still_turns_with_the_scene() {
    let mut rng = ChaCha8Rng::seed_from_u64(14848688515798353609);
    let s = Point3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(0.5..2.0));
    let rays: Vec<Ray> = (0..3)
        .map(|_| {
            let az: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let r: f64 = rng.random_range(1.5..5.0);
            let o = s + Vector3::new(r * az.cos(), r * az.sin(), -rng.random_range(0.3..1.0));
            let mut ray = exact_ray(o, &s, 0.05);
            ray.direction_in_map = perturb(&ray.direction_in_map, 0.05, &mut rng);
            ray
        })
        .collect();
    let t = Isometry3::from_parts(
        Vector3::zeros().into(),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -3.023090852290898),
    );
    let moved: Vec<Ray> = rays
        .iter()
        .map(|r| Ray {
            origin_in_map: t * r.origin_in_map,
            direction_in_map: Unit::new_normalize(t * r.direction_in_map.into_inner()),
            ..*r
        })
        .collect();
    let cfg = TriangulationConfig::default();
    match (triangulate(&rays, &cfg), triangulate(&moved, &cfg)) {
        (Triangulation::Solved(a), Triangulation::Solved(b)) => {
            assert_eq!(a.method, Method::LevenbergMarquardt);
            assert!(
                (t * a.source_in_map - b.source_in_map).norm() < 1e-9,
                "moved by {}",
                (t * a.source_in_map - b.source_in_map).norm()
            );
        }
        other => panic!("{other:?}"),
    }
}

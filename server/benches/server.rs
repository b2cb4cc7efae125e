//! Coordinator benchmarks (`cargo bench -p soundmap-server --bench server`).
//!
//! - triangulation: the paper's closest point (reference) vs the full pair
//!   triangulation with covariance, GDOP, θ and gate; 8-ray LS + LM;
//! - the gRPC service over loopback with 2, 16 and 128 robot streams:
//!   observations per second and the latency from an observation's receipt
//!   to the publication of the first estimate that used it.
//!
//! - tracker: the source tracker's per-DoA update, in order and with late DoAs;
//! - planner: one planning cycle for 2, 3 and 8 robots;
//! - sources: several sources (8 robots × 4 tracks) against one;
//! - fleet: the coordinator's state machine with 128 robots, one thread,
//!   against the 128-ray triangulation alone.
//!
//! Options: `--quick` (shorter runs), `--only NAME` (triangulation | tracker |
//! planner | sources | fleet | service), `--no-tracking` (the service without its source tracker,
//! to see the tracker's share), `--folded` (the service's robots declare a
//! planar array and its band, as soundmap agents do, so that the coordinator
//! fits their rays on the floor-image model).

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Unit, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use soundmap_proto::wire::robot_link_client::RobotLinkClient;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{ArrayInfo, Hello, Observation, RobotId, Stamp, TrackedDoa, wire};
use soundmap_server::clock::SystemClock;
use soundmap_server::floor_image::{FloorFold, array_pattern};
use soundmap_server::planner::{
    Heard, PlanOutcome, Planner, PlannerConfig, PlannerInput, RobotState, SourceEstimate, StartPlan,
    StartRobot,
};
use soundmap_server::ray::tangent_basis;
use soundmap_server::tracking::{InitOutcome, SourceTracker, TrackerConfig};
use soundmap_server::triangulation::pair::paper_ray_to_ray;
use soundmap_server::{CoordinatorConfig, Ray, TriangulationConfig, service, triangulate, triangulate_from};

/// Best-of-`reps` nanoseconds per call of `f` over `n` calls.
fn time_per_call(reps: usize, n: usize, mut f: impl FnMut(usize)) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let start = Instant::now();
        for i in 0..n {
            f(i);
        }
        best = best.min(start.elapsed().as_nanos() as f64 / n as f64);
    }
    best
}

fn rays_around(source: Point3<f64>, n: usize, k: usize) -> Vec<Ray> {
    (0..n)
        .map(|i| {
            let a = i as f64 * std::f64::consts::TAU / n as f64 + 0.01 * k as f64;
            let o = source + Vector3::new(3.0 * a.cos(), 3.0 * a.sin(), -0.6);
            let wobble =
                Vector3::new((k as f64 * 0.37 + i as f64).sin(), (k as f64 * 0.71).cos(), 0.3) * 0.05;
            Ray {
                origin_in_map: o,
                direction_in_map: Unit::new_normalize(source - o + wobble),
                sigma_rad: 0.05,
                origin_sigma_m: 0.01,
                fold: None,
            }
        })
        .collect()
}

fn bench_triangulation(quick: bool) {
    let source = Point3::new(2.0, 3.0, 1.12);
    let sets: Vec<Vec<Ray>> = (0..256).map(|k| rays_around(source, 2, k)).collect();
    let sets8: Vec<Vec<Ray>> = (0..256).map(|k| rays_around(source, 8, k)).collect();
    let sets128: Vec<Vec<Ray>> = (0..64).map(|k| rays_around(source, 128, k)).collect();
    let cfg = TriangulationConfig::default();
    let n = if quick { 20_000 } else { 200_000 };
    let paper = time_per_call(5, n, |i| {
        let r = &sets[i % 256];
        black_box(paper_ray_to_ray(
            &r[0].origin_in_map,
            &r[0].direction_in_map,
            &r[1].origin_in_map,
            &r[1].direction_in_map,
        ));
    });
    let pair = time_per_call(5, n, |i| {
        black_box(triangulate(black_box(&sets[i % 256]), &cfg));
    });
    let n8 = n / 10;
    let lm8 = time_per_call(5, n8, |i| {
        black_box(triangulate(black_box(&sets8[i % 256]), &cfg));
    });
    let sets_folded: Vec<Vec<Ray>> = sets.iter().map(|r| folded(r, None)).collect();
    let sets8_folded: Vec<Vec<Ray>> = sets8.iter().map(|r| folded(r, None)).collect();
    let sets_ceiling: Vec<Vec<Ray>> = sets.iter().map(|r| folded(r, Some(3.0))).collect();
    let pair_folded = time_per_call(5, n, |i| {
        black_box(triangulate(black_box(&sets_folded[i % 256]), &cfg));
    });
    let pair_ceiling = time_per_call(5, n / 10, |i| {
        black_box(triangulate(black_box(&sets_ceiling[i % 256]), &cfg));
    });
    let lm8_folded = time_per_call(5, n8, |i| {
        black_box(triangulate(black_box(&sets8_folded[i % 256]), &cfg));
    });
    let lm128 = time_per_call(3, n / 200, |i| {
        black_box(triangulate(black_box(&sets128[i % 64]), &cfg));
    });
    let sets128_folded: Vec<Vec<Ray>> = sets128.iter().map(|r| folded(r, None)).collect();
    let lm128_folded = time_per_call(3, n / 1000, |i| {
        black_box(triangulate(black_box(&sets128_folded[i % 64]), &cfg));
    });
    // Warm starts: each set's fit point moved 1.5 cm (what a source's last
    // estimate typically is from its next fit in the simulations), and 7.5 cm.
    let hints = |sets: &[Vec<Ray>], off_m: f64| -> Vec<Point3<f64>> {
        sets.iter()
            .enumerate()
            .map(|(k, r)| {
                let p = triangulate(r, &cfg).solution().map_or(source, |s| s.source_in_map);
                let a = k as f64 * 2.399;
                p + Vector3::new(a.cos(), a.sin(), 0.5 * (1.7 * a).sin()).normalize() * off_m
            })
            .collect()
    };
    let warm = |sets: &[Vec<Ray>], hints: &[Point3<f64>], reps: usize, calls: usize| {
        time_per_call(reps, calls, |i| {
            let k = i % sets.len();
            black_box(triangulate_from(black_box(&sets[k]), &cfg, Some(hints[k])));
        })
    };
    let (near8, far8) = (hints(&sets8_folded, 0.015), hints(&sets8_folded, 0.075));
    let lm8_warm = warm(&sets8_folded, &near8, 5, n8);
    let lm8_warm_far = warm(&sets8_folded, &far8, 5, n8);
    let (near128, far128) = (hints(&sets128_folded, 0.015), hints(&sets128_folded, 0.075));
    let lm128_warm = warm(&sets128_folded, &near128, 3, n / 1000);
    let lm128_warm_far = warm(&sets128_folded, &far128, 3, n / 1000);
    let near128_straight = hints(&sets128, 0.015);
    let lm128_warm_straight = warm(&sets128, &near128_straight, 3, n / 200);
    println!("## triangulation (one thread)");
    println!("| operation | ns per call |");
    println!("|---|---|");
    println!("| paper's ray-to-ray point only (reference) | {paper:.0} |");
    println!("| pair triangulation with covariance, GDOP, θ, κ, gate | {pair:.0} |");
    println!(
        "| the same, folded rays (floor-image model: pair point + LM on the model) | {pair_folded:.0} |"
    );
    println!("| the same, folded rays with a 3 m ceiling (vertical family of images) | {pair_ceiling:.0} |");
    println!("| 8 rays, folded (floor-image model) | {lm8_folded:.0} |");
    println!(
        "| 8 rays: IRLS least squares + Levenberg–Marquardt (Cauchy) with covariance and gate | {lm8:.0} |"
    );
    println!(
        "| 128 rays: IRLS least squares + Levenberg–Marquardt (Cauchy) with covariance and gate | {lm128:.0} |"
    );
    println!("| 128 rays, folded (floor-image model) | {lm128_folded:.0} |");
    println!("| 8 rays, folded, warm-started 1.5 cm / 7.5 cm off | {lm8_warm:.0} / {lm8_warm_far:.0} |");
    println!(
        "| 128 rays, folded, warm-started 1.5 cm / 7.5 cm off | {lm128_warm:.0} / {lm128_warm_far:.0} |"
    );
    println!("| 128 straight rays, warm-started 1.5 cm off | {lm128_warm_straight:.0} |");
    println!(
        "warm / cold: 128 straight rays {:.2}, 8 folded rays {:.2} / {:.2}, 128 folded rays {:.2} / {:.2}",
        lm128_warm_straight / lm128,
        lm8_warm / lm8_folded,
        lm8_warm_far / lm8_folded,
        lm128_warm / lm128_folded,
        lm128_warm_far / lm128_folded
    );
    println!("pair / paper ratio: {:.1}×; target for the pair: < 1000 ns\n", pair / paper);
}

/// 3 robots at 20 Hz each (60 DoAs/s) watching a source walking a 2 m circle at
/// 0.5 m/s, DoAs with σ = 3°: (stamp, robot, ray), in stamp order.
fn tracker_doas(seconds: f64) -> Vec<(Stamp, u32, Ray)> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let sigma = 3f64.to_radians();
    let robots = [Point3::new(-3.0, 0.0, 0.5), Point3::new(3.0, 0.5, 0.5), Point3::new(0.0, 3.5, 0.5)];
    let t0 = Stamp::from_ns(1_767_225_600_000_000_000);
    let mut out = Vec::new();
    for k in 0..(seconds * 20.0) as usize {
        for (i, o) in robots.iter().enumerate() {
            let t = k as f64 / 20.0 + i as f64 * 0.0167;
            let a = 0.25 * t;
            let source = Point3::new(2.0 * a.cos(), 2.0 * a.sin(), 1.2);
            let d = Unit::new_normalize(source - o);
            let (b1, b2) = tangent_basis(&d);
            let (e1, e2): (f64, f64) = (StandardNormal.sample(&mut rng), StandardNormal.sample(&mut rng));
            let direction = Unit::new_normalize(d.into_inner() + (b1 * e1 + b2 * e2) * sigma);
            out.push((
                t0.plus_secs(t),
                i as u32,
                Ray {
                    origin_in_map: *o,
                    direction_in_map: direction,
                    sigma_rad: sigma,
                    origin_sigma_m: 0.0,
                    fold: None,
                },
            ));
        }
    }
    out
}

/// Band of the planar arrays' search (Hz), as a soundmap agent declares it.
const BAND_HZ: (f64, f64) = (100.0, 8000.0);

/// 8 microphones on a 0.36 m circle, about the 16SoundsUSB's aperture.
fn planar_ring() -> Vec<Point3<f64>> {
    (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_4;
            Point3::new(0.18 * a.cos(), 0.18 * a.sin(), 0.0)
        })
        .collect()
}

/// The pattern of [`planar_ring`] over [`BAND_HZ`].
fn ring_pattern() -> &'static soundmap_server::floor_image::ArrayPattern {
    array_pattern(&planar_ring(), BAND_HZ).expect("planar array")
}

/// The same rays as seen by planar arrays 0.5 m above the floor (8 microphones
/// on a 0.36 m circle, about the 16SoundsUSB's aperture; the floor-image
/// measurement model on, broadband source; `ceiling_m` adds the ceiling's images).
fn folded(rays: &[Ray], ceiling_m: Option<f64>) -> Vec<Ray> {
    let pattern = ring_pattern();
    let (lobe, vertical_spread) = (pattern.lobe(None), Some(pattern.vertical_spread()));
    rays.iter()
        .map(|r| Ray {
            fold: Some(FloorFold {
                array_height_m: r.origin_in_map.z.max(0.5),
                reflection: 0.6,
                lobe,
                ceiling_m,
                vertical_spread,
                upper_branch: true,
                fitted_range_m: None,
            }),
            ..*r
        })
        .collect()
}

fn bench_tracker(quick: bool) {
    let doas = tracker_doas(if quick { 20.0 } else { 120.0 });
    let start_with = |config: TrackerConfig| {
        let mut start = SourceTracker::new(config);
        let init = start.initialize(doas[0].0, Point3::new(2.0, 0.0, 1.2), Matrix3::identity() * 0.04);
        assert!(matches!(init, InitOutcome::Started { .. }));
        start
    };
    let start = start_with(TrackerConfig::default());
    // The fixed-lag smoother's share: the same without it.
    let unsmoothed = start_with(TrackerConfig { smoothing_lag_s: 0.0, ..TrackerConfig::default() });
    // Arrival order: 1 DoA in 16 arrives 0.25 s late (inserted into the lag buffer, the later ones re-run).
    let late_ns = 250_000_000;
    let mut late: Vec<_> = doas
        .iter()
        .enumerate()
        .map(|(k, d)| (d.0.plus_ns(if k % 16 == 8 { late_ns } else { 0 }), *d))
        .collect();
    late.sort_by_key(|(arrival, _)| *arrival);
    let late: Vec<_> = late.into_iter().map(|(_, d)| d).collect();
    println!("## source tracker (one thread; 3 robots × 20 Hz, σ 3°, moving source, default settings)");
    println!("| DoA arrival | ns per update (mean) | applied |");
    println!("|---|---|---|");
    let mut per_update = Vec::new();
    let folded_doas: Vec<_> = {
        let rays = folded(&doas.iter().map(|d| d.2).collect::<Vec<_>>(), None);
        doas.iter().zip(rays).map(|(d, r)| (d.0, d.1, r)).collect()
    };
    let ceiling_doas: Vec<_> = {
        let rays = folded(&doas.iter().map(|d| d.2).collect::<Vec<_>>(), Some(3.0));
        doas.iter().zip(rays).map(|(d, r)| (d.0, d.1, r)).collect()
    };
    for (name, order, start) in [
        ("in stamp order", &doas, &start),
        ("1 in 16 arriving 0.25 s late", &late, &start),
        ("in stamp order, folded rays (floor-image model)", &folded_doas, &start),
        ("in stamp order, folded rays with a 3 m ceiling", &ceiling_doas, &start),
        ("in stamp order, smoothing off (`smoothing_lag_s = 0`)", &doas, &unsmoothed),
    ] {
        let mut applied = 0;
        let per = time_per_call(if quick { 5 } else { 20 }, 1, |_| {
            let mut t = start.clone();
            for (stamp, robot, ray) in order.iter() {
                black_box(t.update(*stamp, *robot, ray));
            }
            applied = t.estimate().map_or(0, |e| e.counts.applied);
        }) / order.len() as f64;
        per_update.push(per);
        println!("| {name} | {per:.0} | {applied} of {} |", order.len());
    }
    // A DoA 0.25 s late precedes ~15 buffered DoAs (60/s), which are re-run after it.
    println!(
        "folded / straight rays: {:.2}×; with the ceiling: {:.2}×",
        per_update[2] / per_update[0],
        per_update[3] / per_update[0]
    );
    println!(
        "the fixed-lag smoother (refreshed every 50 ms of DoA time): {:.2} µs per update, {:.2}× the update without it",
        (per_update[0] - per_update[4]) / 1e3,
        per_update[0] / per_update[4]
    );
    let extra = (per_update[1] - per_update[0]) * 16.0;
    println!(
        "extra cost of one late DoA (insertion and re-running the ~15 after it): {:.1} µs\n",
        extra / 1e3
    );
}

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
    vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
}

fn planner_robot(k: usize, x: f64, y: f64) -> RobotState {
    RobotState {
        id: RobotId::parse(&format!("r{k}"), "id").expect("valid id"),
        map_from_base: Isometry3::translation(x, y, 0.0),
        base_from_array: Isometry3::translation(0.0, 0.0, 0.5),
        sigma_rad: 3f64.to_radians(),
        active_goal: None,
        base: Default::default(),
    }
}

fn bench_planner(quick: bool) {
    let mut convex = PlannerConfig::default();
    convex.free_space.room = rect(-6.0, -5.0, 6.0, 5.0);
    convex.free_space.obstacles = vec![rect(2.5, 2.0, 3.5, 3.0), rect(-3.5, -3.0, -2.5, -2.0)];
    // Obstacles ignored by the pattern search and a block over the target wedges: the sampling fallback.
    let mut fallback = PlannerConfig { blocked_spot_penalty_m: 0.0, ..convex.clone() };
    fallback.free_space.obstacles = vec![rect(-0.5, 0.7, 4.0, 4.5)];
    let source = SourceEstimate::at(Point3::new(0.0, 0.0, 1.2), 0.1);
    let iters = if quick { 50 } else { 300 };
    println!("## planner (one thread; one planning cycle, planner reset before each)");
    println!("| robots | case | ms per cycle | outcome |");
    println!("|---|---|---|---|");
    for (case, cfg) in [("re-plan, convex QP/SOCP", &convex), ("re-plan, sampling fallback", &fallback)] {
        for n in [2usize, 3, 8] {
            // Clustered 4.6–5.5 m from the source: θ out of band, every robot must move.
            let robots =
                (0..n).map(|k| planner_robot(k, 4.6 + 0.9 * (k / 4) as f64, -0.4 + 0.8 * (k % 4) as f64));
            let input = PlannerInput { source: source.clone(), robots: robots.collect(), others: vec![] };
            let mut planner = Planner::new(cfg.clone()).expect("valid config");
            let outcome = match planner.plan(Stamp::ZERO, &input) {
                PlanOutcome::Planned(goals) => {
                    format!(
                        "{} goals{}",
                        goals.len(),
                        if goals.iter().any(|g| g.used_fallback) { ", fallback" } else { "" }
                    )
                }
                other => panic!("{case}, {n} robots: {other:?}"),
            };
            let per = time_per_call(3, iters, |_| {
                planner.reset();
                black_box(planner.plan(Stamp::ZERO, black_box(&input)));
            });
            println!("| {n} | {case} | {:.3} | {outcome} |", per / 1e6);
        }
    }
    // The common case once the robots are placed: every estimate asks, the planner holds.
    for n in [2usize, 3, 8] {
        let robots = (0..n).map(|k| {
            // Bearings k·180°/n: Σ e^{2jφ} = 0, a D-optimal spread for any n (theory §3.2).
            let a = k as f64 * std::f64::consts::PI / n as f64;
            planner_robot(k, 2.0 * a.cos(), 2.0 * a.sin())
        });
        let input = PlannerInput { source: source.clone(), robots: robots.collect(), others: vec![] };
        let mut planner = Planner::new(convex.clone()).expect("valid config");
        let outcome = planner.plan(Stamp::ZERO, &input);
        assert!(matches!(outcome, PlanOutcome::Hold(_)), "{outcome:?}");
        let per = time_per_call(3, iters, |_| {
            planner.reset();
            black_box(planner.plan(Stamp::ZERO, black_box(&input)));
        });
        println!("| {n} | hold (optimal spread at 2 m) | {:.3} | hold |", per / 1e6);
    }
    // A walker (1 m/s toward +y) comes up to the formation: every robot of the
    // spread at 2 m but the first stands inside its keep-out or its path's,
    // plus a second source at the far side whose keep-out they must also keep.
    for n in [2usize, 3, 8] {
        let robots = (0..n).map(|k| {
            let a = k as f64 * std::f64::consts::PI / n as f64;
            let r = if k == 0 { 2.0 } else { 0.6 };
            planner_robot(k, r * a.cos(), r * a.sin())
        });
        let mut walker = source.clone();
        walker.velocity_in_map = Some(Vector3::new(0.0, 1.0, 0.0));
        let others = vec![SourceEstimate::at(Point3::new(-3.0, -2.0, 1.0), 0.1)];
        let input = PlannerInput { source: walker, robots: robots.collect(), others };
        let mut planner = Planner::new(convex.clone()).expect("valid config");
        let outcome = match planner.plan(Stamp::ZERO, &input) {
            PlanOutcome::Planned(goals) => format!("{} goals out of the keep-out", goals.len()),
            other => panic!("keep-out, {n} robots: {other:?}"),
        };
        let per = time_per_call(3, iters, |_| {
            planner.reset();
            black_box(planner.plan(Stamp::ZERO, black_box(&input)));
        });
        println!("| {n} | backing out of the keep-out (two sources) | {:.3} | {outcome} |", per / 1e6);
    }
    bench_planner_from_bearings(&convex, iters);
    println!("targets: < 2 ms for 2 robots, < 20 ms for 8\n");
}

/// No position yet: robot 0 hears along +x, the others (clustered, deaf) are spread across its bearing.
fn bench_planner_from_bearings(cfg: &PlannerConfig, iters: usize) {
    for n in [2usize, 3, 8] {
        let robots: Vec<StartRobot> = (0..n)
            .map(|k| {
                let (x, y) = (-5.0 + 0.9 * (k / 4) as f64, -4.0 + 0.8 * (k % 4) as f64);
                StartRobot {
                    id: RobotId::parse(&format!("r{k}"), "id").expect("valid id"),
                    base_xy: Some(Point2::new(x, y)),
                    heard: (k == 0).then(|| Heard {
                        origin_in_map: Point3::new(x, y, 0.5),
                        direction_in_map: Unit::new_normalize(Vector3::new(1.0, 0.6, 0.1)),
                        activity: 0.8,
                    }),
                    active_goal: None,
                }
            })
            .collect();
        let mut planner = Planner::new(cfg.clone()).expect("valid config");
        let outcome = match planner.plan_from_bearings(Stamp::ZERO, &robots, None) {
            StartPlan::Goals(g) => format!("{} goals", g.len()),
            other => panic!("from bearings, {n} robots: {other:?}"),
        };
        let per = time_per_call(3, iters, |_| {
            planner.reset();
            black_box(planner.plan_from_bearings(Stamp::ZERO, black_box(&robots), None));
        });
        println!("| {n} | no position yet: from bearings | {:.3} | {outcome} |", per / 1e6);
    }
}

/// What the service bench's robots carry: an array 0.48 m above the base,
/// declared without geometry (its rays are straight lines), or with the
/// planar ring and its band (`--folded`: the coordinator folds its rays).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Arrays {
    Undeclared,
    Folded,
}

const ARRAY_HEIGHT_M: f64 = 0.48;

/// The hello of robot `i`, declaring the planar ring and its band when `folded`.
fn hello(i: usize, folded: bool) -> wire::RobotMessage {
    let h = Hello {
        robot_id: RobotId::parse(&format!("bench-{i}"), "id").expect("valid id"),
        array: ArrayInfo {
            base_from_array: Isometry3::translation(0.0, 0.0, ARRAY_HEIGHT_M),
            microphone_count: if folded { 8 } else { 16 },
            preset: None,
            microphone_positions: if folded { planar_ring() } else { vec![] },
            srp_band_hz: folded.then_some([BAND_HZ.0, BAND_HZ.1]),
            direct_path_elevations: false,
        },
        software_version: "bench".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    };
    wire::RobotMessage { msg: Some(Up::Hello(h.to_wire())) }
}

/// Where a folded robot's array hears the source: the direction the
/// coordinator's floor-image model (its default reflection, broadband, no
/// ceiling) predicts, so that its fits meet consistent rays.
fn heard_fold() -> FloorFold {
    let doa = CoordinatorConfig::default().doa;
    FloorFold {
        array_height_m: ARRAY_HEIGHT_M + doa.base_height_m,
        reflection: doa.floor_reflection,
        lobe: ring_pattern().lobe(None),
        ceiling_m: None,
        vertical_spread: None,
        upper_branch: true,
        fitted_range_m: None,
    }
}

fn observation(i: usize, n: usize, seq: u64, stamp: Stamp, fold: Option<&FloorFold>) -> wire::RobotMessage {
    let source = Point3::new(0.0, 0.0, 1.12);
    let a = i as f64 * std::f64::consts::TAU / n as f64;
    let base = Point3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.0);
    let array = base + Vector3::new(0.0, 0.0, ARRAY_HEIGHT_M);
    let d =
        fold.and_then(|f| f.measured_direction(&array, &source)).map_or(source - array, |u| u.into_inner());
    let o = Observation {
        sequence: seq,
        stamp,
        map_from_base: Isometry3::translation(base.x, base.y, 0.0),
        pose_covariance: None,
        doas: vec![TrackedDoa {
            track_id: 1,
            direction_in_array: Unit::new_normalize(d),
            activity: 0.9,
            angular_sigma_rad: Some(0.05),
            signature: None,
            coherence: None,
            floor_fit_range_m: None,
        }],
    };
    wire::RobotMessage { msg: Some(Up::Observation(o.to_wire())) }
}

/// How a robot paces its observations.
#[derive(Clone, Copy)]
enum Load {
    /// As fast as acknowledgements allow, with at most this many unacknowledged.
    Saturate(u64),
    /// At this rate (observations per second), whatever the acknowledgements do.
    Paced(f64),
}

/// One robot streaming observations until `stop`; returns how many were
/// acknowledged. With `fold`, it declares the planar ring and reports what
/// that fold predicts the array hears.
async fn robot(
    channel: tonic::transport::Channel,
    i: usize,
    n: usize,
    load: Load,
    fold: Option<FloorFold>,
    stop: Instant,
) -> u64 {
    let (tx, rx) = tokio::sync::mpsc::channel(4096);
    tx.send(hello(i, fold.is_some())).await.expect("open");
    let mut stream = RobotLinkClient::new(channel)
        .connect(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .expect("connect")
        .into_inner();
    let _welcome = stream.message().await.expect("welcome");
    let acked = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let notify = Arc::new(tokio::sync::Notify::new());
    let reader = {
        let (acked, notify) = (acked.clone(), notify.clone());
        tokio::spawn(async move {
            while let Ok(Some(m)) = stream.message().await {
                if let Some(wire::coordinator_message::Msg::ObservationAck(a)) = m.msg {
                    acked.store(a.up_to_sequence, std::sync::atomic::Ordering::Release);
                    notify.notify_one();
                }
            }
        })
    };
    let mut sent = 0u64;
    match load {
        Load::Saturate(window) => {
            while Instant::now() < stop {
                while sent >= acked.load(std::sync::atomic::Ordering::Acquire) + window {
                    notify.notified().await;
                }
                sent += 1;
                let _ = tx.send(observation(i, n, sent, Stamp::now(), fold.as_ref())).await;
            }
        }
        Load::Paced(rate) => {
            let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
            while Instant::now() < stop {
                tick.tick().await;
                sent += 1;
                let _ = tx.send(observation(i, n, sent, Stamp::now(), fold.as_ref())).await;
            }
        }
    }
    // Let the last acknowledgements arrive.
    let deadline = Instant::now() + Duration::from_secs(2);
    while acked.load(std::sync::atomic::Ordering::Acquire) < sent && Instant::now() < deadline {
        let _ = tokio::time::timeout(Duration::from_millis(50), notify.notified()).await;
    }
    drop(tx);
    reader.abort();
    acked.load(std::sync::atomic::Ordering::Acquire)
}

struct ServiceFigures {
    rate: f64,
    p50: Duration,
    p99: Duration,
    max: Duration,
    samples: u64,
}

/// Drives `n` robots against the coordinator at `addr` and reads its latency metrics.
async fn drive(
    addr: std::net::SocketAddr,
    metrics: Arc<service::Metrics>,
    n: usize,
    load: Load,
    arrays: Arrays,
    seconds: f64,
) -> ServiceFigures {
    let fold = (arrays == Arrays::Folded).then(heard_fold);
    let endpoint = format!("http://{addr}");
    // Robots share a few HTTP/2 connections: a load generator on one machine
    // cannot afford one per robot as real robots would have.
    let connections = n.clamp(1, 8);
    let mut channels = Vec::new();
    for _ in 0..connections {
        channels.push(
            tonic::transport::Endpoint::from_shared(endpoint.clone())
                .expect("uri")
                .tcp_nodelay(true)
                .connect()
                .await
                .expect("connect"),
        );
    }
    let warm = Instant::now() + Duration::from_millis(300);
    let tasks: Vec<_> = (0..n)
        .map(|i| tokio::spawn(robot(channels[i % connections].clone(), i, n, load, fold, warm)))
        .collect();
    for t in tasks {
        t.await.expect("robot");
    }
    let _ = metrics.take_latency(true);
    let start = Instant::now();
    let stop = start + Duration::from_secs_f64(seconds);
    let tasks: Vec<_> = (0..n)
        .map(|i| tokio::spawn(robot(channels[i % connections].clone(), i + n, n, load, fold, stop)))
        .collect();
    let mut total = 0;
    for t in tasks {
        total += t.await.expect("robot");
    }
    let h = metrics.take_latency(false);
    ServiceFigures {
        rate: total as f64 / seconds,
        p50: h.quantile(0.5),
        p99: h.quantile(0.99),
        max: h.max(),
        samples: h.count(),
    }
}

fn bench_service(quick: bool, tracking: bool, arrays: Arrays) {
    // The coordinator and the load generator run on separate runtimes (as they
    // would in separate processes); the coordinator task has its own thread.
    let runtime = |name: &str| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name(name)
            .enable_all()
            .build()
            .expect("runtime")
    };
    let (server_rt, client_rt) = (runtime("coordinator-rt"), runtime("load-rt"));
    let seconds = if quick { 1.0 } else { 4.0 };
    println!(
        "## coordinator service over loopback (coordinator: 2 worker threads + its task's thread; load generator: 2 threads in the same process; source tracker {}; {})",
        if tracking { "on" } else { "off" },
        match arrays {
            Arrays::Undeclared => "arrays undeclared: straight rays",
            Arrays::Folded => "planar arrays declared with their band: rays folded on the floor-image model",
        }
    );
    println!(
        "| robot streams | load | observations/s acknowledged | p50 latency | p99 latency | max | samples |"
    );
    println!("|---|---|---|---|---|---|---|");
    for n in [2, 16, 128] {
        for (name, load) in [
            ("50,000/s offered", Load::Paced(50_000.0 / n as f64)),
            ("saturating (16 in flight per robot)", Load::Saturate(16)),
        ] {
            let running = server_rt.block_on(async {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
                let mut config = CoordinatorConfig::default();
                config.liveness.tick_ms = 0;
                config.tracking.enabled = tracking;
                service::start(config, Arc::new(SystemClock), listener).await.expect("start")
            });
            let f = client_rt.block_on(drive(
                running.local_addr,
                running.metrics.clone(),
                n,
                load,
                arrays,
                seconds,
            ));
            server_rt.block_on(running.shutdown()).expect("shutdown");
            println!(
                "| {n} | {name} | {:.0} | {:?} | {:?} | {:?} | {} |",
                f.rate, f.p50, f.p99, f.max, f.samples
            );
        }
    }
    println!(
        "latency: receipt of an observation by its stream handler → publication of the first estimate using it"
    );
    println!("targets: ≥ 50,000 observations/s with 128 robots, p99 < 5 ms\n");
}

/// The array the in-process coordinator benches' robots declare: 16
/// microphones 0.48 m above the base, positions and band undeclared.
fn bench_array() -> ArrayInfo {
    ArrayInfo { preset: None, ..soundmap_server::loadgen::array() }
}

/// Connects robots `r0` … `r{n-1}` to `c` at `t0`, each with `array` and up to
/// `max_tracks` tracks per observation; their connections in that order.
fn connect_robots(
    c: &mut soundmap_server::coordinator::Coordinator,
    t0: Stamp,
    array: &ArrayInfo,
    n: usize,
    max_tracks: u32,
) -> Vec<soundmap_server::coordinator::ConnId> {
    (0..n)
        .map(|r| {
            let hello = Hello {
                robot_id: RobotId::parse(&format!("r{r}"), "id").unwrap(),
                array: array.clone(),
                software_version: "bench".into(),
                signature_bands: None,
                max_tracks: Some(max_tracks),
                base_limits: Default::default(),
            };
            c.connect(t0, hello, None).unwrap().conn
        })
        .collect()
}

/// Several sources: the coordinator state machine (in process) with 8 robots
/// around 4 sources, each robot reporting 4 tracks at 20 Hz; the cost per
/// observation of validation-free `observe` plus the batch's association,
/// tracking and estimates, against the same run with one source followed
/// (`max_sources = 1`, each robot's dominant DoA) as the reference.
fn bench_sources(quick: bool) {
    use soundmap_server::coordinator::Coordinator;
    let array = bench_array();
    let sources = [
        Point3::new(1.0, 0.5, 1.2),
        Point3::new(-1.2, 0.8, 1.7),
        Point3::new(0.3, -1.4, 0.9),
        Point3::new(-0.6, -0.5, 1.5),
    ];
    let robots: Vec<Point3<f64>> = (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 8.0;
            Point3::new(4.5 * a.cos(), 4.5 * a.sin(), 0.0)
        })
        .collect();
    let seconds = if quick { 10.0 } else { 30.0 };
    let rounds = (seconds * 20.0) as i64;
    let t0 = Stamp::from_ns(1_767_225_600_000_000_000);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    // Observations, prepared outside the timing.
    let mut all = Vec::new();
    for k in 0..rounds {
        for (r, base) in robots.iter().enumerate() {
            let stamp = t0.plus_ns(k * 50_000_000 + r as i64 * 1_000_000);
            let map_from_base = Isometry3::translation(base.x, base.y, base.z);
            let map_from_array = map_from_base * array.base_from_array;
            let doas = sources
                .iter()
                .enumerate()
                .map(|(j, s)| {
                    let d = (map_from_array.inverse() * s).coords.normalize();
                    let e: f64 = StandardNormal.sample(&mut rng);
                    let d = (d + tangent_basis(&Unit::new_normalize(d)).0 * e * 0.01).normalize();
                    TrackedDoa {
                        track_id: j as u64 + 1,
                        direction_in_array: Unit::new_normalize(d),
                        activity: 0.9,
                        angular_sigma_rad: Some(1f64.to_radians()),
                        signature: None,
                        coherence: None,
                        floor_fit_range_m: None,
                    }
                })
                .collect();
            let obs =
                Observation { sequence: k as u64 + 1, stamp, map_from_base, pose_covariance: None, doas };
            all.push((r, stamp, obs));
        }
    }
    println!("## several sources (one thread; 8 robots × 4 tracks at 20 Hz around 4 sources, {seconds} s)");
    println!(
        "| coordinator | µs per observation (observe + association, tracking, estimates per round) | sources at the end |"
    );
    println!("|---|---|---|");
    for max_sources in [1, 4] {
        let mut config = CoordinatorConfig::default();
        config.sources.max_sources = max_sources;
        let mut found = 0;
        let per = time_per_call(if quick { 2 } else { 5 }, 1, |_| {
            let mut c = Coordinator::new(config.clone()).unwrap();
            let conns = connect_robots(&mut c, t0, &array, robots.len(), 4);
            for (i, (r, stamp, obs)) in all.iter().enumerate() {
                let now = stamp.plus_ns(5_000_000);
                c.observe(now, conns[*r], obs.clone()).unwrap();
                if i % robots.len() == robots.len() - 1 {
                    black_box(c.estimate(now));
                }
            }
            found = c.latest_estimates().len();
        }) / all.len() as f64;
        let name = if max_sources == 1 {
            "one source (reference: dominant DoA)"
        } else {
            "sound map, max_sources = 4"
        };
        println!("| {name} | {:.1} | {found} |", per / 1e3);
    }
    println!("target: < 50 µs per observation with 8 robots × 4 tracks\n");
}

/// The coordinator's state machine at fleet scale, on one thread: 128 robots
/// around one source, each reporting one DoA at 390 Hz (50,000 observations/s
/// in all, as in the service's 128-robot cell), an estimate after every
/// observation (the most the service's state task can be asked for).
/// The reference in the same run is the 128-ray triangulation alone,
/// warm-started 1 cm from the source (the coordinator starts from its last
/// accepted estimate): what is left over is `observe`, the
/// gathering of each robot's nearest observation, tracking and the
/// estimate's bookkeeping.
fn bench_fleet(quick: bool) {
    use soundmap_server::coordinator::Coordinator;
    let n = 128usize;
    let array = bench_array();
    let source = Point3::new(0.4, -0.3, 1.2);
    let bases: Vec<Point3<f64>> = (0..n)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / n as f64;
            let r = 3.0 + (k % 4) as f64 * 0.5;
            Point3::new(r * a.cos(), r * a.sin(), 0.0)
        })
        .collect();
    let seconds = if quick { 0.5 } else { 2.0 };
    let period_ns = (1e9 * n as f64 / 50_000.0) as i64;
    let rounds = (seconds * 1e9 / period_ns as f64) as i64;
    let t0 = Stamp::from_ns(1_767_225_600_000_000_000);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut all = Vec::new();
    let mut last_rays = Vec::new();
    for k in 0..rounds {
        last_rays.clear();
        for (r, base) in bases.iter().enumerate() {
            let stamp = t0.plus_ns(k * period_ns + r as i64 * period_ns / n as i64);
            let map_from_base = Isometry3::translation(base.x, base.y, base.z);
            let map_from_array = map_from_base * array.base_from_array;
            let d = (map_from_array.inverse() * source).coords.normalize();
            let e: f64 = StandardNormal.sample(&mut rng);
            let d = Unit::new_normalize(d + tangent_basis(&Unit::new_normalize(d)).0 * e * 0.01);
            let sigma = 1f64.to_radians();
            last_rays.push(Ray {
                origin_in_map: map_from_array * Point3::origin(),
                direction_in_map: d,
                sigma_rad: sigma,
                origin_sigma_m: 0.01,
                fold: None,
            });
            let doas = vec![TrackedDoa {
                track_id: 1,
                direction_in_array: d,
                activity: 0.9,
                angular_sigma_rad: Some(sigma),
                signature: None,
                coherence: None,
                floor_fit_range_m: None,
            }];
            let obs =
                Observation { sequence: k as u64 + 1, stamp, map_from_base, pose_covariance: None, doas };
            all.push((r, stamp, obs));
        }
    }
    let reps = if quick { 3 } else { 5 };
    let config = CoordinatorConfig::default();
    let mut estimates = 0u64;
    let per_obs = time_per_call(reps, 1, |_| {
        let mut c = Coordinator::new(config.clone()).unwrap();
        let conns = connect_robots(&mut c, t0, &array, n, 1);
        estimates = 0;
        for (r, stamp, obs) in &all {
            let now = stamp.plus_ns(1_000_000);
            c.observe(now, conns[*r], obs.clone()).unwrap();
            estimates += c.estimate(now).len() as u64;
        }
    }) / all.len() as f64;
    let hint = Some(source + Vector3::new(0.01, 0.0, 0.0));
    let tri = time_per_call(reps, 2000, |_| {
        black_box(triangulate_from(black_box(&last_rays), &config.triangulation, hint));
    });
    println!(
        "## the coordinator at fleet scale (one thread; {n} robots × 1 DoA, 50,000 observations/s of stamps, an estimate after each; {seconds} s)"
    );
    println!("| work | µs |");
    println!("|---|---|");
    println!(
        "| per observation: observe + estimate ({estimates} estimates of {}) | {:.1} |",
        all.len(),
        per_obs / 1e3
    );
    println!("| reference: the {n}-ray triangulation alone, warm-started | {:.1} |", tri / 1e3);
    println!("| the rest (observe, gathering, tracking, bookkeeping) | {:.1} |\n", (per_obs - tri) / 1e3);
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let only = args.iter().position(|a| a == "--only").and_then(|i| args.get(i + 1)).cloned();
    let run = |name: &str| only.as_deref().is_none_or(|o| o == name);
    if run("triangulation") {
        bench_triangulation(quick);
    }
    if run("tracker") {
        bench_tracker(quick);
    }
    if run("planner") {
        bench_planner(quick);
    }
    if run("sources") {
        bench_sources(quick);
    }
    if run("fleet") {
        bench_fleet(quick);
    }
    if run("service") {
        let arrays = if args.iter().any(|a| a == "--folded") { Arrays::Folded } else { Arrays::Undeclared };
        bench_service(quick, !args.iter().any(|a| a == "--no-tracking"), arrays);
    }
}

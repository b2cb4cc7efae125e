//! The source tracker against simulated DoAs (theory §4): convergence on a
//! static source, consistency (NEES, NIS) on a moving one, exact out-of-sequence
//! handling, gating, lifecycle and degenerate inputs. All randomness is seeded.

use nalgebra::{Matrix3, Point3, Unit, Vector3, Vector6};
use proptest::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use soundmap_proto::Stamp;
use soundmap_server::ray::tangent_basis;
use soundmap_server::stats::{chi2_quantile, normal_quantile};
use soundmap_server::tracking::{
    InitOutcome, InitRejection, LossReason, SourceTracker, TrackEstimate, TrackState, TrackerConfig,
    Unusable, UpdateOutcome,
};
use soundmap_server::uncertainty::{Sensor, assess};
use soundmap_server::{Ray, Triangulation, TriangulationConfig, triangulate};

const T0_NS: i64 = 1_700_000_000_000_000_000;

fn at(t_s: f64) -> Stamp {
    Stamp::from_ns(T0_NS).plus_secs(t_s)
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// Rotates `d` by a random small angle with N(0, σ²) components on both tangent axes.
fn perturb(d: &Unit<Vector3<f64>>, sigma: f64, rng: &mut ChaCha8Rng) -> Unit<Vector3<f64>> {
    let (b1, b2) = tangent_basis(d);
    let (a1, a2) = (gauss(rng) * sigma, gauss(rng) * sigma);
    let angle = (a1 * a1 + a2 * a2).sqrt();
    if angle == 0.0 {
        return *d;
    }
    let axis = (b1 * a1 + b2 * a2) / angle;
    Unit::new_normalize(d.into_inner() * angle.cos() + axis * angle.sin())
}

/// A noisy DoA ray from `origin` toward `source`.
fn doa(origin: Point3<f64>, source: &Point3<f64>, sigma: f64, rng: &mut ChaCha8Rng) -> Ray {
    let d = Unit::new_normalize(source - origin);
    Ray {
        origin_in_map: origin,
        direction_in_map: perturb(&d, sigma, rng),
        sigma_rad: sigma,
        origin_sigma_m: 0.0,
        fold: None,
    }
}

/// Stamps (s) of a robot publishing at `rate_hz` from `phase_s` with ±`jitter_s` jitter.
fn schedule(rate_hz: f64, phase_s: f64, jitter_s: f64, end_s: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..)
        .map(|k| phase_s + k as f64 / rate_hz + rng.random_range(-jitter_s..=jitter_s))
        .take_while(|t| *t < end_s)
        .collect()
}

/// NEES eᵀP⁻¹e of the position (3 dof) and of the full state (6 dof).
fn nees(e: &TrackEstimate, position: &Point3<f64>, velocity: &Vector3<f64>) -> (f64, f64) {
    let dp = e.position_in_map - position;
    let pos = e.position_covariance().cholesky().expect("SPD position covariance").solve(&dp);
    let mut err = Vector6::zeros();
    err.fixed_rows_mut::<3>(0).copy_from(&dp);
    err.fixed_rows_mut::<3>(3).copy_from(&(e.velocity_in_map - velocity));
    let full = e.covariance.cholesky().expect("SPD covariance").solve(&err);
    (dp.dot(&pos), err.dot(&full))
}

/// χ² quantile for many degrees of freedom (Wilson–Hilferty; relative error
/// below 1e-4 beyond a few hundred dof).
fn chi2_wilson_hilferty(dof: usize, p: f64) -> f64 {
    let (k, z) = (dof as f64, normal_quantile(p));
    let h = 2.0 / (9.0 * k);
    k * (1.0 - h + z * h.sqrt()).powi(3)
}

/// The filter's own model, matched to how these tests draw the truth: the
/// single CV filter (the IMM's still mode would be a mismatched model here;
/// `tracking::imm` tests the modes), no variance inflation.
fn ideal_config() -> TrackerConfig {
    TrackerConfig {
        doa_variance_inflation: 1.0,
        init_covariance_inflation: 1.0,
        still_mode: false,
        ..TrackerConfig::default()
    }
}

fn finite(e: &TrackEstimate) -> bool {
    e.position_in_map.iter().chain(e.velocity_in_map.iter()).chain(e.covariance.iter()).all(|v| v.is_finite())
        && e.position_rms_m.is_finite()
        && e.last_nis.is_none_or(f64::is_finite)
        && e.mean_nis.is_none_or(f64::is_finite)
}

// ---------------------------------------------------------------------------------------------
// Static source

const STATIC_SOURCE: Point3<f64> = Point3::new(2.0, 2.5, 1.4);
const STATIC_ROBOTS: [Point3<f64>; 2] = [Point3::new(0.0, 0.0, 0.5), Point3::new(4.0, 0.0, 0.5)];
const SIGMA_3DEG: f64 = 3.0 * std::f64::consts::PI / 180.0;

/// Time-ordered DoAs of the two static robots at 10 Hz each, asynchronous.
fn static_doas(end_s: f64, rng: &mut ChaCha8Rng) -> Vec<(f64, u32, Ray)> {
    let mut all = Vec::new();
    for (i, (o, phase)) in STATIC_ROBOTS.iter().zip([0.0, 0.05]).enumerate() {
        for t in schedule(10.0, phase + 0.011, 0.01, end_s, rng) {
            all.push((t, i as u32, doa(*o, &STATIC_SOURCE, SIGMA_3DEG, rng)));
        }
    }
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    all
}

fn static_config() -> TrackerConfig {
    TrackerConfig {
        accel_psd_horizontal_m2_per_s3: 1e-4,
        accel_psd_vertical_m2_per_s3: 1e-5,
        initial_velocity_sigma_horizontal_m_per_s: 0.1,
        initial_velocity_sigma_vertical_m_per_s: 0.05,
        ..ideal_config()
    }
}

/// Starts `tracker` from the triangulation of the first DoA of each robot and
/// returns the triangulated point and the index of the first DoA not used.
fn start_from_first_pair(tracker: &mut SourceTracker, doas: &[(f64, u32, Ray)]) -> (Point3<f64>, usize) {
    let second = doas.iter().position(|d| d.1 != doas[0].1).expect("two robots");
    let rays = [doas[0].2, doas[second].2];
    let tri = triangulate(&rays, &TriangulationConfig::default());
    let sol = tri.solution().expect("a point").clone();
    let cov = sol.quality.covariance.expect("covariance");
    assert!(matches!(
        tracker.initialize(at(doas[second].0), sol.source_in_map, cov),
        InitOutcome::Started { .. }
    ));
    (sol.source_in_map, second + 1)
}

/// Runs the static scenario; returns (triangulation RMS, tracker RMS, mean final
/// position NEES, mean predicted RMS) over `runs` seeds.
fn run_static(config: &TrackerConfig, runs: u64, end_s: f64) -> (f64, f64, f64, f64) {
    let (mut tri_sq, mut filt_sq, mut nees_sum, mut predicted) = (0.0, 0.0, 0.0, 0.0);
    for seed in 0..runs {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let doas = static_doas(end_s, &mut rng);
        let mut tracker = SourceTracker::new(config.clone());
        let (tri_point, first) = start_from_first_pair(&mut tracker, &doas);
        tri_sq += (tri_point - STATIC_SOURCE).norm_squared();
        for (t, robot, ray) in &doas[first..] {
            tracker.update(at(*t), *robot, ray);
        }
        let e = tracker.estimate().unwrap();
        filt_sq += (e.position_in_map - STATIC_SOURCE).norm_squared();
        nees_sum += nees(&e, &STATIC_SOURCE, &Vector3::zeros()).0;
        predicted += e.position_rms_m;
        assert_eq!(e.state, TrackState::Confirmed, "seed {seed}");
        assert!(e.trusted);
        assert!(e.counts.applied >= 190, "seed {seed}: {:?}", e.counts);
    }
    let n = runs as f64;
    ((tri_sq / n).sqrt(), (filt_sq / n).sqrt(), nees_sum / n, predicted / n)
}

#[test]
fn static_source_converges_well_below_one_triangulation() {
    let (runs, end_s) = (50, 10.0);
    let sensors: Vec<Sensor> = STATIC_ROBOTS
        .iter()
        .map(|o| Sensor { origin: *o, sigma_rad: SIGMA_3DEG, origin_sigma_m: 0.0 })
        .collect();
    // 100 DoA pairs of a static source: the bound of the pooled data.
    let bound = assess(&sensors, &STATIC_SOURCE).rms_m / 10.0;
    // 95 % interval of the mean of `runs` χ²₃ draws.
    let k = 3 * runs as usize;
    let (lo, hi) = (chi2_quantile(k, 0.025) / runs as f64, chi2_quantile(k, 0.975) / runs as f64);
    // (name, config, largest ratio to one triangulation's RMS, largest ratio to the pooled bound)
    for (name, config, vs_triangulation, vs_bound) in [
        ("CV model, q̃ 1e-4", static_config(), 0.3, 3.0),
        // Nearly a constant-position model: the tracker should pool all DoAs.
        (
            "CV model, q̃ 1e-9",
            TrackerConfig {
                accel_psd_horizontal_m2_per_s3: 1e-9,
                accel_psd_vertical_m2_per_s3: 1e-9,
                initial_velocity_sigma_horizontal_m_per_s: 1e-3,
                initial_velocity_sigma_vertical_m_per_s: 1e-3,
                ..static_config()
            },
            0.15,
            1.25,
        ),
    ] {
        let (tri_rms, filt_rms, mean_nees, predicted) = run_static(&config, runs, end_s);
        println!(
            "static, 2 robots, σ 3°, 10 Hz each, {end_s} s, {runs} seeds, {name}: one triangulation RMS \
             {tri_rms:.3} m, tracker RMS {filt_rms:.4} m (its own predicted RMS {predicted:.4} m; bound of the \
             pooled DoAs {bound:.4} m), final position NEES {mean_nees:.2} (95 % [{lo:.2}, {hi:.2}])"
        );
        assert!(
            filt_rms < vs_triangulation * tri_rms,
            "{name}: tracker {filt_rms} vs triangulation {tri_rms}"
        );
        assert!(filt_rms < vs_bound * bound, "{name}: tracker {filt_rms} vs the pooled bound {bound}");
        assert!(filt_rms > 0.7 * bound, "{name}: tracker {filt_rms} below the bound {bound}?");
        assert!(mean_nees > lo && mean_nees < hi, "{name}: position NEES {mean_nees} outside [{lo}, {hi}]");
    }
}

// ---------------------------------------------------------------------------------------------
// Moving source

/// The true source: the CV model driven by white-noise acceleration with PSDs
/// `q` (m²/s³, x y z), sampled exactly at increasing times (the filter's model).
struct Truth {
    t: f64,
    p: Vector3<f64>,
    v: Vector3<f64>,
    q: [f64; 3],
}

impl Truth {
    fn advance(&mut self, t: f64, rng: &mut ChaCha8Rng) {
        let dt = t - self.t;
        if dt <= 0.0 {
            return;
        }
        for k in 0..3 {
            // Cholesky factor of q[dt³/3 dt²/2; dt²/2 dt].
            let q = self.q[k];
            let (l11, l21, l22) =
                ((q * dt.powi(3) / 3.0).sqrt(), (3.0 * q * dt).sqrt() / 2.0, (q * dt).sqrt() / 2.0);
            let (w1, w2) = (gauss(rng), gauss(rng));
            self.p[k] += self.v[k] * dt + l11 * w1;
            self.v[k] += l21 * w1 + l22 * w2;
        }
        self.t = t;
    }

    fn position(&self) -> Point3<f64> {
        Point3::from(self.p)
    }
}

/// Robot `i`'s array centre at `t` (s): 0 is parked in a corner, 1 follows the
/// source at 3 m on a slowly turning bearing, 2 drives along a straight line.
fn robot_position(i: usize, t: f64, source: &Point3<f64>) -> Point3<f64> {
    match i {
        0 => Point3::new(1.0, 7.0, 0.5),
        1 => {
            let b = (30.0 + 2.0 * t).to_radians();
            Point3::new(source.x + 3.0 * b.cos(), source.y + 3.0 * b.sin(), 0.5)
        }
        _ => Point3::new(9.0 - 0.25 * t, 1.0 + 0.15 * t, 0.45),
    }
}

const ROBOT_RATES_HZ: [f64; 3] = [10.0, 15.0, 20.0];
const MOVING_Q: [f64; 3] = [0.01, 0.01, 0.0005];

fn moving_config() -> TrackerConfig {
    TrackerConfig {
        accel_psd_horizontal_m2_per_s3: MOVING_Q[0],
        accel_psd_vertical_m2_per_s3: MOVING_Q[2],
        initial_velocity_sigma_horizontal_m_per_s: 0.5,
        initial_velocity_sigma_vertical_m_per_s: 0.1,
        ..ideal_config()
    }
}

/// One DoA of the moving scenario.
#[derive(Clone, Copy, Debug)]
struct Doa {
    t: f64,
    robot: u32,
    ray: Ray,
    /// The true source at `t`.
    source: Point3<f64>,
}

/// What a moving run is evaluated with: the truth at the evaluation times.
struct MovingRun {
    doas: Vec<Doa>,
    /// (t, position, velocity) of the truth on the evaluation grid.
    truth: Vec<(f64, Point3<f64>, Vector3<f64>)>,
}

/// A run of `end_s` seconds with `robots` robots: the source starts at
/// (3.5, 3.5, 1.3) moving at 0.5 m/s (with a vertical component); DoAs σ 3°.
fn moving_run(robots: usize, end_s: f64, eval_dt_s: f64, seed: u64) -> MovingRun {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut events: Vec<(f64, Option<u32>)> = Vec::new();
    for (i, rate) in ROBOT_RATES_HZ.iter().take(robots).enumerate() {
        let phase = rng.random_range(0.0..1.0 / rate);
        events.extend(
            schedule(*rate, phase + 0.006, 0.005, end_s, &mut rng).into_iter().map(|t| (t, Some(i as u32))),
        );
    }
    events.extend((1..).map(|k| k as f64 * eval_dt_s).take_while(|t| *t < end_s).map(|t| (t, None)));
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut truth =
        Truth { t: 0.0, p: Vector3::new(3.5, 3.5, 1.3), v: Vector3::new(0.4, 0.29, 0.06), q: MOVING_Q };
    let mut run = MovingRun { doas: Vec::new(), truth: Vec::new() };
    for (t, robot) in events {
        truth.advance(t, &mut rng);
        let s = truth.position();
        match robot {
            Some(i) => {
                let ray = doa(robot_position(i as usize, t, &s), &s, SIGMA_3DEG, &mut rng);
                run.doas.push(Doa { t, robot: i, ray, source: s });
            }
            None => run.truth.push((t, s, truth.v)),
        }
    }
    run
}

/// Starts a tracker from the triangulation of the first DoA of each robot;
/// returns it and the index of the first DoA after the initialization stamp.
fn start_moving(config: &TrackerConfig, run: &MovingRun, robots: usize) -> (SourceTracker, usize) {
    let mut first: Vec<Option<usize>> = vec![None; robots];
    for (k, d) in run.doas.iter().enumerate() {
        first[d.robot as usize].get_or_insert(k);
    }
    let idx: Vec<usize> = first.into_iter().map(|f| f.expect("every robot speaks")).collect();
    let rays: Vec<Ray> = idx.iter().map(|k| run.doas[*k].ray).collect();
    let last = *idx.iter().max().unwrap();
    let sol = triangulate(&rays, &TriangulationConfig::default()).solution().expect("a point").clone();
    let mut tracker = SourceTracker::new(config.clone());
    let init = tracker.initialize(
        at(run.doas[last].t),
        sol.source_in_map,
        sol.quality.covariance.expect("covariance"),
    );
    assert!(matches!(init, InitOutcome::Started { .. }));
    (tracker, last + 1)
}

/// Ensemble statistics of `runs` moving runs.
#[derive(Debug, Default)]
struct Ensemble {
    /// Per evaluation time: sums over runs of position and full NEES.
    nees_pos: Vec<f64>,
    nees_full: Vec<f64>,
    nis_sum: f64,
    nis_count: usize,
    gated: u64,
    sq_err: f64,
    sq_count: usize,
    confirmed_at_end: usize,
}

fn moving_ensemble(robots: usize, runs: u64) -> Ensemble {
    let (end_s, eval_dt_s, settle_s) = (10.0, 0.1, 2.0);
    let config = moving_config();
    let mut ens = Ensemble::default();
    for seed in 0..runs {
        let run = moving_run(robots, end_s, eval_dt_s, 1000 * robots as u64 + seed);
        let (mut tracker, mut next) = start_moving(&config, &run, robots);
        if ens.nees_pos.is_empty() {
            ens.nees_pos = vec![0.0; run.truth.len()];
            ens.nees_full = vec![0.0; run.truth.len()];
        }
        for (j, (t, p, v)) in run.truth.iter().enumerate() {
            while next < run.doas.len() && run.doas[next].t <= *t {
                let d = &run.doas[next];
                match tracker.update(at(d.t), d.robot, &d.ray) {
                    UpdateOutcome::Applied { nis } => {
                        (ens.nis_sum, ens.nis_count) = (ens.nis_sum + nis, ens.nis_count + 1)
                    }
                    UpdateOutcome::Gated { nis, .. } => {
                        (ens.nis_sum, ens.nis_count) = (ens.nis_sum + nis, ens.nis_count + 1);
                        ens.gated += 1;
                    }
                    other => panic!("seed {seed}: unexpected {other:?}"),
                }
                next += 1;
            }
            let e = tracker.predict_to(at(*t)).unwrap();
            let (np, nf) = nees(&e, p, v);
            ens.nees_pos[j] += np;
            ens.nees_full[j] += nf;
            if *t >= settle_s {
                ens.sq_err += (e.position_in_map - p).norm_squared();
                ens.sq_count += 1;
            }
        }
        let e = tracker.estimate().unwrap();
        assert!(finite(&e));
        ens.confirmed_at_end += usize::from(e.state == TrackState::Confirmed);
    }
    ens
}

#[test]
fn moving_source_is_tracked_consistently() {
    let runs = 100;
    for robots in [2, 3] {
        let ens = moving_ensemble(robots, runs);
        let k = runs as f64;
        let steps = ens.nees_pos.len();
        let interval = |dof: usize| {
            (chi2_quantile(dof * runs as usize, 0.025) / k, chi2_quantile(dof * runs as usize, 0.975) / k)
        };
        let (lo3, hi3) = interval(3);
        let (lo6, hi6) = interval(6);
        let mean3 = ens.nees_pos.iter().sum::<f64>() / (k * steps as f64);
        let mean6 = ens.nees_full.iter().sum::<f64>() / (k * steps as f64);
        let inside3 =
            ens.nees_pos.iter().filter(|s| (lo3..=hi3).contains(&(*s / k))).count() as f64 / steps as f64;
        let inside6 =
            ens.nees_full.iter().filter(|s| (lo6..=hi6).contains(&(*s / k))).count() as f64 / steps as f64;
        let n = ens.nis_count;
        let nis = ens.nis_sum / n as f64;
        let (nis_lo, nis_hi) =
            (chi2_wilson_hilferty(2 * n, 0.025) / n as f64, chi2_wilson_hilferty(2 * n, 0.975) / n as f64);
        let rms = (ens.sq_err / ens.sq_count as f64).sqrt();
        println!(
            "moving 0.5 m/s, {robots} robots, σ 3°, {runs} seeds × 10 s: RMS position error (t ≥ 2 s) {rms:.3} m; \
             mean NEES pos {mean3:.3} (95 % [{lo3:.2}, {hi3:.2}], {:.0} % of times inside), \
             full {mean6:.3} (95 % [{lo6:.2}, {hi6:.2}], {:.0} % inside); mean NIS {nis:.4} over {n} DoAs \
             (95 % [{nis_lo:.3}, {nis_hi:.3}]), gated {}, confirmed at end {}/{runs}",
            100.0 * inside3,
            100.0 * inside6,
            ens.gated,
            ens.confirmed_at_end,
        );
        assert!(mean3 > lo3 && mean3 < hi3, "{robots} robots: position NEES {mean3}");
        assert!(mean6 > lo6 && mean6 < hi6, "{robots} robots: full NEES {mean6}");
        assert!(inside3 >= 0.85 && inside6 >= 0.85, "{robots} robots: {inside3} / {inside6} of times inside");
        assert!(nis > nis_lo && nis < nis_hi, "{robots} robots: NIS {nis}");
        assert_eq!(ens.confirmed_at_end, runs as usize);
    }
}

// ---------------------------------------------------------------------------------------------
// The fixed-lag smoother

/// The smoothed states of the moving runs (model-matched, the single CV
/// filter: the Rauch–Tung–Striebel smoother up to the history's 50 ms
/// spacing) against the truth at their stamps, beside the live filter's
/// estimate at the same stamps: it is better and as honest.
#[test]
fn the_smoothed_state_is_better_than_the_live_one_and_consistent() {
    let config = TrackerConfig { smoothing_lag_s: 1.0, ..moving_config() };
    let (mut sq_live, mut sq_smoothed, mut nees_sum, mut n) = (0.0, 0.0, 0.0, 0usize);
    for seed in 0..40 {
        let run = moving_run(2, 10.0, 1.0, 7000 + seed);
        let (mut tracker, next) = start_moving(&config, &run, 2);
        let start = run.doas[next - 1].t;
        // The live estimate and the truth at every applied DoA's stamp.
        let mut live: std::collections::HashMap<i64, (TrackEstimate, Point3<f64>)> = Default::default();
        let mut last_smoothed = None;
        for d in &run.doas[next..] {
            let applied = matches!(feed(&mut tracker, d), UpdateOutcome::Applied { .. });
            if applied {
                live.insert(at(d.t).as_ns(), (tracker.estimate().unwrap(), d.source));
            }
            let Some(s) = tracker.smoothed() else {
                assert!(
                    d.t - start < 1.0 + 0.1,
                    "seed {seed}: no smoothed state {} s after the start",
                    d.t - start
                );
                continue;
            };
            assert!((1.0..1.2).contains(&s.lag_s), "seed {seed}: lag {}", s.lag_s);
            assert!(s.stamp <= at(d.t).plus_secs(-1.0));
            if last_smoothed == Some(s.stamp) || s.stamp.seconds_since(at(start)) < 3.0 {
                continue;
            }
            last_smoothed = Some(s.stamp);
            let (e, truth) = live[&s.stamp.as_ns()];
            sq_live += (e.position_in_map - truth).norm_squared();
            let err = s.position_in_map - truth;
            sq_smoothed += err.norm_squared();
            nees_sum += err.dot(&s.position_covariance().cholesky().unwrap().solve(&err));
            n += 1;
        }
    }
    let (live, smoothed, nees) =
        ((sq_live / n as f64).sqrt(), (sq_smoothed / n as f64).sqrt(), nees_sum / n as f64);
    println!(
        "{n} smoothed states: RMS {smoothed:.4} m against the live {live:.4} m at the same stamps; NEES {nees:.2}"
    );
    assert!(n > 40 * 40, "{n}");
    assert!(smoothed < 0.7 * live, "smoothed RMS {smoothed} vs live {live}");
    assert!((2.4..3.6).contains(&nees), "smoothed NEES {nees} (3 when consistent)");
}

#[test]
fn a_lost_track_has_no_smoothed_state() {
    let config = TrackerConfig { smoothing_lag_s: 1.0, ..moving_config() };
    let run = moving_run(2, 4.0, 1.0, 4);
    let (mut tracker, next) = start_moving(&config, &run, 2);
    for d in &run.doas[next..] {
        feed(&mut tracker, d);
    }
    assert!(tracker.smoothed().is_some());
    tracker.maintain(at(run.doas.last().unwrap().t + 60.0));
    assert!(tracker.loss().is_some());
    assert_eq!(tracker.smoothed(), None);
}

#[test]
fn no_smoothed_state_when_switched_off() {
    let config = TrackerConfig { smoothing_lag_s: 0.0, ..moving_config() };
    let run = moving_run(2, 4.0, 1.0, 3);
    let (mut tracker, next) = start_moving(&config, &run, 2);
    for d in &run.doas[next..] {
        feed(&mut tracker, d);
    }
    assert!(tracker.estimate().is_some_and(|e| e.counts.applied > 20));
    assert_eq!(tracker.smoothed(), None);
}

// ---------------------------------------------------------------------------------------------
// Out-of-sequence DoAs

fn feed(tracker: &mut SourceTracker, d: &Doa) -> UpdateOutcome {
    tracker.update(at(d.t), d.robot, &d.ray)
}

/// Largest difference between two estimates' numbers.
fn max_difference(a: &TrackEstimate, b: &TrackEstimate) -> f64 {
    let dp = (a.position_in_map - b.position_in_map).amax();
    let dv = (a.velocity_in_map - b.velocity_in_map).amax();
    let dc = (a.covariance - b.covariance).amax();
    dp.max(dv).max(dc)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]

    /// Delivering the DoAs of 3 robots with random delays below the lag gives
    /// the estimate of in-order processing.
    #[test]
    fn shuffled_arrivals_within_the_lag_give_the_in_order_estimate(seed in any::<u64>(), max_delay_s in 0.05f64..0.45) {
        let run = moving_run(3, 4.0, 1.0, seed);
        let (mut in_order, next) = start_moving(&moving_config(), &run, 3);
        let mut shuffled = in_order.clone();
        for d in &run.doas[next..] {
            feed(&mut in_order, d);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
        let mut arrivals: Vec<(f64, &Doa)> =
            run.doas[next..].iter().map(|d| (d.t + rng.random_range(0.0..max_delay_s), d)).collect();
        arrivals.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (mut newest, mut late) = (f64::MIN, 0);
        for (_, d) in arrivals {
            late += usize::from(d.t < newest);
            newest = newest.max(d.t);
            let outcome = feed(&mut shuffled, d);
            prop_assert!(matches!(outcome, UpdateOutcome::Applied { .. } | UpdateOutcome::Gated { .. }), "{outcome:?}");
        }
        prop_assert!(late > 0);
        let (a, b) = (in_order.estimate().unwrap(), shuffled.estimate().unwrap());
        prop_assert!(max_difference(&a, &b) < 1e-9, "difference {}", max_difference(&a, &b));
        prop_assert_eq!(a.stamp, b.stamp);
        prop_assert_eq!(a.state, b.state);
        prop_assert_eq!(a.counts, b.counts);
        prop_assert_eq!(a.last_nis, b.last_nis);
    }
}

#[test]
fn shuffling_reorders_a_lot_and_the_result_is_bit_identical() {
    let run = moving_run(3, 6.0, 1.0, 42);
    let (mut in_order, next) = start_moving(&moving_config(), &run, 3);
    let mut shuffled = in_order.clone();
    for d in &run.doas[next..] {
        feed(&mut in_order, d);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut arrivals: Vec<(f64, &Doa)> =
        run.doas[next..].iter().map(|d| (d.t + rng.random_range(0.0..0.45), d)).collect();
    arrivals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut newest, mut late) = (f64::MIN, 0);
    for (_, d) in &arrivals {
        late += usize::from(d.t < newest);
        newest = newest.max(d.t);
        feed(&mut shuffled, d);
    }
    let (a, b) = (in_order.estimate().unwrap(), shuffled.estimate().unwrap());
    println!(
        "out of sequence: {late} of {} DoAs arrived after a newer one; max difference to in-order {:e}",
        arrivals.len(),
        max_difference(&a, &b)
    );
    assert!(late * 3 > arrivals.len(), "the shuffle should reorder many DoAs ({late})");
    assert_eq!(a, b, "replay is exact");
}

#[test]
fn doas_older_than_the_lag_are_dropped_and_counted() {
    let run = moving_run(2, 5.0, 1.0, 5);
    let config = moving_config();
    let (mut reference, next) = start_moving(&config, &run, 2);
    let mut tracker = reference.clone();
    let doas = &run.doas[next..];
    // Every 7th DoA is held back and delivered 0.6 s late (the lag is 0.5 s).
    let held: Vec<&Doa> = doas.iter().skip(5).step_by(7).collect();
    let is_held = |d: &Doa| held.iter().any(|h| h.t == d.t && h.robot == d.robot);
    let mut pending = held.clone();
    for d in doas.iter().filter(|d| !is_held(d)) {
        assert!(matches!(
            feed(&mut reference, d),
            UpdateOutcome::Applied { .. } | UpdateOutcome::Gated { .. }
        ));
        feed(&mut tracker, d);
        while let Some(h) = pending.first().filter(|h| d.t > h.t + 0.6) {
            assert_eq!(feed(&mut tracker, h), UpdateOutcome::TooLate);
            pending.remove(0);
        }
    }
    let (a, b) = (reference.estimate().unwrap(), tracker.estimate().unwrap());
    assert_eq!(b.counts.too_late as usize, held.len() - pending.len());
    assert!(b.counts.too_late >= 10, "{:?}", b.counts);
    assert!(max_difference(&a, &b) < 1e-9);
    assert_eq!(a.counts.applied, b.counts.applied);
    // And a DoA stamped before the initialization is refused too.
    assert_eq!(feed(&mut tracker, &run.doas[0]), UpdateOutcome::BeforeTrack);
    assert_eq!(tracker.estimate().unwrap().counts.before_track, 1);
}

#[test]
fn same_seed_same_output() {
    let go = |seed| {
        let run = moving_run(3, 3.0, 1.0, seed);
        let (mut t, next) = start_moving(&moving_config(), &run, 3);
        let outcomes: Vec<UpdateOutcome> = run.doas[next..].iter().map(|d| feed(&mut t, d)).collect();
        (outcomes, t.estimate().unwrap())
    };
    assert_eq!(go(9), go(9));
    assert_ne!(go(9).1, go(10).1);
}

// ---------------------------------------------------------------------------------------------
// Gating and lifecycle

/// `ray` turned by `angle_rad` about the vertical.
fn turned(ray: &Ray, angle_rad: f64) -> Ray {
    let rot = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), angle_rad);
    Ray { direction_in_map: Unit::new_normalize(rot * ray.direction_in_map.into_inner()), ..*ray }
}

#[test]
fn gross_outliers_are_gated_and_the_track_survives() {
    // The single CV filter, and the IMM (whose mixing must not run at a gated DoA's stamp).
    for config in [static_config(), TrackerConfig { still_mode: true, ..static_config() }] {
        gross_outliers_are_gated(config);
    }
}

fn gross_outliers_are_gated(config: TrackerConfig) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let doas = static_doas(10.0, &mut rng);
    let mut clean = SourceTracker::new(config);
    let (_, first) = start_from_first_pair(&mut clean, &doas);
    let mut dirty = clean.clone();
    for (t, robot, ray) in &doas[first..] {
        clean.update(at(*t), *robot, ray);
        dirty.update(at(*t), *robot, ray);
        // A 40° wrong DoA from robot 1 at 5 s, and a second of 40° reflections from robot 0 at 7 s.
        let outlier = (*robot == 1 && (5.0..5.1).contains(t)) || (*robot == 0 && (7.0..8.0).contains(t));
        if outlier {
            let bad = doa(ray.origin_in_map, &STATIC_SOURCE, SIGMA_3DEG, &mut rng);
            let bad = turned(&bad, 40f64.to_radians());
            let stamp = at(*t + 0.001);
            let nis = dirty.nis(stamp, &bad).unwrap();
            assert!(nis > dirty.association_threshold());
            match dirty.update(stamp, *robot, &bad) {
                UpdateOutcome::Gated { nis: gated, threshold } => {
                    assert_eq!(gated, nis);
                    assert!(gated > 100.0 && threshold > 13.0 && threshold < 14.0, "{gated} {threshold}");
                }
                other => panic!("outlier not gated: {other:?}"),
            }
        }
    }
    let (c, d) = (clean.estimate().unwrap(), dirty.estimate().unwrap());
    assert_eq!(d.counts.gated, c.counts.gated + 11, "{:?} vs {:?}", d.counts, c.counts);
    assert_eq!(d.counts.applied, c.counts.applied);
    assert_eq!(d.state, TrackState::Confirmed);
    assert!(d.trusted);
    assert!((d.position_in_map - c.position_in_map).norm() < 1e-9);
    assert!((d.position_in_map - STATIC_SOURCE).norm() < 0.2);
}

#[test]
fn lifecycle_tentative_confirmed_lost_and_restarted() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let doas = static_doas(8.0, &mut rng);
    let config = TrackerConfig {
        confirm_updates: 6,
        confirm_min_robots: 2,
        confirm_window_s: 2.0,
        tentative_timeout_s: 2.0,
        lost_timeout_s: 3.0,
        ..static_config()
    };
    let mut tracker = SourceTracker::new(config.clone());
    assert!(tracker.needs_track());
    assert_eq!(tracker.update(at(1.0), 0, &doas[0].2), UpdateOutcome::NoTrack);
    let (_, first) = start_from_first_pair(&mut tracker, &doas);
    let e = tracker.estimate().unwrap();
    assert_eq!((e.state, e.trusted, e.track_id), (TrackState::Tentative, false, 1));
    assert!(!tracker.needs_track());

    // Robot 0 alone for 2 s: many accepted updates, one robot, still tentative.
    let rest = &doas[first..];
    let solo: Vec<_> = rest.iter().filter(|d| d.1 == 0 && d.0 < 2.0).collect();
    for (t, robot, ray) in &solo {
        tracker.update(at(*t), *robot, ray);
        assert_eq!(tracker.estimate().unwrap().state, TrackState::Tentative);
    }
    assert!(tracker.estimate().unwrap().counts.applied >= 15);
    // Then both robots: confirmed once the last 6 accepted updates include robot 1.
    let mut confirmed_after = None;
    for (k, (t, robot, ray)) in rest.iter().filter(|d| d.0 >= 2.0).enumerate() {
        tracker.update(at(*t), *robot, ray);
        if confirmed_after.is_none() && tracker.estimate().unwrap().state == TrackState::Confirmed {
            confirmed_after = Some(k + 1);
        }
    }
    let confirmed_after = confirmed_after.expect("confirmed");
    assert!(confirmed_after <= 2, "confirmed after {confirmed_after} two-robot updates");
    let e = tracker.estimate().unwrap();
    assert!(e.trusted);
    let last = e.stamp;

    // The estimate is not trusted when predicted far ahead, though still confirmed.
    let far = tracker.predict_to(last.plus_secs(20.0)).unwrap();
    assert_eq!(far.state, TrackState::Confirmed);
    assert!(!far.trusted && far.position_rms_m > config.trusted_max_rms_m);
    // predict_to does not change the track.
    assert_eq!(tracker.estimate().unwrap(), e);

    // Silence: still confirmed at 2.9 s, lost at 3.1 s.
    tracker.maintain(last.plus_secs(2.9));
    assert_eq!(tracker.estimate().unwrap().state, TrackState::Confirmed);
    tracker.maintain(last.plus_secs(3.1));
    let e = tracker.estimate().unwrap();
    assert!(matches!(e.state, TrackState::Lost(LossReason::Silent { silent_s }) if silent_s > 3.0));
    assert!(!e.trusted && tracker.needs_track());
    assert_eq!(tracker.update(last.plus_secs(3.2), 0, &doas[0].2), UpdateOutcome::NoTrack);

    // A new triangulation restarts a tentative track with a new id.
    let tri = triangulate(&[doas[0].2, doas[1].2], &TriangulationConfig::default());
    let restart = last.plus_secs(3.3);
    assert_eq!(tracker.initialize_from_triangulation(restart, &tri), InitOutcome::Started { track_id: 2 });
    let e = tracker.estimate().unwrap();
    assert_eq!((e.state, e.counts.applied, e.stamp), (TrackState::Tentative, 0, restart));
    // Initialized from a triangulation, its covariance is the triangulation's × the inflation.
    let tri_cov = tri.solution().unwrap().quality.covariance.unwrap();
    assert!((e.position_covariance() - tri_cov * config.init_covariance_inflation).amax() < 1e-12);

    // A tentative track that hears nothing is lost after its (shorter) timeout.
    tracker.maintain(restart.plus_secs(1.9));
    assert_eq!(tracker.estimate().unwrap().state, TrackState::Tentative);
    tracker.maintain(restart.plus_secs(2.1));
    assert!(matches!(tracker.estimate().unwrap().state, TrackState::Lost(LossReason::Silent { .. })));
}

#[test]
fn a_track_whose_covariance_explodes_is_lost() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let doas = static_doas(3.0, &mut rng);
    let config = TrackerConfig {
        accel_psd_horizontal_m2_per_s3: 0.5,
        lost_timeout_s: 1e6,
        lost_max_rms_m: 1.0,
        ..static_config()
    };
    let mut tracker = SourceTracker::new(config);
    let (_, first) = start_from_first_pair(&mut tracker, &doas);
    for (t, robot, ray) in &doas[first..] {
        tracker.update(at(*t), *robot, ray);
    }
    let last = tracker.estimate().unwrap().stamp;
    assert_eq!(tracker.estimate().unwrap().state, TrackState::Confirmed);
    tracker.maintain(last.plus_secs(0.5));
    assert_eq!(tracker.estimate().unwrap().state, TrackState::Confirmed);
    tracker.maintain(last.plus_secs(10.0));
    let e = tracker.estimate().unwrap();
    assert!(
        matches!(e.state, TrackState::Lost(LossReason::Diverged { position_rms_m }) if position_rms_m > 1.0)
    );
}

// ---------------------------------------------------------------------------------------------
// Degenerate inputs

#[test]
fn degenerate_inputs_never_give_nan() {
    let mut tracker = SourceTracker::new(ideal_config());
    let source = Point3::new(2.0, 1.0, 1.2);
    let cov = Matrix3::from_diagonal_element(0.04);
    // Bad initializations change nothing.
    let nan_cov = Matrix3::from_diagonal_element(f64::NAN);
    assert_eq!(tracker.initialize(at(0.0), source, nan_cov), InitOutcome::Rejected(InitRejection::NonFinite));
    assert_eq!(
        tracker.initialize(at(0.0), source, Matrix3::zeros()),
        InitOutcome::Rejected(InitRejection::NotPositiveDefinite)
    );
    assert!(tracker.estimate().is_none());
    // Parallel rays give no triangulation, hence no track.
    let o = [Point3::new(-1.0, 1.0, 1.2), Point3::new(-2.0, 1.0, 1.2)];
    let parallel: Vec<Ray> =
        o.iter().map(|o| doa(*o, &source, 0.0, &mut ChaCha8Rng::seed_from_u64(0))).collect();
    let tri = triangulate(&parallel, &TriangulationConfig::default());
    assert!(matches!(tri, Triangulation::Degenerate(_)));
    assert_eq!(
        tracker.initialize_from_triangulation(at(0.0), &tri),
        InitOutcome::Rejected(InitRejection::NoSolution)
    );

    assert!(matches!(tracker.initialize(at(0.0), source, cov), InitOutcome::Started { .. }));
    let good = doa(Point3::new(5.0, 1.0, 0.5), &source, SIGMA_3DEG, &mut ChaCha8Rng::seed_from_u64(1));
    // A ray from the source's own position, from 10 cm away, NaN and zero directions.
    let from_source = Ray { origin_in_map: source, ..good };
    let near = Ray { origin_in_map: source + Vector3::new(0.1, 0.0, 0.0), ..good };
    let nan = Ray { direction_in_map: Unit::new_unchecked(Vector3::new(f64::NAN, 0.0, 1.0)), ..good };
    let zero = Ray { direction_in_map: Unit::new_unchecked(Vector3::zeros()), ..good };
    let inf_sigma = Ray { sigma_rad: f64::INFINITY, ..good };
    assert_eq!(
        tracker.update(at(0.1), 0, &from_source),
        UpdateOutcome::Unusable(Unusable::TooClose { range_m: 0.0 })
    );
    assert!(matches!(tracker.update(at(0.2), 0, &near), UpdateOutcome::Unusable(Unusable::TooClose { .. })));
    for (k, ray) in [nan, zero, inf_sigma].iter().enumerate() {
        let outcome = tracker.update(at(0.3 + 0.01 * k as f64), 0, ray);
        assert_eq!(outcome, UpdateOutcome::Unusable(Unusable::NonFinite), "{k}");
        assert!(tracker.nis(at(0.35), ray).is_none());
    }
    // A ray pointing away from the source is gated, not applied.
    let away = Ray { direction_in_map: -good.direction_in_map, ..good };
    assert!(matches!(tracker.update(at(0.4), 0, &away), UpdateOutcome::Gated { .. }));
    let e = tracker.estimate().unwrap();
    assert!(finite(&e));
    assert_eq!((e.counts.unusable, e.counts.gated, e.counts.applied), (5, 1, 0));
    assert_eq!(e.position_in_map, source, "nothing was applied");

    // One robot, parallel rays for a minute: the depth is unobservable; the
    // numbers stay finite and the track is never confirmed nor trusted.
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for k in 0..600 {
        let ray = doa(Point3::new(5.0, 1.0, 0.5), &source, SIGMA_3DEG, &mut rng);
        tracker.update(at(1.0 + 0.1 * k as f64), 0, &ray);
        let e = tracker.estimate().unwrap();
        assert!(finite(&e), "step {k}");
        assert!(!e.trusted && e.state == TrackState::Tentative);
    }
    let e = tracker.predict_to(at(1e4)).unwrap();
    assert!(finite(&e) && !e.trusted);
}

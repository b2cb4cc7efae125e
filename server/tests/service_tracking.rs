//! Source tracking end to end over a real loopback socket: estimates carry the
//! filtered state beside the triangulation, the filter beats a single
//! triangulation, and its uncertainty is honest (NEES within χ² bounds). All
//! noise is seeded.

use crate::common;

use common::*;
use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use soundmap_proto::monitoring::covariance_from_wire;
use soundmap_proto::wire;
use soundmap_server::CoordinatorConfig;
use soundmap_server::stats::chi2_quantile;

const SOURCE: Point3<f64> = Point3::new(2.0, 3.0, 1.12);
const SIGMA_DEG: f64 = 3.0;

/// Bases of two robots 3 m (horizontally) from the source, 90° apart at the source.
fn bases() -> [Point3<f64>; 2] {
    [Point3::new(SOURCE.x - 3.0, SOURCE.y, 0.0), Point3::new(SOURCE.x, SOURCE.y - 3.0, 0.0)]
}

/// A random rotation with N(0, σ²) components (the radial one does nothing to a direction).
fn noise(rng: &mut ChaCha8Rng) -> UnitQuaternion<f64> {
    let sigma = SIGMA_DEG.to_radians();
    let v = Vector3::new(StandardNormal.sample(rng), StandardNormal.sample(rng), StandardNormal.sample(rng));
    UnitQuaternion::from_scaled_axis(v * sigma)
}

fn point(v: &wire::Vec3) -> Point3<f64> {
    Point3::new(v.x, v.y, v.z)
}

/// eᵀ C⁻¹ e.
fn nees(position: &wire::Vec3, covariance: &wire::Covariance3) -> f64 {
    let e = point(position) - SOURCE;
    let c: Matrix3<f64> = covariance_from_wire(covariance).unwrap();
    e.dot(&c.cholesky().expect("SPD covariance").solve(&e))
}

/// What one run of the static scenario published.
#[derive(Default)]
struct Run {
    /// Squared errors after the warm-up: the triangulation, the filter.
    tri_sq: Vec<f64>,
    filt_sq: Vec<f64>,
    /// NEES of the filtered state at the checkpoints.
    checkpoint_nees: Vec<f64>,
    /// NEES of every estimate published as trusted (its best position and covariance).
    trusted_nees: Vec<f64>,
    /// Estimates whose best position was the filter's.
    filtered_best: usize,
    /// Squared errors of the smoothed states, each distinct one once, and
    /// the NEES of the trusted ones against their published covariance.
    smoothed_sq: Vec<f64>,
    smoothed_trusted_nees: Vec<f64>,
    estimates: usize,
    source_ids: Vec<u64>,
}

const STEPS: usize = 100;
const WARM_UP_STEPS: usize = 20;
const CHECKPOINTS: [usize; 5] = [19, 39, 59, 79, 99];

/// Two robots stream σ = 3° DoAs of the static source at 10 Hz for 10 s.
async fn run(config: CoordinatorConfig, seed: u64) -> Run {
    let (coordinator, clock) = start(config).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    let [pa, pb] = bases();
    let sigma = SIGMA_DEG.to_radians();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Run::default();
    let mut last_smoothed = None;
    for k in 0..STEPS {
        let t = T0.plus_secs(0.1 * k as f64);
        clock.set(t);
        let s = a.observe(observation_of(t, pa, 0.2, &SOURCE, Some(noise(&mut rng)), sigma)).await;
        a.until_acked(s).await;
        let s = b.observe(observation_of(t, pb, -0.7, &SOURCE, Some(noise(&mut rng)), sigma)).await;
        b.until_acked(s).await;
        let e = next_estimate(&mut estimates).await;
        assert_eq!(e.stamp_ns, t.as_ns());
        out.estimates += 1;
        out.source_ids.push(e.source_id);
        let tri = e.triangulation.as_ref().expect("the triangulation is always published");
        assert_eq!(tri.robots, ["a", "b"]);
        if e.method == wire::EstimateMethod::KalmanFilter as i32 {
            let f = e.filtered.as_ref().expect("a filtered best estimate has its filtered state");
            assert!(f.trusted && f.state == wire::TrackState::Confirmed as i32, "{f:?}");
            assert_eq!(e.position_in_map_m, f.position_in_map_m);
            assert!(e.trusted);
            out.filtered_best += 1;
        } else {
            assert_eq!(e.position_in_map_m, tri.position_in_map_m, "else the best is the triangulation");
            assert_eq!(e.trusted, tri.gate == wire::GateDecision::Accepted as i32);
        }
        if e.trusted {
            out.trusted_nees
                .push(nees(e.position_in_map_m.as_ref().unwrap(), e.covariance.as_ref().unwrap()));
        }
        let f = e.filtered.as_ref().expect("the track starts on the first trusted triangulation");
        let fp = f.position_in_map_m.as_ref().unwrap();
        if k >= WARM_UP_STEPS {
            out.tri_sq.push((point(tri.position_in_map_m.as_ref().unwrap()) - SOURCE).norm_squared());
            out.filt_sq.push((point(fp) - SOURCE).norm_squared());
        }
        if CHECKPOINTS.contains(&k) {
            out.checkpoint_nees.push(nees(fp, f.position_covariance.as_ref().unwrap()));
        }
        if let Some(s) = &e.smoothed {
            // About a second behind the estimate, and trusted only with the track.
            assert!((1.0..1.2).contains(&s.lag_s), "{s:?}");
            assert!(s.stamp_ns < e.stamp_ns - 900_000_000, "{s:?} at {}", e.stamp_ns);
            assert!(!s.trusted || f.trusted, "{s:?} {f:?}");
            let p = s.position_in_map_m.as_ref().unwrap();
            if last_smoothed != Some(s.stamp_ns) && k >= WARM_UP_STEPS {
                out.smoothed_sq.push((point(p) - SOURCE).norm_squared());
                if s.trusted {
                    out.smoothed_trusted_nees.push(nees(p, s.position_covariance.as_ref().unwrap()));
                }
            }
            last_smoothed = Some(s.stamp_ns);
        } else {
            assert!(k < WARM_UP_STEPS, "step {k}: no smoothed state");
        }
    }
    drop((a, b));
    coordinator.shutdown().await.unwrap();
    out
}

/// The tracker tuned for a static talker, with the noise model the simulation
/// uses: the still mode does not diffuse (the source is fixed) and the moving
/// mode barely accelerates.
fn static_talker() -> CoordinatorConfig {
    let mut c = CoordinatorConfig::default();
    c.tracking.still_diffusion_horizontal_m2_per_s = 1e-6;
    c.tracking.still_diffusion_vertical_m2_per_s = 1e-7;
    c.tracking.accel_psd_horizontal_m2_per_s3 = 1e-4;
    c.tracking.accel_psd_vertical_m2_per_s3 = 1e-5;
    c.tracking.initial_velocity_sigma_horizontal_m_per_s = 0.1;
    c.tracking.initial_velocity_sigma_vertical_m_per_s = 0.05;
    c.tracking.doa_variance_inflation = 1.0;
    c
}

struct Summary {
    tri_rms: f64,
    filt_rms: f64,
    /// Per checkpoint: mean NEES over the runs.
    checkpoint_mean_nees: Vec<f64>,
    trusted_mean_nees: f64,
    /// Fraction of trusted estimates with NEES above χ²₃(0.99).
    trusted_outliers: f64,
    filtered_best: f64,
    smoothed_rms: f64,
    smoothed_trusted_outliers: f64,
}

async fn runs(config: &CoordinatorConfig, n: u64) -> Summary {
    let mut all = Vec::new();
    for seed in 0..n {
        let r = run(config.clone(), 100 + seed).await;
        let first_id = r.source_ids.iter().copied().find(|id| *id != 0).expect("a track started");
        assert!(
            r.source_ids.iter().skip_while(|id| **id == 0).all(|id| *id == first_id),
            "seed {seed}: the source id changed on a static source: {:?}",
            r.source_ids
        );
        all.push(r);
    }
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let gate = chi2_quantile(3, 0.99);
    let trusted: Vec<f64> = all.iter().flat_map(|r| r.trusted_nees.clone()).collect();
    Summary {
        tri_rms: mean(all.iter().flat_map(|r| r.tri_sq.clone()).collect()).sqrt(),
        filt_rms: mean(all.iter().flat_map(|r| r.filt_sq.clone()).collect()).sqrt(),
        checkpoint_mean_nees: (0..CHECKPOINTS.len())
            .map(|i| mean(all.iter().map(|r| r.checkpoint_nees[i]).collect()))
            .collect(),
        trusted_outliers: trusted.iter().filter(|v| **v > gate).count() as f64 / trusted.len() as f64,
        trusted_mean_nees: mean(trusted),
        filtered_best: all.iter().map(|r| r.filtered_best).sum::<usize>() as f64
            / all.iter().map(|r| r.estimates).sum::<usize>() as f64,
        smoothed_rms: mean(all.iter().flat_map(|r| r.smoothed_sq.clone()).collect()).sqrt(),
        smoothed_trusted_outliers: {
            let n: Vec<f64> = all.iter().flat_map(|r| r.smoothed_trusted_nees.clone()).collect();
            n.iter().filter(|v| **v > gate).count() as f64 / n.len() as f64
        },
    }
}

/// Static source, 20 seeded runs: the filtered position is several times
/// better than one triangulation, its NEES at each checkpoint is within the
/// two-sided 99 % χ² interval of the 20-run mean, and estimates published as
/// trusted are consistent with their covariance.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn filtered_estimates_beat_triangulation_and_are_consistent() {
    let n = 20u64;
    let s = runs(&static_talker(), n).await;
    let dof = 3 * n as usize;
    let (lo, hi) = (chi2_quantile(dof, 0.005) / n as f64, chi2_quantile(dof, 0.995) / n as f64);
    println!(
        "static source, 2 robots at 90°, σ {SIGMA_DEG}°, 10 Hz, {n} runs of 10 s (after 2 s): triangulation RSE \
         {:.3} m, filtered RSE {:.4} m ({:.2}×); filtered NEES per checkpoint {:.2?} (99 % [{lo:.2}, {hi:.2}]); \
         trusted estimates: mean NEES {:.2}, {:.1} % above χ²₃(0.99); best = filter in {:.0} % of estimates; \
         smoothed states RSE {:.4} m, {:.1} % of the trusted above χ²₃(0.99)",
        s.tri_rms,
        s.filt_rms,
        s.filt_rms / s.tri_rms,
        s.checkpoint_mean_nees,
        s.trusted_mean_nees,
        100.0 * s.trusted_outliers,
        100.0 * s.filtered_best,
        s.smoothed_rms,
        100.0 * s.smoothed_trusted_outliers,
    );
    assert!(s.smoothed_rms < s.filt_rms, "smoothed {} vs filtered {}", s.smoothed_rms, s.filt_rms);
    assert!(
        s.smoothed_trusted_outliers < 0.03,
        "{:.3} of trusted smoothed states",
        s.smoothed_trusted_outliers
    );
    assert!(s.filt_rms < 0.3 * s.tri_rms, "filtered {} vs triangulation {}", s.filt_rms, s.tri_rms);
    for (k, m) in CHECKPOINTS.iter().zip(&s.checkpoint_mean_nees) {
        assert!(*m > lo && *m < hi, "step {k}: mean NEES {m} outside [{lo}, {hi}]");
    }
    assert!(s.trusted_outliers < 0.03, "{:.3} of trusted estimates above the 99 % gate", s.trusted_outliers);
    assert!(s.trusted_mean_nees < 3.5, "trusted estimates overconfident: mean NEES {}", s.trusted_mean_nees);
    assert!(s.filtered_best > 0.8, "the confirmed track should carry most estimates: {}", s.filtered_best);
}

/// With the default tracker (tuned for a walking talker, DoA variance inflated
/// 1.5×) the filter is conservative: never overconfident, still better than one
/// triangulation.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn default_tracker_is_conservative_on_a_static_source() {
    let n = 10u64;
    let s = runs(&CoordinatorConfig::default(), n).await;
    let hi = chi2_quantile(3 * n as usize, 0.995) / n as f64;
    println!(
        "default tracker, {n} runs: triangulation RSE {:.3} m, filtered RSE {:.3} m; NEES per checkpoint {:.2?}; \
         trusted: mean NEES {:.2}, {:.1} % above χ²₃(0.99)",
        s.tri_rms,
        s.filt_rms,
        s.checkpoint_mean_nees,
        s.trusted_mean_nees,
        100.0 * s.trusted_outliers
    );
    assert!(s.filt_rms < 0.7 * s.tri_rms, "filtered {} vs triangulation {}", s.filt_rms, s.tri_rms);
    assert!(s.checkpoint_mean_nees.iter().all(|m| *m < hi), "overconfident: {:?}", s.checkpoint_mean_nees);
    assert!(s.trusted_outliers < 0.03 && s.trusted_mean_nees < 3.5);
}

/// Tracking off: no filtered state, source id 0, the best estimate is the triangulation.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tracking_can_be_switched_off() {
    let mut config = CoordinatorConfig::default();
    config.tracking.enabled = false;
    let (coordinator, clock) = start(config).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    let [pa, pb] = bases();
    for k in 0..30 {
        let t = T0.plus_secs(0.1 * k as f64);
        clock.set(t);
        let s = a.observe(observation_of(t, pa, 0.0, &SOURCE, None, 0.05)).await;
        a.until_acked(s).await;
        let s = b.observe(observation_of(t, pb, 0.0, &SOURCE, None, 0.05)).await;
        b.until_acked(s).await;
        let e = next_estimate(&mut estimates).await;
        assert!(e.filtered.is_none() && e.source_id == 0, "{e:?}");
        assert_eq!(e.method, wire::EstimateMethod::RayPair as i32);
        assert!(e.trusted);
    }
    coordinator.shutdown().await.unwrap();
}

/// A track lost to silence is replaced by a new one (new source id) when the
/// source is heard again; meanwhile the triangulation carries the estimate.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_track_is_replaced_with_a_new_id() {
    let (coordinator, clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    let [pa, pb] = bases();
    let mut step = async |t: soundmap_proto::Stamp| {
        clock.set(t);
        let s = a.observe(observation_of(t, pa, 0.0, &SOURCE, None, 0.02)).await;
        a.until_acked(s).await;
        let s = b.observe(observation_of(t, pb, 0.0, &SOURCE, None, 0.02)).await;
        b.until_acked(s).await;
    };
    for k in 0..20 {
        step(T0.plus_secs(0.1 * k as f64)).await;
    }
    let mut e = next_estimate(&mut estimates).await;
    for _ in 1..20 {
        e = next_estimate(&mut estimates).await;
    }
    let first = e.source_id;
    assert_ne!(first, 0);
    assert_eq!(e.method, wire::EstimateMethod::KalmanFilter as i32, "confirmed after 2 s: {e:?}");
    // 4 s of silence (> lost_timeout_s = 3 s), then the source speaks again.
    step(T0.plus_secs(6.0)).await;
    let e = next_estimate(&mut estimates).await;
    let f = e.filtered.as_ref().unwrap();
    assert_eq!(f.state, wire::TrackState::Tentative as i32, "a new track: {f:?}");
    assert_eq!(e.source_id, first + 1);
    assert_ne!(e.method, wire::EstimateMethod::KalmanFilter as i32);
    assert!(e.trusted, "the triangulation is trusted meanwhile");
    coordinator.shutdown().await.unwrap();
}

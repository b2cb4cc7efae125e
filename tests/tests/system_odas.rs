//! Robots that run ODAS: ODAS-like DoAs (truth + room bias + jitter, snapped
//! to ODAS's level-4 grid, see `soundmap_sim::odas_like`) written as SST JSON,
//! replayed with `soundmap-sim replay --robot id=…,odas=FILE.json,…` through the
//! agent core and the coordinator over gRPC, and compared with the paper's
//! closest-point method on the same DoAs.
//!
//! `cargo test -p soundmap-sim --test system_odas -- --nocapture` runs one
//! 60 s trial of each talker (swaying, walking); `-- --include-ignored` adds
//! the sweeps over seeds 1–5 (both talkers, and both with the single-mode
//! tracker). Each run is scored twice: the live estimates, and the smoothed
//! states published beside them a second behind (`SourceEstimate.smoothed`).

use std::time::Instant;

use soundmap_sim::odas_like::trial::{OdasTrial, OdasTrialSpec, write_trial};
use soundmap_sim::replay::{ReplayArgs, parse_robot, replay};
use soundmap_sim::report::RunRecord;

/// χ² (3 dof) at 0.99.
const CHI2_3_99: f64 = 11.345;
const BAND: (f64, f64) = (40.0, 140.0);

fn p95(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() as f64 * 0.95).ceil() as usize).clamp(1, v.len()) - 1])
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// The in-band p95 of the best causal constant-velocity Kalman filter on the
/// closest-point positions, its white-acceleration density q̃ chosen in
/// hindsight from a grid (per axis: position measurements of σ 0.5 m at every
/// hop, q̃ in m²/s³): a reference for what filtering alone can take out of
/// these DoAs. Returns (p95 m, q̃).
fn best_causal_cv(rows: &[soundmap_sim::odas_like::trial::ClosestPointRow]) -> (f64, f64) {
    use nalgebra::{Matrix2, Vector2};
    let in_band = |t: f64| (BAND.0..=BAND.1).contains(&t);
    let p95_for = |q: f64| {
        let r2 = 0.25;
        let mut state = [(Vector2::zeros(), Matrix2::identity() * 100.0); 3];
        let mut last_t: Option<f64> = None;
        let mut errors = Vec::new();
        for row in rows {
            let dt = last_t.map_or(0.0, |t| row.t_s - t);
            last_t = Some(row.t_s);
            let mut e2 = 0.0;
            for (axis, (x, p)) in state.iter_mut().enumerate() {
                let f = Matrix2::new(1.0, dt, 0.0, 1.0);
                let qm = Matrix2::new(dt.powi(3) / 3.0, dt.powi(2) / 2.0, dt.powi(2) / 2.0, dt) * q;
                *x = f * *x;
                *p = f * *p * f.transpose() + qm;
                let s = p[(0, 0)] + r2;
                let k = Vector2::new(p[(0, 0)], p[(1, 0)]) / s;
                let innovation = row.point[axis] - x[0];
                *x += k * innovation;
                *p -= k * Vector2::new(p[(0, 0)], p[(0, 1)]).transpose();
                e2 += (x[0] - row.truth[axis]).powi(2);
            }
            if in_band(row.true_theta_deg) {
                errors.push(e2.sqrt());
            }
        }
        p95(errors).unwrap_or(f64::NAN)
    };
    [0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0]
        .iter()
        .map(|&q| (p95_for(q), q))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap_or((f64::NAN, 0.0))
}

/// The figures of one trial.
#[derive(Debug)]
struct Figures {
    soundmap_p95_band: f64,
    soundmap_median: f64,
    /// The same for the smoothed states published beside the estimates
    /// (`summary.json`'s `smoothed`), scored at their own stamps.
    smoothed_p95_band: f64,
    smoothed_lag_s: f64,
    smoothed_inside_99: f64,
    smoothed_trusted_bad_low_theta: usize,
    closest_p95_band: f64,
    closest_median: f64,
    /// The best causal CV filter on the closest points, q̃ chosen in hindsight.
    best_cv_p95_band: (f64, f64),
    trusted: usize,
    trusted_bad_low_theta: usize,
    trusted_inside_99: f64,
    estimates: usize,
    replay_s: f64,
}

fn figures(record: &RunRecord, trial: &OdasTrial, replay_s: f64) -> Figures {
    let in_band = |t: f64| (BAND.0..=BAND.1).contains(&t);
    let derived = soundmap_sim::report::derived::Derived::new(record);
    let smoothed = soundmap_sim::report::Summary::new(record, &derived).smoothed;
    let scored: Vec<_> =
        record.rows.iter().filter_map(|r| Some((r, r.rse_m()?, r.true_theta_deg?))).collect();
    let trusted: Vec<_> = scored.iter().filter(|(r, ..)| r.trusted).collect();
    let inside = trusted.iter().filter(|(r, ..)| r.nees().is_some_and(|n| n <= CHI2_3_99)).count();
    Figures {
        soundmap_p95_band: p95(scored.iter().filter(|s| in_band(s.2)).map(|s| s.1).collect())
            .unwrap_or(f64::NAN),
        soundmap_median: median(scored.iter().map(|s| s.1).collect()).unwrap_or(f64::NAN),
        smoothed_p95_band: smoothed.as_ref().and_then(|s| s.rse_p95_in_band_m).unwrap_or(f64::NAN),
        smoothed_lag_s: smoothed.as_ref().and_then(|s| s.lag_mean_s).unwrap_or(f64::NAN),
        smoothed_inside_99: smoothed
            .as_ref()
            .and_then(|s| s.nees_above_chi2_99_trusted_ratio)
            .map_or(f64::NAN, |r| 1.0 - r),
        smoothed_trusted_bad_low_theta: smoothed.as_ref().map_or(0, |s| s.trusted_low_theta_over_0_5_m),
        closest_p95_band: p95(trial
            .closest_point
            .iter()
            .filter(|c| in_band(c.true_theta_deg))
            .map(|c| c.rse_m)
            .collect())
        .unwrap_or(f64::NAN),
        closest_median: median(trial.closest_point.iter().map(|c| c.rse_m).collect()).unwrap_or(f64::NAN),
        best_cv_p95_band: best_causal_cv(&trial.closest_point),
        trusted: trusted.len(),
        trusted_bad_low_theta: trusted.iter().filter(|(_, e, t)| t.min(180.0 - t) < 20.0 && *e > 0.5).count(),
        trusted_inside_99: if trusted.is_empty() { f64::NAN } else { inside as f64 / trusted.len() as f64 },
        estimates: scored.len(),
        replay_s,
    }
}

/// The tracker as it was before it learned the noise: no learning, no
/// consistency or geometry condition on trust, no restart.
const WITHOUT_HONEST_NOISE: &str = "[tracking]\nlearn_doa_noise = false\nconsistency_probability = 0.99999999\n\
    good_geometry_theta_deg = 0.0\nevidence_updates = 0\n";

fn run(seed: u64) -> Figures {
    run_with(seed, None, 0.0)
}

fn run_with(seed: u64, coordinator_toml: Option<&str>, walk_m_per_s: f64) -> Figures {
    // One directory per run: the sweeps may run in parallel.
    let tmp = tempfile::Builder::new().prefix(&format!("soundmap-odas-{seed}-")).tempdir().unwrap();
    let dir = tmp.path();
    let spec = OdasTrialSpec { seed, walk_m_per_s, ..OdasTrialSpec::default() };
    let trial = write_trial(dir, &spec).unwrap();
    // Through the command line's own parser, as a user would give it.
    let robots = trial.robots.iter().map(|r| parse_robot(&r.to_argument()).unwrap()).collect();
    let coordinator_config = coordinator_toml.map(|toml| {
        let path = dir.join("coordinator.toml");
        std::fs::write(&path, toml).unwrap();
        path
    });
    let args = ReplayArgs {
        robots,
        truths: vec![trial.truth.clone()],
        out: dir.join("out"),
        coordinator_config,
        pipeline: None,
        max_pose_gap_s: 0.5,
        rosbag: None,
        view: Default::default(),
    };
    let t0 = Instant::now();
    let record = replay(&args).unwrap();
    let f = figures(&record, &trial, t0.elapsed().as_secs_f64());
    if std::env::var_os("SOUNDMAP_KEEP_RUNS").is_some() {
        println!("kept {}", tmp.keep().display());
    }
    println!(
        "seed {seed}: in-band p95 soundmap {:.3} m vs closest point {:.3} m ({:+.0} %), smoothed {:.3} m ({:+.0} %, \
         {:.2} s behind, {:.1} % of trusted inside their 99 % ellipsoid, {} trusted at θ<20° with error>0.5 m), \
         best causal CV filter on \
         the closest points {:.3} m (q̃ {} in hindsight); median {:.3} vs {:.3} m; \
         {} estimates, {} trusted, {} trusted at θ<20° with error>0.5 m, {:.1} % of trusted inside their 99 % ellipsoid; \
         replay {:.2} s",
        f.soundmap_p95_band,
        f.closest_p95_band,
        100.0 * (f.soundmap_p95_band / f.closest_p95_band - 1.0),
        f.smoothed_p95_band,
        100.0 * (f.smoothed_p95_band / f.closest_p95_band - 1.0),
        f.smoothed_lag_s,
        100.0 * f.smoothed_inside_99,
        f.smoothed_trusted_bad_low_theta,
        f.best_cv_p95_band.0,
        f.best_cv_p95_band.1,
        f.soundmap_median,
        f.closest_median,
        f.estimates,
        f.trusted,
        f.trusted_bad_low_theta,
        100.0 * f.trusted_inside_99,
        f.replay_s
    );
    f
}

#[test]
fn odas_recording_replays_and_is_honest() {
    let f = run(1);
    assert!(f.estimates > 500, "{f:?}");
    assert!(f.trusted > 0, "some estimates are trusted: {f:?}");
    assert_eq!(f.trusted_bad_low_theta, 0, "{f:?}");
    assert!(f.soundmap_p95_band.is_finite() && f.closest_p95_band.is_finite(), "{f:?}");
    // The targets on this (swaying) talker: in-band p95 ≤ 0.3 m and
    // at least 25 % better than closest point on the same DoAs (seed 1
    // measured 0.214 m against 0.492 m).
    assert!(f.soundmap_p95_band <= 0.3, "{f:?}");
    assert!(f.soundmap_p95_band <= 0.75 * f.closest_p95_band, "{f:?}");
    assert!(f.trusted_inside_99 >= 0.97, "{f:?}");
    // The smoothed states (a second behind): as honest, and no worse.
    assert!(f.smoothed_p95_band <= f.soundmap_p95_band, "{f:?}");
    assert!(f.smoothed_inside_99 >= 0.97, "{f:?}");
    assert_eq!(f.smoothed_trusted_bad_low_theta, 0, "{f:?}");
}

/// The talker walking back and forth (0.7 m/s, ±1.5 m, 2 s pauses), seed 1:
/// the live estimate misses the in-band targets here (0.413 m against
/// closest point's 0.520 m); the smoothed states, a second behind, meet them
/// (0.243 m, measured 2026-11-27).
#[test]
fn odas_walking_talker_is_met_by_the_smoothed_states() {
    let f = run_with(1, None, 0.7);
    assert!(f.smoothed_p95_band <= 0.3, "{f:?}");
    assert!(f.smoothed_p95_band <= 0.75 * f.closest_p95_band, "{f:?}");
    assert!(f.smoothed_inside_99 >= 0.97, "{f:?}");
    assert_eq!(f.smoothed_trusted_bad_low_theta, 0, "{f:?}");
    assert_eq!(f.trusted_bad_low_theta, 0, "{f:?}");
}

#[test]
#[ignore = "sweep: seeds 1-5, ~1 min"]
fn odas_sweep() {
    sweep(None, 0.0);
}

#[test]
#[ignore = "sweep: seeds 1-5 with the talker walking back and forth at 0.7 m/s, ~1 min"]
fn odas_sweep_walking_talker() {
    sweep(None, 0.7);
}

/// The tracker's single CV filter (no still mode), for comparison.
const SINGLE_MODE: &str = "[tracking]\nstill_mode = false\n";

#[test]
#[ignore = "sweep: seeds 1-5 with the single-mode tracker, still and walking talker, ~2 min"]
fn odas_sweep_single_mode() {
    sweep(Some(SINGLE_MODE), 0.0);
    sweep(Some(SINGLE_MODE), 0.7);
}

#[test]
#[ignore = "sweep: seeds 1-5 with the tracker's noise learning and trust conditions off, ~1 min"]
fn odas_sweep_without_honest_noise() {
    sweep(Some(WITHOUT_HONEST_NOISE), 0.0);
}

fn sweep(coordinator_toml: Option<&str>, walk_m_per_s: f64) {
    let all: Vec<Figures> = (1..=5).map(|seed| run_with(seed, coordinator_toml, walk_m_per_s)).collect();
    let mean = |g: fn(&Figures) -> f64| all.iter().map(g).sum::<f64>() / all.len() as f64;
    println!(
        "{}{}seeds 1-5: in-band p95 soundmap {:.3} m vs closest point {:.3} m, smoothed {:.3} m \
         ({:.1} % of trusted inside 99 %, {} trusted bad at θ<20°) (best causal CV filter on the \
         closest points {:.3} m); trusted inside 99 %: {:.1} %; \
         trusted bad at θ<20°: {}; replay {:.2} s (max {:.2})",
        match coordinator_toml {
            Some(SINGLE_MODE) => "single mode: ",
            Some(_) => "without honest noise: ",
            None => "",
        },
        if walk_m_per_s > 0.0 { format!("talker walking at {walk_m_per_s} m/s: ") } else { String::new() },
        mean(|f| f.soundmap_p95_band),
        mean(|f| f.closest_p95_band),
        mean(|f| f.smoothed_p95_band),
        100.0 * mean(|f| f.smoothed_inside_99),
        all.iter().map(|f| f.smoothed_trusted_bad_low_theta).sum::<usize>(),
        mean(|f| f.best_cv_p95_band.0),
        100.0 * mean(|f| f.trusted_inside_99),
        all.iter().map(|f| f.trusted_bad_low_theta).sum::<usize>(),
        mean(|f| f.replay_s),
        all.iter().map(|f| f.replay_s).fold(0.0, f64::max),
    );
}

//! End to end over a real loopback socket: robots stream DoAs, the coordinator
//! publishes estimates (watch stream, JSON-lines file, GetState).

use crate::common;

use common::*;
use nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use soundmap_proto::monitoring::covariance_from_wire;
use soundmap_proto::wire;
use soundmap_server::CoordinatorConfig;
use soundmap_server::uncertainty::{Sensor, assess};

const SOURCE: Point3<f64> = Point3::new(2.0, 3.0, 1.12);

/// Bases of two robots 3 m (horizontally) from the source, 90° apart at the source.
fn bases() -> [Point3<f64>; 2] {
    [Point3::new(SOURCE.x - 3.0, SOURCE.y, 0.0), Point3::new(SOURCE.x, SOURCE.y - 3.0, 0.0)]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn exact_doas_give_the_source_within_a_millimetre() {
    let dir = tempfile::Builder::new().prefix("soundmap-e2e-").tempdir().unwrap();
    let jsonl = dir.path().join("estimates.jsonl");
    let mut config = CoordinatorConfig::default();
    config.output.estimates_jsonl = Some(jsonl.clone());
    let (coordinator, clock) = start(config).await;
    let addr = coordinator.local_addr;
    let mut watch =
        monitoring(addr).await.watch_estimates(wire::WatchEstimatesRequest {}).await.unwrap().into_inner();
    let mut a = connect(addr, "pioneer").await;
    let mut b = connect(addr, "turtlebot").await;
    let [pa, pb] = bases();
    for k in 0..20 {
        let t = T0.plus_secs(0.1 * k as f64);
        clock.set(t);
        let s = a.observe(observation_of(t, pa, 0.3, &SOURCE, None, 0.05)).await;
        a.until_acked(s).await;
        let s = b.observe(observation_of(t, pb, -1.0, &SOURCE, None, 0.05)).await;
        b.until_acked(s).await;
    }
    let mut n = 0;
    while n < 20 {
        let e = tokio::time::timeout(std::time::Duration::from_secs(5), watch.message())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        let err = (position(&e) - SOURCE).norm();
        assert!(err < 1e-3, "estimate {} m from the source", err);
        assert!(e.trusted, "exact rays at θ=90°, 3 m: {:?}", e.triangulation);
        assert!((e.theta_deg - 90.0).abs() < 8.0, "θ {}", e.theta_deg);
        assert_eq!(e.robots, vec!["pioneer".to_string(), "turtlebot".to_string()]);
        n += 1;
    }
    // GetState reports both robots live and the last estimate.
    let state = monitoring(addr).await.get_state(wire::GetStateRequest {}).await.unwrap().into_inner();
    assert_eq!(state.robots.len(), 2);
    assert!(
        state
            .robots
            .iter()
            .all(|r| r.liveness == wire::Liveness::Live as i32 && r.observations_accepted == 20)
    );
    assert_eq!(state.sources.len(), 1);
    drop((a, b));
    coordinator.shutdown().await.unwrap();
    // The JSON-lines file has one line per estimate, with the documented keys.
    let text = std::fs::read_to_string(&jsonl).unwrap();
    let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 20);
    for l in &lines {
        for key in ["stamp_ns", "x", "y", "z", "cov", "gdop", "theta_deg", "robots"] {
            assert!(l.get(key).is_some(), "missing {key} in {l}");
        }
        assert_eq!(l["cov"].as_array().unwrap().len(), 9);
        assert!((l["x"].as_f64().unwrap() - SOURCE.x).abs() < 1e-3);
        // Once the track is older than the smoothing lag (1 s), the line
        // carries the smoothed state, about a second earlier.
        if let Some(s) = l.get("smoothed") {
            let behind_s = (l["stamp_ns"].as_i64().unwrap() - s["stamp_ns"].as_i64().unwrap()) as f64 * 1e-9;
            assert!((1.0..1.2).contains(&behind_s), "{l}");
            assert_eq!(s["cov"].as_array().unwrap().len(), 9);
            assert!(s["trusted"].is_boolean());
            assert!((s["x"].as_f64().unwrap() - SOURCE.x).abs() < 1e-3, "{l}");
        }
    }
    let smoothed = lines.iter().filter(|l| l.get("smoothed").is_some()).count();
    assert!((5..=10).contains(&smoothed), "{smoothed} lines with a smoothed state");
}

/// σ = 3° per tangent axis on both robots at 3 m and θ = 90°: the published
/// triangulations' RMS error matches the Cramér–Rao bound (within 10%) and
/// their covariances are consistent with the errors (mean NEES ≈ 3). (The
/// estimate's top-level position is the filtered one once the track is
/// trusted: see `service_tracking.rs`.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn noisy_doas_match_the_monte_carlo_expectation() {
    let sigma = 3f64.to_radians();
    let (coordinator, clock) = start(CoordinatorConfig::default()).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    let [pa, pb] = bases();
    let arrays = [pa + Vector3::new(0.0, 0.0, 0.48), pb + Vector3::new(0.0, 0.0, 0.48)];
    let crlb =
        assess(&arrays.map(|o| Sensor { origin: o, sigma_rad: sigma, origin_sigma_m: 0.0 }), &SOURCE).rms_m;
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let noise = |rng: &mut ChaCha8Rng| {
        let v =
            Vector3::new(StandardNormal.sample(rng), StandardNormal.sample(rng), StandardNormal.sample(rng))
                * sigma;
        // Only the two tangent components matter for a direction; the radial one is a no-op rotation about it.
        UnitQuaternion::from_scaled_axis(v)
    };
    let (mut sq, mut nees, mut n) = (0.0, 0.0, 0);
    let trials = 1500;
    for k in 0..trials {
        let t = T0.plus_secs(0.1 * k as f64);
        clock.set(t);
        let s = a.observe(observation_of(t, pa, 0.0, &SOURCE, Some(noise(&mut rng)), sigma)).await;
        a.until_acked(s).await;
        let s = b.observe(observation_of(t, pb, 0.0, &SOURCE, Some(noise(&mut rng)), sigma)).await;
        b.until_acked(s).await;
        let e = next_estimate(&mut estimates).await;
        let tri = e.triangulation.as_ref().expect("the triangulation is always published");
        let Some(p) = tri.position_in_map_m.as_ref() else { continue };
        let err = Point3::new(p.x, p.y, p.z) - SOURCE;
        let cov = covariance_from_wire(tri.covariance.as_ref().unwrap()).unwrap();
        sq += err.norm_squared();
        nees += (err.transpose() * cov.try_inverse().unwrap() * err)[0];
        n += 1;
    }
    assert!(n >= trials * 99 / 100, "{n} estimates with a position out of {trials}");
    let rms = (sq / n as f64).sqrt();
    let mean_nees = nees / n as f64;
    println!("end to end, σ=3°, r≈3 m, θ=90°: RMS {rms:.3} m (CRLB {crlb:.3} m), mean NEES {mean_nees:.2}");
    assert!((rms - crlb).abs() / crlb < 0.10, "RMS {rms} vs CRLB {crlb}");
    assert!((mean_nees - 3.0).abs() < 0.35, "mean NEES {mean_nees}");
    coordinator.shutdown().await.unwrap();
}

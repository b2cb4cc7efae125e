//! How accuracy and honesty fall off with distance: two robots at 90° around
//! a static white-noise source (1.2 m high) in a 14 × 12 × 3 m room with
//! RT60 0.5 s, 25 dB SNR at 3 m, each robot `d` metres from the source, 10 s
//! per run, no active positioning. For each distance: RSE median and p95 of
//! the published estimates, their mean height error (the floor reflection's
//! pull), and the mean NEES of trusted estimates with the share above
//! χ²₃(0.99) (honest: 3 and 1 %).
//!
//! CI runs 2 m and 6 m at seed 1 and checks the targets there (RSE median
//! ≤ 0.2 m at 6 m, trusted NEES ≤ 5); the `#[ignore]`d sweep checks them over
//! 2–6 m and seeds 1–3:
//! `cargo test -p soundmap-sim --test distance_sweep -- --ignored --nocapture`.
//!
//! The sweep takes other sources from the environment (its targets are then
//! not asserted): `SOUNDMAP_DISTANCE_SIGNAL` = `white` (default), `band`
//! (noise 300–3400 Hz) or `talker` (the same band, syllabic);
//! `SOUNDMAP_DISTANCE_SOURCE_HEIGHT` (m, default 1.2); and
//! `SOUNDMAP_DISTANCE_CEILING` (m): the ceiling height the coordinator's
//! floor-image model is told (default: the room's, 3 m; 100 leaves the
//! ceiling out of the model). `SOUNDMAP_DISTANCE_FLOOR_FIT=1` turns on the
//! agents' experimental floor-reflection fit (`[agent.srp] floor_fit`);
//! `SOUNDMAP_DISTANCE_ONLY=5` runs one distance (m) of the sweep.

use soundmap_sim::report::derived::Derived;
use soundmap_sim::report::{RunRecord, Summary};
use soundmap_sim::runner::{RunOptions, run};
use soundmap_sim::scenario::Scenario;

/// The source, away from the room's centre so that both robots stay ≥ 1.5 m from the walls at 6 m.
const SOURCE: [f64; 3] = [2.0, 1.5, 1.2];

/// The source the sweep runs: its signal (a scenario `signal = …` value),
/// height (m) and the ceiling the coordinator's model is told (m; `None`: the room's).
#[derive(Clone, Debug)]
struct Source {
    signal: String,
    height_m: f64,
    ceiling_m: Option<f64>,
}

/// The variables that change the sweep's source (module docs).
const SOURCE_VARIABLES: [&str; 3] =
    ["SOUNDMAP_DISTANCE_SIGNAL", "SOUNDMAP_DISTANCE_SOURCE_HEIGHT", "SOUNDMAP_DISTANCE_CEILING"];

impl Source {
    /// The sweep's own source: white noise at `SOURCE`, the room's ceiling.
    fn white() -> Self {
        Source { signal: "{ kind = \"white_noise\" }".to_string(), height_m: SOURCE[2], ceiling_m: None }
    }

    /// The source the environment asks for, `None` when it sets none of
    /// [`SOURCE_VARIABLES`].
    fn from_environment() -> Option<Self> {
        let var = |name: &str| std::env::var(name).ok();
        if SOURCE_VARIABLES.iter().all(|v| var(v).is_none()) {
            return None;
        }
        let signal = match var("SOUNDMAP_DISTANCE_SIGNAL").as_deref() {
            None | Some("white") => Source::white().signal,
            Some("band") => "{ kind = \"band_noise\", low_hz = 300.0, high_hz = 3400.0 }".to_string(),
            Some("talker") => {
                "{ kind = \"talker\", low_hz = 300.0, high_hz = 3400.0, syllable_hz = 5.0 }".to_string()
            }
            Some(other) => panic!("SOUNDMAP_DISTANCE_SIGNAL: {other} is not white, band or talker"),
        };
        let number =
            |name: &str| var(name).map(|v| v.parse::<f64>().unwrap_or_else(|e| panic!("{name}: {v}: {e}")));
        Some(Source {
            signal,
            height_m: number("SOUNDMAP_DISTANCE_SOURCE_HEIGHT").unwrap_or(SOURCE[2]),
            ceiling_m: number("SOUNDMAP_DISTANCE_CEILING"),
        })
    }
}

fn scenario(distance_m: f64, seed: u64, source: &Source) -> Scenario {
    let [x, y, _] = SOURCE;
    let (signal, z) = (&source.signal, source.height_m);
    let mut ceiling =
        source.ceiling_m.map_or(String::new(), |h| format!("[coordinator.doa]\nceiling_height_m = {h}\n"));
    // `SOUNDMAP_DISTANCE_FLOOR_FIT=1`: the agents fit the floor's reflection
    // (`[agent.srp] floor_fit`, experimental).
    if std::env::var("SOUNDMAP_DISTANCE_FLOOR_FIT").is_ok_and(|v| v != "0") {
        ceiling.push_str("[agent.srp]\nfloor_fit = true\n");
    }
    let text = format!(
        r#"name = "distance-{distance_m}"
description = "two robots at 90 degrees, {distance_m} m from a white-noise source (14 x 12 m room, RT60 0.5 s)"
duration_s = 10.0
seed = {seed}

[room]
min_corner_m = [-7.0, -6.0, 0.0]
size_m = [14.0, 12.0, 3.0]
rt60_s = 0.5

[noise]
sensor_snr_db = 25.0
reference_distance_m = 3.0

{ceiling}
[[robots]]
id = "pioneer"
array = "16soundsusb-pioneer"
start = [{ax}, {y}, 0.0]
max_speed_m_per_s = 0.5

[[robots]]
id = "turtlebot"
array = "16soundsusb-turtlebot"
start = [{x}, {by}, 90.0]
max_speed_m_per_s = 0.5

[[sources]]
signal = {signal}
rms = 0.1
path = [{{ t_s = 0.0, x_m = {x}, y_m = {y}, z_m = {z} }}]
"#,
        ax = x - distance_m,
        by = y - distance_m,
    );
    Scenario::from_toml(&text, &format!("distance sweep {distance_m} m")).unwrap()
}

#[derive(Debug)]
struct Figures {
    estimates: usize,
    rse_median_m: Option<f64>,
    rse_p95_m: Option<f64>,
    height_error_mean_m: Option<f64>,
    trusted: usize,
    nees_mean_trusted: Option<f64>,
    nees_above_99: Option<f64>,
}

fn measure(distance_m: f64, seed: u64, source: &Source) -> Figures {
    let record: RunRecord = run(&scenario(distance_m, seed, source), &RunOptions::default()).unwrap();
    let s = Summary::new(&record, &Derived::new(&record));
    let dz: Vec<f64> =
        record.rows.iter().filter_map(|r| Some(r.estimate_in_map?.z - r.truth_in_map?.z)).collect();
    Figures {
        estimates: record.rows.iter().filter(|r| r.estimate_in_map.is_some()).count(),
        rse_median_m: s.rse_median_m,
        rse_p95_m: s.rse_p95_m,
        height_error_mean_m: (!dz.is_empty()).then(|| dz.iter().sum::<f64>() / dz.len() as f64),
        trusted: record.rows.iter().filter(|r| r.trusted).count(),
        nees_mean_trusted: s.nees_mean_trusted,
        nees_above_99: s.nees_above_chi2_99_trusted_ratio,
    }
}

fn show(v: Option<f64>, scale: f64, digits: usize) -> String {
    v.map_or("—".into(), |v| format!("{:.*}", digits, v * scale))
}

fn row(distance_m: f64, seed: u64, f: &Figures) {
    println!(
        "| {distance_m:.0} m | {seed} | {} | {} m | {} m | {} m | {} | {} | {} % |",
        f.estimates,
        show(f.rse_median_m, 1.0, 3),
        show(f.rse_p95_m, 1.0, 3),
        show(f.height_error_mean_m, 1.0, 3),
        f.trusted,
        show(f.nees_mean_trusted, 1.0, 2),
        show(f.nees_above_99, 100.0, 1),
    );
}

const HEADER: &str = "| distance | seed | estimates | RSE median | RSE p95 | mean height error | trusted | NEES mean (trusted) | NEES > χ²₃(0.99) |\n|---|---|---|---|---|---|---|---|---|";

#[test]
fn near_and_far_sources_are_located() {
    println!("{HEADER}");
    for d in [2.0, 6.0] {
        let f = measure(d, 1, &Source::white());
        row(d, 1, &f);
        assert!(f.estimates > 100, "{d} m: {f:?}");
        assert!(f.rse_median_m.is_some_and(|m| m <= 0.2), "{d} m: {f:?}");
        assert!(f.nees_mean_trusted.is_some_and(|n| n <= 5.0), "{d} m: {f:?}");
    }
}

#[test]
#[ignore = "sweep: 2-6 m x seeds 1-3, a few minutes"]
fn sweep_over_distance() {
    let chosen = Source::from_environment();
    let source = chosen.clone().unwrap_or_else(Source::white);
    println!(
        "source {} at {} m, ceiling in the model {:?}\n{HEADER}",
        source.signal, source.height_m, source.ceiling_m
    );
    let mut missed = Vec::new();
    let only: Option<f64> = std::env::var("SOUNDMAP_DISTANCE_ONLY")
        .ok()
        .map(|v| v.parse().unwrap_or_else(|e| panic!("SOUNDMAP_DISTANCE_ONLY: {v}: {e}")));
    for d in [2.0, 3.0, 4.0, 5.0, 6.0].into_iter().filter(|d| only.is_none_or(|o| o == *d)) {
        for seed in 1..=3 {
            let f = measure(d, seed, &source);
            row(d, seed, &f);
            if f.nees_mean_trusted.is_some_and(|n| n > 5.0) {
                missed.push(format!("{d} m seed {seed}: trusted NEES {:.1}", f.nees_mean_trusted.unwrap()));
            }
            if d == 6.0 && f.rse_median_m.is_none_or(|m| m > 0.2) {
                missed.push(format!("6 m seed {seed}: RSE median {:?}", f.rse_median_m));
            }
        }
    }
    if chosen.is_none() {
        assert!(missed.is_empty(), "targets missed: {missed:?}");
    } else if !missed.is_empty() {
        println!("(not asserted for this source) targets missed: {missed:?}");
    }
}

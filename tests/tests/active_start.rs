//! Active positioning that starts before any position exists: robots in a
//! corner, a far source, a fast walker, a robot against a wall (scenarios in
//! `tests/scenarios/`), end to end over real gRPC with the simulated robots.
//!
//! CI runs each scenario once at its own seed; the `#[ignore]`d sweep runs
//! seeds 1–20 of each (and of `active-moving`) and prints the table of
//! BENCHMARKS.md:
//! `cargo test -p soundmap-sim --test active_start -- --ignored --nocapture`.
//! With `SOUNDMAP_SWEEP_VERBOSE=1` it also prints, per run, every goal issued
//! within the keep-out of the true source and every stretch after
//! convergence where the true θ left the band (with how far each robot drove
//! and turned, and the commands issued around it). `SOUNDMAP_SWEEP_ONLY=a,b`
//! runs only those scenarios, `SOUNDMAP_SWEEP_SEEDS=N` N seeds, and
//! `SOUNDMAP_SWEEP_FIRST_SEED=K` starts at seed K (e.g. 21 for a second set).

use soundmap_sim::kinematics::wrap_angle;
use soundmap_sim::report::derived::Derived;
use soundmap_sim::report::{RunRecord, Summary, distinct_smoothed_states};
use soundmap_sim::runner::{RunOptions, run};
use soundmap_sim::scenario::Scenario;

/// Keep-out radius around the source (the planner's default `min_range_m`).
const KEEP_OUT_M: f64 = 1.0;

/// The figures the targets speak of, for one run.
#[derive(Debug)]
struct Figures {
    first_position_s: Option<f64>,
    time_to_band_s: Option<f64>,
    in_band_after: Option<f64>,
    rse_p95_after_m: Option<f64>,
    /// The same for the smoothed states (each once, stamped after `time_to_band_s`),
    /// for comparison; the targets are on the live estimates.
    smoothed_rse_p95_after_m: Option<f64>,
    /// Goals inside an obstacle, outside the room, or within the keep-out
    /// radius (horizontal) of the true source when issued.
    unsafe_goals: Vec<String>,
    /// The same, of goals planned from bearings (before a usable estimate).
    unsafe_start_goals: Vec<String>,
    commands: usize,
}

/// The 95th percentile of the smoothed states' RSE from `from_s` on, each
/// distinct state once.
fn smoothed_p95_after(record: &RunRecord, from_s: Option<f64>) -> Option<f64> {
    let from_s = from_s?;
    let mut e: Vec<f64> = distinct_smoothed_states(record)
        .into_iter()
        .filter(|(_, s)| s.t_s >= from_s)
        .filter_map(|(_, s)| s.rse_m())
        .collect();
    e.sort_by(f64::total_cmp);
    (!e.is_empty()).then(|| e[((e.len() as f64 * 0.95).ceil() as usize).clamp(1, e.len()) - 1])
}

fn run_seed(name: &str, seed: Option<u64>) -> (Scenario, RunRecord, Figures) {
    let scenario = Scenario::load(name).unwrap();
    let options = RunOptions { active_positioning: Some(true), seed, ..RunOptions::default() };
    let record = run(&scenario, &options).unwrap();
    let s = Summary::new(&record, &Derived::new(&record));
    let first_position_s = record.rows.iter().find(|r| r.estimate_in_map.is_some()).map(|r| r.t_s);
    let unsafe_goals = unsafe_goals(&scenario, &record);
    let from_bearings = |g: &String| {
        record.commands.iter().any(|(t, robot, detail)| {
            g.starts_with(&format!("{robot} at {t:.1} s"))
                && (detail.contains("no position yet") || detail.contains("nothing heard"))
        })
    };
    let unsafe_start_goals = unsafe_goals.iter().filter(|g| from_bearings(g)).cloned().collect();
    let figures = Figures {
        first_position_s,
        time_to_band_s: s.time_to_band_s,
        in_band_after: s.in_band_ratio_after_convergence,
        rse_p95_after_m: s.rse_p95_after_convergence_m,
        smoothed_rse_p95_after_m: smoothed_p95_after(&record, s.time_to_band_s),
        unsafe_goals,
        unsafe_start_goals,
        commands: record.commands.len(),
    };
    (scenario, record, figures)
}

fn unsafe_goals(scenario: &Scenario, record: &RunRecord) -> Vec<String> {
    let room = &scenario.room;
    let [x0, y0, _] = room.min_corner_m;
    let [w, d, _] = room.size_m;
    let mut bad = Vec::new();
    for path in &record.robots {
        for &(t, x, y) in &path.goals {
            let truth = scenario.sources[0].position_at(t);
            let range = ((truth.x - x).powi(2) + (truth.y - y).powi(2)).sqrt();
            let outside = !(x0..=x0 + w).contains(&x) || !(y0..=y0 + d).contains(&y);
            let in_obstacle = room.obstacles.iter().any(|p| point_in_polygon(p, x, y));
            if outside || in_obstacle || range < KEEP_OUT_M {
                let robot = path.samples.iter().min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()));
                let robot_range =
                    robot.map_or(f64::NAN, |r| ((truth.x - r.1).powi(2) + (truth.y - r.2).powi(2)).sqrt());
                let why = record
                    .commands
                    .iter()
                    .find(|c| c.1 == path.id && (c.0 - t).abs() < 0.05)
                    .map_or("", |c| c.2.split(':').next().unwrap_or(""));
                bad.push(format!(
                    "{} at {t:.1} s: goal ({x:.2}, {y:.2}), source {range:.2} m away (robot {robot_range:.2} m; {why})",
                    path.id
                ));
            }
        }
    }
    bad
}

/// Even-odd rule.
fn point_in_polygon(poly: &[[f64; 2]], x: f64, y: f64) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let ([xi, yi], [xj, yj]) = (poly[i], poly[j]);
        if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
            inside = !inside;
        }
        j = i;
    }
    inside
}

fn show(v: Option<f64>, scale: f64, unit: &str) -> String {
    v.map_or("never".into(), |x| format!("{:.1}{unit}", x * scale))
}

/// The robots, which start where nothing useful is published, are commanded,
/// and every goal planned from bearings keeps out of obstacles, inside the
/// room and outside the keep-out radius of the true source. (Goals of the
/// Fisher planning keep the keep-out around the *estimate*; the sweep reports
/// those that came near the true source too.)
fn check_one(name: &str) -> (RunRecord, Figures) {
    let (_, record, f) = run_seed(name, None);
    println!("{name}: {f:?}");
    for c in record.commands.iter().take(4) {
        println!("  {c:?}");
    }
    assert!(f.commands > 0, "{name}: no command");
    assert!(f.unsafe_start_goals.is_empty(), "{name}: unsafe goals {:?}", f.unsafe_start_goals);
    (record, f)
}

#[test]
fn corner_start_moves_out_of_the_corner() {
    let (record, f) = check_one("corner-start");
    // Nobody waits: the first command comes within a second. When no position
    // was published by then, it must come from bearings (the planner's unit
    // tests cover that path itself; here a position may come first, at 0.3 s).
    let first_command = record.commands.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
    assert!(first_command < 1.0, "first command at {first_command} s");
    let spread =
        record.commands.iter().any(|c| c.2.starts_with("no position yet: spreading across the bearing"));
    assert!(
        spread || f.first_position_s.is_some_and(|t| t <= first_command),
        "no position at the first command ({first_command} s) and no robot spread across a bearing: {:?}",
        record.commands
    );
    assert!(f.first_position_s.is_some() && f.time_to_band_s.is_some(), "{f:?}");
}

/// Seeds 1–3. One seed's time in band moves by ±10 points when an estimate
/// moves by millimetres (the walker meets the robots at other moments): seed 1
/// gave 86–89 % under four variants of the floor-image model and the
/// keep-out, ≥ 95 % before them. So every seed must reach the band and stay
/// in it ≥ 85 % of the time, and the three ≥ 93 % on average.
#[test]
fn fast_walker_is_followed() {
    let (_, f) = check_one("fast-walker");
    assert!(f.time_to_band_s.is_some_and(|t| t < 20.0), "{f:?}");
    let mut in_band = vec![f.in_band_after.expect("in band after convergence")];
    for seed in [2, 3] {
        let (_, _, f) = run_seed("fast-walker", Some(seed));
        println!("fast-walker seed {seed}: {f:?}");
        assert!(f.time_to_band_s.is_some_and(|t| t < 20.0), "seed {seed}: {f:?}");
        assert!(f.unsafe_start_goals.is_empty(), "seed {seed}: unsafe goals {:?}", f.unsafe_start_goals);
        in_band.push(f.in_band_after.expect("in band after convergence"));
    }
    let mean = in_band.iter().sum::<f64>() / in_band.len() as f64;
    assert!(
        in_band.iter().all(|&r| r >= 0.85) && mean >= 0.93,
        "θ in band after convergence, seeds 1–3: {in_band:?}"
    );
}

#[test]
fn robot_against_a_wall() {
    let (_, f) = check_one("deaf-near-wall");
    assert!(f.time_to_band_s.is_some_and(|t| t < 20.0), "{f:?}");
}

/// Seeds 1–20 of every scenario of this file and of `active-moving`: the
/// table of BENCHMARKS.md, then the targets, asserted.
#[test]
#[ignore = "100+ simulated minutes; run on demand for the figures in BENCHMARKS.md"]
fn sweep_over_seeds() {
    let seeds: u64 = std::env::var("SOUNDMAP_SWEEP_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(20);
    // Seeds `first..first + seeds` (a second set of seeds to tell a change from the loop's scatter).
    let first: u64 =
        std::env::var("SOUNDMAP_SWEEP_FIRST_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let names =
        ["corner-start", "corner-start-3", "far-source", "fast-walker", "deaf-near-wall", "active-moving"];
    let only = std::env::var("SOUNDMAP_SWEEP_ONLY").ok();
    let mut failures = Vec::new();
    for name in names.iter().filter(|n| only.as_deref().is_none_or(|o| o.split(',').any(|x| x == **n))) {
        println!(
            "\n{name}\n| seed | first position | time to band | in band after | RSE p95 after (smoothed) | unsafe goals (from bearings) |"
        );
        println!("|---|---|---|---|---|---|");
        let mut rows = Vec::new();
        for seed in first..first + seeds {
            let (scenario, record, f) = run_seed(name, Some(seed));
            println!(
                "| {seed} | {} | {} | {} | {} | {} ({}) |",
                show(f.first_position_s, 1.0, " s"),
                show(f.time_to_band_s, 1.0, " s"),
                show(f.in_band_after, 100.0, " %"),
                f.rse_p95_after_m.map_or("—".into(), |p| format!("{p:.3} m"))
                    + &f.smoothed_rse_p95_after_m.map_or(" (—)".into(), |p| format!(" ({p:.3} m)")),
                f.unsafe_goals.len(),
                f.unsafe_start_goals.len()
            );
            if std::env::var_os("SOUNDMAP_SWEEP_VERBOSE").is_some() {
                for g in &f.unsafe_goals {
                    println!("    unsafe: {g}");
                }
                for e in out_of_band_episodes(&scenario, &record) {
                    println!("    out of band: {e}");
                }
            }
            let start_targets = *name != "active-moving" && *name != "fast-walker";
            let ok = f.unsafe_goals.is_empty()
                && f.in_band_after.is_some_and(|r| r >= 0.95)
                && f.rse_p95_after_m.is_some_and(|p| p <= 0.3)
                && (!start_targets
                    || (f.first_position_s.is_some_and(|t| t <= 10.0)
                        && f.time_to_band_s.is_some_and(|t| t <= 20.0)));
            if !ok {
                failures.push(format!("{name} seed {seed}"));
            }
            rows.push(f);
        }
        summarize(&rows);
    }
    assert!(failures.is_empty(), "targets missed: {failures:?}");
}

/// The stretches after convergence where the true θ left the band (at least
/// 0.3 s of weighted time), each with what the robots, the source, the
/// estimate and the planner were doing: for `SOUNDMAP_SWEEP_VERBOSE`.
fn out_of_band_episodes(scenario: &Scenario, record: &RunRecord) -> Vec<String> {
    let d = Derived::new(record);
    let Some(k) = d.in_band.iter().position(|b| *b) else { return Vec::new() };
    let mut out = Vec::new();
    let mut i = k;
    while i < record.rows.len() {
        if d.in_band[i] {
            i += 1;
            continue;
        }
        let j = (i..record.rows.len()).find(|&j| d.in_band[j]).unwrap_or(record.rows.len());
        let time: f64 = d.weights_s[i..j].iter().sum();
        if time >= 0.3 {
            let (t0, t1) = (record.rows[i].t_s, record.rows[j - 1].t_s);
            let th = &d.theta_deg[i..j];
            let pub_th: Vec<f64> = record.rows[i..j].iter().map(|r| r.theta_deg).collect();
            let rse = d.rse_m[i..j].iter().flatten().fold(0.0f64, |a, b| a.max(*b));
            let near = record.rows[i..j]
                .iter()
                .flat_map(|r| r.distances_m.iter().copied())
                .fold(f64::INFINITY, f64::min);
            let speed = {
                let (a, b) = (scenario.sources[0].position_at(t0), scenario.sources[0].position_at(t0 + 0.5));
                (b - a).xy().norm() / 0.5
            };
            let cmds: Vec<String> = record
                .commands
                .iter()
                .filter(|c| c.0 >= t0 - 3.0 && c.0 <= t1)
                .map(|c| format!("{:.1} {} {}", c.0, c.1, c.2.split(':').next().unwrap_or("")))
                .collect();
            let motion: Vec<String> = record
                .robots
                .iter()
                .map(|r| {
                    let within: Vec<_> = r.samples.iter().filter(|s| s.0 >= t0 - 1.0 && s.0 <= t1).collect();
                    let (mut dist, mut turn) = (0.0, 0.0);
                    for w in within.windows(2) {
                        dist += (w[1].1 - w[0].1).hypot(w[1].2 - w[0].2);
                        turn += wrap_angle(w[1].3 - w[0].3).abs();
                    }
                    format!("{} drove {dist:.2} m, turned {:.0}°", r.id, turn.to_degrees())
                })
                .collect();
            let minmax = |v: &[f64]| {
                let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                format!("{lo:.0}–{hi:.0}°")
            };
            out.push(format!(
                "{t0:.1}–{t1:.1} s ({time:.1} s): true θ {}, published θ {}, RSE ≤ {rse:.2} m, nearest robot {near:.2} m, source {speed:.2} m/s; from 1 s before: {}; commands from 3 s before: {}",
                minmax(th),
                minmax(&pub_th),
                motion.join(", "),
                if cmds.is_empty() { "none".to_string() } else { cmds.join("; ") }
            ));
        }
        i = j;
    }
    out
}

fn summarize(rows: &[Figures]) {
    let stat = |get: &dyn Fn(&Figures) -> Option<f64>, worst_is_max: bool| {
        let mut v: Vec<f64> = rows.iter().map(|f| get(f).unwrap_or(f64::NAN)).collect();
        v.sort_by(f64::total_cmp);
        let never = v.iter().filter(|x| x.is_nan()).count();
        let ok: Vec<f64> = v.into_iter().filter(|x| !x.is_nan()).collect();
        if ok.is_empty() {
            return "never".to_string();
        }
        let median = ok[ok.len() / 2];
        let worst = if worst_is_max { ok[ok.len() - 1] } else { ok[0] };
        format!(
            "median {median:.3}, worst {worst:.3}{}",
            if never > 0 { format!(", never {never}") } else { String::new() }
        )
    };
    println!("first position (s): {}", stat(&|f| f.first_position_s, true));
    println!("time to band (s): {}", stat(&|f| f.time_to_band_s, true));
    println!("in band after convergence: {}", stat(&|f| f.in_band_after, false));
    println!("RSE p95 after convergence (m): {}", stat(&|f| f.rse_p95_after_m, true));
    println!(
        "smoothed states' RSE p95 after convergence (m): {}",
        stat(&|f| f.smoothed_rse_p95_after_m, true)
    );
}

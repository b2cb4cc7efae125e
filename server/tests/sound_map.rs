//! Several sources (`sources.max_sources > 1`), the coordinator driven
//! in-process with `(now, input)`: every robot reports every track it hears;
//! the coordinator must find each source once, publish no ghosts, and keep a
//! source's id when it falls silent and speaks again at the same place.

use std::collections::BTreeMap;

use crate::common::undeclared_array;
use nalgebra::{Isometry3, Point3, Unit, UnitQuaternion};
use soundmap_proto::{Hello, Observation, RobotId, Stamp, TrackedDoa};
use soundmap_server::CoordinatorConfig;
use soundmap_server::coordinator::{ConnId, Coordinator, Estimate};

const T0: Stamp = Stamp::from_ns(1_767_225_600_000_000_000);
const MS: i64 = 1_000_000;

fn hello(id: &str) -> Hello {
    Hello {
        robot_id: RobotId::parse(id, "hello.robot_id").unwrap(),
        array: undeclared_array(),
        software_version: "t".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    }
}

/// Deterministic small angular noise (rad) for DoA `k` of observation `n`.
fn jitter(n: u64, k: u64) -> (f64, f64) {
    let mut x = n.wrapping_mul(6364136223846793005).wrapping_add(k.wrapping_mul(1442695040888963407));
    let mut u = || {
        x ^= x >> 33;
        x = x.wrapping_mul(0xff51afd7ed558ccd);
        x ^= x >> 33;
        (x % 10_000) as f64 / 10_000.0 - 0.5
    };
    (u() * 0.02, u() * 0.02) // within ±0.6°
}

struct Robot {
    conn: ConnId,
    base: Point3<f64>,
    sequence: u64,
}

/// Robot `r`'s observation at `stamp` of the sources `heard`: (robot-local track id, position).
fn observe(c: &mut Coordinator, r: &mut Robot, stamp: Stamp, heard: &[(u64, Point3<f64>)]) {
    observe_with(c, r, stamp, heard, |_| None)
}

/// [`observe`], with each DoA's signature given by `signature(track_id)`.
fn observe_with(
    c: &mut Coordinator,
    r: &mut Robot,
    stamp: Stamp,
    heard: &[(u64, Point3<f64>)],
    signature: impl Fn(u64) -> Option<Vec<f32>>,
) {
    r.sequence += 1;
    let map_from_base = Isometry3::translation(r.base.x, r.base.y, r.base.z);
    let map_from_array = map_from_base * undeclared_array().base_from_array;
    let doas = heard
        .iter()
        .map(|&(track_id, source)| {
            let d = (map_from_array.inverse() * source).coords.normalize();
            let (a, b) = jitter(r.sequence, track_id);
            let turn = UnitQuaternion::from_euler_angles(a, b, 0.0);
            TrackedDoa {
                track_id,
                direction_in_array: Unit::new_normalize(turn * d),
                activity: 0.9,
                angular_sigma_rad: Some(1f64.to_radians()),
                signature: signature(track_id),
                coherence: None,
                floor_fit_range_m: None,
            }
        })
        .collect();
    let obs = Observation { sequence: r.sequence, stamp, map_from_base, pose_covariance: None, doas };
    c.observe(stamp, r.conn, obs).unwrap();
}

fn several() -> CoordinatorConfig {
    let mut config = CoordinatorConfig::default();
    config.sources.max_sources = 4;
    config
}

fn robots(c: &mut Coordinator, bases: &[Point3<f64>]) -> Vec<Robot> {
    bases
        .iter()
        .enumerate()
        .map(|(i, &base)| {
            let conn = c.connect(T0, hello(&format!("r{i}")), None).unwrap().conn;
            Robot { conn, base, sequence: 0 }
        })
        .collect()
}

/// Runs `seconds` at 20 Hz per robot; `heard(robot, t_s)` lists what robot hears.
fn run(
    c: &mut Coordinator,
    robots: &mut [Robot],
    from_s: f64,
    seconds: f64,
    heard: impl Fn(usize, f64) -> Vec<(u64, Point3<f64>)>,
) -> Vec<(f64, Estimate)> {
    let mut out = Vec::new();
    let steps = (seconds * 20.0) as i64;
    for k in 0..steps {
        let t_s = from_s + k as f64 * 0.05;
        for (i, r) in robots.iter_mut().enumerate() {
            let stamp = T0.plus_secs(t_s).plus_ns(i as i64 * 3 * MS);
            observe(c, r, stamp, &heard(i, t_s));
        }
        let now = T0.plus_secs(t_s).plus_ns(20 * MS);
        c.tick(now);
        out.extend(c.estimate(now).into_iter().map(|e| (t_s, e)));
    }
    out
}

fn nearest(p: Point3<f64>, truths: &[Point3<f64>]) -> (usize, f64) {
    truths.iter().enumerate().map(|(i, t)| (i, (t - p).norm())).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap()
}

/// Ids per truth, and the largest distance of any estimate to its nearest truth.
fn score(estimates: &[(f64, Estimate)], truths: &[Point3<f64>]) -> (BTreeMap<usize, Vec<u64>>, f64) {
    let mut ids: BTreeMap<usize, Vec<u64>> = BTreeMap::new();
    let mut worst: f64 = 0.0;
    for (_, e) in estimates {
        let p = e.position().expect("a position");
        let (i, d) = nearest(p, truths);
        worst = worst.max(d);
        let v = ids.entry(i).or_default();
        if !v.contains(&e.source_id) {
            v.push(e.source_id);
        }
    }
    (ids, worst)
}

#[test]
fn three_robots_two_sources_no_ghosts_and_a_returning_source_keeps_its_id() {
    let mut c = Coordinator::new(several()).unwrap();
    let bases = [Point3::new(4.0, 0.0, 0.0), Point3::new(0.0, 4.0, 0.0), Point3::new(-3.0, -3.0, 0.0)];
    let mut rs = robots(&mut c, &bases);
    let s1 = Point3::new(1.0, 0.5, 1.2);
    let s2 = Point3::new(-0.5, 1.0, 1.7);
    let truths = [s1, s2];
    // Each robot numbers its tracks its own way.
    let local =
        |robot: usize, source: usize, epoch: u64| (10 * robot as u64 + source as u64 + 1) + 100 * epoch;
    let both = |i: usize, _t: f64| vec![(local(i, 0, 0), s1), (local(i, 1, 0), s2)];
    let first = run(&mut c, &mut rs, 0.0, 6.0, both);
    let (ids, worst) = score(&first, &truths);
    println!("first 6 s: ids per source {ids:?}, worst distance {worst:.3} m, {} estimates", first.len());
    assert_eq!(ids.len(), 2, "both sources found: {ids:?}");
    assert!(ids.values().all(|v| v.len() == 1), "one id per source: {ids:?}");
    assert!(worst < 0.3, "an estimate {worst:.2} m from every source (a ghost or a bad fit)");
    let late: Vec<_> = first.iter().filter(|(t, _)| *t > 2.0).collect();
    assert!(late.len() > 150, "both sources published every round: {}", late.len());
    let id2 = ids[&1][0];

    // Source 2 falls silent for 8 s, then speaks again at the same place; the
    // robots' trackers give it new local ids.
    let only_s1 = |i: usize, _t: f64| vec![(local(i, 0, 0), s1)];
    let quiet = run(&mut c, &mut rs, 6.0, 8.0, only_s1);
    assert!(quiet.iter().all(|(_, e)| e.source_id != id2 || (e.position().unwrap() - s2).norm() < 0.3));
    let again = |i: usize, _t: f64| vec![(local(i, 0, 0), s1), (local(i, 1, 1), s2)];
    let back = run(&mut c, &mut rs, 14.0, 6.0, again);
    let (ids_back, worst_back) = score(&back, &truths);
    let births = c.sound_map().unwrap().births;
    println!("after the pause: ids per source {ids_back:?}, worst {worst_back:.3} m, {births} births in all");
    assert_eq!(births, 3, "source 2 was lost during the pause and born again");
    assert_eq!(c.source_track_events(), (3, 0), "what /metrics counts: born, restarted");
    assert_eq!(ids_back.get(&1), Some(&vec![id2]), "the returning source keeps its id");
    assert!(worst_back < 0.3);
}

#[test]
fn two_robots_two_sources_at_different_heights_give_no_ghosts() {
    let mut c = Coordinator::new(several()).unwrap();
    let bases = [Point3::new(3.0, -1.0, 0.0), Point3::new(-1.0, 3.0, 0.0)];
    let mut rs = robots(&mut c, &bases);
    let s1 = Point3::new(0.8, 0.6, 1.1);
    let s2 = Point3::new(-0.6, -0.4, 1.8);
    let truths = [s1, s2];
    // Both talk at once from the start: the pairing must come from geometry.
    let both = |i: usize, _t: f64| vec![(i as u64 * 7 + 1, s1), (i as u64 * 7 + 2, s2)];
    let est = run(&mut c, &mut rs, 0.0, 6.0, both);
    let (ids, worst) = score(&est, &truths);
    println!("two robots: ids per source {ids:?}, worst distance {worst:.3} m, {} estimates", est.len());
    assert_eq!(ids.len(), 2, "{ids:?}");
    assert!(ids.values().all(|v| v.len() == 1), "{ids:?}");
    assert!(worst < 0.35, "a ghost: an estimate {worst:.2} m from every source");
}

#[test]
fn one_source_is_still_one_source() {
    let mut c = Coordinator::new(several()).unwrap();
    let bases = [Point3::new(4.0, 0.0, 0.0), Point3::new(0.0, 4.0, 0.0)];
    let mut rs = robots(&mut c, &bases);
    let s = Point3::new(0.5, 0.5, 1.3);
    let est = run(&mut c, &mut rs, 0.0, 5.0, |i, _| vec![(i as u64 + 4, s)]);
    let (ids, worst) = score(&est, &[s]);
    assert_eq!(ids[&0].len(), 1, "{ids:?}");
    assert!(worst < 0.3);
    assert_eq!(c.latest_estimates().len(), 1);
}

/// Two sources at one height, both sounding from the start, heard by two
/// robots: geometry alone cannot tell the true pairs from the ghosts (all four
/// ray pairs meet), the spectra can: a fan and a talker.
#[test]
fn sources_at_one_height_with_signatures_give_no_ghosts() {
    let fan: Vec<f32> = (0..24).map(|b| 70.0 - 1.5 * b as f32).collect();
    let talker: Vec<f32> =
        (0..24).map(|b| 40.0 + 20.0 * (-((b as f32 - 12.0) / 4.0).powi(2)).exp()).collect();
    let run_with = |signatures: bool| {
        let mut c = Coordinator::new(several()).unwrap();
        let bases = [Point3::new(3.0, -1.0, 0.0), Point3::new(-1.0, 3.0, 0.0)];
        let mut rs = robots(&mut c, &bases);
        let (s1, s2) = (Point3::new(0.8, 0.6, 1.4), Point3::new(-0.6, -0.4, 1.4));
        // Robot-local ids: fan tracks end in 1, talker tracks in 2.
        let sig = |track: u64| signatures.then(|| if track % 10 == 1 { fan.clone() } else { talker.clone() });
        let mut out = Vec::new();
        for k in 0..120 {
            let t_s = k as f64 * 0.05;
            for (i, r) in rs.iter_mut().enumerate() {
                let stamp = T0.plus_secs(t_s).plus_ns(i as i64 * 3 * MS);
                let heard = [(10 * i as u64 + 1, s1), (10 * i as u64 + 2, s2)];
                observe_with(&mut c, r, stamp, &heard, sig);
            }
            let now = T0.plus_secs(t_s).plus_ns(20 * MS);
            out.extend(c.estimate(now).into_iter().map(|e| (t_s, e)));
        }
        score(&out, &[s1, s2])
    };
    let (ids, worst) = run_with(true);
    println!("one height, signatures: ids {ids:?}, worst {worst:.2} m");
    assert_eq!(ids.len(), 2, "{ids:?}");
    assert!(worst < 0.35, "a ghost {worst:.2} m from every source");
    let (ids_blind, worst_blind) = run_with(false);
    println!("one height, no signatures: ids {ids_blind:?}, worst {worst_blind:.2} m");
}

/// Robot a hears only a fan, robot b only a talker, and their rays happen to
/// meet at a point: without signatures that point is taken for a source (a
/// ghost); with them, the spectra say the two tracks hear different things.
#[test]
fn rays_that_meet_but_hear_different_things_make_no_source() {
    let fan: Vec<f32> = (0..24).map(|b| 70.0 - 1.5 * b as f32).collect();
    let talker: Vec<f32> =
        (0..24).map(|b| 40.0 + 20.0 * (-((b as f32 - 12.0) / 4.0).powi(2)).exp()).collect();
    let meet = Point3::new(0.5, 0.5, 1.3);
    let births = |signatures: bool| {
        let mut c = Coordinator::new(several()).unwrap();
        let mut rs = robots(&mut c, &[Point3::new(3.0, 0.0, 0.0), Point3::new(0.0, 3.0, 0.0)]);
        for k in 0..60 {
            let t_s = k as f64 * 0.05;
            for (i, r) in rs.iter_mut().enumerate() {
                let stamp = T0.plus_secs(t_s).plus_ns(i as i64 * 3 * MS);
                let sig = |_| signatures.then(|| if i == 0 { fan.clone() } else { talker.clone() });
                observe_with(&mut c, r, stamp, &[(1, meet)], sig);
            }
            c.estimate(T0.plus_secs(t_s).plus_ns(20 * MS));
        }
        c.sound_map().unwrap().births
    };
    assert_eq!(births(false), 1, "without signatures the meeting point is taken for a source");
    assert_eq!(births(true), 0, "a fan and a talker are not one source");
}

/// Two robots' rays at two different sources meet at a point where there is
/// nothing: a third robot nearer to that point, which hears a source of its
/// own and nothing there, keeps the point from being born (negative
/// information); with `sources.unheard_range_ratio = 0`, or when the third
/// robot's array is smaller than the pair's, it is born, a ghost.
#[test]
fn a_nearer_robot_that_hears_nothing_there_keeps_a_ghost_from_being_born() {
    let ghost = Point3::new(0.0, 0.0, 1.2);
    let bases = [Point3::new(-3.0, 0.0, 0.0), Point3::new(0.0, -3.0, 0.0), Point3::new(1.5, 1.5, 0.0)];
    // Sources on the first two robots' lines through the ghost, beyond it,
    // and a third source that only the third robot hears.
    let beyond = |base: Point3<f64>| {
        let array = base + nalgebra::Vector3::new(0.0, 0.0, 0.48);
        array + (ghost - array) * 1.5
    };
    let (s1, s2, s3) = (beyond(bases[0]), beyond(bases[1]), Point3::new(3.0, 3.0, 1.0));
    let heard = move |i: usize, _t: f64| match i {
        0 => vec![(1, s1)],
        1 => vec![(2, s2)],
        _ => vec![(3, s3)],
    };
    // 16 microphones on a circle of radius r (aperture 2r).
    let ring = |r: f64| -> Vec<Point3<f64>> {
        (0..16)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 16.0;
                Point3::new(r * a.cos(), r * a.sin(), 0.0)
            })
            .collect()
    };
    let mut published = Vec::new();
    // (ratio, the third robot's array radius): the default; off; the third
    // robot's array smaller than the pair's (it hears later and less, so its
    // silence says less).
    for (ratio, third_radius) in [(1.5, 0.18), (0.0, 0.18), (1.5, 0.045)] {
        let mut config = several();
        config.sources.unheard_range_ratio = ratio;
        let mut c = Coordinator::new(config).unwrap();
        let mut rs: Vec<Robot> = bases
            .iter()
            .enumerate()
            .map(|(i, &base)| {
                let mut h = hello(&format!("r{i}"));
                h.array.microphone_positions = ring(if i == 2 { third_radius } else { 0.18 });
                let conn = c.connect(T0, h, None).unwrap().conn;
                Robot { conn, base, sequence: 0 }
            })
            .collect();
        let est = run(&mut c, &mut rs, 0.0, 4.0, heard);
        let near_ghost =
            est.iter().filter(|(_, e)| e.position().is_some_and(|p| (p - ghost).norm() < 0.3)).count();
        published.push((est.len(), near_ghost));
    }
    println!("(estimates, at the ghost) with the veto / without / from a smaller array: {published:?}");
    assert_eq!(published[0], (0, 0), "the veto let something be born");
    assert!(published[1].1 > 0, "without the veto the ghost should be born: {published:?}");
    assert!(published[2].1 > 0, "a smaller array's silence should not veto: {published:?}");
}

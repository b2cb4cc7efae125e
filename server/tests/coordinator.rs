//! The coordinator state machine driven in-process with `(now, input)`: no
//! tokio, no sockets, no clock. What the gRPC service, the simulator and a
//! replay all run: hellos, observations, estimates, liveness, and the planning
//! cycle's commands.

use crate::common::undeclared_array;
use nalgebra::{Isometry3, Point3, Unit, Vector3};
use soundmap_proto::wire;
use soundmap_proto::{
    ArrayInfo, CommandAck, Hello, Limits, Observation, Problem, RepositionReason, RobotId, RobotInput, Stamp,
    TrackedDoa,
};
use soundmap_server::coordinator::{
    ConnId, Coordinator, Liveness, LivenessChange, Outbound, PlanKind, Welcome,
};
use soundmap_server::uncertainty::angle_at_deg;
use soundmap_server::{CoordinatorConfig, ServerError};

/// Start of coordinator time in these tests (2026-01-01T00:00:00Z).
const T0: Stamp = Stamp::from_ns(1_767_225_600_000_000_000);
const MS: i64 = 1_000_000;

const SOURCE: Point3<f64> = Point3::new(0.0, 0.0, 1.2);

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

fn connect(c: &mut Coordinator, now: Stamp, id: &str) -> ConnId {
    let w: Welcome = c.connect(now, hello(id), None).unwrap();
    assert_eq!((w.robot_id.as_str(), w.resumed), (id, false));
    w.conn
}

/// A noise-free observation of `source` by a robot whose base is at `base`,
/// facing +x, stamped `stamp` with `sequence`.
fn observation(sequence: u64, stamp: Stamp, base: Point3<f64>, source: &Point3<f64>) -> Observation {
    let map_from_base = Isometry3::translation(base.x, base.y, base.z);
    let map_from_array = map_from_base * undeclared_array().base_from_array;
    let direction_in_array = Unit::new_normalize((map_from_array.inverse() * source).coords);
    Observation {
        sequence,
        stamp,
        map_from_base,
        pose_covariance: None,
        doas: vec![TrackedDoa {
            track_id: 1,
            direction_in_array,
            activity: 0.9,
            angular_sigma_rad: Some(1f64.to_radians()),
            signature: None,
            coherence: None,
            floor_fit_range_m: None,
        }],
    }
}

fn array_in_map(base: Point3<f64>) -> Point3<f64> {
    base + Vector3::new(0.0, 0.0, 0.48)
}

#[test]
fn two_robots_observing_a_known_source_give_an_estimate_near_it() {
    let mut c = Coordinator::new(CoordinatorConfig::default()).unwrap();
    let a = connect(&mut c, T0, "a");
    let b = connect(&mut c, T0, "b");
    assert_ne!(a, b);
    // 90° apart at 4 m.
    let (base_a, base_b) = (Point3::new(4.0, 0.0, 0.0), Point3::new(0.0, 4.0, 0.0));
    let stamp = T0.plus_ns(50 * MS);
    let now = T0.plus_ns(60 * MS);
    c.observe(now, a, observation(1, stamp, base_a, &SOURCE)).unwrap();
    assert!(c.estimate(now).is_empty(), "one robot cannot triangulate");
    assert_eq!(c.counters().unaligned, 1);
    c.observe(now, b, observation(1, stamp.plus_ns(5 * MS), base_b, &SOURCE)).unwrap();
    let e = c.estimate(now).pop().expect("two aligned robots");
    let p = e.position().expect("a position");
    assert!((p - SOURCE).norm() < 0.01, "estimate {p} vs source {SOURCE}");
    let ids: Vec<&str> = e.robots.iter().map(|r| r.as_str()).collect();
    assert_eq!(ids, ["a", "b"]);
    let expected_theta = angle_at_deg(&SOURCE, &array_in_map(base_a), &array_in_map(base_b));
    assert!((e.theta_deg() - expected_theta).abs() < 0.5, "θ {} vs {expected_theta}", e.theta_deg());
    assert!(e.trusted(), "θ ≈ 87° with 1° DoAs is trusted: {:?}", e.triangulation);
    let cov = e.covariance().expect("a covariance");
    assert!(cov.trace().sqrt() < 0.3, "honest but small: {cov}");
    // Nothing new: no new estimate, and the counters say what happened.
    assert!(c.estimate(now).is_empty());
    let n = c.counters();
    assert_eq!((n.observations, n.rejected, n.estimates), (2, 0, 1));
    assert_eq!(c.last_estimate().map(|e| e.stamp), Some(stamp.plus_ns(5 * MS)));
    let at = c.array_in_map(&RobotId::parse("b", "id").unwrap()).unwrap();
    assert!((at - array_in_map(base_b)).norm() < 1e-12);
}

#[test]
fn bad_or_out_of_order_observations_are_rejected_naming_the_field_and_state_is_kept() {
    let mut c = Coordinator::new(CoordinatorConfig::default()).unwrap();
    let a = connect(&mut c, T0, "a");
    let base = Point3::new(4.0, 0.0, 0.0);
    let stamp = T0.plus_ns(100 * MS);
    let now = T0.plus_ns(110 * MS);
    c.observe(now, a, observation(5, stamp, base, &SOURCE)).unwrap();

    let field_of = |r: Result<(), ServerError>| match r {
        Err(ServerError::Invalid(v)) => (v.field, v.problem),
        other => panic!("expected a validation error, got {other:?}"),
    };
    // The same sequence again.
    let (field, problem) = field_of(c.observe(now, a, observation(5, stamp.plus_ns(MS), base, &SOURCE)));
    assert_eq!(field, "observation.sequence");
    assert_eq!(problem, Problem::SequenceNotIncreasing { sequence: 5, previous: 5 });
    // A newer sequence with an older stamp.
    let (field, problem) = field_of(c.observe(now, a, observation(6, stamp.plus_ns(-MS), base, &SOURCE)));
    assert_eq!(field, "observation.stamp_ns");
    assert_eq!(problem, Problem::OutOfOrder { stamp_ns: stamp.as_ns() - MS, previous_ns: stamp.as_ns() });

    // A malformed wire observation fails validation before the core, naming the
    // field; the shell counts it with note_rejected.
    let mut w = observation(6, stamp.plus_ns(MS), base, &SOURCE).to_wire();
    w.doas[0].direction_in_array = Some(wire::Vec3 { x: 2.0, y: 0.0, z: 0.0 });
    let msg = wire::RobotMessage { msg: Some(wire::robot_message::Msg::Observation(w)) };
    let e = RobotInput::from_wire(&msg, &Limits::at(now)).unwrap_err();
    assert_eq!(e.field, "observation.doas[0].direction_in_array");
    assert!(matches!(e.problem, Problem::NotUnitVector { .. }), "{e}");
    c.note_rejected(now, a);

    // The robot's state is that of its one good observation.
    let (_, entry) = c.robots().next().unwrap();
    assert_eq!((entry.accepted, entry.rejected), (1, 3));
    assert_eq!((entry.last_sequence, entry.last_stamp), (Some(5), Some(stamp)));
    assert_eq!(entry.history.len(), 1);
    assert_eq!((c.counters().observations, c.counters().rejected), (1, 3));
    // The next in-order observation is accepted.
    c.observe(now, a, observation(6, stamp.plus_ns(MS), base, &SOURCE)).unwrap();
    assert_eq!(c.counters().observations, 2);
    // A stream that never said hello.
    assert!(matches!(
        c.observe(now, 999, observation(1, stamp, base, &SOURCE)),
        Err(ServerError::NoHello("observation"))
    ));
}

#[test]
fn a_stale_robot_leaves_triangulation() {
    let mut c = Coordinator::new(CoordinatorConfig::default()).unwrap();
    let bases = [Point3::new(4.0, 0.0, 0.0), Point3::new(0.0, 4.0, 0.0), Point3::new(-4.0, 0.0, 0.0)];
    let conns: Vec<ConnId> = ["a", "b", "c"].iter().map(|id| connect(&mut c, T0, id)).collect();
    let robots_of = |e: &soundmap_server::coordinator::Estimate| -> Vec<String> {
        e.robots.iter().map(|r| r.to_string()).collect()
    };
    // All three heard at once: all three triangulate.
    let s1 = T0.plus_ns(100 * MS);
    let now = T0.plus_ns(110 * MS);
    for (k, (&conn, base)) in conns.iter().zip(&bases).enumerate() {
        c.observe(now, conn, observation(1, s1.plus_ns(k as i64 * MS), *base, &SOURCE)).unwrap();
    }
    assert!(c.tick(now).is_empty());
    assert_eq!(robots_of(&c.estimate(now).pop().unwrap()), ["a", "b", "c"]);
    // c's next observation arrives on time; a's and b's of the same instant arrive
    // 2.2 s later (stale_after_ms = 2000), by which time c has been silent too long.
    let s2 = T0.plus_ns(200 * MS);
    c.observe(T0.plus_ns(210 * MS), conns[2], observation(2, s2, bases[2], &SOURCE)).unwrap();
    let late = T0.plus_ns(2_410 * MS);
    for k in 0..2 {
        c.observe(late, conns[k], observation(2, s2.plus_ns(MS), bases[k], &SOURCE)).unwrap();
    }
    let changes = c.tick(late);
    let stale = RobotId::parse("c", "id").unwrap();
    assert_eq!(changes, [LivenessChange { robot_id: stale.clone(), liveness: Liveness::Stale }]);
    assert_eq!(c.liveness_of(&stale, late), Some(Liveness::Stale));
    let e = c.estimate(late).pop().unwrap();
    assert_eq!(robots_of(&e), ["a", "b"], "c's aligned observation is left out");
    assert!((e.position().unwrap() - SOURCE).norm() < 0.01);
    // c speaks again: live again, back in.
    c.heartbeat(late, conns[2]).unwrap();
    assert_eq!(c.tick(late), [LivenessChange { robot_id: stale, liveness: Liveness::Live }]);
}

fn positioning_config() -> CoordinatorConfig {
    let mut config = CoordinatorConfig::default();
    config.active_positioning.enabled = true;
    config.planner.free_space.room = vec![[-6.0, -5.0], [6.0, -5.0], [6.0, 5.0], [-6.0, 5.0]];
    config
}

#[test]
fn active_positioning_sends_side_by_side_robots_into_the_band() {
    let mut c = Coordinator::new(positioning_config()).unwrap();
    // 0.8 m apart, 5 m from the source: θ ≈ 9°, the paper's failure case.
    let bases = [Point3::new(5.0, 0.4, 0.0), Point3::new(5.0, -0.4, 0.0)];
    let conns = [connect(&mut c, T0, "a"), connect(&mut c, T0, "b")];
    let theta0 = angle_at_deg(&SOURCE, &array_in_map(bases[0]), &array_in_map(bases[1]));
    assert!((theta0 - 9.0).abs() < 1.0, "θ {theta0}");
    let stamp = T0.plus_ns(100 * MS);
    let now = T0.plus_ns(110 * MS);
    for (k, &conn) in conns.iter().enumerate() {
        c.observe(now, conn, observation(1, stamp, bases[k], &SOURCE)).unwrap();
    }
    let e = c.estimate(now).pop().unwrap();
    assert!(!e.trusted(), "θ ≈ 9° is not trusted");
    let out = c.take_outgoing();
    assert_eq!(out.len(), 2, "{out:?}");
    let mut goals = Vec::new();
    for (o, &conn) in out.iter().zip(&conns) {
        assert_eq!(o.conn, conn);
        let Outbound::Reposition(cmd) = &o.message else { panic!("{o:?}") };
        assert_eq!(cmd.reason, RepositionReason::ThetaOutOfBand);
        assert_eq!((cmd.issued, cmd.deadline), (now, now.plus_secs(30.0)));
        assert!(cmd.detail.starts_with("θ out of band: θ 9."), "{}", cmd.detail);
        assert!((cmd.look_at_in_map - SOURCE).norm() < 0.5, "{:?}", cmd.look_at_in_map);
        goals.push(cmd.goal_map_from_base.translation.vector);
    }
    let ids: Vec<u64> = out
        .iter()
        .map(|o| match &o.message {
            Outbound::Reposition(cmd) => cmd.command_id,
            other => panic!("{other:?}"),
        })
        .collect();
    assert_ne!(ids[0], ids[1]);
    // The goals open the angle (one step at a time, so not yet into the band).
    let goal_theta = angle_at_deg(&SOURCE, &array_in_map(goals[0].into()), &array_in_map(goals[1].into()));
    assert!(goal_theta > theta0 + 10.0, "θ at the goals {goal_theta} vs {theta0}");
    let status = c.planner_status().unwrap();
    assert_eq!((status.kind, status.commands_issued, status.last_planned), (PlanKind::Planned, 2, Some(now)));
    assert!(status.predicted_theta_deg.unwrap() > theta0);

    // The robots answer: an unknown command is refused naming the field.
    let ack = |id| CommandAck { command_id: id, accepted: true, reason: String::new() };
    c.command_ack(now, conns[0], &ack(ids[0])).unwrap();
    assert!(matches!(
        c.command_ack(now, conns[0], &ack(ids[1])),
        Err(ServerError::UnknownCommand { field: "command_ack.command_id", .. })
    ));

    // Within the planning period (1 s): more estimates, no new commands.
    for k in 1..=5 {
        let stamp = stamp.plus_ns(k * 150 * MS);
        let now = now.plus_ns(k * 150 * MS);
        for (i, &conn) in conns.iter().enumerate() {
            c.observe(now, conn, observation(1 + k as u64, stamp, bases[i], &SOURCE)).unwrap();
        }
        assert!(!c.estimate(now).is_empty());
        assert!(c.take_outgoing().is_empty(), "re-tasked {} ms after the plan", k * 150);
    }
    assert_eq!(c.planner_status().unwrap().commands_issued, 2);

    // Switched off: the commands still being executed are cancelled.
    let update =
        soundmap_server::coordinator::PositioningUpdate { enabled: Some(false), ..Default::default() };
    assert!(!c.set_active_positioning(now, &update).unwrap().enabled);
    let cancels: Vec<u64> = c
        .take_outgoing()
        .into_iter()
        .map(|o| match o.message {
            Outbound::Cancel { command_id, .. } => command_id,
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(cancels, ids);
}

#[test]
fn a_band_without_90_degrees_is_refused_naming_the_field() {
    let mut c = Coordinator::new(positioning_config()).unwrap();
    let update =
        soundmap_server::coordinator::PositioningUpdate { theta_min_deg: Some(100.0), ..Default::default() };
    match c.set_active_positioning(T0, &update) {
        Err(ServerError::Invalid(v)) => assert_eq!(v.field, "theta_min_deg", "{v}"),
        other => panic!("{other:?}"),
    }
    let s = c.positioning();
    assert_eq!((s.enabled, s.theta_min_deg, s.theta_max_deg), (true, 40.0, 140.0), "unchanged");
}

/// The wiring of the floor-image model: robots whose hello declares a planar
/// array's microphone positions and SRP band get their DoAs compared with what
/// such an array measures (`server::floor_image`: elevation pulled toward the
/// mirrored floor image); robots that declare no band get them taken as
/// straight directions. DoAs here are made by the model itself, 5 m away, where
/// the pull is large.
/// A planar array of 8 microphones on a 0.15 m circle.
fn octagon() -> Vec<Point3<f64>> {
    (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_4;
            Point3::new(0.15 * a.cos(), 0.15 * a.sin(), 0.0)
        })
        .collect()
}

/// The SRP band the [`octagon`] robots declare (Hz).
const OCTAGON_BAND: [f64; 2] = [100.0, 8000.0];

/// What an [`octagon`] array 0.48 m above the floor measures, with the
/// floor's reflection coefficient `reflection`, one σ on both axes.
fn octagon_fold(reflection: f64) -> soundmap_server::floor_image::FloorFold {
    let [lo, hi] = OCTAGON_BAND;
    let lobe = soundmap_server::floor_image::array_pattern(&octagon(), (lo, hi)).expect("planar").lobe(None);
    soundmap_server::floor_image::FloorFold {
        array_height_m: 0.48,
        reflection,
        lobe,
        ceiling_m: None,
        vertical_spread: None,
        upper_branch: true,
        fitted_range_m: None,
    }
}

#[test]
fn declared_planar_arrays_get_the_floor_image_model_and_others_do_not() {
    let source = Point3::new(0.0, 0.0, 1.2);
    let band = OCTAGON_BAND;
    let config = CoordinatorConfig::default();
    let fold = octagon_fold(config.doa.floor_reflection);
    let declared = folded_estimate(config.clone(), Some(band), &fold, None, &source);
    let undeclared = folded_estimate(config, None, &fold, None, &source);
    assert!((declared - source).norm() < 0.02, "declared: {declared} vs {source}");
    assert!(undeclared.z - source.z > 0.15, "undeclared: {undeclared} is pulled up from {source}");
}

/// A robot that fitted the floor's reflection into its DoAs says so
/// (`ArrayInfo::direct_path_elevations`): its DoAs of the direct path are
/// folded without a pull and meet at the source. Sent without the flag, the
/// same DoAs are corrected for a pull they do not have and meet below it.
#[test]
fn direct_path_elevations_are_folded_without_a_pull() {
    let source = Point3::new(0.0, 0.0, 1.2);
    let config = CoordinatorConfig::default();
    let direct = octagon_fold(0.0);
    let declared = folded_published(config.clone(), Some(OCTAGON_BAND), &direct, None, &source, true, None).0;
    let undeclared = folded_published(config, Some(OCTAGON_BAND), &direct, None, &source, false, None).0;
    assert!((declared - source).norm() < 0.02, "declared: {declared} vs {source}");
    assert!(source.z - undeclared.z > 0.1, "undeclared: {undeclared} is pulled down from {source}");
}

/// A robot's floor fit that resolved the image path but not the range
/// (fitted 12 m away for a source 5 m away) reports a direction too high;
/// sent with its `floor_fit_range_m`, the coordinator reads it along that
/// image path at its own range and the rays meet at the source. Without
/// the range, the same DoAs meet above it.
#[test]
fn a_floor_fit_is_read_along_its_image_path_at_the_coordinators_range() {
    let source = Point3::new(0.0, 0.0, 1.2);
    let config = CoordinatorConfig::default();
    let fitted = soundmap_server::floor_image::FloorFold { fitted_range_m: Some(12.0), ..octagon_fold(0.0) };
    let band = Some(OCTAGON_BAND);
    let read = folded_published(config.clone(), band, &fitted, None, &source, true, Some(12.0)).0;
    let unread = folded_published(config, band, &fitted, None, &source, true, None).0;
    assert!((read - source).norm() < 0.02, "with the range: {read} vs {source}");
    assert!(unread.z - source.z > 0.1, "without: {unread} is above {source}");
}

/// With `doa.reverberant_pull` on, a DoA's coherence sets the floor image's
/// weight (`floor_image::reverberant_reflection`); off, the fixed
/// `floor_reflection` does, whatever the DoA says.
#[test]
fn a_doas_coherence_sets_the_floor_image_weight_when_asked() {
    use soundmap_server::floor_image::reverberant_reflection;
    let source = Point3::new(0.0, 0.0, 1.2);
    let band = OCTAGON_BAND;
    let (coherence, pull) = (0.22, 0.06);
    let reflection = reverberant_reflection(coherence, 1.0, pull).unwrap();
    assert!(reflection > 0.8, "{reflection}");
    let fold = octagon_fold(reflection);
    let errors: Vec<f64> = [pull, 0.0]
        .into_iter()
        .map(|p| {
            let mut config = CoordinatorConfig::default();
            config.doa.reverberant_pull = p;
            (folded_estimate(config, Some(band), &fold, Some(coherence), &source) - source).norm()
        })
        .collect();
    assert!(errors[0] < 0.02, "pull on: {errors:?}");
    assert!(errors[1] > 0.05, "pull off (fixed reflection): {errors:?}");
}

/// With `doa.planar_elevation_noise` on, a declared planar array's DoAs count
/// as noisier in elevation than in azimuth: two such robots at the same
/// height as each other and 0.7 m below a source 5 m away publish a height
/// variance several times larger than with one σ, the horizontal ones
/// nearly unchanged, and the same position.
#[test]
fn planar_elevation_noise_widens_the_published_height_only() {
    let source = Point3::new(0.0, 0.0, 1.2);
    let published = |on: bool| {
        let mut config = CoordinatorConfig::default();
        config.doa.planar_elevation_noise = on;
        let fold = octagon_fold(config.doa.floor_reflection);
        folded_published(config, Some(OCTAGON_BAND), &fold, None, &source, false, None)
    };
    let (off_p, off_cov) = published(false);
    let (on_p, on_cov) = published(true);
    assert!((on_p - off_p).norm() < 0.02, "{on_p} vs {off_p}");
    assert!(on_cov[(2, 2)] > 4.0 * off_cov[(2, 2)], "zz: {} vs {}", on_cov[(2, 2)], off_cov[(2, 2)]);
    for k in 0..2 {
        assert!(on_cov[(k, k)] < 1.2 * off_cov[(k, k)], "axis {k}: {on_cov} vs {off_cov}");
    }
}

/// The position a coordinator with `config` publishes when two robots with
/// [`octagon`] arrays (declaring `band`, or no SRP band), 5 m from `source`
/// at 90°, report what `fold` says such arrays measure for it, each DoA
/// carrying `coherence`.
fn folded_estimate(
    config: CoordinatorConfig,
    band: Option<[f64; 2]>,
    fold: &soundmap_server::floor_image::FloorFold,
    coherence: Option<f64>,
    source: &Point3<f64>,
) -> Point3<f64> {
    folded_published(config, band, fold, coherence, source, false, None).0
}

/// [`folded_estimate`]'s position and its covariance, the robots declaring
/// `direct_path_elevations` and each DoA carrying `floor_fit_range_m`.
fn folded_published(
    config: CoordinatorConfig,
    band: Option<[f64; 2]>,
    fold: &soundmap_server::floor_image::FloorFold,
    coherence: Option<f64>,
    source: &Point3<f64>,
    direct_path_elevations: bool,
    floor_fit_range_m: Option<f64>,
) -> (Point3<f64>, nalgebra::Matrix3<f64>) {
    let mut c = Coordinator::new(config).unwrap();
    let planar = ArrayInfo {
        microphone_count: 8,
        microphone_positions: octagon(),
        srp_band_hz: band,
        direct_path_elevations,
        ..undeclared_array()
    };
    let conns: Vec<_> = ["a", "b"]
        .iter()
        .map(|id| c.connect(T0, Hello { array: planar.clone(), ..hello(id) }, None).unwrap().conn)
        .collect();
    let now = T0.plus_ns(60 * MS);
    for (k, (conn, base)) in
        conns.iter().zip([Point3::new(5.0, 0.0, 0.0), Point3::new(0.0, 5.0, 0.0)]).enumerate()
    {
        let mut obs = observation(1, T0.plus_ns((50 + k as i64) * MS), base, source);
        obs.doas[0].direction_in_array = fold.measured_direction(&array_in_map(base), source).unwrap();
        obs.doas[0].coherence = coherence;
        obs.doas[0].floor_fit_range_m = floor_fit_range_m;
        c.observe(now, *conn, obs).unwrap();
    }
    let e = c.estimate(now).pop().expect("two aligned robots");
    (e.position().expect("a position"), e.covariance().expect("a covariance"))
}

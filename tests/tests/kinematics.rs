//! Simulated robots: differential-drive limits, waypoint following, the
//! navigator, sampled trajectories, and the SLAM pose error model.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use soundmap_proto::CommandState;
use soundmap_sim::kinematics::{
    DiffDriveRobot, DriveLimits, FollowStatus, FollowerConfig, Navigator, NavigatorConfig, Pose2,
    SampledTrajectory, Twist, Waypoint, WaypointFollower, wrap_angle,
};
use soundmap_sim::slam_noise::{Drift, SlamNoise, SlamNoiseConfig};

const DT: f64 = 0.01;

#[test]
fn kinematic_limits_hold_under_arbitrary_commands() {
    let limits = DriveLimits { max_reverse_speed_m_per_s: 0.2, ..DriveLimits::default() };
    let mut robot = DiffDriveRobot::new(Pose2::new(1.0, 2.0, 0.3), limits, DT).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut cmd = Twist::default();
    let eps = 1e-9;
    for step in 0..20_000 {
        if step % 37 == 0 {
            // Wild commands, far beyond the limits, sometimes not finite.
            cmd = Twist::new(rng.random_range(-5.0..5.0), rng.random_range(-10.0..10.0));
            if step % 999 == 0 {
                cmd.linear_m_per_s = f64::NAN;
            }
        }
        let (before, tw0) = (robot.pose(), robot.twist());
        robot.step(cmd);
        let (after, tw1) = (robot.pose(), robot.twist());
        assert!(tw1.linear_m_per_s <= limits.max_speed_m_per_s + eps);
        assert!(tw1.linear_m_per_s >= -limits.max_reverse_speed_m_per_s - eps);
        assert!(tw1.angular_rad_per_s.abs() <= limits.max_turn_rate_rad_per_s + eps);
        assert!((tw1.linear_m_per_s - tw0.linear_m_per_s).abs() <= limits.max_accel_m_per_s2 * DT + eps);
        assert!(
            (tw1.angular_rad_per_s - tw0.angular_rad_per_s).abs()
                <= limits.max_angular_accel_rad_per_s2 * DT + eps
        );
        assert!(before.distance_to(&after) <= limits.max_speed_m_per_s * DT + eps);
        let turned = wrap_angle(after.yaw_rad - before.yaw_rad).abs();
        assert!(turned <= limits.max_turn_rate_rad_per_s * DT + eps);
        assert!(after.x_m.is_finite() && after.y_m.is_finite());
    }
    let p = robot.map_from_base();
    assert_eq!(p.translation.z, 0.0, "ground robots stay at z = 0");
}

#[test]
fn waypoint_following_reaches_every_waypoint_in_order() {
    let limits = DriveLimits::default();
    let wps =
        vec![Waypoint::at(3.0, 0.0), Waypoint::at(3.0, 3.0), Waypoint::at(0.0, 3.0), Waypoint::at(0.5, 0.5)];
    let config = FollowerConfig::default();
    let mut robot = DiffDriveRobot::new(Pose2::new(0.0, 0.0, 0.0), limits, DT).unwrap();
    let mut f = WaypointFollower::new(wps.clone(), config);
    let mut next = 0;
    while robot.time_s() < 120.0 {
        let (cmd, status) = f.command(robot.time_s(), &robot.pose(), &limits);
        if let FollowStatus::Driving { index, .. } = status {
            assert!(index >= next, "waypoints are visited in order");
            next = index;
        }
        if status == FollowStatus::Done {
            break;
        }
        robot.step(cmd);
    }
    assert!(f.is_done(), "not done after {} s: {:?}", robot.time_s(), f.reached_s());
    assert_eq!(f.reached_s().len(), wps.len());
    let last = wps.last().unwrap();
    assert!(robot.pose().distance_to(&Pose2::new(last.x_m, last.y_m, 0.0)) <= config.tolerance_m);
    // About 9.7 m of path at 0.5 m/s plus turns.
    assert!(robot.time_s() < 40.0, "took {} s", robot.time_s());
    // It stops at the last one (deceleration planned within the limits).
    for _ in 0..300 {
        let (cmd, _) = f.command(robot.time_s(), &robot.pose(), &limits);
        robot.step(cmd);
    }
    assert!(robot.twist().linear_m_per_s.abs() < 1e-9);
    assert!(robot.pose().distance_to(&Pose2::new(last.x_m, last.y_m, 0.0)) <= config.tolerance_m + 0.05);
}

#[test]
fn timed_waypoints_are_reached_on_time_not_early() {
    let limits = DriveLimits::default();
    // 2 m in 8 s (0.25 m/s), then 2 m by 12 s (0.5 m/s, tight), then a wait point.
    let wps = vec![
        Waypoint::timed(2.0, 0.0, 8.0),
        Waypoint::timed(2.0, 2.0, 14.0),
        Waypoint::timed(2.5, 2.0, 20.0),
    ];
    let traj = SampledTrajectory::from_waypoints(
        Pose2::default(),
        wps.clone(),
        limits,
        FollowerConfig::default(),
        DT,
        30.0,
    )
    .unwrap();
    let mut f = WaypointFollower::new(wps.clone(), FollowerConfig::default());
    let mut robot = DiffDriveRobot::new(Pose2::default(), limits, DT).unwrap();
    while robot.time_s() < 30.0 {
        let (cmd, _) = f.command(robot.time_s(), &robot.pose(), &limits);
        robot.step(cmd);
        // The free function and the hand-run loop agree.
        let p = traj.pose_at(robot.time_s());
        assert!(p.distance_to(&robot.pose()) < 1e-9);
    }
    assert!(f.is_done());
    for (wp, reached) in wps.iter().zip(f.reached_s()) {
        let t = wp.arrival_s.unwrap();
        assert!(*reached > t - 1.5 && *reached < t + 1.5, "waypoint due at {t} s reached at {reached} s");
    }
    // It waited at the last waypoint: not there long before 20 s means it did not rush; the
    // status while early is Waiting.
    let mut f = WaypointFollower::new(vec![Waypoint::timed(0.05, 0.0, 5.0)], FollowerConfig::default());
    let (cmd, status) = f.command(1.0, &Pose2::default(), &limits);
    assert_eq!(status, FollowStatus::Waiting { index: 0 });
    assert_eq!(cmd, Twist::default());
    assert_eq!(f.command(5.1, &Pose2::default(), &limits).1, FollowStatus::Done);
}

fn run_nav(nav: &mut Navigator, robot: &mut DiffDriveRobot, until_s: f64) -> Vec<(f64, CommandState, f64)> {
    let mut log = Vec::new();
    while robot.time_s() < until_s {
        let (cmd, progress) = nav.step(robot.time_s(), &robot.pose(), &robot.twist(), robot.limits());
        let p = progress.unwrap();
        log.push((robot.time_s(), p.state, p.distance_remaining_m));
        if p.state != CommandState::Executing {
            break;
        }
        robot.step(cmd);
    }
    log
}

fn goal(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

#[test]
fn navigator_reaches_a_goal_pose_and_reports_progress() {
    let limits = DriveLimits::default();
    let mut robot = DiffDriveRobot::new(Pose2::new(0.0, 0.0, 0.0), limits, DT).unwrap();
    let mut nav = Navigator::new(NavigatorConfig::default());
    assert_eq!(nav.set_goal(7, &goal(4.0, 3.0, 2.0), None).unwrap(), None);
    assert_eq!(nav.progress().unwrap().state, CommandState::Executing);
    let log = run_nav(&mut nav, &mut robot, 60.0);
    let (t_end, state, _) = *log.last().unwrap();
    assert_eq!(state, CommandState::Succeeded, "not arrived after {t_end} s");
    // 5 m at 0.5 m/s plus two turns: well under 20 s.
    assert!(t_end < 20.0, "took {t_end} s");
    let cfg = NavigatorConfig::default();
    let p = robot.pose();
    assert!(p.distance_to(&Pose2::new(4.0, 3.0, 0.0)) <= cfg.position_tolerance_m);
    assert!(wrap_angle(p.yaw_rad - 2.0).abs() <= cfg.yaw_tolerance_rad);
    // Remaining distance starts at 5 m and goes down second by second.
    assert!((log[0].2 - 5.0).abs() < 1e-9);
    let per_second: Vec<f64> = log.iter().step_by(100).map(|l| l.2).collect();
    for w in per_second.windows(2) {
        assert!(w[1] <= w[0] + 1e-6, "remaining distance went up: {per_second:?}");
    }
    // Idle after arrival: zero command, last progress kept.
    let (cmd, progress) = nav.step(robot.time_s(), &robot.pose(), &robot.twist(), &limits);
    assert_eq!(cmd, Twist::default());
    assert_eq!(progress.unwrap().state, CommandState::Succeeded);
    assert_eq!(progress.unwrap().goal_id, 7);
}

#[test]
fn a_newer_goal_replaces_the_current_one() {
    let limits = DriveLimits::default();
    let mut robot = DiffDriveRobot::new(Pose2::new(1.0, 1.0, 0.0), limits, DT).unwrap();
    let mut nav = Navigator::new(NavigatorConfig::default());
    nav.set_goal(1, &goal(6.0, 1.0, 0.0), None).unwrap();
    run_nav(&mut nav, &mut robot, 3.0);
    assert!(nav.set_goal(9, &goal(f64::NAN, 4.0, -1.0), None).is_err(), "a non-finite goal is refused");
    assert_eq!(nav.progress().unwrap().goal_id, 1, "a refused goal leaves the current one");
    let replaced = nav.set_goal(2, &goal(1.0, 4.0, -1.0), None).unwrap().expect("goal 1 was open");
    assert_eq!((replaced.goal_id, replaced.state), (1, CommandState::Canceled));
    assert!(replaced.distance_remaining_m < 5.0 && replaced.distance_remaining_m > 3.0);
    let log = run_nav(&mut nav, &mut robot, 60.0);
    assert_eq!(log.last().unwrap().1, CommandState::Succeeded);
    assert_eq!(nav.progress().unwrap().goal_id, 2);
    assert!(robot.pose().distance_to(&Pose2::new(1.0, 4.0, 0.0)) <= 0.1);
    // A goal that cannot be reached before its deadline fails.
    nav.set_goal(3, &goal(10.0, 10.0, 0.0), Some(robot.time_s() + 2.0)).unwrap();
    let until = robot.time_s() + 10.0;
    let log = run_nav(&mut nav, &mut robot, until);
    assert_eq!(log.last().unwrap().1, CommandState::Failed);
}

#[test]
fn sampled_trajectory_interpolates_between_samples() {
    let poses = vec![Pose2::new(0.0, 0.0, 3.0), Pose2::new(1.0, 2.0, -3.0)];
    let t = SampledTrajectory::new(10.0, 0.5, poses).unwrap();
    let mid = t.pose_at(10.25);
    assert!((mid.x_m - 0.5).abs() < 1e-12 && (mid.y_m - 1.0).abs() < 1e-12);
    // Heading interpolates across ±π along the short way.
    assert!((wrap_angle(mid.yaw_rad - std::f64::consts::PI)).abs() < 1e-9, "{}", mid.yaw_rad);
    assert_eq!(t.pose_at(0.0), Pose2::new(0.0, 0.0, 3.0));
    assert_eq!(t.pose_at(99.0), Pose2::new(1.0, 2.0, -3.0));
}

fn truth(t: f64) -> Isometry3<f64> {
    goal(2.0 + 0.1 * t, 1.0, 0.05 * t)
}

/// Errors (x, y, yaw) of the reported pose against the truth.
fn errors(reported: &Isometry3<f64>, t: f64) -> [f64; 3] {
    let (r, tr) = (Pose2::from_map_from_base(reported), Pose2::from_map_from_base(&truth(t)));
    [r.x_m - tr.x_m, r.y_m - tr.y_m, wrap_angle(r.yaw_rad - tr.yaw_rad)]
}

fn std(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn slam_white_noise_has_the_configured_spread() {
    let cfg = SlamNoiseConfig { drift: Drift::None, ..SlamNoiseConfig::default() };
    let mut noise = SlamNoise::new(cfg, 3).unwrap();
    let mut e = [Vec::new(), Vec::new(), Vec::new()];
    for i in 0..20_000 {
        let t = i as f64 * 0.05;
        let err = errors(&noise.observe(t, &truth(t)).unwrap(), t);
        for k in 0..3 {
            e[k].push(err[k]);
        }
    }
    let want = [cfg.position_white_std_m, cfg.position_white_std_m, cfg.yaw_white_std_rad];
    for k in 0..3 {
        assert!((std(&e[k]) / want[k] - 1.0).abs() < 0.03, "axis {k}: std {} vs {}", std(&e[k]), want[k]);
    }
    let cov = noise.covariance();
    assert!((cov[(0, 0)] - want[0].powi(2)).abs() < 1e-15 && (cov[(5, 5)] - want[2].powi(2)).abs() < 1e-15);
}

#[test]
fn slam_drift_is_gauss_markov_with_the_configured_time_constant() {
    let (sigma, yaw_sigma, tau) = (0.03, 0.8f64.to_radians(), 20.0);
    let cfg = SlamNoiseConfig {
        position_white_std_m: 0.0,
        yaw_white_std_rad: 0.0,
        drift: Drift::GaussMarkov { position_std_m: sigma, yaw_std_rad: yaw_sigma, time_constant_s: tau },
        ..SlamNoiseConfig::default()
    };
    // Many independent robots: the variance at t = 5 s and t = 200 s.
    let (mut at5, mut at200) = (Vec::new(), Vec::new());
    for seed in 0..3000 {
        let mut noise = SlamNoise::new(cfg, seed).unwrap();
        let mut t = 0.0;
        while t < 200.0 {
            t += 0.5;
            noise.observe(t, &truth(t)).unwrap();
            if t == 5.0 {
                at5.push(noise.drift().x);
            }
        }
        at200.push(noise.drift().x);
    }
    let expected5 = sigma * (1.0 - (-2.0 * 5.0 / tau).exp()).sqrt();
    assert!((std(&at5) / expected5 - 1.0).abs() < 0.06, "std at 5 s {} vs {expected5}", std(&at5));
    assert!((std(&at200) / sigma - 1.0).abs() < 0.06, "stationary std {} vs {sigma}", std(&at200));
    let cov5 = SlamNoise::new(cfg, 0).unwrap().covariance_at(5.0);
    assert!((cov5[(0, 0)].sqrt() / expected5 - 1.0).abs() < 1e-12);
    // One long run: the autocorrelation at lag τ is 1/e; variable step sizes do not matter.
    let mut noise = SlamNoise::new(cfg, 99).unwrap();
    let (mut xs, mut yaws) = (Vec::new(), Vec::new());
    let mut t = 0.0;
    let mut i = 0;
    while t < 40_000.0 {
        t += if i % 2 == 0 { 0.3 } else { 0.7 };
        i += 1;
        let err = errors(&noise.observe(t, &truth(t)).unwrap(), t);
        if i % 2 == 0 {
            xs.push(err[0]);
            yaws.push(err[2]);
        }
    }
    // Samples are 1 s apart.
    let lag = tau as usize;
    let m = xs.iter().sum::<f64>() / xs.len() as f64;
    let c0: f64 = xs.iter().map(|x| (x - m).powi(2)).sum();
    let c1: f64 = xs.windows(lag + 1).map(|w| (w[0] - m) * (w[lag] - m)).sum();
    let rho = c1 / c0;
    assert!((rho - (-1.0f64).exp()).abs() < 0.06, "autocorrelation at τ: {rho}");
    assert!((std(&yaws) / yaw_sigma - 1.0).abs() < 0.1, "yaw drift std {} vs {yaw_sigma}", std(&yaws));
}

#[test]
fn slam_random_walk_grows_like_sqrt_t_and_covariance_follows() {
    let cfg = SlamNoiseConfig {
        drift: Drift::RandomWalk { position_m_per_sqrt_s: 0.004, yaw_rad_per_sqrt_s: 0.001 },
        ..SlamNoiseConfig::default()
    };
    let mut errs = Vec::new();
    for seed in 0..3000 {
        let mut noise = SlamNoise::new(cfg, seed).unwrap();
        let mut last = noise.observe(0.0, &truth(0.0)).unwrap();
        for k in 1..=100 {
            last = noise.observe(k as f64, &truth(k as f64)).unwrap();
        }
        errs.push(errors(&last, 100.0)[1]);
        if seed == 0 {
            let c = noise.covariance();
            let want = 0.02f64.powi(2) + 0.004f64.powi(2) * 100.0;
            assert!((c[(1, 1)] - want).abs() < 1e-15);
        }
    }
    let want = (0.02f64.powi(2) + 0.004f64.powi(2) * 100.0).sqrt();
    assert!((std(&errs) / want - 1.0).abs() < 0.05, "total std {} vs {want}", std(&errs));
}

#[test]
fn slam_noise_is_deterministic_and_rejects_time_going_back() {
    let run = |seed| {
        let mut n = SlamNoise::new(SlamNoiseConfig::default(), seed).unwrap();
        (0..50).map(|k| n.observe(k as f64 * 0.1, &truth(k as f64 * 0.1)).unwrap()).collect::<Vec<_>>()
    };
    assert_eq!(run(4), run(4));
    assert_ne!(run(4), run(5));
    let mut n = SlamNoise::new(SlamNoiseConfig::default(), 1).unwrap();
    n.observe(2.0, &truth(2.0)).unwrap();
    assert!(n.observe(1.0, &truth(1.0)).is_err());
    let perfect = SlamNoise::new(SlamNoiseConfig::perfect(), 1).unwrap().observe(1.0, &truth(1.0)).unwrap();
    assert_eq!(perfect, truth(1.0));
    assert!(SlamNoise::new(SlamNoiseConfig { position_white_std_m: -1.0, ..Default::default() }, 0).is_err());
}

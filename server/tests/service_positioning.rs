//! Active positioning end to end at the protocol level, over a real loopback
//! socket: reposition commands reach the robots before the acknowledgement of
//! the observation that caused them, robots answer and "drive" (report their
//! goal pose), θ enters the band and the planner holds; the operator switches
//! it on and off and sets the band; refused goals are not re-sent blindly;
//! three robots.

use crate::common;

use common::fleet::{Answer, Fleet, time_of};
use common::*;
use nalgebra::Point3;
use soundmap_proto::{BaseLimits, wire};
use soundmap_server::CoordinatorConfig;
use tonic::Code;

const SOURCE: Point3<f64> = Point3::new(0.0, 0.0, 1.2);

/// Two robots 0.8 m apart, 5 m from the source: θ ≈ 9° (the paper's failure case).
const SIDE_BY_SIDE: [Point3<f64>; 2] = [Point3::new(5.0, 0.4, 0.0), Point3::new(5.0, -0.4, 0.0)];

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
    vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
}

/// Active positioning on, in a 12 m × 10 m room.
fn config(enabled: bool) -> CoordinatorConfig {
    let mut c = CoordinatorConfig::default();
    c.active_positioning.enabled = enabled;
    c.planner.free_space.room = rect(-6.0, -5.0, 6.0, 5.0);
    c
}

async fn state(addr: std::net::SocketAddr) -> wire::CoordinatorState {
    monitoring(addr).await.get_state(wire::GetStateRequest {}).await.unwrap().into_inner()
}

async fn set(
    addr: std::net::SocketAddr,
    enabled: Option<bool>,
    min: Option<f64>,
    max: Option<f64>,
) -> Result<wire::ActivePositioning, tonic::Status> {
    let r = wire::SetActivePositioningRequest { enabled, theta_min_deg: min, theta_max_deg: max };
    monitoring(addr).await.set_active_positioning(r).await.map(|r| r.into_inner())
}

/// Steps the fleet until the planner holds with a good geometry (at most `max_steps`).
async fn until_geometry_good(
    fleet: &mut Fleet,
    clock: &soundmap_server::clock::ManualClock,
    addr: std::net::SocketAddr,
    max_steps: usize,
) -> wire::CoordinatorState {
    for _ in 0..max_steps {
        fleet.step(clock).await;
        if fleet.step.is_multiple_of(10) {
            let s = state(addr).await;
            let p = s.planner.as_ref().expect("the planner ran");
            if p.outcome == wire::PlannerOutcome::Hold as i32 && p.detail.starts_with("geometry good") {
                return s;
            }
        }
    }
    panic!(
        "no good geometry after {max_steps} steps: θ {:.1}°, {:?}",
        fleet.theta_deg(),
        state(addr).await.planner
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn side_by_side_robots_are_sent_into_the_band_and_the_planner_holds() {
    let (coordinator, clock) = start(config(true)).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let mut fleet = Fleet::connect(addr, &["a", "b"], &SIDE_BY_SIDE, SOURCE).await;
    let theta0 = fleet.theta_deg();
    assert!((theta0 - 9.0).abs() < 1.0, "start θ {theta0}");
    // Step 0: a's observation alone gives no estimate; b's gives one, whose
    // planning cycle commands both robots. b, whose observation caused it, gets
    // its command before that observation's ack; a before its next ack.
    let t0 = fleet.step(&clock).await;
    let e = next_estimate(&mut estimates).await;
    assert!(!e.trusted, "θ ≈ 9° is not trusted: {:?}", e.triangulation);
    assert_eq!(fleet.commands[1].len(), 1, "b: {:?}", fleet.commands[1]);
    assert_eq!(fleet.commands[1][0].step, 0);
    assert!(fleet.commands[0].is_empty());
    fleet.step(&clock).await;
    assert_eq!(fleet.commands[0].len(), 1);
    assert_eq!(fleet.commands[0][0].step, 1, "a's command came before the ack of its next observation");
    let (ca, cb) = (&fleet.commands[0][0].command, &fleet.commands[1][0].command);
    for c in [ca, cb] {
        assert_eq!(c.issued_ns, t0.as_ns());
        assert_eq!(c.deadline_ns, t0.plus_secs(30.0).as_ns());
        assert_eq!(c.reason, wire::RepositionReason::ThetaOutOfBand as i32);
        assert!(c.detail.starts_with("θ out of band: θ 9."), "{}", c.detail);
        let look = c.look_at_in_map_m.as_ref().unwrap();
        assert!((Point3::new(look.x, look.y, look.z) - SOURCE).norm() < 0.5, "looks at the source: {look:?}");
    }
    assert!(cb.command_id > 0 && ca.command_id != cb.command_id);
    // GetState: both commands, the robots' reports, the planner's decision.
    let s = state(addr).await;
    let p = s.planner.as_ref().unwrap();
    assert_eq!(p.outcome, wire::PlannerOutcome::Planned as i32, "{p:?}");
    assert_eq!(p.commands_issued, 2);
    assert_eq!(p.last_planned_ns, t0.as_ns());
    assert!(p.predicted_theta_deg > theta0, "{p:?}");
    assert_eq!(
        s.active_positioning,
        Some(wire::ActivePositioning { enabled: true, theta_min_deg: 40.0, theta_max_deg: 140.0 })
    );
    // The robots "drive" (arrive at each goal one step after it is sent) until the planner holds.
    let s = until_geometry_good(&mut fleet, &clock, addr, 400).await;
    let theta = fleet.theta_deg();
    println!(
        "side by side: θ {theta0:.1}° → {theta:.1}° after {} steps ({:.1} s), {} commands; planner: {}",
        fleet.step,
        fleet.step as f64 * fleet.dt_s,
        fleet.command_count(),
        s.planner.as_ref().unwrap().detail
    );
    assert!((40.0..=140.0).contains(&theta), "θ {theta}");
    let last = s.sources.first().expect("an estimate");
    assert!(last.trusted && (40.0..=140.0).contains(&last.theta_deg), "{last:?}");
    assert!(fleet.commands.iter().all(|c| !c.is_empty()));
    // Every command came with a new id and at most once per planning period per robot.
    let period_ns = (config(true).planner.planning_period_s * 1e9).round() as i64;
    for cmds in &fleet.commands {
        for w in cmds.windows(2) {
            assert!(w[1].command.command_id > w[0].command.command_id);
            assert!(w[1].command.issued_ns - w[0].command.issued_ns >= period_ns, "{w:?}");
        }
    }
    // Holding: more steps, no more commands.
    let n = fleet.command_count();
    for _ in 0..30 {
        fleet.step(&clock).await;
    }
    assert_eq!(fleet.command_count(), n, "the planner holds a good geometry");
    for r in &state(addr).await.robots {
        assert_eq!(r.active_command_state, wire::CommandState::Succeeded as i32, "{}", r.robot_id);
    }
    coordinator.shutdown().await.unwrap();
}

/// Each robot's goals are planned for the speed its hello declares: from the
/// paper's failure case, a base declaring 0.1 m/s is sent no farther than it
/// drives in 1.5 planning periods, the other (0.8 m/s) up to the configured
/// largest step; GetState shows what each declared.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn goals_follow_each_robots_declared_speed() {
    let (coordinator, clock) = start(config(true)).await;
    let addr = coordinator.local_addr;
    let slow = BaseLimits { max_speed_m_per_s: Some(0.1), max_turn_rate_deg_per_s: Some(90.0) };
    let fast = BaseLimits { max_speed_m_per_s: Some(0.8), max_turn_rate_deg_per_s: None };
    let mut fleet = Fleet::connect_declaring(addr, &["a", "b"], &SIDE_BY_SIDE, SOURCE, &[slow, fast]).await;
    let s = state(addr).await;
    for (id, declared) in [("a", slow), ("b", fast)] {
        let r = s.robots.iter().find(|r| r.robot_id == id).expect("listed");
        assert_eq!(r.base_limits, declared.to_wire(), "{id}");
    }
    fleet.step(&clock).await;
    fleet.step(&clock).await;
    let planner = config(true).planner;
    let moved = |i: usize| {
        let c = &fleet.commands[i].first().unwrap_or_else(|| panic!("robot {i} commanded")).command;
        let g = c.goal_map_from_base.as_ref().unwrap().translation_m.as_ref().unwrap();
        (g.x - SIDE_BY_SIDE[i].x).hypot(g.y - SIDE_BY_SIDE[i].y)
    };
    let (a, b) = (moved(0), moved(1));
    let slow_step = 1.5 * 0.1 * planner.planning_period_s;
    assert!(a > 0.05 && a <= slow_step + 1e-6, "the slow robot moves {a:.3} m (step {slow_step} m)");
    assert!(b > 2.0 * slow_step && b <= planner.max_step_m + 1e-6, "the fast robot moves {b:.3} m");
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disabled_positioning_sends_nothing_and_the_operator_switches_it() {
    let (coordinator, clock) = start(config(false)).await;
    let addr = coordinator.local_addr;
    let mut fleet = Fleet::connect(addr, &["a", "b"], &SIDE_BY_SIDE, SOURCE).await;
    for _ in 0..30 {
        fleet.step(&clock).await;
    }
    assert_eq!(fleet.command_count(), 0, "disabled by default");
    let s = state(addr).await;
    assert_eq!(
        s.active_positioning,
        Some(wire::ActivePositioning { enabled: false, theta_min_deg: 40.0, theta_max_deg: 140.0 })
    );
    assert!(s.planner.is_none(), "the planner never ran");
    // Bad bands: INVALID_ARGUMENT naming the field; nothing changes.
    for (min, max, field) in [
        (Some(-1.0), None, "theta_min_deg"),
        (Some(f64::NAN), None, "theta_min_deg"),
        (None, Some(181.0), "theta_max_deg"),
        (None, Some(f64::INFINITY), "theta_max_deg"),
        (Some(150.0), None, "theta_min_deg"),
        (None, Some(30.0), "theta_max_deg"),
        (Some(80.0), Some(85.0), "theta_min_deg"),
        (Some(100.0), Some(100.0), "theta_min_deg"),
        (Some(100.0), Some(170.0), "theta_min_deg"),
        (None, Some(80.0), "theta_max_deg"),
    ] {
        let e = set(addr, Some(true), min, max).await.expect_err("a bad band");
        assert_eq!(e.code(), Code::InvalidArgument, "{min:?} {max:?}: {e:?}");
        assert!(e.message().starts_with(field), "{min:?} {max:?}: {:?} should name {field}", e.message());
    }
    assert!(!state(addr).await.active_positioning.unwrap().enabled);
    // Switched on with a band of its own: returned and shown by GetState; commands flow.
    let on = set(addr, Some(true), Some(0.0), Some(180.0)).await.unwrap();
    assert_eq!(on, wire::ActivePositioning { enabled: true, theta_min_deg: 0.0, theta_max_deg: 180.0 });
    let on = set(addr, None, Some(45.0), None).await.unwrap();
    assert_eq!(on, wire::ActivePositioning { enabled: true, theta_min_deg: 45.0, theta_max_deg: 180.0 });
    let on = set(addr, None, None, Some(135.0)).await.unwrap();
    assert_eq!(on, wire::ActivePositioning { enabled: true, theta_min_deg: 45.0, theta_max_deg: 135.0 });
    assert_eq!(state(addr).await.active_positioning, Some(on));
    fleet.step(&clock).await;
    fleet.step(&clock).await;
    assert!(fleet.commands.iter().all(|c| c.len() == 1), "{:?}", fleet.commands);
    let detail = &fleet.commands[0][0].command.detail;
    assert!(detail.contains("band 45–135°"), "the band reached the planner: {detail}");
    // b got its command first and has arrived; a is still driving. Switched
    // off now, a's command is canceled (b's is finished).
    let s = state(addr).await;
    let states: Vec<i32> = s.robots.iter().map(|r| r.active_command_state).collect();
    assert_eq!(states, [wire::CommandState::Executing as i32, wire::CommandState::Succeeded as i32]);
    let off = set(addr, Some(false), None, None).await.unwrap();
    assert!(!off.enabled);
    fleet.step(&clock).await;
    assert_eq!(fleet.cancels[0].len(), 1, "{:?}", fleet.cancels);
    assert_eq!(fleet.cancels[0][0].command_id, fleet.commands[0][0].command.command_id);
    assert!(fleet.cancels[1].is_empty(), "{:?}", fleet.cancels);
    let n = fleet.command_count();
    for _ in 0..30 {
        fleet.step(&clock).await;
    }
    assert_eq!(fleet.command_count(), n, "off again");
    coordinator.shutdown().await.unwrap();
}

/// The band reaches the planner: robots 70° apart (horizontally) at 2 m see
/// the source at θ ≈ 65°, which 40–140° accepts (the planner holds); a band of
/// 70–140° does not, and the robots are sent to the optimum (θ ≈ 83°, the 3D
/// angle of a 90° spread).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_band_reaches_the_planner() {
    let (coordinator, clock) = start(config(true)).await;
    let addr = coordinator.local_addr;
    let b = 70f64.to_radians();
    let bases = [Point3::new(2.0, 0.0, 0.0), Point3::new(2.0 * b.cos(), 2.0 * b.sin(), 0.0)];
    let mut fleet = Fleet::connect(addr, &["a", "b"], &bases, SOURCE).await;
    let theta0 = fleet.theta_deg();
    for _ in 0..20 {
        fleet.step(&clock).await;
    }
    assert_eq!(fleet.command_count(), 0, "θ {theta0:.1}° is in 40–140°");
    let p = state(addr).await.planner.unwrap();
    assert_eq!(p.outcome, wire::PlannerOutcome::Hold as i32);
    assert!(p.detail.starts_with("geometry good"), "{}", p.detail);
    set(addr, None, Some(70.0), None).await.unwrap();
    fleet.step(&clock).await;
    fleet.step(&clock).await;
    let sent: Vec<_> = fleet.commands.iter().flatten().collect();
    assert!(!sent.is_empty());
    for c in &sent {
        assert_eq!(c.command.reason, wire::RepositionReason::ThetaOutOfBand as i32, "{c:?}");
        assert!(c.command.detail.contains("band 70–140°"), "{}", c.command.detail);
    }
    let s = until_geometry_good(&mut fleet, &clock, addr, 400).await;
    println!("band 70–140°: θ {theta0:.1}° → {:.1}° ({})", fleet.theta_deg(), s.planner.unwrap().detail);
    assert!((75.0..=135.0).contains(&fleet.theta_deg()));
    coordinator.shutdown().await.unwrap();
}

/// Refused goals are not re-sent within `retry_after_s`; after it they are.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refused_goals_are_not_resent_blindly() {
    let (coordinator, clock) = start(config(true)).await;
    let addr = coordinator.local_addr;
    let mut fleet = Fleet::connect(addr, &["a", "b"], &SIDE_BY_SIDE, SOURCE).await;
    fleet.answers = vec![Answer::Refuse; 2];
    fleet.step(&clock).await;
    fleet.step(&clock).await;
    assert!(fleet.commands.iter().all(|c| c.len() == 1), "{:?}", fleet.commands);
    // 5 s: more than two planning periods, less than retry_after_s (10 s).
    for _ in 0..50 {
        fleet.step(&clock).await;
    }
    assert!(fleet.commands.iter().all(|c| c.len() == 1), "re-sent a refused goal: {:?}", fleet.commands);
    let s = state(addr).await;
    let p = s.planner.unwrap();
    assert!(p.detail.contains("not re-sent the goal it refused"), "{}", p.detail);
    for r in &s.robots {
        assert_eq!(r.active_command_state, wire::CommandState::Failed as i32);
    }
    // After retry_after_s (and the next planning cycle) the same goal may be tried again.
    for _ in 0..80 {
        fleet.step(&clock).await;
    }
    assert!(fleet.commands.iter().all(|c| c.len() == 2), "retried after 10 s: {:?}", fleet.commands);
    let [first, again] = &fleet.commands[0][..] else { unreachable!() };
    assert!(again.command.issued_ns - first.command.issued_ns >= 10_000_000_000);
    coordinator.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_robots_are_all_commanded_and_all_used() {
    let (coordinator, clock) = start(config(true)).await;
    let addr = coordinator.local_addr;
    let mut estimates = coordinator.subscribe();
    let bases: Vec<Point3<f64>> = (0..3).map(|k| Point3::new(4.6, -0.4 + 0.8 * k as f64, 0.0)).collect();
    let mut fleet = Fleet::connect(addr, &["a", "b", "c"], &bases, SOURCE).await;
    let theta0 = fleet.theta_deg();
    let s = until_geometry_good(&mut fleet, &clock, addr, 400).await;
    println!(
        "three robots: best θ {theta0:.1}° → {:.1}° after {:.1} s, commands per robot {:?}; planner: {}",
        fleet.theta_deg(),
        fleet.step as f64 * fleet.dt_s,
        fleet.commands.iter().map(Vec::len).collect::<Vec<_>>(),
        s.planner.unwrap().detail
    );
    assert!(fleet.commands.iter().all(|c| !c.is_empty()), "every robot was commanded: {:?}", fleet.commands);
    // Estimates use all three robots.
    fleet.step(&clock).await;
    let t = time_of(fleet.step - 1, fleet.dt_s);
    let mut e = next_estimate(&mut estimates).await;
    while e.stamp_ns < t.as_ns() || e.robots.len() < 3 {
        e = next_estimate(&mut estimates).await;
    }
    assert_eq!(e.robots, ["a", "b", "c"]);
    let tri = e.triangulation.as_ref().unwrap();
    assert_eq!(tri.method, wire::EstimateMethod::LevenbergMarquardt as i32);
    assert_eq!(tri.pairwise_theta.len(), 3);
    assert!(e.trusted && (position(&e) - SOURCE).norm() < 0.05, "{e:?}");
    coordinator.shutdown().await.unwrap();
}

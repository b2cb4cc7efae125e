use std::sync::{Arc, Mutex};

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use soundmap_proto::{CommandState, RepositionReason};

use super::*;
use crate::navigator::JsonLinesNavigator;

const S: i64 = 1_000_000_000;

fn hello() -> Hello {
    let array = ArrayGeometry::load("respeaker-4").unwrap();
    super::hello(RobotId::parse("r1", "robot_id").unwrap(), &array, "test".into())
}

fn core() -> Agent {
    Agent::new(hello(), CoreConfig::default(), "poses").unwrap()
}

fn t(ms: i64) -> Stamp {
    Stamp::from_ns(100 * S + ms * 1_000_000)
}

fn pose(ms: i64, x: f64) -> StampedPose {
    StampedPose { stamp: t(ms), map_from_base: Isometry3::translation(x, 0.0, 0.0), covariance: None }
}

fn doa(sigma: Option<f64>) -> TrackedDoa {
    TrackedDoa {
        track_id: 1,
        direction_in_array: Unit::new_normalize(Vector3::new(1.0, 1.0, 0.0)),
        activity: 1.0,
        angular_sigma_rad: sigma,
        signature: None,
        coherence: None,
        floor_fit_range_m: None,
    }
}

fn drain(core: &mut Agent) -> Vec<Observation> {
    std::iter::from_fn(|| core.poll_observation()).collect()
}

#[test]
fn hops_wait_for_their_pose_then_carry_it_interpolated() {
    let mut c = core();
    c.handle_pose(t(0), pose(0, 0.0)).unwrap();
    c.handle_hop(t(10), t(40), vec![doa(Some(0.01))]);
    assert!(c.poll_observation().is_none(), "waits for a pose after its stamp");
    assert_eq!(c.poll_timeout(), Some(t(540)));
    c.handle_pose(t(60), pose(100, 1.0)).unwrap();
    let obs = drain(&mut c);
    assert_eq!(obs.len(), 1);
    assert_eq!((obs[0].sequence, obs[0].stamp), (1, t(40)));
    assert!((obs[0].map_from_base.translation.x - 0.4).abs() < 1e-12);
    // σ floor (1°) in quadrature.
    let s = obs[0].doas[0].angular_sigma_rad.unwrap();
    assert!((s - 0.01f64.hypot(1f64.to_radians())).abs() < 1e-15);
}

#[test]
fn hops_without_a_pose_are_dropped_and_reported() {
    let mut c = core();
    c.handle_pose(t(0), pose(0, 0.0)).unwrap();
    c.handle_pose(t(0), pose(2000, 0.0)).unwrap(); // a 2 s gap
    c.handle_hop(t(2000), t(1000), vec![doa(None)]);
    assert!(c.poll_observation().is_none());
    assert!(matches!(
        c.poll_event(),
        Some(AgentEvent::HopWithoutPose { reason: PoseLookupError::Gap { .. }, .. })
    ));
    // A hop after the last pose waits, then gives up at its deadline.
    c.handle_hop(t(2100), t(2100), vec![doa(None)]);
    c.handle_timeout(t(2500));
    assert_eq!(c.waiting_hops(), 1);
    c.handle_timeout(t(2700));
    assert_eq!(c.waiting_hops(), 0);
    assert_eq!(c.stats().hops_without_pose, 2);
    // A DoA without σ (ODAS) keeps none.
    c.handle_pose(t(2700), pose(2200, 0.0)).unwrap();
    c.handle_hop(t(2800), t(2150), vec![doa(None)]);
    assert_eq!(drain(&mut c)[0].doas[0].angular_sigma_rad, None);
}

/// The first hop is sent even when silent (the coordinator learns where the
/// robot is), then tracks, then one empty observation when they end; the
/// rest of the silence sends one every 0.5 s (not within these 40 ms).
#[test]
fn silent_hops_send_one_empty_observation() {
    let mut c = core();
    c.handle_pose(t(0), pose(0, 0.0)).unwrap();
    c.handle_pose(t(0), pose(400, 0.0)).unwrap();
    for (k, d) in [vec![], vec![doa(None)], vec![], vec![], vec![]].into_iter().enumerate() {
        c.handle_hop(t(400), t(10 * k as i64), d);
    }
    let obs = drain(&mut c);
    assert_eq!(obs.iter().map(|o| o.doas.len()).collect::<Vec<_>>(), vec![0, 1, 0]);
    assert_eq!(obs.iter().map(|o| o.sequence).collect::<Vec<_>>(), vec![1, 2, 3]);
    assert_eq!(c.stats().silent_hops, 2);
}

#[test]
fn a_new_stream_resends_what_was_not_acknowledged() {
    let mut c = core();
    c.handle_pose(t(0), pose(0, 0.0)).unwrap();
    c.handle_pose(t(0), pose(400, 0.0)).unwrap();
    for k in 0..3 {
        c.handle_hop(t(400), t(10 * k), vec![doa(None)]);
    }
    assert_eq!(drain(&mut c).len(), 3);
    c.handle_coordinator(t(400), FromCoordinator::Ack { up_to_sequence: 1 });
    c.handle_coordinator(t(400), FromCoordinator::Connected);
    assert_eq!(drain(&mut c).iter().map(|o| o.sequence).collect::<Vec<_>>(), vec![2, 3]);
    let s = c.stats();
    assert_eq!((s.acknowledged, s.resent, s.pending), (1, 2, 2));
}

fn command(id: u64, x: f64) -> RepositionCommand {
    RepositionCommand {
        command_id: id,
        goal_map_from_base: Isometry3::translation(x, 0.0, 0.0),
        look_at_in_map: Point3::new(5.0, 5.0, 1.0),
        reason: RepositionReason::ThetaOutOfBand,
        detail: "θ 12°".into(),
        deadline: t(60_000),
        issued: t(0),
    }
}

#[derive(Clone, Default)]
struct Sink(Arc<Mutex<Vec<u8>>>);
impl std::io::Write for Sink {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

fn replies(c: &mut Agent) -> Vec<Reply> {
    std::iter::from_fn(|| c.poll_reply()).collect()
}

/// While the source is silent only one empty observation per 0.5 s is sent,
/// yet the navigator must still see the robot arrive: every pose reaches it,
/// not only those attached to sent observations.
#[test]
fn the_navigator_sees_the_robot_arrive_while_nothing_is_heard() {
    let mut c = core();
    let mut nav = JsonLinesNavigator::new("goals", Box::new(Sink::default()), 0.2);
    c.handle_pose(t(0), pose(0, 0.0)).unwrap();
    c.handle_coordinator(t(0), FromCoordinator::Event(CoordinatorEvent::Reposition(command(7, 2.0))));
    c.exchange_with(&mut nav, t(0));
    let r = replies(&mut c);
    assert!(matches!(&r[0], Reply::Ack(a) if a.accepted && a.command_id == 7), "{r:?}");
    assert!(matches!(&r[1], Reply::Progress(p) if p.state == CommandState::Executing));
    // The robot drives; every hop is silent.
    for k in 1..=20 {
        c.handle_pose(t(100 * k), pose(100 * k, 0.1 * k as f64)).unwrap();
        c.handle_hop(t(100 * k), t(100 * k - 50), vec![]);
        c.exchange_with(&mut nav, t(100 * k));
    }
    let sent = drain(&mut c);
    assert!(sent.iter().all(|o| o.doas.is_empty()), "nothing heard, nothing but silence sent");
    assert_eq!(sent.len(), 4, "2 s of silence: one empty observation per 0.5 s");
    let r = replies(&mut c);
    assert!(
        r.iter().any(
            |r| matches!(r, Reply::Progress(p) if p.command_id == 7 && p.state == CommandState::Succeeded)
        ),
        "{r:?}"
    );
    assert_eq!(c.active_command(), None);
}

#[test]
fn commands_refused_cancelled_and_invalid() {
    let mut c = core();
    let mut nav = JsonLinesNavigator::new("goals", Box::new(Sink::default()), 0.2);
    let mut late = command(1, 1.0);
    late.deadline = t(5);
    c.handle_coordinator(t(10), FromCoordinator::Event(CoordinatorEvent::Reposition(late)));
    c.handle_coordinator(t(10), FromCoordinator::Event(CoordinatorEvent::Reposition(command(2, 1.0))));
    c.exchange_with(&mut nav, t(10));
    c.handle_coordinator(
        t(20),
        FromCoordinator::Event(CoordinatorEvent::Cancel { command_id: 1, reason: "x".into() }),
    );
    c.handle_coordinator(
        t(20),
        FromCoordinator::Event(CoordinatorEvent::Cancel { command_id: 2, reason: "source lost".into() }),
    );
    c.exchange_with(&mut nav, t(20));
    let r = replies(&mut c);
    let summary: Vec<(u64, String)> = r
        .iter()
        .map(|r| match r {
            Reply::Ack(a) => (a.command_id, format!("ack {}", a.accepted)),
            Reply::Progress(p) => (p.command_id, format!("{:?}", p.state)),
        })
        .collect();
    assert_eq!(
        summary,
        vec![
            (1, "ack false".into()),
            (2, "ack true".into()),
            (2, "Executing".into()),
            (2, "Canceled".into())
        ]
    );
    let events: Vec<AgentEvent> = std::iter::from_fn(|| c.poll_event()).collect();
    assert!(events.iter().any(|e| matches!(e, AgentEvent::CommandRefused { command_id: 1, .. })));
    assert!(events.iter().any(|e| matches!(e, AgentEvent::Ignored(w) if w.contains("cancel of command 1"))));
    assert_eq!(c.stats().commands, 2);
}

#[test]
fn out_of_order_poses_are_errors_and_the_core_goes_on() {
    let mut c = core();
    c.handle_pose(t(0), pose(100, 0.0)).unwrap();
    let e = c.handle_pose(t(0), pose(50, 0.0)).unwrap_err();
    assert!(e.to_string().contains("poses") && e.to_string().contains("does not increase"), "{e}");
    c.handle_pose(t(0), pose(200, 0.0)).unwrap();
    c.handle_hop(t(200), t(150), vec![doa(None)]);
    assert_eq!(drain(&mut c).len(), 1);
}

#[test]
fn the_hello_names_presets_only() {
    let h = hello();
    assert_eq!(h.array.preset.as_deref(), Some("respeaker-4"));
    assert_eq!(h.array.microphone_count, 4);
}

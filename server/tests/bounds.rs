//! The registry's bounds on the pure coordinator: a flood of equal stamps
//! keeps a robot's history at `server.max_history_per_robot`, throw-away robot
//! ids are forgotten beyond `server.max_robots` and after
//! `server.robot_retention_s`, and a full registry of connected robots refuses
//! a new one with RESOURCE_EXHAUSTED.

use soundmap_proto::{Hello, Observation, RobotId, Stamp, wire};
use soundmap_server::coordinator::Coordinator;
use soundmap_server::loadgen::{RobotSpec, array, observation};
use soundmap_server::{CoordinatorConfig, ServerError};

const T0: Stamp = Stamp::from_ns(1_767_225_600_000_000_000);

fn hello(id: &str) -> Hello {
    Hello {
        robot_id: RobotId::parse(id, "id").unwrap(),
        array: array(),
        software_version: "test".into(),
        signature_bands: None,
        max_tracks: None,
        base_limits: Default::default(),
    }
}

fn obs(c: &Coordinator, spec: &RobotSpec, seq: u64, stamp: Stamp) -> Observation {
    let wire::RobotMessage { msg: Some(wire::robot_message::Msg::Observation(o)) } =
        observation(spec, seq, stamp)
    else {
        unreachable!()
    };
    Observation::from_wire(&o, &c.limits(stamp)).unwrap()
}

#[test]
fn equal_stamps_do_not_grow_a_robots_history() {
    let mut c = Coordinator::new(CoordinatorConfig::default()).unwrap();
    let spec = RobotSpec::on_ring("flood", 0, 1, 3.0);
    let conn = c.connect(T0, hello(&spec.id), None).unwrap().conn;
    for seq in 1..=20_000 {
        c.observe(T0, conn, obs(&c, &spec, seq, T0)).unwrap();
    }
    let (_, e) = c.robots().next().unwrap();
    assert_eq!(e.history.len(), CoordinatorConfig::default().server.max_history_per_robot);
    assert_eq!(c.counters().history_trimmed, 20_000 - 512);
}

#[test]
fn throw_away_ids_are_forgotten_and_a_full_registry_refuses() {
    let mut config = CoordinatorConfig::default();
    config.server.max_robots = 100;
    config.server.robot_retention_s = 60.0;
    let mut c = Coordinator::new(config).unwrap();
    for i in 0..5_000 {
        let w = c.connect(T0.plus_secs(i as f64 * 1e-3), hello(&format!("throwaway-{i}")), None).unwrap();
        c.disconnect(T0, w.conn);
    }
    assert_eq!(c.robots().count(), 100);
    assert_eq!(c.counters().robots_forgotten, 4_900);
    // Tracker indices stay below the registry's size.
    assert!(c.robots().all(|(_, e)| e.index < 100));
    // Retention: all gone a minute later.
    c.tick(T0.plus_secs(70.0));
    assert_eq!(c.robots().count(), 0);
    // Connected robots are never replaced: the 101st is refused.
    for i in 0..100 {
        c.connect(T0.plus_secs(71.0), hello(&format!("live-{i}")), None).unwrap();
    }
    let e = c.connect(T0.plus_secs(71.0), hello("one-too-many"), None).unwrap_err();
    assert!(matches!(e, ServerError::Exhausted(_)), "{e}");
}

//! Property-based fuzzing of what reaches the coordinator from outside:
//! arbitrary bytes decoded as every inbound wire message and validated
//! (never a panic, whatever the bytes), mutations of valid messages, and
//! the configuration parser on arbitrary text, on the shipped example with
//! one line replaced, and on every numeric key with arbitrary values (a
//! value accepted at load must also start a coordinator).

use crate::common;

use std::path::Path;

use common::{T0, hello, observation_of};
use nalgebra::Point3;
use proptest::prelude::*;
use prost::Message;
use soundmap_proto::monitoring::PositioningUpdate;
use soundmap_proto::wire::{self, robot_message::Msg as Up};
use soundmap_proto::{Hello, Limits, RepositionCommand, RobotInput};
use soundmap_server::CoordinatorConfig;
use soundmap_server::coordinator::Coordinator;

const EXAMPLE: &str = include_str!("../../deploy/coordinator.example.toml");

fn limits() -> Limits {
    Limits { max_past_ns: 300_000_000_000, ..Limits::at(T0) }
}

/// Decodes and validates `bytes` as each inbound message type.
fn decode_and_validate(bytes: &[u8]) {
    if let Ok(m) = wire::RobotMessage::decode(bytes) {
        let checked = RobotInput::from_wire(&m, &limits());
        if let (Ok(RobotInput::Observation(obs)), Some(Up::Hello(h))) = (checked, hello("r1").msg) {
            let hello = Hello::from_wire(&h, &limits()).unwrap();
            let _ = obs.check_against(&hello);
        }
    }
    if let Ok(m) = wire::CoordinatorMessage::decode(bytes)
        && let Some(wire::coordinator_message::Msg::Reposition(c)) = &m.msg
    {
        let _ = RepositionCommand::from_wire(c, &limits());
    }
    if let Ok(r) = wire::SetActivePositioningRequest::decode(bytes) {
        let mut coordinator = Coordinator::new(CoordinatorConfig::default()).unwrap();
        let _ = coordinator.set_active_positioning(T0, &PositioningUpdate::from_wire(&r));
    }
    let _ = wire::SetFocusRequest::decode(bytes);
    let _ = wire::GetStateRequest::decode(bytes);
}

fn valid_messages() -> Vec<Vec<u8>> {
    let obs = observation_of(T0, Point3::origin(), 0.3, &Point3::new(2.0, 1.0, 1.0), None, 0.05);
    vec![
        hello("r1").encode_to_vec(),
        wire::RobotMessage { msg: Some(Up::Observation(obs)) }.encode_to_vec(),
        wire::SetActivePositioningRequest {
            enabled: Some(true),
            theta_min_deg: Some(30.0),
            theta_max_deg: None,
        }
        .encode_to_vec(),
    ]
}

/// Every numeric key of the configuration, as `section.key`.
const NUMERIC_KEYS: &[&str] = &[
    "liveness.stale_after_ms",
    "liveness.tick_ms",
    "alignment.window_ms",
    "alignment.history_ms",
    "doa.default_sigma_deg",
    "doa.min_activity",
    "limits.max_future_ms",
    "limits.max_past_ms",
    "limits.unit_vector_tolerance",
    "limits.quaternion_tolerance",
    "triangulation.min_range_m",
    "triangulation.max_rms_m",
    "triangulation.max_range_m",
    "triangulation.min_sigma_rad",
    "sources.max_sources",
    "sources.birth_rounds",
    "sources.memory_s",
    "active_positioning.theta_min_deg",
    "active_positioning.command_deadline_s",
    "active_positioning.evaluate_period_ms",
    "active_positioning.retry_after_s",
];

fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<u64>().prop_map(|v| v.to_string()),
        any::<i64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_filter("TOML floats", |v| v.is_finite()).prop_map(|v| format!("{v:?}")),
        Just("18446744073709551615".to_string()),
        Just("9223372036854775807".to_string()),
        Just("1e300".to_string()),
        Just("-0.0".to_string()),
        Just("nan".to_string()),
        Just("inf".to_string()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        decode_and_validate(&bytes);
    }

    #[test]
    fn mutated_valid_messages_never_panic(
        which in 0usize..3,
        flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
    ) {
        let mut bytes = valid_messages().swap_remove(which);
        for (at, v) in flips {
            let i = at % bytes.len();
            bytes[i] = v;
        }
        decode_and_validate(&bytes);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn config_parser_never_panics(text in "\\PC{0,400}", line in any::<usize>(), junk in "\\PC{0,60}") {
        let _ = CoordinatorConfig::from_toml(&text, Path::new("fuzz.toml"));
        let mut lines: Vec<&str> = EXAMPLE.lines().collect();
        let i = line % lines.len();
        lines[i] = &junk;
        let _ = CoordinatorConfig::from_toml(&lines.join("\n"), Path::new("fuzz.toml"));
    }

    /// A numeric value is refused naming its key, or accepted and then starts a coordinator.
    #[test]
    fn numeric_values_are_refused_by_key_or_usable(key in 0usize..NUMERIC_KEYS.len(), value in number()) {
        let (section, name) = NUMERIC_KEYS[key].split_once('.').unwrap();
        let text = format!("[{section}]\n{name} = {value}\n");
        match CoordinatorConfig::from_toml(&text, Path::new("fuzz.toml")) {
            Ok(config) => prop_assert!(Coordinator::new(config).is_ok(), "{}", text),
            Err(e) => {
                let e = e.to_string();
                prop_assert!(e.starts_with("fuzz.toml: "), "{}", e);
            }
        }
    }
}

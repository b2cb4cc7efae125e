//! `agent.toml` parsing and validation.

use std::path::{Path, PathBuf};

use super::*;

fn example_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/agent.example.toml")
}

fn example() -> String {
    std::fs::read_to_string(example_path()).unwrap()
}

#[test]
fn the_example_config_parses() {
    let c = AgentConfig::load(&example_path()).unwrap();
    assert_eq!(c.robot_id.as_str(), "pioneer-1");
    assert_eq!(c.coordinator.endpoint, "http://127.0.0.1:50051");
    assert_eq!(c.array, "16soundsusb-pioneer");
    let DoaSource::Own { audio, pipeline } = &c.doa else { panic!("{:?}", c.doa) };
    let dir = example_path().parent().unwrap().to_path_buf();
    assert_eq!(audio.input, AudioInput::Wav { path: dir.join("recordings/pioneer-1.wav") });
    assert!(audio.realtime);
    assert_eq!(pipeline.hop_len, 128);
    assert_eq!(
        c.pose.source,
        PoseSource::Tum { path: dir.join("recordings/pioneer-1.tum"), start_s: Some(0.0) }
    );
    assert_eq!(c.navigator.path, dir.join("goals.jsonl"));
    assert_eq!(
        c.navigator.base_limits,
        soundmap_proto::BaseLimits { max_speed_m_per_s: Some(0.8), max_turn_rate_deg_per_s: Some(120.0) }
    );
    assert_eq!(c.link.buffer_capacity, 1024);
    assert_eq!(c.link.endpoint, c.coordinator.endpoint);
}

/// The example with `from` replaced by `to` must fail on `field` with a message containing `what`.
fn fails(from: &str, to: &str, field: &str, what: &str) {
    fails_with(&[(from, to)], field, what)
}

/// [`fails`] with several replacements.
fn fails_with(edits: &[(&str, &str)], field: &str, what: &str) {
    let mut text = example();
    for (from, to) in edits {
        assert!(text.contains(from), "example has no {from:?}");
        text = text.replacen(from, to, 1);
    }
    let (from, to) = edits[0];
    match AgentConfig::parse(&text, Path::new("conf/agent.toml")) {
        Err(AgentError::Config { path, field: f, message }) => {
            assert_eq!(path, Path::new("conf/agent.toml"));
            assert_eq!(f, field, "{from:?} → {to:?}: {message}");
            assert!(message.contains(what), "{from:?} → {to:?}: {message}");
            let shown = AgentError::Config { path, field: f, message }.to_string();
            assert!(shown.starts_with(&format!("conf/agent.toml: {field}: ")), "{shown}");
        }
        other => panic!("{from:?} → {to:?}: expected a config error, got {other:?}"),
    }
}

#[test]
fn parse_errors_name_the_field() {
    fails("robot_id = \"pioneer-1\"", "robot_id = \"pioneer 1\"", "robot_id", "invalid character");
    fails("pace = \"realtime\"", "pace = \"realtime\"\nchanels = 4", "audio.chanels", "unknown field");
    fails("source = \"wav\"", "source = \"mp3\"", "audio.source", "unknown variant");
    fails("hop_len = 128\nwindow", "hop_len = \"x\"\nwindow", "pipeline.hop_len", "invalid type");
    fails("buffer_capacity = 1024", "buffer_capacity = -1", "link.buffer_capacity", "");
    fails("[navigator]", "[navigatr]", "navigatr", "unknown field");
}

#[test]
fn validation_errors_name_the_field() {
    let wav = "source = \"wav\"\npath = \"recordings/pioneer-1.wav\"";
    fails(
        wav,
        "source = \"raw\"\npath = \"x.raw\"\nformat = \"s16le\"\nsample_rate_hz = 16000",
        "audio.channels",
        "required when audio.source = \"raw\"",
    );
    fails(
        wav,
        "source = \"raw\"\npath = \"x.raw\"\nformat = \"s16le\"\nchannels = 16\nsample_rate_hz = 48000",
        "audio.sample_rate_hz",
        "does not match pipeline.sample_rate_hz = 16000",
    );
    fails(wav, "source = \"wav\"\npath = \"a.wav\"\nchannels = 16", "audio.channels", "not used for WAV");
    fails_with(
        &[
            (wav, "source = \"stdin\"\nformat = \"s16le\"\nchannels = 16\nsample_rate_hz = 16000"),
            ("pace = \"realtime\"", "pace = \"asap\""),
        ],
        "audio.pace",
        "only files",
    );
    fails(
        wav,
        "source = \"live\"\nformat = \"s16le\"\nchannels = 16\nsample_rate_hz = 16000",
        "audio.device",
        "required",
    );
    fails(wav, "source = \"wav\"\npath = \"a.wav\"\nchannel_map = []", "audio.channel_map", "empty");
    fails(wav, "source = \"wav\"\npath = \"a.wav\"\nstart_ns = -5", "audio.start_ns", "negative");
    fails(
        "endpoint = \"http://127.0.0.1:50051\"",
        "endpoint = \"127.0.0.1:50051\"",
        "coordinator.endpoint",
        "not a URL",
    );
    fails("# token = \"…\"", "token = \"a\"\ntoken_file = \"t\"", "coordinator.token_file", "not both");
    fails("# token = \"…\"", "token_file = \"missing.token\"", "coordinator.token_file", "missing.token");
    fails("preset = \"16soundsusb-pioneer\"", "", "array", "give `preset");
    fails("path = \"recordings/pioneer-1.tum\"", "", "pose.path", "required when pose.source = \"tum\"");
    fails("source = \"tum\"", "source = \"jsonl_tcp\"", "pose.path", "not used");
    fails("max_gap_s = 0.5", "max_gap_s = 0", "pose.max_gap_s", "positive");
    fails("capacity = 10000", "capacity = 1", "pose.capacity", "at least 2");
    fails(
        "arrival_tolerance_m = 0.25",
        "arrival_tolerance_m = 0",
        "navigator.arrival_tolerance_m",
        "positive",
    );
    fails("max_speed_m_per_s = 0.8", "max_speed_m_per_s = 0", "navigator.max_speed_m_per_s", "(0, 10]");
    fails("max_speed_m_per_s = 0.8", "max_speed_m_per_s = nan", "navigator.max_speed_m_per_s", "(0, 10]");
    fails(
        "max_turn_rate_deg_per_s = 120.0",
        "max_turn_rate_deg_per_s = 5000.0",
        "navigator.max_turn_rate_deg_per_s",
        "(0, 3600]",
    );
    fails("backoff_initial_ms = 200", "backoff_initial_ms = 20000", "link.backoff_initial_ms", "more than");
    fails(
        "heartbeat_interval_ms = 1000",
        "heartbeat_interval_ms = 0",
        "link.heartbeat_interval_ms",
        "at least",
    );
    fails(
        "source = \"own\"",
        "source = \"odas\"\nlisten = \"127.0.0.1:9000\"",
        "audio",
        "not used when doa.source = \"odas\"",
    );
}

#[test]
fn odas_and_live_pose_sources() {
    let text = example();
    let start = text.find("\n[audio]\n").unwrap();
    let end = text.find("\n[pose]\n").unwrap();
    let text = format!("{}{}", &text[..start], &text[end..])
        .replacen("source = \"own\"", "source = \"odas\"\nlisten = \"127.0.0.1:9000\"\nhop_len = 256", 1)
        .replacen(
            "source = \"tum\"\npath = \"recordings/pioneer-1.tum\"\n",
            "source = \"jsonl_tcp\"\nlisten = \"127.0.0.1:7001\"\n",
            1,
        )
        .replacen("start_s = 0.0\n", "", 1);
    let c = AgentConfig::parse(&text, Path::new("agent.toml")).unwrap();
    let DoaSource::Odas(o) = &c.doa else { panic!() };
    assert_eq!(o.input, OdasInput::Listen("127.0.0.1:9000".parse().unwrap()));
    assert_eq!((o.hop_len, o.sample_rate_hz, o.start), (256, 16_000, None));
    assert_eq!(c.pose.source, PoseSource::JsonlTcp("127.0.0.1:7001".parse().unwrap()));
}

/// The example with `from` replaced by `to`, as its error message when parsed as `agent.toml`.
fn shown_error(from: &str, to: &str) -> String {
    let text = example();
    assert!(text.contains(from), "example has no {from:?}");
    match AgentConfig::parse(&text.replacen(from, to, 1), Path::new("agent.toml")) {
        Err(e @ AgentError::Config { .. }) => e.to_string(),
        other => panic!("{from:?} → {to:?}: expected a config error, got {other:?}"),
    }
}

#[test]
fn missing_keys_are_named_by_their_dotted_path() {
    // Not the file's first (comment) line: the key itself.
    assert_eq!(shown_error("robot_id = \"pioneer-1\"", ""), "agent.toml: robot_id: missing");
    assert_eq!(
        shown_error("endpoint = \"http://127.0.0.1:50051\"", ""),
        "agent.toml: coordinator.endpoint: missing"
    );
    assert_eq!(shown_error("source = \"tum\"", ""), "agent.toml: pose.source: missing");
    fails("[coordinator]", "[coordinatr]", "coordinatr", "unknown field");
}

#[test]
fn type_and_unknown_key_errors_name_the_dotted_path() {
    let e = shown_error("buffer_capacity = 1024", "buffer_capacity = 1024\nendpoint = \"http://x:1\"");
    assert!(e.starts_with("agent.toml: link.endpoint: unknown field `endpoint`"), "{e}");
    let e = shown_error("robot_id = \"pioneer-1\"", "robot_id = 7");
    assert!(e.starts_with("agent.toml: robot_id: invalid type: integer `7`"), "{e}");
    let e = shown_error("\nnear_field = false\n", "\nnear_field = false\ncoarse_level = \"two\"\n");
    assert!(e.starts_with("agent.toml: pipeline.srp.coarse_level: invalid type"), "{e}");
    // A syntax error still names the key on its line.
    let e = shown_error("hop_len = 128\nwindow", "hop_len = 12 8\nwindow");
    assert!(e.starts_with("agent.toml: pipeline.hop_len: "), "{e}");
    // One that is on no key names the document.
    let e = AgentConfig::parse("\n= 3\n", Path::new("agent.toml")).unwrap_err().to_string();
    assert!(e.starts_with("agent.toml: (document): "), "{e}");
}

#[test]
fn pipeline_files_name_their_keys() {
    let dir = tempfile::Builder::new().prefix("soundmap-agent-pipeline-").tempdir().unwrap();
    let file = dir.path().join("pipeline.toml");
    std::fs::write(&file, "hop_len = 128\n[srp]\nspeed_of_sound_m_per_s = \"fast\"\n").unwrap();
    let e = load_pipeline(&file).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{}: srp.speed_of_sound_m_per_s: invalid type", file.display())), "{e}");
    // The old spelling of the unit is still accepted.
    std::fs::write(&file, "[srp]\nspeed_of_sound_m_s = 340.0\n").unwrap();
    assert_eq!(load_pipeline(&file).unwrap().srp.speed_of_sound_m_per_s, 340.0);
}

/// The example with ODAS instead of `[audio]`: `doa` lines after `source = "odas"`, the pose file kept.
fn odas_example(doa: &str) -> Result<AgentConfig, AgentError> {
    let text = example();
    let start = text.find("\n[audio]\n").unwrap();
    let end = text.find("\n[pose]\n").unwrap();
    let text = format!("{}{}", &text[..start], &text[end..]).replacen(
        "source = \"own\"",
        &format!("source = \"odas\"\n{doa}"),
        1,
    );
    AgentConfig::parse(&text, Path::new("agent.toml"))
}

#[test]
fn odas_files_pace_and_follow() {
    let c = odas_example("file = \"tracks.json\"\npace = \"asap\"").unwrap();
    let DoaSource::Odas(o) = &c.doa else { panic!() };
    assert!(matches!(&o.input, OdasInput::File { follow: false, .. }) && !o.realtime);
    let c = odas_example("file = \"tracks.json\"").unwrap();
    let DoaSource::Odas(o) = &c.doa else { panic!() };
    assert!(o.realtime, "realtime by default");
    let c = odas_example("file = \"tracks.json\"\nfollow = true\nstart_ns = 1700000000000000000").unwrap();
    let DoaSource::Odas(o) = &c.doa else { panic!() };
    assert!(matches!(&o.input, OdasInput::File { follow: true, .. }));

    let err = |doa: &str| odas_example(doa).unwrap_err().to_string();
    let e = err("listen = \"127.0.0.1:9000\"\npace = \"asap\"");
    assert!(e.starts_with("agent.toml: doa.pace: only for doa.file"), "{e}");
    let e = err("file = \"t.json\"\nfollow = true\npace = \"asap\"\nstart_ns = 1");
    assert!(e.starts_with("agent.toml: doa.pace: a followed file"), "{e}");
    // The clock rule: a live ODAS with poses from a TUM file placed by start_s
    // needs ODAS's start.
    for live in ["listen = \"127.0.0.1:9000\"", "file = \"t.json\"\nfollow = true"] {
        let e = err(live);
        assert!(e.starts_with("agent.toml: doa.start_ns: required when poses come from a TUM file"), "{e}");
    }
    // Not for our own DoAs.
    let e = shown_error("source = \"own\"", "source = \"own\"\nfollow = true");
    assert!(e.starts_with("agent.toml: doa.follow: only for doa.source = \"odas\""), "{e}");
}

#[test]
fn odas_out_needs_a_sink_and_sane_slots() {
    let with = |extra: &str| {
        AgentConfig::parse(&format!("{}\n[odas_out]\n{extra}\n", example()), Path::new("agent.toml"))
    };
    let c = with("connect = \"127.0.0.1:9000\"\nfile = \"sst.json\"").unwrap();
    let o = c.odas_out.unwrap();
    assert_eq!((o.connect, o.slots), (Some("127.0.0.1:9000".parse().unwrap()), 4));
    assert!(o.file.unwrap().ends_with("sst.json"));
    let e = with("").unwrap_err().to_string();
    assert!(e.starts_with("agent.toml: odas_out: give"), "{e}");
    let e = with("file = \"a.json\"\nslots = 0").unwrap_err().to_string();
    assert!(e.starts_with("agent.toml: odas_out.slots: 0: must be 1 to 64"), "{e}");
    let e = with("connect = \"odas-web\"").unwrap_err().to_string();
    assert!(e.starts_with("agent.toml: odas_out.connect"), "{e}");
    assert_eq!(AgentConfig::parse(&example(), Path::new("agent.toml")).unwrap().odas_out, None);
}

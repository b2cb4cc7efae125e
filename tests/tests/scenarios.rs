//! Scenario files: the built-ins parse, and bad files name the file and key.

use soundmap_sim::SimError;
use soundmap_sim::scenario::{Scenario, builtin};

#[test]
fn builtin_scenarios_parse() {
    for name in builtin::NAMES {
        let s = Scenario::load(name).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.name, name);
    }
}

fn error_of(text: &str) -> String {
    match Scenario::from_toml(text, "trial.toml") {
        Err(e @ SimError::Scenario { .. }) => e.to_string(),
        other => panic!("expected a scenario error, got {other:?}"),
    }
}

#[test]
fn bad_scenarios_name_the_file_and_key() {
    let good = builtin::text("smoke").unwrap();
    let cases = [
        (good.replace("duration_s = 4.0", "duration_s = -4.0"), "trial.toml: duration_s:"),
        (good.replace("rt60_s = 0.3", "rt60_s = \"long\""), "trial.toml: room.rt60_s:"),
        (good.replace("seed = 3", "seed = 3\ncolour = \"red\""), "colour"),
        (
            good.replace("array = \"16soundsusb-turtlebot\"", "array = \"no-such-array\""),
            "trial.toml: robots[1].array:",
        ),
        (
            good.replace("start = [0.0, -2.0, 90.0]", "start = [40.0, -2.0, 90.0]"),
            "trial.toml: robots[1].start:",
        ),
        (good.replace("id = \"turtlebot\"", "id = \"pioneer\""), "trial.toml: robots[1].id:"),
        (good.replace("z_m = 1.2", "z_m = 9.0"), "trial.toml: sources[0].path[0]:"),
        (good.replace("kind = \"white_noise\"", "kind = \"speech\""), "trial.toml: sources[0].signal"),
        (good.replace("[noise]", "[noise\n"), "trial.toml: (document):"),
        (
            good.replace(
                "kind = \"white_noise\"",
                "kind = \"talker\", low_hz = 300.0, high_hz = 3000.0, syllable_hz = 50.0",
            ),
            "trial.toml: sources[0].signal.syllable_hz:",
        ),
        (
            good.replace("kind = \"white_noise\"", "kind = \"talker\", low_hz = 3000.0, high_hz = 300.0"),
            "trial.toml: sources[0].signal.band_hz:",
        ),
        (
            good.replace("kind = \"white_noise\"", "kind = \"fan\", hum_hz = 5000.0"),
            "sources[0].signal.hum_hz:",
        ),
        // A missing key is named itself, not its table or the document.
        (good.replace("duration_s = 4.0\n", ""), "trial.toml: duration_s: missing"),
        (good.replace("id = \"turtlebot\"\n", ""), "trial.toml: robots[1].id: missing"),
    ];
    for (text, expected) in cases {
        let e = error_of(&text);
        assert!(e.contains(expected), "{e:?} should contain {expected:?}");
    }
    let e = Scenario::load("no-such-scenario").unwrap_err().to_string();
    assert!(e.contains("no-such-scenario") && e.contains("paper-static"), "{e}");
}

/// A recording is replayed with the settings it ran with: the scenario's own
/// `[coordinator]` tables (here `[sources] max_sources`, without which a
/// replay of several sources follows one) and the room's ceiling in
/// `coordinator.toml`, and its `[agent]` tables in `pipeline.toml`, both read
/// back by the loaders `soundmap-sim replay` uses.
#[test]
fn replay_settings_carry_the_scenarios_own_tables() {
    use soundmap_sim::runner::{write_replay_config, write_replay_pipeline};
    let tmp = tempfile::Builder::new().prefix("soundmap-sim-replay-settings-").tempdir().unwrap();
    let dir = tmp.path();

    let plain = Scenario::load("smoke").unwrap();
    assert!(write_replay_pipeline(dir, &plain).unwrap().is_none(), "no [agent] table, no pipeline file");
    let config =
        soundmap_server::CoordinatorConfig::from_file(&write_replay_config(dir, &plain).unwrap()).unwrap();
    assert_eq!(config.doa.ceiling_height_m, Some(plain.room.size_m[2]));
    assert_eq!(config.sources.max_sources, 1);

    let text = format!(
        "{}\n[agent.tracker]\nshaped_measurement_noise = true\nmax_coast_s = 2.5\n",
        builtin::text("cocktail").unwrap()
    );
    let cocktail = Scenario::from_toml(&text, "cocktail.toml").unwrap();
    let config =
        soundmap_server::CoordinatorConfig::from_file(&write_replay_config(dir, &cocktail).unwrap()).unwrap();
    assert_eq!(config.sources.max_sources, cocktail.coordinator.sources.max_sources);
    assert_eq!(config.sources.max_sources, 4);
    assert_eq!(config.doa.ceiling_height_m, Some(cocktail.room.size_m[2]));
    let path = write_replay_pipeline(dir, &cocktail).unwrap().expect("a pipeline file");
    let pipeline = soundmap_agent::config::load_pipeline(&path).unwrap();
    assert!(pipeline.tracker.shaped_measurement_noise);
    assert_eq!(pipeline.tracker.max_coast_s, 2.5);
}

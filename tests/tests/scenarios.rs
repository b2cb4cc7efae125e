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

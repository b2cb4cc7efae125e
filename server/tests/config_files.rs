//! Every example coordinator config in the repository parses, and the binary
//! reports a broken config naming the file and the key.

use std::path::Path;
use std::process::Command;

use soundmap_server::CoordinatorConfig;

fn deploy_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

#[test]
fn example_configs_parse() {
    let mut n = 0;
    for entry in std::fs::read_dir(deploy_dir()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if name.starts_with("coordinator") && name.ends_with(".toml") {
            CoordinatorConfig::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
            n += 1;
        }
    }
    assert!(n >= 1, "no coordinator example config found in deploy/");
}

#[test]
fn binary_names_file_and_key_of_a_broken_config() {
    let dir = tempfile::Builder::new().prefix("soundmap-cfg-").tempdir().unwrap();
    let bad = dir.path().join("coordinator.toml");
    std::fs::write(&bad, "[alignment]\nwindow_ms = -3\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_soundmap-coordinator"))
        .arg("--config")
        .arg(&bad)
        .arg("--check")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains(&format!("{}: alignment.window_ms:", bad.display())), "{stderr}");
    let good = deploy_dir().join("coordinator.example.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_soundmap-coordinator"))
        .arg("--config")
        .arg(&good)
        .arg("--check")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let missing = Command::new(env!("CARGO_BIN_EXE_soundmap-coordinator"))
        .args(["--config", "/nonexistent/c.toml"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/nonexistent/c.toml"));
}

/// The example's `[tracking]`, `[active_positioning]` and `[planner]` sections
/// state the defaults (its room and obstacles are an example).
#[test]
fn example_sections_state_the_defaults() {
    let c = CoordinatorConfig::from_file(&deploy_dir().join("coordinator.example.toml")).unwrap();
    let d = CoordinatorConfig::default();
    assert_eq!(c.tracking, d.tracking);
    assert_eq!(c.active_positioning, d.active_positioning);
    assert_eq!(
        soundmap_server::planner::PlannerConfig { free_space: Default::default(), ..c.planner.clone() },
        d.planner
    );
    assert_eq!(c.planner.free_space.obstacles.len(), 2);
}

/// A bad `[planner]` or `[tracking]` key in a config file is reported with the
/// file and the dotted key, as every other key.
#[test]
fn bad_planner_and_tracking_keys_name_file_and_key() {
    let dir = tempfile::Builder::new().prefix("soundmap-cfg-keys-").tempdir().unwrap();
    let path = dir.path().join("coordinator.toml");
    for (text, key) in [
        ("[planner]\nmax_range_m = -2.0\n", "planner.max_range_m"),
        ("[planner]\nrobot_speed_m_per_s = 0.0\n", "planner.robot_speed_m_per_s"),
        // The former spelling still parses, and errors name the key's one spelling.
        ("[planner]\nrobot_speed_mps = 0.0\n", "planner.robot_speed_m_per_s"),
        ("[planner]\nspeed = 1.0\n", "planner.speed"),
        ("[planner.free_space]\nobstacles = [[[0.0, 0.0], [1.0, 0.0]]]\n", "planner.free_space.obstacles[0]"),
        ("[tracking]\nmaintenance_probability = 1.5\n", "tracking.maintenance_probability"),
        ("[tracking]\nlag_s = \"long\"\n", "tracking.lag_s"),
        ("[tracking]\nconfirm_min_robots = 0\n", "tracking.confirm_min_robots"),
        (
            "[active_positioning]\ntheta_min_deg = 100.0\ntheta_max_deg = 90.0\n",
            "active_positioning.theta_min_deg",
        ),
    ] {
        std::fs::write(&path, text).unwrap();
        let e = CoordinatorConfig::from_file(&path).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: {key}: ", path.display())), "{text:?} gave {e}");
    }
    // The binary says the same on --check.
    std::fs::write(&path, "[tracking]\nlag_s = -1.0\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_soundmap-coordinator"))
        .arg("--config")
        .arg(&path)
        .arg("--check")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains(&format!("{}: tracking.lag_s:", path.display())), "{stderr}");
}

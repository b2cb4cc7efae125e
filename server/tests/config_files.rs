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
    let dir = std::env::temp_dir().join(format!("soundmap-cfg-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("coordinator.toml");
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
    std::fs::remove_dir_all(&dir).unwrap();
}

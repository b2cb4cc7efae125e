//! Array files and presets: a good file loads, bad files give
//! `AgentError::Config` naming the file and the field.

use std::path::{Path, PathBuf};

use soundmap_agent::AgentError;
use soundmap_agent::array::{ArrayGeometry, presets};

/// `text` in a scratch file whose name ends in `name`, removed when dropped.
fn temp_file(name: &str, text: &str) -> tempfile::TempPath {
    let file =
        tempfile::Builder::new().prefix("soundmap-array-").suffix(&format!("-{name}")).tempfile().unwrap();
    std::fs::write(file.path(), text).unwrap();
    file.into_temp_path()
}

/// Loads `text` from a file and returns the (path, field, message) of the error.
fn config_error(name: &str, text: &str) -> (PathBuf, PathBuf, String, String) {
    let path = temp_file(name, text);
    match ArrayGeometry::load(path.to_str().unwrap()) {
        Err(AgentError::Config { path: p, field, message }) => (path.to_path_buf(), p, field, message),
        other => panic!("{name}: expected a Config error, got {other:?}"),
    }
}

const TWO_MICS: &str = "name = \"pair\"\n[[microphones]]\nposition_m = [0.05, 0.0, 0.0]\n";

#[test]
fn the_example_file_loads() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/arrays/square-4.toml");
    let g = ArrayGeometry::load(path.to_str().unwrap()).unwrap();
    assert_eq!(g.name, "square-4");
    assert_eq!(g.channels(), 4);
    assert!((g.base_from_array.translation.vector.z - 0.32).abs() < 1e-12);
    // Yawed 90° left: the array's x axis is the base's y axis.
    let x = g.base_from_array.rotation * nalgebra::Vector3::x();
    assert!((x - nalgebra::Vector3::y()).norm() < 1e-9);
    assert!((g.default_region.max_angle_rad.to_degrees() - 100.0).abs() < 1e-9);
    assert!(g.microphones[1].axis_in_array.is_some() && g.microphones[0].axis_in_array.is_none());
    g.check_channels(4, "in.wav").unwrap();
}

#[test]
fn a_planar_file_without_region_searches_its_upper_side() {
    let text = format!(
        "{TWO_MICS}[[microphones]]\nposition_m = [-0.05, 0.0, 0.0]\n[[microphones]]\nposition_m = [0.0, 0.05, 0.0]\n"
    );
    let g = ArrayGeometry::load(temp_file("planar.toml", &text).to_str().unwrap()).unwrap();
    assert!((g.default_region.max_angle_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert!((g.default_region.axis.z - 1.0).abs() < 1e-9);
}

#[test]
fn missing_field() {
    let text = format!("{TWO_MICS}[[microphones]]\ndirection = [0.0, 0.0, 1.0]\n");
    let (path, p, field, message) = config_error("missing.toml", &text);
    assert_eq!(p, path);
    assert_eq!(field, "microphones[1].position_m", "{message}");
    let (_, _, field, _) = config_error("noname.toml", "[[microphones]]\nposition_m = [0.0, 0.0, 0.0]\n");
    assert_eq!(field, "name");
}

#[test]
fn unknown_key() {
    let text = format!("{TWO_MICS}[[microphones]]\nposition_m = [-0.05, 0.0, 0.0]\ngain_db = 3.0\n");
    let (_, _, field, message) = config_error("unknown.toml", &text);
    assert_eq!(field, "microphones[1].gain_db", "{message}");
    let (_, _, field, _) = config_error("unknown-top.toml", &format!("colour = \"red\"\n{TWO_MICS}"));
    assert_eq!(field, "colour");
    let (_, _, field, _) =
        config_error("unknown-pose.toml", &format!("{TWO_MICS}[base_from_array]\nyaw_deg = 90.0\n"));
    assert_eq!(field, "base_from_array.yaw_deg");
}

#[test]
fn wrong_type_or_length() {
    let text = format!("{TWO_MICS}[[microphones]]\nposition_m = [-0.05, 0.0]\n");
    let (_, _, field, _) = config_error("short.toml", &text);
    assert_eq!(field, "microphones[1].position_m");
    let text = format!("{TWO_MICS}[[microphones]]\nposition_m = \"here\"\n");
    let (_, _, field, _) = config_error("string.toml", &text);
    assert_eq!(field, "microphones[1].position_m");
}

#[test]
fn nan_position() {
    let text = format!("{TWO_MICS}[[microphones]]\nposition_m = [nan, 0.0, 0.0]\n");
    let (_, _, field, message) = config_error("nan.toml", &text);
    assert_eq!(field, "microphones[1].position_m");
    assert!(message.contains("finite"), "{message}");
}

#[test]
fn duplicate_positions() {
    let text = format!("{TWO_MICS}[[microphones]]\nposition_m = [0.0502, 0.0, 0.0]\n");
    let (_, _, field, message) = config_error("duplicate.toml", &text);
    assert_eq!(field, "microphones[1].position_m");
    assert!(message.contains("microphones[0]") && message.contains("1 mm"), "{message}");
}

#[test]
fn one_microphone() {
    let (_, _, field, message) = config_error("one.toml", TWO_MICS);
    assert_eq!(field, "microphones");
    assert!(message.contains("at least 2"), "{message}");
}

#[test]
fn bad_region_and_pose() {
    let text = format!(
        "{TWO_MICS}[[microphones]]\nposition_m = [-0.05, 0.0, 0.0]\n[search_region]\naxis = [0.0, 0.0, 0.0]\nmax_angle_deg = 90.0\n"
    );
    let (_, _, field, _) = config_error("region.toml", &text);
    assert_eq!(field, "search_region");
    let text = format!(
        "{TWO_MICS}[[microphones]]\nposition_m = [-0.05, 0.0, 0.0]\n[base_from_array]\nrotation_xyzw = [0.0, 0.0, 0.0, 0.0]\n"
    );
    let (_, _, field, _) = config_error("pose.toml", &text);
    assert_eq!(field, "base_from_array.rotation_xyzw");
}

#[test]
fn channel_count_mismatch() {
    let g = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let Err(AgentError::Config { path, field, message }) = g.check_channels(8, "trial-3.wav") else {
        panic!("expected a Config error")
    };
    assert_eq!(path, PathBuf::from("trial-3.wav"));
    assert_eq!(field, "channels");
    assert!(message.contains('8') && message.contains("16"), "{message}");
    let shown = g.check_channels(8, "trial-3.wav").unwrap_err().to_string();
    assert!(shown.starts_with("trial-3.wav: channels:"), "{shown}");
}

#[test]
fn errors_display_file_and_field() {
    let text = format!("{TWO_MICS}[[microphones]]\nposition_m = [nan, 0.0, 0.0]\n");
    let path = temp_file("shown.toml", &text);
    let shown = ArrayGeometry::load(path.to_str().unwrap()).unwrap_err().to_string();
    assert!(shown.contains("shown.toml") && shown.contains("microphones[1].position_m"), "{shown}");
}

#[test]
fn presets_and_unknown_names() {
    for name in presets::NAMES {
        let g = ArrayGeometry::load(name).unwrap();
        assert_eq!(&g.name, name);
    }
    let Err(AgentError::Config { field, message, .. }) = ArrayGeometry::load("respeaker-5") else { panic!() };
    assert_eq!(field, "array");
    assert!(message.contains("respeaker-4"), "{message}");
    assert!(matches!(ArrayGeometry::load("/nonexistent/array.toml"), Err(AgentError::Io { .. })));
}

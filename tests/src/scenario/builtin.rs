//! Scenarios shipped with soundmap (`tests/scenarios/*.toml`).

/// Names of the built-in scenarios.
pub const NAMES: [&str; 17] = [
    "smoke",
    "paper-static",
    "paper-moving",
    "active-moving",
    "three-robots",
    "obstacles",
    "two-talkers",
    "cocktail",
    "crossing",
    "cocktail-active",
    "corner-start",
    "corner-start-3",
    "far-source",
    "fast-walker",
    "deaf-near-wall",
    "mixed-fleet",
    "low-source",
];

/// The TOML text of a built-in scenario.
pub fn text(name: &str) -> Option<&'static str> {
    Some(match name {
        "smoke" => include_str!("../../scenarios/smoke.toml"),
        "paper-static" => include_str!("../../scenarios/paper-static.toml"),
        "paper-moving" => include_str!("../../scenarios/paper-moving.toml"),
        "active-moving" => include_str!("../../scenarios/active-moving.toml"),
        "three-robots" => include_str!("../../scenarios/three-robots.toml"),
        "obstacles" => include_str!("../../scenarios/obstacles.toml"),
        "two-talkers" => include_str!("../../scenarios/two-talkers.toml"),
        "cocktail" => include_str!("../../scenarios/cocktail.toml"),
        "crossing" => include_str!("../../scenarios/crossing.toml"),
        "cocktail-active" => include_str!("../../scenarios/cocktail-active.toml"),
        "corner-start" => include_str!("../../scenarios/corner-start.toml"),
        "corner-start-3" => include_str!("../../scenarios/corner-start-3.toml"),
        "far-source" => include_str!("../../scenarios/far-source.toml"),
        "fast-walker" => include_str!("../../scenarios/fast-walker.toml"),
        "deaf-near-wall" => include_str!("../../scenarios/deaf-near-wall.toml"),
        "mixed-fleet" => include_str!("../../scenarios/mixed-fleet.toml"),
        "low-source" => include_str!("../../scenarios/low-source.toml"),
        _ => return None,
    })
}

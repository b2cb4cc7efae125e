//! Scenarios shipped with soundmap (`tests/scenarios/*.toml`).

/// Names of the built-in scenarios.
pub const NAMES: [&str; 10] = [
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
        _ => return None,
    })
}

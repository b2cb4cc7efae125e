//! The tests' Python environment: built from tests/python/requirements.txt and
//! able to import every client library the system tests use.

use soundmap_sim::pytools;

#[test]
fn python_environment_imports_every_client_library() {
    let out = pytools::run("tests/python/check_env.py", std::iter::empty::<&str>());
    let requirements = std::fs::read_to_string(pytools::repo_root().join("tests/python/requirements.txt"))
        .expect("tests/python/requirements.txt");
    for line in requirements.lines().filter(|l| !l.trim().is_empty() && !l.starts_with('#')) {
        let (name, pinned) = line.split_once("==").expect("requirements are pinned with ==");
        let wanted = format!("{name} {pinned}");
        assert!(out.stdout.lines().any(|l| l == wanted), "{wanted} not installed:\n{}", out.stdout);
    }
}

//! Paths of the project-local environment that `scripts/setup` creates under `.local/`.

use std::path::{Path, PathBuf};

/// The workspace root (the folder holding the top-level `Cargo.toml`).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .nth(2)
        .expect("test-support lives two levels below the workspace root (tests/support)")
        .to_path_buf()
}

/// `.local/fixtures/NAME`, checked to exist.
///
/// # Panics
/// With the command that makes it when the fixture is missing.
pub fn fixture(name: &str) -> PathBuf {
    let path = workspace_root().join(".local/fixtures").join(name);
    assert!(
        path.is_file(),
        "fixture {} is missing: run `scripts/setup` (it regenerates .local/fixtures)",
        path.display()
    );
    path
}

/// TWIST2's material (a trained general tracker for the G1, its model and retargeted clips:
/// third-party, never committed), read in place at `../shared/third_party/twist2/` beside the
/// checkout; `None`, with a line saying the test is skipped, where it is absent (`.ci/run` fails
/// then, so CI never skips).
pub fn twist2_dir() -> Option<PathBuf> {
    let dir = workspace_root().join("../shared/third_party/twist2");
    if dir.join("README.md").is_file() {
        Some(dir)
    } else {
        eprintln!(
            "skipped: {} is absent (TWIST2's material is read in place, never committed)",
            dir.display()
        );
        None
    }
}

/// The human motion capture of `../shared/data/mocap/` (clips whose licence keeps them out of
/// the repository, read in place); `None`, with a line saying the test is skipped, where absent.
pub fn shared_mocap_dir() -> Option<PathBuf> {
    let dir = workspace_root().join("../shared/data/mocap");
    if dir.join("README.md").is_file() {
        Some(dir)
    } else {
        eprintln!(
            "skipped: {} is absent (third-party motion capture, read in place)",
            dir.display()
        );
        None
    }
}

/// The Python interpreter of the project's environment, with the independent third-party
/// clients and readers the tests drive (`.local/venv/bin/python`).
///
/// # Panics
/// With the command that makes it when the environment is missing.
pub fn venv_python() -> PathBuf {
    let path = workspace_root().join(".local/venv/bin/python");
    assert!(
        path.is_file(),
        "{} is missing: run `scripts/setup`",
        path.display()
    );
    path
}

/// Runs `script` (Python source) with the project's interpreter and `args`, for fixtures a test
/// makes with the third-party packages there (`onnx`, `mcap`).
///
/// # Panics
/// With the script's error output when it fails.
pub fn run_python(script: &str, args: &[&std::ffi::OsStr]) {
    let out = std::process::Command::new(venv_python())
        .args(["-c", script])
        .args(args)
        .output()
        .expect("the project's Python runs");
    assert!(
        out.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `robot_toml`'s text with its `policy = "…"` line pointing at the file beside `original` (the
/// folder it came from): a copy written elsewhere keeps its robot's own policy.
pub fn policy_from(robot_toml: &str, original: &Path) -> String {
    robot_toml
        .lines()
        .map(|l| match l.strip_prefix("policy = ") {
            Some(rel) => format!("policy = {:?}", original.join(rel.trim_matches('"'))),
            None => l.to_owned(),
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

//! The `robodeploy` binary for whole-path tests, started as a user starts it.
//!
//! Integration tests of another package cannot name a binary through `CARGO_BIN_EXE_*`, so the
//! binary is found beside the test executable (`target/<profile>/deps/..`). Under cargo it is
//! first brought up to date, once per test process, so a test never runs an old build.

use std::path::PathBuf;
use std::process::Command;
use std::sync::OnceLock;

/// The path of the `robodeploy` binary of this build profile, built if cargo is at hand.
///
/// # Panics
/// When the binary cannot be built or found, with the command that builds it.
pub fn robodeploy_path() -> PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let exe = std::env::current_exe().expect("the test executable has a path");
        let mut dir = exe
            .parent()
            .expect("the test executable is in a folder")
            .to_path_buf();
        if dir.ends_with("deps") {
            dir.pop();
        }
        if let Some(cargo) = std::env::var_os("CARGO") {
            let profile = match dir.file_name().and_then(|n| n.to_str()) {
                Some("debug") | None => "dev".to_owned(),
                Some(other) => other.to_owned(),
            };
            let status = Command::new(cargo)
                .args([
                    "build",
                    "--quiet",
                    "-p",
                    "robodeploy",
                    "--bin",
                    "robodeploy",
                    "--profile",
                ])
                .arg(&profile)
                .status()
                .expect("cargo runs");
            assert!(status.success(), "cargo build -p robodeploy failed");
        }
        let path = dir.join("robodeploy");
        assert!(
            path.is_file(),
            "{} is missing: build it with `cargo build -p robodeploy` (scripts/dev test does)",
            path.display()
        );
        path
    })
    .clone()
}

/// A command that runs `robodeploy`.
pub fn robodeploy() -> Command {
    Command::new(robodeploy_path())
}

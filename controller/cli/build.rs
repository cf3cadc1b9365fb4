//! The binary's build script: the shared run path (`scripts/build-rpath.rs`), and the commit
//! HEAD pointed at when the binary was built, which every recording names beside the version
//! (`ROBODEPLOY_COMMIT`; "unknown" outside a git checkout). Uncommitted changes are not told
//! apart: the build script reruns when HEAD moves, not on every edit.

#[path = "../../scripts/build-rpath.rs"]
mod rpath;

use std::process::Command;

/// `git args` in this crate's folder, its trimmed output when it succeeds.
fn git(args: &[&str]) -> Option<String> {
    let dir = std::env::var("CARGO_MANIFEST_DIR").ok()?;
    let out = Command::new("git").args(args).current_dir(dir).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_owned())
}

fn main() {
    rpath::main();
    let commit = git(&["rev-parse", "--short=12", "HEAD"]).unwrap_or_else(|| "unknown".to_owned());
    println!("cargo::rustc-env=ROBODEPLOY_COMMIT={commit}");
    // Built again when HEAD moves (a commit, a checkout). Only files that exist: cargo takes a
    // missing one as changed on every build, and the binary would be rebuilt under running tests.
    let head = git(&["symbolic-ref", "-q", "HEAD"]);
    for path in ["HEAD", "packed-refs"].into_iter().chain(head.as_deref()) {
        if let Some(p) = git(&["rev-parse", "--path-format=absolute", "--git-path", path])
            && std::path::Path::new(&p).is_file()
        {
            println!("cargo::rerun-if-changed={p}");
        }
    }
}

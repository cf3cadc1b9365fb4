//! What a binary finds from its own place at run time: the bundle it was unpacked from
//! (`bin/robodeploy` beside `bundle.toml`), or the checkout it was built in (`target/…/robodeploy`
//! under the workspace). Nothing here is a path compiled in, so a bundle or an installed binary
//! names no folder of the machine that built it.

use std::path::{Path, PathBuf};

/// The file `robodeploy bundle` writes at the top of a bundle: what its binary runs when given no
/// `--robot`, `--policy` or `--clip`, relative to the bundle's top folder.
pub const BUNDLE_FILE: &str = "bundle.toml";

/// A bundle's defaults (`bundle.toml`), paths relative to the bundle's top folder.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct BundleDefaults {
    /// The robot description.
    pub robot: PathBuf,
    /// The policy (manifest or export).
    pub policy: PathBuf,
    /// The clip, when one was packed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clip: Option<PathBuf>,
}

/// A bundle found beside the running binary: its top folder and defaults, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct Bundle {
    /// The bundle's top folder (`bin/`'s parent).
    pub root: PathBuf,
    /// The robot description it packs.
    pub robot: PathBuf,
    /// The policy it packs.
    pub policy: PathBuf,
    /// The first clip it packs.
    pub clip: Option<PathBuf>,
}

/// The folder of the running executable.
pub fn executable_dir() -> Option<PathBuf> {
    std::env::current_exe().ok()?.parent().map(Path::to_path_buf)
}

/// The bundle the running binary was unpacked from: `bundle.toml` one level up from it. A file
/// there that does not read is no bundle (said by `robodeploy doctor`'s library lines, not here).
pub fn bundle() -> Option<Bundle> {
    let root = executable_dir()?.parent()?.to_path_buf();
    let text = std::fs::read_to_string(root.join(BUNDLE_FILE)).ok()?;
    let defaults: BundleDefaults = toml::from_str(&text).ok()?;
    Some(Bundle {
        robot: root.join(defaults.robot),
        policy: root.join(defaults.policy),
        clip: defaults.clip.map(|c| root.join(c)),
        root,
    })
}

/// The checkout the running binary was built in: the nearest folder above it holding the
/// workspace's `Cargo.toml` and the reference robot.
pub fn checkout() -> Option<PathBuf> {
    let dir = executable_dir()?;
    dir.ancestors()
        .find(|d| d.join("Cargo.toml").is_file() && d.join("robots/biped/robot.toml").is_file())
        .map(Path::to_path_buf)
}

/// The robot a command runs without `--robot`: the bundle's, else the checkout's reference robot
/// (`robots/biped/robot.toml`), else `robot.toml` in the current folder.
pub fn default_robot() -> PathBuf {
    if let Some(b) = bundle() {
        return b.robot;
    }
    checkout().map_or_else(
        || PathBuf::from("robot.toml"),
        |c| c.join("robots/biped/robot.toml"),
    )
}

/// The clip a run falls back on: the bundle's first clip, else the reference robot's squat.
pub fn default_clip() -> PathBuf {
    bundle()
        .and_then(|b| b.clip)
        .unwrap_or_else(|| default_robot().with_file_name("clips/squat.csv"))
}

/// The policy a run takes for `robot` when none is given and the robot is its bundle's: the
/// policy the bundle was made with (which may differ from the one robot.toml names).
pub fn bundle_policy_for(robot: &Path) -> Option<PathBuf> {
    let b = bundle()?;
    let same = |a: &Path, c: &Path| match (std::fs::canonicalize(a), std::fs::canonicalize(c)) {
        (Ok(a), Ok(c)) => a == c,
        _ => false,
    };
    same(robot, &b.robot).then_some(b.policy)
}

/// Where the native libraries are looked for, most specific first: `lib/` beside the binary or
/// one level up (a bundle, an install), then the checkout's `.local/lib` (where `scripts/setup`
/// puts them).
pub fn library_dirs() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(exe_dir) = executable_dir() {
        dirs.push(exe_dir.join("lib"));
        dirs.push(exe_dir.join("../lib"));
    }
    if let Some(c) = checkout() {
        dirs.push(c.join(".local/lib"));
    }
    dirs
}

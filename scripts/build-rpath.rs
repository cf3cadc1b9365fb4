//! Shared build script of every crate whose binaries, tests or benches link MuJoCo.
//!
//! `.cargo/config.toml` points `MUJOCO_DYNAMIC_LINK_DIR` at the project's `.local/lib`; this bakes
//! the same directory into the binaries' run path, so they start without `LD_LIBRARY_PATH` — after
//! `lib/` beside the binary and one level up, where a shipped bundle keeps its libraries.
//! A missing library is reported here, with the fix, before the linker fails less clearly.

pub fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    println!("cargo::rerun-if-env-changed=ROBODEPLOY_BUNDLE_BUILD");
    let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") else {
        println!(
            "cargo::warning=MUJOCO_DYNAMIC_LINK_DIR is not set; run cargo from the workspace so .cargo/config.toml applies"
        );
        return;
    };
    let lib = std::path::Path::new(&dir).join("libmujoco.so.3.17.0");
    println!("cargo::rerun-if-changed={}", lib.display());
    if !lib.is_file() {
        panic!(
            "{} is missing: run `scripts/setup` from the workspace root to install the pinned native libraries",
            lib.display()
        );
    }
    // A bundle (bin/robodeploy beside lib/, as `robodeploy bundle` and `robodeploy-ray` ship it
    // to other machines) finds its libraries beside it first; a build in the workspace finds
    // .local/lib. A bundle's own build (`scripts/dev bundle` sets ROBODEPLOY_BUNDLE_BUILD) names
    // no folder of this machine.
    if std::env::var_os("ROBODEPLOY_BUNDLE_BUILD").is_some() {
        println!("cargo::rustc-link-arg=-Wl,-rpath,$ORIGIN/lib:$ORIGIN/../lib");
    } else {
        println!("cargo::rustc-link-arg=-Wl,-rpath,$ORIGIN/lib:$ORIGIN/../lib:{dir}");
    }
}

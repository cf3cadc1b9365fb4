//! The robodeploy binary as a user runs it.

use std::process::Command;

fn robodeploy() -> Command {
    Command::new(env!("CARGO_BIN_EXE_robodeploy"))
}

#[test]
fn doctor_loads_both_native_libraries_and_models() {
    let root = test_support::fixtures::workspace_root();
    let out = robodeploy()
        .args(["doctor", "--mjcf"])
        .arg(root.join("robots/fixtures/pendulum.xml"))
        .arg("--onnx")
        .arg(test_support::fixtures::fixture("mlp_obs96_act20.onnx"))
        // The binary must find its libraries with no help from the environment.
        .env_remove("LD_LIBRARY_PATH")
        .env_remove("ORT_DYLIB_PATH")
        .env_remove("MUJOCO_DYNAMIC_LINK_DIR")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "stdout:\n{stdout}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("MuJoCo        3.17.0 (mj_version 3017000)"),
        "{stdout}"
    );
    assert!(stdout.contains("nq 1 nv 1 nu 1"), "{stdout}");
    assert!(
        stdout.contains("input 'obs' [96] -> output 'actions' [20]"),
        "{stdout}"
    );
    assert!(stdout.contains("doctor: all checks passed"), "{stdout}");
}

#[test]
fn doctor_rejects_a_bad_model_with_its_path() {
    let bad = std::env::temp_dir().join(format!("robodeploy-bad-{}.xml", std::process::id()));
    std::fs::write(
        &bad,
        "<mujoco><worldbody><geom type='nonsense'/></worldbody></mujoco>",
    )
    .unwrap();
    let out = robodeploy()
        .args(["doctor", "--mjcf"])
        .arg(&bad)
        .arg("--onnx")
        .arg(test_support::fixtures::fixture("mlp_obs96_act20.onnx"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains(&bad.display().to_string()), "{stderr}");
}

#[test]
fn help_teaches_the_commands() {
    let out = robodeploy().arg("--help").output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    assert!(stdout.contains("doctor"), "{stdout}");
}

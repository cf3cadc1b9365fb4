//! Both pinned native libraries load into one process, found by the project's own set-up alone.

#[test]
fn mujoco_and_onnxruntime_load_together_at_their_pinned_versions() {
    assert_eq!(sim2real::mujoco::loaded_version_string(), "3.17.0");
    let info = policy::onnx::runtime_info().expect("ONNX Runtime loads from .local/lib");
    assert!(info.starts_with("1.31.1 ("), "unexpected ONNX Runtime: {info}");
    let found = policy::native::find_onnxruntime().unwrap();
    assert_eq!(policy::native::onnxruntime_version(&found).unwrap(), "1.31.1");
    assert!(
        found.starts_with(test_support::fixtures::workspace_root()),
        "{}",
        found.display()
    );
}

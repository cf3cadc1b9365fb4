//! The fixture policy runs through ort + the pinned ONNX Runtime and agrees with ONNX Runtime's
//! Python API, which produced the reference outputs beside the model (scripts/gen_onnx_fixtures.py).

#[global_allocator]
static ALLOC: test_support::alloc::CountingAllocator = test_support::alloc::CountingAllocator;

use policy::onnx::{OnnxError, OnnxModel};

#[derive(serde::Deserialize)]
struct Case {
    obs: Vec<f32>,
    actions: Vec<f32>,
}

#[derive(serde::Deserialize)]
struct Reference {
    producer: String,
    cases: Vec<Case>,
}

#[test]
fn matches_onnxruntime_python_outputs() {
    let model_path = test_support::fixtures::fixture("mlp_obs96_act20.onnx");
    let reference: Reference = serde_json::from_str(
        &std::fs::read_to_string(test_support::fixtures::fixture("mlp_obs96_act20.io.json")).unwrap(),
    )
    .unwrap();
    assert!(
        reference.producer.contains("1.31.1"),
        "reference made by {}",
        reference.producer
    );

    let mut model = OnnxModel::load(&model_path).unwrap();
    assert_eq!(model.input(), ("obs", 96));
    assert_eq!(model.output(), ("actions", 20));
    let mut act = [0.0f32; 20];
    for case in &reference.cases {
        model.run(&case.obs, &mut act).unwrap();
        for (i, (got, want)) in act.iter().zip(&case.actions).enumerate() {
            assert!(
                (got - want).abs() <= 1e-4 * (1.0 + want.abs()),
                "action {i}: {got} vs python {want}"
            );
        }
    }
    // The outputs are not trivially the same for every input.
    assert_ne!(reference.cases[0].actions, reference.cases[1].actions);
}

#[test]
fn wrong_buffer_sizes_are_refused() {
    let mut model = OnnxModel::load(&test_support::fixtures::fixture("mlp_obs96_act20.onnx")).unwrap();
    let mut act = [0.0f32; 20];
    let err = model.run(&[0.0; 95], &mut act).unwrap_err();
    assert!(
        matches!(
            err,
            OnnxError::BufferSize {
                what: "observation",
                expected: 96,
                actual: 95
            }
        ),
        "{err}"
    );
    let err = model.run(&[0.0; 96], &mut [0.0; 19]).unwrap_err();
    assert!(
        matches!(
            err,
            OnnxError::BufferSize {
                what: "action",
                expected: 20,
                actual: 19
            }
        ),
        "{err}"
    );
}

#[test]
fn missing_and_corrupt_models_name_the_file() {
    let err = OnnxModel::load(std::path::Path::new("/nonexistent/policy.onnx")).unwrap_err();
    assert!(err.to_string().contains("/nonexistent/policy.onnx"), "{err}");

    let garbage = std::env::temp_dir().join(format!("robodeploy-garbage-{}.onnx", std::process::id()));
    std::fs::write(&garbage, b"this is not a protobuf").unwrap();
    let err = OnnxModel::load(&garbage).unwrap_err();
    assert!(matches!(err, OnnxError::Load { .. }), "{err}");
    assert!(err.to_string().contains(&garbage.display().to_string()), "{err}");
}

#[test]
fn inference_allocates_nothing_after_the_first_run() {
    use test_support::alloc::count_allocations;
    let mut model = OnnxModel::load(&test_support::fixtures::fixture("mlp_obs96_act20.onnx")).unwrap();
    let obs = vec![0.1f32; 96];
    let mut actions = vec![0.0f32; 20];
    model.run(&obs, &mut actions).unwrap();
    let (_, stats) = count_allocations(|| {
        for _ in 0..50 {
            model.run(&obs, &mut actions).unwrap();
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
    assert!(actions.iter().all(|a| a.is_finite()));
}

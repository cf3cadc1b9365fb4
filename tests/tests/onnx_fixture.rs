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
    let _ = std::fs::remove_file(&garbage);
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

/// Writes a model `actions = W · obs` with a rank-`rank` input and output (W: 2 × 4, row i
/// holding i + 1 at column i), built with the `onnx` package.
fn linear_model(rank: usize, path: &std::path::Path) {
    let script = "import onnx, sys\n\
                  from onnx import helper, TensorProto, numpy_helper\n\
                  import numpy as np\n\
                  rank = int(sys.argv[2])\n\
                  w = np.zeros((4, 2), np.float32); w[0, 0] = 1.0; w[1, 1] = 2.0\n\
                  shape_in = [4] if rank == 1 else [1, 4]\n\
                  shape_out = [2] if rank == 1 else [1, 2]\n\
                  g = helper.make_graph([helper.make_node('MatMul', ['obs', 'w'], ['actions'])], 'linear',\n\
                      [helper.make_tensor_value_info('obs', TensorProto.FLOAT, shape_in)],\n\
                      [helper.make_tensor_value_info('actions', TensorProto.FLOAT, shape_out)],\n\
                      [numpy_helper.from_array(w, 'w')])\n\
                  m = helper.make_model(g, opset_imports=[helper.make_opsetid('', 17)])\n\
                  m.ir_version = 8\n\
                  onnx.checker.check_model(m)\n\
                  onnx.save(m, sys.argv[1])\n";
    let rank = rank.to_string();
    test_support::fixtures::run_python(script, &[path.as_os_str(), rank.as_ref()]);
}

#[test]
fn a_rank_1_model_is_fed_with_its_own_rank_and_runs_like_the_batched_one() {
    // A model whose input and output are plain vectors (no batch dimension): fed `[1, n]`
    // tensors, ONNX Runtime refused every inference ("Invalid rank for input") and the loop saw
    // only non-finite actions.
    let dir = std::env::temp_dir().join(format!("robodeploy-rank1-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let obs = [0.5f32, -1.0, 3.0, 7.0];
    let mut results = Vec::new();
    for rank in [1, 2] {
        let path = dir.join(format!("linear_rank{rank}.onnx"));
        linear_model(rank, &path);
        let mut model = OnnxModel::load(&path).unwrap_or_else(|e| panic!("rank {rank}: {e}"));
        let mut actions = [0.0f32; 2];
        model.run(&obs, &mut actions).unwrap();
        results.push(actions);
    }
    assert_eq!(results[0], [0.5, -2.0]);
    assert_eq!(results[0], results[1]);
    std::fs::remove_dir_all(&dir).unwrap();
}

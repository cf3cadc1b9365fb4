#!/usr/bin/env python3
"""Generate the small ONNX fixture models the Rust tests and benches load.

mlp_obs96_act20.onnx
    A tracking-policy-shaped MLP: input "obs" [batch, 96] -> 512 -> 256 -> 128 -> output "actions"
    [batch, 20], ELU between layers, weights from a fixed seed (deterministic bytes). Beside it,
    mlp_obs96_act20.io.json holds three input vectors and the outputs ONNX Runtime's Python API
    computes for them, so the Rust side is checked against an independent implementation.

Usage: gen_onnx_fixtures.py --out DIR
"""
import argparse
import json
import pathlib

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17


def mlp(name: str, sizes: list[int], seed: int, input_name: str, output_name: str) -> onnx.ModelProto:
    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    x = input_name
    for i, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        # Kaiming-like scale keeps activations O(1) through the layers, like a trained policy.
        w = (rng.standard_normal((fan_out, fan_in)) * np.sqrt(2.0 / fan_in)).astype(np.float32)
        b = (rng.standard_normal(fan_out) * 0.05).astype(np.float32)
        inits += [numpy_helper.from_array(w, f"w{i}"), numpy_helper.from_array(b, f"b{i}")]
        last = i == len(sizes) - 2
        y = output_name if last else f"h{i}"
        pre = y if last else f"z{i}"
        nodes.append(helper.make_node("Gemm", [x, f"w{i}", f"b{i}"], [pre], transB=1))
        if not last:
            nodes.append(helper.make_node("Elu", [pre], [y], alpha=1.0))
        x = y
    graph = helper.make_graph(
        nodes,
        name,
        [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, ["batch", sizes[0]])],
        [helper.make_tensor_value_info(output_name, TensorProto.FLOAT, ["batch", sizes[-1]])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="gen_onnx_fixtures")
    model.ir_version = 8
    onnx.checker.check_model(model, full_check=True)
    return model


def reference_io(model_path: pathlib.Path, n_in: int, seed: int) -> dict:
    import onnxruntime as ort

    sess = ort.InferenceSession(str(model_path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(3):
        obs = (rng.standard_normal((1, n_in)) * (k + 1)).astype(np.float32)
        (out,) = sess.run(None, {sess.get_inputs()[0].name: obs})
        cases.append({"obs": obs[0].tolist(), "actions": out[0].tolist()})
    return {"producer": f"onnxruntime {ort.__version__} (Python)", "cases": cases}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=pathlib.Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    path = args.out / "mlp_obs96_act20.onnx"
    onnx.save(mlp("mlp_obs96_act20", [96, 512, 256, 128, 20], seed=7, input_name="obs", output_name="actions"), path)
    (args.out / "mlp_obs96_act20.io.json").write_text(json.dumps(reference_io(path, 96, seed=11)))
    print(f"wrote {path}")

    # An untrained MLP with the sparse-input paper's observation size for rd-biped: tracker poses
    # at t and t−1 (2 × 27), joint positions, velocities and last actions (3 × 20) → 114.
    path = args.out / "sparse_input_obs114_act20.onnx"
    onnx.save(mlp("sparse_input_obs114_act20", [114, 128, 64, 20], seed=13, input_name="obs", output_name="actions"), path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

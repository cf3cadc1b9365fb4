#!/usr/bin/env python3
"""Generate the reference-following policy of a robot: an ONNX graph, NOT a trained network.

It reads the policy manifest (TOML), finds the observation ranges of `joint_pos` (relative),
`ramp` (ψ) and the current frame of `ref_joint_pos` (relative), and builds

    action = q_rel + ψ · (ref_rel − q_rel)          (then divided by the action scale)

so the robot is brought from wherever it stands to the clip during the start-up ramp and then
follows the clip's joint angles. It has no balance control of its own: it is for gantry runs and
for clips that keep the weight over the feet. The manifest must list those three terms.

Usage: gen_reference_policy.py MANIFEST.toml [--nan-after-half-ramp OUT.onnx]
The second form writes a test fixture whose actions turn NaN once ψ > 0.5.
"""
import argparse
import pathlib
import tomllib

import onnx
from onnx import TensorProto, helper, numpy_helper
import numpy as np

OPSET = 17


def width(term: dict, joints: int) -> int:
    kind = term["term"]
    fixed = {"gyro": 3, "accelerometer": 3, "projected_gravity": 3, "base_lin_vel": 3,
             "base_orientation": 4, "base_height": 1, "ramp": 1, "phase": 2}
    if kind in fixed:
        return fixed[kind]
    if kind in ("joint_pos", "joint_vel", "last_targets"):
        return joints
    if kind == "last_actions":
        return joints * term.get("k", 1)
    if kind in ("ref_joint_pos", "ref_joint_vel"):
        return joints * len(term.get("frames", [0]))
    if kind == "ref_root_pose":
        return 9 * len(term.get("frames", [0]))
    if kind == "ref_body_pos":
        return 3 * len(term["bodies"]) * len(term.get("frames", [0]))
    if kind == "command":
        return len(term["values"])
    if kind == "ref_keypoints":
        return 3 * len(term["views"]) * len(term["keypoints"]) * len(term.get("frames", [0]))
    if kind == "keypoints":
        return 3 * len(term["views"]) * len(term["keypoints"])
    raise SystemExit(f"unsupported term {kind!r}")


def layout(manifest: dict) -> tuple[dict, int]:
    n = len(manifest["joints"])
    at, ranges = 0, {}
    for term in manifest["observation"]:
        w = width(term, n) * term.get("history", 1)
        ranges.setdefault(term["term"], (at, term))
        at += w
    return ranges, at


def build(manifest: dict, nan_after_half_ramp: bool) -> onnx.ModelProto:
    n = len(manifest["joints"])
    ranges, obs_len = layout(manifest)
    for needed in ("joint_pos", "ramp", "ref_joint_pos"):
        if needed not in ranges:
            raise SystemExit(f"the manifest needs a {needed!r} term")
    q_at, q_term = ranges["joint_pos"]
    ref_at, ref_term = ranges["ref_joint_pos"]
    psi_at, _ = ranges["ramp"]
    if not (q_term.get("relative") and ref_term.get("relative")):
        raise SystemExit("joint_pos and ref_joint_pos must both be relative to the default pose")
    for t in (q_term, ref_term):
        if t.get("scale", 1.0) != 1.0 or t.get("offset", 0.0) != 0.0:
            raise SystemExit("joint_pos and ref_joint_pos must be unscaled")
    scale = manifest["action"].get("scale", 1.0)

    def const(name, values, dtype=np.int64):
        return numpy_helper.from_array(np.array(values, dtype=dtype), name)

    inits = [
        const("q_lo", [0, q_at]), const("q_hi", [1, q_at + n]),
        const("r_lo", [0, ref_at]), const("r_hi", [1, ref_at + n]),
        const("p_lo", [0, psi_at]), const("p_hi", [1, psi_at + 1]),
        const("inv_scale", [1.0 / scale], np.float32),
    ]
    nodes = [
        helper.make_node("Slice", ["obs", "q_lo", "q_hi"], ["q_rel"]),
        helper.make_node("Slice", ["obs", "r_lo", "r_hi"], ["ref_rel"]),
        helper.make_node("Slice", ["obs", "p_lo", "p_hi"], ["psi"]),
        helper.make_node("Sub", ["ref_rel", "q_rel"], ["gap"]),
        helper.make_node("Mul", ["psi", "gap"], ["step"]),
        helper.make_node("Add", ["q_rel", "step"], ["target_rel"]),
    ]
    out = "actions"
    if nan_after_half_ramp:
        # log(0.5 − ψ) is NaN once ψ > 0.5; times zero keeps it NaN, and finite values unchanged.
        inits += [const("half", [0.5], np.float32), const("zero", [0.0], np.float32)]
        nodes += [
            helper.make_node("Sub", ["half", "psi"], ["margin"]),
            helper.make_node("Log", ["margin"], ["poison"]),
            helper.make_node("Mul", ["poison", "zero"], ["nan_or_zero"]),
            helper.make_node("Add", ["target_rel", "nan_or_zero"], ["unscaled"]),
        ]
    else:
        nodes.append(helper.make_node("Identity", ["target_rel"], ["unscaled"]))
    nodes.append(helper.make_node("Mul", ["unscaled", "inv_scale"], [out]))
    graph = helper.make_graph(
        nodes,
        "reference_follower",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, obs_len])],
        [helper.make_tensor_value_info(out, TensorProto.FLOAT, [1, n])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="gen_reference_policy")
    model.ir_version = 8
    model.doc_string = "Reference follower: not a trained policy. " + manifest["description"][:200]
    onnx.checker.check_model(model, full_check=True)
    return model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("manifest", type=pathlib.Path)
    ap.add_argument("--nan-after-half-ramp", type=pathlib.Path, help="write the NaN test fixture here instead")
    args = ap.parse_args()
    manifest = tomllib.loads(args.manifest.read_text())
    if args.nan_after_half_ramp:
        onnx.save(build(manifest, True), args.nan_after_half_ramp)
        return
    out = args.manifest.parent / manifest["onnx"]
    onnx.save(build(manifest, False), out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

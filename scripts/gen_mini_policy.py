#!/usr/bin/env python3
"""Generate rd-mini's command-driven fixture: an ONNX graph, NOT a trained network.

It reads the manifest (robots/mini/policies/stand_walk.toml) for its joint order and observation
layout and builds, in the action units of the manifest (rad / action scale):

    lean      hip pitch −, ankle pitch + with the forward command (the body leans into it)
    sideways  hip roll and ankle roll with the leftward command
    turn      hip yaw, both legs, with the turning command
    step      knees and ankle pitches in antiphase with the gait phase, the amplitude
              proportional to |forward| + |leftward| + |turning| (zero when told to stand)

so the robot stands at its default pose under a zero command, and the commands visibly change
what it does. It has no balance control and does not walk.

Usage: gen_mini_policy.py MANIFEST.toml   (writes the ONNX file the manifest names, beside it)
"""
import pathlib
import sys
import tomllib

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17


def term_widths(manifest):
    n = len(manifest["joints"])
    fixed = {"base_ang_vel": 3, "projected_gravity": 3, "phase": 2, "command": len(manifest["commands"]["names"])}
    at, slots = 0, {}
    for t in manifest["observation"]:
        kind = t["term"]
        w = fixed.get(kind, n) * t.get("history", 1)
        slots[kind] = (at, w)
        at += w
    return slots, at


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    path = pathlib.Path(sys.argv[1])
    manifest = tomllib.loads(path.read_text())
    joints = manifest["joints"]
    n = len(joints)
    slots, obs_len = term_widths(manifest)
    j = {name: i for i, name in enumerate(joints)}
    cmd, _ = slots["command"]
    phase, _ = slots["phase"]
    # The command term is observed scaled (manifest `scales`): weights act on what the policy sees.
    w = np.zeros((obs_len, n), dtype=np.float32)
    vx, vy, wz = cmd, cmd + 1, cmd + 2
    for side in ("l", "r"):
        w[vx, j[f"{side}_hip_pitch"]] = -0.4
        w[vx, j[f"{side}_ankle_pitch"]] = 0.2
        w[vy, j[f"{side}_hip_roll"]] = 0.5
        w[vy, j[f"{side}_ankle_roll"]] = -0.5
        w[wz, j[f"{side}_hip_yaw"]] = 0.6
    # Stepping: amplitude(cmd) · sin(phase) · pattern.
    pattern = np.zeros((1, n), dtype=np.float32)
    for name, sign in [("l_knee", 1.0), ("r_knee", -1.0), ("l_ankle_pitch", -0.5), ("r_ankle_pitch", 0.5)]:
        pattern[0, j[name]] = 0.3 * sign
    nodes = [
        helper.make_node("MatMul", ["obs", "W"], ["linear"]),
        helper.make_node("Slice", ["obs", "cmd_start", "cmd_end", "axis1"], ["commands"]),
        helper.make_node("Abs", ["commands"], ["abs_commands"]),
        helper.make_node("ReduceSum", ["abs_commands", "axis1"], ["amplitude"], keepdims=1),
        helper.make_node("Slice", ["obs", "sin_start", "sin_end", "axis1"], ["phase_sin"]),
        helper.make_node("Mul", ["amplitude", "phase_sin"], ["gait"]),
        helper.make_node("MatMul", ["gait", "pattern"], ["stepping"]),
        helper.make_node("Add", ["linear", "stepping"], ["actions"]),
    ]
    # The phase term is [cos, sin]: sin is its second value.
    inits = [
        numpy_helper.from_array(w, "W"),
        numpy_helper.from_array(pattern, "pattern"),
        numpy_helper.from_array(np.array([cmd], dtype=np.int64), "cmd_start"),
        numpy_helper.from_array(np.array([cmd + 3], dtype=np.int64), "cmd_end"),
        numpy_helper.from_array(np.array([phase + 1], dtype=np.int64), "sin_start"),
        numpy_helper.from_array(np.array([phase + 2], dtype=np.int64), "sin_end"),
        numpy_helper.from_array(np.array([1], dtype=np.int64), "axis1"),
    ]
    save_fixture(
        nodes,
        inits,
        "rd_mini_stand_walk_fixture",
        "robodeploy fixture (scripts/gen_mini_policy.py): not a trained policy",
        (obs_len, n),
        path.parent / manifest["onnx"],
    )


def save_fixture(nodes, inits, name, doc, shape, out):
    """Checks and writes a graph of `obs` [1, obs_len] → `actions` [1, n] (`shape`) to `out`."""
    obs_len, n = shape
    graph = helper.make_graph(
        nodes,
        name,
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, obs_len])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, n])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    model.doc_string = doc
    onnx.checker.check_model(model)
    onnx.save(model, out)
    print(f"wrote {out} ({obs_len} observations → {n} actions)")


if __name__ == "__main__":
    main()

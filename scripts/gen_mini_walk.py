#!/usr/bin/env python3
"""Generate rd-mini's walking fixture: an ONNX graph of a fixed gait, NOT a trained network.

It reads the manifest (robots/mini/policies/walk.toml) for its joint order and observation layout
and builds, from the gait phase φ (the observation's [cos φ, sin φ]) and the forward command v
(as the policy observes it, scaled), in radians about the default pose:

    sway     both hip rolls −SWAY·sin φ, ankle rolls +SWAY·ANKLE_ROLL·sin φ: the pelvis over the
             left foot while sin φ > 0, over the right one while sin φ < 0
    lift     the unloaded leg's knee +LIFT·max(0, ∓sin φ), its hip and ankle pitch −LIFT/2 each
             (the sole stays level)
    stride   each hip pitch ∓v·(STRIDE·cos φ + STRIDE_SIN·sin φ), its ankle pitch the opposite: the
             swinging leg reaches forward, the standing one pushes back
    balance  ankle pitch +PITCH_GAIN·g_x and ankle roll +ROLL_GAIN·g_y from the projected gravity

all of it (but balance) scaled by a gate min(1, GATE·|v|), so a zero command stands still. The
constants below were found by a random search over these eight numbers against the mirror (10 s
at v = 0.2 m/s on the Dynamixel build: no fall, most ground covered, heading kept); they walk
rd-mini about 0.08 m/s ahead for a 0.2 m/s command on Dynamixel and Feetech servos alike, with a
slow drift in heading. No turning, no sideways steps: the manifest offers forward speed only.

Usage: gen_mini_walk.py MANIFEST.toml   (writes the ONNX file the manifest names, beside it)
"""
import pathlib
import sys
import tomllib

import numpy as np
from onnx import helper, numpy_helper

from gen_mini_policy import save_fixture, term_widths

SWAY = 0.044
ANKLE_ROLL = 0.223
LIFT = 0.216
STRIDE = 0.101
STRIDE_SIN = -0.191
STRIDE_ANKLE = 1.005
PITCH_GAIN = 0.391
ROLL_GAIN = 0.285
GATE = 10.0


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    path = pathlib.Path(sys.argv[1])
    manifest = tomllib.loads(path.read_text())
    joints = manifest["joints"]
    n = len(joints)
    j = {name: i for i, name in enumerate(joints)}
    slots, obs_len = term_widths(manifest)
    cmd, width = slots["command"]
    assert manifest["commands"]["names"] == ["lin_vel_x"] and width == 1, "forward speed only"
    phase, _ = slots["phase"]
    gravity, _ = slots["projected_gravity"]
    scale = manifest["action"]["scale"]

    # Balance: linear in the observation.
    w = np.zeros((obs_len, n), dtype=np.float32)
    # Gait: rows [cos φ, sin φ, max(0, sin φ), max(0, −sin φ), v cos φ, v sin φ] → joints.
    gait = np.zeros((6, n), dtype=np.float32)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        w[gravity + 0, j[f"{side}_ankle_pitch"]] = PITCH_GAIN
        w[gravity + 1, j[f"{side}_ankle_roll"]] = ROLL_GAIN
        gait[1, j[f"{side}_hip_roll"]] = -SWAY
        gait[1, j[f"{side}_ankle_roll"]] = SWAY * ANKLE_ROLL
        # The left leg swings while the weight is on the right (sin φ < 0), the right one while
        # it is on the left.
        unloaded = 3 if side == "l" else 2
        gait[unloaded, j[f"{side}_knee"]] = LIFT
        gait[unloaded, j[f"{side}_hip_pitch"]] = -LIFT / 2
        gait[unloaded, j[f"{side}_ankle_pitch"]] = -LIFT / 2
        for row, amount in ((4, STRIDE), (5, STRIDE_SIN)):
            gait[row, j[f"{side}_hip_pitch"]] = -amount * sign
            gait[row, j[f"{side}_ankle_pitch"]] = amount * sign * STRIDE_ANKLE
    w /= scale
    gait /= scale

    def index(v):
        return np.array([v], dtype=np.int64)

    nodes = [
        helper.make_node("MatMul", ["obs", "W"], ["balance"]),
        helper.make_node("Slice", ["obs", "cmd_start", "cmd_end", "axis1"], ["v"]),
        helper.make_node("Abs", ["v"], ["speed"]),
        helper.make_node("Mul", ["speed", "gate_gain"], ["gate_raw"]),
        helper.make_node("Clip", ["gate_raw", "zero", "one"], ["gate"]),
        # The phase term is [cos, sin].
        helper.make_node("Slice", ["obs", "cos_start", "sin_start", "axis1"], ["cos"]),
        helper.make_node("Slice", ["obs", "sin_start", "phase_end", "axis1"], ["sin"]),
        helper.make_node("Relu", ["sin"], ["left_loaded"]),
        helper.make_node("Neg", ["sin"], ["minus_sin"]),
        helper.make_node("Relu", ["minus_sin"], ["right_loaded"]),
        helper.make_node("Mul", ["v", "cos"], ["v_cos"]),
        helper.make_node("Mul", ["v", "sin"], ["v_sin"]),
        helper.make_node(
            "Concat", ["cos", "sin", "left_loaded", "right_loaded", "v_cos", "v_sin"], ["basis"], axis=1
        ),
        helper.make_node("Mul", ["basis", "gate"], ["gated"]),
        helper.make_node("MatMul", ["gated", "G"], ["stepping"]),
        helper.make_node("Add", ["balance", "stepping"], ["actions"]),
    ]
    inits = [
        numpy_helper.from_array(w, "W"),
        numpy_helper.from_array(gait, "G"),
        numpy_helper.from_array(index(cmd), "cmd_start"),
        numpy_helper.from_array(index(cmd + 1), "cmd_end"),
        numpy_helper.from_array(index(phase), "cos_start"),
        numpy_helper.from_array(index(phase + 1), "sin_start"),
        numpy_helper.from_array(index(phase + 2), "phase_end"),
        numpy_helper.from_array(index(1), "axis1"),
        numpy_helper.from_array(np.array(GATE, dtype=np.float32), "gate_gain"),
        numpy_helper.from_array(np.array(0.0, dtype=np.float32), "zero"),
        numpy_helper.from_array(np.array(1.0, dtype=np.float32), "one"),
    ]
    save_fixture(
        nodes,
        inits,
        "rd_mini_walk_fixture",
        "robodeploy fixture (scripts/gen_mini_walk.py): a fixed gait, not a trained policy",
        (obs_len, n),
        path.parent / manifest["onnx"],
    )


if __name__ == "__main__":
    main()

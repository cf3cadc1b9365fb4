#!/usr/bin/env python3
"""Fit the project's small online motion generator and export it to ONNX with its description.

WHAT IT IS: a LINEAR autoregressive model (ridge regression, NumPy), not a learned motion prior.
From the last N frames of joint angles it predicts the next K frames directly (one matrix):

    squat = (history[1, N·J] − μ) · W + b + μ
    stand = history · S                       (each frame 15 % closer to the standing pose)
    frames[1, K, J] = reshape( c · squat + (1 − c) · stand ),   c = command[1, 1], "intensity"

with W fitted on rd-biped's own squat clip (robots/biped/clips/squat.csv, 30 Hz; its two 3 s squats
looped, so the model learns one squat cycle as a stable oscillation). Rolled out on its own
output it keeps squatting; it has no notion of balance, commands or style. It exists to run the
stack's generator path (worker thread, plans, resampling, deadlines) with a real model whose
frames a reference follower can track on the mirror.

The fit is checked before anything is written: the K-step prediction error on the training data,
and a 120 s rollout from the seed that must stay finite and within the training range.

Writes OUT/squat_ar.onnx (inputs "history" [1, N, J] and "command" [1, 1], output "frames"
[1, K, J]) and OUT/squat_ar.toml (the description the runtime reads: names, N, K, frame rate,
joints, seed clip, the command).

Usage: gen_generator.py [--out robots/biped/generators] [--history 8] [--horizon 3]
"""
import argparse
import pathlib

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17
ROOT = pathlib.Path(__file__).resolve().parent.parent
CLIP = ROOT / "robots/biped/clips/squat.csv"
FRAME_HZ = 30.0
# The clip's two squats (0–6 s at 30 Hz) start and end standing: looped, they are one cycle.
CYCLE_FRAMES = 180
LOOPS = 6
RIDGE = 1e-4
# With intensity 0, each frame closes this share of the gap to the standing pose.
SETTLE = 0.15


def load_clip(path: pathlib.Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    lines = [l for l in path.read_text().splitlines() if l and not l.startswith("#")]
    head = lines[0].split(",")
    data = np.array([[float(x) for x in l.split(",")] for l in lines[1:]])
    return head[8:], data[:, 0], data[:, 8:]


def fit(q: np.ndarray, n: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Ridge fit of the next k frames on the last n; returns μ, W, b and the fit's RMSE (rad)."""
    mu = q.mean(axis=0)
    x = q - mu
    rows = range(n, len(x) - k + 1)
    X = np.array([x[i - n:i].ravel() for i in rows])
    Y = np.array([x[i:i + k].ravel() for i in rows])
    Xa = np.hstack([X, np.ones((len(X), 1))])
    Wa = np.linalg.solve(Xa.T @ Xa + RIDGE * np.eye(Xa.shape[1]), Xa.T @ Y)
    rmse = float(np.sqrt(((Xa @ Wa - Y) ** 2).mean()))
    return mu, Wa[:-1], Wa[-1], rmse


def rollout(seed: np.ndarray, mu, W, b, k: int, frames: int) -> np.ndarray:
    n = len(seed)
    stream = list(seed - mu)
    while len(stream) < n + frames:
        y = np.concatenate(stream[-n:]) @ W + b
        stream.extend(y.reshape(k, -1))
    return np.array(stream[n:n + frames]) + mu


def settle(stand: np.ndarray, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The linear map (S, s) from the history to k frames that each close SETTLE of the gap from
    the newest frame to `stand`: frame i = stand + (1 − SETTLE)^(i+1) · (last − stand)."""
    j = len(stand)
    S = np.zeros((n * j, k * j))
    s = np.zeros(k * j)
    for i in range(k):
        keep = (1.0 - SETTLE) ** (i + 1)
        S[(n - 1) * j:n * j, i * j:(i + 1) * j] = keep * np.eye(j)
        s[i * j:(i + 1) * j] = (1.0 - keep) * stand
    return S, s


def export(mu, W, b, stand, n: int, k: int, j: int) -> onnx.ModelProto:
    f32 = np.float32
    S, s = settle(stand, n, k)
    inits = [
        numpy_helper.from_array(np.array([1, n * j], dtype=np.int64), "flat"),
        numpy_helper.from_array(np.array([1, k, j], dtype=np.int64), "shaped"),
        numpy_helper.from_array(np.tile(mu, n).astype(f32), "mu_in"),
        numpy_helper.from_array(W.astype(f32), "W"),
        numpy_helper.from_array((b + np.tile(mu, k)).astype(f32), "b_out"),
        numpy_helper.from_array(S.astype(f32), "S"),
        numpy_helper.from_array(s.astype(f32), "s_out"),
        numpy_helper.from_array(np.array([1.0], dtype=f32), "one"),
    ]
    nodes = [
        helper.make_node("Reshape", ["history", "flat"], ["h"]),
        helper.make_node("Sub", ["h", "mu_in"], ["x"]),
        helper.make_node("MatMul", ["x", "W"], ["y"]),
        helper.make_node("Add", ["y", "b_out"], ["squat"]),
        helper.make_node("MatMul", ["h", "S"], ["held"]),
        helper.make_node("Add", ["held", "s_out"], ["stand"]),
        # c · squat + (1 − c) · stand, c broadcast from [1, 1].
        helper.make_node("Mul", ["command", "squat"], ["a"]),
        helper.make_node("Sub", ["one", "command"], ["rest"]),
        helper.make_node("Mul", ["rest", "stand"], ["b"]),
        helper.make_node("Add", ["a", "b"], ["z"]),
        helper.make_node("Reshape", ["z", "shaped"], ["frames"]),
    ]
    graph = helper.make_graph(
        nodes,
        "squat_ar",
        [
            helper.make_tensor_value_info("history", TensorProto.FLOAT, [1, n, j]),
            helper.make_tensor_value_info("command", TensorProto.FLOAT, [1, 1]),
        ],
        [helper.make_tensor_value_info("frames", TensorProto.FLOAT, [1, k, j])],
        inits,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="robodeploy scripts/gen_generator.py",
        doc_string="Linear autoregressive squat generator (ridge fit on rd-biped's squat clip). "
        "NOT a learned motion prior.",
    )
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "robots/biped/generators")
    ap.add_argument("--history", type=int, default=8, help="N: frames the model looks back")
    ap.add_argument("--horizon", type=int, default=3, help="K: frames one step produces")
    args = ap.parse_args()
    n, k = args.history, args.horizon
    joints, times, q = load_clip(CLIP)
    if abs((times[1] - times[0]) * FRAME_HZ - 1.0) > 1e-3:
        raise SystemExit(f"{CLIP} is not at {FRAME_HZ} Hz")
    train = np.concatenate([q[:CYCLE_FRAMES]] * LOOPS)
    mu, W, b, rmse = fit(train, n, k)
    if rmse > 1e-3:
        raise SystemExit(f"fit RMSE {rmse:.2e} rad: the model does not reproduce its training data")
    seconds = 120
    out = rollout(q[:n], mu, W, b, k, int(seconds * FRAME_HZ))
    lo, hi = train.min(axis=0), train.max(axis=0)
    margin = 0.1 * (hi - lo) + 1e-3
    if not np.isfinite(out).all() or (out < lo - margin).any() or (out > hi + margin).any():
        raise SystemExit(f"a {seconds} s rollout leaves the training range: the model is unstable")
    amplitude = np.abs(out[-int(3 * FRAME_HZ):] - out[-int(3 * FRAME_HZ):].mean(axis=0)).max()
    args.out.mkdir(parents=True, exist_ok=True)
    onnx.save(export(mu, W, b, q[0], n, k, len(joints)), args.out / "squat_ar.onnx")
    seed = pathlib.Path("../clips/squat.csv")
    listed = ",\n".join(f'    "{j}"' for j in joints)
    (args.out / "squat_ar.toml").write_text(f'''# Motion generator description: what the ONNX file beside it takes and gives (robodeploy play --generator).
# Generated by scripts/gen_generator.py.
description = """Linear autoregressive squat generator for rd-biped. NOT a learned motion prior: a ridge regression (NumPy) of the next {k} frames on the last {n}, fitted on the project's own squat clip (its two squats looped), so that rolled out on its own output it keeps squatting (training-fit RMSE {rmse:.1e} rad; a {seconds} s rollout stays within the clip's range, last-cycle amplitude {amplitude:.2f} rad). Its command, the intensity, mixes that squat (1) with settling into the standing pose (0). It has no balance or style."""
onnx = "squat_ar.onnx"
input = "history"      # [1, history, joints]
output = "frames"      # [1, horizon, joints]
history = {n}            # N frames looked back
horizon = {k}            # K frames per step: {FRAME_HZ / k:g} steps a second
frame_hz = {FRAME_HZ:g}
seed_clip = "{seed.as_posix()}"   # its first {n} frames start the history
joints = [
{listed},
]

[command]              # the model's second input, [1, 1]
input = "command"
names = ["intensity"]  # 1: squat; 0: settle into the standing pose
values = [1.0]         # unless the run says otherwise (play --generator-command)
''')
    print(f"{args.out}/squat_ar.onnx: N={n}, K={k}, {len(joints)} joints, fit RMSE {rmse:.1e} rad, "
          f"{seconds} s rollout amplitude {amplitude:.2f} rad")


if __name__ == "__main__":
    main()

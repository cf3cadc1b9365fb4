"""Checks a recorded run of a motion-tracking export against an independent computation: NumPy for
the anchor terms, ONNX Runtime's Python API for the motion the export carries.

Usage: check_tracking_export.py RUN.mcap EXPORT.onnx ORI POS CMD J RAMP

ORI, POS, CMD: where motion_anchor_ori_b (6), motion_anchor_pos_b (3; -1 when the policy has
none) and command (2 J) start in the observation. RAMP: ticks the first frame is held after the
policy takes over. Prints JSON:
  ori_max_err, pos_max_err  largest difference between the recorded observation and
                            R(q_robot^-1 q_ref)[:, :2] row by row / R_robot^T (p_ref - p_robot)
                            computed here from the recorded anchor poses
  ticks                     policy messages with anchors
  frames_matched            policy ticks whose command equals the export's own joint_pos output
                            for the frame that tick plays: max(0, k - RAMP) on the k-th tick
  frames_mismatched         policy ticks whose command does not
"""
import json
import sys

import numpy as np
import onnxruntime as ort
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def rotation(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def pose(p):
    """x y z qw qx qy qz of a robodeploy.Pose."""
    return np.array([p.position.x, p.position.y, p.position.z,
                     p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z])


def main():
    path, onnx_path = sys.argv[1], sys.argv[2]
    ori, pos, cmd, j, ramp = (int(a) for a in sys.argv[3:8])
    ori_err = pos_err = 0.0
    ticks = 0
    commands = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/policy"]):
            if not m.HasField("robot_anchor") or not m.running:
                continue
            obs = np.array(m.observation, dtype=np.float64)
            robot, ref = pose(m.robot_anchor), pose(m.reference_anchor)
            rr, rm = rotation(robot[3:]), rotation(ref[3:])
            want = (rr.T @ rm)[:, :2].reshape(-1)
            ori_err = max(ori_err, float(np.max(np.abs(obs[ori:ori + 6] - want))))
            if pos >= 0:
                want = rr.T @ (ref[:3] - robot[:3])
                pos_err = max(pos_err, float(np.max(np.abs(obs[pos:pos + 3] - want))))
            commands.append(obs[cmd:cmd + j])
            ticks += 1
    session = ort.InferenceSession(onnx_path, providers=["CPUExecutionProvider"])
    n_obs = session.get_inputs()[0].shape[1]
    matched = 0
    for k, command in enumerate(commands):
        frame = max(0, k - ramp)
        out = session.run(["joint_pos"], {"obs": np.zeros((1, n_obs), np.float32),
                                          "time_step": np.array([[frame]], np.float32)})
        matched += int(np.max(np.abs(command - out[0][0])) <= 1e-6)
    print(json.dumps({
        "ori_max_err": ori_err,
        "pos_max_err": pos_err,
        "ticks": ticks,
        "frames_matched": matched,
        "frames_mismatched": len(commands) - matched,
    }))


if __name__ == "__main__":
    main()

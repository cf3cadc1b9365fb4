#!/usr/bin/env python3
"""Write rd-biped policies in the export convention of BeyondMimic / mjlab motion tracking, as
FIXTURES: NOT trained policies. Each ONNX file has what those exporters write, byte for byte in
names, shapes, opset and metadata encoding:

  inputs   obs [1, N], time_step [1, 1] (float32)
  outputs  actions [1, J], and the motion baked in as constant tables indexed by
           min(time_step, T - 1): joint_pos [1, J], joint_vel [1, J], body_pos_w [1, B, 3],
           body_quat_w [1, B, 4] (w x y z), body_lin_vel_w [1, B, 3], body_ang_vel_w [1, B, 3]
  opset    11
  metadata run_path, joint_names, joint_stiffness, joint_damping, default_joint_pos,
           command_names, observation_names, action_scale, anchor_body_name, body_names
           (lists joined with ",", numbers with 3 decimals), and the history keys below.

The policy part is a fixed graph, not a network: it reads the reference joint positions from the
`command` term of its own observation and returns the action that puts the joint targets there,
(command[:J] - default) / action_scale. It balances only because the squat keeps the weight over
the feet. The motion is rd-biped's squat (robots/biped/clips/squat.csv) resampled to 50 Hz, with
body poses by forward kinematics of robots/biped/biped.xml. The joint order is the MJCF's (as
mjlab writes it), not robot.toml's.

  rd_biped_tracking.onnx          BeyondMimic's terms: command, motion_anchor_pos_b,
                                  motion_anchor_ori_b, base_lin_vel, base_ang_vel, joint_pos,
                                  joint_vel, actions; observation_history_lengths all 1
  rd_biped_tracking_wose.onnx     "without state estimation": no motion_anchor_pos_b, base_lin_vel
  rd_biped_tracking_history.onnx  newer mjlab keys: observation_terms_history_length (3 on
                                  joint_pos, joint_vel, actions; oldest first), _scale (0.05 on
                                  joint_vel), _clip ([-inf, inf] or [-c, c])

With --broken-quaternion-order it also writes rd_biped_tracking_xyzw.onnx: the first variant with
body_quat_w stored x y z w, a deliberately wrong export for the tests of robodeploy's check.

Usage: gen_tracking_export.py --out DIR [--broken-quaternion-order]
"""
import argparse
import csv
import pathlib
import tomllib

import mujoco
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

ROOT = pathlib.Path(__file__).resolve().parent.parent
ROBOT = ROOT / "robots/biped"
CLIP = ROBOT / "clips/squat.csv"
RATE_HZ = 50.0
OPSET = 11
BODIES = ["pelvis", "torso", "head", "left_forearm", "right_forearm", "left_shin", "right_shin",
          "left_foot", "right_foot"]
ANCHOR = "torso"


def csv3(values):
    """The exporters' list encoding: numbers with 3 decimals, strings as they are."""
    return ",".join(f"{v:.3f}" if isinstance(v, (int, float)) else str(v) for v in values)


def read_clip():
    rows = list(csv.reader(l for l in CLIP.read_text().splitlines() if not l.startswith("#")))
    header, data = rows[0], np.array([[float(x) for x in r] for r in rows[1:]])
    return header[8:], data[:, 0], data[:, 1:4], data[:, 4:8], data[:, 8:]


def resample(times, values):
    t = np.arange(0.0, times[-1] + 1e-9, 1.0 / RATE_HZ)
    return t, np.stack([np.interp(t, times, values[:, k]) for k in range(values.shape[1])], axis=1)


def motion(model, joint_order, defaults):
    names, times, pos, quat, q = read_clip()
    t, pos = resample(times, pos)
    _, quat = resample(times, quat)
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    _, q = resample(times, q)
    by_name = {n: q[:, k] for k, n in enumerate(names)}
    data = mujoco.MjData(model)
    # Joints the clip does not name stay at the default pose, as robodeploy plays it.
    jpos = np.stack([by_name.get(n, np.full(len(t), d)) for n, d in zip(joint_order, defaults)], axis=1)
    body_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in BODIES]
    body_pos = np.zeros((len(t), len(BODIES), 3))
    body_quat = np.zeros((len(t), len(BODIES), 4))
    for k in range(len(t)):
        data.qpos[:3], data.qpos[3:7] = pos[k], quat[k]
        for j, name in enumerate(joint_order):
            data.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)]] = jpos[k, j]
        mujoco.mj_kinematics(model, data)
        body_pos[k] = data.xpos[body_ids]
        body_quat[k] = data.xquat[body_ids]
    dt = 1.0 / RATE_HZ
    ang = np.zeros_like(body_pos)
    for k in range(len(t) - 1):
        for b in range(len(BODIES)):
            dq = np.zeros(3)
            conj = body_quat[k, b] * np.array([1, -1, -1, -1])
            rel = np.zeros(4)
            mujoco.mju_mulQuat(rel, body_quat[k + 1, b], conj)
            mujoco.mju_quat2Vel(dq, rel, dt)
            ang[k, b] = dq
    ang[-1] = ang[-2]
    return {
        "joint_pos": jpos.astype(np.float32),
        "joint_vel": np.gradient(jpos, dt, axis=0).astype(np.float32),
        "body_pos_w": body_pos.astype(np.float32),
        "body_quat_w": body_quat.astype(np.float32),
        "body_lin_vel_w": np.gradient(body_pos, dt, axis=0).astype(np.float32),
        "body_ang_vel_w": ang.astype(np.float32),
    }


WIDTHS = {"motion_anchor_pos_b": 3, "motion_anchor_ori_b": 6, "base_lin_vel": 3, "base_ang_vel": 3}


def build(name, tables, meta, terms, history):
    """The export: obs -> actions through the command's joint positions; the motion tables."""
    j = tables["joint_pos"].shape[1]
    widths = {**WIDTHS, "command": 2 * j, "joint_pos": j, "joint_vel": j, "actions": j}
    n_obs = sum(widths[t] * max(1, history.get(t, 1)) for t in terms)
    cmd_at = 0
    for t in terms:
        if t == "command":
            break
        cmd_at += widths[t] * max(1, history.get(t, 1))
    default = np.array([float(f"{v:.3f}") for v in meta["default"]], dtype=np.float32)
    scale = np.array([float(f"{v:.3f}") for v in meta["scale"]], dtype=np.float32)
    t_total = tables["joint_pos"].shape[0]
    inits = [
        numpy_helper.from_array(np.array([0, cmd_at], dtype=np.int64), "cmd_lo"),
        numpy_helper.from_array(np.array([1, cmd_at + j], dtype=np.int64), "cmd_hi"),
        numpy_helper.from_array(default[None, :], "default"),
        numpy_helper.from_array((1.0 / scale)[None, :], "inv_scale"),
        numpy_helper.from_array(np.array([[t_total - 1]], dtype=np.float32), "last_step"),
        numpy_helper.from_array(np.array([1], dtype=np.int64), "one"),
    ]
    nodes = [
        helper.make_node("Slice", ["obs", "cmd_lo", "cmd_hi"], ["ref_q"]),
        helper.make_node("Sub", ["ref_q", "default"], ["ref_rel"]),
        helper.make_node("Mul", ["ref_rel", "inv_scale"], ["actions"]),
        helper.make_node("Min", ["time_step", "last_step"], ["step_clamped"]),
        helper.make_node("Cast", ["step_clamped"], ["step_long"], to=TensorProto.INT64),
        helper.make_node("Reshape", ["step_long", "one"], ["step"]),
    ]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, j])]
    for key, table in tables.items():
        inits.append(numpy_helper.from_array(table, f"{key}_table"))
        nodes.append(helper.make_node("Gather", [f"{key}_table", "step"], [key], axis=0))
        outputs.append(helper.make_tensor_value_info(key, TensorProto.FLOAT, [1, *table.shape[1:]]))
    graph = helper.make_graph(
        nodes,
        name,
        [
            helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, n_obs]),
            helper.make_tensor_value_info("time_step", TensorProto.FLOAT, [1, 1]),
        ],
        outputs,
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="gen_tracking_export")
    model.ir_version = 7
    model.doc_string = "FIXTURE, not a trained policy: scripts/gen_tracking_export.py"
    onnx.checker.check_model(model, full_check=True)
    return model


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=pathlib.Path, required=True)
    ap.add_argument("--broken-quaternion-order", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    robot = tomllib.loads((ROBOT / "robot.toml").read_text())
    joints = {j["mjcf_joint"]: j for j in robot["joints"]}
    model = mujoco.MjModel.from_xml_path(str(ROBOT / robot["mjcf"]))
    # mjlab's joint order: the model's.
    order = [model.joint(i).name for i in range(model.njnt) if model.joint(i).name in joints]
    by = [joints[n] for n in order]
    tables = motion(model, order, [j["default_position"] for j in by])
    meta = {
        "default": [j["default_position"] for j in by],
        # BeyondMimic's rule: a quarter of the effort limit over the stiffness.
        "scale": [0.25 * j["torque_limit"] / j["kp"] for j in by],
    }
    common = {
        "run_path": "fixtures/rd-biped-squat (NOT a trained policy: scripts/gen_tracking_export.py)",
        "joint_names": order,
        "joint_stiffness": [j["kp"] for j in by],
        "joint_damping": [j["kd"] for j in by],
        "default_joint_pos": meta["default"],
        "command_names": ["motion"],
        "action_scale": meta["scale"],
        "anchor_body_name": ANCHOR,
        "body_names": BODIES,
    }
    full = ["command", "motion_anchor_pos_b", "motion_anchor_ori_b", "base_lin_vel", "base_ang_vel",
            "joint_pos", "joint_vel", "actions"]
    wose = [t for t in full if t not in ("motion_anchor_pos_b", "base_lin_vel")]
    hist_terms = ["command", "motion_anchor_ori_b", "base_ang_vel", "joint_pos", "joint_vel", "actions"]
    history = {"joint_pos": 3, "joint_vel": 3, "actions": 3}
    variants = [
        ("rd_biped_tracking", full, {}, {"observation_history_lengths": [1] * len(full)}),
        ("rd_biped_tracking_wose", wose, {}, {"observation_history_lengths": [1] * len(wose)}),
        ("rd_biped_tracking_history", hist_terms, history, {
            "observation_terms_history_length": [history.get(t, 0) for t in hist_terms],
            "observation_terms_scale": [0.05 if t == "joint_vel" else 1.0 for t in hist_terms],
            "observation_terms_clip": [[-100.0, 100.0] if t == "joint_vel" else [float("-inf"), float("inf")]
                                       for t in hist_terms],
        }),
    ]
    if args.broken_quaternion_order:
        broken = {**tables, "body_quat_w": np.roll(tables["body_quat_w"], -1, axis=2)}
        variants.append(("rd_biped_tracking_xyzw", full, {}, variants[0][3], broken))
    for name, terms, hist, extra, *motion_tables in variants:
        m = build(name, motion_tables[0] if motion_tables else tables, meta, terms, hist)
        for key, value in {**common, "observation_names": terms, **extra}.items():
            entry = m.metadata_props.add()
            entry.key, entry.value = key, csv3(value) if isinstance(value, list) else str(value)
        path = args.out / f"{name}.onnx"
        onnx.save(m, path)
        print(f"wrote {path} ({tables['joint_pos'].shape[0]} frames)")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""A plain MuJoCo + ONNX Runtime loop for a robot and a command-driven policy manifest of this
project: what a user would otherwise run, no robodeploy. The floor bench
(`cargo bench -p controller --bench floor`) times robodeploy's mirror against it.

The robot's MJCF (robot.toml `mjcf`) at its own physics step, started from robot.toml's
`start_keyframe` (or the default pose on the floor); the model's position actuators driven with
robot.toml's gains (`kp`, `kd` per joint, as the mirror does), the policy at `control_rate_hz`.
The observation is built from the simulation's state with the manifest's terms and scales; the
terms a command-driven walking policy uses are supported (`base_ang_vel`, `projected_gravity`,
`command`, `joint_pos`, `joint_vel`, `last_actions`, `phase`), any other is refused.

  python plain_loop.py ROBOT.toml MANIFEST.toml --command 0.2 --seconds 20

Prints one JSON object: simulated_s, wall_s (the loop alone), load_s (model, policy), the
distance from the start, and whether the robot fell (base tilted beyond 0.8 rad).
"""

import argparse
import json
import math
import pathlib
import sys
import time
import tomllib

import mujoco
import numpy as np
import onnxruntime as ort

TILT_LIMIT = 0.8
SUPPORTED = {"base_ang_vel", "projected_gravity", "command", "joint_pos", "joint_vel", "last_actions", "phase"}


def projected_gravity(quat):
    """Gravity's direction (0, 0, -1) in the base frame, for a base-to-world quaternion (w, x, y, z)."""
    w, x, y, z = quat
    return np.array([-2.0 * (x * z - w * y), -2.0 * (y * z + w * x), -(1.0 - 2.0 * (x * x + y * y))])


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("robot", type=pathlib.Path)
    p.add_argument("manifest", type=pathlib.Path)
    p.add_argument("--command", type=float, nargs="*", default=[], help="the policy's commands")
    p.add_argument("--seconds", type=float, default=20.0)
    a = p.parse_args()
    if not 0.0 < a.seconds <= 3600.0:
        p.error(f"--seconds {a.seconds}: outside (0, 3600]")

    load_start = time.perf_counter()
    robot = tomllib.loads(a.robot.read_text())
    manifest = tomllib.loads(a.manifest.read_text())
    for term in manifest["observation"]:
        if term["term"] not in SUPPORTED:
            p.error(f"{a.manifest}: observation term {term['term']!r} is not one this loop builds")
    model = mujoco.MjModel.from_xml_path(str(a.robot.parent / robot["mjcf"]))
    data = mujoco.MjData(model)
    joints = {j["name"]: j for j in robot["joints"]}
    order = manifest.get("joints") or [j["name"] for j in robot["joints"]]
    qadr = np.array([model.jnt_qposadr[model.joint(joints[n]["mjcf_joint"]).id] for n in order])
    vadr = np.array([model.jnt_dofadr[model.joint(joints[n]["mjcf_joint"]).id] for n in order])
    default = np.array([joints[n]["default_position"] for n in order])
    # The model's position actuators take robot.toml's gains, as the mirror gives them.
    act = []
    for n in order:
        jid = model.joint(joints[n]["mjcf_joint"]).id
        a_id = next(i for i in range(model.nu) if model.actuator_trnid[i, 0] == jid)
        kp, kd = joints[n]["kp"], joints[n]["kd"]
        model.actuator_gainprm[a_id, 0] = kp
        model.actuator_biasprm[a_id, 1:3] = (-kp, -kd)
        act.append(a_id)
    act = np.array(act)
    if "start_keyframe" in robot:
        mujoco.mj_resetDataKeyframe(model, data, model.key(robot["start_keyframe"]).id)
    else:
        data.qpos[qadr] = default
    mujoco.mj_forward(model, data)
    session = ort.InferenceSession(str(a.manifest.parent / manifest["onnx"]), providers=["CPUExecutionProvider"])
    input_name = session.get_inputs()[0].name
    load_s = time.perf_counter() - load_start

    rate = robot["control_rate_hz"]
    substeps = int(round(1.0 / rate / model.opt.timestep))
    action_cfg = manifest["action"]
    scale, clip = action_cfg.get("scale", 1.0), action_cfg.get("clip", math.inf)
    command = np.array(a.command or [0.0] * len(manifest.get("commands", {}).get("names", [])))
    n = len(order)
    last = np.zeros(n)
    start_xy = data.qpos[0:2].copy()
    ticks = int(round(a.seconds * rate))
    fell = False
    obs = []
    wall_start = time.perf_counter()
    for step in range(ticks):
        obs.clear()
        quat = data.qpos[3:7]
        for term in manifest["observation"]:
            name = term["term"]
            if name == "base_ang_vel":
                v = data.qvel[3:6] * term.get("scale", 1.0)
            elif name == "projected_gravity":
                v = projected_gravity(quat) * term.get("scale", 1.0)
            elif name == "command":
                v = command * np.array(term.get("scales", [1.0] * len(command)))
            elif name == "joint_pos":
                v = (data.qpos[qadr] - (default if term.get("relative") else 0.0)) * term.get("scale", 1.0)
            elif name == "joint_vel":
                v = data.qvel[vadr] * term.get("scale", 1.0)
            elif name == "last_actions":
                v = last * term.get("scale", 1.0)
            else:  # phase
                k = step + int(term.get("advance_first", False))
                period = term["period_ticks"]
                angle = 2.0 * math.pi * ((k % period) / period)
                v = np.array([math.sin(angle), math.cos(angle)] if term.get("sin_first") else [math.cos(angle), math.sin(angle)])
            obs.append(v)
        x = np.concatenate(obs).astype(np.float32)[None, :]
        action = session.run(None, {input_name: x})[0][0].astype(np.float64)
        last = np.clip(action, -clip, clip)
        data.ctrl[act] = default + scale * last
        for _ in range(substeps):
            mujoco.mj_step(model, data)
        w, qx, qy, _ = data.qpos[3:7]
        if math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (qx * qx + qy * qy)))) > TILT_LIMIT:
            fell = True
            break
    wall = time.perf_counter() - wall_start
    print(json.dumps({
        "simulated_s": (step + 1) / rate,
        "wall_s": wall,
        "load_s": load_s,
        "distance_m": float(np.linalg.norm(data.qpos[0:2] - start_xy)),
        "fell": fell,
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())

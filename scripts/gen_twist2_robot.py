#!/usr/bin/env python3
"""Writes robots/g1-twist2/robot.toml: the Unitree G1 as TWIST2's authors run their trained general
tracker on it (TWIST2, MIT licence, read in place from ../shared/third_party/twist2/, never
committed; scripts/setup links it as .local/twist2).

Facts, not files, carry over: the joint order, default pose, PD gains and torque limits of the
material's README (its table, below, as the authors' loop applies them); each joint's range and its
motor's torque range (`actuatorfrcrange`) read from the authors' model; the motor index on the G1's
board, the motor class and its speed limit from robots/g1/robot.toml (Unitree's motors, the same
robot). The torque limit is the smaller of the README's clip and the motor's range, which the
authors' MuJoCo applies on top of their clip. Run: .local/venv/bin/python scripts/gen_twist2_robot.py
(the output is committed; a test checks it matches).
"""

import argparse
import json
import pathlib
import tomllib

import mujoco

ROOT = pathlib.Path(__file__).resolve().parent.parent
TWIST2 = ROOT / ".local/twist2"
MODEL = "g1/g1_sim2sim_29dof.xml"

# The README's table, per joint in its order: legs (left, then right), waist, arms (left, right).
LEG = {"default": [-0.2, 0, 0, 0.4, -0.2, 0], "kp": [100, 100, 100, 150, 40, 40],
       "kd": [2, 2, 2, 4, 2, 2], "limit": [100, 100, 100, 150, 40, 40]}
WAIST = {"default": [0, 0, 0], "kp": [150] * 3, "kd": [4] * 3, "limit": [150] * 3}
ARM = {"default": [0, 0.4, 0, 1.2, 0, 0, 0], "kp": [40, 40, 40, 40, 4, 4, 4],
       "kd": [5, 5, 5, 5, 0.2, 0.2, 0.2], "limit": [40, 40, 40, 40, 4, 4, 4]}
LEG_JOINTS = ["hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll"]
ARM_JOINTS = ["shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll", "wrist_pitch", "wrist_yaw"]


def table():
    """(joint name, default, kp, kd, torque clip) in TWIST2's order."""
    rows = []
    for side in ("left", "right"):
        rows += [(f"{side}_{j}_joint", *(LEG[k][i] for k in ("default", "kp", "kd", "limit")))
                 for i, j in enumerate(LEG_JOINTS)]
    rows += [(f"waist_{j}_joint", *(WAIST[k][i] for k in ("default", "kp", "kd", "limit")))
             for i, j in enumerate(["yaw", "roll", "pitch"])]
    for side, sign in (("left", 1), ("right", -1)):
        for i, j in enumerate(ARM_JOINTS):
            d = ARM["default"][i] * (sign if j == "shoulder_roll" else 1)
            rows.append((f"{side}_{j}_joint", d, ARM["kp"][i], ARM["kd"][i], ARM["limit"][i]))
    return rows


def fmt(x):
    return repr(round(float(x), 6))


# How human motion maps onto this G1 (`robodeploy retarget`, written into robot.toml as is).
RETARGET = """
# How human motion maps onto the G1 (`robodeploy retarget`): GMR's recipe for this robot, as the
# motions TWIST2 was trained on were made (facts of GMR's published BVH-to-G1 table: which body
# follows which, the posture stage's orientations and the feet, then positions; arms scaled to
# 0.83 of the legs). Rest-pose alignment is measured from the nominal frame, not tabulated.
[retarget]
# The G1 matching a human T-pose: arms straight out to the sides.
tpose = { left_shoulder_roll_joint = 1.5708, right_shoulder_roll_joint = -1.5708, left_elbow_joint = 1.5708, right_elbow_joint = 1.5708 }

[[retarget.pairs]]
human = "root"
frame = "pelvis"
position_weight = 100.0
orientation_weight = 5.0
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "chest"
frame = "torso_link"
orientation_weight = 10.0
posture = { orientation_weight = 100.0 }

[[retarget.pairs]]
human = "left_hip"
frame = "left_hip_yaw_link"
position_weight = 10.0
orientation_weight = 5.0
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "right_hip"
frame = "right_hip_yaw_link"
position_weight = 10.0
orientation_weight = 5.0
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "left_knee"
frame = "left_knee_link"
position_weight = 10.0
orientation_weight = 5.0
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "right_knee"
frame = "right_knee_link"
position_weight = 10.0
orientation_weight = 5.0
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "left_foot"
frame = "left_ankle_roll_link"
position_weight = 50.0
orientation_weight = 10.0
posture = { position_weight = 50.0, orientation_weight = 10.0 }

[[retarget.pairs]]
human = "right_foot"
frame = "right_ankle_roll_link"
position_weight = 50.0
orientation_weight = 10.0
posture = { position_weight = 50.0, orientation_weight = 10.0 }

[[retarget.pairs]]
human = "left_shoulder"
frame = "left_shoulder_yaw_link"
position_weight = 5.0
orientation_weight = 100.0
scale = 0.83
posture = { orientation_weight = 100.0 }

[[retarget.pairs]]
human = "right_shoulder"
frame = "right_shoulder_yaw_link"
position_weight = 5.0
orientation_weight = 100.0
scale = 0.83
posture = { orientation_weight = 100.0 }

[[retarget.pairs]]
human = "left_elbow"
frame = "left_elbow_link"
position_weight = 10.0
orientation_weight = 5.0
scale = 0.83
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "right_elbow"
frame = "right_elbow_link"
position_weight = 10.0
orientation_weight = 5.0
scale = 0.83
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "left_hand"
frame = "left_wrist_yaw_link"
position_weight = 10.0
orientation_weight = 5.0
scale = 0.83
posture = { orientation_weight = 10.0 }

[[retarget.pairs]]
human = "right_hand"
frame = "right_wrist_yaw_link"
position_weight = 10.0
orientation_weight = 5.0
scale = 0.83
posture = { orientation_weight = 10.0 }
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "robots/g1-twist2/robot.toml")
    args = ap.parse_args()
    model = mujoco.MjModel.from_xml_path(str(TWIST2 / MODEL))
    g1 = tomllib.loads((ROOT / "robots/g1/robot.toml").read_text())
    g1_joints = {j["name"]: j for j in g1["joints"]}
    lines = [
        "# Unitree G1, 29 DoF, as TWIST2's authors run their trained general tracker on it (TWIST2, MIT",
        "# licence, (c) 2025 Yanjie Ze; read in place from ../shared/third_party/twist2/, linked by",
        "# scripts/setup as .local/twist2, never committed).",
        "# WRITTEN BY scripts/gen_twist2_robot.py: default pose, PD gains and torque clips from the",
        "# material's README (the authors' loop); joint ranges and motor torque ranges from their model",
        "# (g1_sim2sim_29dof.xml: 1 ms step, PGS); motor indices, classes and speed limits from",
        "# robots/g1/robot.toml (the same robot's board).",
        "#",
        "# The policy follows any retargeted motion frame by frame (policies/twist2.toml); it is in",
        "# control from its first tick with the robot standing at the default pose on the floor.",
        'name = "g1-twist2"',
        f'mjcf = "../../.local/twist2/{MODEL}"',
        'root_body = "pelvis"',
        'feet = ["left_ankle_roll_link", "right_ankle_roll_link"]',
        "control_rate_hz = 50.0",
        "# The policy a run takes without --policy.",
        'policy = "policies/twist2.toml"',
        "",
        "# The IMU the board reports; the model has no accelerometer, the mirror adds one at the site.",
        "[imu]",
        'bus = "lowlevel"',
        'site = "imu_in_pelvis"',
        "rate_hz = 500.0",
        "mounting_rpy_deg = [0.0, 0.0, 0.0]",
        "",
        "# The authors start the policy on the floor: root at 0.793 m, the default pose, no harness.",
        "[start]",
        'mode = "policy"',
        "",
        "# Walking clips cross their joints' targets by up to ~0.5 rad for a few ticks while tracking.",
        "[safety]",
        'position_targets = "torque_reach"',
        "tracking_error = 0.8",
        "tracking_s = 1.0",
        "",
        "# The trainer's actuator: the authors compute the PD torque from the newest targets every",
        "# physics step, clipped to each joint's limit.",
        "[[actuators]]",
        'joints = ["*"]',
        'model = "explicit_pd"',
        "",
    ]
    used = []
    for name, *_ in table():
        m = g1_joints[name]["model"]
        if m not in used:
            used.append(m)
    for mm in g1["mit_models"]:
        if mm["name"] in used:
            lines += ["[[mit_models]]"] + [
                f"{k} = {json.dumps(v)}" if isinstance(v, str) else
                f"{k} = [{fmt(v[0])}, {fmt(v[1])}]" if isinstance(v, list) else f"{k} = {fmt(v)}"
                for k, v in mm.items()
            ] + [""]
    bus = next(b for b in g1["buses"] if b["name"] == "lowlevel")
    lines += ["[[buses]]"] + [
        f"{k} = {json.dumps(v)}" if isinstance(v, str) else f"{k} = {v}" for k, v in bus.items()
    ] + [""]
    for name, default, kp, kd, clip in table():
        j = g1_joints[name]
        jid = model.joint(name).id
        lo, hi = model.jnt_range[jid]
        frc = model.jnt_actfrcrange[jid][1] if model.jnt_actfrclimited[jid] else float("inf")
        lines += [
            "[[joints]]",
            f'name = "{name}"',
            f'mjcf_joint = "{name}"',
            'bus = "lowlevel"',
            f"id = {j['id']}",
            f'model = "{j["model"]}"',
            "direction = 1.0",
            "zero_offset = 0.0",
            "gear = 1.0",
            f"position_limits = [{fmt(lo)}, {fmt(hi)}]",
            f"velocity_limit = {fmt(j['velocity_limit'])}",
            f"torque_limit = {fmt(min(clip, frc))}",
            f"default_position = {fmt(default)}",
            f"kp = {fmt(kp)}",
            f"kd = {fmt(kd)}",
            "",
        ]
    lines += RETARGET.splitlines()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines).rstrip() + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Writes robots/g1/robot.toml for holosoma's Unitree G1 (29 DoF) from the pinned holosoma packages
that scripts/setup installs (.local/holosoma, .local/holosoma-inference).

Every figure is read, not typed: joint order, stiffness and damping from the trained policy's ONNX
metadata (`dof_names`, `kp`, `kd`); position, velocity and effort limits and the standing pose from the
whole-body-tracking export's training configuration (`experiment_config`: robot.dof_*_limit_list,
robot.init_state.default_joint_angles). The model file itself stays in the installed package; the
robot.toml points at it through .local/holosoma.

The G1's motors are not on a bus the host drives (its own board runs them over DDS); until robodeploy
has that link, the file puts them on five MIT-mode CAN buses with one motor model per G1 actuator
class, whose ranges are the G1's effort and speed limits. Run: .local/venv/bin/python
scripts/gen_holosoma_robots.py (the output is committed; a test checks it matches).
"""

import argparse
import json
import pathlib

import mujoco
import onnx

ROOT = pathlib.Path(__file__).resolve().parent.parent
INFERENCE = ROOT / ".local/holosoma-inference"
DANCE = INFERENCE / "models/wbt/ppo_g1_29dof_dancing.onnx"
G1_SCENE = "data/robots/g1/scenes/scene_g1_29dof_wbt_plane.xml"

# Buses: each leg, the waist, each arm at 1 Mbit/s, all cycling at 500 Hz (seven motors: 1.9 ms
# of wire in a 2 ms period) rather than the default 250 Hz: a humanoid's balance feels every
# millisecond between a measurement and the command that answers it. On the mirror holosoma's
# dance fell in 1 of 7 seeded runs at 250 Hz, in 1 of 3 with only the arms at 250 Hz, and in none
# of 10 at 500 Hz.
BUSES = [
    ("can0", "left leg", 500, lambda n: n.startswith("left_") and any(k in n for k in ("hip", "knee", "ankle"))),
    ("can1", "right leg", 500, lambda n: n.startswith("right_") and any(k in n for k in ("hip", "knee", "ankle"))),
    ("can2", "waist", 500, lambda n: n.startswith("waist")),
    ("can3", "left arm", 500, lambda n: n.startswith("left_")),
    ("can4", "right arm", 500, lambda n: n.startswith("right_")),
]


def metadata(path):
    m = onnx.load(str(path), load_external_data=False)
    return {p.key: p.value for p in m.metadata_props}


def fmt(x):
    return repr(float(x))


def motor_name(effort, velocity):
    return f"G1-{effort:g}Nm-{velocity:g}rads"


def g1(out):
    meta = metadata(DANCE)
    names = json.loads(meta["dof_names"])
    kp = json.loads(meta["kp"])
    kd = json.loads(meta["kd"])
    robot = json.loads(meta["experiment_config"])["robot"]
    assert robot["dof_names"] == names, "the export's joint order differs from its configuration's"
    lower, upper = robot["dof_pos_lower_limit_list"], robot["dof_pos_upper_limit_list"]
    velocity, effort = robot["dof_vel_limit_list"], robot["dof_effort_limit_list"]
    default = robot["init_state"]["default_joint_angles"]
    # The configuration's limits, inside the model's joint ranges (they differ in the last digits).
    model = mujoco.MjModel.from_xml_path(str(ROOT / ".local/holosoma" / G1_SCENE))
    for i, n in enumerate(names):
        lo, hi = model.jnt_range[model.joint(n).id]
        lower[i], upper[i] = max(lower[i], float(lo)), min(upper[i], float(hi))

    motors = sorted({(e, v) for e, v in zip(effort, velocity)})
    lines = [
        "# Unitree G1, 29 DoF, as holosoma trained its policies on it (holosoma==0.0.3, Apache-2.0).",
        "# WRITTEN BY scripts/gen_holosoma_robots.py from the installed packages: joint order, kp and kd",
        "# from the trained policies' ONNX metadata; limits and the standing pose from the dance export's",
        "# training configuration. The MJCF (scene with floor, 2 ms step, armature per joint) stays in",
        "# the installed package: run scripts/setup first.",
        "#",
        "# Buses: the real G1's motors are driven by its own board over DDS (Unitree's low-level link, not",
        "# yet in robodeploy); here they sit on five MIT-mode CAN buses, one motor model per G1 actuator",
        "# class with the G1's effort and speed limits as its ranges.",
        'name = "g1"',
        f'mjcf = "../../.local/holosoma/{G1_SCENE}"',
        'root_body = "pelvis"',
        'feet = ["left_ankle_roll_link", "right_ankle_roll_link"]',
        "control_rate_hz = 50.0",
        "",
        "[imu]",
        'bus = "imu0"',
        'site = "imu_in_pelvis"',
        'gyro = "base_gyro"',
        'accelerometer = "base_accel"',
        'orientation = "base_quat"',
        "rate_hz = 200.0",
        "mounting_rpy_deg = [0.0, 0.0, 0.0]",
        "",
        "# A humanoid does not stand on its joints' PD alone: the policy takes it from the first tick,",
        "# hanging in a harness that lowers it onto its feet.",
        "[start]",
        'mode = "harness"',
        "",
        "[start.harness]",
        "lift_m = 0.03",
        "lower_s = 2.0",
        "settle_s = 1.0",
        "",
        "# Trained with targets unclipped, the policies press ankles and waist against their limits on",
        "# purpose. Tracking-error stop: three times the longest excursion of a good run of holosoma's",
        "# dance (legs and waist 17 ticks beyond 0.8 rad, arms 13 ticks beyond 0.6 rad).",
        "[safety]",
        'position_targets = "torque_reach"',
        "tracking_error = 0.6",
        "tracking_s = 0.8",
        "",
        "[[safety.tracking]]",
        'joints = ["*hip*", "*knee*", "*ankle*", "waist_*"]',
        "error = 0.8",
        "seconds = 1.0",
        "",
    ]
    for effort_nm, speed in motors:
        lines += [
            "[[mit_models]]",
            f'name = "{motor_name(effort_nm, speed)}"',
            'reply = "damiao"',
            "position = [-12.5, 12.5]",
            f"velocity = [-{fmt(speed)}, {fmt(speed)}]",
            f"torque = [-{fmt(effort_nm)}, {fmt(effort_nm)}]",
            "kp = [0.0, 500.0]",
            "kd = [0.0, 10.0]",
            f"rated_torque = {fmt(effort_nm / 2)}",
            "",
        ]
    for bus, what, rate_hz, _ in BUSES:
        lines += [
            "[[buses]]",
            f'name = "{bus}"          # {what}',
            'kind = "mit_can"',
            f'device = "{bus}"',
            "rate = 1000000",
        ]
        if rate_hz:
            lines.append(f"rate_hz = {rate_hz:.1f}")
            # Ten periods would be 20 ms: a host without a real-time kernel stalls that long now
            # and then, and the motors would drop torque mid-stride.
            lines.append("command_timeout_ms = 50.0")
        lines.append("")
    lines += [
        "[[buses]]",
        'name = "imu0"',
        'kind = "imu_serial"',
        'device = "/dev/ttyUSB0"',
        "rate = 921600",
        "",
    ]
    ids = {b: 0 for b, _, _, _ in BUSES}
    for i, n in enumerate(names):
        bus = next(b for b, _, _, test in BUSES if test(n))
        ids[bus] += 1
        lines += [
            "[[joints]]",
            f'name = "{n}"',
            f'mjcf_joint = "{n}"',
            f'bus = "{bus}"',
            f"id = {ids[bus]}",
            f'model = "{motor_name(effort[i], velocity[i])}"',
            "direction = 1.0",
            "zero_offset = 0.0",
            "gear = 1.0",
            f"position_limits = [{fmt(lower[i])}, {fmt(upper[i])}]",
            f"velocity_limit = {fmt(velocity[i])}",
            f"torque_limit = {fmt(effort[i])}",
            f"default_position = {fmt(default[n])}",
            f"kp = {fmt(kp[i])}",
            f"kd = {fmt(kd[i])}",
            "",
        ]
    out.write_text("\n".join(lines))
    print(f"wrote {out} ({len(names)} joints)")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=pathlib.Path, default=ROOT / "robots/g1/robot.toml")
    a = p.parse_args()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    g1(a.out)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Writes robots/g1/robot.toml and robots/t1/robot.toml for holosoma's Unitree G1 and Booster T1
(29 DoF each) from the pinned holosoma packages that scripts/setup installs (.local/holosoma,
.local/holosoma-inference).

Every figure is read, not typed: joint order, stiffness and damping from the trained policies' ONNX
metadata (`dof_names`, `kp`, `kd`); position, velocity and effort limits from the training
configuration (the G1 dance export's `experiment_config`; holosoma's config_values/robot.py for the
T1, parsed as data, not run), inside the model's joint ranges; the standing pose from the same
configuration (the G1) or holosoma-inference's deployment config (the T1). The model files stay in
the installed package; a robot.toml points at them through .local/holosoma (the T1 through the
project's scene, robots/t1/scene.xml, which adds the floor holosoma's file lacks).

Neither robot's motors are on a bus the host drives: their own boards run them. The G1's board is
reached over Unitree's low-level DDS link (a `unitree_dds` bus, each joint at the motor index
holosoma-inference's deployment configuration maps it to); the T1's link is not in robodeploy, so its
file puts the motors on five MIT-mode CAN buses. Either way one motor model per actuator class
carries the robot's effort and speed limits as its ranges. Run: .local/venv/bin/python
scripts/gen_holosoma_robots.py (the output is committed; a test checks it matches).
"""

import argparse
import ast
import json
import pathlib

import mujoco
import onnx

ROOT = pathlib.Path(__file__).resolve().parent.parent
HOLOSOMA = ROOT / ".local/holosoma"
INFERENCE = ROOT / ".local/holosoma-inference"


def metadata(path):
    m = onnx.load(str(path), load_external_data=False)
    return {p.key: p.value for p in m.metadata_props}


def robot_config(path, variable, keys):
    """Literal fields of the RobotConfig the Python file `path` assigns to `variable` (parsed, not
    run: holosoma's code needs torch, its configuration is data)."""
    tree = ast.parse(path.read_text())
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == variable for t in node.targets)
            and isinstance(node.value, ast.Call)
        ):
            found = {k.arg: k.value for k in node.value.keywords}
            return {k: literal(found[k]) for k in keys}
    raise SystemExit(f"no robot config {variable} in {path}")


def literal(node):
    """A literal, or `tuple(range(n))` (how holosoma writes an identity mapping)."""
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "tuple"
            and len(node.args) == 1 and isinstance(node.args[0], ast.Call)
            and isinstance(node.args[0].func, ast.Name) and node.args[0].func.id == "range"):
        return tuple(range(*(ast.literal_eval(a) for a in node.args[0].args)))
    return ast.literal_eval(node)


def fmt(x):
    return repr(float(x))


def g1_facts():
    meta = metadata(INFERENCE / "models/wbt/ppo_g1_29dof_dancing.onnx")
    names = json.loads(meta["dof_names"])
    robot = json.loads(meta["experiment_config"])["robot"]
    assert robot["dof_names"] == names, "the export's joint order differs from its configuration's"
    default = robot["init_state"]["default_joint_angles"]
    deployed = robot_config(INFERENCE / "config/config_values/robot.py", "g1_29dof",
                            ["dof_names", "joint2motor", "message_type"])
    assert list(deployed["dof_names"]) == names and deployed["message_type"] == "HG"
    return {
        "key": "g1",
        "title": "Unitree G1, 29 DoF",
        "source": ["joint order, kp and kd from the trained policies' ONNX metadata; limits and the",
                   "standing pose from the dance export's training configuration."],
        "mjcf": "../../.local/holosoma/data/robots/g1/scenes/scene_g1_29dof_wbt_plane.xml",
        "root": "pelvis",
        "feet": ["left_ankle_roll_link", "right_ankle_roll_link"],
        "imu": ("imu_in_pelvis", "base_gyro", "base_accel", "base_quat"),
        "names": names,
        "kp": json.loads(meta["kp"]),
        "kd": json.loads(meta["kd"]),
        "lower": robot["dof_pos_lower_limit_list"],
        "upper": robot["dof_pos_upper_limit_list"],
        "velocity": robot["dof_vel_limit_list"],
        "effort": robot["dof_effort_limit_list"],
        "default": [default[n] for n in names],
        "buses": [
            ("can0", "left leg", lambda n: n.startswith("left_") and any(k in n for k in ("hip", "knee", "ankle"))),
            ("can1", "right leg", lambda n: n.startswith("right_") and any(k in n for k in ("hip", "knee", "ankle"))),
            ("can2", "waist", lambda n: n.startswith("waist")),
            ("can3", "left arm", lambda n: n.startswith("left_")),
            ("can4", "right arm", lambda n: n.startswith("right_")),
        ],
        "legs_and_waist": ["*hip*", "*knee*", "*ankle*", "waist_*"],
        # Unitree's low-level link: each joint's motor index in LowCmd/LowState.
        "unitree_hg": list(deployed["joint2motor"]),
    }


def t1_facts():
    meta = metadata(INFERENCE / "models/loco/t1_29dof/ppo_t1_29dof.onnx")
    names = json.loads(meta["dof_names"])
    limits = robot_config(
        HOLOSOMA / "config_values/robot.py",
        "t1_29dof_waist_wrist",
        ["dof_names", "dof_pos_lower_limit_list", "dof_pos_upper_limit_list", "dof_vel_limit_list",
         "dof_effort_limit_list"],
    )
    deployed = robot_config(
        INFERENCE / "config/config_values/robot.py", "t1_29dof", ["dof_names", "default_dof_angles"]
    )
    assert list(limits["dof_names"]) == names and list(deployed["dof_names"]) == names
    return {
        "key": "t1",
        "title": "Booster T1, 29 DoF",
        "source": ["joint order, kp and kd from the trained locomotion policies' ONNX metadata; limits",
                   "from holosoma's training configuration (config_values/robot.py, t1_29dof_waist_wrist); the",
                   "standing pose from holosoma-inference's deployment configuration (t1_29dof)."],
        "mjcf": "scene.xml",
        "root": "Trunk",
        "feet": ["left_foot_link", "right_foot_link"],
        "imu": ("imu", "angular-velocity", "base_accel", "base_quat"),
        "names": names,
        "kp": json.loads(meta["kp"]),
        "kd": json.loads(meta["kd"]),
        "lower": list(limits["dof_pos_lower_limit_list"]),
        "upper": list(limits["dof_pos_upper_limit_list"]),
        "velocity": list(limits["dof_vel_limit_list"]),
        "effort": list(limits["dof_effort_limit_list"]),
        "default": list(deployed["default_dof_angles"]),
        "buses": [
            ("can0", "left leg", lambda n: n.startswith("Left_") and any(k in n for k in ("Hip", "Knee", "Ankle"))),
            ("can1", "right leg", lambda n: n.startswith("Right_") and any(k in n for k in ("Hip", "Knee", "Ankle"))),
            ("can2", "waist and head", lambda n: n == "Waist" or "Head" in n),
            ("can3", "left arm", lambda n: n.startswith("Left_")),
            ("can4", "right arm", lambda n: n.startswith("Right_")),
        ],
        "legs_and_waist": ["*Hip*", "*Knee*", "*Ankle*", "Waist"],
    }


def write(facts, out):
    names, lower, upper = facts["names"], list(facts["lower"]), list(facts["upper"])
    velocity, effort = facts["velocity"], facts["effort"]
    # The configuration's limits, inside the model's joint ranges (they differ in the last digits).
    model = mujoco.MjModel.from_xml_path(str(ROOT / "robots" / facts["key"] / facts["mjcf"]))
    for i, n in enumerate(names):
        lo, hi = model.jnt_range[model.joint(n).id]
        lower[i], upper[i] = max(lower[i], float(lo)), min(upper[i], float(hi))
    prefix = facts["key"].upper()

    def motor(e, v):
        return f"{prefix}-{e:g}Nm-{v:g}rads"

    site, gyro, accel, orientation = facts["imu"]
    unitree = facts.get("unitree_hg")
    if unitree:
        about_buses = [
            "# Link: the robot's own board runs its motors; robodeploy reaches it over Unitree's low-level",
            "# DDS link (rt/lowcmd, rt/lowstate, unitree_hg messages with their CRC) at the board's 500 Hz,",
            "# each joint at the motor index holosoma-inference's deployment maps it to, the IMU read from",
            "# the board's state. Set `device` to the host's interface on the robot's network. The motors'",
            "# ranges are MIT-law tables (the board runs the same impedance law; `reply` is not used here).",
        ]
        imu_bus, imu_rate = "lowlevel", "500.0"
    else:
        about_buses = [
            "# Buses: the robot's own board drives its motors (the vendor's low-level link, not yet in",
            "# robodeploy); here they sit on five MIT-mode CAN buses, one motor model per actuator class with",
            "# the robot's effort and speed limits as its ranges, all cycling at 500 Hz (seven motors: 1.9 ms",
            "# of wire in a 2 ms period) rather than the default 250 Hz: a humanoid's balance feels every",
            "# millisecond between a measurement and the command that answers it. On the mirror holosoma's G1",
            "# dance fell in 1 of 7 seeded runs at 250 Hz, in 1 of 3 with only the arms at 250 Hz, and in none",
            "# of 10 at 500 Hz.",
        ]
        imu_bus, imu_rate = "imu0", "200.0"
    lines = [
        f"# {facts['title']}, as holosoma trained its policies on it (holosoma==0.0.3, Apache-2.0).",
        "# WRITTEN BY scripts/gen_holosoma_robots.py from the installed packages:",
        *(f"# {line}" for line in facts["source"]),
        "# The model files stay in the installed package: run scripts/setup first.",
        "#",
        *about_buses,
        f'name = "{facts["key"]}"',
        f'mjcf = "{facts["mjcf"]}"',
        f'root_body = "{facts["root"]}"',
        f'feet = ["{facts["feet"][0]}", "{facts["feet"][1]}"]',
        "control_rate_hz = 50.0",
        "# The policy a run takes without --policy.",
        'policy = "policies/holosoma_loco_ppo.toml"',
        "",
        "[imu]",
        f'bus = "{imu_bus}"',
        f'site = "{site}"',
        f'gyro = "{gyro}"',
        f'accelerometer = "{accel}"',
        f'orientation = "{orientation}"',
        f"rate_hz = {imu_rate}",
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
        "# purpose. Tracking-error stop: three times the longest excursion of a good run of holosoma's G1",
        "# dance (legs and waist 17 ticks beyond 0.8 rad, arms 13 ticks beyond 0.6 rad).",
        "[safety]",
        'position_targets = "torque_reach"',
        "tracking_error = 0.6",
        "tracking_s = 0.8",
        "",
        "[[safety.tracking]]",
        "joints = [" + ", ".join(f'"{p}"' for p in facts["legs_and_waist"]) + "]",
        "error = 0.8",
        "seconds = 1.0",
        "",
        "# The trainer's actuator: holosoma's MuJoCo loop computes the PD torque from the newest",
        "# targets every physics step, clipped to the effort limits (the motors' torque ranges below).",
        "[[actuators]]",
        'joints = ["*"]',
        'model = "explicit_pd"',
        "",
    ]
    for e, v in sorted({(e, v) for e, v in zip(effort, velocity)}):
        lines += [
            "[[mit_models]]",
            f'name = "{motor(e, v)}"',
            'reply = "damiao"',
            "position = [-12.5, 12.5]",
            f"velocity = [-{fmt(v)}, {fmt(v)}]",
            f"torque = [-{fmt(e)}, {fmt(e)}]",
            "kp = [0.0, 500.0]",
            "kd = [0.0, 10.0]",
            f"rated_torque = {fmt(e / 2)}",
            "",
        ]
    if unitree:
        lines += [
            "[[buses]]",
            'name = "lowlevel"',
            'kind = "unitree_dds"',
            'device = "eth0"',
            "# Gigabit Ethernet.",
            "rate = 1000000000",
            "rate_hz = 500.0",
            # As on the CAN buses: a host without a real-time kernel stalls 20 ms now and then.
            "command_timeout_ms = 50.0",
            "domain = 0",
            'family = "unitree_hg"',
            "",
        ]
    for bus, what, _ in [] if unitree else facts["buses"]:
        lines += [
            "[[buses]]",
            f'name = "{bus}"          # {what}',
            'kind = "mit_can"',
            f'device = "{bus}"',
            "rate = 1000000",
            "rate_hz = 500.0",
            # Ten periods would be 20 ms: a host without a real-time kernel stalls that long now and
            # then, and the motors would drop torque mid-stride.
            "command_timeout_ms = 50.0",
            "",
        ]
    if not unitree:
        lines += [
            "[[buses]]",
            'name = "imu0"',
            'kind = "imu_serial"',
            'device = "/dev/ttyUSB0"',
            "rate = 921600",
            "",
        ]
    ids = {b: 0 for b, _, _ in facts["buses"]}
    for i, n in enumerate(names):
        if unitree:
            bus, motor_id = "lowlevel", unitree[i]
        else:
            bus = next(b for b, _, test in facts["buses"] if test(n))
            ids[bus] += 1
            motor_id = ids[bus]
        lines += [
            "[[joints]]",
            f'name = "{n}"',
            f'mjcf_joint = "{n}"',
            f'bus = "{bus}"',
            f"id = {motor_id}",
            f'model = "{motor(effort[i], velocity[i])}"',
            "direction = 1.0",
            "zero_offset = 0.0",
            "gear = 1.0",
            f"position_limits = [{fmt(lower[i])}, {fmt(upper[i])}]",
            f"velocity_limit = {fmt(velocity[i])}",
            f"torque_limit = {fmt(effort[i])}",
            f"default_position = {fmt(facts['default'][i])}",
            f"kp = {fmt(facts['kp'][i])}",
            f"kd = {fmt(facts['kd'][i])}",
            "",
        ]
    out.write_text("\n".join(lines))
    print(f"wrote {out} ({len(names)} joints)")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=pathlib.Path, default=ROOT / "robots",
                   help="folder holding g1/ and t1/ (default: the repository's robots/)")
    a = p.parse_args()
    for facts in (g1_facts(), t1_facts()):
        folder = a.out / facts["key"]
        folder.mkdir(parents=True, exist_ok=True)
        write(facts, folder / "robot.toml")


if __name__ == "__main__":
    main()

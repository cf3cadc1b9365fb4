#!/usr/bin/env python3
"""The project's own reference loop for holosoma's trained policies: plain MuJoCo, no robodeploy.

Written here from holosoma's documented configuration (facts only; none of its code): the policy at
50 Hz, four physics steps of 5 ms per policy step, PD torques every physics step with the export's kp
and kd, clipped to the configuration's effort limits; the observation's terms sorted by name; the
whole-body-tracking export called with the frame this tick plays, its motion outputs observed on the
next tick. The tests compare robodeploy's runs on its mirror against what this loop measures.

  python holosoma_reference.py dance --robot-dir .local/holosoma --policy-dir .local/holosoma-inference
        [--frames N] [--hold S]
  python holosoma_reference.py walk --robot g1|t1 --robot-dir … --policy-dir … [--vx 0.5]
        [--stand 1] [--walk 10] [--rest 6]

With `--trace PATH` either loop writes the observation the policy saw at every step as CSV (a
header naming each value, then one row per step), the trainer-side trace `robodeploy compare
RUN.mcap PATH` reads term by term.

dance prints one JSON object: frames played, joint RMSE (rad), anchor position RMSE (m), whether the
robot fell (base tilted beyond 0.8 rad), its lowest base height, and the wall time of the loop. walk
runs the velocity-command policy (its commands ramped at 1 per second, the two-leg gait phase held
at π while they rest) and prints the displacement, forward distance and heading change over the
run, the standing and lowest base heights, and whether it fell.
"""

import argparse
import json
import math
import pathlib
import sys
import time

import mujoco
import numpy as np
import onnx
import onnxruntime as ort

POLICY_DT = 0.02
PHYSICS_DT = 0.005
TILT_LIMIT = 0.8


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def quat_conj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_of_yaw(yaw):
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def yaw_of(q):
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def rotate(q, v):
    return quat_mul(quat_mul(q, np.array([0.0, *v])), quat_conj(q))[1:]


def matrix(q):
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, dtype=float))
    return m.reshape(3, 3)


def tilt(q):
    up = rotate(q, [0.0, 0.0, 1.0])
    return math.acos(max(-1.0, min(1.0, up[2])))


def metadata(path):
    return {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}


def pd_steps(model, data, index, gains, target):
    """One policy step of physics: the trainer's PD torques, clipped to the effort limits, recomputed
    every physics step. `index` is (qpos, qvel, actuator) per joint, `gains` (kp, kd, effort)."""
    qadr, vadr, act = index
    kp, kd, effort = gains
    for _ in range(int(round(POLICY_DT / model.opt.timestep))):
        q, qd = data.qpos[qadr], data.qvel[vadr]
        data.ctrl[act] = np.clip(kp * (target - q) - kd * qd, -effort, effort)
        mujoco.mj_step(model, data)


def place_on_floor(model, data, root_qpos):
    """Moves the root so the lowest collision geometry touches the floor."""
    mujoco.mj_forward(model, data)
    lowest = math.inf
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0 or model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
            continue
        c = data.geom_xpos[g]
        r = model.geom_size[g]
        axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
        t = model.geom_type[g]
        if t == mujoco.mjtGeom.mjGEOM_CAPSULE:
            z = c[2] - r[0] - r[1] * abs(axis[2])
        elif t == mujoco.mjtGeom.mjGEOM_SPHERE:
            z = c[2] - r[0]
        else:
            z = c[2] - float(np.linalg.norm(r))
        lowest = min(lowest, z)
    data.qpos[root_qpos + 2] -= lowest
    mujoco.mj_forward(model, data)


class Trace:
    """The observations a loop fed its policy, one CSV row per step (nothing without a path)."""

    def __init__(self, path):
        self.file = open(path, "w", encoding="utf-8") if path else None
        self.header = False

    def write(self, names_and_parts):
        if not self.file:
            return
        if not self.header:
            names = [f"{n}[{i}]" for n, v in names_and_parts for i in range(len(np.ravel(v)))]
            self.file.write(",".join(names) + "\n")
            self.header = True
        values = np.concatenate([np.ravel(v) for _, v in names_and_parts]).astype(np.float32)
        self.file.write(",".join(repr(float(x)) for x in values) + "\n")

    def close(self):
        if self.file:
            self.file.close()


def dance(a):
    trace = Trace(a.trace)
    export = a.policy_dir / "models/wbt/ppo_g1_29dof_dancing.onnx"
    scene = a.robot_dir / "data/robots/g1/scenes/scene_g1_29dof_wbt_plane.xml"
    meta = metadata(export)
    names = json.loads(meta["dof_names"])
    kp = np.array(json.loads(meta["kp"]))
    kd = np.array(json.loads(meta["kd"]))
    cfg = json.loads(meta["experiment_config"])
    robot = cfg["robot"]
    effort = np.array(robot["dof_effort_limit_list"])
    default = np.array([robot["init_state"]["default_joint_angles"][n] for n in names])
    control = robot["control"]
    scale = control["action_scale"] * effort / kp
    clip = control["action_clip_value"]
    anchor = cfg["command"]["setup_terms"]["motion_command"]["params"]["motion_config"]["body_name_ref"][0]
    terms = sorted(cfg["observation"]["groups"]["actor_obs"]["terms"])

    model = mujoco.MjModel.from_xml_path(str(scene))
    model.opt.timestep = a.physics_dt
    data = mujoco.MjData(model)
    qadr = np.array([model.jnt_qposadr[model.joint(n).id] for n in names])
    vadr = np.array([model.jnt_dofadr[model.joint(n).id] for n in names])
    act = np.array([model.actuator(n).id for n in names])
    torso = model.body(anchor).id
    gyro = model.sensor("base_gyro")
    gyro_adr = model.sensor_adr[gyro.id]

    session = ort.InferenceSession(str(export), providers=["CPUExecutionProvider"])
    obs_len = session.get_inputs()[0].shape[1]

    def call(obs, step):
        out = session.run(
            ["actions", "joint_pos", "joint_vel", "ref_pos_xyz", "ref_quat_xyzw"],
            {"obs": obs.reshape(1, -1).astype(np.float32), "time_step": np.array([[step]], dtype=np.float32)},
        )
        x, y, z, w = out[4][0]
        return out[0][0], out[1][0], out[2][0], out[3][0], np.array([w, x, y, z])

    # The whole motion, read out first (its length: where the table stops changing).
    frames = []
    step = 0
    while True:
        _, jp, jv, pos, quat = call(np.zeros(obs_len), step)
        if frames and np.array_equal(jp, frames[-1][0]) and np.array_equal(pos, frames[-1][2]):
            break
        frames.append((jp, jv, pos, quat))
        step += 1
        if a.frames and step >= a.frames:
            break
    total = len(frames)

    data.qpos[qadr] = frames[0][0]
    data.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
    place_on_floor(model, data, 0)

    hold_ticks = int(round(a.hold / POLICY_DT))
    robot_yaw0 = yaw_of(data.xquat[torso])
    motion_yaw0 = yaw_of(frames[0][3])
    turn = quat_of_yaw(robot_yaw0 - motion_yaw0)
    # Positions: the motion's first anchor put on the robot's, horizontally.
    shift = data.xpos[torso][:2] - rotate(turn, frames[0][2])[:2]

    last_action = np.zeros(len(names))
    # While the policy holds the first frame, the reference stands still: no velocity in it.
    still = np.zeros(len(names))
    command = np.concatenate([frames[0][0], still if hold_ticks > 0 else frames[0][1]])
    ref_quat = frames[0][3]
    joint_sq, anchor_sq, tracked = 0.0, 0.0, 0
    fell, lowest = False, math.inf
    t0 = time.perf_counter()
    for tick in range(hold_ticks + total):
        frame = max(0, tick - hold_ticks)
        q = data.qpos[qadr].copy()
        qd = data.qvel[vadr].copy()
        robot_q = quat_mul(quat_of_yaw(-robot_yaw0), data.xquat[torso])
        motion_q = quat_mul(quat_of_yaw(-motion_yaw0), ref_quat)
        ori = matrix(quat_mul(quat_conj(robot_q), motion_q))[:, :2].reshape(-1)
        parts = {
            "actions": last_action,
            "base_ang_vel": data.sensordata[gyro_adr : gyro_adr + 3],
            "dof_pos": q - default,
            "dof_vel": qd,
            "motion_command": command,
            "motion_ref_ori_b": ori,
        }
        obs = np.concatenate([parts[t] for t in terms])
        # The export's second input, the frame it plays, closes the policy's view of the step.
        trace.write([(t, parts[t]) for t in terms] + [("time_step", [float(frame)])])
        if tick >= hold_ticks:
            # The robot against the frame this tick plays, and its anchor against the motion's.
            joint_sq += float(np.mean((q - frames[frame][0]) ** 2))
            ref_anchor = rotate(turn, frames[frame][2])
            ref_anchor[:2] += shift
            anchor_sq += float(np.sum((data.xpos[torso] - ref_anchor) ** 2))
            tracked += 1
        action, jp, jv, _, ref_quat = call(obs, frame)
        command = np.concatenate([jp, still if tick + 1 < hold_ticks else jv])
        last_action = np.clip(action, -clip, clip)
        pd_steps(model, data, (qadr, vadr, act), (kp, kd, effort), default + scale * last_action)
        lowest = min(lowest, float(data.qpos[2]))
        if tilt(data.qpos[3:7]) > TILT_LIMIT:
            fell = True
            break
    wall = time.perf_counter() - t0
    trace.close()
    result = {
        "frames": total,
        "tracked_ticks": tracked,
        "joint_rmse_rad": math.sqrt(joint_sq / max(tracked, 1)),
        "anchor_rmse_m": math.sqrt(anchor_sq / max(tracked, 1)),
        "fell": fell,
        "lowest_base_m": lowest,
        "wall_s": wall,
        "simulated_s": (hold_ticks + total) * POLICY_DT,
    }
    print(json.dumps(result))


ROBOTS = {
    # scene, export, the training and the deployment robot config, observation scales
    # (base_ang_vel, dof_vel), the gyro sensor
    "g1": ("data/robots/g1/scenes/scene_g1_29dof_wbt_plane.xml", "models/loco/g1_29dof/ppo_g1_29dof.onnx",
           ("g1_29dof", "g1_29dof"), (0.25, 0.05), "base_gyro"),
    # holosoma's T1 file has no floor: the project's scene adds one
    "t1": (str(pathlib.Path(__file__).resolve().parents[2] / "robots/t1/scene.xml"),
           "models/loco/t1_29dof/ppo_t1_29dof.onnx",
           ("t1_29dof_waist_wrist", "t1_29dof"), (1.0, 0.1), "angular-velocity"),
}


def robot_config(path, variable, keys):
    """Literal fields of the RobotConfig the Python file `path` assigns to `variable`, read as data
    (the file is parsed, not run)."""
    import ast
    tree = ast.parse(path.read_text())
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == variable for t in node.targets)
            and isinstance(node.value, ast.Call)
        ):
            found = {k.arg: k.value for k in node.value.keywords}
            return {k: ast.literal_eval(found[k]) for k in keys}
    raise SystemExit(f"no robot config {variable} in {path}")


def walk(a):
    trace = Trace(a.trace)
    scene, export, (training, deployment), (ang_scale, vel_scale), gyro_name = ROBOTS[a.robot]
    export = a.policy_dir / export
    meta = metadata(export)
    names = json.loads(meta["dof_names"])
    kp = np.array(json.loads(meta["kp"]))
    kd = np.array(json.loads(meta["kd"]))
    cfg = robot_config(a.robot_dir / "config_values/robot.py", training, ["dof_effort_limit_list"])
    effort = np.array(cfg["dof_effort_limit_list"], dtype=float)
    # The standing pose as holosoma-inference deploys it (its robot config's default_dof_angles).
    inference = robot_config(
        a.policy_dir / "config/config_values/robot.py", deployment, ["default_dof_angles", "dof_names"]
    )
    assert list(inference["dof_names"]) == names
    default = np.array(inference["default_dof_angles"], dtype=float)

    model = mujoco.MjModel.from_xml_path(str(a.robot_dir / scene))
    model.opt.timestep = a.physics_dt
    data = mujoco.MjData(model)
    qadr = np.array([model.jnt_qposadr[model.joint(n).id] for n in names])
    vadr = np.array([model.jnt_dofadr[model.joint(n).id] for n in names])
    act = np.array([model.actuator(n).id for n in names])
    gyro_adr = model.sensor_adr[model.sensor(gyro_name).id]
    session = ort.InferenceSession(str(export), providers=["CPUExecutionProvider"])

    data.qpos[qadr] = default
    data.qpos[3:7] = [1.0, 0.0, 0.0, 1e-12]
    if model.ngeom and not any(model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE for g in range(model.ngeom)):
        raise SystemExit(f"{scene} has no floor")
    place_on_floor(model, data, 0)
    standing = float(data.qpos[2])
    start = data.qpos[:2].copy()
    yaw0 = yaw_of(data.qpos[3:7])

    phase = np.array([0.0, math.pi])
    phase_dt = 2 * math.pi / (50 * 1.0)
    standing_still = False
    last_action = np.zeros(len(names))
    command = np.zeros(3)  # ang_vel_z, lin_vel_x, lin_vel_y
    # The commands move at most `--ramp` per second (0: at once, as `play --command` gives them).
    ramp = a.ramp * POLICY_DT if a.ramp > 0 else math.inf
    ticks = int(round((a.stand + a.walk + a.rest) / POLICY_DT))
    lowest, fell = math.inf, False
    t0 = time.perf_counter()
    for tick in range(ticks):
        t = tick * POLICY_DT
        want = np.array([0.0, a.vx, 0.0]) if a.stand <= t < a.stand + a.walk else np.zeros(3)
        command += np.clip(want - command, -ramp, ramp)
        phase = np.fmod(phase + phase_dt + math.pi, 2 * math.pi) - math.pi
        if np.linalg.norm(command) < 0.01:
            phase[:] = math.pi
            standing_still = True
        elif standing_still:
            phase = np.array([0.0, math.pi])
            standing_still = False
        q, qd = data.qpos[qadr], data.qvel[vadr]
        gravity = rotate(quat_conj(data.qpos[3:7]), [0.0, 0.0, -1.0])
        parts = {
            "actions": last_action,
            "base_ang_vel": data.sensordata[gyro_adr : gyro_adr + 3] * ang_scale,
            "command_ang_vel": command[:1],
            "command_lin_vel": command[1:],
            "cos_phase": np.cos(phase),
            "dof_pos": q - default,
            "dof_vel": qd * vel_scale,
            "projected_gravity": gravity,
            "sin_phase": np.sin(phase),
        }
        obs = np.concatenate([parts[k] for k in sorted(parts)]).astype(np.float32).reshape(1, -1)
        trace.write([(k, parts[k]) for k in sorted(parts)])
        action = session.run(None, {session.get_inputs()[0].name: obs})[0][0]
        last_action = np.clip(action, -100, 100)
        pd_steps(model, data, (qadr, vadr, act), (kp, kd, effort), default + 0.25 * last_action)
        lowest = min(lowest, float(data.qpos[2]))
        if tilt(data.qpos[3:7]) > TILT_LIMIT:
            fell = True
            break
    wall = time.perf_counter() - t0
    trace.close()
    moved = data.qpos[:2] - start
    heading = (yaw_of(data.qpos[3:7]) - yaw0 + math.pi) % (2 * math.pi) - math.pi
    forward = float(moved @ np.array([math.cos(yaw0), math.sin(yaw0)]))
    print(json.dumps({
        "displacement_m": float(np.linalg.norm(moved)),
        "forward_m": forward,
        "heading_change_deg": math.degrees(heading),
        "standing_base_m": standing,
        "lowest_base_m": lowest,
        "fell": fell,
        "wall_s": wall,
    }))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("task", choices=["dance", "walk"])
    p.add_argument("--robot", choices=sorted(ROBOTS), default="g1", help="walk: the robot")
    p.add_argument("--vx", type=float, default=0.5, help="walk: forward command, m/s")
    p.add_argument("--stand", type=float, default=1.0, help="walk: seconds standing first")
    p.add_argument("--walk", type=float, default=10.0, help="walk: seconds walking")
    p.add_argument("--rest", type=float, default=6.0, help="walk: seconds of rest command after")
    p.add_argument("--ramp", type=float, default=1.0, help="walk: command ramp, per second (0: a step)")
    p.add_argument("--robot-dir", type=pathlib.Path, required=True, help="the holosoma package (.local/holosoma)")
    p.add_argument("--policy-dir", type=pathlib.Path, required=True, help="holosoma-inference (.local/holosoma-inference)")
    p.add_argument("--frames", type=int, default=0, help="play only the first N frames of the motion (0: all)")
    p.add_argument("--hold", type=float, default=1.0, help="seconds the policy stands on the first frame first")
    p.add_argument("--physics-dt", type=float, default=PHYSICS_DT,
                   help="physics step, s (holosoma's: 0.005; a divisor of the 20 ms policy step)")
    p.add_argument("--trace", type=pathlib.Path, help="write the observation of every step here (CSV)")
    a = p.parse_args()
    if not 0.0 < a.physics_dt <= POLICY_DT or abs(POLICY_DT / a.physics_dt - round(POLICY_DT / a.physics_dt)) > 1e-9:
        p.error(f"--physics-dt {a.physics_dt}: must divide the policy step ({POLICY_DT} s)")
    if a.task == "dance":
        dance(a)
    else:
        walk(a)
    return 0


if __name__ == "__main__":
    sys.exit(main())

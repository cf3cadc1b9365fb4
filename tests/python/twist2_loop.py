"""The project's own re-statement of TWIST2's authors' sim-to-sim loop, written from the facts of
../shared/third_party/twist2/README.md (no code of theirs), as the reference the general-tracker
tests compare robodeploy against; and the same figures computed from a robodeploy recording.

Usage: twist2_loop.py TWIST2_DIR MOTION.pkl [RUN.mcap]

Prints JSON:
  python    the loop's own run: ticks, fell, joint_rmse (rad, against the reference at each tick's
            own time k·0.02 s), height_rmse (m), body_rmse (m: every body's position in the root's
            frame, robot against the reference's forward kinematics)
  run       (with RUN.mcap) the same figures from the recording's state at each policy tick, and
            obs_max_err: the largest difference between the observation the run recorded and the
            one rebuilt here from the run's own recorded state and the motion file by the README's
            rules (one tick ahead, central differences over the motion's frames, SO(3) for the
            root, blended between frames; the current block, the 10 previous oldest first with
            zeros before the first tick, the reference block again), obs_ticks compared, obs_len
"""
import collections
import json
import math
import pickle
import sys

import mujoco
import numpy as np
import onnxruntime as ort

RATE = 50.0
DT = 1.0 / RATE
PHYSICS_STEPS = 20
# The README's table, in its joint order.
LEG = dict(default=[-0.2, 0, 0, 0.4, -0.2, 0], kp=[100, 100, 100, 150, 40, 40], kd=[2, 2, 2, 4, 2, 2],
           limit=[100, 100, 100, 150, 40, 40])
WAIST = dict(default=[0, 0, 0], kp=[150] * 3, kd=[4] * 3, limit=[150] * 3)
ARM = dict(default=[0, 0.4, 0, 1.2, 0, 0, 0], kp=[40, 40, 40, 40, 4, 4, 4], kd=[5, 5, 5, 5, 0.2, 0.2, 0.2],
           limit=[40, 40, 40, 40, 4, 4, 4])


def per_joint(key):
    right_arm = list(ARM[key])
    if key == "default":
        right_arm[1] = -right_arm[1]
    return np.array(LEG[key] * 2 + WAIST[key] + ARM[key] + right_arm, dtype=np.float64)


DEFAULT, KP, KD, LIMIT = (per_joint(k) for k in ("default", "kp", "kd", "limit"))
ANKLES = [4, 5, 10, 11]


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def quat_conj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_rotate(q, v):
    return quat_mul(quat_mul(q, np.array([0.0, *v])), quat_conj(q))[1:]


def rotvec(q):
    """Axis · angle of a unit quaternion (w x y z), the short way."""
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    s = np.linalg.norm(q[1:])
    if s < 1e-15:
        return np.zeros(3)
    return q[1:] * (2.0 * math.atan2(s, q[0]) / s)


def slerp(a, b, t):
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 0.9995:
        q = a + t * (b - a)
        return q / np.linalg.norm(q)
    th = math.acos(d)
    return (math.sin((1 - t) * th) * a + math.sin(t * th) * b) / math.sin(th)


def roll_pitch(q):
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    return roll, pitch


class Motion:
    """A GMR motion with the README's velocities and interpolation."""

    def __init__(self, path):
        with open(path, "rb") as f:
            m = pickle.load(f)
        self.fps = float(m["fps"])
        self.pos = np.asarray(m["root_pos"], dtype=np.float64)
        xyzw = np.asarray(m["root_rot"], dtype=np.float64)
        self.rot = xyzw[:, [3, 0, 1, 2]] / np.linalg.norm(xyzw, axis=1, keepdims=True)
        self.dof = np.asarray(m["dof_pos"], dtype=np.float64)
        self.n = len(self.pos)
        dt = 1.0 / self.fps
        self.lin = np.gradient(self.pos, dt, axis=0)
        self.ang = np.zeros((self.n, 3))
        for i in range(self.n):
            a, b = max(i - 1, 0), min(i + 1, self.n - 1)
            self.ang[i] = rotvec(quat_mul(self.rot[b], quat_conj(self.rot[a]))) / ((b - a) * dt)
        self.duration = (self.n - 1) / self.fps
        # The last control tick of the motion: where robodeploy's `hold` end holds it, at rest.
        self.last_tick = math.floor(self.duration * RATE) / RATE

    def at(self, t):
        """Root position, quaternion, linear and angular velocity (world), joints at time t; past
        the motion's last control tick it holds that tick's pose at rest (robodeploy's `hold`
        end; the authors' loop would loop the motion)."""
        if t > self.last_tick + 1e-9:
            pos, rot, _, _, dof = self.at(self.last_tick)
            return pos, rot, np.zeros(3), np.zeros(3), dof
        f = t * self.fps
        i0 = min(int(math.floor(f)), self.n - 1)
        i1 = min(i0 + 1, self.n - 1)
        a = f - i0 if i1 > i0 else 0.0
        lerp = lambda x: x[i0] * (1 - a) + x[i1] * a  # noqa: E731
        return lerp(self.pos), slerp(self.rot[i0], self.rot[i1], a), lerp(self.lin), lerp(self.ang), lerp(self.dof)


def mimic(motion, t):
    """The reference block (35) for time t."""
    pos, rot, lin, ang, dof = motion.at(t)
    inv = quat_conj(rot)
    v = quat_rotate(inv, lin)
    w = quat_rotate(inv, ang)
    r, p = roll_pitch(rot)
    return np.concatenate([v[:2], [pos[2]], [r, p], [w[2]], dof])


def proprio(gyro, quat, q, qd, last_action):
    r, p = roll_pitch(quat)
    vel = qd * 0.05
    vel[ANKLES] = 0.0
    return np.concatenate([gyro * 0.25, [r, p], q - DEFAULT, vel, last_action])


class Observer:
    """Current, history (10 previous, oldest first, zeros before the first tick), future."""

    def __init__(self):
        self.history = collections.deque([np.zeros(127)] * 10, maxlen=10)

    def build(self, mim, pro):
        current = np.concatenate([mim, pro])
        obs = np.concatenate([current, *self.history, mim])
        self.history.append(current)
        return obs


def body_frame_positions(model, data):
    """Every body's position in the root's frame (root = body 1, the pelvis)."""
    root, rot = data.xpos[1], data.xmat[1].reshape(3, 3)
    return (data.xpos[1:] - root) @ rot


def reference_bodies(model, scratch, motion, t):
    pos, rot, _, _, dof = motion.at(t)
    scratch.qpos[:3], scratch.qpos[3:7], scratch.qpos[7:] = pos, rot, dof
    mujoco.mj_kinematics(model, scratch)
    return body_frame_positions(model, scratch)


def figures(samples):
    """RMSEs and a fall from (q, ref q, height, ref height, bodies, ref bodies, up z) per tick."""
    q = np.array([s[0] - s[1] for s in samples])
    h = np.array([s[2] - s[3] for s in samples])
    b = np.array([np.linalg.norm(s[4] - s[5], axis=1) for s in samples])
    return {
        "ticks": len(samples),
        "fell": bool(any(s[2] < 0.4 or s[6] < 0.5 for s in samples)),
        "joint_rmse": float(np.sqrt(np.mean(q ** 2))),
        "height_rmse": float(np.sqrt(np.mean(h ** 2))),
        "body_rmse": float(np.sqrt(np.mean(b ** 2))),
    }


def authors_loop(twist2, motion):
    model = mujoco.MjModel.from_xml_path(f"{twist2}/g1/g1_sim2sim_29dof.xml")
    data, scratch = mujoco.MjData(model), mujoco.MjData(model)
    session = ort.InferenceSession(f"{twist2}/ckpts/twist2_1017_20k.onnx", providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    start = DEFAULT.copy()
    start[16], start[23] = 0.2, -0.2
    data.qpos[:3], data.qpos[3:7], data.qpos[7:] = [0, 0, 0.793], [1, 0, 0, 0], start
    mujoco.mj_forward(model, data)
    observer, last = Observer(), np.zeros(29)
    samples = []
    ticks = int(math.floor(motion.duration * RATE)) + 1
    for k in range(ticks):
        q, qd = data.qpos[7:].copy(), data.qvel[6:].copy()
        quat, gyro = data.qpos[3:7].copy(), data.qvel[3:6].copy()
        _, _, _, _, ref_q = motion.at(k * DT)
        ref_pos = motion.at(k * DT)[0]
        up = quat_rotate(quat, [0, 0, 1])[2]
        samples.append((q, ref_q, data.qpos[2], ref_pos[2], body_frame_positions(model, data),
                        reference_bodies(model, scratch, motion, k * DT), up))
        obs = observer.build(mimic(motion, (k + 1) * DT), proprio(gyro, quat, q, qd, last))
        action = session.run(None, {name: obs[None].astype(np.float32)})[0][0].astype(np.float64)
        last = action
        target = DEFAULT + 0.5 * np.clip(action, -10, 10)
        for _ in range(PHYSICS_STEPS):
            tau = KP * (target - data.qpos[7:]) - KD * data.qvel[6:]
            data.ctrl[:] = np.clip(tau, -LIMIT, LIMIT)
            mujoco.mj_step(model, data)
    return figures(samples)


def recorded_run(twist2, motion, path):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    model = mujoco.MjModel.from_xml_path(f"{twist2}/g1/g1_sim2sim_29dof.xml")
    data, scratch = mujoco.MjData(model), mujoco.MjData(model)
    replay, policy = {}, {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(
                topics=["/policy"], log_time_order=True):
            if decoded.policy_ran:
                policy[decoded.tick] = (np.array(decoded.observation, dtype=np.float64),
                                        np.array(decoded.action, dtype=np.float64))
    with open(path, "rb") as f:
        for _, _, message in make_reader(f).iter_messages(topics=["/replay"]):
            r = json.loads(message.data)
            replay[r["tick"]] = r
    ticks = sorted(policy)
    first = ticks[0]
    observer, last = Observer(), np.zeros(29)
    samples, worst, compared, obs_len = [], 0.0, 0, 0
    clip_ticks = int(math.floor(motion.duration * RATE)) + 1
    for tick in ticks:
        k = tick - first
        r = replay[tick]
        q, qd = np.array(r["q"]), np.array(r["qd"])
        imu = np.array(r["imu"])
        gyro, quat = imu[:3], imu[6:10]
        rebuilt = observer.build(mimic(motion, (k + 1) * DT), proprio(gyro, quat, q, qd, last))
        obs, action = policy[tick]
        obs_len = len(obs)
        if k < clip_ticks and len(obs) == len(rebuilt):
            worst = max(worst, float(np.max(np.abs(obs - rebuilt))))
            compared += 1
        elif len(obs) != len(rebuilt):
            worst = float("inf")
        last = action
        if k < clip_ticks:
            base = np.array(r["base_pose"])
            data.qpos[:3], data.qpos[3:7], data.qpos[7:] = base[:3], base[3:7], q
            mujoco.mj_kinematics(model, data)
            _, _, _, _, ref_q = motion.at(k * DT)
            up = quat_rotate(base[3:7], [0, 0, 1])[2]
            samples.append((q, ref_q, base[2], motion.at(k * DT)[0][2], body_frame_positions(model, data),
                            reference_bodies(model, scratch, motion, k * DT), up))
    out = figures(samples)
    out.update(obs_max_err=worst, obs_ticks=compared, obs_len=obs_len)
    return out


def main():
    twist2, motion_path = sys.argv[1], sys.argv[2]
    motion = Motion(motion_path)
    out = {"python": authors_loop(twist2, motion)}
    if len(sys.argv) > 3:
        out["run"] = recorded_run(twist2, motion, sys.argv[3])
    print(json.dumps(out))


if __name__ == "__main__":
    main()

"""An independent whole-body VMC sender: python-osc (PyPI), unmodified, as a motion-capture app would
use it.

Usage: vmc_skeleton_send.py PORT [SECONDS [SCALE]]
Sends, in Unity axes (x right, y up, z forward, left handed), a 1.70 m performer's humanoid bones
(Unity's HumanBodyBones names, each pose local to its parent, the root at the origin) at 60 Hz, one
OSC bundle per frame: a T-pose for 1.5 s, then squats (knees forward, feet flat and still) while
the right arm waves above the shoulder, until SECONDS (default 8) have passed. SCALE (default 1)
scales the performer (0.4: a doll whose hips stand 0.38 m high).
"""
import math
import sys
import time

from pythonosc import osc_bundle_builder, osc_message_builder
from pythonosc.udp_client import SimpleUDPClient

port = int(sys.argv[1])
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 8.0
scale = float(sys.argv[3]) if len(sys.argv) > 3 else 1.0
client = SimpleUDPClient("127.0.0.1", port)

THIGH = SHIN = 0.42
# Local offsets from the parent (Unity axes) in the T-pose; rotations are identity there.
BONES = [
    ("Hips", None, [0.0, 0.95, 0.0]),
    ("Spine", "Hips", [0.0, 0.10, 0.0]),
    ("Chest", "Spine", [0.0, 0.15, 0.0]),
    ("Neck", "Chest", [0.0, 0.22, 0.0]),
    ("Head", "Neck", [0.0, 0.10, 0.0]),
    ("LeftShoulder", "Chest", [-0.04, 0.17, 0.0]),
    ("LeftUpperArm", "LeftShoulder", [-0.13, 0.0, 0.0]),
    ("LeftLowerArm", "LeftUpperArm", [-0.28, 0.0, 0.0]),
    ("LeftHand", "LeftLowerArm", [-0.25, 0.0, 0.0]),
    ("RightShoulder", "Chest", [0.04, 0.17, 0.0]),
    ("RightUpperArm", "RightShoulder", [0.13, 0.0, 0.0]),
    ("RightLowerArm", "RightUpperArm", [0.28, 0.0, 0.0]),
    ("RightHand", "RightLowerArm", [0.25, 0.0, 0.0]),
    ("LeftUpperLeg", "Hips", [-0.09, -0.05, 0.0]),
    ("LeftLowerLeg", "LeftUpperLeg", [0.0, -THIGH, 0.0]),
    ("LeftFoot", "LeftLowerLeg", [0.0, -SHIN, 0.0]),
    ("LeftToes", "LeftFoot", [0.0, -0.06, 0.13]),
    ("RightUpperLeg", "Hips", [0.09, -0.05, 0.0]),
    ("RightLowerLeg", "RightUpperLeg", [0.0, -THIGH, 0.0]),
    ("RightFoot", "RightLowerLeg", [0.0, -SHIN, 0.0]),
    ("RightToes", "RightFoot", [0.0, -0.06, 0.13]),
]


def axis_angle(axis, angle):
    """Unity quaternion (x, y, z, w) of `angle` about `axis`."""
    s = math.sin(angle / 2)
    return [axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2)]


IDENTITY = [0.0, 0.0, 0.0, 1.0]


def frame(t):
    """Each bone's local (position, rotation) at `t` seconds."""
    poses = {name: (list(offset), IDENTITY) for name, _, offset in BONES}
    if t < 1.5:
        return poses
    m = t - 1.5
    # Squat: the thighs swing the knees forward, the shins back, the feet level again.
    bend = 0.35 * (1 - math.cos(2 * math.pi * m / 3.0)) / 2
    drop = THIGH * (1 - math.cos(bend)) + SHIN * (1 - math.cos(bend))
    poses["Hips"] = ([0.0, 0.95 - drop, 0.0], IDENTITY)
    for side in ("Left", "Right"):
        poses[side + "UpperLeg"] = (poses[side + "UpperLeg"][0], axis_angle([1, 0, 0], -bend))
        poses[side + "LowerLeg"] = (poses[side + "LowerLeg"][0], axis_angle([1, 0, 0], 2 * bend))
        poses[side + "Foot"] = (poses[side + "Foot"][0], axis_angle([1, 0, 0], -bend))
    # The right arm up above the shoulder, the forearm waving.
    lift = min(1.0, m / 0.8)
    poses["RightUpperArm"] = (poses["RightUpperArm"][0], axis_angle([0, 0, 1], 0.9 * lift))
    poses["RightLowerArm"] = (
        poses["RightLowerArm"][0],
        axis_angle([0, 0, 1], lift * (0.6 + 0.4 * math.sin(2 * math.pi * m / 1.2))),
    )
    return poses


start = time.monotonic()
sent = 0
while True:
    t = time.monotonic() - start
    if t > seconds:
        break
    bundle = osc_bundle_builder.OscBundleBuilder(osc_bundle_builder.IMMEDIATELY)
    root = osc_message_builder.OscMessageBuilder(address="/VMC/Ext/Root/Pos")
    for v in ["root", 0.0, 0.0, 0.0] + IDENTITY:
        root.add_arg(v)
    bundle.add_content(root.build())
    for name, (p, q) in frame(t).items():
        m = osc_message_builder.OscMessageBuilder(address="/VMC/Ext/Bone/Pos")
        for v in [name] + [scale * x for x in p] + q:
            m.add_arg(v)
        bundle.add_content(m.build())
    client.send(bundle.build())
    sent += 1
    time.sleep(max(0.0, start + sent / 60.0 - time.monotonic()))
print(sent)

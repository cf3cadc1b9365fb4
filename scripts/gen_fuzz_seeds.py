#!/usr/bin/env python3
"""Write the seed corpora of the file and network parsers' fuzz targets (tests/fuzz/corpus/).

Every seed is made here, small and valid, so the fuzzer starts from inputs the parser accepts and
mutates them into the ones it must refuse. None is third-party material:

  rvc_stream/      BNO08x UART-RVC frames: the datasheet's example frame, and three frames in a row.
  bno055_uart/     BNO055 UART traffic: the mode write and its acknowledgement, a data-block read
                   request and its answer.
  mit_frames/      CAN motor frames (4-byte little-endian identifier, top bit = 29-bit, then the
                   data): an MIT-mode enable and command to motor 1, Robstride enable, control
                   and feedback frames for motor 2 and host 0xFD.
  feetech_packets/ Feetech STS traffic: a ping and a read of the present position with their
                   answers, a sync read to three servos.
  dds_samples/     DDS samples as CDR: a zero unitree_hg LowCmd and LowState with their CRC (Unitree's
                   CRC-32, MPEG-2 over the packed words' big-endian bytes), a geometry_msgs Twist.
  udp_command/     operator command datagrams (`play --command-udp`): a valid version-1 message,
                   and one with a value out of range.
  osc_vmc/         VMC tracker datagrams as a VR bridge sends them (a bundle of headset and
                   controller poses, one bare message), and a skeleton as a suit sends it (the
                   root, then humanoid bones local to their parents).
  bvh_text/        a two-joint BVH skeleton with three frames.
  clip_csv/        a three-frame clip in the project's CSV layout (time, root pose, one joint).
  motion_csv/      a motion sidecar, a NUL byte, and the headerless CSV it describes (x y z w and
                   w x y z quaternion orders, two joints).
  npy_array/       NumPy .npy arrays (format 1.0), float64 and float32, as np.save writes them.
  gmr_pickle/      GMR motions (fps, root_pos, root_rot x y z w, dof_pos, link_body_list,
                   local_body_pos) made here with NumPy and pickled at protocols 2, 4 and 5; and the
                   hostile ones: a memo bomb (a value copied into itself forty times), nesting deeper
                   than the reader takes, a length beyond the data, a call of os.system (kept as
                   data, never run).
  policy_toml/     the project's reference-follower manifest with its default pose, stiffness and
                   damping written out (so the target never needs the ONNX file's metadata); the
                   squat generator's description (the target reads the text as both); the keypoint
                   fixture policy's manifest (its ref_keypoints and keypoints terms).
  mirror_toml/     the project's own randomized-with-faults mirror settings (sim2real/configs/).
  onnx_metadata/   the metadata of rd-biped tracking exports as scripts/gen_tracking_export.py
                   writes them (a byte for the time_step input, then key TAB value lines): the
                   BeyondMimic keys, and mjlab's per-term history/scale/clip keys.
  live_client_messages/  what a viewer sends the live server: the protocol's subscribe,
                   unsubscribe, advertise, client message data, parameter, connection-graph,
                   asset and service-call operations, each offered under a subprotocol, and junk.
  mcap_recording/  a tiny recording (two channels, three messages), lz4- and zstd-compressed
                   chunks, written with the `mcap` Python package of the project's venv.

Usage: .local/venv/bin/python scripts/gen_fuzz_seeds.py
"""
import io
import json
import pathlib
import struct

ROOT = pathlib.Path(__file__).resolve().parent.parent / "tests" / "fuzz" / "corpus"


def write(target, name, data):
    d = ROOT / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data if isinstance(data, bytes) else data.encode())


def osc_string(s):
    b = s.encode() + b"\0"
    return b + b"\0" * (-len(b) % 4)


def osc_message(address, args):
    tags = "," + "".join("s" if isinstance(a, str) else "f" for a in args)
    body = b"".join(osc_string(a) if isinstance(a, str) else struct.pack(">f", a) for a in args)
    return osc_string(address) + osc_string(tags) + body


def osc_bundle(elements):
    out = osc_string("#bundle") + struct.pack(">Q", 1)
    for e in elements:
        out += struct.pack(">i", len(e)) + e
    return out


hmd = osc_message("/VMC/Ext/Hmd/Pos", ["HMD", 0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0])
left = osc_message("/VMC/Ext/Con/Pos", ["LeftHand", -0.3, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0])
right = osc_message("/VMC/Ext/Con/Pos", ["RightHand", 0.3, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0])
write("osc_vmc", "bundle", osc_bundle([hmd, left, right]))
write("osc_vmc", "message", hmd)
# Five points: the devices and a tracker on each foot, as `vr send --body five-point` sends them.
feet = [
    osc_message("/VMC/Ext/Tra/Pos", [serial, x, 0.12, 0.06, 0.0, 0.0, 0.0, 1.0])
    for serial, x in [("LeftFoot", -0.1), ("RightFoot", 0.1)]
]
write("osc_vmc", "five_point", osc_bundle([hmd, left, right, *feet]))
# A whole skeleton as a motion-capture suit sends it: the root (VMC 2.1's scale and offset after
# the pose), then bones local to their parents in Unity's humanoid names.
root = osc_message("/VMC/Ext/Root/Pos", ["root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
bones = [
    osc_message("/VMC/Ext/Bone/Pos", [name, *offset, 0.0, 0.0, 0.0, 1.0])
    for name, offset in [
        ("Hips", (0.0, 0.95, 0.0)),
        ("Spine", (0.0, 0.1, 0.0)),
        ("Chest", (0.0, 0.15, 0.0)),
        ("LeftUpperLeg", (-0.09, -0.05, 0.0)),
        ("LeftLowerLeg", (0.0, -0.42, 0.0)),
        ("LeftFoot", (0.0, -0.42, 0.0)),
    ]
]
write("osc_vmc", "skeleton", osc_bundle([root, *bones]))
DATASHEET_RVC = bytes([0xAA, 0xAA, 0xDE, 0x01, 0x00, 0x92, 0xFF, 0x25, 0x08, 0x8D, 0xFE, 0xEC, 0xFF, 0xD1, 0x03, 0x00, 0x00, 0x00, 0xE7])
write("rvc_stream", "datasheet", DATASHEET_RVC)


def rvc(index, yaw):
    body = bytes([index]) + struct.pack("<6h", yaw, 0, 0, 0, 0, 1000) + bytes(3)
    return b"\xaa\xaa" + body + bytes([sum(body) & 0xFF])


write("rvc_stream", "turning", rvc(7, 100) + rvc(8, 110) + rvc(9, 120))
# BNO055: `AA 00 3D 01 08` (IMU mode) answered `EE 01`; `AA 01 08 20` answered `BB 20` + 32 bytes
# (gravity on z, unit quaternion w = 2^14).
block = bytearray(32)
block[4:6] = struct.pack("<h", 981)
block[24:26] = struct.pack("<h", 16384)
write("bno055_uart", "mode_and_read", bytes([0xAA, 0x00, 0x3D, 0x01, 0x08, 0xEE, 0x01, 0xAA, 0x01, 0x08, 0x20, 0xBB, 0x20]) + bytes(block))
def can_frame(ident, data, extended=False):
    return struct.pack("<I", ident | (0x8000_0000 if extended else 0)) + bytes(data)


write("mit_frames", "mit_enable", can_frame(1, [0xFF] * 7 + [0xFC]))
write("mit_frames", "mit_command", can_frame(1, [0x7F, 0xFF, 0x7F, 0xF0, 0x33, 0x33, 0x37, 0xFF]))
write("mit_frames", "robstride_enable", can_frame(0x03 << 24 | 0xFD << 8 | 2, [0] * 8, True))
write("mit_frames", "robstride_control", can_frame(0x01 << 24 | 0x7FFF << 8 | 2, struct.pack(">4H", 0x7FFF, 0x7FFF, 0x0800, 0x0400), True))
write("mit_frames", "robstride_feedback", can_frame(0x02 << 24 | 2 << 22 | 2 << 8 | 0xFD, struct.pack(">4H", 0x8000, 0x7FFF, 0x7FFF, 250), True))
def feetech(ident, first, params):
    body = bytes([ident, len(params) + 2, first]) + bytes(params)
    return b"\xff\xff" + body + bytes([~sum(body) & 0xFF])


write("feetech_packets", "ping_and_read", feetech(1, 0x01, []) + feetech(1, 0, []) + feetech(1, 0x02, [56, 2]) + feetech(1, 0, [0x00, 0x08]))
write("feetech_packets", "sync_read", feetech(0xFE, 0x82, [56, 15, 1, 2, 3]))
def unitree_crc(packed):
    """Unitree's CRC-32 of a packed message: CRC-32/MPEG-2 over its words, the CRC's left out."""
    crc = 0xFFFFFFFF
    for i in range(0, len(packed) - 4, 4):
        for byte in struct.pack(">I", struct.unpack_from("<I", packed, i)[0]):
            crc ^= byte << 24
            for _ in range(8):
                crc = ((crc << 1) ^ 0x04C11DB7) & 0xFFFFFFFF if crc & 0x80000000 else (crc << 1) & 0xFFFFFFFF
    return crc


# A zero message's CDR is its packed layout's zeros at CDR's offsets: 1000 and 2088 body bytes, the
# CRC last; the packed layouts (1004 and 2092 bytes) differ only by C's padding, all zeros.
for name, cdr_body, packed_len in (("low_cmd", 1000, 1004), ("low_state", 2088, 2092)):
    crc = unitree_crc(bytes(packed_len))
    write("dds_samples", name, b"\x00\x01\x00\x00" + bytes(cdr_body - 4) + struct.pack("<I", crc))
write("dds_samples", "twist", b"\x00\x01\x00\x00" + struct.pack("<6d", 0.5, 0.0, 0.0, 0.0, 0.0, -0.25))
# A blob published under the Twist type: a Twist's bytes with more behind them (read once as the
# Twist of its first 48 bytes).
write("dds_samples", "twist_with_a_tail",
      b"\x00\x01\x00\x00" + struct.pack("<6d", 0.5, 0.0, 0.0, 0.0, 0.0, -0.25) + b"\xff" * 256)
write("udp_command", "walk", b'{"version": 1, "seq": 17, "command": [0.3, 0.0, -0.5]}')
write("udp_command", "too_fast", b'{"version": 1, "seq": 18, "command": [3.0, 0.0, 0.0]}')

write("bvh_text", "two_joints.bvh", """HIERARCHY
ROOT Hips
{
  OFFSET 0.0 0.0 0.0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0.0 10.0 0.0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0.0 10.0 0.0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.033333
0 90 0 0 0 0 0 0 0
0 90 1 0 5 0 10 0 0
0 90 2 0 10 0 20 0 0
""")

write("clip_csv", "three_frames.csv", """# fuzz seed: three frames, one joint
time,root_x,root_y,root_z,root_qw,root_qx,root_qy,root_qz,left_knee
0.0,0,0,0.45,1,0,0,0,0.0
0.1,0,0,0.45,1,0,0,0,0.2
0.2,0,0,0.45,1,0,0,0,0.4
""")


write("motion_csv", "xyzw_two_joints", """fps = 30.0
quaternion = "xyzw"
joints = ["left_knee", "right_knee"]
\0""" + """0,0,0.45,0,0,0,1,0.0,0.1
0,0,0.45,0,0,0,1,0.2,0.3
0,0,0.45,0,0,0,1,0.4,0.5
""")
write("motion_csv", "wxyz_robot_order", """fps = 50.0
quaternion = "wxyz"
\0""" + """0,0,0.4,1,0,0,0,0.1,0.2
0,0,0.4,1,0,0,0,0.1,0.3
""")


def npy(descr, shape, payload):
    header = "{'descr': '%s', 'fortran_order': False, 'shape': %s, }" % (descr, shape)
    pad = -(10 + len(header) + 1) % 64
    header = header + " " * pad + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + payload


write("npy_array", "f8_2x3.npy", npy("<f8", "(2, 3)", struct.pack("<6d", *range(6))))
write("npy_array", "f4_4.npy", npy("<f4", "(4,)", struct.pack("<4f", 0.5, 1.5, 2.5, 3.5)))

MIRROR = pathlib.Path(__file__).resolve().parent.parent / "sim2real" / "configs" / "randomized-with-faults.toml"
write("mirror_toml", "randomized-with-faults.toml", MIRROR.read_text())

POLICY = pathlib.Path(__file__).resolve().parent.parent / "robots" / "biped" / "policies" / "reference_follower.toml"
manifest = POLICY.read_text()
head, tables = manifest.split("\n[", 1)
joints = head.count('",') + head.count('"\n]')
explicit = "default_pose = [%s]\nstiffness = [%s]\ndamping = [%s]\n" % (
    ", ".join(["0.0"] * joints), ", ".join(["20.0"] * joints), ", ".join(["1.0"] * joints))
write("policy_toml", "reference_follower.toml", head + "\n" + explicit + "\n[" + tables)
GENERATOR = POLICY.parent.parent / "generators" / "squat_ar.toml"
write("policy_toml", "squat_ar.toml", GENERATOR.read_text())
KEYPOINT_POLICY = POLICY.parent.parent.parent.parent / "tests" / "fixtures" / "policies" / "keypoint_follower.toml"
kp_head, kp_tables = KEYPOINT_POLICY.read_text().split("\n[", 1)
write("policy_toml", "keypoint_follower.toml", kp_head + "\n" + explicit + "\n[" + kp_tables)

import tomllib  # noqa: E402

robot = tomllib.loads((POLICY.parent.parent / "robot.toml").read_text())
names = [j["name"] for j in robot["joints"]]


def csv3(values):
    return ",".join(f"{v:.3f}" if isinstance(v, (int, float)) else str(v) for v in values)


common = {
    "run_path": "fuzz-seed",
    "joint_names": csv3(names),
    "joint_stiffness": csv3([j["kp"] for j in robot["joints"]]),
    "joint_damping": csv3([j["kd"] for j in robot["joints"]]),
    "default_joint_pos": csv3([j["default_position"] for j in robot["joints"]]),
    "action_scale": csv3([0.25 * j["torque_limit"] / j["kp"] for j in robot["joints"]]),
    "command_names": "motion",
    "anchor_body_name": "torso",
    "body_names": "pelvis,torso,left_foot",
}
terms = ["command", "motion_anchor_ori_b", "base_ang_vel", "joint_pos", "joint_vel", "actions"]
beyondmimic = {**common, "observation_names": csv3(terms), "observation_history_lengths": csv3([1] * 6)}
mjlab = {**common, "observation_names": csv3(terms),
         "observation_terms_history_length": csv3([0, 0, 0, 3, 3, 3]),
         "observation_terms_scale": csv3([1.0, 1.0, 1.0, 1.0, 0.05, 1.0]),
         "observation_terms_clip": csv3([[float("-inf"), float("inf")]] * 4 + [[-100.0, 100.0],
                                        [float("-inf"), float("inf")]])}
for name, meta in [("beyondmimic", beyondmimic), ("mjlab_history", mjlab)]:
    write("onnx_metadata", f"{name}.txt", b"\x01" + "".join(f"{k}\t{v}\n" for k, v in meta.items()).encode())

from mcap.writer import CompressionType, Writer  # noqa: E402

for name, compression in [("lz4", CompressionType.LZ4), ("zstd", CompressionType.ZSTD)]:
    buf = io.BytesIO()
    w = Writer(buf, compression=compression)
    w.start(profile="", library="robodeploy fuzz seed")
    schema = w.register_schema(name="seed", encoding="jsonschema", data=b"{}")
    a = w.register_channel(topic="/joints", message_encoding="json", schema_id=schema)
    b = w.register_channel(topic="/safety", message_encoding="json", schema_id=schema)
    for k in range(3):
        w.add_message(a, log_time=k * 20_000_000, publish_time=k * 20_000_000, data=b'{"q":[0.1,0.2]}')
    w.add_message(b, log_time=40_000_000, publish_time=40_000_000, data=b'{"mode":"Damped"}')
    w.finish()
    write("mcap_recording", f"tiny_{name}.mcap", buf.getvalue())

# 2D keypoint inputs: the shipped camera file, a two-frame keypoint CSV over both shipped cameras,
# and COCO results with two people (one frame without the robot).
write("keypoint_inputs", "cameras.toml", (ROOT.parent.parent.parent / "robots" / "biped" / "cameras.toml").read_text())
names = ["nose", "left_wrist"]
header = ["time_s"] + [f"{v}/{n}/{f}" for v in ["front", "side"] for n in names for f in ["u", "v", "confidence"]]
rows = [[0.0] + [640.0, 300.0, 1.0, 700.0, 420.0, 0.9] * 2, [1 / 30] + [641.0, 301.0, 1.0, 0.0, 0.0, 0.0] * 2]
write("keypoint_inputs", "keypoints.csv", ",".join(header) + "\n" + "\n".join(",".join(str(x) for x in r) for r in rows) + "\n")
person = [coord for i in range(17) for coord in (600.0 + i, 300.0 + 5 * i, 0.9)]
decoy = [coord for i in range(17) for coord in (100.0 + i, 200.0, 0.5)]
coco = [{"image_id": 0, "category_id": 1, "track_id": 7, "score": 0.9, "keypoints": person},
        {"image_id": 0, "category_id": 1, "track_id": 3, "score": 0.6, "keypoints": decoy},
        {"image_id": 1, "category_id": 1, "track_id": 3, "score": 0.6, "keypoints": decoy}]
write("keypoint_inputs", "coco_results.json", json.dumps(coco))

# COCO image ids, three bytes each (style, then a 16-bit number): plain numbers with a gap, file
# names around the number, and two ids of one frame number.
def coco_id(style, number):
    return bytes([style]) + struct.pack("<H", number)


write("coco_image_ids", "gap", coco_id(0, 1) + coco_id(0, 5) + coco_id(0, 3))
write("coco_image_ids", "names", coco_id(1, 16) + coco_id(1, 18))
write("coco_image_ids", "duplicate", coco_id(0, 2) + coco_id(2, 2))

# holosoma's training configuration for the reference robot (a synthetic one, in its layout: the
# robot's efforts and standing pose, the control's action scale by effort over stiffness, the actor
# group's terms with their scales, the motion command's anchor body).
import tomllib

joints = [j["name"] for j in tomllib.loads((ROOT.parent.parent.parent / "robots" / "biped" / "robot.toml").read_text())["joints"]]
holosoma = {
    "robot": {
        "dof_effort_limit_list": [20.0] * len(joints),
        "init_state": {"default_joint_angles": {j: 0.0 for j in joints}},
        "control": {"action_scale": 0.25, "action_scales_by_effort_limit_over_p_gain": True,
                    "clip_actions": True, "action_clip_value": 100.0},
    },
    "observation": {"groups": {"actor_obs": {"history_length": 1, "terms": {
        "motion_command": {"func": "holosoma.managers.observation.terms.wbt:motion_command", "scale": 1.0, "clip": None},
        "base_ang_vel": {"func": "holosoma.managers.observation.terms.wbt:base_ang_vel", "scale": 0.25, "clip": None},
        "dof_pos": {"func": "holosoma.managers.observation.terms.wbt:dof_pos", "scale": 1.0, "clip": None},
        "dof_vel": {"func": "holosoma.managers.observation.terms.wbt:dof_vel", "scale": 0.05, "clip": None},
        "actions": {"func": "holosoma.managers.observation.terms.wbt:actions", "scale": 1.0, "clip": None},
    }}}},
    "command": {"setup_terms": {"motion_command": {"params": {"motion_config": {"body_name_ref": ["pelvis"]}}}}},
}
write("holosoma_metadata", "reference_robot.json", json.dumps(holosoma, indent=1))
holosoma["observation"]["groups"]["actor_obs"]["history_length"] = 4
write("holosoma_metadata", "history_4.json", json.dumps(holosoma))
# A stiffness table (keys are parts of joint names) that contradicts the target's kp of 40.
holosoma["robot"]["control"]["stiffness"] = {"hip": 40.0, "knee": 90.0}
write("holosoma_metadata", "stiffness_contradicting_kp.json", json.dumps(holosoma))

# What a viewer sends the live server: the subprotocol byte (0 foxglove.sdk.v1, 1 the older
# foxglove.websocket.v1, 2 none), then frames of a kind byte (0 text, 1 binary, 2 ping, 3 close),
# a little-endian u16 length and the payload: the protocol's operations as its specification
# writes them.
def frame(kind, payload):
    if isinstance(payload, str):
        payload = payload.encode()
    return bytes([kind]) + struct.pack("<H", len(payload)) + payload


def op(**fields):
    return frame(0, json.dumps(fields))


write("live_client_messages", "subscribe_unsubscribe",
      bytes([0]) + op(op="subscribe", subscriptions=[{"id": 1, "channelId": 1}, {"id": 2, "channelId": 99}])
      + op(op="unsubscribe", subscriptionIds=[1, 2, 3]) + frame(3, b""))
write("live_client_messages", "advertise_and_publish",
      bytes([1]) + op(op="advertise", channels=[{"id": 5, "topic": "/cmd", "encoding": "json", "schemaName": "cmd"}])
      + frame(1, bytes([1]) + struct.pack("<I", 5) + b'{"x": 1}') + op(op="unadvertise", channelIds=[5]))
write("live_client_messages", "parameters_and_services",
      bytes([2]) + op(op="getParameters", parameterNames=["a"], id="p")
      + op(op="setParameters", parameters=[{"name": "a", "value": 1}])
      + op(op="subscribeConnectionGraph") + op(op="fetchAsset", uri="package://robot.urdf", requestId=1)
      + frame(1, bytes([2]) + struct.pack("<III", 1, 2, 4) + b"json" + b"{}") + frame(2, b"ping"))
write("live_client_messages", "junk", bytes([3]) + b"x-proto" + frame(0, "{not json") + frame(1, b"\xff" * 40))


def gmr_motion(frames=4, dofs=3):
    import numpy as np  # the project's venv has it

    t = np.arange(frames, dtype=np.float64)
    return {
        "fps": np.float64(30.0),
        "root_pos": np.stack([0.01 * t, 0 * t, 0.8 + 0 * t], axis=1),
        "root_rot": np.tile([0.0, 0.0, 0.0, 1.0], (frames, 1)),
        "dof_pos": 0.1 * np.ones((frames, dofs)),
        "link_body_list": ["pelvis", "foot"],
        "local_body_pos": np.zeros((frames, 2, 3), dtype=np.float32),
    }


import pickle  # noqa: E402

for proto in (2, 4, 5):
    write("gmr_pickle", f"motion_protocol_{proto}.pkl", pickle.dumps(gmr_motion(), protocol=proto))
write("gmr_pickle", "memo_bomb.pkl", b"\x80\x04N\x94" + b"h\x00h\x00\x86q\x00\x30" * 40 + b"h\x00.")
write("gmr_pickle", "deep.pkl", b"\x80\x04" + b"]" * 100 + b"a" * 99 + b".")
write("gmr_pickle", "length_beyond.pkl", b"\x80\x04B\xff\xff\xff\x7fabc.")
write("gmr_pickle", "os_system.pkl", b"\x80\x04\x8c\x02os\x8c\x06system\x93\x8c\x02ls\x85R.")

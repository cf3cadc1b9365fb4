"""A ROS 2 peer made of nothing but Cyclone DDS (PyPI `cyclonedds`, the middleware ROS 2 runs by
default) and ROS 2's type names: it receives a run's /joint_states, /tf, /robot_description (joining
late, as transient local lets it) and /diagnostics, and drives the policy through /cmd_vel.

Starts `robodeploy play ARGS… --ros2 --cmd-vel` itself (run it in a network namespace of the test's
own: DDS discovery's multicast stays there), sends a forward Twist once the robot is free of its
harness, and prints one JSON verdict with what it saw and the run's own report.

Usage: ros2_client.py FORWARD_M_S -- ROBODEPLOY play ARGS…
"""
import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.internal import InvalidSample
from cyclonedds.idl.types import float64, int32, sequence, uint8, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]


@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


forward = float(sys.argv[1])
command = sys.argv[sys.argv.index("--") + 1:]
play = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
out_lines = []
reader_thread = threading.Thread(target=lambda: out_lines.extend(play.stdout), daemon=True)
reader_thread.start()

dp = DomainParticipant(0)
# As ROS 2 subscribers ask by default (tf2 listeners, RViz, diagnostic_aggregator): reliable,
# volatile; every sample between two polls (50 ms: 2.5 ticks) kept, not only the newest. One
# best-effort reader (sensor-data profile) beside them: a reliable writer serves both kinds.
reliable = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile,
               Policy.History.KeepLast(64))
best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(64))
joint_states_topic = Topic(dp, "rt/joint_states", JointState)
streams = {
    "joint_states": DataReader(dp, joint_states_topic, qos=reliable),
    "joint_states_best_effort": DataReader(dp, joint_states_topic, qos=best_effort),
    "tf": DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=reliable),
    "diagnostics": DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=reliable),
    # As rclcpp's clock subscription asks (best effort, the newest): a simulation's time.
    "clock": DataReader(dp, Topic(dp, "rt/clock", Clock), qos=best_effort),
}
cmd_vel = DataWriter(dp, Topic(dp, "rt/cmd_vel", Twist))
seen = {k: [] for k in streams}
latched = Qos(Policy.Durability.TransientLocal, Policy.Reliability.Reliable(duration(seconds=1)),
              Policy.History.KeepLast(1))
late_reader, description = None, []
static_reader, statics = None, []
start = time.monotonic()
sent = 0
while play.poll() is None and time.monotonic() - start < 120:
    for name, reader in streams.items():
        for sample in reader.take(N=64):
            # Cyclone hands over the writer's going away as an InvalidSample.
            if isinstance(sample, InvalidSample):
                continue
            if len(seen[name]) < 2000:
                seen[name].append(sample)
    now = time.monotonic() - start
    # Joining late: the description was published once, at the run's first tick.
    if late_reader is None and now > 6.0:
        late_reader = DataReader(dp, Topic(dp, "rt/robot_description", String), qos=latched)
    if late_reader is not None and not description:
        description.extend(s.data for s in late_reader.take(N=4) if not isinstance(s, InvalidSample))
    # The fixed frames, as tf2 reads /tf_static: transient local, joining late like the description.
    if static_reader is None and now > 6.0:
        static_reader = DataReader(dp, Topic(dp, "rt/tf_static", TFMessage), qos=latched)
    if static_reader is not None and not statics:
        statics.extend(s for s in static_reader.take(N=4) if not isinstance(s, InvalidSample))
    # Forward once the harness has let the robot go (3 s) and the run is walking.
    if now > 5.0:
        cmd_vel.write(Twist(Vector3(forward, 0.0, 0.0), Vector3(0.0, 0.0, 0.0)))
        sent += 1
    time.sleep(0.05)
play.wait(timeout=60)
reader_thread.join(timeout=5)
err = play.stderr.read()
js = seen["joint_states"]
tf = seen["tf"]
diag = seen["diagnostics"]
frames = sorted({t.child_frame_id for m in tf[-1:] for t in m.transforms}) if tf else []
loop = [s for m in diag for s in m.status if s.name == "robodeploy: loop"]
print(json.dumps(dict(
    exit=play.returncode,
    joint_states=len(js),
    joint_states_best_effort=len(seen["joint_states_best_effort"]),
    clock=len(seen["clock"]),
    clock_s=[c.clock.sec + 1e-9 * c.clock.nanosec for c in seen["clock"]],
    joint_state_stamps_s=[m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in js],
    joint_names=list(js[-1].name) if js else [],
    positions_finite=all(abs(p) < 10 for m in js for p in m.position) if js else False,
    tf=len(tf),
    frames=frames,
    tf_parents=sorted({t.header.frame_id for m in tf[-1:] for t in m.transforms}) if tf else [],
    description_chars=len(description[0]) if description else 0,
    static_frames=sorted({t.child_frame_id for m in statics for t in m.transforms}),
    description_has_robot=bool(description) and "<robot" in description[0] and "<joint" in description[0],
    diagnostics=len(diag),
    loop_messages=sorted({s.message for s in loop}),
    loop_hardware=sorted({s.hardware_id for s in loop}),
    cmd_vel_sent=sent,
    stdout=[l.rstrip() for l in out_lines],
    stderr_tail=err.splitlines()[-5:],
)))

"""Unitree's own Python SDK as the emulated G1's low-level client, as its low-level examples use it.

Starts `robodeploy sim serve` for a robot whose joints sit on a `unitree_dds` bus (its DDS on the
loopback interface: run this inside a network namespace of the test's own), then through the SDK's
`ChannelFactoryInitialize`/`ChannelSubscriber`/`ChannelPublisher` (Cyclone DDS underneath):
1. subscribes `rt/lowstate` for a second: the rate, every state's CRC as the SDK computes it, the
   IMU (a unit quaternion), each motor's fields;
2. moves one joint with `LowCmd` (mode 1, q, kp, kd, its CRC from the SDK) at 500 Hz for 2 s, the
   other joints held where they are, and reads where it went (and the accelerometer, the robot on
   its gantry);
3. sends commands with a wrong CRC until the state shows the motor off (at most 5 s): the board
   must not take them — its motors time out instead — and it counts the refusals.
Prints one JSON verdict.

Usage: unitree_sdk_client.py ROBODEPLOY ROBOT_TOML JOINT_SLOT TARGET_RAD
"""
import json
import math
import pathlib
import subprocess
import sys
import threading
import time

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from unitree_sdk import LowCmd_, LowState_, sdk_crc  # noqa: E402
from unitree_sdk2py.core.channel import (  # noqa: E402
    ChannelFactoryInitialize, ChannelPublisher, ChannelSubscriber)
from unitree_sdk2py.idl.default import unitree_hg_msg_dds__LowCmd_  # noqa: E402

binary, robot, slot, target = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
# On the gantry: the robot held still by its stand, so its IMU reads gravity however the joints move.
server = subprocess.Popen([binary, "sim", "serve", "--robot", robot, "--gantry", "--seconds", "120"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
lines = []
for line in server.stdout:
    lines.append(line.rstrip())
    if line.strip().startswith("imu"):
        break
else:
    raise SystemExit("the server ended before it was serving:\n" + "\n".join(lines) + server.stderr.read())
domain = next(int(l.split("domain")[1]) for l in lines if l.strip().startswith("unitree"))

ChannelFactoryInitialize(domain, "lo")
states = []
lock = threading.Lock()


def on_state(msg):
    with lock:
        states.append((time.monotonic(), msg))


subscriber = ChannelSubscriber("rt/lowstate", LowState_)
subscriber.Init(on_state, 50)
publisher = ChannelPublisher("rt/lowcmd", LowCmd_)
publisher.Init()


def newest():
    with lock:
        return states[-1][1] if states else None


# 1. Listen (after discovery has settled).
deadline = time.monotonic() + 10
while newest() is None and time.monotonic() < deadline:
    time.sleep(0.01)
with lock:
    states.clear()
time.sleep(1.0)
with lock:
    window = list(states)
first = window[0][1] if window else None
verdict = dict(
    states_per_s=len(window) / 1.0,
    crc_ok=all(sdk_crc(m) == m.crc for _, m in window) and bool(window),
    quat_norm=math.sqrt(sum(q * q for q in first.imu_state.quaternion)) if first else 0.0,
    temperature=first.motor_state[slot].temperature[0] if first else None,
    voltage=first.motor_state[slot].vol if first else None,
    mode_machine=first.mode_machine if first else None,
    start_q=first.motor_state[slot].q if first else None,
)


# 2. Move the joint; hold the others where they are.
def command(q_of, crc_wrong=False):
    cmd = unitree_hg_msg_dds__LowCmd_()
    state = newest()
    cmd.mode_pr = 0
    cmd.mode_machine = state.mode_machine
    for i in range(29):
        m = cmd.motor_cmd[i]
        m.mode = 1
        m.q = q_of(i, state)
        m.dq = 0.0
        m.kp = 60.0
        m.kd = 2.0
        m.tau = 0.0
    cmd.crc = sdk_crc(cmd)
    if crc_wrong:
        cmd.crc ^= 0x1
    return cmd


hold = [m.q for m in newest().motor_state]
end = time.monotonic() + 2.0
while time.monotonic() < end:
    publisher.Write(command(lambda i, s: target if i == slot else hold[i]))
    time.sleep(0.002)
moved = newest().motor_state[slot]
# On the gantry now that the physics runs: on average over the last half second the accelerometer
# feels the stand hold the robot up against gravity.
with lock:
    recent = [m for t, m in states if t > time.monotonic() - 0.5]
mean = [sum(m.imu_state.accelerometer[k] for m in recent) / max(len(recent), 1) for k in range(3)]
verdict.update(moved_q=moved.q, moved_mode=moved.mode, accel_norm=math.sqrt(sum(a * a for a in mean)))

# 3. Wrong CRCs only, the joint asked back to where it started, for as long as it takes the state
# (through a Python reader that may lag on a busy machine) to show the motor's timeout: were the
# commands taken, the motor would stay on. At least 20 are sent whatever the timing (a starved
# loop may see the timeout after a handful), so the board has that many to refuse.
end = time.monotonic() + 5.0
after = newest().motor_state[slot]
bad_sent = 0
while time.monotonic() < end:
    publisher.Write(command(lambda i, s: verdict["start_q"] if i == slot else hold[i], crc_wrong=True))
    bad_sent += 1
    after = newest().motor_state[slot]
    if after.mode == 0 and bad_sent >= 20:
        break
    time.sleep(0.002)
verdict.update(after_bad_mode=after.mode, after_bad_status=after.motorstate, after_bad_q=after.q, bad_sent=bad_sent)

server.send_signal(2)
out, err = server.communicate(timeout=30)
verdict["server"] = [l for l in (lines + out.splitlines()) if l.strip()]
print(json.dumps(verdict))

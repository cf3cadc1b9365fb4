"""An independent VMC sender: python-osc (PyPI), unmodified, as a VR app would use it.

Usage: vmc_send.py PORT [headset-only]
Sends, in Unity axes (x right, y up, z forward), a user of 1.70 m in a T-pose for 1.2 s, then
reaching forward with the right hand for 2 s, at 60 Hz, one OSC message per device (no bundles).
With `headset-only`, only the headset, which turns 30° to the left after the T-pose.
"""
import math
import sys
import time

from pythonosc.udp_client import SimpleUDPClient

port = int(sys.argv[1])
headset_only = len(sys.argv) > 2 and sys.argv[2] == "headset-only"
client = SimpleUDPClient("127.0.0.1", port)
identity = [0.0, 0.0, 0.0, 1.0]  # x, y, z, w
start = time.monotonic()
sent = 0
while True:
    t = time.monotonic() - start
    if t > 3.2:
        break
    hmd = [0.0, 1.59, 0.0]
    left = [-0.80, 1.42, 0.0]
    if t < 1.2:
        right = [0.80, 1.42, 0.0]
    else:
        # Bring the right hand round to straight ahead at shoulder height over one second.
        a = min(1.0, (t - 1.2) / 1.0)
        right = [0.80 * (1 - a) + 0.20 * a, 1.42, 0.55 * a]
    if headset_only:
        # Unity turns right for a positive angle about +Y: left is negative.
        half = -math.radians(30.0) * min(1.0, max(0.0, t - 1.2)) / 2
        client.send_message("/VMC/Ext/Hmd/Pos", ["HMD"] + hmd + [0.0, math.sin(half), 0.0, math.cos(half)])
    else:
        client.send_message("/VMC/Ext/Hmd/Pos", ["HMD"] + hmd + identity)
        client.send_message("/VMC/Ext/Con/Pos", ["LeftHand"] + left + identity)
        client.send_message("/VMC/Ext/Con/Pos", ["RightHand"] + right + identity)
    sent += 1
    time.sleep(max(0.0, start + sent / 60.0 - time.monotonic()))
print(sent)

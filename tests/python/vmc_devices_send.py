"""An independent five-point VMC sender: python-osc (PyPI), unmodified, as a VR runtime's bridge
would use it.

Usage: vmc_devices_send.py PORT [SECONDS]
Sends, in Unity axes (x right, y up, z forward, left handed), what a 1.70 m operator wears at 72 Hz,
one OSC bundle per frame: the headset (/VMC/Ext/Hmd/Pos), two controllers (/VMC/Ext/Con/Pos, serials
naming their hand) and a tracker on each foot's instep (/VMC/Ext/Tra/Pos, serials naming their
side), all axis-aligned. A T-pose for 1.5 s, then squats of up to 25 cm (the feet still) while the
right hand waves above the shoulder, until SECONDS (default 8) have passed.
"""
import math
import sys
import time

from pythonosc import osc_bundle_builder, osc_message_builder
from pythonosc.udp_client import SimpleUDPClient

port = int(sys.argv[1])
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 8.0
client = SimpleUDPClient("127.0.0.1", port)

EYES = 0.936 * 1.70
SHOULDERS = 0.818 * 1.70
REACH = 0.85
IDENTITY = [0.0, 0.0, 0.0, 1.0]
RATE = 72.0


def devices(t):
    """(address, serial, position) of every device at `t` seconds."""
    moving = max(0.0, t - 1.5)
    drop = 0.25 * (1 - math.cos(2 * math.pi * moving / 3.0)) / 2
    wave = 0.6 * (1 - math.cos(2 * math.pi * moving / 1.5)) / 2
    return [
        ("/VMC/Ext/Hmd/Pos", "HMD", [0.0, EYES - drop, 0.0]),
        ("/VMC/Ext/Con/Pos", "LeftHand", [-REACH, SHOULDERS - drop, 0.0]),
        (
            "/VMC/Ext/Con/Pos",
            "RightHand",
            [REACH * math.cos(wave), SHOULDERS - drop + REACH * math.sin(wave), 0.0],
        ),
        ("/VMC/Ext/Tra/Pos", "tracker_left_foot", [-0.09, 0.12, 0.06]),
        ("/VMC/Ext/Tra/Pos", "tracker_right_foot", [0.09, 0.12, 0.06]),
    ]


start = time.monotonic()
sent = 0
while True:
    t = time.monotonic() - start
    if t > seconds:
        break
    bundle = osc_bundle_builder.OscBundleBuilder(osc_bundle_builder.IMMEDIATELY)
    for address, serial, p in devices(t):
        m = osc_message_builder.OscMessageBuilder(address=address)
        for v in [serial] + p + IDENTITY:
            m.add_arg(v)
        bundle.add_content(m.build())
    client.send(bundle.build())
    sent += 1
    time.sleep(max(0.0, start + sent / RATE - time.monotonic()))
print(sent)

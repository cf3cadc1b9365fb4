"""Independent client: python-can's socketcand interface drives an emulated Robstride motor in
its factory protocol.

Frames are packed here from the protocol description (29-bit ID = type << 24 | data2 << 8 |
target; big-endian 16-bit fields over the model's ranges), not from this project's code. The
script asks the motor's ID, reads its run mode, enables it, commands a position step at 100 Hz,
stops it, and prints a JSON summary. Exit code 0 only when every answer has the expected shape.

usage: robstride_over_socketcand.py HOST PORT MOTOR_ID P_MAX V_MAX T_MAX KP_MAX KD_MAX
"""
import json
import struct
import sys
import time

import can

HOST_ID = 0xFD
GET_ID, CONTROL, FEEDBACK, ENABLE, STOP, READ_PARAM = 0x00, 0x01, 0x02, 0x03, 0x04, 0x11
RUN_MODE = 0x7005


def to_uint(x, lo, hi):
    x = min(max(x, lo), hi)
    return int((x - lo) * 65535 / (hi - lo))


def to_float(u, lo, hi):
    return u * (hi - lo) / 65535 + lo


def main():
    host, port, motor = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    pm, vm, tm, kpm, kdm = (float(a) for a in sys.argv[4:9])
    bus = can.Bus(interface="socketcand", host=host, port=port, channel="can0")

    def frame_id(kind, data2, target):
        return (kind << 24) | (data2 << 8) | target

    def exchange(kind, data2, data, want):
        bus.send(can.Message(arbitration_id=frame_id(kind, data2, motor), data=data, is_extended_id=True))
        deadline = time.time() + 0.5
        while time.time() < deadline:
            msg = bus.recv(timeout=0.1)
            if msg is not None and msg.is_extended_id and (msg.arbitration_id >> 24) == want:
                return msg
        raise SystemExit(f"no answer of type {want:#x} from the motor")

    def feedback(msg):
        ident = msg.arbitration_id
        p, v, t, temp = struct.unpack(">HHHH", bytes(msg.data))
        return {
            "motor": (ident >> 8) & 0xFF,
            "host": ident & 0xFF,
            "faults": (ident >> 16) & 0x3F,
            "mode": (ident >> 22) & 0x03,
            "p": to_float(p, -pm, pm),
            "v": to_float(v, -vm, vm),
            "t": to_float(t, -tm, tm),
            "temperature": temp / 10,
        }

    def control(p, v, kp, kd, t):
        data = struct.pack(">HHHH", to_uint(p, -pm, pm), to_uint(v, -vm, vm), to_uint(kp, 0, kpm), to_uint(kd, 0, kdm))
        return feedback(exchange(CONTROL, to_uint(t, -tm, tm), data, FEEDBACK))

    summary = {}
    ident = exchange(GET_ID, HOST_ID, bytes(8), GET_ID)
    summary["get_id"] = {"motor": (ident.arbitration_id >> 8) & 0xFF, "target": ident.arbitration_id & 0xFF}
    answer = exchange(READ_PARAM, HOST_ID, struct.pack("<HHI", RUN_MODE, 0, 0), READ_PARAM)
    index, _, value = struct.unpack("<HHI", bytes(answer.data))
    summary["run_mode"] = value & 0xFF if index == RUN_MODE else None
    summary["enable"] = feedback(exchange(ENABLE, HOST_ID, bytes(8), FEEDBACK))
    start = control(0, 0, 0, 0, 0)["p"]
    target = start + 1.0
    last = None
    for _ in range(150):  # 1.5 s at 100 Hz
        last = control(target, 0, 20, 1, 0)
        time.sleep(0.01)
    summary["final"] = last
    summary["target"] = target
    summary["stop"] = feedback(exchange(STOP, HOST_ID, bytes(8), FEEDBACK))
    bus.shutdown()
    print(json.dumps(summary))
    ok = (
        summary["get_id"] == {"motor": motor, "target": 0xFE}
        and summary["enable"]["host"] == HOST_ID
        and summary["enable"]["motor"] == motor
        and abs(last["p"] - target) < 0.05
    )
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()

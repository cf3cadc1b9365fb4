"""Independent client: python-can's socketcand interface drives an emulated MIT motor.

Packs MIT-mode frames from the protocol description (not from this project's code), enables the
motor, commands a position step, reads the replies and prints a JSON summary. Exit code 0 only when
every check passes.

usage: mit_over_socketcand.py HOST PORT MOTOR_ID P_MAX V_MAX T_MAX
"""
import json
import sys
import time

import can


def to_uint(x, lo, hi, bits):
    x = min(max(x, lo), hi)
    return int((x - lo) * ((1 << bits) - 1) / (hi - lo))


def to_float(u, lo, hi, bits):
    return u * (hi - lo) / ((1 << bits) - 1) + lo


def pack(p, v, kp, kd, t, pm, vm, tm):
    p, v = to_uint(p, -pm, pm, 16), to_uint(v, -vm, vm, 12)
    kp, kd, t = to_uint(kp, 0, 500, 12), to_uint(kd, 0, 5, 12), to_uint(t, -tm, tm, 12)
    return bytes([p >> 8, p & 0xFF, v >> 4, ((v & 0xF) << 4) | (kp >> 8), kp & 0xFF, kd >> 4, ((kd & 0xF) << 4) | (t >> 8), t & 0xFF])


def main():
    host, port, motor = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    pm, vm, tm = (float(a) for a in sys.argv[4:7])
    bus = can.Bus(interface="socketcand", host=host, port=port, channel="can0")

    def exchange(data):
        # Replies to earlier commands that came late (a busy machine) are not this one's.
        while bus.recv(timeout=0) is not None:
            pass
        bus.send(can.Message(arbitration_id=motor, data=data, is_extended_id=False))
        deadline = time.time() + 0.5
        while time.time() < deadline:
            msg = bus.recv(timeout=0.1)
            if msg is not None and msg.data[0] == motor:
                return msg
        raise SystemExit("no reply from the motor")

    def decode(msg):
        d = msg.data
        p = to_float((d[1] << 8) | d[2], -pm, pm, 16)
        v = to_float((d[3] << 4) | (d[4] >> 4), -vm, vm, 12)
        t = to_float(((d[4] & 0xF) << 8) | d[5], -tm, tm, 12)
        return {"id": msg.arbitration_id, "len": len(d), "p": p, "v": v, "t": t, "temp": d[6], "err": d[7]}

    summary = {}
    summary["enable"] = decode(exchange(bytes([0xFF] * 7 + [0xFC])))
    start = decode(exchange(pack(0, 0, 0, 0, 0, pm, vm, tm)))["p"]
    target = start + 1.0
    last = None
    for _ in range(150):  # 1.5 s at 100 Hz
        last = decode(exchange(pack(target, 0, 20, 1, 0, pm, vm, tm)))
        time.sleep(0.01)
    summary["final"] = last
    summary["target"] = target
    summary["disable"] = decode(exchange(bytes([0xFF] * 7 + [0xFD])))
    bus.shutdown()
    print(json.dumps(summary))
    ok = abs(last["p"] - target) < 0.05 and last["err"] == 0 and summary["enable"]["len"] == 8 and summary["enable"]["id"] == 0
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()

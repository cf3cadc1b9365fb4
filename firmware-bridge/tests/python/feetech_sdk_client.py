"""Independent client: Feetech's own Python SDK (feetech-servo-sdk, scservo_sdk) against the
emulated STS servos on a pseudo-terminal. Pings, reads, writes, sync-writes goal positions and
sync-reads present positions, as a LeRobot-style arm driver does; prints one JSON object.

usage: feetech_sdk_client.py DEVICE BAUD ID...
"""
import json
import sys
import time

import scservo_sdk as scs

ADDR_TORQUE_ENABLE, ADDR_GOAL_POSITION, ADDR_LOCK = 40, 42, 55
ADDR_PRESENT_POSITION, ADDR_STATUS, ADDR_RETURN_DELAY = 56, 65, 7


def main():
    device, baud, ids = sys.argv[1], int(sys.argv[2]), [int(a) for a in sys.argv[3:]]
    port = scs.PortHandler(device)
    if not port.openPort() or not port.setBaudRate(baud):
        raise SystemExit("cannot open the port")
    ph = scs.PacketHandler(0)  # STS: little-endian
    out = {"ping": {}, "goals": {}, "present": {}}
    for i in ids + [9]:
        model, result, error = ph.ping(port, i)
        out["ping"][str(i)] = {"ok": result == scs.COMM_SUCCESS, "model": model, "error": error}
    # A single read and write with their status packets.
    value, result, error = ph.read1ByteTxRx(port, ids[0], ADDR_LOCK)
    out["lock"] = {"ok": result == scs.COMM_SUCCESS, "value": value, "error": error}
    result, error = ph.write1ByteTxRx(port, ids[0], ADDR_RETURN_DELAY, 5)
    value, _, _ = ph.read1ByteTxRx(port, ids[0], ADDR_RETURN_DELAY)
    out["return_delay"] = {"ok": result == scs.COMM_SUCCESS, "value": value}
    for i in ids:
        ph.write1ByteTxRx(port, i, ADDR_TORQUE_ENABLE, 1)
    # Sync write: each servo a goal 300 ticks from the middle, alternating sides.
    writer = scs.GroupSyncWrite(port, ph, ADDR_GOAL_POSITION, 2)
    for k, i in enumerate(ids):
        goal = 2048 + (300 if k % 2 == 0 else -300)
        out["goals"][str(i)] = goal
        writer.addParam(i, [scs.SCS_LOBYTE(goal), scs.SCS_HIBYTE(goal)])
    out["sync_write"] = writer.txPacket() == scs.COMM_SUCCESS
    time.sleep(1.0)
    reader = scs.GroupSyncRead(port, ph, ADDR_PRESENT_POSITION, 2)
    for i in ids:
        reader.addParam(i)
    out["sync_read_ok"] = reader.txRxPacket() == scs.COMM_SUCCESS
    for i in ids:
        out["present"][str(i)] = reader.getData(i, ADDR_PRESENT_POSITION, 2) if reader.isAvailable(i, ADDR_PRESENT_POSITION, 2) else None
    status, result, _ = ph.read1ByteTxRx(port, ids[0], ADDR_STATUS)
    out["status"] = status
    port.closePort()
    print(json.dumps(out))


if __name__ == "__main__":
    main()

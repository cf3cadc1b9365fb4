"""ROBOTIS's own dynamixel-sdk, unmodified, against the emulated servos on a pseudo-terminal.

Usage: dxl_sdk_client.py DEVICE BAUD. Prints one JSON object of what the servos answered.
"""
import json
import sys
import time

from dynamixel_sdk import COMM_SUCCESS, GroupBulkRead, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

device, baud = sys.argv[1], int(sys.argv[2])
port = PortHandler(device)
assert port.openPort() and port.setBaudRate(baud), "cannot open the port"
ph = PacketHandler(2.0)
out = {}

out["ping"] = {}
for dxl_id in (1, 2, 3, 9):
    model, result, error = ph.ping(port, dxl_id)
    out["ping"][str(dxl_id)] = {"model": model, "ok": result == COMM_SUCCESS, "error": error}

def write1(dxl_id, address, value):
    result, error = ph.write1ByteTxRx(port, dxl_id, address, value)
    return {"ok": result == COMM_SUCCESS, "error": error}

def read(dxl_id, address, size):
    reader = {1: ph.read1ByteTxRx, 2: ph.read2ByteTxRx, 4: ph.read4ByteTxRx}[size]
    value, result, error = reader(port, dxl_id, address)
    return {"value": value, "ok": result == COMM_SUCCESS, "error": error}

out["torque_before"] = read(1, 64, 1)
out["mode_write_torque_off"] = write1(1, 11, 4)
out["mode_read_back"] = read(1, 11, 1)
out["mode_restore"] = write1(1, 11, 3)
out["mode_out_of_range"] = write1(2, 11, 2)
for dxl_id in (1, 2, 3):
    out[f"torque_on_{dxl_id}"] = write1(dxl_id, 64, 1)
out["eeprom_with_torque_on"] = write1(1, 11, 4)
result, error = ph.write4ByteTxRx(port, 1, 116, 5000)
out["goal_beyond_limit"] = {"ok": result == COMM_SUCCESS, "error": error}

goals = {1: 2048 + 300, 2: 2048 - 300, 3: 2048 + 500}
writer = GroupSyncWrite(port, ph, 116, 4)
for dxl_id, goal in goals.items():
    writer.addParam(dxl_id, list(goal.to_bytes(4, "little")))
out["sync_write"] = writer.txPacket() == COMM_SUCCESS
time.sleep(0.8)

reader = GroupSyncRead(port, ph, 132, 4)
for dxl_id in goals:
    reader.addParam(dxl_id)
out["sync_read_ok"] = reader.txRxPacket() == COMM_SUCCESS
present = {}
for dxl_id in goals:
    value = reader.getData(dxl_id, 132, 4)
    present[str(dxl_id)] = value - (1 << 32) if value >= 1 << 31 else value
out["present"] = present
out["goals"] = {str(k): v for k, v in goals.items()}

# The fast reads: one status packet for all (ID 0xFE), parsed by the SDK's own code.
fast = GroupSyncRead(port, ph, 132, 4)
for dxl_id in goals:
    fast.addParam(dxl_id)
out["fast_sync_read_ok"] = fast.fastSyncRead() == COMM_SUCCESS
out["fast_present"] = {}
for dxl_id in goals:
    value = fast.getData(dxl_id, 132, 4)
    out["fast_present"][str(dxl_id)] = value - (1 << 32) if value >= 1 << 31 else value
bulk = GroupBulkRead(port, ph)
# Each its own field: servo 1 its position, 2 its model number, 3 its temperature.
bulk.addParam(1, 132, 4)
bulk.addParam(2, 0, 2)
bulk.addParam(3, 146, 1)
out["fast_bulk_read_ok"] = bulk.fastBulkRead() == COMM_SUCCESS
out["fast_bulk"] = {
    "position_1": bulk.getData(1, 132, 4),
    "model_2": bulk.getData(2, 0, 2),
    "temperature_3": bulk.getData(3, 146, 1),
}
out["hardware_error"] = read(3, 70, 1)
port.closePort()
print(json.dumps(out))

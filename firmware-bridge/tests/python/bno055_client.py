"""Adafruit's BNO055 driver (adafruit-circuitpython-bno055, its UART class, unmodified) against
the emulated chip on a pseudo-terminal: it checks the chip ID, restarts the chip, sets normal
power, page 0, the sensor ranges on page 1 and NDOF mode, then reads every output once.

Usage: bno055_client.py DEVICE. Prints one JSON object; exits non-zero on any error.
"""

import json
import sys

import adafruit_bno055
import serial


def main() -> int:
    uart = serial.Serial(sys.argv[1], 115200, timeout=0.5)
    sensor = adafruit_bno055.BNO055_UART(uart)
    print(
        json.dumps(
            {
                "mode": sensor.mode,
                "accel_range": sensor.accel_range,
                "gyro_range": sensor.gyro_range,
                "temperature": sensor.temperature,
                "acceleration": sensor.acceleration,
                "gyro": sensor.gyro,
                "euler": sensor.euler,
                "quaternion": sensor.quaternion,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

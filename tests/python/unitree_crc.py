"""Checks robodeploy's unitree_hg packing and CRC against Unitree's own SDK (unitree_sdk2 on PyPI):
the SDK's struct formats for the packed LowCmd_/LowState_ must read robodeploy's bytes back into
the fields in IDL order, and the SDK's pure-Python CRC (`CRC._crc_py` over `CRC.__Trans`) must give
the CRC robodeploy sealed them with. The SDK's module imports the Cyclone DDS binding at its top, so
the two functions and the formats are taken from its source text, not imported (unitree_sdk.py).

robodeploy's CDR of each message (what DDS carries) is read by the SDK's own IDL classes (through
the Cyclone DDS binding's serializer): the SDK must write the same bytes back, and its own packing
of the message it read must equal robodeploy's packed layout.

Usage: unitree_crc.py CASES.json   (a list of {kind, packed_hex, cdr_hex, fields}; prints a JSON verdict)
"""
import json
import pathlib
import struct
import sys

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from unitree_sdk import LowCmd_, LowState_, formats, functions, packed_words  # noqa: E402

cases = json.loads(pathlib.Path(sys.argv[1]).read_text())
results = []
for case in cases:
    fmt = formats["__packFmtHGLowCmd" if case["kind"] == "LowCmd" else "__packFmtHGLowState"]
    packed = bytes.fromhex(case["packed_hex"])
    size_ok = struct.calcsize(fmt) == len(packed)
    values = list(struct.unpack(fmt, packed)) if size_ok else []
    fields_ok = size_ok and all(
        (abs(a - b) <= 1e-6 * max(1.0, abs(b))) if isinstance(b, float) else a == b
        for a, b in zip(values, case["fields"])) and len(values) == len(case["fields"])
    sdk_crc = functions["_crc_py"](None, functions["__Trans"](None, packed))
    cdr = bytes.fromhex(case["cdr_hex"])
    msg = (LowCmd_ if case["kind"] == "LowCmd" else LowState_).deserialize(cdr)
    # The SDK packs into the words its CRC reads: every word but the CRC's.
    words = packed_words(msg)
    cdr_ok = msg.serialize() == cdr and b"".join(struct.pack("<I", w) for w in words) == packed[:-4]
    results.append(dict(kind=case["kind"], size=size_ok, fields=fields_ok, crc=sdk_crc == case["fields"][-1],
                        cdr=cdr_ok))
print(json.dumps(dict(formats=sorted(formats), results=results)))

"""Checks robodeploy's unitree_hg packing and CRC against Unitree's own SDK (unitree_sdk2 on PyPI):
the SDK's struct formats for the packed LowCmd_/LowState_ must read robodeploy's bytes back into
the fields in IDL order, and the SDK's pure-Python CRC (`CRC._crc_py` over `CRC.__Trans`) must give
the CRC robodeploy sealed them with. The SDK's module imports the Cyclone DDS binding at its top, so
the two functions and the formats are taken from its source text, not imported.

robodeploy's CDR of each message (what DDS carries) is read by the SDK's own IDL classes (through
the Cyclone DDS binding's serializer): the SDK must write the same bytes back, and its own packing
of the message it read must equal robodeploy's packed layout.

Usage: unitree_crc.py CASES.json   (a list of {kind, packed_hex, cdr_hex, fields}; prints a JSON verdict)
"""
import ast
import importlib.util
import json
import pathlib
import struct
import sys
import types

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import unitree_sdk  # noqa: E402,F401  (registers the SDK's package)
from unitree_sdk2py.idl.unitree_hg.msg.dds_ import LowCmd_, LowState_  # noqa: E402

spec = importlib.util.find_spec("unitree_sdk2py")
source = (pathlib.Path(spec.submodule_search_locations[0]) / "utils" / "crc.py").read_text()
tree = ast.parse(source)
crc_class = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "CRC")
formats, functions = {}, {}
for node in crc_class.body:
    if isinstance(node, ast.FunctionDef) and node.name == "__init__":
        for stmt in ast.walk(node):
            if isinstance(stmt, ast.Assign) and isinstance(stmt.targets[0], ast.Attribute):
                name = stmt.targets[0].attr
                if name.startswith("__packFmt"):
                    formats[name] = eval(compile(ast.Expression(stmt.value), "crc.py", "eval"))
    if isinstance(node, ast.FunctionDef) and node.name in (
            "_crc_py", "__Trans", "__PackHGLowCmd", "__PackHGLowState"):
        # What the SDK's module has in scope for them (their annotations name the message types).
        namespace = dict(struct=struct, HGLowCmd_=LowCmd_, HGLowState_=LowState_, LowCmd_=None, LowState_=None)
        exec(compile(ast.Module([node], []), "crc.py", "exec"), namespace)
        functions[node.name] = namespace[node.name]

# The SDK's packing functions, run on a stand-in for the CRC object (their `self.__x` is not
# name-mangled once taken out of the class).
sdk = types.SimpleNamespace()
for name, fmt in formats.items():
    setattr(sdk, name, fmt)
setattr(sdk, "__Trans", lambda data: functions["__Trans"](None, data))

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
    cls, pack = (LowCmd_, "__PackHGLowCmd") if case["kind"] == "LowCmd" else (LowState_, "__PackHGLowState")
    msg = cls.deserialize(cdr)
    # The SDK packs into the words its CRC reads: every word but the CRC's.
    words = functions[pack](sdk, msg)
    cdr_ok = msg.serialize() == cdr and b"".join(struct.pack("<I", w) for w in words) == packed[:-4]
    results.append(dict(kind=case["kind"], size=size_ok, fields=fields_ok, crc=sdk_crc == case["fields"][-1],
                        cdr=cdr_ok))
print(json.dumps(dict(formats=sorted(formats), results=results)))

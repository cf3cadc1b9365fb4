"""Checks robodeploy's unitree_hg packing and CRC against Unitree's own SDK (unitree_sdk2 on PyPI):
the SDK's struct formats for the packed LowCmd_/LowState_ must read robodeploy's bytes back into
the fields in IDL order, and the SDK's pure-Python CRC (`CRC._crc_py` over `CRC.__Trans`) must give
the CRC robodeploy sealed them with. The SDK's module imports the Cyclone DDS binding at its top, so
the two functions and the formats are taken from its source text, not imported.

Usage: unitree_crc.py CASES.json   (a list of {kind, packed_hex, fields}; prints a JSON verdict)
"""
import ast
import importlib.util
import json
import pathlib
import struct
import sys

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
    if isinstance(node, ast.FunctionDef) and node.name in ("_crc_py", "__Trans"):
        namespace = {}
        exec(compile(ast.Module([node], []), "crc.py", "exec"), namespace)
        functions[node.name] = namespace[node.name]

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
    results.append(dict(kind=case["kind"], size=size_ok, fields=fields_ok, crc=sdk_crc == case["fields"][-1]))
print(json.dumps(dict(formats=sorted(formats), results=results)))

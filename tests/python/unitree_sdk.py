"""Unitree's Python SDK (unitree_sdk2 1.0.1 from PyPI) as far as its wheel allows.

The wheel's package `__init__` imports a `b2` subpackage the wheel does not ship, so importing
`unitree_sdk2py` fails; its modules themselves are whole. This registers the package without
running its `__init__`, after which `unitree_sdk2py.core.channel`, `.idl.*` and `.utils.crc`'s
source import as the SDK's own examples use them (with the Cyclone DDS binding, PyPI `cyclonedds`).

The SDK's CRC class loads a native `crc_amd64.so` its wheel lacks on Linux, so its pure-Python CRC
(`CRC._crc_py` over `CRC.__Trans`), its packing functions and struct formats are taken from its
source text: `formats`, `functions`, and `sdk_crc(msg)` (what `CRC().Crc(msg)` computes for the
unitree_hg messages).
"""
import ast
import importlib.util
import pathlib
import struct
import sys
import types

_spec = importlib.util.find_spec("unitree_sdk2py")
if _spec is None:
    raise SystemExit("unitree_sdk2py is not installed: run scripts/setup")
_package = types.ModuleType("unitree_sdk2py")
_package.__path__ = list(_spec.submodule_search_locations)
_package.__spec__ = _spec
sys.modules.setdefault("unitree_sdk2py", _package)

from unitree_sdk2py.idl.unitree_hg.msg.dds_ import LowCmd_, LowState_  # noqa: E402

_source = (pathlib.Path(_spec.submodule_search_locations[0]) / "utils" / "crc.py").read_text()
_crc_class = next(n for n in ast.parse(_source).body if isinstance(n, ast.ClassDef) and n.name == "CRC")
formats, functions = {}, {}
for _node in _crc_class.body:
    if isinstance(_node, ast.FunctionDef) and _node.name == "__init__":
        for _stmt in ast.walk(_node):
            if isinstance(_stmt, ast.Assign) and isinstance(_stmt.targets[0], ast.Attribute):
                _name = _stmt.targets[0].attr
                if _name.startswith("__packFmt"):
                    formats[_name] = eval(compile(ast.Expression(_stmt.value), "crc.py", "eval"))
    if isinstance(_node, ast.FunctionDef) and _node.name in (
            "_crc_py", "__Trans", "__PackHGLowCmd", "__PackHGLowState"):
        # What the SDK's module has in scope for them (their annotations name the message types).
        _scope = dict(struct=struct, HGLowCmd_=LowCmd_, HGLowState_=LowState_, LowCmd_=None, LowState_=None)
        exec(compile(ast.Module([_node], []), "crc.py", "exec"), _scope)
        functions[_node.name] = _scope[_node.name]

# The SDK's packing functions run on a stand-in for the CRC object (their `self.__x` is not
# name-mangled once taken out of the class).
sdk = types.SimpleNamespace()
for _name, _fmt in formats.items():
    setattr(sdk, _name, _fmt)
setattr(sdk, "__Trans", lambda data: functions["__Trans"](None, data))


def packed_words(msg):
    """The SDK's packing of a unitree_hg LowCmd_/LowState_: the words its CRC reads."""
    pack = "__PackHGLowCmd" if isinstance(msg, LowCmd_) else "__PackHGLowState"
    return functions[pack](sdk, msg)


def sdk_crc(msg):
    """The CRC the SDK gives a unitree_hg LowCmd_ or LowState_ (`CRC().Crc(msg)`)."""
    return functions["_crc_py"](None, packed_words(msg))

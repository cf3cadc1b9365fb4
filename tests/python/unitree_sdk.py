"""Imports Unitree's Python SDK (unitree_sdk2 1.0.1 from PyPI) as far as its wheel allows.

The wheel's package `__init__` imports a `b2` subpackage the wheel does not ship, so importing
`unitree_sdk2py` fails; its modules themselves are whole. This registers the package without
running its `__init__`, after which `unitree_sdk2py.core.channel`, `.idl.*` and `.utils.crc`
import as the SDK's own examples use them (with the Cyclone DDS binding, PyPI `cyclonedds`).
"""
import importlib.util
import sys
import types

_spec = importlib.util.find_spec("unitree_sdk2py")
if _spec is None:
    raise SystemExit("unitree_sdk2py is not installed: run scripts/setup")
_package = types.ModuleType("unitree_sdk2py")
_package.__path__ = list(_spec.submodule_search_locations)
_package.__spec__ = _spec
sys.modules.setdefault("unitree_sdk2py", _package)

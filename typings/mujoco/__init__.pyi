# Partial stub for MuJoCo for pyright (the stub path is set in pyproject.toml).
#
# MuJoCo's Python API is pybind11 extension modules (mujoco._functions, _structs, _enums, ...)
# star-imported by mujoco/__init__.py and shipped without type stubs, so a type checker sees none
# of its names (mj_forward, MjSpec, mjtGeom, ...). A module-level __getattr__ is PEP 484's way to
# declare a stub incomplete: every attribute of `mujoco` is typed Any.
from typing import Any

def __getattr__(name: str) -> Any: ...

"""Deprecated module aliases: old names that resolve, with a warning, for one release (private to jaxsem)."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Mapping

__all__ = ["moved_attribute"]


def moved_attribute(module: str, moved: Mapping[str, str], name: str):
    """The module-level ``__getattr__`` of a deprecated alias ``module``.

    ``moved`` maps each old name to the module it now lives in; that name is returned from there
    with a :class:`DeprecationWarning` pointing at the caller's line. Other names raise
    ``AttributeError`` as a plain module would.
    """
    if name in moved:
        target = moved[name]
        warnings.warn(
            f"{module}.{name} moved to {target}.{name}; the old name goes in the next release",
            DeprecationWarning,
            stacklevel=3,
        )
        return getattr(importlib.import_module(target), name)
    raise AttributeError(f"module {module!r} has no attribute {name!r}")

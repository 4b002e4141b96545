"""Traced programs kept on disk next to JAX's persistent compilation cache (no re-tracing).

JAX's persistent compilation cache saves the XLA compile, but every new process still traces
the Python function and lowers it before it can look the executable up. For the online
smoother's step (:func:`jaxsem.slam.run_sequence`) tracing alone is a large share of a short
run. :func:`exported` keeps the traced and lowered program
(``jax.export``: StableHLO plus its calling convention) in
``<jax_compilation_cache_dir>/jaxsem-exports/`` and calls it from there: a later process only
parses it (much cheaper than tracing) and finds the executable in JAX's cache.

- On exactly when JAX's persistent compilation cache is (a directory set and
  ``jax_enable_compilation_cache`` true; the command line turns both on, ``--no-compilation-cache``
  off); otherwise, and whenever anything fails, the jitted function is called as usual.
- The key covers the jax / jaxlib versions, the backend, the x64 flag, the argument tree (static
  fields included), every argument's shape, dtype and weak type, and the source of the
  ``jaxsem`` package, so any code change re-traces.
- At most 16 programs per name are kept (the newest; about 150 kB each for the online step).
- The file holds the ``jax.export.Exported`` in JAX's own serialisation (``Exported.serialize``,
  flatbuffers: loading it runs no Python code).
- Why not the compiled executable itself (``jax.experimental.serialize_executable``)? Loaded
  that way the online step crashed the process on the CPU (``benchmarks/RESULTS.md``, "Other:
  devices and design measurements"), so only the portable program is kept.
"""

from __future__ import annotations

import functools
import hashlib
import pathlib
from collections.abc import Callable
from importlib.metadata import version
from typing import Any

import jax
import numpy as np

from .._atomic import atomic_write_bytes

__all__ = ["cache_folder", "exported"]

_FOLDER = "jaxsem-exports"
_KEEP = 16  # programs kept per name (each about 150 kB for the online step)
#: Programs already loaded in this process, by file: a second call of :func:`exported` for the same
#: program reuses its jitted call instead of reading, lowering and fetching the executable again.
_LOADED: dict[str, Callable] = {}
_LOADED_MAX = 64


def cache_folder() -> pathlib.Path | None:
    """Where traced programs are kept, or None when JAX's persistent compilation cache is off."""
    folder = getattr(jax.config, "jax_compilation_cache_dir")
    if not folder or not getattr(jax.config, "jax_enable_compilation_cache"):
        return None
    return pathlib.Path(folder) / _FOLDER


@functools.cache
def _source_digest() -> str:
    root = pathlib.Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _aval(x) -> str:
    return f"{np.shape(x)}:{jax.numpy.result_type(x)}:{bool(getattr(x, 'weak_type', False))}"


def _key(name: str, leaves, tree) -> str:
    device = jax.devices()[0]
    h = hashlib.sha256()
    for part in (
        name,
        jax.__version__,
        version("jaxlib"),
        device.client.platform,
        device.client.platform_version,
        str(device.device_kind),
        str(getattr(jax.config, "jax_enable_x64")),
        str(tree),
        ";".join(_aval(x) for x in leaves),
        _source_digest(),
    ):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:32]


def _save(path: pathlib.Path, data: bytes) -> None:
    atomic_write_bytes(path, data, record=False)  # a cache entry, not a run's output


def _evict(folder: pathlib.Path, name: str, keep: int) -> None:
    """Keeps the ``keep`` newest programs of ``name`` (old code versions and shapes go)."""
    files = sorted(folder.glob(f"{name}-*.jaxexport"), key=lambda p: p.stat().st_mtime, reverse=True)
    for old in files[keep:]:
        old.unlink(missing_ok=True)


def _export(fn: Callable, leaves, tree):
    def flat(*flat_args):
        return jax.tree_util.tree_leaves(fn(*jax.tree_util.tree_unflatten(tree, flat_args)))

    return jax.export.export(jax.jit(flat))(*leaves)


def exported(name: str, fn: Callable, args: tuple, out_like: Any, folder: pathlib.Path | None = None) -> Callable:
    """A callable equal to ``jax.jit(fn)`` on arguments shaped like ``args``, traced at most once
    per code version and machine.

    Args:
      name: a label for the file name.
      fn: the Python function (not jitted; positional array / pytree arguments).
      args: example arguments (their tree and avals fix the program).
      out_like: a pytree with the tree structure of ``fn(*args)`` (e.g. the input state of a
        step that returns the same state type).
      folder: where to keep the program (default :func:`cache_folder`; None there: no file).

    Returns:
      ``call(*args) -> fn(*args)``: the program loaded from ``folder`` (or traced and saved
      there), called through ``jax.jit``; plain ``jax.jit(fn)`` when there is no folder or
      the file cannot be read or written.
    """
    folder = cache_folder() if folder is None else pathlib.Path(folder)
    plain = jax.jit(fn)
    if folder is None:
        return plain
    try:
        leaves, tree = jax.tree_util.tree_flatten(tuple(args))
        out_tree = jax.tree_util.tree_structure(out_like)
        path = folder / f"{name}-{_key(name, leaves, tree)}.jaxexport"
        call = _LOADED.get(str(path))
        if call is None:
            exp = None
            if path.exists():
                try:  # JAX's own format (flatbuffers): loading runs no code, unlike a pickle
                    exp = jax.export.deserialize(bytearray(path.read_bytes()))
                except Exception:
                    path.unlink(missing_ok=True)
            if exp is None:
                exp = _export(fn, leaves, tree)
                _save(path, bytes(exp.serialize()))
                _evict(folder, name, keep=_KEEP)
            call = jax.jit(exp.call)
            if len(_LOADED) >= _LOADED_MAX:
                _LOADED.pop(next(iter(_LOADED)))
            _LOADED[str(path)] = call
    except Exception:
        return plain

    def run(*a):
        flat, t = jax.tree_util.tree_flatten(tuple(a))
        if t != tree:  # another static configuration: the plain path
            return plain(*a)
        return jax.tree_util.tree_unflatten(out_tree, call(*flat))

    return run

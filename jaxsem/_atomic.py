"""Atomic file outputs, one implementation for the whole package: a temporary name next to the
target, renamed into place, so a failed or killed writer leaves nothing half-written.

Public through :mod:`jaxsem.scripting` (``atomic_write_text``, ...); the methods' own writers
(ROSHAN's compiled-step cache, LSD's expert shards, config files) use it from here. A command's
run (:func:`jaxsem.scripting.start_run`) hears of each recorded write through :data:`_WRITE_HOOKS`
and lists it in its summary.
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import tempfile
from collections.abc import Callable

import numpy as np

#: Called with each path written with ``record=True`` (the active run's bookkeeping).
_WRITE_HOOKS: list[Callable[[pathlib.Path], None]] = []

_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "", *, record: bool = True):
    """Yields a temporary path next to ``path``; on success it is renamed onto ``path``.

    On an exception the temporary file is removed and ``path`` is untouched. ``suffix`` keeps an
    extension some writers need (``.png``, ``.npz``). ``record=False``: not an output of the
    command's run (a cache entry, one data shard among hundreds), so not listed in its summary.
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix + ".tmp", dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; the file gets the mode open() would give
    tmp_path = pathlib.Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    if record:
        for hook in _WRITE_HOOKS:
            hook(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, record: bool = True) -> pathlib.Path:
    """Writes ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path, record=record) as tmp:
        tmp.write_bytes(data)
    return pathlib.Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, *, record: bool = True) -> pathlib.Path:
    """Writes ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"), record=record)


def atomic_savefig(fig, path: str | os.PathLike, **kwargs) -> pathlib.Path:
    """``fig.savefig`` to ``path`` atomically (the format is taken from ``path``'s extension)."""
    path = pathlib.Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def atomic_save_npz(path: str | os.PathLike, *, record: bool = True, **arrays) -> pathlib.Path:
    """``numpy.savez_compressed`` to ``path`` atomically."""
    with atomic_path(path, record=record) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    return pathlib.Path(path)

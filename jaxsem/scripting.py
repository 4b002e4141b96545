"""What every jaxsem command shares: one-line errors, checked flags, atomic outputs.

A command (``jaxsem ...``, ``train/*.py``, ``infer/*.py``, ``benchmarks/*.py``) follows three rules:

1. **Bad input fails well.** It exits non-zero with one line naming the flag or file and what
   was wrong; no traceback unless ``--debug`` is given. :func:`run_main` does this for a
   ``main(argv) -> int`` function: :class:`UsageError`, ``ValueError``, ``OSError`` (missing or
   unreadable files), ``json.JSONDecodeError``, ``zipfile.BadZipFile`` and ``KeyError`` become
   ``<prog>: error: <message>`` and exit status 2.
2. **Validate before long work.** The ``argparse`` types below (:func:`positive_int`,
   :func:`probability`, :func:`existing_file`, ...) reject a bad flag while parsing, naming it.
3. **Outputs are atomic.** :func:`atomic_write_text`, :func:`atomic_write_bytes`,
   :func:`atomic_savefig` and :func:`atomic_save_npz` write to a temporary name next to the
   target and rename it into place, so a failed run leaves nothing half-written.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import pathlib
import sys
import tempfile
import zipfile
from collections.abc import Callable, Sequence

__all__ = [
    "UsageError",
    "run_main",
    "wants_debug",
    "HelpFormatter",
    "positive_int",
    "nonnegative_int",
    "positive_float",
    "nonnegative_float",
    "finite_float",
    "probability",
    "existing_file",
    "existing_dir",
    "output_dir",
    "output_file",
    "int_list",
    "atomic_write_text",
    "atomic_write_bytes",
    "atomic_savefig",
    "atomic_save_npz",
    "atomic_path",
]


class UsageError(Exception):
    """Bad input found by a command: its message names the flag or file and what was wrong."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """``--help`` that keeps the description's line breaks and shows every default (except on a
    required flag, which has none, and where the help text already says what the default is)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if action.required or "default" in text.lower():
            return text
        return super()._get_help_string(action)


_EXPECTED = (UsageError, ValueError, OSError, json.JSONDecodeError, zipfile.BadZipFile, KeyError)


def wants_debug(argv: Sequence[str] | None = None) -> bool:
    """True if ``--debug`` is among the arguments (or ``JAXSEM_DEBUG=1`` is set)."""
    argv = sys.argv[1:] if argv is None else argv
    return "--debug" in argv or os.environ.get("JAXSEM_DEBUG") == "1"


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, KeyError) and exc.args:
        text = f"missing key {exc.args[0]!r}"
    elif isinstance(exc, FileNotFoundError) and exc.filename:
        text = f"{exc.filename}: no such file or directory"
    elif isinstance(exc, OSError) and exc.filename:
        text = f"{exc.filename}: {exc.strerror or exc}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


def run_main(
    main: Callable[[Sequence[str] | None], int | None], argv: Sequence[str] | None = None, prog: str | None = None
) -> int:
    """Runs ``main(argv)`` and turns expected failures into one line on stderr and exit status 2.

    ``--debug`` (or ``JAXSEM_DEBUG=1``) re-raises with the full traceback. ``SystemExit`` from
    argparse passes through (it already printed its one-line usage error). Returns the exit status
    (call as ``sys.exit(run_main(main))``).
    """
    prog = prog or pathlib.Path(sys.argv[0]).name
    try:
        status = main(argv)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except _EXPECTED as exc:
        if wants_debug(argv):
            raise
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    return int(status or 0)


# --------------------------------------------------------------------------------------------
# argparse types: each raises argparse.ArgumentTypeError, which argparse reports naming the flag.


def _number(text: str, kind):
    try:
        value = kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(
            f"expected {'an integer' if kind is int else 'a number'}, got {text!r}"
        ) from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _ranged(kind, name: str, what: str, low=None, high=None, low_open: bool = False):
    """An argparse type reading ``kind`` (int or finite float) within ``[low, high]`` (``(low, ...``
    when ``low_open``); the error says ``expected <what>``."""

    def parse(text: str):
        value = _number(text, kind)
        below = low is not None and (value <= low if low_open else value < low)
        if below or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value

    parse.__name__ = parse.__qualname__ = name
    parse.__doc__ = f"{what[0].upper()}{what[1:]}."
    return parse


positive_int: Callable[[str], int] = _ranged(int, "positive_int", "a positive integer", low=1)
nonnegative_int: Callable[[str], int] = _ranged(int, "nonnegative_int", "a non-negative integer", low=0)
finite_float: Callable[[str], float] = _ranged(float, "finite_float", "a finite number")
positive_float: Callable[[str], float] = _ranged(float, "positive_float", "a positive number", low=0.0, low_open=True)
nonnegative_float: Callable[[str], float] = _ranged(float, "nonnegative_float", "a non-negative number", low=0.0)
probability: Callable[[str], float] = _ranged(float, "probability", "a probability in [0, 1]", low=0.0, high=1.0)


def int_list(text: str) -> list[int]:
    """Comma- or space-separated integers, e.g. ``0,1,2``."""
    parts = [p for p in text.replace(",", " ").split() if p]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of integers, got {text!r}")
    return [_number(p, int) for p in parts]


def existing_file(text: str) -> pathlib.Path:
    """A path to an existing regular file."""
    path = pathlib.Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: not a file")
    return path


def existing_dir(text: str) -> pathlib.Path:
    """A path to an existing directory."""
    path = pathlib.Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such directory")
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: not a directory")
    return path


def output_dir(text: str) -> pathlib.Path:
    """A directory to write into: it may not exist yet, but must not be a file."""
    path = pathlib.Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is not a directory")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{text}: {parent} is not a directory")
            break
    return path


def output_file(text: str) -> pathlib.Path:
    """A file to write: not an existing directory, and its folder not a file."""
    path = pathlib.Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory, expected a file name")
    output_dir(str(path.parent) if str(path.parent) else ".")
    return path


# --------------------------------------------------------------------------------------------
# Atomic outputs.


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ""):
    """Yields a temporary path next to ``path``; on success it is renamed onto ``path``.

    On an exception the temporary file is removed and ``path`` is untouched. ``suffix`` keeps an
    extension some writers need (``.png``, ``.npz``).
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix + ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = pathlib.Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> pathlib.Path:
    """Writes ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return pathlib.Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> pathlib.Path:
    """Writes ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_savefig(fig, path: str | os.PathLike, **kwargs) -> pathlib.Path:
    """``fig.savefig`` to ``path`` atomically (the format is taken from ``path``'s extension)."""
    path = pathlib.Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def atomic_save_npz(path: str | os.PathLike, **arrays) -> pathlib.Path:
    """``numpy.savez_compressed`` to ``path`` atomically."""
    import numpy as np

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    return pathlib.Path(path)

"""Run directories, the record of one command call (rule 4 of :mod:`jaxsem.scripting`)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import json
import math
import os
import pathlib
import sys
import time
from collections.abc import Iterator, Mapping
from importlib import metadata
from typing import Any

from .. import _atomic
from .._atomic import atomic_write_text
from ..config import to_dict
from ._arguments import output_dir
from ._errors import _EXPECTED, HelpFormatter, UsageError, _one_line

# --------------------------------------------------------------------------------------------
# Run directories: the record of one command call.

FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
RUN_DIR_ENV = "JAXSEM_RUNS_DIR"


class CommandParser(argparse.ArgumentParser):
    """The parser of a jaxsem command (made by :func:`command_parser`). The shared run options come
    after the command's own flags (added when the parser is first used), and a ``parser.error``
    raised while a run is active (a check made after parsing) also goes into ``summary.json``."""

    run_dir_default: str | None = None
    _run_options_added = False

    def _add_run_options(self) -> None:
        if self._run_options_added:
            return
        self._run_options_added = True
        group = self.add_argument_group(
            "run options (every jaxsem command)",
            "Each run writes config.json (every argument after defaults, jaxsem/jax versions, the\n"
            "command line) at the start and summary.json (status ok/error with the one-line message,\n"
            "wall time, headline numbers, the figures and files written) at the end into its run\n"
            "directory, whose path is the first line of output.",
        )
        group.add_argument(
            "--run-dir",
            type=output_dir,
            default=None,
            help="run directory (default: "
            + (self.run_dir_default or f"runs/<command>-<UTC time>, under ${RUN_DIR_ENV} when set")
            + ")",
        )
        group.add_argument(
            "--no-compilation-cache",
            action="store_true",
            help="do not use JAX's persistent compilation cache (default: on, in $JAXSEM_CACHE_DIR or "
            "~/.cache/jaxsem/jax; JAXSEM_NO_COMPILATION_CACHE=1 also turns it off)",
        )
        group.add_argument("--debug", action="store_true", help="show tracebacks on errors")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        self._add_run_options()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self._add_run_options()
        return super().format_usage()

    def format_help(self) -> str:
        self._add_run_options()
        return super().format_help()

    def error(self, message: str):  # type: ignore[override]
        if _ACTIVE is not None:
            _ACTIVE.error_message = " ".join(message.split())
        super().error(message)


def default_run_dir(name: str, now: datetime.datetime | None = None) -> pathlib.Path:
    """``runs/<name with '-' for spaces>-<UTC time>`` under ``$JAXSEM_RUNS_DIR`` (default: ``runs``
    in the working directory), e.g. ``runs/volumon-train-20250101T120000Z``."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    root = pathlib.Path(os.environ.get(RUN_DIR_ENV) or "runs")
    return root / f"{'-'.join(name.split())}-{now.strftime('%Y%m%dT%H%M%SZ')}"


def command_parser(prog: str | None, description: str | None, run_dir_default: str | None = None) -> CommandParser:
    """An argparse parser for a jaxsem command: :class:`HelpFormatter` (every default shown) and,
    after the command's own flags, the options every command shares under "run options":
    ``--run-dir`` (``run_dir_default`` says its default in ``--help``), ``--no-compilation-cache``
    and ``--debug`` (a command's own ``--debug`` gives way to it)."""
    parser = CommandParser(
        prog=prog, description=description, formatter_class=HelpFormatter, conflict_handler="resolve"
    )
    parser.run_dir_default = run_dir_default
    return parser


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (str, bool, int)) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if hasattr(value, "tolist"):  # numpy / jax scalars and arrays
        return _jsonable(value.tolist())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):  # a config
        return _jsonable(to_dict(value))
    return str(value)


def _versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": sys.version.split()[0]}
    for name in ("jaxsem", "jax", "jaxlib"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


class Run:
    """The run directory of one command call: ``config.json`` at the start, ``summary.json`` at
    the end. Made by :func:`start_run`; a command reaches the active one through :func:`record`
    (headline numbers) and :func:`record_output`, or :func:`active_run`."""

    def __init__(self, path: pathlib.Path, config: dict[str, Any]):
        self.path = path
        self.config = config
        self.results: dict[str, Any] = {}
        self.figures: list[str] = []
        self.outputs: list[str] = []
        self.error_message: str | None = None
        self.exit_status = 0
        self._start = time.perf_counter()
        self._own = {(path / "config.json").resolve(), (path / "summary.json").resolve()}

    def _wrote(self, path: str | os.PathLike) -> None:
        path = pathlib.Path(path)
        if path.resolve() in self._own:
            return
        names = self.figures if path.suffix.lower() in FIGURE_SUFFIXES else self.outputs
        if str(path) not in names:
            names.append(str(path))

    def _write(self, name: str, data: Mapping[str, Any]) -> None:
        atomic_write_text(self.path / name, json.dumps(_jsonable(data), indent=1) + "\n")

    def add_config(self, **sections: Any) -> None:
        """Adds resolved configuration (e.g. the training config after presets and ``--set``) to
        ``config.json``, rewritten atomically."""
        self.config.update(sections)
        self._write("config.json", self.config)

    def finish(self, status: str, error: str | None = None, exit_status: int = 0) -> dict[str, Any]:
        """Writes ``summary.json``; returns it."""
        summary = {
            "status": status,
            **({"error": error} if error is not None else {}),
            "exit_status": exit_status,
            "wall_seconds": round(time.perf_counter() - self._start, 3),
            "started": self.config.get("started"),
            "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "results": self.results,
            "figures": self.figures,
            "outputs": self.outputs,
        }
        self._write("summary.json", summary)
        return summary


_ACTIVE: Run | None = None


def _note_write(path: pathlib.Path) -> None:
    if _ACTIVE is not None:
        _ACTIVE._wrote(path)


_atomic._WRITE_HOOKS.append(_note_write)


def active_run() -> Run | None:
    """The run started by :func:`start_run` that is still going, or None (a command called as a
    plain function)."""
    return _ACTIVE


def record(**results: Any) -> None:
    """Headline numbers of the active run for ``summary.json`` (``results``); no-op without one."""
    if _ACTIVE is not None:
        _ACTIVE.results.update(_jsonable(results))


def record_config(**sections: Any) -> None:
    """Resolved configuration of the active run (e.g. a training config after presets and
    ``--set``) added to its ``config.json``; no-op without a run."""
    if _ACTIVE is not None:
        _ACTIVE.add_config(**sections)


def record_output(*paths: str | os.PathLike) -> None:
    """Files or folders the active run wrote without the atomic helpers (figures by their
    extension); no-op without a run."""
    if _ACTIVE is not None:
        for path in paths:
            _ACTIVE._wrote(path)


def _exit_message(exc: BaseException) -> tuple[int, str | None]:
    """(exit status, one-line message) of an exception leaving a command."""
    if isinstance(exc, SystemExit):
        if exc.code is None or exc.code == 0:
            return 0, None
        if isinstance(exc.code, int):
            return exc.code, None
        return 2, " ".join(str(exc.code).split())  # a command's message about its input: run_main's rule
    if isinstance(exc, KeyboardInterrupt):
        return 130, "interrupted"
    if isinstance(exc, _EXPECTED):
        return int(getattr(exc, "exit_status", 2)), _one_line(exc)
    return 1, f"{type(exc).__name__}: {_one_line(exc)}"


@contextlib.contextmanager
def start_run(
    path: str | os.PathLike, command: str, args: Mapping[str, Any] | argparse.Namespace, command_line: str, **extra
) -> Iterator[Run]:
    """Starts the run of ``command`` in ``path``: makes the folder, prints ``run directory: PATH``
    (the first line of the command's output), writes ``config.json`` (``args`` after defaults,
    versions, the command line, ``extra``), and on leaving writes ``summary.json``: status "ok",
    or "error" with the one-line message when the body raised (the exception goes on) or set
    ``run.exit_status`` to non-zero.

    Raises :class:`UsageError` naming ``--run-dir`` when the folder cannot be made."""
    global _ACTIVE
    path = pathlib.Path(path)
    if _ACTIVE is not None:
        raise RuntimeError(f"start_run: a run is already active in {_ACTIVE.path}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--run-dir: cannot create {path} ({exc.strerror or exc})") from None
    values = vars(args) if isinstance(args, argparse.Namespace) else dict(args)
    config = {
        "command": command,
        "command_line": command_line,
        "run_dir": str(path),
        "args": values,
        "versions": _versions(),
        "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "cwd": os.getcwd(),
        **extra,
    }
    run = Run(path, _jsonable(config))
    print(f"run directory: {path}", flush=True)
    run._write("config.json", run.config)
    _ACTIVE = run
    try:
        yield run
        if run.exit_status:
            run.finish("error", run.error_message or f"exit status {run.exit_status}", run.exit_status)
        else:
            run.finish("ok")
    except BaseException as exc:
        code, message = _exit_message(exc)
        message = message or run.error_message or f"exit status {code}"
        if code == 0:
            run.finish("ok")
        else:
            run.finish("error", message, code)
        raise
    finally:
        _ACTIVE = None

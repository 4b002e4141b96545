"""What every jaxsem command shares: one-line errors, checked flags, atomic outputs.

A command (``jaxsem ...``, ``train/*.py``, ``infer/*.py``, ``benchmarks/*.py``) follows these rules:

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
4. **Every run is recorded.** A command's parser comes from :func:`command_parser` (the shared
   ``--run-dir``, ``--no-compilation-cache`` and ``--debug`` flags); ``jaxsem.cli`` starts a
   :class:`Run` around it (:func:`start_run`): a run directory named at the start and printed as
   the first line, holding ``config.json`` (every argument after defaults, versions, the command
   line) and, at the end, ``summary.json`` (status, wall time, headline numbers, figures and
   outputs; status ``"error"`` and the one-line message when the run failed). The command reports
   its headline numbers with :func:`record`; what it writes through the atomic helpers is listed
   in the summary by itself (figures under ``figures``, other files under ``outputs``).
5. **No flag copied by hand.** Any config field is settable with ``--set KEY=VALUE``; the few
   convenience flags a command offers for config fields (``--steps``, ``--batch-size``, ...)
   are made by :func:`add_config_flags` from the config dataclass (type, help text, default) and
   applied by :func:`apply_config_flags` through :func:`jaxsem.config.override`, the path of
   ``--set``, so the config's own checks and the one-line errors naming the flag are shared.
"""

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
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

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
    "positive_probability",
    "existing_file",
    "existing_dir",
    "existing_path",
    "output_dir",
    "output_file",
    "int_list",
    "ConfigFlag",
    "add_config_flags",
    "apply_config_flags",
    "config_flags",
    "config_field_help",
    "atomic_write_text",
    "atomic_write_bytes",
    "atomic_savefig",
    "atomic_save_npz",
    "atomic_path",
    "CommandParser",
    "command_parser",
    "Run",
    "start_run",
    "active_run",
    "record",
    "record_config",
    "record_output",
    "default_run_dir",
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
positive_probability: Callable[[str], float] = _ranged(
    float, "positive_probability", "a probability in (0, 1]", low=0.0, high=1.0, low_open=True
)


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


def devices(text: str) -> int | str:
    """``--devices``: ``all`` or a positive count (checked against the devices JAX sees later)."""
    from .parallel import parse_devices

    try:
        return parse_devices(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("devices: ")) from None


def add_devices_argument(parser: argparse.ArgumentParser) -> None:
    """The training commands' ``--devices N|all`` (data-parallel over a Mesh; default one device)."""
    parser.add_argument(
        "--devices",
        type=devices,
        default=None,
        metavar="N|all",
        help="train data-parallel over N devices or 'all' (a Mesh over jax.devices() with a data axis: the "
        "state replicated, each batch split over the devices, so the batch size must divide by N; on "
        "several hosts 'all' spans every host's devices once JAX_COORDINATOR_ADDRESS etc. are set, see "
        "the README's Scaling) (default: one device)",
    )


def devices_mesh(devices, batch_size: int):
    """The data mesh of a parsed ``--devices`` (None without it), after joining a multi-host run;
    :class:`UsageError` naming ``--devices`` or ``--batch-size`` when it cannot be used."""
    if devices is None:
        return None
    from . import parallel

    parallel.initialize_distributed()  # a no-op on one machine
    try:
        mesh = parallel.devices_mesh(devices)
    except ValueError as exc:
        raise UsageError(f"--devices: {str(exc).removeprefix('devices: ')}") from None
    if batch_size % mesh.size:
        raise UsageError(
            f"--batch-size: {batch_size} does not divide over the {mesh.size} devices of --devices {devices}"
        )
    return mesh


def existing_path(text: str) -> pathlib.Path:
    """A path to an existing file or directory."""
    path = pathlib.Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file or directory")
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


_UMASK = os.umask(0o022)
os.umask(_UMASK)


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
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; the file gets the mode open() would give
    tmp_path = pathlib.Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    if _ACTIVE is not None:
        _ACTIVE._wrote(path)


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


# --------------------------------------------------------------------------------------------
# Convenience flags generated from a config dataclass (beside the generic ``--set KEY=VALUE``).


@dataclasses.dataclass(frozen=True)
class ConfigFlag:
    """One ``--flag`` that sets one config field (made into an argparse flag by :func:`add_config_flags`).

    Attributes:
      field: the field's dotted name in the config, e.g. ``"num_steps"`` or ``"noise.box_sigma"``.
      option: the flag, e.g. ``"--steps"`` (default: ``--`` and the field's last name with ``-``
        for ``_``).
      type: the argparse type that checks the text (default: read from the field's annotation:
        an integer, a finite number, a boolean or a string). Range checks such as
        :func:`positive_int` go here.
      help: used only where the dataclass documents nothing for the field in ``metadata["help"]``,
        its docstring's (``Attributes:``) entry or an attribute docstring (it wins over a bare
        trailing ``#`` comment on the field's line).
    """

    field: str
    option: str | None = None
    type: Callable[[str], Any] | None = None
    help: str | None = None

    @property
    def flag(self) -> str:
        return self.option or "--" + self.field.rsplit(".", 1)[-1].replace("_", "-")

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")


def _config_field(config_cls: type, dotted: str) -> tuple[type, dataclasses.Field]:
    """The dataclass that owns the last name of ``dotted`` (nested configs followed through their
    defaults or annotations), and that field; ``ValueError`` naming ``dotted`` otherwise."""
    import typing

    cls = config_cls
    parts = dotted.split(".")
    for i, name in enumerate(parts):
        found = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
        if name not in found:
            raise ValueError(f"{dotted}: {cls.__name__} has no config field {name!r}; fields are {sorted(found)}")
        field = found[name]
        if i == len(parts) - 1:
            return cls, field
        if field.default is not dataclasses.MISSING and dataclasses.is_dataclass(field.default):
            cls = type(field.default)
        elif field.default_factory is not dataclasses.MISSING:
            cls = type(field.default_factory())
        else:
            hint = typing.get_type_hints(cls).get(name)
            if not (isinstance(hint, type) and dataclasses.is_dataclass(hint)):
                raise ValueError(f"{dotted}: {name!r} of {cls.__name__} is not a nested config")
            cls = hint
    raise AssertionError("unreachable")


def _docstring_entries(doc: str) -> dict[str, str]:
    """``{field: text}`` from a class docstring's entries ``name: text`` (also ``a, b: text`` and
    ``a / b: text``, continuation lines indented deeper), inside or without an ``Attributes:``
    heading. An entry whose leading names have no colon (``a, b (note), c.``) documents each of
    them with the whole entry."""
    import inspect
    import re

    lines = inspect.cleandoc(doc).splitlines()
    entries: list[list[str]] = []
    indent = None
    for line in lines:
        stripped = line.strip()
        if not stripped or (stripped.endswith(":") and ": " not in stripped):  # blank or a heading
            indent = None if not stripped else indent
            continue
        depth = len(line) - len(line.lstrip())
        if re.match(r"[A-Za-z_]\w*\s*(?:[,/:(]|$)", stripped) and (indent is None or depth <= indent):
            indent = depth
            entries.append([stripped])
        elif entries and indent is not None and depth > indent:
            entries[-1].append(stripped)
        else:
            indent = None
    out: dict[str, str] = {}
    for entry in entries:
        text = " ".join(entry)
        head, colon, rest = text.partition(": ")
        names = re.findall(r"[A-Za-z_]\w*", re.sub(r"\([^)]*\)", "", head if colon else text))
        for name in names:
            out.setdefault(name, (rest if colon else text).strip())
    return out


def _source_docs(cls: type) -> dict[str, str]:
    """``{field: text}`` from the class body: an attribute docstring (a string right after the
    field) or a trailing ``# comment`` on the field's line."""
    import ast
    import inspect
    import textwrap

    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    body = ast.parse(source).body[0]
    out: dict[str, str] = {}
    if not isinstance(body, ast.ClassDef):
        return out
    for stmt, nxt in zip(body.body, body.body[1:] + [None]):
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        name = stmt.target.id
        if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
            out[name] = " ".join(nxt.value.value.split())
            continue
        line = lines[(stmt.end_lineno or stmt.lineno) - 1]
        code, sep, comment = line.partition("  # ")
        if sep and comment.strip():
            out[name] = "#" + comment.strip()  # marked as a comment for config_field_help
    return out


def config_field_help(config_cls: type, dotted: str, *, comments: bool = True) -> str | None:
    """What the dataclass says about field ``dotted``, first found of: ``metadata["help"]`` (or
    ``"doc"``), the class docstring's entry for it, an attribute docstring, and (``comments``) a
    trailing ``# comment``; None if nothing."""
    cls, field = _config_field(config_cls, dotted)
    for key in ("help", "doc"):
        if field.metadata.get(key):
            return str(field.metadata[key])
    source = _source_docs(cls)
    doc = cls.__doc__ or ""
    if doc.startswith(cls.__name__ + "("):  # the signature dataclasses write where there is no docstring
        doc = ""
    text = _docstring_entries(doc).get(field.name)
    if not text and field.name in source and (comments or not source[field.name].startswith("#")):
        text = source[field.name].removeprefix("#")
    return text or None


def _field_type(config_cls: type, dotted: str) -> Callable[[str], Any]:
    """An argparse type from the field's annotation (int, finite float, bool, str; ``X | None``
    reads X). Other annotations take the text as it is, and :func:`jaxsem.config.override` reads it
    as ``--set`` would."""
    import types
    import typing

    cls, field = _config_field(config_cls, dotted)
    hint = typing.get_type_hints(cls).get(field.name, field.type)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        hint = args[0] if len(args) == 1 else str
    if hint is bool:
        return _boolean
    if hint is int:
        return _ranged(int, "int", "an integer")
    if hint is float:
        return finite_float
    return str


def _boolean(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def add_config_flags(
    parser: argparse.ArgumentParser | Any,
    config_cls: type,
    flags: Sequence[ConfigFlag | str],
    *,
    base: Any = None,
) -> tuple[ConfigFlag, ...]:
    """Adds one ``--flag`` per config field named in ``flags`` (a :class:`ConfigFlag` or a dotted
    field name) to ``parser`` (or an argument group), with its type and help taken from
    ``config_cls``; returns the flags, for :func:`apply_config_flags`.

    Without ``base`` each flag defaults to None (not given: the config keeps its preset's value)
    and ``--help`` says "default: the preset's". With ``base`` (the one config the command starts
    from) the flag's default is that config's value, shown in ``--help`` and recorded with the
    arguments. A name that is not a field of ``config_cls`` raises ``ValueError`` at once.
    """
    out = []
    for spec in flags:
        spec = ConfigFlag(spec) if isinstance(spec, str) else spec
        # the dataclass' documentation first; the command's own text before a bare code comment
        text = config_field_help(config_cls, spec.field, comments=False) or spec.help
        text = text or config_field_help(config_cls, spec.field)
        if not text:
            raise ValueError(f"{spec.field}: {config_cls.__name__} documents nothing for it; give ConfigFlag(help=...)")
        value = None
        if base is not None:
            from .config import fields

            value = base
            for name in spec.field.split("."):
                value = fields(value)[name]
        kind = spec.type or _field_type(config_cls, spec.field)
        parser.add_argument(
            spec.flag,
            dest=spec.dest,
            type=kind,
            default=value,
            metavar=spec.dest.upper(),
            help=f"config field {spec.field}: {text.rstrip('.')} (default: "
            + ("the preset's" if base is None else repr(value))
            + ")",
        )
        out.append(spec)
    registry = getattr(parser, "_config_flags", None)
    if registry is None:
        registry = []
        setattr(parser, "_config_flags", registry)
    registry.append((config_cls, tuple(out)))
    return tuple(out)


def config_flags(parser: argparse.ArgumentParser) -> list[tuple[type, tuple[ConfigFlag, ...]]]:
    """The config classes and flags that :func:`add_config_flags` added to ``parser``."""
    return list(getattr(parser, "_config_flags", []))


def apply_config_flags(config, args: argparse.Namespace, flags: Sequence[ConfigFlag], sets: Sequence[str] = ()):
    """``config`` with every given flag of ``flags`` applied, then the ``--set KEY=VALUE``
    assignments ``sets``, all through :func:`jaxsem.config.override` (so the config's own checks
    run). A bad value raises :class:`UsageError` naming the flag (or ``--set``)."""
    from .config import override

    for spec in flags:
        value = getattr(args, spec.dest, None)
        if value is None:
            continue
        try:
            config = override(config, {spec.field: value})
        except ValueError as exc:
            raise UsageError(f"{spec.flag}: {' '.join(str(exc).split())}") from None
    if sets:
        try:
            config = override(config, list(sets))
        except ValueError as exc:
            raise UsageError(f"--set: {' '.join(str(exc).split())}") from None
    return config


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
        from .config import to_dict

        return _jsonable(to_dict(value))
    return str(value)


def _versions() -> dict[str, str | None]:
    from importlib import metadata

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
        return 1, " ".join(str(exc.code).split())
    if isinstance(exc, KeyboardInterrupt):
        return 130, "interrupted"
    if isinstance(exc, _EXPECTED):
        return 2, _one_line(exc)
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

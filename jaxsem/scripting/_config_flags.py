"""Convenience flags generated from a config dataclass, applied through
:func:`jaxsem.config.override` (rule 5 of :mod:`jaxsem.scripting`)."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import re
import textwrap
import types
import typing
from collections.abc import Callable, Sequence
from typing import Any

from ..config import fields, override
from ._arguments import _ranged, finite_float
from ._errors import UsageError

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

    The parser also gets the generic ``--set KEY=VALUE`` (repeatable, once per parser however
    many groups of flags it has), which reaches every field of ``config_cls`` by its dotted name;
    :func:`apply_config_flags` applies it after the flags.
    """
    if "--set" not in getattr(parser, "_option_string_actions", {}):
        parser.add_argument(
            "--set",
            dest="set",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help=f"override any {config_cls.__name__} field by its dotted name (repeatable; applied after the flags)",
        )
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


def apply_config_flags(
    config, args: argparse.Namespace, flags: Sequence[ConfigFlag], sets: Sequence[str] | None = None
):
    """``config`` with every given flag of ``flags`` applied, then the ``--set KEY=VALUE``
    assignments ``sets`` (default: the ``--set`` that :func:`add_config_flags` added, ``args.set``),
    all through :func:`jaxsem.config.override` (so the config's own checks run). A bad value
    raises :class:`UsageError` naming the flag (or ``--set``)."""
    if sets is None:
        sets = getattr(args, "set", None) or ()

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

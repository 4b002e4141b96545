"""One way to configure: frozen, typed configs with named presets, files and ``key=value`` overrides.

Every configurable part of jaxsem (solvers, simulators, training) has a frozen config object: a
frozen dataclass (the convention), an ``equinox.Module`` or a ``NamedTuple``. This module treats
them all alike:

- :func:`override` returns a copy with fields changed by dotted name (``"loss.primal_weight"``),
  parsing string values into the field's type (``"3"`` -> 3, ``"1e-3"``, ``"true"``, JSON lists);
  an unknown name is a ``ValueError`` listing the fields that exist.
- :func:`to_dict` / :func:`from_dict` round-trip a config through JSON-able dicts (nested configs
  included), and :func:`save` / :func:`load` through a ``.json`` file; :func:`load` rejects keys
  the config does not have.
- :class:`Presets` is a registry of named variants (``default``, ``thesis``, ``tiny`` ...), each a
  function of the default that changes a few fields (a variant never copies the whole config).
- :func:`add_config_arguments` / :func:`config_from_args` give a command ``--config NAME|FILE``
  and ``--set key=value`` (repeatable), so any field is settable from the command line by its
  name, with no flag copied by hand.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import typing
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Generic, TypeVar

from ._atomic import atomic_write_text
from ._files import read_text

__all__ = [
    "Presets",
    "fields",
    "override",
    "to_dict",
    "from_dict",
    "save",
    "load",
    "parse_assignment",
    "add_config_arguments",
    "config_from_args",
]

C = TypeVar("C")


def _is_namedtuple(obj) -> bool:
    return isinstance(obj, tuple) and hasattr(obj, "_fields")


def _is_config(obj) -> bool:
    return dataclasses.is_dataclass(obj) and not isinstance(obj, type) or _is_namedtuple(obj)


def fields(config) -> dict[str, Any]:
    """Field name -> value of a config (dataclass, equinox Module or NamedTuple), in order."""
    if _is_namedtuple(config):
        return dict(zip(config._fields, config))
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        return {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.init}
    raise ValueError(
        f"config: expected a dataclass, equinox Module or NamedTuple instance, got {type(config).__name__}"
    )


def _replace(config, **changes):
    if _is_namedtuple(config):
        return config._replace(**changes)
    try:
        import equinox as eqx  # deferred: equinox is heavy and only equinox-module configs need it

        if isinstance(config, eqx.Module):
            names = list(changes)
            static = {f.name for f in dataclasses.fields(config) if f.metadata.get("static", False)}
            if static.intersection(names):  # not leaves of the pytree: construct it anew
                return dataclasses.replace(config, **changes)
            return eqx.tree_at(
                lambda c: [getattr(c, n) for n in names],
                config,
                [changes[n] for n in names],
                is_leaf=lambda x: x is None,
            )
    except ImportError:  # pragma: no cover - equinox is a dependency
        pass
    return dataclasses.replace(config, **changes)


def _field_type(config, name: str):
    try:
        hints = typing.get_type_hints(type(config))
    except Exception:  # unresolved forward references: fall back to the current value's type
        hints = {}
    return hints.get(name)


def _coerce(value, current, hint, where: str):
    """Turns a command-line string into the type of ``current`` (or the annotation ``hint``)."""
    if not isinstance(value, str):
        return value
    text = value.strip()
    target = type(current) if current is not None else None
    origin = typing.get_origin(hint)
    if text.lower() in ("none", "null") and (current is None or type(None) in typing.get_args(hint)):
        return None
    if current is None and hint is not None:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1 and args[0] in (int, float, str, bool):
            target = args[0]
        elif hint in (int, float, str, bool):
            target = hint
        elif origin in (tuple, list) or (len(args) == 1 and typing.get_origin(args[0]) in (tuple, list)):
            target = tuple
    try:
        if target is bool:
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if target is int:
            return int(text)
        if target is float:
            number = float(text)
            return number
        if target is str or (target is None and text[:1] not in "[{0123456789-."):
            return text
        if target in (tuple, list) or isinstance(current, (tuple, list)):
            parsed = (
                json.loads(text)
                if text.startswith("[")
                else [
                    json.loads(p) if p.strip()[:1] in '0123456789-.[{"tfn' else p.strip()
                    for p in text.split(",")
                    if p.strip()
                ]
            )
            return tuple(parsed) if target is tuple or isinstance(current, tuple) else list(parsed)
        return json.loads(text)
    except (ValueError, json.JSONDecodeError):
        kind = getattr(target, "__name__", "a JSON value")
        raise ValueError(f"{where}: cannot read {value!r} as {kind}") from None


def override(config: C, changes: Mapping[str, Any] | Iterable[str] = (), **kwargs) -> C:
    """A copy of ``config`` with fields changed by dotted name.

    ``changes`` is a mapping ``{"solver.max_steps": 50}`` or an iterable of ``"key=value"`` strings
    (as given to ``--set``); keyword arguments add more (top-level names). String values are read
    as the field's type. Unknown names raise ``ValueError`` listing the fields of that level.
    """
    if isinstance(changes, Mapping):
        items = list(changes.items())
    else:
        items = [parse_assignment(c) for c in changes]
    items += list(kwargs.items())
    for key, value in items:
        config = _set(config, key.split("."), value, key)
    return config


def _set(config, path: list[str], value, full: str):
    names = fields(config)
    head = path[0]
    if head not in names:
        raise ValueError(
            f"{full}: unknown config field {head!r} of {type(config).__name__}; fields are {sorted(names)}"
        )
    if len(path) > 1:
        child = names[head]
        if not _is_config(child):
            raise ValueError(f"{full}: {head!r} is a {type(child).__name__}, not a nested config")
        return _replace(config, **{head: _set(child, path[1:], value, full)})
    current = names[head]
    if _is_config(current) and isinstance(value, Mapping):
        new = from_dict(type(current), {**to_dict(current), **value})
    else:
        new = _coerce(value, current, _field_type(config, head), full)
    return _replace(config, **{head: new})


def parse_assignment(text: str) -> tuple[str, str]:
    """``"a.b=3"`` -> ``("a.b", "3")``; ``ValueError`` naming the text if there is no ``=``."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"--set {text!r}: expected key=value, e.g. loss.primal_weight=0.5")
    return key.strip(), value


def to_dict(config) -> dict[str, Any]:
    """A JSON-able dict of a config (nested configs become nested dicts, tuples lists)."""
    out = {}
    for name, value in fields(config).items():
        if _is_config(value):
            out[name] = to_dict(value)
        elif isinstance(value, tuple):
            out[name] = [to_dict(v) if _is_config(v) else v for v in value]
        else:
            out[name] = value
    return out


def from_dict(cls: type[C], data: Mapping[str, Any], *, base: C | None = None) -> C:
    """A config of class ``cls`` from a dict as written by :func:`to_dict`, over ``base``
    (default ``cls()``). Unknown keys raise ``ValueError`` naming them."""
    config = cls() if base is None else base
    names = fields(config)
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ValueError(f"config: unknown field(s) {unknown} for {cls.__name__}; fields are {sorted(names)}")
    changes = {}
    for key, value in data.items():
        current = names[key]
        if _is_config(current) and isinstance(value, Mapping):
            changes[key] = from_dict(type(current), value, base=current)
        elif isinstance(current, tuple) and isinstance(value, list):
            changes[key] = tuple(value)
        else:
            changes[key] = value
    return typing.cast(C, _replace(config, **changes))


def save(config, path: str | pathlib.Path) -> pathlib.Path:
    """Writes ``config`` as JSON to ``path`` atomically."""
    return atomic_write_text(path, json.dumps(to_dict(config), indent=1, sort_keys=True) + "\n")


def load(cls: type[C], path: str | pathlib.Path, *, base: C | None = None) -> C:
    """Reads a JSON config file written by :func:`save` (or by hand: any subset of the fields)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such config file")
    try:
        data = json.loads(read_text(path, "config file"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object of config fields, got {type(data).__name__}")
    try:
        return from_dict(cls, data, base=base)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


class Presets(Generic[C]):
    """Named variants of a default config: ``presets["thesis"]`` is ``make_thesis(default())``.

    Example::

        PRESETS = Presets(SolverConfig)
        @PRESETS.register("tiny")
        def _tiny(c): return override(c, max_steps=5)
    """

    def __init__(self, default: Callable[[], C] | type[C]):
        self._default = default
        self._variants: dict[str, Callable[[C], C]] = {"default": lambda c: c}

    def register(self, name: str):
        def decorator(fn: Callable[[C], C]):
            self._variants[name] = fn
            return fn

        return decorator

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._variants)

    def __getitem__(self, name: str) -> C:
        if name not in self._variants:
            raise ValueError(f"config {name!r}: unknown preset; presets are {list(self._variants)} (or a .json file)")
        return self._variants[name](self._default())

    def resolve(self, name_or_file: str) -> C:
        """A preset by name, or a JSON file (fields over the default)."""
        if name_or_file in self._variants:
            return self[name_or_file]
        if name_or_file.endswith(".json") or pathlib.Path(name_or_file).exists():
            default = self._default()
            return load(type(default), name_or_file, base=default)
        return self[name_or_file]


def add_config_arguments(parser: argparse.ArgumentParser, presets: Presets, default: str = "default") -> None:
    """Adds ``--config NAME|FILE`` and repeatable ``--set key=value`` to ``parser``."""
    parser.add_argument(
        "--config",
        default=default,
        help=f"preset ({', '.join(presets.names)}) or a JSON file of config fields",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config field by its dotted name (repeatable), e.g. --set loss.primal_weight=0.5",
    )


def config_from_args(args: argparse.Namespace, presets: Presets):
    """The config that ``--config`` and ``--set`` describe (``ValueError`` naming a bad one)."""
    return override(presets.resolve(args.config), args.overrides)

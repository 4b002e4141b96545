"""Checked ``argparse`` types: a bad flag is refused while parsing, naming it (rule 2 of
:mod:`jaxsem.scripting`)."""

from __future__ import annotations

import argparse
import math
import pathlib
from collections.abc import Callable

from .. import parallel
from ..parallel import parse_devices
from ._errors import UsageError

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


def image_size(text: str) -> tuple[int, int]:
    """A network's image size ``W,H``: two integers, multiples of 16 and at least 32 each."""
    try:
        w, h = (int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected W,H (two integers), got {text!r}") from None
    if w < 32 or h < 32 or w % 16 or h % 16:
        raise argparse.ArgumentTypeError(f"expected W,H multiples of 16 and at least 32, got {text!r}")
    return w, h


def _existing(text: str, what: str, is_kind: Callable[[pathlib.Path], bool] | None = None) -> pathlib.Path:
    """``text`` as a path that exists (``no such <what>`` otherwise) and, given ``is_kind``,
    is of that kind (``not a <what>``): the one check behind the ``existing_*`` types."""
    path = pathlib.Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such {what}")
    if is_kind is not None and not is_kind(path):
        raise argparse.ArgumentTypeError(f"{text}: not a {what}")
    return path


def existing_file(text: str) -> pathlib.Path:
    """A path to an existing regular file."""
    return _existing(text, "file", pathlib.Path.is_file)


def devices(text: str) -> int | str:
    """``--devices``: ``all`` or a positive count (checked against the devices JAX sees later)."""
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


def add_force_argument(parser: argparse.ArgumentParser) -> None:
    """The training commands' ``--force``: resume a workdir whose saved config differs from the
    one asked for (their trainers' ``force``)."""
    parser.add_argument("--force", action="store_true", help="resume even if the config differs from the workdir's")


def devices_mesh(devices, batch_size: int):
    """The data mesh of a parsed ``--devices`` (None without it), after joining a multi-host run;
    :class:`UsageError` naming ``--devices`` or ``--batch-size`` when it cannot be used."""
    if devices is None:
        return None

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
    return _existing(text, "file or directory")


def existing_dir(text: str) -> pathlib.Path:
    """A path to an existing directory."""
    return _existing(text, "directory", pathlib.Path.is_dir)


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

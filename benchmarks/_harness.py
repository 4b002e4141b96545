"""What every benchmark here shares: one timer, round-robin timing of rivals, the machine line,
the results epilogue (JSON + markdown with a command / date / machine header).

The rules (``CONTRIBUTING.md``, "How we measure"): warm up (compile) before timing, wait for the
result with ``jax.block_until_ready``, report medians, and time a baseline or peer in the same
run, interleaved, so that the shared machine's load hits both alike. Import it from a benchmark
script as the other private helpers of this folder are imported::

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    import _harness  # noqa: E402
"""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import platform
import subprocess
import time
from collections.abc import Callable, Mapping
from typing import Any

import jax
import numpy as np


def timed(fn: Callable[..., Any], *args, repeats: int, warmup: bool = True) -> tuple[float, Any]:
    """``(median seconds, last output)`` of ``repeats`` calls of ``fn(*args)``, each waited for
    with ``jax.block_until_ready``; ``warmup`` calls it once first, untimed (the compile)."""
    if repeats < 1:
        raise ValueError(f"repeats: expected a positive count, got {repeats}")
    if warmup:
        jax.block_until_ready(fn(*args))
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def median_time(fn: Callable[..., Any], *args, repeats: int, warmup: bool = True) -> float:
    """Median seconds of ``repeats`` calls of ``fn(*args)`` (see :func:`timed`)."""
    return timed(fn, *args, repeats=repeats, warmup=warmup)[0]


def interleaved_medians(fns: Mapping[str, Callable[[], Any]], rounds: Mapping[str, int]) -> dict[str, float]:
    """Median seconds of each zero-argument function, timed round-robin (so that a change in the
    machine's load hits all of them alike); ``rounds[name]`` caps that function's repeats."""
    times: dict[str, list[float]] = {name: [] for name in fns}
    for i in range(max(rounds.values())):
        for name, fn in fns.items():
            if i >= rounds[name]:
                continue
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) for name, t in times.items()}


def machine() -> str:
    """Where the run happened, for the results table (timings compare only on one machine)."""
    dev = jax.devices()[0]
    if dev.platform == "cpu":
        cpu = platform.processor() or platform.machine()
        return f"{cpu}, {os.cpu_count()}-core CPU (shared, noisy)"
    return f"{dev.device_kind} ({dev.platform}), jax {jax.__version__}"


def utc_now() -> str:
    """The run's date for the results header, ``YYYY-MM-DD HH:MM UTC``."""
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def nproc() -> str:
    """``nproc``'s answer (the cores this process may use), as text; empty where it fails."""
    return subprocess.run(["nproc"], capture_output=True, text=True, check=False).stdout.strip()


def output_arguments(parser, stem: str, written: str = ".json / .md", *, float32: bool = False) -> None:
    """Adds the output flags a results-writing benchmark shares: ``--out`` (the folder, default
    ``benchmarks/results``) and ``--name`` (the file stem, default ``stem``); with ``float32`` also
    ``--float32`` (solve in float32 instead of float64). ``written`` lists the files' endings for
    ``--out``'s help."""
    if float32:
        parser.add_argument("--float32", action="store_true", help="solve in float32 (default float64)")
    parser.add_argument(
        "--out", default=str(pathlib.Path(__file__).resolve().parent / "results"), help=f"folder for {stem}{written}"
    )
    parser.add_argument("--name", default=stem, help="output file stem")


def header(title: str, command: str, date: str, machine: str) -> list[str]:
    """The markdown results header: a title, then command, date and machine, each its own paragraph."""
    return [title, "", f"Command: `{command}`", "", f"Date: {date}", "", f"Machine: {machine}", ""]


def write_results(out, name: str, record: Mapping[str, Any], md: list[str], json_default=None) -> pathlib.Path:
    """Writes ``out/name.json`` (``record``, indent 1) and ``out/name.md`` (``md``'s lines), making
    ``out`` if need be; returns ``out`` as a path."""
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(record, indent=1, default=json_default))
    (out / f"{name}.md").write_text("\n".join(md))
    return out


def fold_specs(specs, lo: int, hi: int, *, flag: str, error: Callable[[str], Any], exists: Callable[[str], bool]):
    """``MODEL:LO-HI`` strings as ``[(model, lo, hi), ...]``: the folds of a cross-validation, each
    model on the frame ids ``[LO, HI)`` its run held out. Each range must lie inside ``[lo, hi)``,
    no two may overlap and each model must exist (``exists``); ``error`` gets one line naming
    ``flag`` otherwise (an ``argparse`` parser's ``error``)."""
    folds = []
    for spec in specs:
        path, _, span = spec.rpartition(":")
        lo_hi = span.split("-")
        if not path or len(lo_hi) != 2 or not all(x.isdigit() for x in lo_hi):
            error(f"{flag}: expected MODEL:LO-HI, got {spec}")
        f_lo, f_hi = map(int, lo_hi)
        if not lo <= f_lo < f_hi <= hi:
            error(f"{flag}: {spec} lies outside the frames {lo}-{hi - 1}")
        if any(f_lo < b and a < f_hi for _, a, b in folds):
            error(f"{flag}: {spec} overlaps another fold")
        if not exists(path):
            error(f"{flag}: no model {path}")
        folds.append((path, f_lo, f_hi))
    return folds

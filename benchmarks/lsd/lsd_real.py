"""Benchmark: Table 3.1 on a real map: PRM + LSD against PRM + Unf on a scanned or drawn building.

Reads a map in any format of ``jaxsem.planning.load_map`` (ROS map_server YAML, MRPT
``.gridmap(.gz)``, a plain image with ``--resolution``), resamples it to the planner's 0.1 m
cells, finds its doors and its footprint (``--annotations`` adds hand-drawn ones), writes a figure
of what it found, samples Inside-Inside and Inside-Outside tasks with distance and clearance
bounds (``--tasks thesis``: 8-40 m, the thesis' buildings' size; ``--tasks map``: 8 m to the map's
extent, for maps people cross end to end), and runs both planners from the same start, yaw and key
on every task and every N:

- ``--protocol thesis``: a fresh roadmap at every replan, the first roadmap without a path ends
  the trial (thesis 3.3.3; ``NavConfig(reuse_roadmap=False, max_growth=0)`` for both planners);
- ``--protocol defaults``: the library's defaults (roadmap reuse for the uniform planner, growth
  after a failed search).

LSD is the shipped model (or ``--checkpoint``) under the thesis' sampling rule (no uniform mix).
``--nosem`` adds a row: LSD with its semantic input zeroed (does finding doors matter?);
``--euclid`` one with Euclidean edge weights instead of the thesis' -log p (a variant), ``--replan-when-blocked``
one that keeps its route until the route is blocked, as the reused uniform roadmap does (a variant),
``--outmass`` one whose cells outside the window share a calibrated mass (a variant),
``--unknown-weight W`` two (uniform and LSD) whose edge weights charge a metre through unknown
cells W times one through known free cells (a variant of both planners, compared pairwise),
``--lsd-scale S`` one whose network sees the partial maps pooled S x S (a window S times wider),
``--oracle MODEL`` the fully supervised oracle network fed the true map's crops (a diagnostic),
``--other MODEL`` another LSD model on the same tasks, paired task by task with ``--checkpoint``'s
(``summary[row]["other_vs_lsd"]``: which model to ship).
``--reuse-base RUN`` runs only the variant rows and takes uniform and LSD from an earlier run of
the same tasks (their records are joined, so every reader of the records sees all rows).
Records stream to ``<json stem>.records.jsonl`` as trials end (paths included) and a rerun of the
same command resumes from them. Writes ``summary`` with rows ``II-<N>`` / ``IO-<N>``
(``success_uniform``, ``success_lsd``, ``lsd_only``, ``uniform_only``, ``cl_over_cstar``,
``cb_over_cstar``, ...), the map's facts and the command, to ``--json``.

Seeds: tasks come from ``--seed``; seeds below 1000 are for tuning, report on others.
How much room a row's C/C* leaves (each task's shortest possible length):
``benchmarks/lsd/lsd_real_floor.py --json <this JSON>``.

    python benchmarks/lsd/lsd_real.py --map DATA/mrpt/2006-MalagaCampus.gridmap.gz --trials 20 \\
        --n 500 --sets II IO --protocol thesis --seed 1000 --json benchmarks/results/lsd_real_campus.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import pathlib
import subprocess
import sys
import time


def _parse(argv):
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    p.add_argument(
        "--map",
        required=True,
        nargs="+",
        help="map file(s): .yaml (ROS), .gridmap[.gz] (MRPT) or an image; several are pooled",
    )
    p.add_argument("--resolution", type=float, default=None, help="metres per pixel (plain images)")
    p.add_argument("--annotations", default=None, help="JSON of hand-drawn doors / windows / exit signs")
    p.add_argument(
        "--hatch-px",
        type=float,
        default=None,
        help="plain images drawn with hatched obstacles: light gaps up to twice this wide are obstacle",
    )
    p.add_argument(
        "--footprint",
        choices=["auto", "walls", "density", "none"],
        default="auto",
        help="how inside is told from outside ('none': the whole map is the building)",
    )
    p.add_argument("--trials", type=int, default=10, help="tasks per map and set")
    p.add_argument("--n", type=int, nargs="+", default=[500], help="sample budgets N")
    p.add_argument("--sets", nargs="+", default=["II", "IO"], choices=["II", "IO"])
    p.add_argument("--protocol", choices=["thesis", "defaults"], default="thesis")
    p.add_argument("--seed", type=int, default=1000, help="task seed (< 1000: tuning seeds)")
    p.add_argument(
        "--tasks",
        choices=["thesis", "map"],
        default="thesis",
        help="thesis: start and goal at most --max-distance apart (40 m: the thesis' buildings' size); "
        "map: up to the map's extent (its diagonal), the bound for maps people cross end to end",
    )
    p.add_argument("--min-distance", type=float, default=8.0, help="metres between start and goal, at least")
    p.add_argument(
        "--max-distance",
        type=float,
        default=None,
        help="metres between start and goal, at most, with --tasks thesis (default 40: the thesis' buildings "
        "are about 40 m across)",
    )
    p.add_argument("--clearance", type=float, default=0.3, help="metres from obstacles for start and goal")
    p.add_argument("--max-steps", type=int, default=10_000, help="step limit per trial (thesis: 10000)")
    p.add_argument(
        "--checkpoint",
        default=None,
        help="LSD workdir, exported .npz or a shipped model by name (default, generated, house, campus; None: the default)",
    )
    p.add_argument("--nosem", action="store_true", help="add LSD with the semantic input zeroed")
    p.add_argument(
        "--euclid",
        action="store_true",
        help="add LSD with Euclidean edge weights (a variant row; the default is the thesis' -log p)",
    )
    p.add_argument(
        "--replan-when-blocked",
        action="store_true",
        help="add LSD that replans only when its route is blocked, as the reused uniform roadmap "
        "effectively does (a variant row; the default draws a fresh roadmap every replan_every steps)",
    )
    p.add_argument(
        "--outmass",
        action="store_true",
        help="add LSD whose cells outside the 16 m window share a calibrated mass (lsd_table31.OUTSIDE_MASS, "
        "NavConfig.outside_mass) instead of the window's minimum (a variant row; the default is the thesis' rule)",
    )
    p.add_argument(
        "--unknown-weight",
        type=float,
        default=None,
        metavar="W",
        help="add uniform and LSD whose edge weights charge a metre through unknown cells W times one "
        "through known free cells (NavConfig.unknown_weight; variant rows uniform_unk and lsd_unk, "
        "compared pairwise; the default is the thesis' 1)",
    )
    p.add_argument(
        "--lsd-scale",
        type=int,
        default=None,
        metavar="S",
        help="add LSD whose network sees the partial maps pooled S x S (a 16 S m window; "
        "NavConfig.sampler_scale; variant row lsd_scale; the default is the thesis' 1)",
    )
    p.add_argument(
        "--oracle",
        default=None,
        metavar="MODEL",
        help="add the fully supervised oracle network (an exported .npz, e.g. train/checkpoints/lsd_campus/"
        "lsd_campus_oracle.npz) fed the true map's crops at its window (jaxsem.lsd.full_map_sampler; "
        "variant row lsd_oracle: how far a network that saw the building around it would get)",
    )
    p.add_argument(
        "--other",
        default=None,
        metavar="MODEL",
        help="add another LSD model (exported .npz or a shipped name) on the same tasks, under the same "
        "protocol (variant row lsd_other, paired with --checkpoint's model in other_vs_lsd)",
    )
    p.add_argument(
        "--goal-flag",
        choices=["map", "io"],
        default="map",
        help="the network's goal-outdoors flag: 'map' from the map (a stand-in outside's goals are "
        "indoors, Building.outside_is_outdoors), 'io' 1 for every Inside-Outside goal (stops 23-28)",
    )
    p.add_argument(
        "--uniform-only",
        action="store_true",
        help="run the uniform planner alone (e.g. its large-N point of the figure 3-8 curve)",
    )
    p.add_argument(
        "--reuse-base",
        default=None,
        metavar="RUN",
        help="an earlier lsd_real.py output on the same tasks (same map, seed, trials, bounds, protocol, "
        "step limit and model): run only the variant rows and take uniform and LSD from its records",
    )
    p.add_argument("--json", required=True, help="output JSON (records stream beside it)")
    p.add_argument(
        "--fresh",
        action="store_true",
        help="start the records beside --json over (a rerun otherwise resumes from them, and refuses "
        "records made under other flags or inputs)",
    )
    p.add_argument("--figure", default=None, help="map semantics figure (default: <json stem>_map.png)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    args = p.parse_args(argv)
    if args.tasks == "map" and args.max_distance is not None:
        raise SystemExit(
            "lsd_real: --max-distance: --tasks map draws tasks up to the map's extent; give one or the other"
        )
    if args.tasks == "thesis" and args.max_distance is None:
        args.max_distance = THESIS_MAX_DISTANCE
    return args


#: The thesis' task bound (m): its buildings are about 40 m across.
THESIS_MAX_DISTANCE = 40.0


def task_max_distance(args, b) -> float:
    """The run's bound on the start-to-goal distance (m) on map ``b``: ``--max-distance`` under
    ``--tasks thesis``, the map's diagonal under ``--tasks map``."""
    if args.tasks == "map":
        return float(math.hypot(b.shape[0] * b.resolution, b.shape[1] * b.resolution))
    return float(args.max_distance)


def _sibling(name: str):
    """Another script of ``benchmarks/`` imported as a module."""
    import importlib

    here = str(pathlib.Path(__file__).resolve().parent)
    if here not in sys.path:
        sys.path.insert(0, here)
    return importlib.import_module(name)


def run_args(command: str):
    """The flags of a recorded run (its JSON's ``command``: ``python benchmarks/lsd/lsd_real.py ...``),
    parsed as that run parsed them."""
    import shlex

    return _parse(shlex.split(command)[2:])


def _check(args):
    for path in args.map:
        if not pathlib.Path(path).is_file():
            raise SystemExit(f"lsd_real: --map: no such file {path!r}")
    if args.annotations and not pathlib.Path(args.annotations).is_file():
        raise SystemExit(f"lsd_real: --annotations: no such file {args.annotations!r}")
    if args.trials < 1:
        raise SystemExit(f"lsd_real: --trials: expected >= 1, got {args.trials}")
    if any(n < 1 for n in args.n):
        raise SystemExit(f"lsd_real: --n: expected sample budgets >= 1, got {args.n}")
    if args.tasks == "map":
        if not (math.isfinite(args.min_distance) and args.min_distance >= 0):
            raise SystemExit(f"lsd_real: --min-distance: expected metres >= 0, got {args.min_distance}")
    elif not (0 <= args.min_distance < args.max_distance) or not math.isfinite(args.max_distance):
        raise SystemExit("lsd_real: --max-distance: must be finite and exceed --min-distance (>= 0)")
    if not (math.isfinite(args.clearance) and args.clearance >= 0):
        raise SystemExit(f"lsd_real: --clearance: expected metres >= 0, got {args.clearance}")
    if args.max_steps < 1:
        raise SystemExit(f"lsd_real: --max-steps: expected >= 1, got {args.max_steps}")
    if args.hatch_px is not None and not (math.isfinite(args.hatch_px) and args.hatch_px > 0):
        raise SystemExit(f"lsd_real: --hatch-px: expected pixels > 0, got {args.hatch_px}")
    if args.resolution is not None and not (math.isfinite(args.resolution) and args.resolution > 0):
        raise SystemExit(f"lsd_real: --resolution: expected metres per pixel > 0, got {args.resolution}")
    if args.unknown_weight is not None and not (math.isfinite(args.unknown_weight) and args.unknown_weight > 0):
        raise SystemExit(f"lsd_real: --unknown-weight: expected a finite number > 0, got {args.unknown_weight}")
    if args.oracle is not None and not pathlib.Path(args.oracle).is_file():
        raise SystemExit(f"lsd_real: --oracle: no such file {args.oracle!r}")
    if args.other is not None:
        _sibling("lsd_table31").check_model("--other", args.other, "lsd_real: ")
    if args.oracle is not None and len(args.map) > 1:
        raise SystemExit("lsd_real: --oracle: needs a single --map (it reads that map's true crops)")
    if args.lsd_scale is not None and args.lsd_scale < 1:
        raise SystemExit(f"lsd_real: --lsd-scale: expected an int >= 1, got {args.lsd_scale}")
    out = pathlib.Path(args.json)
    if out.exists() and out.is_dir():
        raise SystemExit(f"lsd_real: --json: {args.json!r} is a folder")
    above = next((p for p in out.absolute().parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise SystemExit(f"lsd_real: --json: {str(above)!r} is a file, so {args.json!r} cannot be written")
    if args.reuse_base is not None:
        _check_reuse(args)


# The flags that each add a variant row (run_planners).
VARIANT_FLAGS = ("nosem", "euclid", "replan_when_blocked", "outmass", "unknown_weight", "lsd_scale", "oracle", "other")
# The flags that decide a run's tasks and its uniform and LSD rows: --reuse-base needs them equal.
SAME_TASK_FLAGS = (
    "trials", "seed", "tasks", "min_distance", "max_distance", "clearance", "protocol", "max_steps", "checkpoint",
    "goal_flag", "resolution", "annotations", "hatch_px", "footprint",
)  # fmt: skip


def _model_behind(checkpoint):
    """What ``--checkpoint`` loads, so that two spellings of one model compare equal (None and
    'default'; a shipped name and its file): a file's content digest, or a workdir's folder and
    latest step."""
    from jaxsem.lsd import load_model
    from jaxsem.training import tree_digest

    try:
        meta = load_model(checkpoint).meta
    except (OSError, ValueError, KeyError) as exc:
        raise SystemExit(f"lsd_real: --checkpoint: {checkpoint!r}: {exc}") from None
    path = pathlib.Path(meta["name"])
    return ("file", tree_digest(path)) if path.is_file() else ("workdir", str(path.resolve()), meta["step"])


def _check_reuse(args) -> None:
    """``--reuse-base``: the earlier run exists, has records, drew the same tasks and ran uniform
    and LSD on every set and N asked; this run adds variant rows only."""
    _, run, _ = _sibling("lsd_real_floor").read_runs([args.reuse_base], "lsd_real", flag="--reuse-base")[0]
    if args.uniform_only or not any(getattr(args, f) for f in VARIANT_FLAGS):
        raise SystemExit(
            "lsd_real: --reuse-base: name at least one variant row (--nosem, --euclid, ...) and not --uniform-only"
        )
    base = run_args(run["command"])
    for name in SAME_TASK_FLAGS:
        if name == "checkpoint":  # the model behind the flag, however it is named
            if _model_behind(base.checkpoint) != _model_behind(args.checkpoint):
                raise SystemExit(
                    f"lsd_real: --reuse-base: --checkpoint {args.checkpoint!r} is another model than "
                    f"{base.checkpoint!r} in {args.reuse_base!r}"
                )
        elif getattr(base, name) != getattr(args, name):
            flag = "--" + name.replace("_", "-")
            raise SystemExit(
                f"lsd_real: --reuse-base: {flag} is {getattr(args, name)!r} here but {getattr(base, name)!r} in {args.reuse_base!r}"
            )
    if [pathlib.Path(m).name for m in base.map] != [pathlib.Path(m).name for m in args.map]:
        raise SystemExit(f"lsd_real: --reuse-base: --map differs from {args.reuse_base!r}")
    if base.uniform_only or not set(args.sets) <= set(base.sets) or not set(args.n) <= set(base.n):
        raise SystemExit(
            f"lsd_real: --reuse-base: {args.reuse_base!r} lacks uniform and LSD rows for --sets / --n asked"
        )


def _git():
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return ""


def main(argv=None) -> int:
    args = _parse(argv)
    _check(args)
    try:
        return _run(args, sys.argv[1:] if argv is None else argv)
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"lsd_real: {type(exc).__name__}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


# Flags that only name outputs or say how to show progress, and the ones whose records are keyed
# (more tasks, sets or N values extend a run); every other flag is part of the records' stamp.
_UNSTAMPED = ("json", "figure", "no_progress", "debug", "fresh", "trials", "n", "sets")


def _provenance(args) -> dict:
    """The flags and inputs that make a trial, for the records' stamp: every flag but the
    :data:`_UNSTAMPED`, the content of each map file and the checkpoint file."""
    from jaxsem.training import tree_digest

    flags = {"--" + k.replace("_", "-"): v for k, v in sorted(vars(args).items()) if k not in _UNSTAMPED}
    files = [pathlib.Path(m) for m in args.map]
    if args.annotations:
        files.append(pathlib.Path(args.annotations))
    for model in (args.checkpoint, args.other):
        if model and pathlib.Path(model).is_file():
            files.append(pathlib.Path(model))
    return {"flags": flags, "files": {str(f): tree_digest(f) for f in files if f.is_file()}}


def load_run_map(args, path):
    """One map of the run as its flags read it (lsd_real_floor.py reloads a run's maps with it)."""
    from jaxsem.planning import load_map

    return load_map(
        path,
        resolution=args.resolution,
        annotations=args.annotations,
        hatch_px=args.hatch_px,
        footprint=args.footprint,
    )


def run_tasks(args, b, kind: str, graph=None) -> list:
    """The run's ``kind`` tasks on building ``b`` as its flags draw them (``lsd_real_replay.py``
    redraws a run's tasks with it)."""
    from jaxsem.planning import sample_tasks

    tasks = sample_tasks(
        b,
        kind,
        args.trials,
        args.seed,
        min_distance=args.min_distance,
        clearance=args.clearance,
        graph=graph,
        max_distance=task_max_distance(args, b),
    )
    if args.goal_flag == "io":
        tasks = [t._replace(goal_outdoors=kind == "IO") for t in tasks]
    return tasks


def run_planners(args, world=None) -> tuple:
    """``(LSD sampler, base NavConfig, variants)`` of the run as its flags set them: the base is
    the protocol's; variants maps each extra row's name to ``(sampler, NavConfig changes)``
    (None: uniform and LSD alone). ``jaxsem.lsd.run_trials`` takes them as they are. world: the
    run's map (a Building; ``--oracle`` reads its true crops)."""
    from jaxsem.lsd import LSDSampler, full_map_sampler, load_model
    from jaxsem.planning import NavConfig

    try:
        model, params, _, _ = load_model(args.checkpoint)
    except ValueError as exc:
        raise ValueError(f"--checkpoint: {exc}") from None
    sampler = LSDSampler(model, params)
    base = NavConfig(reuse_roadmap=False, max_growth=0) if args.protocol == "thesis" else NavConfig()
    variants = {"lsd_nosem": (_zeroed_semantics(sampler), {})} if args.nosem else {}
    if args.euclid:
        variants["lsd_euclid"] = (sampler, {"edge_weight": "euclidean"})
    if args.replan_when_blocked:
        variants["lsd_blocked"] = (sampler, {"replan_every": args.max_steps + 1})
    if args.outmass:
        variants["lsd_outmass"] = (sampler, {"outside_mass": _sibling("lsd_table31").OUTSIDE_MASS})
    if args.unknown_weight is not None:
        unk = {"unknown_weight": args.unknown_weight}
        variants.update(uniform_unk=(None, unk), lsd_unk=(sampler, unk))
    if args.lsd_scale is not None:
        variants["lsd_scale"] = (sampler, {"sampler_scale": args.lsd_scale})
    if args.oracle is not None:
        if world is None:
            raise ValueError("world: --oracle needs the run's map")
        oracle, oracle_params, _, _ = load_model(args.oracle)
        variants["lsd_oracle"] = (full_map_sampler(LSDSampler(oracle, oracle_params), world), {})
    if args.other is not None:
        other, other_params, _, _ = load_model(args.other)  # checked by _check
        variants["lsd_other"] = (LSDSampler(other, other_params), {})
    if args.uniform_only:
        variants = {"uniform": (None, {})}
    return sampler, base, variants or None


def _other_vs_lsd(summary: dict, records: list) -> str:
    """``--other`` paired with ``--checkpoint``'s model, task by task: written into each summary
    row as ``other_vs_lsd`` (success of both, other-only and LSD-only tasks, and the mean C/C* of
    each on the tasks both solved); returns the lines of a table."""
    import numpy as np

    lines = ["", "| set | N | tasks | success LSD | success other | other-only / LSD-only | C/C* LSD | C/C* other |"]
    lines.append("|---|---|---|---|---|---|---|---|")
    for key, row in summary.items():
        rs = [r for r in records if f"{r['set']}-{r['n']}" == key and "lsd_other" in r]
        a = np.array([r["lsd"]["success"] for r in rs], bool)
        b = np.array([r["lsd_other"]["success"] for r in rs], bool)
        both = a & b
        ca = [r["lsd"]["cost"] / r["c_star"] for r, m in zip(rs, both) if m]
        cb = [r["lsd_other"]["cost"] / r["c_star"] for r, m in zip(rs, both) if m]
        pair = {
            "tasks": len(rs),
            "success_lsd": float(a.mean()) if len(rs) else float("nan"),
            "success_other": float(b.mean()) if len(rs) else float("nan"),
            "other_only": int((b & ~a).sum()),
            "lsd_only": int((a & ~b).sum()),
            "c_lsd": float(np.mean(ca)) if ca else float("nan"),
            "c_other": float(np.mean(cb)) if cb else float("nan"),
        }
        row["other_vs_lsd"] = pair
        lines.append(
            f"| {row['set']} | {row['n']} | {pair['tasks']} | {pair['success_lsd']:.1%} | {pair['success_other']:.1%} "
            f"| {pair['other_only']} / {pair['lsd_only']} | {pair['c_lsd']:.2f} | {pair['c_other']:.2f} |"
        )
    return "\n".join(lines)


def _zeroed_semantics(sampler):
    import jax.numpy as jnp

    def fn(inputs):
        return sampler(inputs._replace(semantic=jnp.zeros_like(inputs.semantic)))

    return fn


def _run(args, argv) -> int:
    import dataclasses

    import numpy as np
    import scipy.ndimage as ndi

    from jaxsem.cli import enable_compilation_cache
    from jaxsem.lsd import run_trials, summarise
    from jaxsem.lsd._experiment import format_table  # layers: white-box
    from jaxsem.planning import DOOR, SoftCostGraph, plot_semantics
    from jaxsem.scripting import atomic_write_text

    enable_compilation_cache()
    out = pathlib.Path(args.json)
    records_path = out.with_name(out.stem + ".records.jsonl")
    figure = pathlib.Path(args.figure) if args.figure else out.with_name(out.stem + "_map.png")
    buildings, facts, tasks = [], [], {}
    for i, path in enumerate(args.map):
        t0 = time.perf_counter()
        b = load_run_map(args, path)
        if len(args.map) > 1:  # records name the map by its index
            b = dataclasses.replace(b, seed=i)
        fig_i = figure if len(args.map) == 1 else figure.with_name(f"{figure.stem}_{i}{figure.suffix}")
        plot_semantics(b, fig_i, title=f"{pathlib.Path(path).name}: doors red, outside light blue, unknown grey")
        free = ~b.occupancy
        fact = {
            "map": str(path),
            "index": i,
            "cells": list(b.shape),
            "resolution_m": b.resolution,
            "extent_m": [b.shape[1] * b.resolution, b.shape[0] * b.resolution],
            "free_m2": float(free.sum() * b.resolution**2),
            "indoor_free_m2": float((free & b.indoor).sum() * b.resolution**2),
            "outdoor_free_m2": float((free & ~b.indoor).sum() * b.resolution**2),
            "doors_found": int(ndi.label(b.semantic == DOOR, np.ones((3, 3)))[1]),
            "outside_is_outdoors": bool(b.outside_is_outdoors),
            "figure": str(fig_i),
            "load_seconds": time.perf_counter() - t0,
        }
        print(f"map: {fact}")
        graph = SoftCostGraph(b.occupancy, b)
        for kind in args.sets:
            tasks[(i, kind)] = run_tasks(args, b, kind, graph)
            fact[f"tasks_{kind}"] = len(tasks[(i, kind)])
            print(f"{kind}: {len(tasks[(i, kind)])} tasks (asked {args.trials})")
        buildings.append(b)
        facts.append(fact)
    sampler, base, variants = run_planners(args, buildings[0])
    t1 = time.perf_counter()
    records = run_trials(
        buildings,
        sampler,
        sets=tuple(args.sets),
        ns=tuple(args.n),
        seed=args.seed,
        max_steps=args.max_steps,
        progress=not args.no_progress,
        variants=variants,
        tasks=tasks,
        records_path=records_path,
        keep_paths=True,
        nav_config=base,
        base=not (args.uniform_only or args.reuse_base),
        provenance=_provenance(args),
        fresh=args.fresh,
    )
    if args.reuse_base:  # the earlier run's uniform and LSD rows joined to this run's variants
        from jaxsem.lsd import read_records
        from jaxsem.lsd._experiment import merge_records, records_stamp, write_records  # layers: white-box

        read_runs = _sibling("lsd_real_floor").read_runs
        earlier = read_records(read_runs([args.reuse_base], "lsd_real", flag="--reuse-base")[0][2])
        records = merge_records(records, [r for r in earlier if r["set"] in args.sets and r["n"] in args.n])
        write_records(records_path, records, records_stamp(records_path))
    if args.uniform_only:
        summary = {}
        for kind in args.sets:
            for n in args.n:
                rs = [r for r in records if r["set"] == kind and r["n"] == n]
                ok = np.array([r["uniform"]["success"] for r in rs], bool)
                summary[f"{kind}-{n}"] = {"set": kind, "n": n, "trials": len(rs), "success_uniform": float(ok.mean())}
        table = "\n".join(f"{k}: uniform {v['success_uniform']:.0%} of {v['trials']}" for k, v in summary.items())
    else:
        summary = summarise(records)
        table = format_table(summary)
        if args.other is not None:
            table += "\n" + _other_vs_lsd(summary, records)
    print(table)
    result = {
        "benchmark": "lsd_real",
        "command": "python benchmarks/lsd/lsd_real.py " + " ".join(argv),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "git": _git(),
        "protocol": args.protocol,
        "goal_flag": args.goal_flag,
        "nav_config": {k: v for k, v in dataclasses.asdict(base).items() if k != "sensor"},
        "map_facts": facts[0] if len(facts) == 1 else facts,
        "task_bounds": {
            "min_distance": args.min_distance,
            "tasks": args.tasks,
            "max_distance": [task_max_distance(args, b) for b in buildings]
            if len(buildings) > 1
            else task_max_distance(args, buildings[0]),
            "clearance": args.clearance,
        },
        "seconds": time.perf_counter() - t1,
        "reuse_base": args.reuse_base,
        "summary": summary,
        "table": table,
        "records": str(records_path),
    }
    atomic_write_text(out, json.dumps(result, indent=1, default=float))
    print(f"wrote {out} ({result['seconds'] / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    from jaxsem.scripting import run_main  # the one exit-status rule: bad flags exit 2

    sys.exit(run_main(main))

"""LSD's expert data (thesis section 3.3.2): partial maps paired with optimal paths.

A robot starts indoors and navigates towards a random goal with the uniform PRM (Euclidean
weights, no prior map), uncovering the partial maps. At random moments (probability
``sample_prob`` per step) it draws ``goals_per_moment`` new goals and computes their soft-cost
optimal paths on the *true* map (one single-source Dijkstra from the robot's cell serves them
all). Each (goal, path) becomes one sample paired with the partial maps at that moment. When the
robot reaches its goal (or fails), a new navigation task starts from where it stands.

Shard schema (``np.savez_compressed``; ``S`` samples; written by :func:`write_expert_dataset`,
read by :func:`load_expert_dataset`):

======================  ===================  ==============================================
key                     shape, dtype         meaning
======================  ===================  ==============================================
``occupancy``           (S, 160, 160) int8   partial occupancy crop centred on the robot
                                             (crop cell [80, 80]); -1 unknown, 0 free,
                                             1 occupied (off the map: 1)
``semantic``            (S, 160, 160) int8   partial semantic crop: 0 none, 2 door,
                                             3 window, 4 exit sign
``context``             (S, 4) float32       [cos a, sin a, min(d, 20 m) / 20 m, outdoors]
                                             (a: world heading of the goal, x = crop
                                             columns, y = crop rows; outdoors 1.0 / 0.0)
``path_mask``           (S, 160, 160) bool   cells of the optimal path inside the crop
``path_cells``          (P, 2) int16         the same cells as (row, col) crop indices ...
``path_offsets``        (S + 1,) int64       ... sample i owns rows offsets[i]:offsets[i+1]
``robot_xy``            (S, 2) float32       world position of the robot (metres)
``goal_xy``             (S, 2) float32       world position of the goal
``goal_outdoors``       (S,) bool            goal outside the building
``path_cost``           (S,) float32         soft cost of the full optimal path
``building_seed``       () int64             seed of the building (with ``family``)
``family``              () str               'train', 'test', 'house' or 'campus'
``resolution``          () float32           metres per cell (0.1)
======================  ===================  ==============================================
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing
import os
import pathlib
import zipfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

import jax
import jax.numpy as jnp
import numpy as np

from .._atomic import atomic_save_npz
from .._files import check_npz
from ..planning import (
    CROP_SIZE,
    DEFAULT_RESOLUTION,
    FREE,
    NONE,
    OBJECT_CLASSES,
    OCCUPIED,
    Building,
    MapState,
    NavConfig,
    SoftCostGraph,
    Trial,
    generate_building,
    local_inputs,
    task_pools,
)
from ..training import check_stamp

SCHEMA_VERSION = 1
SCHEMA_KEYS = (
    "occupancy",
    "semantic",
    "context",
    "path_mask",
    "path_cells",
    "path_offsets",
    "robot_xy",
    "goal_xy",
    "goal_outdoors",
    "path_cost",
    "building_seed",
    "family",
    "resolution",
)


@dataclasses.dataclass(frozen=True)
class ExpertConfig:
    """Settings of expert data generation."""

    samples_per_building: int = 200
    sample_prob: float = 0.1  # chance per step of a sampling moment
    goals_per_moment: int = 8  # one Dijkstra (~0.1-0.2 s on a building) serves them all
    min_goal_distance: float = 3.0  # metres, straight line from the robot
    clearance: float = 0.3  # start/goal cells at least this far from any obstacle
    outdoor_goal_prob: float = 0.4
    nav: NavConfig = NavConfig(n_samples=1000, max_steps=600)
    max_tasks: int = 200  # safety bound on navigation tasks per building


# The per-sample arrays of a shard (beside path_offsets and the per-shard scalars).
_SHARD_ARRAYS = (
    "occupancy",
    "semantic",
    "context",
    "path_mask",
    "path_cells",
    "robot_xy",
    "goal_xy",
    "goal_outdoors",
    "path_cost",
)


def _crop_path(cells: np.ndarray, center: np.ndarray, size: int):
    local = cells - center[None, :] + size // 2
    keep = np.all((local >= 0) & (local < size), axis=1)
    local = local[keep]
    mask = np.zeros((size, size), bool)
    mask[local[:, 0], local[:, 1]] = True
    return mask, np.unique(local, axis=0).astype(np.int16)


def generate_expert_samples(
    building: Building, seed: int, config: ExpertConfig = ExpertConfig(), progress=None
) -> dict:
    """Expert samples for one building as a dict of arrays (the shard schema of this module).

    ``progress``: optional callable ``progress(n_new)`` called as samples are made.
    """
    rng = np.random.default_rng([int(seed), building.seed, 0xE4])
    key = jax.random.PRNGKey(int(rng.integers(2**31)))
    graph = SoftCostGraph(building.occupancy, building)
    inside, outside = task_pools(building, config.clearance)
    out = {k: [] for k in _SHARD_ARRAYS}
    n = 0
    start = building.cell_center(inside[rng.integers(len(inside))])
    state = None
    for _ in range(config.max_tasks):
        if n >= config.samples_per_building:
            break
        pool = outside if rng.random() < config.outdoor_goal_prob else inside
        goal = building.cell_center(pool[rng.integers(len(pool))])
        key, sub = jax.random.split(key)
        trial = Trial(building, start, goal, sub, config.nav, None, float(rng.uniform(-math.pi, math.pi)), state=state)
        while n < config.samples_per_building:
            if rng.random() < config.sample_prob:
                tree = graph.search(trial.xy)
                for _ in range(config.goals_per_moment):
                    out_goal = rng.random() < config.outdoor_goal_prob
                    pool = outside if out_goal else inside
                    g = building.cell_center(pool[rng.integers(len(pool))])
                    for _try in range(19):  # at most 20 draws; the last one is kept
                        if np.linalg.norm(g - trial.xy) >= config.min_goal_distance:
                            break
                        g = building.cell_center(pool[rng.integers(len(pool))])
                    p = tree.path_to(g)
                    if not p.found:
                        continue
                    inp = local_inputs(
                        trial.state,
                        trial.xy,
                        g,
                        out_goal,
                        building,
                        CROP_SIZE,
                        config.nav.max_context_distance,
                    )
                    mask, cells = _crop_path(p.cells, np.asarray(inp.center_cell), CROP_SIZE)
                    out["occupancy"].append(np.asarray(inp.occupancy))
                    out["semantic"].append(np.asarray(inp.semantic))
                    out["context"].append(np.asarray(inp.context))
                    out["path_mask"].append(mask)
                    out["path_cells"].append(cells)
                    out["robot_xy"].append(trial.xy.astype(np.float32))
                    out["goal_xy"].append(g.astype(np.float32))
                    out["goal_outdoors"].append(out_goal)
                    out["path_cost"].append(np.float32(p.cost))
                    n += 1
                    if progress is not None:
                        progress(1)
                    if n >= config.samples_per_building:
                        break
            if not trial.step():
                break
        start, state = trial.xy.copy(), trial.state
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in out["path_cells"]])]).astype(np.int64)
    size = CROP_SIZE
    return {
        "occupancy": np.asarray(out["occupancy"], np.int8).reshape(-1, size, size),
        "semantic": np.asarray(out["semantic"], np.int8).reshape(-1, size, size),
        "context": np.asarray(out["context"], np.float32).reshape(-1, 4),
        "path_mask": np.asarray(out["path_mask"], bool).reshape(-1, size, size),
        "path_cells": (np.concatenate(out["path_cells"]) if out["path_cells"] else np.zeros((0, 2))).astype(np.int16),
        "path_offsets": offsets,
        "robot_xy": np.asarray(out["robot_xy"], np.float32).reshape(-1, 2),
        "goal_xy": np.asarray(out["goal_xy"], np.float32).reshape(-1, 2),
        "goal_outdoors": np.asarray(out["goal_outdoors"], bool),
        "path_cost": np.asarray(out["path_cost"], np.float32),
        "building_seed": np.int64(building.seed),
        "family": np.str_(building.family),
        "resolution": np.float32(building.resolution),
    }


def full_map_state(building: Building) -> MapState:
    """The partial-map encoding of a building seen completely: what a fully informed robot knows.

    occupancy OCCUPIED / FREE everywhere (no UNKNOWN), semantic the building's object classes
    (door, window, exit sign; walls are NONE there, as the sensors write them). The input of the
    *oracle* LSD network (:func:`with_full_map`), a diagnostic of how much the partial map costs.
    """
    occ = np.where(np.asarray(building.occupancy, bool), OCCUPIED, FREE).astype(np.int8)
    sem = np.asarray(building.semantic, np.int8)
    sem = np.where(np.isin(sem, OBJECT_CLASSES), sem, NONE).astype(np.int8)
    return MapState(jnp.asarray(occ), jnp.asarray(sem))


def with_full_map(shard: dict, building: Building | None = None) -> dict:
    """A copy of one expert shard (:func:`generate_expert_samples`' dict, or an ``np.load`` of a
    shard file) whose ``occupancy`` / ``semantic`` crops are cut from the *true* map of its
    building at each sample's ``robot_xy``; every other key is unchanged (same goals, paths and
    context). The training data of the fully supervised oracle. ``building``: the shard's
    building, default regenerated from its ``family`` and ``building_seed``. ``ValueError`` for a
    shard without those keys or whose building does not match."""
    missing = [k for k in ("occupancy", "semantic", "robot_xy", "building_seed", "family") if k not in shard]
    if missing:
        raise ValueError(f"shard: missing keys {missing}; expected an expert shard (see EXPERT_SCHEMA)")
    seed, family = int(np.asarray(shard["building_seed"])), str(np.asarray(shard["family"]))
    if building is None:
        res = float(np.asarray(shard.get("resolution", DEFAULT_RESOLUTION)))
        building = generate_building(seed, family, res)
    elif (building.seed, building.family) != (seed, family):
        raise ValueError(
            f"building: expected the shard's building ({family!r}, {seed}), got ({building.family!r}, {building.seed})"
        )
    state = full_map_state(building)
    xy = jnp.asarray(np.asarray(shard["robot_xy"], np.float64).reshape(-1, 2))
    size = int(np.asarray(shard["occupancy"]).shape[-1])
    grid = building.grid
    crops = jax.vmap(lambda p: local_inputs(state, p, p, False, grid, size, 20.0))(xy)
    out = {k: np.asarray(v) for k, v in shard.items()}
    out["occupancy"] = np.asarray(crops.occupancy, np.int8).reshape(np.shape(shard["occupancy"]))
    out["semantic"] = np.asarray(crops.semantic, np.int8).reshape(np.shape(shard["semantic"]))
    return out


#: buildings a worker process generates before it is replaced by a fresh one
WORKER_TASKS = 16


def _init_worker(cache_dir):
    if cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def _shard_job(args):
    family, seed, config, out_dir, resolution = args
    b = generate_building(seed, family, resolution)
    data = generate_expert_samples(b, seed, config)
    path = pathlib.Path(out_dir) / f"expert_{family}_{seed:05d}.npz"
    atomic_save_npz(path, record=False, **data)  # one shard of many: not listed in the run's summary
    return str(path), int(len(data["context"]))


def write_expert_dataset(
    out_dir,
    family: str,
    seeds,
    config: ExpertConfig = ExpertConfig(),
    workers: int = 2,
    resolution: float = DEFAULT_RESOLUTION,
    progress: bool = True,
    job_fn=None,
    worker_tasks: int = WORKER_TASKS,
):
    """Generates one shard per building seed into ``out_dir`` (``expert_<family>_<seed>.npz``),
    in parallel over buildings (``workers`` processes, spawned), with a tqdm bar; also writes
    ``schema.json``. Existing shards are kept (resume); ``stamp_<family>.json`` records the
    family's config and resolution, and a call with others into the same folder is refused
    (:func:`jaxsem.training.check_stamp`; more seeds extend it). Returns the list of shard paths.
    ``ChildProcessError`` (naming the unfinished seeds) when a worker process dies; the shards
    already written stay. ``job_fn``: the per-building job (tests), default the shard writer.
    ``worker_tasks``: buildings a worker process generates before a fresh one replaces it."""
    if not (isinstance(worker_tasks, int) and worker_tasks >= 1):
        raise ValueError(f"worker_tasks: expected an int >= 1, got {worker_tasks!r}")
    job_fn = _shard_job if job_fn is None else job_fn
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "schema.json").write_text(
        json.dumps(
            {
                "version": SCHEMA_VERSION,
                "keys": list(SCHEMA_KEYS),
                "crop_size": CROP_SIZE,
                "doc": "see jaxsem.lsd.EXPERT_SCHEMA",
            },
            indent=1,
        )
    )
    check_stamp(
        out / f"stamp_{family}.json",
        {"what": "expert shards", "family": family, "config": dataclasses.asdict(config), "resolution": resolution,
         "schema": SCHEMA_VERSION},
        adopt=True,
        hint="write to another folder",
    )  # fmt: skip
    jobs = [
        (family, int(s), config, str(out), resolution)
        for s in seeds
        if not (out / f"expert_{family}_{int(s):05d}.npz").exists()
    ]
    done = [
        str(out / f"expert_{family}_{int(s):05d}.npz")
        for s in seeds
        if (out / f"expert_{family}_{int(s):05d}.npz").exists()
    ]
    bar = None
    if progress:
        from tqdm import tqdm  # deferred: tqdm is slow to import and only a shown bar needs it

        bar = tqdm(total=len(jobs), desc=f"expert {family}", unit="building")
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            done.append(job_fn(job)[0])
            if bar:
                bar.update(1)
    else:
        ctx = multiprocessing.get_context("spawn")  # JAX is multithreaded: never fork it
        # workers share the parent's compile cache (jax's options are dynamic attributes, not in its stubs)
        cache = jax.config.jax_compilation_cache_dir  # pyright: ignore[reportAttributeAccessIssue]
        # An executor, not multiprocessing.Pool: a worker that dies (killed, or aborted inside
        # XLA) hung Pool.imap forever with its building lost (240 buildings, 2 missing, no error);
        # here it raises BrokenProcessPool. Workers are replaced every WORKER_TASKS buildings, so
        # one process does not pile up compiled programs and memory over hundreds: by a fresh
        # executor per batch, not max_tasks_per_child, which on Python 3.11 hung for good once
        # every worker had retired (32 of 240 buildings written, no live worker, no error).
        batch = workers * worker_tasks
        for b0 in range(0, len(jobs), batch):
            part = jobs[b0 : b0 + batch]
            with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(cache,)) as pool:
                futures = {pool.submit(job_fn, job): job[1] for job in part}
                try:
                    for fut in as_completed(futures):
                        done.append(fut.result()[0])
                        if bar:
                            bar.update(1)
                except BrokenProcessPool as exc:
                    if bar:
                        bar.close()
                    lost = sorted(seed for f, seed in futures.items() if not f.done() or f.exception() is not None)
                    lost += [job[1] for job in jobs[b0 + batch :]]
                    raise ChildProcessError(
                        f"workers: a worker process died (killed or crashed) with building seeds {lost[:8]}"
                        f"{' ...' if len(lost) > 8 else ''} unfinished; the {len(done)} shards written in "
                        f"{str(out)!r} are kept: rerun the same command to resume"
                    ) from exc
    if bar:
        bar.close()
    return sorted(done)


def load_expert_dataset(paths) -> dict:
    """Concatenates shards (paths or a folder) into one dict with the schema's per-sample keys
    plus ``building_seed`` (S,) and ``family`` (S,); ``path_offsets`` is re-based."""
    if isinstance(paths, (str, os.PathLike)) and pathlib.Path(paths).is_dir():
        # ``expert_*.npz.tmp.npz``: half a shard of an earlier writer killed mid-write
        paths = sorted(p for p in pathlib.Path(paths).glob("expert_*.npz") if not p.name.endswith(".tmp.npz"))
    elif isinstance(paths, (str, os.PathLike)):  # one shard
        paths = [paths]
    paths = [pathlib.Path(p) for p in paths]
    if not paths:
        raise ValueError("paths: no expert shards given (expected expert_*.npz files)")
    parts = {k: [] for k in SCHEMA_KEYS}
    base = 0
    for p in paths:
        shard = _read_shard(p)
        S = len(shard["context"])
        for k in _SHARD_ARRAYS:
            parts[k].append(shard[k])
        parts["path_offsets"].append(shard["path_offsets"][:-1] + base)
        base += int(shard["path_offsets"][-1])
        parts["building_seed"].append(np.full(S, int(shard["building_seed"])))
        parts["family"].append(np.full(S, str(shard["family"])))
        parts["resolution"].append(np.full(S, float(shard["resolution"]), np.float32))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["path_offsets"] = np.append(out["path_offsets"], base)
    return out


def _read_shard(p: pathlib.Path) -> dict:
    """One shard's arrays, read whole; a damaged or foreign file is a ``ValueError`` naming it
    (``np.load`` alone says "pickled (object) data" or "bad zip" and names no file)."""
    keys = (*_SHARD_ARRAYS, "path_offsets", "building_seed", "family", "resolution")
    try:
        # The file is opened here, not by np.load: np.load left a truncated zip's file open.
        with open(p, "rb") as f:
            if f.read(4) != b"PK\x03\x04":
                raise ValueError(f"{p}: not a readable expert shard (not an .npz archive)")
            f.seek(0)
            check_npz(p)  # the declared sizes within budget before anything is inflated
            with np.load(f) as z:
                missing = [k for k in keys if k not in z.files]
                if missing:
                    raise ValueError(f"{p}: not an expert shard (missing {', '.join(missing)})")
                return {k: z[k] for k in keys}
    except ValueError as exc:
        if str(exc).startswith(f"{p}:"):
            raise
        raise ValueError(f"{p}: not a readable expert shard ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{p}: not a readable expert shard ({type(exc).__name__}: {exc})") from None

"""The Table 3.1 / figure 3-8 experiment: PRM + LSD against PRM + Unf on unseen buildings.

For every test building, test set ('II': start and goal indoors; 'IO': start indoors, goal
outdoors), sample budget N and trial, both planners run the online loop of
:func:`jaxsem.planning.navigate` from the same start, initial yaw and PRNG key: the uniform PRM
with Euclidean edge weights, and the LSD-sampled PRM with ``-log p`` edge weights. A record keeps
success, the distance travelled ``C`` (metres) and the resolution-optimal length ``C*`` (soft-cost
optimal path on the true map). :func:`summarise` gives per (set, N): success rates of both, and
on mutually successful trials the mean +- s.e.m. of ``C_l / C*`` and ``C_b / C*``, the
zero-intercept regression slope of ``C_b`` on ``C_l`` and its R^2.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from .._atomic import atomic_write_text
from .._files import read_text
from ..metrics import mean_sem, zero_intercept_slope
from ..planning import NavConfig, sample_tasks
from ..training import ConfigMismatchError, stamp_differences, tree_digest
from ._config import cpu_config
from ._expert import ExpertConfig, write_expert_dataset
from ._train import load_model, train_and_evaluate


def trial_key(seed: int, building_seed: int, kind: str, t_i: int, n: int):
    """The PRNG key of one trial of :func:`run_trials`: task seed ``seed``, the building's seed,
    set ``kind`` ('II' or 'IO'), task index ``t_i`` and budget ``n``. Every planner of the trial
    gets the same key, a function of the trial only (not of Python's hash seed), so a trial can
    be replayed from its record."""
    if kind not in ("II", "IO"):
        raise ValueError(f"kind: expected 'II' or 'IO', got {kind!r}")
    return jax.random.PRNGKey(
        int(
            np.random.default_rng(
                [int(seed), int(building_seed) & 0xFFFFFFFF, ("II", "IO").index(kind), t_i, n]
            ).integers(2**31)
        )
    )


def nav_record(res, seconds: float, *, replans: bool = False) -> dict:
    """The JSON record of one planner's trial (a :class:`~jaxsem.planning.NavResult`): success,
    distance travelled, why it stopped, steps, plans and the wall time ``seconds``; with
    ``replans`` also the roadmap growths and the replans by cause. The trial runner and the
    pipeline benchmark write their records with it, so the two files read alike."""
    rec = {
        "success": bool(res.success),
        "cost": float(res.cost),
        "reason": res.reason,
        "steps": int(res.steps),
        "plans": int(res.plans),
    }
    if replans:
        rec["grown"] = int(res.grown)
        rec["replans_blocked"] = int(res.blocked_replans)
        rec["replans_periodic"] = int(res.periodic_replans)
    rec["seconds"] = seconds
    return rec


def _run_job(job, planners: dict, seed: int, max_steps: int, keep_paths: bool = False, base=None) -> dict:
    """One (building, set, trial, N): every planner from the same start, yaw and key."""
    b, kind, t_i, task, n = job
    base = base or NavConfig()
    key = trial_key(seed, b.seed, kind, t_i, n)
    rec = {
        "building": int(b.seed),
        "set": kind,
        "trial": t_i,
        "n": n,
        "c_star": float(task.c_star),
        "start": task.start.tolist(),
        "goal": task.goal.tolist(),
    }
    for name, (smp, changes) in planners.items():
        cfg = dataclasses.replace(base, n_samples=n, max_steps=max_steps, **changes)
        t0 = time.perf_counter()
        res = task.navigate(b, key, cfg, smp)
        rec[name] = nav_record(res, time.perf_counter() - t0, replans=True)
        if keep_paths:
            rec[name]["path"] = np.round(np.asarray(res.path, np.float64), 3).tolist()
    return rec


def _on_device(planners: dict, device) -> dict:
    """The planners with each sampler's parameters placed on ``device`` (samplers with an
    ``on_device`` method, e.g. :class:`LSDSampler`; other callables as they are)."""
    out = {}
    for name, (smp, changes) in planners.items():
        move = getattr(smp, "on_device", None)
        out[name] = (move(device) if callable(move) else smp, changes)
    return out


def run_trials(
    buildings,
    sampler,
    sets=("II", "IO"),
    ns=(100, 500, 1000, 5000),
    trials: int = 3,
    seed: int = 0,
    max_steps: int = 10_000,
    progress: bool = True,
    log=print,
    variants: dict | None = None,
    mesh=None,
    base: bool = True,
    tasks: dict | None = None,
    records_path=None,
    keep_paths: bool = False,
    nav_config=None,
    provenance: dict | None = None,
    fresh: bool = False,
) -> list:
    """Runs the planners on every (building, set, N, trial); returns a list of dict records.

    buildings: test :class:`jaxsem.planning.Building` s; sampler: an :class:`LSDSampler` (or any
    ``sampler(LocalInputs) -> (k, k)`` probabilities); trials: tasks per building and set (the
    same tasks for every N); max_steps: the loop's step limit (thesis: 10,000). variants: extra
    planners (ablation rows) run on the same tasks with the same key, ``{name: (sampler or
    None, dict of NavConfig changes)}``; 'uniform' and 'lsd' run too unless ``base`` is False
    (then only the variants run: records to merge with a run of the same tasks,
    :func:`merge_records`; :func:`summarise` needs 'uniform' and 'lsd').

    mesh: None (every trial on the default device, one after another) or a one-axis
    :class:`jax.sharding.Mesh` (:func:`jaxsem.parallel.devices_mesh`, ``--devices N|all``): the
    trials are dealt round-robin over the mesh's devices and each device's group runs in its own
    host thread with its arrays (maps, roadmaps, the sampler's parameters via ``on_device``) on
    that device. The navigation loop is host-driven (scipy's Dijkstra and the trial's control
    flow run in Python), so this is task parallelism over devices, not one sharded ``jit``: it
    overlaps one device's jitted sensing, network and roadmap work with the others' and the
    host's, and speeds up only as far as the host's Python (one interpreter lock) keeps up.
    The records are the same, in the same order, as with ``mesh=None`` (each trial's key is a
    function of the trial only). Every device of the mesh must belong to this process.

    tasks: ``{(building index, set): [Task, ...]}`` to run instead of ``sample_tasks(b, set,
    trials, seed)`` (e.g. tasks drawn with distance and clearance bounds on a scanned map).
    records_path: a JSON-lines file the records are appended to as each trial ends (flushed and
    synced: a killed run keeps every finished trial); when it exists, its records of the same
    tasks are read back and those trials are not run again (the run resumes). keep_paths: each
    planner's travelled path ((T, 2) world metres, mm-rounded) goes into its record.
    nav_config: the :class:`~jaxsem.planning.NavConfig` the planners start from (``n_samples``
    and ``max_steps`` are set per job; default: ``NavConfig()``).

    The records file starts with a stamp of what makes a trial: the maps' contents, ``seed``,
    ``max_steps``, ``keep_paths``, ``nav_config``, each planner's changes and its sampler's
    parameters, and ``provenance`` (the caller's other inputs: a checkpoint's hash, the flags of
    a command). A resume whose stamp differs raises :class:`~jaxsem.training.ConfigMismatchError`
    naming each difference, so no table mixes trials made under other settings; ``fresh=True``
    starts the file over (only a records file is overwritten). The number of tasks, the sets and
    the N values may grow between runs: their records are keyed by task.
    """
    for kind in sets:
        if kind not in ("II", "IO"):
            raise ValueError(f"sets: expected 'II' and/or 'IO', got {kind!r}")
    if trials < 1:
        raise ValueError(f"trials: expected >= 1, got {trials}")
    devices = None
    if mesh is not None:
        if not isinstance(mesh, jax.sharding.Mesh) or len(mesh.axis_names) != 1:
            raise ValueError(f"mesh: expected a one-axis jax.sharding.Mesh (jaxsem.parallel.data_mesh()), got {mesh!r}")
        devices = list(mesh.devices.flat)
        foreign = [d for d in devices if d.process_index != jax.process_index()]
        if foreign:
            raise ValueError(
                f"mesh: {len(foreign)} of its devices belong to other processes; trials run on this "
                "process's devices only (give each process a mesh of its local devices and merge the records)"
            )
    planners = {"uniform": (None, {}), "lsd": (sampler, {})} if base else {}
    planners.update(variants or {})
    if not planners:
        raise ValueError("variants: base=False needs at least one variant planner")
    jobs = []
    for b_i, b in enumerate(buildings):
        for kind in sets:
            chosen = tasks[(b_i, kind)] if tasks is not None else sample_tasks(b, kind, trials, seed)
            for t_i, task in enumerate(chosen):
                for n in ns:
                    jobs.append((b, kind, t_i, task, int(n)))
    stream = None
    if records_path is not None:
        stamp = {
            "seed": int(seed),
            "max_steps": int(max_steps),
            "keep_paths": bool(keep_paths),
            "nav_config": dataclasses.asdict(nav_config if nav_config is not None else NavConfig()),
            "maps": [_map_digest(b) for b in buildings],
            "planners": {name: {"sampler": _sampler_digest(sp), "changes": ch} for name, (sp, ch) in planners.items()},
            "provenance": dict(provenance or {}),
        }
        stream = _RecordStream(records_path, list(planners), stamp, fresh=fresh)
    bar = None
    if progress:
        from tqdm import tqdm  # deferred: tqdm is slow to import and only a shown bar needs it

        bar = tqdm(total=len(jobs), desc="table 3.1 trials", unit="task")
    lock = threading.Lock()

    def done(rec):
        if bar:
            with lock:
                bar.update(1)
                ok = " ".join(f"{name}={int(rec[name]['success'])}" for name in planners)
                bar.set_postfix_str(f"set={rec['set']} n={rec['n']} {ok}")

    records: list = [None] * len(jobs)

    def run_one(i, group):
        rec = stream.get(jobs[i]) if stream is not None else None
        if rec is None:
            rec = _run_job(jobs[i], group, seed, max_steps, keep_paths, nav_config)
            if stream is not None:
                stream.append(rec)
        records[i] = rec
        done(rec)

    if devices is None or len(devices) == 1:
        group = planners if devices is None else _on_device(planners, devices[0])
        for i in range(len(jobs)):
            if devices is None:
                run_one(i, group)
            else:
                with jax.default_device(devices[0]):
                    run_one(i, group)
    else:

        def run_group(d_i):
            device = devices[d_i]
            group = _on_device(planners, device)
            with jax.default_device(device):
                for i in range(d_i, len(jobs), len(devices)):
                    run_one(i, group)

        with ThreadPoolExecutor(max_workers=len(devices)) as pool:
            for fut in [pool.submit(run_group, d_i) for d_i in range(len(devices))]:
                fut.result()
    if bar:
        bar.close()
    return records


def _map_digest(b) -> str:
    known = getattr(b, "known", None)
    return tree_digest(
        (np.asarray(b.occupancy), np.asarray(b.semantic), np.asarray(b.origin), float(b.resolution), int(b.seed))
        + ((np.asarray(known),) if known is not None else ())
    )


def _sampler_digest(sampler) -> str | None:
    """The sampler's identity for a stamp: its class, settings and parameters' hash (a plain
    function: its qualified name; the caller's ``provenance`` names what it closes over)."""
    if sampler is None:
        return None
    params = getattr(sampler, "params", None)
    name = getattr(sampler, "__qualname__", type(sampler).__qualname__)
    if params is None:
        return name
    extra = {k: getattr(sampler, k) for k in ("use_context", "uniform_mix") if hasattr(sampler, k)}
    return f"{name} {tree_digest(params)} {json.dumps(extra, sort_keys=True)}"


class _RecordStream:
    """The JSON-lines record file of :func:`run_trials`: a stamp line first, then the finished
    records, read back by task; new ones appended one line each (flushed and fsynced under a
    lock). A torn last line (a run killed while writing) is ignored and rewritten by the resumed
    run. A file whose stamp differs from this run's is refused (``fresh``: started over)."""

    def __init__(self, path, planners: list, stamp: dict, fresh: bool = False):
        self.path = pathlib.Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.done: dict = {}
        self.lock = threading.Lock()
        stamp = json.loads(json.dumps(stamp, default=str))
        header = json.dumps({"stamp": stamp}) + "\n"
        if self.path.exists():
            lines = read_text(self.path, "records file").splitlines()
            made = _stamp_of(lines[0]) if lines else None
            if fresh:
                if lines and made is None and not _is_record(lines[0]):
                    raise ValueError(f"records_path: {self.path} is not a records file; not overwritten")
                lines = []
            elif lines and made is None:
                raise ConfigMismatchError(
                    f"records_path: {self.path} holds records with no stamp of the settings that made them;"
                    " start over (--fresh) or write to another file"
                )
            elif lines:
                diff = stamp_differences(made or {}, stamp)
                if diff:
                    raise ConfigMismatchError(
                        f"records_path: {self.path} was made with other settings ({'; '.join(diff)});"
                        " start over (--fresh) or write to another file"
                    )
                lines = lines[1:]
            good = []
            for i, line in enumerate(lines):
                try:
                    r = json.loads(line)
                except json.JSONDecodeError:
                    if i == len(lines) - 1:
                        break  # the torn tail of a killed run
                    raise ValueError(f"records_path: {self.path} line {i + 1} is not a JSON record") from None
                good.append(line)
                if all(name in r for name in planners):
                    self.done[_record_key(r)] = r
            atomic_write_text(self.path, header + "".join(g + "\n" for g in good), record=False)
        else:
            atomic_write_text(self.path, header, record=False)

    @staticmethod
    def _job_key(job) -> tuple:
        b, kind, t_i, task, n = job
        return (
            int(b.seed),
            kind,
            t_i,
            int(n),
            tuple(np.asarray(task.start).tolist()),
            tuple(np.asarray(task.goal).tolist()),
        )

    def get(self, job):
        return self.done.get(self._job_key(job))

    def append(self, rec: dict) -> None:
        with self.lock, self.path.open("a") as f:
            f.write(json.dumps(rec) + "\n")
            f.flush()
            os.fsync(f.fileno())


def _stamp_of(line: str) -> dict | None:
    try:
        r = json.loads(line)
    except json.JSONDecodeError:
        return None
    return r["stamp"] if isinstance(r, dict) and set(r) == {"stamp"} and isinstance(r["stamp"], dict) else None


def _is_record(line: str) -> bool:
    try:
        r = json.loads(line)
    except json.JSONDecodeError:
        return False
    return isinstance(r, dict) and {"building", "set", "trial", "n"} <= set(r)


def read_records(path) -> list:
    """The records of a :func:`run_trials` ``records_path`` file (its stamp line and a torn last
    line skipped); :func:`records_stamp` gives the stamp."""
    out = []
    lines = read_text(path, "records file").splitlines()
    for i, line in enumerate(lines):
        if i == 0 and _stamp_of(line) is not None:
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            if i != len(lines) - 1:
                raise ValueError(f"path: {path} line {i + 1} is not a JSON record") from None
    return out


def records_stamp(path) -> dict | None:
    """The stamp a :func:`run_trials` records file starts with (None for a file without one)."""
    with open(path, "rb") as f:
        head = f.readline()
    try:
        return _stamp_of(head.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a readable records file (not UTF-8 text)") from None


def write_records(path, records: list, stamp: dict | None) -> None:
    """Writes a records file atomically: ``stamp`` (from :func:`records_stamp`) then one line per record."""
    head = json.dumps({"stamp": stamp}) + "\n" if stamp is not None else ""
    atomic_write_text(path, head + "".join(json.dumps(r) + "\n" for r in records))


def _record_key(r: dict) -> tuple:
    return (r["building"], r["set"], r["trial"], r["n"], tuple(r["start"]), tuple(r["goal"]))


def merge_records(*runs: list) -> list:
    """Joins runs of the same tasks planner-wise: records of the same (building, set, trial, N,
    start, goal) become one record holding every run's planners (the first run's order; a
    planner in two runs keeps the first run's result). Records of tasks only one run has are
    kept as they are."""
    out: dict = {}
    for recs in runs:
        for r in recs:
            k = _record_key(r)
            if k in out:
                for name, v in r.items():
                    out[k].setdefault(name, v)
            else:
                out[k] = dict(r)
    return list(out.values())


def _rate_sem(x):
    x = np.asarray(x, np.float64)
    p = float(x.mean()) if x.size else float("nan")
    return p, float(np.sqrt(p * (1 - p) / x.size)) if x.size > 1 else 0.0


def summarise(records: list) -> dict:
    """Per ``f"{set}-{N}"``: trials, success rates (``success_<planner>`` and its binomial s.e.m.
    ``success_<planner>_sem``), the paired count of LSD-only and uniform-only successes, mutual
    successes and the cost statistics of LSD against uniform; ablation planners get their
    success rates too."""
    out = {}
    keys = sorted({(r["set"], r["n"]) for r in records}, key=lambda k: (k[0], k[1]))
    for kind, n in keys:
        rs = [r for r in records if r["set"] == kind and r["n"] == n]
        su = np.array([r["uniform"]["success"] for r in rs])
        sl = np.array([r["lsd"]["success"] for r in rs])
        both = su & sl
        cs = np.array([r["c_star"] for r in rs])[both]
        cl = np.array([r["lsd"]["cost"] for r in rs])[both]
        cb = np.array([r["uniform"]["cost"] for r in rs])[both]
        slope = zero_intercept_slope(cl, cb) if both.any() else float("nan")
        if both.sum() >= 2:
            ss_res = float(np.sum((cb - slope * cl) ** 2))
            ss_tot = float(np.sum((cb - cb.mean()) ** 2))
            r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan")
        else:
            r2 = float("nan")
        row = {
            "set": kind,
            "n": int(n),
            "trials": len(rs),
            "mutual": int(both.sum()),
            "success_uniform": float(su.mean()),
            "success_lsd": float(sl.mean()),
            "success_uniform_sem": _rate_sem(su)[1],
            "success_lsd_sem": _rate_sem(sl)[1],
            "lsd_only": int((sl & ~su).sum()),
            "uniform_only": int((su & ~sl).sum()),
            "cl_over_cstar": mean_sem(cl / cs) if both.any() else (float("nan"), float("nan")),
            "cb_over_cstar": mean_sem(cb / cs) if both.any() else (float("nan"), float("nan")),
            "slope_cb_on_cl": slope,
            "r2": r2,
        }
        for name in rs[0]:
            if isinstance(rs[0][name], dict) and name not in ("uniform", "lsd") and "success" in rs[0][name]:
                x = np.array([r[name]["success"] for r in rs])
                row[f"success_{name}"], row[f"success_{name}_sem"] = _rate_sem(x)
                mut = x & su
                cx = np.array([r[name]["cost"] for r in rs])[mut]
                csx = np.array([r["c_star"] for r in rs])[mut]
                row[f"c_{name}_over_cstar_vs_uniform"] = (
                    mean_sem(cx / csx) if mut.any() else (float("nan"), float("nan"))
                )
        # A variant run by both planners ('lsd_X' and 'uniform_X', e.g. the thesis' protocol) is
        # compared pairwise like the defaults: X-only successes and costs on mutual successes.
        for name in rs[0]:
            other = "uniform_" + name[len("lsd_") :]
            if name.startswith("lsd_") and isinstance(rs[0][name], dict) and isinstance(rs[0].get(other), dict):
                xl = np.array([r[name]["success"] for r in rs])
                xu = np.array([r[other]["success"] for r in rs])
                mut = xl & xu
                csx = np.array([r["c_star"] for r in rs])[mut]
                nan2 = (float("nan"), float("nan"))
                row[f"paired_{name[len('lsd_') :]}"] = {
                    "lsd_only": int((xl & ~xu).sum()),
                    "uniform_only": int((xu & ~xl).sum()),
                    "mutual": int(mut.sum()),
                    "cl_over_cstar": mean_sem(np.array([r[name]["cost"] for r in rs])[mut] / csx)
                    if mut.any()
                    else nan2,
                    "cb_over_cstar": mean_sem(np.array([r[other]["cost"] for r in rs])[mut] / csx)
                    if mut.any()
                    else nan2,
                }
        out[f"{kind}-{n}"] = row
    return out


def _pm(ms):
    m, s = ms
    return "-" if not np.isfinite(m) else f"{m:.2f} +- {s:.2f}"


def format_table(summary: dict) -> str:
    """A markdown table of :func:`summarise`'s output (one row per set and N), plus one row
    per ablation planner when there are any."""
    lines = [
        "| set | N | trials | success Unf | success LSD | LSD-only / Unf-only | mutual | C_l/C* | C_b/C* | "
        "slope C_b~C_l | R^2 |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in summary.values():
        lines.append(
            f"| {v['set']} | {v['n']} | {v['trials']} | {100 * v['success_uniform']:.0f} % | "
            f"{100 * v['success_lsd']:.0f} % | {v.get('lsd_only', '-')} / {v.get('uniform_only', '-')} | "
            f"{v['mutual']} | {_pm(v['cl_over_cstar'])} | "
            f"{_pm(v['cb_over_cstar'])} | {v['slope_cb_on_cl']:.2f} | {v['r2']:.2f} |"
        )
    abl = sorted(
        {
            k[len("success_") : -len("_sem")]
            for v in summary.values()
            for k in v
            if k.startswith("success_") and k.endswith("_sem")
        }
        - {"uniform", "lsd"}
    )
    if abl:
        lines += [
            "",
            "| set | N | planner | success | C/C* (on trials Unf also solved) |",
            "|---|---|---|---|---|",
        ]
        for v in summary.values():
            for name in ("uniform", "lsd", *abl):
                c = v.get(
                    f"c_{name}_over_cstar_vs_uniform",
                    v["cl_over_cstar"]
                    if name == "lsd"
                    else (v["cb_over_cstar"] if name == "uniform" else (float("nan"), float("nan"))),
                )
                lines.append(
                    f"| {v['set']} | {v['n']} | {name} | {100 * v[f'success_{name}']:.0f} +- "
                    f"{100 * v[f'success_{name}_sem']:.0f} % | {_pm(c)} |"
                )
    pairs = sorted({k[len("paired_") :] for v in summary.values() for k in v if k.startswith("paired_")})
    if pairs:
        lines += [
            "",
            "| set | N | variant (both planners) | success Unf | success LSD | LSD-only / Unf-only | mutual "
            "| C_l/C* | C_b/C* |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for v in summary.values():
            for x in pairs:
                if f"paired_{x}" not in v:
                    continue
                pv = v[f"paired_{x}"]
                lines.append(
                    f"| {v['set']} | {v['n']} | {x} | {100 * v[f'success_uniform_{x}']:.0f} +- "
                    f"{100 * v[f'success_uniform_{x}_sem']:.0f} % | {100 * v[f'success_lsd_{x}']:.0f} +- "
                    f"{100 * v[f'success_lsd_{x}_sem']:.0f} % | {pv['lsd_only']} / {pv['uniform_only']} | "
                    f"{pv['mutual']} | {_pm(pv['cl_over_cstar'])} | {_pm(pv['cb_over_cstar'])} |"
                )
    return "\n".join(lines)


def plot_success(summary: dict, path) -> None:
    """Success rate against N for both planners and each set (figure 3-8), with binomial
    standard errors as error bars, saved as PNG; a variant both planners ran (``paired_X`` in
    the summary, e.g. the thesis' protocol) gets its own pair of dotted lines."""
    import matplotlib  # deferred: matplotlib is slow to import and only the figures need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = sorted({v["set"] for v in summary.values()})
    fig, axes = plt.subplots(1, len(sets), figsize=(4.5 * len(sets), 3.6), squeeze=False)
    for ax, kind in zip(axes[0], sets):
        rows = sorted((v for v in summary.values() if v["set"] == kind), key=lambda v: v["n"])
        ns = [v["n"] for v in rows]
        for who, fmt, color, label in (("lsd", "o-", "tab:red", "PRM + LSD"), ("uniform", "s--", "k", "PRM + Unf")):
            ax.errorbar(
                ns,
                [100 * v[f"success_{who}"] for v in rows],
                yerr=[100 * v.get(f"success_{who}_sem", 0.0) for v in rows],
                fmt=fmt,
                color=color,
                capsize=3,
                label=label,
            )
        # Each variant both planners ran (paired_X): its own pair of lines, hollow markers.
        pairs = sorted({k[len("paired_") :] for v in rows for k in v if k.startswith("paired_")})
        for x, (cl, cu) in zip(pairs, [("tab:orange", "tab:gray"), ("tab:purple", "tab:olive")] * 4):
            for who, fmt, color, label in (("lsd", "o:", cl, "PRM + LSD"), ("uniform", "s:", cu, "PRM + Unf")):
                ax.errorbar(
                    ns,
                    [100 * v.get(f"success_{who}_{x}", float("nan")) for v in rows],
                    yerr=[100 * v.get(f"success_{who}_{x}_sem", 0.0) for v in rows],
                    fmt=fmt,
                    color=color,
                    mfc="none",
                    capsize=3,
                    label=f"{label}, {x}",
                )
        if len(set(ns)) > 1:
            ax.set_xscale("log")
        ax.set_ylim(-5, 105)
        ax.set_xlabel("N (samples per roadmap)")
        ax.set_ylabel("success rate (%)")
        counts = sorted({v["trials"] for v in rows}) or [0]
        per_n = str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
        ax.set_title(f"{kind}: {per_n} trials per N")
        ax.legend(fontsize=7 if pairs else None)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


@dataclasses.dataclass(frozen=True)
class ExperimentSetup:
    """How :func:`prepare_model` makes a CPU-sized model when no checkpoint is given."""

    train_buildings: int = 6
    samples_per_building: int = 80
    workers: int = 2


def prepare_model(
    workdir,
    checkpoint=None,
    setup: ExperimentSetup = ExperimentSetup(),
    config=None,
    progress: bool = True,
    log=print,
):
    """``(model, params, info)``: loads ``checkpoint`` (a training workdir or an exported .npz,
    :func:`jaxsem.lsd.load_model`) or generates expert
    data on train-family buildings into ``workdir/data`` and trains there (resuming if present)."""
    if checkpoint:
        model, params, cfg, _ = load_model(checkpoint)
        return model, params, {"checkpoint": str(checkpoint), "trained_here": False}
    workdir = pathlib.Path(workdir)
    t0 = time.perf_counter()
    shards = write_expert_dataset(
        workdir / "data",
        "train",
        range(setup.train_buildings),
        ExpertConfig(samples_per_building=setup.samples_per_building),
        workers=setup.workers,
        progress=progress,
    )
    t_data = time.perf_counter() - t0
    cfg = config or cpu_config()
    t0 = time.perf_counter()
    res = train_and_evaluate(cfg, workdir, data=shards, progress=progress)
    t_train = time.perf_counter() - t0
    last = res.history[-1] if res.history else {}
    info = {
        "checkpoint": str(workdir),
        "trained_here": True,
        "shards": len(shards),
        "data_seconds": t_data,
        "train_seconds": t_train,
        "val_nll": last.get("val_nll"),
        "uniform_nll": last.get("uniform_nll"),
        "stage1_steps": cfg.stage1_steps,
        "stage2_steps": cfg.stage2_steps,
    }
    log(f"trained LSD in {workdir}: {info}")
    return res.model, res.params, info


def plot_navigation(
    world,
    results: dict,
    path,
    start=None,
    goal=None,
    distribution=None,
    title: str = "",
) -> None:
    """PNG: the true map (walls black, doors green, windows blue, exit signs red), the last
    full-map LSD distribution (log scale, when given), and each planner's trajectory.

    world: a Building-like object; results: ``{name: NavResult}``; distribution: (H, W) or None.
    """
    import matplotlib  # deferred: matplotlib is slow to import and only the figures need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    occ = np.asarray(world.occupancy)
    sem = np.asarray(world.semantic)
    H, W = occ.shape
    ox, oy = np.asarray(world.origin, float)
    ext = [ox, ox + W * world.resolution, oy, oy + H * world.resolution]
    ncols = 2 if distribution is not None else 1
    fig, axes = plt.subplots(1, ncols, figsize=(6.5 * ncols, 6.5 * H / W + 0.8), squeeze=False)
    img = np.ones((H, W, 3))
    img[occ] = 0.0
    for cls, col in ((2, (0.1, 0.7, 0.1)), (3, (0.2, 0.4, 1.0)), (4, (1.0, 0.1, 0.1))):
        img[sem == cls] = col
    colors = {"uniform": "tab:blue", "lsd": "tab:green"}
    panels = [(axes[0, 0], "map and trajectories")]
    if distribution is not None:
        ax = axes[0, 1]
        ax.imshow(
            np.log10(np.maximum(np.asarray(distribution), 1e-30)),
            origin="lower",
            extent=ext,
            cmap="viridis",
        )
        ax.contour(occ, levels=[0.5], colors="w", linewidths=0.3, extent=ext, origin="lower")
        panels.append((ax, "last LSD sampling distribution (log10 p)"))
    axes[0, 0].imshow(img, origin="lower", extent=ext, interpolation="nearest")
    for ax, t in panels:
        for name, res in results.items():
            p = np.asarray(res.path)
            label = f"{name}: {'ok' if res.success else res.reason}, {res.cost:.1f} m"
            ax.plot(p[:, 0], p[:, 1], "-", color=colors.get(name, None), lw=1.5, label=label)
        if start is not None:
            ax.plot(*start, "rx", ms=9, mew=2)
        if goal is not None:
            ax.plot(*goal, "o", mfc="none", mec="r", ms=9, mew=2)
        ax.set_title(t, fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    axes[0, 0].legend(fontsize=8, loc="upper right")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)

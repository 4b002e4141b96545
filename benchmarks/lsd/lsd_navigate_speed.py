"""Benchmark: wall time of one :func:`jaxsem.planning.navigate` task on a real map, LSD and uniform.

The claim: after the first task of a process, a task on the campus (about 28 m from start to
goal) takes at most 2 s with the LSD sampler. Both planners run the same tasks, interleaved
task by task (LSD, then uniform), with the defaults of :class:`jaxsem.planning.NavConfig`; the
uniform planner is the baseline timed in the same run. Each planner's first task is reported
apart: it compiles (from JAX's persistent cache when that folder already holds this code's
programs; the run says whether the cache was on).

Tasks: start and goal in free cells (clearance 0.3 m) whose straight-line distance lies in
``[--min-dist, --max-dist]`` and that the 8-connected grid joins; drawn from ``--seed``.

    python benchmarks/lsd/lsd_navigate_speed.py --map data/mrpt/2006-MalagaCampus.gridmap.gz --tasks 8 --seed 7000
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax
import numpy as np

from jaxsem import lsd, planning

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _harness

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from lsd_prm_campus import MAP, sample_queries


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", default=MAP, help="an occupancy map jaxsem.planning.load_map reads")
    ap.add_argument("--model", default="campus", help="the LSD model (a shipped name, workdir or .npz)")
    ap.add_argument("--tasks", type=int, default=8)
    ap.add_argument("--seed", type=int, default=7000, help="task and roadmap seed")
    ap.add_argument("--min-dist", type=float, default=26.0)
    ap.add_argument("--max-dist", type=float, default=30.0)
    _harness.output_arguments(ap, "lsd_navigate_speed")
    args = ap.parse_args(argv)
    if args.tasks < 2:
        ap.error("--tasks: at least 2 (the first task of each planner is reported apart)")
    if not 0 < args.min_dist <= args.max_dist:
        ap.error("--min-dist, --max-dist: expected 0 < min <= max")
    if not pathlib.Path(args.map).is_file():
        ap.error(f"--map: no such file {args.map} (jaxsem data fetch maps --out data)")
    world = planning.load_map(args.map)
    loaded = lsd.load_model(args.model)
    sampler = lsd.LSDSampler(loaded.model, loaded.variables, cell_size=loaded.meta["cell_size"])
    tasks = sample_queries(world, args.tasks, args.seed, min_dist=args.min_dist, max_dist=args.max_dist)
    planners = {"lsd": sampler, "uniform": None}
    rows: dict[str, list] = {p: [] for p in planners}
    for ti, (s, g, cstar) in enumerate(tasks):
        for name, smp in planners.items():
            t0 = time.perf_counter()
            r = planning.navigate(world, s, g, jax.random.PRNGKey(args.seed + ti), sampler=smp)
            dt = time.perf_counter() - t0
            rows[name].append(
                {"task": ti, "seconds": dt, "success": bool(r.success), "steps": int(r.steps), "plans": int(r.plans)}
            )
            print(f"task {ti} ({np.linalg.norm(g - s):.1f} m) {name}: {dt:.2f} s, success {r.success}, {r.plans} plans")
    summary = {}
    for name, rs in rows.items():
        later = [r["seconds"] for r in rs[1:]]
        summary[name] = {
            "first_task_s": rs[0]["seconds"],
            "later_median_s": float(np.median(later)),
            "later_max_s": float(np.max(later)),
            "success": float(np.mean([r["success"] for r in rs])),
        }
    cache = jax.config.jax_compilation_cache_dir
    command = "python benchmarks/lsd/lsd_navigate_speed.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date, mach = _harness.utc_now(), _harness.machine()
    md = _harness.header("# navigate: wall time per task", command, date, mach)
    md += [
        f"Map `{args.map}`, {args.tasks} tasks of {args.min_dist:g}-{args.max_dist:g} m, LSD model `{args.model}`, "
        f"compilation cache {'on' if cache else 'off'}.",
        "",
        "| planner | first task (s) | later tasks, median (s) | later, max (s) | success |",
        "|---|---|---|---|---|",
    ]
    for name, sm in summary.items():
        md.append(
            f"| {name} | {sm['first_task_s']:.1f} | {sm['later_median_s']:.2f} | {sm['later_max_s']:.2f} | "
            f"{sm['success']:.2f} |"
        )
    record = {
        "command": command,
        "date": date,
        "machine": mach,
        "compilation_cache": bool(cache),
        "summary": summary,
        "tasks": rows,
    }
    out = _harness.write_results(args.out, args.name, record, md)
    print("\n".join(md))
    print(f"wrote {out / args.name}.json / .md")
    return 0


if __name__ == "__main__":
    sys.exit(main())

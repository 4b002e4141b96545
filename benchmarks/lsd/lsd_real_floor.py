"""Benchmark: how much room an ``lsd_real`` table leaves: each task's shortest possible length.

A planner's C/C* (metres travelled over the length of the soft-cost optimal path) cannot fall
below the task's geodesic, the shortest path any robot could drive between start and goal on the
true map. This script reads ``lsd_real.py`` outputs (the JSON and the records beside it), loads
each map again from the JSON's own command, and measures every task's geodesic on the
16-connected grid (``SoftCostGraph(weight=0, connectivity=16)``: within 2.7 % of the any-angle
shortest path in open space, so ``floor / 1.0275`` is a near-certain lower bound). Per row
(``<set>-<N>``), over the tasks both planners solved:

- ``floor_over_cstar``: mean geodesic / C*;
- ``cb_over_cstar``, ``cl_over_cstar``: the planners' mean C/C* (as in the table);
- ``cb_over_floor``, ``cl_over_floor``: how far each planner drove beyond the geodesic;
- ``room_below_uniform``: ``1 - floor / C_b`` in means, the most any planner could be below
  uniform's mean C/C*; ``room_below_uniform_bound`` the same with ``floor / 1.0275``.

A target "C_l/C* at least 10 % below C_b/C*" cannot be met on a row whose room is under 10 %
(``room_below_uniform_bound`` under 0.10 rules it out for any planner, even one that knew the map).

    python benchmarks/lsd/lsd_real_floor.py --json benchmarks/results/lsd_real_campus_defaults_io_map_s1002.json \\
        --out benchmarks/results/lsd_real_floor_campus.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import sys
import time

DISCRETISATION = 1.0275  # 1 / cos(atan(1/2) / 2): the 16-connected grid's worst straight-line excess


def _parse(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", required=True, nargs="+", help="lsd_real.py outputs (their records lie beside them)")
    p.add_argument("--out", required=True, help="output JSON (a Markdown table is printed)")
    p.add_argument("--figure", default=None, help="per-task C/floor of both planners (default: <out stem>.png)")
    p.add_argument("--data", default=None, help="replace the folder of the maps named in the JSON (moved data)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p.parse_args(argv)


def read_runs(paths, prog: str = "lsd_real_floor", need_command: bool = True, flag: str = "--json") -> list:
    """``[(json path, run dict, records path)]`` of ``lsd_real.py`` outputs named by ``--json``;
    ``SystemExit`` naming the flag and file for a missing, foreign or record-less one (``prog``
    prefixes the message; also used by ``lsd_real_uturns.py``)."""
    runs = []
    for path in paths:
        f = pathlib.Path(path)
        if not f.is_file():
            raise SystemExit(f"{prog}: {flag}: no such file {path!r}")
        try:
            run = json.loads(f.read_text())
        except json.JSONDecodeError as exc:
            raise SystemExit(f"{prog}: {flag}: {path!r} is not JSON ({exc.msg})") from None
        if run.get("benchmark") != "lsd_real" or (need_command and "command" not in run):
            raise SystemExit(f"{prog}: {flag}: {path!r} is not an lsd_real.py output")
        records = pathlib.Path(run.get("records", ""))
        if not records.is_file():
            records = f.with_name(f.stem + ".records.jsonl")
        if not records.is_file():
            raise SystemExit(f"{prog}: {flag}: no records beside {path!r}")
        runs.append((f, run, records))
    return runs


def _check(args) -> list:
    runs = read_runs(args.json)
    if args.data is not None and not pathlib.Path(args.data).is_dir():
        raise SystemExit(f"lsd_real_floor: --data: no such folder {args.data!r}")
    out = pathlib.Path(args.out)
    if out.exists() and out.is_dir():
        raise SystemExit(f"lsd_real_floor: --out: {args.out!r} is a folder")
    return runs


def load_run_maps(run: dict, data: str | None, prog: str = "lsd_real_floor") -> list:
    """The run's buildings, loaded as its command loaded them (index = the records' building);
    ``data``: the folder the maps lie in now (None: the paths of the run's command). Also used
    by ``lsd_real_replay.py``."""
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    import lsd_real

    a = lsd_real.run_args(run["command"])
    paths = [str(pathlib.Path(data) / pathlib.Path(m).name) if data else m for m in a.map]
    for m in paths:
        if not pathlib.Path(m).is_file():
            raise SystemExit(f"{prog}: the run's map {m!r} is missing (fetch it, or name its folder with --data)")
    return [lsd_real.load_run_map(a, m) for m in paths]


def _floors(buildings: list, records: list) -> list:
    import numpy as np

    from jaxsem.planning import SoftCostGraph

    graphs = {}
    out = []
    for r in records:
        i = 0 if r["building"] < 0 else int(r["building"])
        b = buildings[i]
        if i not in graphs:
            graphs[i] = SoftCostGraph(b.occupancy, b, weight=0.0, connectivity=16)
        tree = graphs[i].search(np.asarray(r["start"]), limit=4.0 * float(r["c_star"]) + 5.0)
        out.append(tree.path_to(np.asarray(r["goal"])).length)
    return out


def _rows(records: list, floors: list) -> dict:
    import numpy as np

    rows = {}
    for key in sorted({(r["set"], r["n"]) for r in records}):
        idx = [i for i, r in enumerate(records) if (r["set"], r["n"]) == key]
        mutual = [i for i in idx if records[i]["uniform"]["success"] and records[i]["lsd"]["success"]]
        if not mutual:
            continue
        tasks = {"uniform": [], "lsd": []}
        for i in mutual:
            for k in tasks:
                tasks[k].append(float(records[i][k]["cost"] / floors[i]))
        cs = np.array([records[i]["c_star"] for i in mutual])
        fl = np.array([floors[i] for i in mutual])
        cb = np.array([records[i]["uniform"]["cost"] for i in mutual])
        cl = np.array([records[i]["lsd"]["cost"] for i in mutual])
        f, b, l = (fl / cs).mean(), (cb / cs).mean(), (cl / cs).mean()
        rows[f"{key[0]}-{key[1]}"] = {
            "set": key[0],
            "n": key[1],
            "trials": len(idx),
            "mutual": len(mutual),
            "floor_over_cstar": float(f),
            "cb_over_cstar": float(b),
            "cl_over_cstar": float(l),
            "cb_over_floor": float((cb / fl).mean()),
            "cl_over_floor": float((cl / fl).mean()),
            "lsd_below_uniform": float(1.0 - l / b),
            "room_below_uniform": float(1.0 - f / b),
            "room_below_uniform_bound": float(1.0 - f / DISCRETISATION / b),
            "per_task_over_floor": tasks,
            "tasks_within_2pct_of_floor": {
                "uniform": int(np.sum(cb <= 1.02 * fl)),
                "lsd": int(np.sum(cl <= 1.02 * fl)),
            },
        }
    return rows


def _figure(runs: dict, path: pathlib.Path) -> None:
    """One panel per row: each task's C/floor, uniform against LSD, with the lines where LSD
    equals uniform and where it is 10 % below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    from jaxsem.scripting import atomic_savefig

    panels = [(f"{run}\n{name}", row) for run, v in runs.items() for name, row in v["rows"].items()]
    if not panels:
        return
    cols = min(4, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.2 * rows), squeeze=False)
    for ax in axes.flat[len(panels) :]:
        ax.set_axis_off()
    for ax, (title, row) in zip(axes.flat, panels):
        u, l = row["per_task_over_floor"]["uniform"], row["per_task_over_floor"]["lsd"]
        hi = max(1.5, max(u + l) * 1.05)  # every task shown: the detours decide the means
        ax.plot([1, hi], [1, hi], "k-", lw=0.8, label="LSD = uniform")
        ax.plot([1, hi], [0.9, 0.9 * hi], "k--", lw=0.8, label="LSD 10 % below")
        ax.axhline(1.0, color="grey", lw=0.6)
        ax.scatter(u, l, s=14, c="tab:red", label=f"{row['mutual']} tasks")
        ax.set_xlim(0.95, hi)
        ax.set_ylim(0.85, hi)
        if hi > 3.0:
            ax.set_xscale("log")
            ax.set_yscale("log")
            ticks = [t for t in (1, 1.5, 2, 3, 4, 6, 8, 12) if t <= hi]
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_ticks(ticks)
                axis.set_major_formatter(ticker.ScalarFormatter())
                axis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("uniform: driven / shortest possible")
        ax.set_ylabel("LSD: driven / shortest possible")
        ax.set_title(title, fontsize=8)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    args = _parse(argv)
    runs = _check(args)
    try:
        return _run(args, runs, sys.argv[1:] if argv is None else argv)
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"lsd_real_floor: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2


def _run(args, runs, argv) -> int:
    from jaxsem.lsd import read_records
    from jaxsem.scripting import atomic_write_text

    t0 = time.perf_counter()
    result = {
        "benchmark": "lsd_real_floor",
        "command": "python benchmarks/lsd/lsd_real_floor.py " + " ".join(argv),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "discretisation": DISCRETISATION,
        "runs": {},
    }
    lines = [
        "| run | row | mutual / trials | floor/C* | C_b/C* | C_l/C* | C_b/floor | C_l/floor | LSD below uniform | "
        "room below uniform (floor / bound) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f, run, records_path in runs:
        records = read_records(records_path)
        records = [r for r in records if "uniform" in r and "lsd" in r]
        floors = _floors(load_run_maps(run, args.data), records)
        rows = _rows(records, floors)
        result["runs"][f.stem] = {"command": run["command"], "rows": rows}
        for name, v in rows.items():
            lines.append(
                f"| {f.stem} | {name} | {v['mutual']} / {v['trials']} | {v['floor_over_cstar']:.3f} | "
                f"{v['cb_over_cstar']:.3f} | {v['cl_over_cstar']:.3f} | {v['cb_over_floor']:.3f} | "
                f"{v['cl_over_floor']:.3f} | {v['lsd_below_uniform']:+.1%} | "
                f"{v['room_below_uniform']:.1%} / {v['room_below_uniform_bound']:.1%} |"
            )
        print(f"{f.stem}: {len(records)} tasks ({time.perf_counter() - t0:.0f} s)", flush=True)
    result["table"] = "\n".join(lines)
    figure = pathlib.Path(args.figure) if args.figure else pathlib.Path(args.out).with_suffix(".png")
    _figure(result["runs"], figure)
    result["figure"] = str(figure)
    result["seconds"] = time.perf_counter() - t0
    print(result["table"])
    atomic_write_text(pathlib.Path(args.out), json.dumps(result, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: why one trial of an ``lsd_real`` run drove where it drove: the trial replayed, with
the plan it held after each replan and why it replanned.

Reloads the run's map and redraws its tasks from the run's own command (``--data`` names the
folder the maps lie in now), rebuilds the planner of ``--planner`` (``uniform``, ``lsd`` or one of
the run's variant rows) with the run's protocol, N and step limit, and replays task ``--trial``
of ``--set`` step by step with the trial's own key (``jaxsem.lsd.trial_key``). The replay is the
recorded trial when it runs on the same kind of machine: its cost is checked against the record
and a mismatch is reported in the title and the JSON (``replayed_as_recorded``).

Writes ``--out`` (a figure: one panel per replan, the first ``--panels`` of them or those
evenly spread over the trial with ``--spread``; the true map light, what the robot knew dark,
the path driven so far blue and the plan red, the reason in the title) and ``<out stem>.json``
(every replan: step, position, reason, plan length):

    python benchmarks/lsd/lsd_real_replay.py --json benchmarks/results/lsd_real_campus_defaults_campus_blocked_tune_s3.json \\
        --set II --trial 5 --planner lsd --out benchmarks/results/lsd_real_replay_campus_s3_t5.png
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time


def _parse(argv):
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    p.add_argument("--json", required=True, help="an lsd_real.py output (its records lie beside it)")
    p.add_argument("--set", default="II", choices=["II", "IO"])
    p.add_argument("--trial", type=int, required=True, help="task index within the set")
    p.add_argument("--n", type=int, default=None, help="sample budget (default: the run's only one)")
    p.add_argument("--planner", default="lsd", help="uniform, lsd or a variant row of the run")
    p.add_argument("--data", default=None, help="folder the run's maps lie in now")
    p.add_argument("--panels", type=int, default=12, help="replans drawn")
    p.add_argument("--spread", action="store_true", help="draw replans spread over the trial, not the first")
    p.add_argument("--window", type=float, default=50.0, help="metres shown around the robot")
    p.add_argument("--out", required=True, help="figure (.png); the replans go to <stem>.json")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p.parse_args(argv)


def _check(args):
    """Everything that can be checked before the map loads: the run, its record, the flags."""
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    from lsd_real_floor import read_runs

    from jaxsem.lsd import read_records

    _, run, records = read_runs([args.json], "lsd_real_replay")[0]
    if args.panels < 1 or not args.window > 0:
        raise SystemExit("lsd_real_replay: --panels: expected >= 1 (and --window > 0)")
    out = pathlib.Path(args.out)
    if out.suffix.lower() != ".png" or (out.exists() and out.is_dir()):
        raise SystemExit(f"lsd_real_replay: --out: expected a .png file, got {args.out!r}")
    rows = read_records(records)
    ns = sorted({r["n"] for r in rows if r["set"] == args.set})
    if args.n is None and len(ns) > 1:
        raise SystemExit(f"lsd_real_replay: --n: the run has several budgets {ns}; name one")
    n = args.n if args.n is not None else (ns[0] if ns else None)
    match = [r for r in rows if r["set"] == args.set and r["trial"] == args.trial and r["n"] == n]
    if not match:
        raise SystemExit(f"lsd_real_replay: --trial: no {args.set} trial {args.trial} at N = {n} in {records}")
    rec = match[0]
    if args.planner not in rec or not isinstance(rec[args.planner], dict):
        names = [k for k, v in rec.items() if isinstance(v, dict) and "cost" in v]
        raise SystemExit(f"lsd_real_replay: --planner: {args.planner!r} is not a row of the run (rows: {names})")
    return run, rec


def replay(trial, window: float) -> list:
    """Runs ``trial`` (a ``jaxsem.planning.Trial``) to its end; returns one event per replan:
    step, position, reason, plan, the length of the path driven so far, and what the robot knew
    to be occupied then within ``window`` metres around it (a bool crop and its world extent)."""
    import numpy as np

    from jaxsem.planning import OCCUPIED

    o, res = np.asarray(trial.origin, np.float64), float(trial.resolution)
    half = int(np.ceil(window / 2 / res))
    events = []
    while not trial.done:
        searches, blocked, periodic = trial.searches, trial.blocked_replans, trial.periodic_replans
        trial.step()
        if trial.searches == searches:
            continue
        if trial.blocked_replans > blocked:
            why = "blocked"  # the rest of the plan crossed a known obstacle
        elif trial.periodic_replans > periodic:
            why = "timer"  # replan_every steps on a clear plan
        else:
            why = "first plan" if not events else "turn blocked"  # the first leg, seen after turning
        known = np.asarray(trial.state.occupancy)
        c, r = np.floor((trial.xy - o) / res).astype(int)
        r0, r1 = max(r - half, 0), min(r + half, known.shape[0])
        c0, c1 = max(c - half, 0), min(c + half, known.shape[1])
        events.append(
            {
                "step": trial.steps,
                "xy": trial.xy.tolist(),
                "reason": why,
                "plan": None if trial.plan is None else np.asarray(trial.plan, np.float64).copy(),
                "driven": len(trial.path),
                "known": known[r0:r1, c0:c1] == OCCUPIED,
                "known_extent": (o[0] + c0 * res, o[0] + c1 * res, o[1] + r0 * res, o[1] + r1 * res),
            }
        )
    return events


def _figure(b, trial, events, chosen, title, window, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from jaxsem.scripting import atomic_savefig

    occ = np.asarray(b.occupancy)
    o, res = np.asarray(b.origin, np.float64), float(b.resolution)
    ext = (o[0], o[0] + occ.shape[1] * res, o[1], o[1] + occ.shape[0] * res)
    path_xy = np.asarray(trial.path)
    cols = min(4, len(chosen))
    rows = (len(chosen) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.8 * rows + 0.6), squeeze=False)
    for ax in axes.ravel()[len(chosen) :]:
        ax.axis("off")
    for ax, i in zip(axes.ravel(), chosen):
        e = events[i]
        ax.imshow(occ, origin="lower", cmap="Greys", vmin=0, vmax=4, extent=ext, interpolation="nearest")
        known = np.ma.masked_where(~e["known"], np.ones(e["known"].shape))
        ax.imshow(
            known, origin="lower", cmap="Greys", vmin=0, vmax=1, extent=e["known_extent"], interpolation="nearest"
        )
        ax.plot(path_xy[: e["driven"], 0], path_xy[: e["driven"], 1], "b-", lw=1)
        if e["plan"] is not None:
            ax.plot(e["plan"][:, 0], e["plan"][:, 1], "r.-", lw=1, ms=2)
        ax.plot(*trial.goal, "k*", ms=9)
        x, y = e["xy"]
        ax.set_xlim(x - window / 2, x + window / 2)
        ax.set_ylim(y - window / 2, y + window / 2)
        ax.set_title(f"replan {i + 1}, step {e['step']}: {e['reason']}", fontsize=8)
        ax.tick_params(labelsize=6)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    args = _parse(argv)
    run, rec = _check(args)
    try:
        return _run(args, run, rec, sys.argv[1:] if argv is None else argv)
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"lsd_real_replay: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2


def _run(args, run, rec, argv) -> int:
    import dataclasses

    import lsd_real
    import numpy as np
    from lsd_real_floor import load_run_maps

    from jaxsem.cli import enable_compilation_cache
    from jaxsem.lsd._experiment import trial_key  # layers: white-box
    from jaxsem.planning import SoftCostGraph, Trial
    from jaxsem.scripting import atomic_write_text

    enable_compilation_cache()
    t0 = time.perf_counter()
    a = lsd_real.run_args(run["command"])
    i = 0 if rec["building"] < 0 else int(rec["building"])
    b = load_run_maps(run, args.data, "lsd_real_replay")[i]
    tasks = lsd_real.run_tasks(a, b, args.set, SoftCostGraph(b.occupancy, b))
    task = tasks[args.trial]
    if not (np.allclose(task.start, rec["start"], atol=1e-4) and np.allclose(task.goal, rec["goal"], atol=1e-4)):
        raise ValueError(f"--json: task {args.trial} redrawn at {task.start.tolist()} -> {task.goal.tolist()}, "
                         f"recorded {rec['start']} -> {rec['goal']}: the map or the code that draws tasks changed")  # fmt: skip
    sampler, base, variants = lsd_real.run_planners(a, b)
    planners = {"uniform": (None, {}), "lsd": (sampler, {}), **(variants or {})}
    if args.planner not in planners:
        raise SystemExit(f"lsd_real_replay: --planner: {args.planner!r} cannot be rebuilt from the run's flags")
    smp, changes = planners[args.planner]
    cfg = dataclasses.replace(base, n_samples=rec["n"], max_steps=a.max_steps, **changes)
    key = trial_key(a.seed, b.seed, args.set, args.trial, rec["n"])
    trial = Trial(b, task.start, task.goal, key, cfg, smp, task.yaw0, task.goal_outdoors)
    events = replay(trial, args.window)
    res = trial.result()
    recorded = rec[args.planner]
    same = bool(np.isclose(res.cost, recorded["cost"], rtol=1e-6) and res.success == recorded["success"])
    if args.spread:  # panels evenly spread over the trial's replans
        chosen = sorted(set(np.linspace(0, len(events) - 1, min(args.panels, len(events))).round().astype(int)))
    else:
        chosen = list(range(min(args.panels, len(events))))
    cstar = float(rec["c_star"])
    title = (
        f"{pathlib.Path(args.json).stem}: {args.set} task {args.trial}, {args.planner}, C/C* {res.cost / cstar:.2f}, "
        f"replans blocked {res.blocked_replans} / timer {res.periodic_replans}"
        + ("" if same else f" (REPLAY DIFFERS: recorded C/C* {recorded['cost'] / cstar:.2f})")
    )
    out = pathlib.Path(args.out)
    _figure(b, trial, events, chosen, title, args.window, out)
    result = {
        "command": "python benchmarks/lsd/lsd_real_replay.py " + " ".join(argv),
        "run": str(args.json),
        "set": args.set,
        "trial": args.trial,
        "planner": args.planner,
        "replayed_as_recorded": same,
        "cost_over_cstar": res.cost / cstar,
        "recorded_cost_over_cstar": recorded["cost"] / cstar,
        "success": bool(res.success),
        "reason": res.reason,
        "steps": int(res.steps),
        "replans_blocked": int(res.blocked_replans),
        "replans_periodic": int(res.periodic_replans),
        "replans": [
            {
                "step": e["step"],
                "xy": [round(v, 3) for v in e["xy"]],
                "reason": e["reason"],
                "plan_length": None if e["plan"] is None else float(np.hypot(*np.diff(e["plan"], axis=0).T).sum()),
            }
            for e in events
        ],
        "figure": str(out),
        "seconds": time.perf_counter() - t0,
    }
    atomic_write_text(out.with_suffix(".json"), json.dumps(result, indent=1))
    print(title)
    print(f"wrote {out} and {out.with_suffix('.json')} ({result['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

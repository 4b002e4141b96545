"""How much of the expert's path lies outside the LSD window, on train-family buildings.

The thesis' planner gives every cell outside the robot-centred 160 x 160 window (16 m) the
window's minimum (section 3.2.5), so the mass outside is whatever that minimum adds up to
(3-12 % on the test buildings, ``benchmarks/lsd/lsd_diagnose_finding.md``). This script estimates
the mass the expert itself puts there: the expected share of the cells of a soft-cost optimal
path (the expert's training target) that fall outside the window centred on the robot, split by
goal indoors / outdoors. Robot positions and goals follow the expert data generator
(``jaxsem.lsd.ExpertConfig``: the robot starts at a clear indoor cell, goals are clear
cells at least 3 m away, 40 % outdoors) without its uniform-PRM navigation: the robot is placed
at points along optimal paths from its start (every ``--every`` metres), which is where an
expert robot walks. Only train-family buildings are used (never the test seeds).

With ``--model-tasks K`` it also measures what the thesis' rule gives there with the shipped
model: on K Inside-Inside and K Inside-Outside tasks per building (``sample_tasks``), the mass the
full-map distribution (window + the window's minimum outside) puts on cells outside the window
that are not known to be occupied (the cells the PRM samples from), at the start and after
``--model-steps`` steps of the uniform planner's navigation.

    python benchmarks/lsd/lsd_outside_share.py --buildings 20 --first 0 --out benchmarks/results
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import time

import numpy as np

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
WINDOW = 160  # cells, jaxsem.planning CROP_SIZE


def _write(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def shares_for_building(b, rng, tasks: int, goals: int, every: float, outdoor_prob: float, min_goal: float):
    """List of (goal_outdoors, share outside, path cells, distance to goal m) samples."""
    import scipy.ndimage

    from jaxsem.planning import SoftCostGraph

    graph = SoftCostGraph(b.occupancy, b)
    d = np.asarray(scipy.ndimage.distance_transform_edt(~b.occupancy)) * b.resolution
    ok = d >= 0.3
    inside, outside = np.argwhere(ok & b.indoor), np.argwhere(ok & ~b.indoor)

    def world(rc):
        return b.origin + (np.asarray(rc)[..., ::-1] + 0.5) * b.resolution

    out = []
    step_cells = max(1, int(round(every / b.resolution)))
    for _ in range(tasks):
        start = world(inside[rng.integers(len(inside))])
        pool = outside if rng.random() < outdoor_prob else inside
        walk = graph.path(start, world(pool[rng.integers(len(pool))]))
        if not walk.found:
            continue
        for rc in walk.cells[::step_cells]:
            xy = world(rc)
            tree = graph.search(xy)
            for _g in range(goals):
                outdoor = bool(rng.random() < outdoor_prob)
                pool = outside if outdoor else inside
                g = world(pool[rng.integers(len(pool))])
                for _try in range(19):
                    if np.linalg.norm(g - xy) >= min_goal:
                        break
                    g = world(pool[rng.integers(len(pool))])
                p = tree.path_to(g)
                if not p.found or len(p.cells) == 0:
                    continue
                local = p.cells - np.asarray(rc)[None] + WINDOW // 2
                inside_w = np.all((local >= 0) & (local < WINDOW), axis=1)
                out.append((outdoor, 1.0 - float(inside_w.mean()), len(p.cells), float(np.linalg.norm(g - xy))))
    return out


def thesis_outside_mass(b, sampler, tasks: int, seed: int, steps: int):
    """List of (goal_outdoors, step, mass outside the window on cells not known occupied)."""
    import jax

    from jaxsem.planning import OCCUPIED, NavConfig, Trial, embed_local_distribution, sample_tasks

    out = []
    for kind in ("II", "IO"):
        for t_i, task in enumerate(sample_tasks(b, kind, tasks, seed)):
            trial = Trial(
                b,
                task.start,
                task.goal,
                jax.random.PRNGKey(seed + t_i),
                NavConfig(max_steps=steps + 1),
                None,
                task.yaw0,
            )
            for target in (0, steps):
                while trial.steps < target and trial.step():
                    pass
                if trial.done:
                    break
                inputs = trial.local_inputs()
                full = np.asarray(
                    embed_local_distribution(sampler(inputs), inputs.center_cell, trial.state.occupancy.shape),
                    np.float64,
                )
                usable = np.asarray(trial.state.occupancy) != OCCUPIED
                r, c = (int(v) for v in np.asarray(inputs.center_cell))
                window = np.zeros(full.shape, bool)
                window[max(r - WINDOW // 2, 0) : r + WINDOW // 2, max(c - WINDOW // 2, 0) : c + WINDOW // 2] = True
                w = full * usable
                out.append((kind == "IO", int(trial.steps), float(w[~window].sum() / w.sum())))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    p.add_argument("--buildings", type=int, default=20, help="train-family buildings")
    p.add_argument("--first", type=int, default=0, help="first train-family seed")
    p.add_argument("--tasks", type=int, default=2, help="walks per building")
    p.add_argument("--goals", type=int, default=8, help="goals per robot position (one search serves them)")
    p.add_argument("--every", type=float, default=4.0, help="metres between robot positions on a walk")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--model-tasks", type=int, default=0, help="II and IO tasks per building for the thesis-rule mass (0: skip)"
    )
    p.add_argument("--model-steps", type=int, default=60, help="uniform-planner steps before the second measurement")
    p.add_argument(
        "--model-buildings", type=int, default=None, help="buildings for the thesis-rule mass (default: --buildings)"
    )
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--name", default="lsd_outside_share")
    args = p.parse_args(argv)
    if args.model_tasks < 0 or args.model_steps < 1:
        raise SystemExit("--model-tasks: expected >= 0 (and --model-steps >= 1)")
    for name in ("buildings", "tasks", "goals"):
        if getattr(args, name) < 1:
            raise SystemExit(f"--{name}: expected >= 1, got {getattr(args, name)}")
    if not args.every > 0:
        raise SystemExit(f"--every: expected > 0, got {args.every}")
    from jaxsem.lsd import ExpertConfig
    from jaxsem.planning import generate_building

    ecfg = ExpertConfig()
    t0 = time.perf_counter()
    rows = []
    for s in range(args.first, args.first + args.buildings):
        rng = np.random.default_rng([args.seed, s, 0x5A])
        b = generate_building(s, "train")
        rows += shares_for_building(
            b, rng, args.tasks, args.goals, args.every, ecfg.outdoor_goal_prob, ecfg.min_goal_distance
        )
    rows_a = np.array([(o, sh, n, dist) for o, sh, n, dist in rows], np.float64)
    summary = {}
    for name, sel in (
        ("all", np.ones(len(rows_a), bool)),
        ("goal_indoors", rows_a[:, 0] == 0),
        ("goal_outdoors", rows_a[:, 0] == 1),
    ):
        x = rows_a[sel, 1]
        cells = rows_a[sel, 2]
        summary[name] = {
            "samples": int(sel.sum()),
            "share_outside_mean": float(x.mean()),
            "share_outside_sem": float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else 0.0,
            "share_outside_median": float(np.median(x)),
            "share_outside_cell_weighted": float(np.sum(x * cells) / np.sum(cells)),
            "fraction_with_any_outside": float(np.mean(x > 0)),
        }
    model_rows = []
    if args.model_tasks > 0:
        from jaxsem.lsd import LSDSampler, load_model

        model, params, _, _ = load_model()
        sampler = LSDSampler(model, params)
        nb = args.buildings if args.model_buildings is None else args.model_buildings
        for s_ in range(args.first, args.first + nb):
            model_rows += thesis_outside_mass(
                generate_building(s_, "train"), sampler, args.model_tasks, args.seed, args.model_steps
            )
        m = np.array(model_rows, np.float64)
        for name, sel in (("goal_indoors (II)", m[:, 0] == 0), ("goal_outdoors (IO)", m[:, 0] == 1)):
            for when, ws in (("start", m[:, 1] == 0), (f"after {args.model_steps} steps", m[:, 1] > 0)):
                x = m[sel & ws, 2]
                if len(x):
                    summary[f"thesis_rule {name} {when}"] = {
                        "samples": int(len(x)),
                        "mass_outside_mean": float(x.mean()),
                        "mass_outside_min": float(x.min()),
                        "mass_outside_max": float(x.max()),
                    }
    total = time.perf_counter() - t0
    cmd = "python benchmarks/lsd/lsd_outside_share.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True, check=False).stdout.strip()
    load = open("/proc/loadavg").read().split()[:3] if pathlib.Path("/proc/loadavg").exists() else []
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _write(
        out / f"{args.name}.json",
        json.dumps({"command": cmd, "date": date, "load": load, "seconds": total, "summary": summary}, indent=1),
    )
    lines = [
        "## LSD: share of the expert's path outside the 16 m window (train-family buildings)",
        "",
        f"Command: `{cmd}`",
        "",
        f"Date: {date}; machine: 2-core CPU, shared, noisy; load average {' '.join(load)}; {total:.0f} s.",
        "",
        f"Train-family buildings {args.first}..{args.first + args.buildings - 1}; robot positions every "
        f"{args.every} m along optimal walks from clear indoor starts; {args.goals} goals per position "
        "(expert data rules: >= 3 m away, 40 % outdoors); share = path cells outside the 160 x 160 "
        "window centred on the robot / path cells.",
        "",
        "| goals | samples | share outside: mean +- s.e.m. | median | cell-weighted | any outside |",
        "|---|---|---|---|---|---|",
    ]
    for name, v in summary.items():
        if name.startswith("thesis_rule"):
            continue
        lines.append(
            f"| {name} | {v['samples']} | {v['share_outside_mean']:.3f} +- {v['share_outside_sem']:.3f} | "
            f"{v['share_outside_median']:.3f} | {v['share_outside_cell_weighted']:.3f} | "
            f"{100 * v['fraction_with_any_outside']:.0f} % |"
        )
    if model_rows:
        lines += [
            "",
            "The thesis' rule with the shipped model (window + the window's minimum outside): mass on "
            "cells outside the window not known occupied, at the start of a task and after "
            f"{args.model_steps} steps of the uniform planner (train-family buildings {args.first}.."
            f"{args.first + (args.buildings if args.model_buildings is None else args.model_buildings) - 1}, "
            f"{args.model_tasks} tasks per set):",
            "",
            "| tasks, when | samples | mass outside: mean | min | max |",
            "|---|---|---|---|---|",
        ]
        for name, v in summary.items():
            if name.startswith("thesis_rule"):
                lines.append(
                    f"| {name[len('thesis_rule ') :]} | {v['samples']} | {v['mass_outside_mean']:.3f} | "
                    f"{v['mass_outside_min']:.3f} | {v['mass_outside_max']:.3f} |"
                )
    _write(out / f"{args.name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

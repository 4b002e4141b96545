"""Online navigation with the LSD sampler and/or the uniform PRM on one map; saves figures.

The map is a generated building (--family, --building) or an npz file (--map) with keys
``occupancy`` (H, W) bool, ``semantic`` (H, W) int8, ``origin`` (2,), ``resolution`` () and
optionally ``indoor`` (H, W) bool (default: all indoor). Start and goal are world (x, y) in
metres; when omitted a task of --kind (II / IO) is drawn on the building. The model is the
shipped one unless --checkpoint names another.

Outputs: --out (the map, both trajectories and the last full-map LSD distribution) and, for the
LSD trial, ``<out stem>_over_time.png``: a strip of the window distributions at evenly spaced
replans along the path (the distribution over time). The run directory (``--run-dir``) gets
config.json and summary.json (per planner: success, reason, metres travelled, steps, roadmaps;
the figures' paths).

    python infer/plan.py --building 3 --family test --kind IO --out plan.png
    python infer/plan.py --map my_map.npz --start 2 3 --goal 30 12 --sampler uniform

The same command: ``jaxsem lsd plan`` (``python infer/plan.py``).
"""

from __future__ import annotations

import argparse
import pathlib
import types
from typing import Any

from jaxsem import scripting as sc
from jaxsem.planning import NavConfig

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.

# The planner's settings: NavConfig's defaults with a shorter step limit (the thesis uses 10000),
# and convenience flags for two of its fields (--n, --max-steps).
NAV_BASE = NavConfig(max_steps=2000)
CONFIG_FLAGS = (
    sc.ConfigFlag("n_samples", "--n", help="PRM samples per roadmap"),
    sc.ConfigFlag("max_steps", help="step limit of a trial (thesis: 10000)"),
)


def _load_map(path):
    import numpy as np

    from jaxsem import quadrics as Q
    from jaxsem._files import MAX_CELLS, npz_shapes

    if not pathlib.Path(path).exists():
        raise SystemExit(f"--map: no such file {path!r}")
    try:  # the declared sizes first: nothing is inflated beyond the map budget
        shapes = npz_shapes(path)
    except ValueError as exc:
        raise SystemExit(f"--map: {exc}") from None
    occ_shape = shapes.get("occupancy", ())
    if len(occ_shape) != 2 or int(np.prod(occ_shape)) > MAX_CELLS:
        raise SystemExit(
            f"--map: {path} declares occupancy of shape {occ_shape}; expected an (H, W) grid of at most "
            f"{MAX_CELLS:,} cells"
        )
    for k in ("semantic", "indoor"):
        if k in shapes and shapes[k] != occ_shape:
            raise SystemExit(f"--map: {path} declares {k} of shape {shapes[k]}, occupancy of shape {occ_shape}")
    try:
        z = np.load(path)
    except Exception as exc:
        raise SystemExit(f"--map: {path} is not a readable npz file ({type(exc).__name__})") from None
    with z:
        for k in ("occupancy", "semantic", "origin", "resolution"):
            if k not in z:
                raise SystemExit(f"--map: {path} lacks key {k!r} (needs occupancy, semantic, origin, resolution)")
        occ = z["occupancy"].astype(bool)
        origin, resolution = np.asarray(z["origin"], np.float64), float(z["resolution"])
        return types.SimpleNamespace(
            grid=Q.Grid.host(origin, resolution, occ.shape),
            occupancy=occ,
            semantic=z["semantic"].astype(np.int8),
            indoor=z["indoor"].astype(bool) if "indoor" in z else np.ones_like(occ),
            origin=origin,
            resolution=resolution,
            seed=0,
        )


def plot_over_time(world, snapshots, path, goal, out, panels: int = 6, title: str = "") -> None:
    """A strip of ``panels`` window distributions (log10 p over the robot-centred 160 x 160
    window; the true walls in white) at evenly spaced replans, with the whole travelled path,
    the robot (x) and the goal direction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    if not snapshots:
        return
    idx = np.unique(np.linspace(0, len(snapshots) - 1, min(panels, len(snapshots))).round().astype(int))
    fig, axes = plt.subplots(1, len(idx), figsize=(3.3 * len(idx), 3.6), squeeze=False)
    res = world.resolution
    occ = np.asarray(world.occupancy)
    for ax, i in zip(axes[0], idx):
        step, xy, local, center = snapshots[i]
        h = local.shape[0] // 2
        r0, c0 = int(center[0]) - h, int(center[1]) - h
        x0, y0 = world.origin[0] + c0 * res, world.origin[1] + r0 * res
        ext = [x0, x0 + local.shape[1] * res, y0, y0 + local.shape[0] * res]
        ax.imshow(
            np.log10(np.maximum(local, 1e-30)),
            origin="lower",
            extent=ext,
            cmap="viridis",
            interpolation="nearest",
        )
        rr, cc = np.mgrid[r0 : r0 + local.shape[0], c0 : c0 + local.shape[1]]
        on = (rr >= 0) & (rr < occ.shape[0]) & (cc >= 0) & (cc < occ.shape[1])
        walls = np.zeros(local.shape, bool)
        walls[on] = occ[rr[on], cc[on]]
        ax.contour(walls, levels=[0.5], colors="w", linewidths=0.3, extent=ext, origin="lower")
        p = np.asarray(path)
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:green", lw=1.0, alpha=0.6)
        ax.plot(*xy, "rx", ms=8, mew=2)
        d = np.asarray(goal) - xy
        d = d / max(float(np.hypot(*d)), 1e-9)
        ax.arrow(xy[0], xy[1], 3.0 * d[0], 3.0 * d[1], color="r", width=0.15)
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
        ax.set_title(f"step {step}", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(
        title or "LSD window distribution over time (log10 p; true walls in white)",
        fontsize=9,
    )
    fig.tight_layout()
    sc.atomic_savefig(fig, out, dpi=90)
    plt.close(fig)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument("--map", help="npz map file (None: a generated building)")
    p.add_argument("--family", default="test", choices=("train", "test", "house", "campus"), help="building family")
    p.add_argument("--building", type=int, default=0, help="building seed")
    p.add_argument(
        "--start",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="start (m)",
    )
    p.add_argument("--goal", type=float, nargs=2, metavar=("X", "Y"), help="goal (m)")
    p.add_argument(
        "--kind",
        default="IO",
        choices=("II", "IO"),
        help="task kind when start/goal are omitted",
    )
    p.add_argument(
        "--checkpoint",
        help="LSD training workdir or exported .npz (None: the shipped model)",
    )
    p.add_argument(
        "--sampler",
        default="both",
        choices=("lsd", "uniform", "both"),
        help="planner(s)",
    )
    p.add_argument(
        "--uniform-mix",
        type=float,
        default=0.0,
        help="share of uniform mixed into the LSD window (0 = the thesis' rule)",
    )
    sc.add_config_flags(p, NavConfig, CONFIG_FLAGS, base=NAV_BASE)
    p.add_argument(
        "--yaw",
        type=float,
        default=0.0,
        help="initial heading (rad) with --start/--goal",
    )
    p.add_argument("--seed", type=int, default=0, help="task and sampling seed")
    p.add_argument(
        "--panels",
        type=sc.positive_int,
        default=6,
        help="windows in the distribution-over-time strip",
    )
    p.add_argument("--out", default="plan.png", help="figure path")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def parse_args(argv=None, prog: str | None = None) -> argparse.Namespace:
    """The flags, checked (one line naming a bad one; before any run starts)."""
    args = build_parser(prog).parse_args(argv)
    if args.n < 1:
        raise SystemExit(f"--n: expected >= 1, got {args.n}")
    if args.max_steps < 1:
        raise SystemExit(f"--max-steps: expected >= 1, got {args.max_steps}")
    if args.map and not pathlib.Path(args.map).exists():
        raise SystemExit(f"--map: no such file {args.map!r}")
    if args.checkpoint and not pathlib.Path(args.checkpoint).exists():
        raise SystemExit(f"--checkpoint: no such file or folder {args.checkpoint!r}")
    if not 0.0 <= args.uniform_mix < 1.0:
        raise SystemExit(f"--uniform-mix: expected in [0, 1), got {args.uniform_mix}")
    if (args.start is None) != (args.goal is None):  # one alone would be dropped for a sampled task
        given, missing = ("--start", "--goal") if args.goal is None else ("--goal", "--start")
        raise SystemExit(f"{missing}: needed with {given} (give both, or neither for a sampled --kind task)")
    return args


def main(argv=None, prog: str | None = None) -> int:
    args = parse_args(argv, prog)
    try:
        return _run(args)
    except ValueError as exc:
        if args.debug:
            raise
        raise SystemExit(f"{prog or 'plan.py'}: {exc}") from None


def _run(args) -> int:
    if pathlib.Path(args.out).is_dir():  # savefig would write "<dir>.png" beside it, not into it
        raise ValueError(f"--out: {args.out} is a folder; give the figure's file path, e.g. {args.out}/plan.png")
    try:  # the figure's folder, made before the long work (a bad --out fails now, not after the trials)
        pathlib.Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out: cannot create the folder of {args.out} ({exc})") from None
    import jax
    import numpy as np
    from tqdm import tqdm

    from jaxsem.lsd import (
        LSDSampler,
        full_map_distribution,
        load_model,
        plot_navigation,
    )
    from jaxsem.planning import Trial, generate_building, sample_tasks

    world: Any = _load_map(args.map) if args.map else generate_building(args.building, args.family)
    yaw = args.yaw
    if args.start is None or args.goal is None:
        if args.map:
            raise SystemExit("--start/--goal: required with --map")
        tasks = sample_tasks(world, args.kind, 1, args.seed)
        if not tasks:  # sample_tasks has warned why (no free cell, no pair within the bounds)
            raise SystemExit(f"--building/--kind: no {args.kind} task found in this building; give --start and --goal")
        task = tasks[0]
        start, goal, yaw = task.start, task.goal, task.yaw0
        print(f"task {args.kind}: start {start.round(2).tolist()} goal {goal.round(2).tolist()} C* {task.c_star:.1f} m")
    else:
        start, goal = np.asarray(args.start), np.asarray(args.goal)
    sampler = None
    if args.sampler != "uniform":
        model, params, _, meta = load_model(args.checkpoint)
        sampler = LSDSampler(model, params, uniform_mix=args.uniform_mix, cell_size=meta["cell_size"])
    names = {"both": ["uniform", "lsd"], "lsd": ["lsd"], "uniform": ["uniform"]}[args.sampler]
    key = jax.random.PRNGKey(args.seed)
    cfg = sc.apply_config_flags(NAV_BASE, args, CONFIG_FLAGS)
    results, dist, trial_lsd = {}, None, None
    for name in names:
        trial = Trial(
            world,
            start,
            goal,
            key,
            cfg,
            sampler if name == "lsd" else None,
            yaw0=yaw,
            keep_distributions=100_000 if name == "lsd" else 0,
        )
        # The bar counts to the trial's real step limit and closes at the step where it ended.
        with tqdm(
            total=cfg.max_steps,
            desc=f"{name} steps",
            unit="step",
            disable=args.no_progress,
        ) as bar:
            while trial.step():
                bar.update(trial.steps - bar.n)
            bar.update(trial.steps - bar.n)
            bar.set_postfix(result=trial.reason)
        res = trial.result()
        results[name] = res
        sc.record(
            **{name: dict(success=res.success, reason=res.reason, travelled_m=round(res.cost, 2), steps=res.steps)}
        )
        print(
            f"{name}: success {res.success} ({res.reason}), travelled {res.cost:.1f} m, "
            f"{res.steps} steps, {res.plans} roadmaps, {res.searches} searches, {res.grown} growths"
        )
        if name == "lsd":
            trial_lsd = res
            assert sampler is not None  # the LSD trial runs only when a sampler was loaded
            dist = full_map_distribution(
                sampler,
                res.final_state,
                res.path[-1],
                goal,
                trial.goal_outdoors,
                world,
            )
    out = pathlib.Path(args.out)
    plot_navigation(
        world,
        results,
        out,
        start,
        goal,
        dist,
        title=f"N = {args.n}: " + ", ".join(names),
    )
    print(f"figure: {out}")
    sc.record_output(out)
    if trial_lsd is not None and trial_lsd.distributions:
        strip = out.with_name(out.stem + "_over_time.png")
        plot_over_time(world, trial_lsd.distributions, trial_lsd.path, goal, strip, args.panels)
        print(f"figure: {strip}")
    return 0

"""Online navigation with the LSD sampler and/or the uniform PRM on one map; saves a figure.

The map is a generated building (--family, --building) or an npz file (--map) with keys
``occupancy`` (H, W) bool, ``semantic`` (H, W) int8, ``origin`` (2,), ``resolution`` () and
optionally ``indoor`` (H, W) bool (default: all indoor). Start and goal are world (x, y) in
metres; when omitted a task of --kind (II / IO) is drawn on the building.

    python infer/plan.py --checkpoint runs/lsd --building 3 --family test --kind IO --out plan.png
    python infer/plan.py --map my_map.npz --start 2 3 --goal 30 12 --sampler uniform
"""

from __future__ import annotations

import argparse
import sys
import types


def _load_map(path):
    import numpy as np

    with np.load(path) as z:
        for k in ("occupancy", "semantic", "origin", "resolution"):
            if k not in z:
                raise SystemExit(f"--map: {path} lacks key {k!r} (needs occupancy, semantic, origin, resolution)")
        occ = z["occupancy"].astype(bool)
        return types.SimpleNamespace(
            occupancy=occ, semantic=z["semantic"].astype(np.int8),
            indoor=z["indoor"].astype(bool) if "indoor" in z else np.ones_like(occ),
            origin=np.asarray(z["origin"], np.float64), resolution=float(z["resolution"]), seed=0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--map", default=None, help="npz map file (else a generated building)")
    p.add_argument("--family", default="test", help="building family: train | test")
    p.add_argument("--building", type=int, default=0, help="building seed")
    p.add_argument("--start", type=float, nargs=2, default=None, metavar=("X", "Y"))
    p.add_argument("--goal", type=float, nargs=2, default=None, metavar=("X", "Y"))
    p.add_argument("--kind", default="IO", help="task kind when start/goal are omitted: II | IO")
    p.add_argument("--checkpoint", default=None,
                   help="LSD training workdir or exported .npz (default: the bundled CPU model)")
    p.add_argument("--sampler", default="both", help="lsd | uniform | both")
    p.add_argument("--uniform-mix", type=float, default=0.1,
                   help="share of uniform mixed into the LSD window (0 = the thesis' rule)")
    p.add_argument("--n", type=int, default=500, help="PRM samples per roadmap")
    p.add_argument("--max-steps", type=int, default=10_000)
    p.add_argument("--yaw", type=float, default=0.0, help="initial heading (rad)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="plan.png")
    args = p.parse_args(argv)
    if args.sampler not in ("lsd", "uniform", "both"):
        raise SystemExit(f"--sampler: expected lsd, uniform or both, got {args.sampler!r}")

    import jax
    import numpy as np
    from tqdm import tqdm

    from jaxsem.cli import enable_compilation_cache
    from jaxsem.lsd import LSDSampler, full_map_distribution, load_model, plot_navigation
    from jaxsem.planning import NavConfig, Trial, generate_building, sample_tasks

    enable_compilation_cache()
    world = _load_map(args.map) if args.map else generate_building(args.building, args.family)
    yaw = args.yaw
    if args.start is None or args.goal is None:
        if args.map:
            raise SystemExit("--start/--goal: required with --map")
        task = sample_tasks(world, args.kind, 1, args.seed)[0]
        start, goal, yaw = task.start, task.goal, task.yaw0
        print(f"task {args.kind}: start {start.round(2).tolist()} goal {goal.round(2).tolist()} "
              f"C* {task.c_star:.1f} m")
    else:
        start, goal = np.asarray(args.start), np.asarray(args.goal)
    sampler = None
    if args.sampler != "uniform":
        model, params, _ = load_model(args.checkpoint)
        sampler = LSDSampler(model, params, uniform_mix=args.uniform_mix)
    names = {"both": ["uniform", "lsd"], "lsd": ["lsd"], "uniform": ["uniform"]}[args.sampler]
    key = jax.random.PRNGKey(args.seed)
    cfg = NavConfig(n_samples=args.n, max_steps=args.max_steps)
    results, dist = {}, None
    for name in names:
        trial = Trial(world, start, goal, key, cfg, sampler if name == "lsd" else None, yaw0=yaw)
        with tqdm(total=args.max_steps, desc=f"{name} steps", unit="step") as bar:
            while trial.step():
                bar.update(1)
        res = trial.result()
        results[name] = res
        print(f"{name}: success {res.success} ({res.reason}), travelled {res.cost:.1f} m, "
              f"{res.steps} steps, {res.plans} roadmaps")
        if name == "lsd":
            dist = full_map_distribution(sampler, res.final_state, res.path[-1], goal,
                                         trial.goal_outdoors, world.origin, world.resolution)
    plot_navigation(world, results, args.out, start, goal, dist,
                    title=f"N = {args.n}: " + ", ".join(names))
    print(f"figure: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

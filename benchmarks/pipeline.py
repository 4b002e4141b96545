"""The integration experiment (thesis 5.8.3, issue 13 part 3), ground-truth object maps first.

On unseen (test-family) buildings, the online loop of jaxsem.planning runs, from the same start,
yaw and PRNG key, with:

- ``uniform``: the uniform PRM (Euclidean edges), the thesis' PRM + Unf;
- ``lsd``: LSD fed the robot's own object-camera semantic cells (chapter 3 as shipped);
- ``lsd_objmap``: LSD fed an object map (jaxsem.mapping) built online from the ground-truth
  ellipsoids of every door, window and exit sign the object camera has seen so far (one
  ``mapping.update`` per replan), rasterised as ellipse footprints: the 5.8.3 pipeline with a
  perfect estimator in place of VoluMon / ROSHAN;
- ``lsd_prior``: LSD fed the object map of *all* the building's objects from the start (an
  oracle: what a complete, exact object map would buy).

Success rate per sample budget N and, on trials where every planner succeeded, C/C* (metres
travelled over the resolution-optimal length) as mean +- s.e.m. (Table 3.1's statistic).
Writes benchmarks/results/pipeline.{json,md}.

    python benchmarks/pipeline.py                   # small CPU run (bundled LSD model)
    python benchmarks/pipeline.py --test-buildings 4 --trials 5 --n 100 500 1000 --max-steps 2000
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import platform
import subprocess
import sys
import time

import numpy as np

RESULTS = pathlib.Path(__file__).resolve().parent / "results"
PLANNERS = ("uniform", "lsd", "lsd_objmap", "lsd_prior")


class ObjectMapSampler:
    """LSD sampler whose semantic crop comes from an object map of a trial's seen objects.

    ``bind(trial)`` after the trial is built; at each replan the ground-truth ellipsoids of the
    objects with a cell in the trial's semantic map go into the store as one frame.
    """

    def __init__(self, lsd, building, objects, capacity, prior: bool):
        from jaxsem import mapping

        self.lsd, self.building, self.prior = lsd, building, prior
        self.dets = objects.ellipsoids(capacity)
        self.cells = objects.cells
        self.state = mapping.init(capacity)
        self.trial = None
        self.calls = 0
        if prior:
            self.state = mapping.update(self.state, self.dets, gate=0.5)

    def bind(self, trial):
        self.trial = trial

    def __call__(self, inputs):
        from jaxsem import mapping

        b = self.building
        if not self.prior:
            assert self.trial is not None, "bind(trial) first"
            sem = np.asarray(self.trial.state.semantic)
            seen = np.array(
                [np.any(sem[r0:r1, c0:c1] > 0) for r0, c0, r1, c1 in self.cells]
                + [False] * (self.dets.valid.shape[0] - len(self.cells))
            )
            frame = mapping.Ellipsoids(
                self.dets.rotation,
                self.dets.center,
                self.dets.radii,
                self.dets.class_id,
                self.dets.valid & seen,
            )
            self.state = mapping.update(self.state, frame, gate=0.5)
        grid = mapping.semantic_grid(self.state, b.shape, b.origin, b.resolution)
        self.calls += 1
        return mapping.object_map_sampler(self.lsd, grid)(inputs)


def run(args) -> dict:
    import jax

    from jaxsem import mapping
    from jaxsem.lsd import LSDSampler, load_model
    from jaxsem.metrics import mean_sem
    from jaxsem.planning import NavConfig, Trial, building_family, sample_tasks

    model, params, _ = load_model(args.checkpoint)
    lsd = LSDSampler(model, params, uniform_mix=args.uniform_mix)
    buildings = building_family("test", args.test_buildings, start=args.test_start)
    records = []
    for b in buildings:
        objects = mapping.building_objects(b)
        capacity = int(2 ** np.ceil(np.log2(max(len(objects), 1))))  # one compile per bucket
        for kind in args.sets:
            for t_i, task in enumerate(sample_tasks(b, kind, args.trials, args.seed)):
                for n in args.n:
                    key = jax.random.PRNGKey(
                        int(
                            np.random.default_rng(
                                [
                                    args.seed,
                                    int(b.seed),
                                    ("II", "IO").index(kind),
                                    t_i,
                                    n,
                                ]
                            ).integers(2**31)
                        )
                    )
                    rec = {
                        "building": int(b.seed),
                        "set": kind,
                        "trial": t_i,
                        "n": int(n),
                        "c_star": float(task.c_star),
                        "objects": len(objects),
                    }
                    for name in PLANNERS:
                        sampler = None
                        if name == "lsd":
                            sampler = lsd
                        elif name in ("lsd_objmap", "lsd_prior"):
                            sampler = ObjectMapSampler(lsd, b, objects, capacity, name == "lsd_prior")
                        cfg = NavConfig(n_samples=int(n), max_steps=args.max_steps)
                        t0 = time.perf_counter()
                        trial = Trial(
                            b,
                            task.start,
                            task.goal,
                            key,
                            cfg,
                            sampler,
                            yaw0=task.yaw0,
                            goal_outdoors=task.goal_outdoors,
                        )
                        if isinstance(sampler, ObjectMapSampler):
                            sampler.bind(trial)
                        while trial.step():
                            pass
                        res = trial.result()
                        rec[name] = {
                            "success": bool(res.success),
                            "cost": float(res.cost),
                            "reason": res.reason,
                            "steps": int(res.steps),
                            "plans": int(res.plans),
                            "seconds": time.perf_counter() - t0,
                        }
                        if isinstance(sampler, ObjectMapSampler):
                            rec[name]["mapped_objects"] = int(sampler.state.valid.sum())
                    records.append(rec)
                    if not args.no_progress:
                        print(
                            f"building {b.seed} {kind} trial {t_i} N={n}: "
                            + ", ".join(
                                f"{p} {'ok' if rec[p]['success'] else 'fail'} {rec[p]['cost']:.1f} m" for p in PLANNERS
                            ),
                            flush=True,
                        )
    summary = {}
    for kind in args.sets:
        for n in args.n:
            rs = [r for r in records if r["set"] == kind and r["n"] == n]
            mutual = [r for r in rs if all(r[p]["success"] for p in PLANNERS)]
            row = {"set": kind, "n": int(n), "trials": len(rs), "mutual": len(mutual)}
            for p in PLANNERS:
                row[f"success_{p}"] = float(np.mean([r[p]["success"] for r in rs])) if rs else float("nan")
                row[f"ratio_{p}"] = mean_sem([r[p]["cost"] / r["c_star"] for r in mutual])
            summary[f"{kind}-{n}"] = row
    return {"summary": summary, "records": records}


def format_table(summary: dict) -> str:
    def pm(ms):
        m, s = ms
        return "-" if not np.isfinite(m) else f"{m:.2f} +- {s:.2f}"

    head = ["set", "N", "trials", "mutual"] + [f"success {p}" for p in PLANNERS] + [f"C/C* {p}" for p in PLANNERS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in summary.values():
        cells = [row["set"], str(row["n"]), str(row["trials"]), str(row["mutual"])]
        cells += [f"{100 * row[f'success_{p}']:.0f} %" for p in PLANNERS]
        cells += [pm(row[f"ratio_{p}"]) for p in PLANNERS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "pipeline").splitlines()[0])
    p.add_argument("--checkpoint", default=None, help="LSD model (default: the bundled CPU model)")
    p.add_argument("--test-buildings", type=int, default=2)
    p.add_argument("--test-start", type=int, default=0)
    p.add_argument("--trials", type=int, default=2, help="tasks per building and set")
    p.add_argument("--n", type=int, nargs="+", default=[100, 500])
    p.add_argument("--sets", nargs="+", default=["IO", "II"])
    p.add_argument("--max-steps", type=int, default=600)
    p.add_argument("--uniform-mix", type=float, default=0.1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--name", default="pipeline")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    try:
        from jaxsem.cli import enable_compilation_cache

        enable_compilation_cache()
    except ImportError:  # pragma: no cover - older checkouts
        pass
    t0 = time.perf_counter()
    result = run(args)
    total = time.perf_counter() - t0
    table = format_table(result["summary"])
    print(table)
    cmd = "python benchmarks/pipeline.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    machine = f"{platform.machine()} CPU, {subprocess.run(['nproc'], capture_output=True, text=True, check=False).stdout.strip()} cores (shared, noisy)"
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.name}.json").write_text(
        json.dumps(
            {
                "command": cmd,
                "date": date,
                "machine": machine,
                "args": vars(args),
                "seconds": total,
                **result,
            },
            indent=1,
            default=float,
        )
    )
    md = [
        f"## Integration: LSD with object maps (`{args.name}`, thesis 5.8.3)",
        "",
        f"Command: `{cmd}`",
        "",
        f"Date: {date}",
        "",
        f"Machine: {machine}",
        "",
        (
            f"Test-family buildings {args.test_start}..{args.test_start + args.test_buildings - 1}, "
            f"{args.trials} tasks per building and set, step limit {args.max_steps}, LSD uniform mix "
            f"{args.uniform_mix}, bundled CPU LSD model; total {total / 60:.1f} min. Planners: "
            "`uniform` PRM; `lsd` with its own object-camera cells; `lsd_objmap` with a jaxsem.mapping "
            "object map of the ground-truth ellipsoids of the objects seen so far (ellipse "
            "footprints); `lsd_prior` with every object of the building mapped from the start. C/C* "
            "on trials where all four succeeded."
        ),
        "",
        table,
        "",
        (
            "Read small runs as smoke tests: with a handful of trials per row and one mutual "
            "success the s.e.m. is 0 by construction. C* is the length of the soft-cost "
            "optimal path (it keeps away from walls), so C/C* slightly below 1 is possible."
        ),
        "",
        (
            "Not yet measured here (issue 13 part 3): VoluMon and ROSHAN object maps from rendered "
            "detections (jaxsem.sim.BuildingRenderer provides the images and segmentation boxes)."
        ),
        "",
    ]
    (out / f"{args.name}.md").write_text("\n".join(md))
    print(f"wrote {out / (args.name + '.json')} and .md in {total / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())

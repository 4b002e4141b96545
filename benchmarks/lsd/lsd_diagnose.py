"""Why does the thesis' rule (LSD window distribution, no uniform mixing) lose to uniform sampling?

Measures each suspect at the first planning step of Inside-Inside and Inside-Outside tasks on
test-family buildings, for one or more models (no navigation, so it is cheap):

- coverage outside the window: the share of the N samples that fall outside the 160 x 160
  window under the thesis' rule (outside = the window's minimum, renormalised), and where the
  window's minimum sits (a known-occupied / off-map cell or a free / unknown one);
- a collapsed distribution: the window's perplexity (exp of its entropy, in cells) and its
  max / min ratio;
- first-roadmap failures: how often the first roadmap of N samples (no growth) has no path, for
  uniform sampling and for LSD with -log p and with Euclidean edge weights (the -log p suspect);
- window misalignment: the network's log-probability on the cells of the true soft-cost path
  inside the window, against uniform's (a window shifted against the map would score the path
  no better than uniform);
- too little data: the same numbers for each model given (e.g. the 6-building model and the
  shipped one).

    python benchmarks/lsd/lsd_diagnose.py --models jaxsem/lsd/pretrained_cpu.npz jaxsem/lsd/pretrained.npz \\
        --buildings 4 --first 50 --tasks 3 --n 500
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys

import numpy as np

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"


def _write(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def diagnose(model_path, buildings, tasks_per_set, n, seed):
    import jax
    import jax.numpy as jnp

    from jaxsem.lsd import LSDSampler, load_model
    from jaxsem.planning import (
        CROP_SIZE,
        OCCUPIED,
        PRM,
        NavConfig,
        SoftCostGraph,
        Trial,
        embed_local_distribution,
        sample_tasks,
    )

    model, params, cfg, _ = load_model(model_path)
    smp = LSDSampler(model, params, uniform_mix=0.0)
    rows = []
    for b in buildings:
        graph = SoftCostGraph(b.occupancy, b)
        for kind in ("II", "IO"):
            for ti, t in enumerate(sample_tasks(b, kind, tasks_per_set, seed, graph=graph)):
                tr = Trial(
                    b,
                    t.start,
                    t.goal,
                    jax.random.PRNGKey(0),
                    NavConfig(n_samples=n),
                    smp,
                    yaw0=t.yaw0,
                    goal_outdoors=t.goal_outdoors,
                )
                inp = tr.local_inputs()
                local = np.asarray(smp(inp), np.float64).reshape(CROP_SIZE, CROP_SIZE)
                occ = np.asarray(inp.occupancy)
                known = np.asarray(tr.state.occupancy)
                full = np.asarray(embed_local_distribution(jnp.asarray(local), inp.center_cell, known.shape))
                r0, c0 = (int(v) - CROP_SIZE // 2 for v in np.asarray(inp.center_cell))
                inwin = np.zeros(known.shape, bool)
                inwin[max(r0, 0) : r0 + CROP_SIZE, max(c0, 0) : c0 + CROP_SIZE] = True
                free = known != OCCUPIED
                share_out = float(full[~inwin & free].sum() / full[free].sum())
                amin = np.unravel_index(np.argmin(local), local.shape)
                ent = -np.sum(local * np.log(np.maximum(local, 1e-300)))
                # Expert path cells in the window vs uniform.
                p = graph.path(t.start, t.goal)
                cells = p.cells - np.array([r0, c0])
                ok = np.all((cells >= 0) & (cells < CROP_SIZE), axis=1)
                lp_path = float(np.mean(np.log(local[cells[ok, 0], cells[ok, 1]]))) if ok.any() else float("nan")
                found = {}
                for name, dist, weight in (
                    ("uniform", None, "euclidean"),
                    ("lsd", full, "neglogp"),
                    ("lsd_euclid", full, "euclidean"),
                ):
                    hits = 0
                    for rep in range(3):
                        prm = PRM(
                            known,
                            b,
                            capacity=n,
                            k=None,
                            radius=tr.radius,
                            weight=weight,
                        )
                        prm.grow(jax.random.PRNGKey(100 * rep + ti), n, dist)
                        hits += prm.query(t.start, t.goal).found
                    found[name] = hits / 3
                rows.append(
                    {
                        "building": b.seed,
                        "set": kind,
                        "task": ti,
                        "share_outside": share_out,
                        "samples_outside": n * share_out,
                        "min_cell_occupied": bool(occ[amin] == OCCUPIED),
                        "max_over_min": float(local.max() / max(local.min(), 1e-300)),
                        "perplexity": float(np.exp(ent)),
                        "path_logp": lp_path,
                        "uniform_logp": float(-np.log(CROP_SIZE**2)),
                        "first_roadmap_found": found,
                        "goal_distance": float(np.linalg.norm(t.goal - t.start)),
                    }
                )
    return {"model": str(model_path), "config": str(cfg.model), "rows": rows}


def summary(res):
    r = res["rows"]
    arr = lambda k: np.array([x[k] for x in r], float)
    fr = {
        name: float(np.mean([x["first_roadmap_found"][name] for x in r])) for name in ("uniform", "lsd", "lsd_euclid")
    }
    return {
        "tasks": len(r),
        "samples_outside_median": float(np.median(arr("samples_outside"))),
        "samples_outside_min": float(arr("samples_outside").min()),
        "tasks_with_<5_samples_outside": int((arr("samples_outside") < 5).sum()),
        "min_in_occupied_cell": int(sum(x["min_cell_occupied"] for x in r)),
        "max_over_min_median": float(np.median(arr("max_over_min"))),
        "perplexity_median": float(np.median(arr("perplexity"))),
        "path_logp_mean": float(np.nanmean(arr("path_logp"))),
        "uniform_logp": r[0]["uniform_logp"],
        "first_roadmap_found": fr,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument(
        "--models",
        nargs="+",
        default=[None],
        help="model files / workdirs (default: shipped)",
    )
    ap.add_argument("--buildings", type=int, default=4, help="test-family buildings")
    ap.add_argument("--first", type=int, default=50, help="first building seed (50+: tuning seeds)")
    ap.add_argument("--tasks", type=int, default=3, help="tasks per building and set")
    ap.add_argument("--n", type=int, default=500, help="samples of the first roadmap")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--name", default="lsd_diagnose")
    args = ap.parse_args(argv)
    for m in args.models:
        if m is not None and not pathlib.Path(m).exists():
            raise SystemExit(f"--models: no such file or folder {m!r}")

    from jaxsem.cli import enable_compilation_cache
    from jaxsem.planning._buildings import building_family  # layers: white-box

    enable_compilation_cache()
    buildings = building_family("test", args.buildings, start=args.first)
    results = []
    for m in args.models:
        res = diagnose(m, buildings, args.tasks, args.n, args.seed)
        res["summary"] = summary(res)
        results.append(res)
        print(json.dumps(res["summary"], indent=1), flush=True)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True, check=False).stdout.strip()
    cmd = "python benchmarks/lsd/lsd_diagnose.py " + " ".join(sys.argv[1:] if argv is None else argv)
    _write(
        out / f"{args.name}.json",
        json.dumps({"command": cmd, "date": date, "results": results}, indent=1),
    )
    lines = [
        f"## LSD diagnosis: why the thesis' rule lost to uniform (`{args.name}`)",
        "",
        f"Command: `{cmd}`  ",
        f"Date: {date}  ",
        "Machine: 2-core CPU (shared, noisy)",
        "",
        f"First planning step of {args.tasks} II + {args.tasks} IO tasks on test buildings "
        f"{args.first}..{args.first + args.buildings - 1}; N = {args.n}; first-roadmap success over 3 "
        "roadmaps per task, no growth.",
        "",
        "| model | samples outside the window (median / min / tasks < 5) | window min in a known-occupied "
        "cell | max/min (median) | perplexity (cells, median) | mean log p on the true path (uniform) | "
        "first roadmap found: uniform / LSD -log p / LSD Euclidean |",
        "|---|---|---|---|---|---|---|",
    ]
    for res in results:
        s = res["summary"]
        fr = s["first_roadmap_found"]
        lines.append(
            f"| {pathlib.Path(res['model']).name if res['model'] != 'None' else 'shipped'} | "
            f"{s['samples_outside_median']:.0f} / {s['samples_outside_min']:.1f} / "
            f"{s['tasks_with_<5_samples_outside']} of {s['tasks']} | {s['min_in_occupied_cell']} of {s['tasks']} | "
            f"{s['max_over_min_median']:.3g} | {s['perplexity_median']:.0f} | {s['path_logp_mean']:.2f} "
            f"({s['uniform_logp']:.2f}) | {100 * fr['uniform']:.0f} % / {100 * fr['lsd']:.0f} % / "
            f"{100 * fr['lsd_euclid']:.0f} % |"
        )
    finding = pathlib.Path(__file__).with_name("lsd_diagnose_finding.md")
    if finding.exists():  # the write-up of the committed run (numbers from its table)
        lines.append(finding.read_text())
    _write(out / f"{args.name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

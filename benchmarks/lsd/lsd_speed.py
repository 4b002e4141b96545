"""Benchmark: the LSD planner's per-step pieces against their targets and against OMPL's PRM.

Rows (all in one run, on the same maps):

- PRM build + query at N vertices (default 5000), jaxsem (jitted sampling, bucket-grid kNN,
  exact edge checks; scipy Dijkstra) vs OMPL's ``PRM`` from Python: ``growRoadmapPtc`` until
  exactly N milestones, the same grid as validity checker, motion checks at the same half-cell
  resolution, its default k = 10 neighbours; one roadmap per map, reused for every query: start
  and goal connected to their 10 nearest milestones with ``checkMotion`` and the extracted graph
  searched with scipy Dijkstra. jaxsem builds one roadmap per query (start and goal are
  vertices), k = 15 (about OMPL's edges per vertex). Success and path length / C* compared.
- Ray-cast sensing of one pose (depth 85.2 deg / 5 m + object camera 69.4 deg / 10 m).
- Expert dataset throughput (samples per second, one process).
- The LSD network forward pass on one 160 x 160 x 2 input (``jaxsem.models``), if present.

    python benchmarks/lsd/lsd_speed.py [--n 5000] [--maps 3] [--tasks 4] [--k 15] [--repeats 3]
                                   [--expert-samples 40]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxsem import lsd, planning

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _harness

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _ompl_peer import OmplPRM, edge_degree as _degree

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"


def ours_prm(b, task, n, seed, k):
    rm = planning.build_roadmap(jax.random.PRNGKey(seed), b.occupancy, task.start, task.goal, n, b, k=k)
    jax.block_until_ready(rm)
    return rm


def ours_degree(rm):
    nbr, ok = np.asarray(rm.neighbors), np.asarray(rm.edge_valid)
    src = np.repeat(np.arange(nbr.shape[0]), nbr.shape[1])[ok.ravel()]
    return _degree(src, nbr.ravel()[ok.ravel()], int(np.asarray(rm.valid).sum()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000, help="PRM vertices (samples)")
    ap.add_argument("--maps", type=int, default=3, help="test-family buildings (seeds 0..maps-1)")
    ap.add_argument("--tasks", type=int, default=4, help="Inside-Inside start/goal pairs per map")
    ap.add_argument("--k", type=int, default=15, help="jaxsem neighbours per vertex (OMPL keeps its default 10)")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats of jaxsem per task (medians)")
    ap.add_argument("--seed", type=int, default=0, help="task / sampling seed")
    ap.add_argument("--expert-samples", type=int, default=40, help="samples for the throughput row")
    ap.add_argument("--no-ompl", action="store_true", help="skip the OMPL peer")
    ap.add_argument("--out", default=str(RESULTS), help="folder for lsd_speed.json / .md")
    args = ap.parse_args(argv)

    rows, detail = [], {"prm": []}
    buildings = [planning.generate_building(s, "test") for s in range(args.maps)]
    ours_b, ours_q, om_b, om_q = [], [], [], []
    ours_found, om_found, ours_len, om_len, ours_deg, om_deg = 0, 0, [], [], [], []
    n_tasks = 0
    for b in buildings:
        tasks = planning.sample_tasks(b, "II", args.tasks, seed=args.seed)
        ours_prm(b, tasks[0], args.n, 999, args.k)  # warm-up: compile for this map shape
        om = None if args.no_ompl else OmplPRM(b, args.n)
        if om is not None:
            om_deg.append(om.degree)
        for ti, task in enumerate(tasks):
            n_tasks += 1
            t_build, rm = _harness.timed(
                lambda: ours_prm(b, task, args.n, args.seed + ti, args.k), repeats=args.repeats, warmup=False
            )
            t_query, path = _harness.timed(
                lambda: planning.roadmap_shortest_path(rm), repeats=args.repeats, warmup=False
            )
            ours_b.append(t_build)
            ours_q.append(t_query)
            ours_deg.append(ours_degree(rm))
            ours_found += path.found
            rec = {
                "building": b.seed,
                "task": ti,
                "shape": list(b.shape),
                "c_star": task.c_star,
                "ours": {
                    "build_s": t_build,
                    "query_s": t_query,
                    "found": path.found,
                    "length": path.length,
                    "degree": ours_deg[-1],
                },
            }
            line = (
                f"building {b.seed} task {ti}: ours build {t_build * 1e3:.1f} ms, query "
                f"{t_query * 1e3:.2f} ms, found {path.found}, length {path.length:.2f} m"
            )
            if om is not None:
                t_oq, o_found, o_len, _ = om.query(task.start, task.goal, with_path=False)
                # OMPL builds one roadmap per map and reuses it: its build counts once per map.
                om_q.append(t_oq)
                om_found += o_found
                rec["ompl"] = {
                    "build_s": om.build_s,
                    "extract_s": om.extract_s,
                    "query_s": t_oq,
                    "found": o_found,
                    "length": o_len,
                    "degree": om.degree,
                }
                line += f" | OMPL query {t_oq * 1e3:.1f} ms, found {o_found}, length {o_len:.2f} m"
                if o_found and path.found:
                    ours_len.append(path.length / task.c_star)
                    om_len.append(o_len / task.c_star)
            detail["prm"].append(rec)
            print(line, flush=True)
        if om is not None:
            om_b.append(om.build_s + om.extract_s)
            print(
                f"building {b.seed}: OMPL build {om.build_s * 1e3:.0f} ms + extract "
                f"{om.extract_s * 1e3:.0f} ms, degree {om.degree:.1f} (ours {np.mean(ours_deg[-len(tasks) :]):.1f})",
                flush=True,
            )
    ours_total = float(np.median(ours_b) + np.median(ours_q))
    peer_total = float(np.median(om_b) + np.median(om_q)) if om_b else None
    rows.append((f"PRM build (N={args.n})", float(np.median(ours_b)), float(np.median(om_b)) if om_b else None))
    rows.append(("PRM query", float(np.median(ours_q)), float(np.median(om_q)) if om_q else None))
    rows.append(("PRM build + query", ours_total, peer_total))
    detail["found"] = {"ours": ours_found, "ompl": om_found, "tasks": n_tasks}
    detail["degree"] = {"ours": float(np.mean(ours_deg)), "ompl": float(np.mean(om_deg)) if om_deg else None}
    if ours_len:
        detail["length_over_c_star"] = {
            "ours": float(np.mean(ours_len)),
            "ompl": float(np.mean(om_len)),
            "both_found": len(ours_len),
        }

    # Sensing one pose.
    b = buildings[0]
    st = planning.empty_map_state(b.shape)
    occ, sem = jnp.asarray(b.occupancy), jnp.asarray(b.semantic)
    pose = jnp.asarray([b.entrance[0], b.entrance[1], np.pi])
    planning.sense(occ, sem, st, pose, b)
    t_sense, _ = _harness.timed(lambda: planning.sense(occ, sem, st, pose, b), repeats=200, warmup=False)
    rows.append(("sense one pose (depth + objects)", t_sense, None))

    # Expert data throughput (one process; the script runs two workers over buildings).
    small = lsd.ExpertConfig(samples_per_building=4)
    lsd.generate_expert_samples(b, 1, small)  # warm-up compiles
    cfg = lsd.ExpertConfig(samples_per_building=args.expert_samples)
    t0 = time.perf_counter()
    data = lsd.generate_expert_samples(b, 2, cfg)
    t_exp = time.perf_counter() - t0
    n_exp = len(data["context"])
    detail["expert_samples_per_s"] = n_exp / t_exp

    # Network forward.
    t_net, net_note = None, ""
    try:
        from jaxsem import models

        model, params = models.init_lsd(jax.random.PRNGKey(0))
        fwd = jax.jit(lambda p, o, s, c: models.lsd_distribution(model, p, o, s, c))
        o = jnp.zeros((1, 160, 160), jnp.int8)
        c = jnp.zeros((1, 4), jnp.float32)
        jax.block_until_ready(fwd(params, o, o, c))
        t_net, _ = _harness.timed(lambda: fwd(params, o, o, c), repeats=50, warmup=False)
        rows.append(("LSD network forward 160x160x2", t_net, None))
    except Exception as exc:  # C2's module absent or changed: skip the row, say why
        net_note = f"network row skipped: {type(exc).__name__}: {exc}"
        print(net_note)

    header = "| step | jaxsem (ms) | OMPL PRM (ms) | OMPL / jaxsem |\n|---|---|---|---|"
    lines = [header]
    for name, ours, peer in rows:
        ratio = f"{peer / ours:.1f}x" if peer else "-"
        lines.append(
            f"| {name} | {ours * 1e3:.2f} | {peer * 1e3:.1f} |  {ratio} |"
            if peer
            else f"| {name} | {ours * 1e3:.2f} | - | - |"
        )
    lines.append(f"| expert data throughput | {detail['expert_samples_per_s']:.1f} samples/s | - | - |")
    table = "\n".join(lines)
    print(table)
    quality = ""
    if ours_len:
        quality = (
            f"Paths found: jaxsem {ours_found} / {n_tasks}, OMPL {om_found} / {n_tasks} Inside-Inside "
            f"tasks; where both found one ({len(ours_len)}), mean length / C*: jaxsem "
            f"{np.mean(ours_len):.3f}, OMPL {np.mean(om_len):.3f} (C*: soft-cost optimal path length; "
            f"N = {args.n}; jaxsem k = {args.k}, OMPL k = 10; distinct edges per vertex: jaxsem "
            f"{detail['degree']['ours']:.1f}, OMPL {detail['degree']['ompl']:.1f}). OMPL's build is "
            f"one roadmap per map, reused by its {args.tasks} queries; jaxsem builds one per query."
        )
        print(quality)

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip()
    cmd = "python benchmarks/lsd/lsd_speed.py " + " ".join(argv if argv is not None else __import__("sys").argv[1:])
    payload = {
        "command": cmd.strip(),
        "date": date,
        "machine": "2-core CPU (shared, noisy)",
        "platform": platform.platform(),
        "jax": jax.__version__,
        "n": args.n,
        "maps": args.maps,
        "rows": [{"step": n, "jaxsem_s": o, "ompl_s": p} for n, o, p in rows],
        "expert_samples_per_s": detail["expert_samples_per_s"],
        "network_note": net_note,
        "detail": detail,
    }
    (out / "lsd_speed.json").write_text(json.dumps(payload, indent=1, default=float))
    behind = []
    if t_sense > 1e-3:
        behind.append(f"sensing one pose takes {t_sense * 1e3:.2f} ms, over the 1 ms target")
    if t_net is not None and t_net > 1e-2:
        behind.append(f"the network forward takes {t_net * 1e3:.1f} ms, over the 10 ms target")
    if peer_total and ours_total > peer_total:
        behind.append("the PRM is slower than OMPL's")
    if ours_len and np.mean(ours_len) > np.mean(om_len) * 1.001:
        behind.append(f"our mean path is {np.mean(ours_len) / np.mean(om_len) - 1:.1%} longer than OMPL's")
    if om_b and ours_found < om_found:
        behind.append(f"we found {ours_found} paths to OMPL's {om_found}")
    summary = (
        ("Where we are behind: " + "; ".join(behind) + ".")
        if behind
        else (
            "Where we are behind: nowhere on these rows; note OMPL runs a Python validity checker (its "
            "C++ core waits on Python callbacks), which is how a Python user meets it."
        )
    )
    md = [
        "## LSD planner speed",
        "",
        f"Command: `{cmd.strip()}`  ",
        f"Date: {date}  ",
        "Machine: 2-core CPU (shared, noisy)",
        "",
        table,
        "",
    ]
    if quality:
        md += [quality, ""]
    if net_note:
        md += [net_note, ""]
    md.append(summary)
    (out / "lsd_speed.md").write_text("\n".join(md) + "\n")
    print(summary)


if __name__ == "__main__":
    main()

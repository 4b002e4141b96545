"""Benchmark: the LSD planner's per-step pieces against their targets and against OMPL's PRM.

Rows (all in one run, on the same maps):

- PRM build + query at N vertices (default 5000), jaxsem (jitted sampling, bucket-grid kNN,
  exact edge checks; scipy Dijkstra) vs OMPL's ``PRM`` from Python: ``growRoadmapPtc`` until
  exactly N milestones, the same grid as validity checker, motion checks at the same half-cell
  resolution, k = 10 neighbours; start and goal connected to their 10 nearest milestones with
  ``checkMotion`` and the extracted graph searched with scipy Dijkstra. Path length compared.
- Ray-cast sensing of one pose (depth 85.2 deg / 5 m + object camera 69.4 deg / 10 m).
- Expert dataset throughput (samples per second, one process).
- The LSD network forward pass on one 160 x 160 x 2 input (``jaxsem.models``), if present.

    python benchmarks/lsd_speed.py [--n 5000] [--maps 3] [--repeats 3] [--expert-samples 40]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import subprocess
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from jaxsem import planning

RESULTS = pathlib.Path(__file__).parent / "results"


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        jax.block_until_ready(out)
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def ours_prm(b, task, n, seed):
    rm = planning.build_roadmap(jax.random.PRNGKey(seed), b.occupancy, task.start, task.goal, n,
                                b.origin, b.resolution)
    jax.block_until_ready(rm)
    return rm


def ompl_prm(b, task, n, k=10):
    from ompl import base as ob
    from ompl import geometric as og

    occ, res = b.occupancy, b.resolution
    H, W = occ.shape
    ox, oy = float(b.origin[0]), float(b.origin[1])
    space = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(0, ox)
    bounds.setHigh(0, ox + W * res)
    bounds.setLow(1, oy)
    bounds.setHigh(1, oy + H * res)
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)

    def valid(s):
        c, r = int((s[0] - ox) / res), int((s[1] - oy) / res)
        return bool(0 <= r < H and 0 <= c < W and not occ[r, c])  # bool(): OMPL needs a real bool

    si.setStateValidityChecker(valid)
    si.setStateValidityCheckingResolution(0.5 * res / space.getMaximumExtent())
    si.setup()
    pdef = ob.ProblemDefinition(si)
    planner = og.PRM(si)
    planner.setProblemDefinition(pdef)
    planner.setMaxNearestNeighbors(k)
    planner.setup()
    t0 = time.perf_counter()
    # Exactly n milestones: growRoadmap runs in this thread, so a Python condition is safe here
    # (it is PRM::solve's second thread that deadlocks on one); it costs one call per milestone,
    # against hundreds of validity-checker calls per milestone.
    planner.growRoadmapPtc(ob.PlannerTerminationCondition(lambda: planner.milestoneCount() >= n))
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    pd = ob.PlannerData(si)
    planner.getPlannerData(pd)
    M = pd.numVertices()
    pts = np.array([[pd.getVertex(i).getState()[0], pd.getVertex(i).getState()[1]] for i in range(M)])
    src, dst = [], []
    for i in range(M):
        for j in pd.getEdges(i):
            src.append(i)
            dst.append(j)
    extract = time.perf_counter() - t0
    t0 = time.perf_counter()
    # Query: connect start and goal to their k nearest milestones (checkMotion), then Dijkstra.
    st_a, st_b = si.allocState(), si.allocState()
    allp = np.vstack([pts, task.start, task.goal])
    s_idx, g_idx = M, M + 1
    for q_idx, q in ((s_idx, task.start), (g_idx, task.goal)):
        d = np.linalg.norm(pts - q, axis=1)
        for j in np.argsort(d)[:k]:
            st_a[0], st_a[1] = float(q[0]), float(q[1])
            st_b[0], st_b[1] = float(pts[j, 0]), float(pts[j, 1])
            if si.checkMotion(st_a, st_b):
                src.append(q_idx)
                dst.append(int(j))
    src, dst = np.array(src), np.array(dst)
    w = np.maximum(np.linalg.norm(allp[src] - allp[dst], axis=1), 1e-12)
    g = scipy.sparse.csr_matrix((w, (src, dst)), shape=(M + 2, M + 2))
    dist = scipy.sparse.csgraph.dijkstra(g, directed=False, indices=s_idx)
    query = time.perf_counter() - t0
    return {"build_s": build, "extract_s": extract, "query_s": query, "milestones": M,
            "edges": int(pd.numEdges()), "found": bool(np.isfinite(dist[g_idx])),
            "length": float(dist[g_idx])}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000, help="PRM vertices (samples)")
    ap.add_argument("--maps", type=int, default=3, help="test-family buildings (seeds 0..maps-1)")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats of jaxsem per map (medians)")
    ap.add_argument("--seed", type=int, default=0, help="task / sampling seed")
    ap.add_argument("--expert-samples", type=int, default=40, help="samples for the throughput row")
    ap.add_argument("--no-ompl", action="store_true", help="skip the OMPL peer")
    ap.add_argument("--out", default=str(RESULTS), help="folder for lsd_speed.json / .md")
    args = ap.parse_args(argv)

    rows, detail = [], {"prm": []}
    buildings = [planning.generate_building(s, "test") for s in range(args.maps)]
    ours_b, ours_q, ours_len, om_b, om_q, om_len, both = [], [], [], [], [], [], 0
    for b in buildings:
        task = planning.sample_tasks(b, "II", 1, seed=args.seed)[0]
        ours_prm(b, task, args.n, 999)  # warm-up: compile for this map shape
        t_build, rm = median_time(lambda: ours_prm(b, task, args.n, args.seed), args.repeats)
        t_query, path = median_time(lambda: planning.roadmap_shortest_path(rm), args.repeats)
        rec = {"building": b.seed, "shape": list(b.shape), "c_star": task.c_star,
               "ours": {"build_s": t_build, "query_s": t_query, "found": path.found, "length": path.length,
                        "valid_vertices": int(np.asarray(rm.valid).sum()),
                        "edges": int(np.asarray(rm.edge_valid).sum())}}
        ours_b.append(t_build)
        ours_q.append(t_query)
        if not args.no_ompl:
            om = ompl_prm(b, task, args.n)
            rec["ompl"] = om
            om_b.append(om["build_s"])
            om_q.append(om["extract_s"] + om["query_s"])
            if om["found"] and path.found:
                both += 1
                ours_len.append(path.length)
                om_len.append(om["length"])
        detail["prm"].append(rec)
        print(f"building {b.seed} {b.shape}: ours build {t_build * 1e3:.1f} ms, query {t_query * 1e3:.2f} ms,"
              f" found {path.found} length {path.length:.2f} m"
              + ("" if args.no_ompl else f" | OMPL build {om['build_s'] * 1e3:.0f} ms, extract+query "
                 f"{(om['extract_s'] + om['query_s']) * 1e3:.1f} ms, found {om['found']} length {om['length']:.2f} m"),
              flush=True)
    ours_total = float(np.median(np.add(ours_b, ours_q)))
    rows.append(("PRM build (N=%d)" % args.n, float(np.median(ours_b)), float(np.median(om_b)) if om_b else None))
    rows.append(("PRM query", float(np.median(ours_q)), float(np.median(om_q)) if om_q else None))
    rows.append(("PRM build + query", ours_total, float(np.median(np.add(om_b, om_q))) if om_b else None))
    if ours_len:
        detail["path_length_mean"] = {"ours": float(np.mean(ours_len)), "ompl": float(np.mean(om_len)),
                                      "maps_both_found": both}

    # Sensing one pose.
    b = buildings[0]
    st = planning.empty_map_state(b.shape)
    occ, sem = jnp.asarray(b.occupancy), jnp.asarray(b.semantic)
    pose = jnp.asarray([b.entrance[0], b.entrance[1], np.pi])
    planning.sense(occ, sem, st, pose, b.origin, b.resolution)
    t_sense, _ = median_time(lambda: planning.sense(occ, sem, st, pose, b.origin, b.resolution), 200)
    rows.append(("sense one pose (depth + objects)", t_sense, None))

    # Expert data throughput (one process; the script runs two workers over buildings).
    small = planning.ExpertConfig(samples_per_building=4)
    planning.generate_expert_samples(b, 1, small)  # warm-up compiles
    cfg = planning.ExpertConfig(samples_per_building=args.expert_samples)
    t0 = time.perf_counter()
    data = planning.generate_expert_samples(b, 2, cfg)
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
        t_net, _ = median_time(lambda: fwd(params, o, o, c), 50)
        rows.append(("LSD network forward 160x160x2", t_net, None))
    except Exception as exc:  # C2's module absent or changed: skip the row, say why
        net_note = f"network row skipped: {type(exc).__name__}: {exc}"
        print(net_note)

    header = f"| step | jaxsem (ms) | OMPL PRM (ms) | OMPL / jaxsem |\n|---|---|---|---|"
    lines = [header]
    for name, ours, peer in rows:
        ratio = f"{peer / ours:.1f}x" if peer else "-"
        lines.append(f"| {name} | {ours * 1e3:.2f} | {peer * 1e3:.1f} |  {ratio} |" if peer
                     else f"| {name} | {ours * 1e3:.2f} | - | - |")
    lines.append(f"| expert data throughput | {detail['expert_samples_per_s']:.1f} samples/s | - | - |")
    table = "\n".join(lines)
    print(table)
    if ours_len:
        print(f"mean path length on maps where both found a path ({both}): jaxsem {np.mean(ours_len):.2f} m, "
              f"OMPL {np.mean(om_len):.2f} m")

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip()
    cmd = "python benchmarks/lsd_speed.py " + " ".join(argv if argv is not None else __import__("sys").argv[1:])
    payload = {"command": cmd.strip(), "date": date, "machine": "2-core CPU (shared, noisy)",
               "platform": platform.platform(), "jax": jax.__version__, "n": args.n, "maps": args.maps,
               "rows": [{"step": n, "jaxsem_s": o, "ompl_s": p} for n, o, p in rows],
               "expert_samples_per_s": detail["expert_samples_per_s"], "network_note": net_note, "detail": detail}
    (out / "lsd_speed.json").write_text(json.dumps(payload, indent=1, default=float))
    behind = []
    if t_sense > 1e-3:
        behind.append(f"sensing one pose takes {t_sense * 1e3:.2f} ms, over the 1 ms target")
    if t_net is not None and t_net > 1e-2:
        behind.append(f"the network forward takes {t_net * 1e3:.1f} ms, over the 10 ms target")
    if om_b and ours_total > float(np.median(np.add(om_b, om_q))):
        behind.append("the PRM is slower than OMPL's")
    if ours_len and np.mean(ours_len) > np.mean(om_len) * 1.001:
        behind.append(f"our mean path is {np.mean(ours_len) / np.mean(om_len) - 1:.1%} longer than OMPL's")
    summary = ("Where we are behind: " + "; ".join(behind) + ".") if behind else (
        "Where we are behind: nowhere on these rows; note OMPL runs a Python validity checker (its "
        "C++ core waits on Python callbacks), which is how a Python user meets it.")
    md = [f"## LSD planner speed", "", f"Command: `{cmd.strip()}`  ", f"Date: {date}  ",
          "Machine: 2-core CPU (shared, noisy)", "", table, ""]
    if ours_len:
        md.append(f"Mean path length where both found a path ({both} of {args.maps} maps): jaxsem "
                  f"{np.mean(ours_len):.2f} m, OMPL {np.mean(om_len):.2f} m (N = {args.n}, k = 10).")
        md.append("")
    if net_note:
        md += [net_note, ""]
    md.append(summary)
    (out / "lsd_speed.md").write_text("\n".join(md) + "\n")
    print(summary)


if __name__ == "__main__":
    main()

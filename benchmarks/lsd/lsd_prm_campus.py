"""Benchmark: jaxsem's PRM against OMPL's PRM (C++ core, compiled grid checker) on the campus map.

Issue 25 item 5. The map: MRPT's ``2006-MalagaCampus.gridmap.gz`` (151 x 219 m, read with
:func:`jaxsem.planning.load_map`; unknown cells are obstacles). At each N the planners take
turns, repeat after repeat, in one run:

- ``ompl_grid``: OMPL's ``PRM`` (libompl-dev, k = 10) in C++ with a compiled validity checker
  that reads the grid (``benchmarks/lsd/ompl_grid_prm.cpp``, built here with g++): ``growRoadmap``
  to exactly N milestones, then per query the start and goal linked to their 10 nearest
  milestones with ``checkMotion`` (half a cell) and Dijkstra. OMPL's Python bindings have no
  compiled grid checker; this is the strongest OMPL configuration a user can run on a grid. Its
  clock runs inside the process (map parsing and process start excluded).
- ``jaxsem``: :class:`jaxsem.planning.PRM` under its defaults (k = prm_star_k(N), 8 direction
  sectors, default radius), constructed + ``grow(N)`` + first ``query``; ``jaxsem_reuse``: each
  later query on that roadmap. ``--lazy``: also the defaults with ``lazy=True`` (Lazy PRM: the
  grow checks no edge, a query checks those its shortest path needs; the same roadmap and
  shortest paths), in its own rows. ``jaxsem_batch``: ``PRM.query_many`` of ``--batch`` queries
  (the tasks repeated) in one call on that roadmap, per query (each batch first on a fresh
  roadmap of the same seed, so a lazy roadmap has checked nothing beyond its first query; its
  paths' lengths are compared with the single queries', ``batch_differ`` in the JSON rows).
  ``--fast-k K``: also a faster configuration (k = K, the default
  radius times ``--fast-radius-factor``), timed in the same run and reported in its own rows
  beside the defaults (never in their place).

The PRM keeps per-map setup (sampling aids, clearance table) for the latest maps
(:func:`jaxsem.planning.clear_map_cache`), so a repeated build on one map costs less than the first
one on a new map: each jaxsem configuration is timed both ways, in turn, every repeat: "first
build" with the cache cleared first (what a fresh user pays), then "build" on the same map again.

Queries: start and goal in free cells with at least 0.3 m clearance, at least 20 m apart and
connected; C* the 8-connected grid shortest path (metres). Timings: medians after a warm-up
(``block_until_ready``).

    python benchmarks/lsd/lsd_prm_campus.py --n 5000 20000 --repeats 3 --tasks 6 --seed 1000
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
import numpy as np
import scipy.ndimage
import scipy.sparse
import scipy.sparse.csgraph

from jaxsem import planning
from jaxsem.planning._roadmap import default_radius  # layers: white-box

HERE = pathlib.Path(__file__).resolve().parent
BENCH = HERE.parent  # benchmarks/: the shared results folder and _harness
RESULTS = BENCH / "results"
MAP = "data/mrpt/2006-MalagaCampus.gridmap.gz"  # where `jaxsem data fetch maps --out data` puts it


def build_ompl(out: pathlib.Path) -> pathlib.Path:
    exe = out / "ompl_grid_prm"
    src = HERE / "ompl_grid_prm.cpp"
    if not exe.exists() or exe.stat().st_mtime < src.stat().st_mtime:
        inc = sorted(pathlib.Path("/usr/include").glob("ompl-*"))
        if not inc:
            raise SystemExit("OMPL headers not found: apt-get install libompl-dev")
        cmd = ["g++", "-O2", "-std=c++17", f"-I{inc[-1]}", "-I/usr/include/eigen3", str(src), "-o", str(exe), "-lompl"]
        subprocess.run(cmd, check=True)
    return exe


def grid_graph(occ, res):
    H, W = occ.shape
    idx = np.arange(H * W).reshape(H, W)
    src, dst, w = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = occ[: H - dr, max(0, -dc) : W - max(0, dc)]
        b = occ[dr:, max(0, dc) : W + min(0, dc) if dc < 0 else W][:, : a.shape[1]]
        ok = ~a & ~b
        ia = idx[: H - dr, max(0, -dc) : W - max(0, dc)][ok]
        ib = idx[dr:, max(0, dc) :][:, : a.shape[1]][ok] if dc >= 0 else idx[dr:, : W + dc][ok]
        src.append(ia)
        dst.append(ib)
        w.append(np.full(len(ia), res * (np.sqrt(2) if dr and dc else 1.0)))
    src, dst, w = map(np.concatenate, (src, dst, w))
    return scipy.sparse.csr_matrix((w, (src, dst)), shape=(H * W, H * W))


def sample_queries(b, count, seed, clearance=0.3, min_dist=20.0, max_dist=float("inf")):
    occ, res = b.occupancy, b.resolution
    H, W = occ.shape
    ok = scipy.ndimage.distance_transform_edt(~np.pad(occ, 1, constant_values=True))[1:-1, 1:-1] * res >= clearance
    cells = np.argwhere(ok)
    rng = np.random.default_rng(seed)
    g = grid_graph(occ, res)
    out = []
    while len(out) < count:
        s, t = cells[rng.integers(len(cells))], cells[rng.integers(len(cells))]
        ps, pt = b.origin + (s[::-1] + 0.5) * res, b.origin + (t[::-1] + 0.5) * res
        if not min_dist <= np.linalg.norm(ps - pt) <= max_dist:
            continue
        d = scipy.sparse.csgraph.dijkstra(g, directed=False, indices=int(s[0] * W + s[1]), limit=np.inf)
        c = d[t[0] * W + t[1]]
        if np.isfinite(c):
            out.append((ps, pt, float(c)))
    return out


def run_ompl(exe, b, n, seed, queries, k=10):
    occ = b.occupancy
    H, W = occ.shape
    head = (
        f"{H} {W} {float(b.resolution)!r} {float(b.origin[0])!r} {float(b.origin[1])!r} {n} {k} {seed} {len(queries)}\n"
    )
    body = "\n".join("".join(r) for r in np.where(occ, "1", "0"))
    qs = "\n".join(" ".join(repr(float(v)) for v in (*s, *t)) for s, t, _ in queries)
    out = subprocess.run([str(exe)], input=head + body + "\n" + qs + "\n", capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", default=MAP)
    ap.add_argument("--n", type=int, nargs="+", default=[5000, 20000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tasks", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1000, help="query and roadmap seed (tuning: < 1000)")
    ap.add_argument("--batch", type=int, default=64, help="queries in one PRM.query_many call (0: none)")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--name", default="lsd_prm_campus")
    ap.add_argument(
        "--fast-k",
        type=int,
        default=0,
        help="also run a named faster jaxsem configuration with this k (0: defaults only); its rows say so",
    )
    ap.add_argument(
        "--lazy",
        action="store_true",
        help="also run the defaults with lazy=True (Lazy PRM: edges checked at query time), in their own rows",
    )
    ap.add_argument(
        "--fast-radius-factor",
        type=float,
        default=1.0,
        help="that configuration's radius: the default radius times this (rounded to 0.5 m)",
    )
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    exe = build_ompl(pathlib.Path("/tmp"))
    b = planning.load_map(args.map)
    tasks = sample_queries(b, args.tasks, args.seed)
    rows, recs = [], []
    free_cells = int(np.count_nonzero(~np.asarray(b.occupancy)))
    # Configurations: the PRM's defaults, and (--fast-k) a named faster one reported beside them.
    configs = {"jaxsem": None}
    if args.fast_k:
        configs["jaxsem_fast"] = args.fast_k
    if args.lazy:
        configs["jaxsem_lazy"] = True
    for n in args.n:
        t = {"ompl_grid": [], **{c: [] for c in configs}, **{f"{c}_reuse": [] for c in configs}}
        t.update({f"{c}_first": [] for c in configs})
        t.update({f"{c}_batch": [] for c in configs})
        differ = dict.fromkeys(configs, 0)  # batch paths whose length is not the single query's
        found = {"ompl_grid": [], **{c: [] for c in configs}}
        ratio = {"ompl_grid": [], **{c: [] for c in configs}}
        kw = {"jaxsem": {}, "jaxsem_lazy": {"lazy": True}}
        if args.fast_k:
            r = default_radius(n, b.occupancy.shape, b.resolution, free_cells=free_cells)
            kw["jaxsem_fast"] = {"k": args.fast_k, "radius": max(0.5, round(r * args.fast_radius_factor * 2) / 2)}

        def jaxsem_run(seed, c, fresh=False):
            if fresh:
                planning.clear_map_cache()
            t0 = time.perf_counter()
            prm = planning.PRM(b.occupancy, b, capacity=n, **kw[c])
            prm.grow(jax.random.PRNGKey(seed), n)
            p0 = prm.query(tasks[0][0], tasks[0][1])
            return time.perf_counter() - t0, prm, p0

        B = args.batch
        b_starts = np.array([tasks[i % len(tasks)][0] for i in range(B)])
        b_goals = np.array([tasks[i % len(tasks)][1] for i in range(B)])

        def batch_run(seed, c):
            """Per-query seconds of one query_many of B queries on a fresh roadmap (after its
            first query, as the single queries' roadmap), and the paths."""
            _, prm, _ = jaxsem_run(seed, c)
            t0 = time.perf_counter()
            paths = prm.query_many(b_starts, b_goals)
            return (time.perf_counter() - t0) / B, paths

        for c in configs:  # warm-up (compilation): a first build on a new map, then one on the same map
            jaxsem_run(args.seed + 999, c, fresh=True)
            _, prm, _ = jaxsem_run(args.seed + 999, c)
            for s, g, _ in tasks[1:]:
                prm.query(s, g)
            if B:
                batch_run(args.seed + 999, c)
        for rep in range(args.repeats):
            seed = args.seed + rep
            o = run_ompl(exe, b, n, seed, tasks)
            t["ompl_grid"].append(o["build_s"] + o["queries"][0]["query_s"])
            for ti in range(len(tasks)):
                oq = o["queries"][ti]
                found["ompl_grid"].append(oq["found"])
                ratio["ompl_grid"].append(oq["length"] / tasks[ti][2] if oq["found"] else np.nan)
            msg = f"N {n} rep {rep}: OMPL C++ grid {t['ompl_grid'][-1] * 1e3:.0f} ms"
            for c in configs:
                dt, _, _ = jaxsem_run(seed, c, fresh=True)
                t[f"{c}_first"].append(dt)
                dt, prm, p0 = jaxsem_run(seed, c)
                t[c].append(dt)
                lengths = {}
                msg += f", {c} {t[f'{c}_first'][-1] * 1e3:.0f} (first build) / {dt * 1e3:.0f} ms"
                for ti, (s, g, cstar) in enumerate(tasks):
                    if ti == 0:
                        p = p0
                    else:
                        t0 = time.perf_counter()
                        p = prm.query(s, g)
                        t[f"{c}_reuse"].append(time.perf_counter() - t0)
                    oq = o["queries"][ti]
                    found[c].append(bool(p.found))
                    ratio[c].append(p.length / cstar if p.found else np.nan)
                    recs.append(
                        {
                            "n": n,
                            "config": c,
                            "kwargs": kw[c],
                            "rep": rep,
                            "task": ti,
                            "c_star": cstar,
                            "ompl": oq["found"] and oq["length"],
                            "jaxsem": bool(p.found) and p.length,
                        }
                    )
                    lengths[ti] = p.length if p.found else np.inf
                if B:
                    dt, paths = batch_run(seed, c)
                    t[f"{c}_batch"].append(dt)
                    want = np.array([lengths[i % len(tasks)] for i in range(B)])
                    differ[c] += int(np.sum(np.where(paths.found, paths.length, np.inf) != want))
                    msg += f", batch {dt * 1e3:.2f} ms/query"
            print(msg, flush=True)
        for c in configs:
            both = np.array(found["ompl_grid"]) & np.array(found[c])
            med = {k: float(np.median(t[k])) * 1e3 for k in ("ompl_grid", c, f"{c}_reuse", f"{c}_first")}
            med[f"{c}_batch"] = float(np.median(t[f"{c}_batch"])) * 1e3 if t[f"{c}_batch"] else float("nan")
            rows.append(
                {
                    "n": n,
                    "config": c,
                    "kwargs": kw[c],
                    "queries": len(found[c]),
                    "found_ompl": int(np.sum(found["ompl_grid"])),
                    "found_jaxsem": int(np.sum(found[c])),
                    "both": int(both.sum()),
                    "len_ompl": float(np.mean(np.array(ratio["ompl_grid"])[both])) if both.any() else None,
                    "len_jaxsem": float(np.mean(np.array(ratio[c])[both])) if both.any() else None,
                    "ms": {
                        "ompl_grid": med["ompl_grid"],
                        "jaxsem": med[c],
                        "jaxsem_reuse": med[f"{c}_reuse"],
                        "jaxsem_first": med[f"{c}_first"],
                        "jaxsem_batch": med[f"{c}_batch"],
                    },
                    "batch": B,
                    "batch_differ": differ[c],
                }
            )
    table = [
        "| N | queries | found OMPL | found jaxsem | length / C* OMPL (both found) | jaxsem | OMPL C++ grid checker: "
        "build + query (ms) | jaxsem first build on a new map + query (ms) | / OMPL | jaxsem build + query, "
        "same map again (ms) | / OMPL | jaxsem per query, reused (ms) | jaxsem per query, batch of "
        f"{args.batch} in one call (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m = r["ms"]
        label = str(r["n"]) if r["config"] == "jaxsem" else f"{r['n']}, jaxsem {r['kwargs']}"
        table.append(
            f"| {label} | {r['queries']} | {r['found_ompl']} | {r['found_jaxsem']} | {r['len_ompl']:.3f} | "
            f"{r['len_jaxsem']:.3f} | {m['ompl_grid']:.0f} | {m['jaxsem_first']:.0f} | "
            f"{m['jaxsem_first'] / m['ompl_grid']:.2f} | {m['jaxsem']:.0f} | {m['jaxsem'] / m['ompl_grid']:.2f} | "
            f"{m['jaxsem_reuse']:.1f} | {m['jaxsem_batch']:.2f} |"
        )
    print("\n".join(table))
    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip()
    cmd = "python benchmarks/lsd/lsd_prm_campus.py " + " ".join(sys.argv[1:] if argv is None else argv)
    payload = {
        "command": cmd,
        "date": date,
        "platform": platform.platform(),
        "jax": jax.__version__,
        "args": vars(args),
        "rows": rows,
        "records": recs,
    }
    (out / f"{args.name}.json").write_text(json.dumps(payload, indent=1))
    md = [
        f"## PRM on the campus map against OMPL's C++ PRM with a grid checker (`{args.name}`)",
        "",
        f"Command: `{cmd}`  ",
        f"Date: {date}  ",
        "Machine: 2-core CPU, shared with other jobs (noisy)",
        "",
        *table,
        "",
    ]
    (out / f"{args.name}.md").write_text("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())

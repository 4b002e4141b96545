"""Benchmark: jaxsem's PRM against OMPL's PRM at equal N on the same grids, quality and speed.

One run, interleaved (for every map and N the configurations take turns, repeat after repeat):

- ``ompl_py``: OMPL ``PRM`` with a Python grid validity checker (what a Python user gets),
  motion checks at half-cell resolution, its default k = 10; ``growRoadmapPtc`` to exactly N
  milestones, then per query the start and goal linked to their 10 nearest milestones with
  ``checkMotion`` and the extracted graph searched with scipy Dijkstra.
- ``ompl_cpp``: the same with ``AllValidStateValidityChecker`` (OMPL's C++ core alone, checks
  nothing: a lower bound on its cost, not a planner for this map; timing only).
- ``jaxsem``: :class:`jaxsem.planning.PRM` built and queried (``grow`` N samples + ``query``).
- ``jaxsem_reuse``: per query on a roadmap built once (``query`` only; the roadmap is rechecked
  against the map only when it changes, which it does not here).

Quality: Inside-Inside tasks on test-family buildings with the full map known; success and path
length / C* (C* the soft-cost optimal path length) of the raw roadmap path (no smoothing),
where both planners found one. Timings are medians after a warm-up, ``block_until_ready``.

    python benchmarks/lsd/lsd_prm.py --maps 4 --tasks 6 --n 500 1000 5000 --repeats 3 --first-map 0
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

from jaxsem import planning
from jaxsem.planning._edges import polyline_clear  # layers: white-box
from jaxsem.planning._roadmap import DEFAULT_SECTORS, default_radius  # layers: white-box

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _ompl_peer import OmplPRM, ompl_version

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"


def _len_cell(mean, sem) -> str:
    """``mean +- sem`` of length / C*, or '-' where no query was solved by both planners."""
    if mean is None:
        return "-"
    return f"{mean:.3f}" if sem is None else f"{mean:+.3f} +- {sem:.3f}" if mean < 0 else f"{mean:.3f} +- {sem:.3f}"


def jaxsem_build(b, n, key, k, radius, sectors=DEFAULT_SECTORS):
    prm = planning.PRM(b.occupancy, b, capacity=n, k=k, radius=radius, sectors=sectors)
    prm.grow(key, n)
    jax.block_until_ready(prm.roadmap)
    return prm


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--maps", type=int, default=4, help="test-family buildings")
    ap.add_argument("--first-map", type=int, default=0, help="seed of the first building")
    ap.add_argument("--tasks", type=int, default=6, help="Inside-Inside queries per map")
    ap.add_argument("--n", type=int, nargs="+", default=[500, 1000, 5000], help="roadmap sizes N")
    ap.add_argument("--repeats", type=int, default=3, help="roadmaps per (map, N) and planner")
    ap.add_argument(
        "--k",
        type=int,
        default=None,
        help="jaxsem neighbours per vertex (default: planning.prm_star_k(N); OMPL: its default 10)",
    )
    ap.add_argument(
        "--radius-scale",
        type=float,
        default=None,
        help="jaxsem radius = this x mean spacing (default: planning.default_radius)",
    )
    ap.add_argument(
        "--sectors",
        type=int,
        default=DEFAULT_SECTORS,
        help="jaxsem connection policy: direction sectors (0: the plain k nearest)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--name", default="lsd_prm")
    args = ap.parse_args(argv)

    from jaxsem.cli import enable_compilation_cache

    enable_compilation_cache()
    buildings = [planning.generate_building(s, "test") for s in range(args.first_map, args.first_map + args.maps)]
    recs = []
    times = {(c, n): [] for c in ("ompl_py", "ompl_cpp", "jaxsem", "jaxsem_reuse") for n in args.n}
    for b in buildings:
        tasks = planning.sample_tasks(b, "II", args.tasks, seed=args.seed)
        for n in args.n:
            if args.radius_scale is None:
                radius = default_radius(n, b.shape, b.resolution)
            else:
                area = b.shape[0] * b.shape[1] * b.resolution**2
                radius = float(np.ceil(2 * args.radius_scale * np.sqrt(area / n)) / 2)
            jaxsem_build(b, n, jax.random.PRNGKey(10_000), args.k, radius, args.sectors).query(
                tasks[0].start, tasks[0].goal
            )
            for rep in range(args.repeats):
                seed = args.seed * 1000 + rep
                om = OmplPRM(b, n, seed=seed)
                oc = OmplPRM(b, n, trivial=True, seed=seed)
                t0 = time.perf_counter()
                prm = jaxsem_build(b, n, jax.random.PRNGKey(seed), args.k, radius, args.sectors)
                t_build = time.perf_counter() - t0
                for ti, task in enumerate(tasks):
                    t_oq, o_found, o_len, o_path = om.query(task.start, task.goal)
                    t_cq = oc.query(task.start, task.goal)[0]
                    t0 = time.perf_counter()
                    p = prm.query(task.start, task.goal)
                    t_q = time.perf_counter() - t0
                    if ti == 0:  # build + first query
                        times[("jaxsem", n)].append(t_build + t_q)
                        times[("ompl_cpp", n)].append(oc.build_s + t_cq)
                        times[("ompl_py", n)].append(om.build_s + t_oq)
                    else:  # later queries reuse the roadmap (and its cached edge list)
                        times[("jaxsem_reuse", n)].append(t_q)
                    recs.append(
                        {
                            "building": b.seed,
                            "n": n,
                            "rep": rep,
                            "task": ti,
                            "c_star": task.c_star,
                            "ompl": {
                                "found": o_found,
                                "length": o_len,
                                "query_s": t_oq,
                                # does OMPL's path (half-cell point checks) pass jaxsem's edge
                                # rule (no occupied cell touched, diagonal side cells included)?
                                "passes_jaxsem_rule": bool(o_found and polyline_clear(o_path, b.occupancy, b, radius)),
                            },
                            "jaxsem": {
                                "found": bool(p.found),
                                "length": p.length,
                                "query_s": t_q,
                            },
                        }
                    )
                print(
                    f"building {b.seed} N {n} rep {rep}: OMPL-py build {om.build_s * 1e3:.0f} ms, "
                    f"OMPL-C++ {oc.build_s * 1e3:.0f} ms, jaxsem build+query {times[('jaxsem', n)][-1] * 1e3:.1f} ms, "
                    f"reuse query {np.median(times[('jaxsem_reuse', n)][-len(tasks) + 1 :]) * 1e3:.2f} ms",
                    flush=True,
                )

    rows = []
    for n in args.n:
        rs = [r for r in recs if r["n"] == n]
        of = np.array([r["ompl"]["found"] for r in rs])
        jf = np.array([r["jaxsem"]["found"] for r in rs])
        both = of & jf
        strict = np.array([r["ompl"].get("passes_jaxsem_rule", False) for r in rs])
        ol = np.array([r["ompl"]["length"] / r["c_star"] for r in rs])[both]
        jl = np.array([r["jaxsem"]["length"] / r["c_star"] for r in rs])[both]
        fair = both & strict  # OMPL's path valid under jaxsem's stricter rule too
        ols = np.array([r["ompl"]["length"] / r["c_star"] for r in rs])[fair]
        jls = np.array([r["jaxsem"]["length"] / r["c_star"] for r in rs])[fair]
        med = {c: float(np.median(times[(c, n)])) for c in ("ompl_py", "ompl_cpp", "jaxsem", "jaxsem_reuse")}
        rows.append(
            {
                "n": n,
                "queries": len(rs),
                "found_ompl": int(of.sum()),
                "found_jaxsem": int(jf.sum()),
                "ompl_passing_jaxsem_rule": int(strict.sum()),
                "both": int(both.sum()),
                "len_ompl": float(ol.mean()) if both.any() else None,
                "len_jaxsem": float(jl.mean()) if both.any() else None,
                "len_sem_ompl": float(ol.std(ddof=1) / np.sqrt(len(ol))) if both.sum() > 1 else None,
                "len_sem_jaxsem": float(jl.std(ddof=1) / np.sqrt(len(jl))) if both.sum() > 1 else None,
                "both_same_rule": int(fair.sum()),
                "len_ompl_same_rule": float(ols.mean()) if fair.any() else None,
                "len_jaxsem_same_rule": float(jls.mean()) if fair.any() else None,
                "len_diff_same_rule": float((jls - ols).mean()) if fair.any() else None,
                "len_diff_sem_same_rule": float((jls - ols).std(ddof=1) / np.sqrt(fair.sum()))
                if fair.sum() > 1
                else None,
                "times_s": med,
            }
        )

    qual = [
        "| N | queries | found OMPL | of them passing jaxsem's edge rule | found jaxsem | both | length / C* OMPL | length / C* jaxsem "
        "| both, OMPL's path valid under jaxsem's rule | length / C* OMPL there | jaxsem there | paired jaxsem - OMPL |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        qual.append(
            f"| {r['n']} | {r['queries']} | {r['found_ompl']} | {r['ompl_passing_jaxsem_rule']} | {r['found_jaxsem']} | {r['both']} | "
            f"{_len_cell(r['len_ompl'], r['len_sem_ompl'])} | {_len_cell(r['len_jaxsem'], r['len_sem_jaxsem'])} | "
            f"{r['both_same_rule']} | {_len_cell(r['len_ompl_same_rule'], None)} | {_len_cell(r['len_jaxsem_same_rule'], None)} | "
            f"{_len_cell(r['len_diff_same_rule'], r['len_diff_sem_same_rule'])} |"
        )
    speed = [
        "| N | OMPL PRM, Python checker: build + query (ms) | OMPL C++ core, trivial checker: build + "
        "query (ms) | jaxsem build + query (ms) | jaxsem per query, roadmap reused (ms) | "
        "OMPL-py / jaxsem | OMPL-C++ / jaxsem | OMPL-C++ / jaxsem reuse |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        t = r["times_s"]
        speed.append(
            f"| {r['n']} | {t['ompl_py'] * 1e3:.1f} | {t['ompl_cpp'] * 1e3:.1f} | {t['jaxsem'] * 1e3:.1f} | "
            f"{t['jaxsem_reuse'] * 1e3:.2f} | {t['ompl_py'] / t['jaxsem']:.1f}x | "
            f"{t['ompl_cpp'] / t['jaxsem']:.2f}x | {t['ompl_cpp'] / t['jaxsem_reuse']:.1f}x |"
        )
    print("\n".join(qual))
    print("\n".join(speed))

    behind = []
    for r in rows:
        t = r["times_s"]
        if r["found_jaxsem"] < r["found_ompl"]:
            behind.append(f"N={r['n']}: jaxsem found {r['found_jaxsem']} paths to OMPL's {r['found_ompl']}")
        if r["len_jaxsem"] is not None and r["len_jaxsem"] > r["len_ompl"]:
            behind.append(f"N={r['n']}: length / C* {r['len_jaxsem']:.3f} vs OMPL {r['len_ompl']:.3f}")
        d, e = r["len_diff_same_rule"], r["len_diff_sem_same_rule"]
        if d is not None and d > 2 * (e or 0):
            behind.append(f"N={r['n']}: longer by {d:.3f} C* (> 2 s.e.m.) where both paths pass jaxsem's rule")
        if t["jaxsem"] > t["ompl_py"]:
            behind.append(f"N={r['n']}: build + query slower than OMPL with the Python checker")
        if t["jaxsem"] > t["ompl_cpp"]:
            behind.append(
                f"N={r['n']}: build + query {t['jaxsem'] / t['ompl_cpp']:.1f}x OMPL's C++ core with a "
                f"checker that checks nothing"
            )
        if t["jaxsem_reuse"] > t["ompl_cpp"]:
            behind.append(f"N={r['n']}: per query with reuse slower than OMPL's C++ core build")
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip()
    cmd = "python benchmarks/lsd/lsd_prm.py " + " ".join(sys.argv[1:] if argv is None else argv)
    payload = {
        "command": cmd,
        "date": date,
        "machine": "2-core CPU (shared with other jobs; noisy)",
        "platform": platform.platform(),
        "jax": jax.__version__,
        "args": vars(args),
        "rows": rows,
        "records": recs,
    }
    tmp = out / f"{args.name}.json.tmp"
    tmp.write_text(json.dumps(payload, indent=1))
    tmp.replace(out / f"{args.name}.json")
    md = [
        f"## LSD planner: PRM quality and speed against OMPL (`{args.name}`)",
        "",
        f"Command: `{cmd}`  ",
        f"Date: {date}  ",
        "Machine: 2-core CPU, shared with other jobs (noisy)",
        "",
        f"Test-family buildings {args.first_map}..{args.first_map + args.maps - 1}, full map known, "
        f"{args.tasks} Inside-Inside queries per map, {args.repeats} roadmaps per (map, N) and planner. jaxsem: "
        f"k = {args.k or 'prm_star_k(N) (26 / 29 / 35 at N = 500 / 1000 / 5000)'}, radius {'planning.default_radius' if args.radius_scale is None else f'{args.radius_scale} x spacing'}, "
        f"{'direction-first links over ' + str(args.sectors) + ' sectors (the default policy)' if args.sectors else 'the plain k nearest (sectors 0)'}, "
        "valid-state sampling, exact neighbour search; "
        f"OMPL {ompl_version()}: PRM, k = 10, growRoadmapPtc to N milestones. "
        "Length / C*: mean +- s.e.m. of the raw roadmap path over the soft-cost optimal length, on queries "
        "both solved. The validity rules differ: OMPL checks points half a cell apart, jaxsem's edge rule "
        "also forbids the side cells of a diagonal step (no occupied cell touched); the column 'passing "
        "jaxsem's edge rule' counts the OMPL paths that would be valid under it.",
        "",
        "### Quality at equal N",
        "",
        *qual,
        "",
        "### Speed (medians; each ratio names the OMPL configuration it is against)",
        "",
        *speed,
        "",
        "OMPL-C++ checks nothing (AllValidStateValidityChecker): the floor of its own cost, not a planner "
        "for these maps; jaxsem checks every vertex and edge against the grid in every row.",
        "",
        "Where we are behind: " + ("; ".join(behind) if behind else "nowhere on these rows") + ".",
        "",
    ]
    tmp = out / f"{args.name}.md.tmp"
    tmp.write_text("\n".join(md))
    tmp.replace(out / f"{args.name}.md")
    print(md[-2])
    return 0


if __name__ == "__main__":
    sys.exit(main())

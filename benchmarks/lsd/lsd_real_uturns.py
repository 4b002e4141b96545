"""Benchmark: where an ``lsd_real`` row's detours come from: U-turns in the driven paths.

Under the library's defaults the uniform planner reuses its roadmap and keeps its route until the
route is blocked, while a learned sampler draws a fresh roadmap from its moving window at every
replan (every ``replan_every`` steps, thesis 3.2.5). A fresh roadmap can send the robot back the
way it came. This script counts, in each driven path of ``lsd_real.py`` records, the *U-turns*:
places where the heading over ``--window`` steps turns by more than ``--angle`` degrees (a dead
end reached, or a route given up). Per row, over the tasks both planners solved, it gives both
planners' mean U-turns, and for each task where either drove more than ``--detour`` times C*
both planners' C/C* and U-turns, so a reader can tell dead ends (both turn) from dithering
(only one turns, on a task the other drove near C*).

    python benchmarks/lsd/lsd_real_uturns.py --json benchmarks/results/lsd_real_campus_defaults_ii_shipped_s1004.json \\
        --out benchmarks/results/lsd_real_uturns_campus_s1004.json
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

REASONS = ("replans_blocked", "replans_periodic")  # the record keys of jaxsem.lsd's trial runner


def uturns(path, window: int = 4, angle: float = 150.0) -> int:
    """U-turns of a driven ``(T, 2)`` polyline: heading changes over ``window`` steps above
    ``angle`` degrees, each counted once (the scan skips ``2 * window`` steps after one)."""
    p = np.asarray(path, np.float64).reshape(-1, 2)
    if len(p) < 2 * window + 2:
        return 0
    d = p[window:] - p[:-window]
    moving = np.hypot(d[:, 0], d[:, 1]) > 1e-9
    h = np.arctan2(d[:, 1], d[:, 0])
    limit = np.deg2rad(angle)
    count, i = 0, 0
    while i + window < len(h):
        turn = abs((h[i + window] - h[i] + np.pi) % (2 * np.pi) - np.pi)
        if moving[i] and moving[i + window] and turn > limit:
            count += 1
            i += 2 * window
        else:
            i += 1
    return count


def _parse(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", required=True, nargs="+", help="lsd_real.py outputs (their records lie beside them)")
    p.add_argument("--out", required=True, help="output JSON (a Markdown table is printed)")
    p.add_argument("--window", type=int, default=4, help="steps over which the heading is compared")
    p.add_argument("--angle", type=float, default=150.0, help="degrees of turn that count as a U-turn")
    p.add_argument("--detour", type=float, default=2.0, help="C/C* above which a task is listed")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = _parse(argv)
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    from lsd_real_floor import read_runs

    runs = [(f, records) for f, _, records in read_runs(args.json, "lsd_real_uturns", need_command=False)]
    if args.window < 1 or not 90.0 <= args.angle <= 180.0:
        raise SystemExit("lsd_real_uturns: --window: expected >= 1 and --angle in [90, 180]")

    from jaxsem.lsd import read_records
    from jaxsem.scripting import atomic_write_text

    out = {"command": "python benchmarks/lsd/lsd_real_uturns.py " + " ".join(argv or sys.argv[1:]), "rows": []}
    lines = [
        "| run | row | mutual | U-turns uniform / LSD (mean) | replans blocked / periodic: uniform; LSD (mean) "
        "| detours: task (C_b/C*, U-turns; C_l/C*, U-turns) |",
        "|---|---|---|---|---|---|",
    ]
    for f, records in runs:
        rows: dict = {}
        why: dict = {}
        for r in read_records(records):
            u, lsd = r["uniform"], r["lsd"]
            if not (u["success"] and lsd["success"]):
                continue
            key = f"{r['set']}-{r['n']}"
            cu, cl = u["cost"] / r["c_star"], lsd["cost"] / r["c_star"]
            tu, tl = uturns(u["path"], args.window, args.angle), uturns(lsd["path"], args.window, args.angle)
            rows.setdefault(key, []).append((int(r["trial"]), cu, tu, cl, tl))
            # why each planner replanned (records written before the counts existed lack them)
            why.setdefault(key, []).append([x.get(k, np.nan) for x in (u, lsd) for k in REASONS])
        for key, t in rows.items():
            a = np.array(t, np.float64)
            w = np.array(why[key], np.float64).mean(axis=0)
            replans = {
                f"{k}_{p}": (None if np.isnan(v) else float(v))
                for (p, k), v in zip([(p, k) for p in ("uniform", "lsd") for k in REASONS], w)
            }
            detours = [x for x in t if max(x[1], x[3]) > args.detour]
            row = {
                "run": f.stem,
                "row": key,
                "mutual": len(t),
                "uturns_uniform": float(a[:, 2].mean()),
                "uturns_lsd": float(a[:, 4].mean()),
                **replans,
                "detours": [
                    {"trial": i, "cb_over_cstar": cu, "uturns_uniform": tu, "cl_over_cstar": cl, "uturns_lsd": tl}
                    for i, cu, tu, cl, tl in detours
                ],
            }
            out["rows"].append(row)
            listed = "; ".join(f"{i} ({cu:.2f}, {tu}; {cl:.2f}, {tl})" for i, cu, tu, cl, tl in detours)
            rp = "n/a" if np.isnan(w).any() else f"{w[0]:.1f} / {w[1]:.1f}; {w[2]:.1f} / {w[3]:.1f}"
            lines.append(
                f"| {f.stem} | {key} | {len(t)} | {row['uturns_uniform']:.2f} / {row['uturns_lsd']:.2f} | {rp} | {listed} |"
            )
    print("\n".join(lines))
    atomic_write_text(pathlib.Path(args.out), json.dumps(out, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

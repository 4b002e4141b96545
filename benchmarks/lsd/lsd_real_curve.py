"""Figure 3-8 on a real map: success against N for both planners, from ``lsd_real.py`` results.

Several result files of the same map and protocol (different ``--n``, a ``--uniform-only`` run at
a large N, or other task seeds) are pooled by (set, N), their trials together:

    python benchmarks/lsd/lsd_real_curve.py --json benchmarks/results/lsd_real_campus_thesis_*_s1000.json \\
        --title "campus, thesis protocol" --out benchmarks/results/lsd_real_campus_curve.png
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", nargs="+", required=True, help="lsd_real.py result files")
    p.add_argument("--title", default="")
    p.add_argument("--out", required=True, help="PNG")
    args = p.parse_args(argv)
    rows: dict = {}
    for f in args.json:
        try:
            d = json.loads(pathlib.Path(f).read_text())
        except (OSError, ValueError) as exc:
            raise SystemExit(f"lsd_real_curve: --json: cannot read {f!r} ({type(exc).__name__})") from None
        for row in d.get("summary", {}).values():
            key = (row["set"], int(row["n"]))
            for planner in ("uniform", "lsd"):
                if f"success_{planner}" in row:
                    # Files of other task seeds at the same (set, N) pool their trials.
                    done, trials = rows.setdefault(key, {}).get(planner, (0.0, 0))
                    t = int(row["trials"])
                    rows[key][planner] = ((done * trials + row[f"success_{planner}"] * t) / (trials + t), trials + t)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = sorted({k[0] for k in rows})
    fig, axes = plt.subplots(1, len(sets), figsize=(4.5 * len(sets), 3.6), dpi=110, squeeze=False)
    for ax, kind in zip(axes[0], sets):
        for planner, style in (("uniform", "s--"), ("lsd", "o-")):
            pts = sorted((n, v[planner]) for (k, n), v in rows.items() if k == kind and planner in v)
            if pts:
                ax.plot([n for n, _ in pts], [100 * s for _, (s, _) in pts], style, label=f"PRM + {planner}")
                for n, (s, t) in pts:
                    ax.annotate(f"{t}", (n, 100 * s), fontsize=6, xytext=(2, 2), textcoords="offset points")
        ax.set_xscale("log")
        ns = sorted({n for (k, n) in rows if k == kind})
        ax.set_xticks(ns, [str(n) for n in ns])  # the budgets run, not log-scale decades
        ax.minorticks_off()
        ax.set_ylim(0, 105)
        ax.set_xlabel("samples N")
        ax.set_ylabel("success (%)")
        ax.set_title(f"{kind} {args.title}".strip(), fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    from jaxsem.scripting import atomic_savefig

    out = atomic_savefig(fig, args.out)
    plt.close(fig)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

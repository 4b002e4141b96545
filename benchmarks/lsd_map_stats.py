"""Benchmark: do the generated buildings look like the real maps? Free-space widths side by side.

The LSD network was trained on the generator's buildings (``planning.generate_building``, train
family). Issue 25 item 4 asks whether the generator's statistics cover the real maps'. This
script measures, on generated buildings and on real maps read with ``planning.load_map`` (0.1 m
cells), the width of the free space along its medial ridge (twice the distance to the nearest
obstacle at cells where that distance is a local maximum: a corridor's or a doorway's width, a
room's narrower side) and the share of free space in passages narrower than 1.2 m, and draws the
width distributions in one figure.

    python benchmarks/lsd_map_stats.py --maps DATA/mrpt/2006-MalagaCampus.gridmap.gz \\
        --houses DATA/hm3d/hm3d_*.png --house-resolution 0.03 --json benchmarks/results/lsd_map_stats.json
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys


def ridge_widths(free, resolution: float):
    """Metres: the free space's width at its medial ridge cells (see the module docstring)."""
    import numpy as np
    import scipy.ndimage as ndi

    dt = np.asarray(ndi.distance_transform_edt(free), float)
    ridge = free & (dt >= ndi.maximum_filter(dt, size=3) - 0.5) & (dt > 1.0)
    return 2.0 * dt[ridge] * resolution


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maps", nargs="*", default=[], help="real maps (any load_map format)")
    p.add_argument("--houses", nargs="*", default=[], help="hatched house drawings (ir-sim HM3D)")
    p.add_argument("--house-resolution", type=float, default=0.03, help="metres per house pixel (assumed)")
    p.add_argument("--generated", type=int, default=12, help="generated buildings per family")
    p.add_argument("--json", required=True)
    args = p.parse_args(argv)
    for f in args.maps + args.houses:
        if not pathlib.Path(f).is_file():
            raise SystemExit(f"lsd_map_stats: no such map file {f!r}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from jaxsem import planning

    groups: dict = {}
    for family in ("train", "test"):
        ws = []
        for seed in range(args.generated):
            b = planning.generate_building(seed, family=family)
            ws.append(ridge_widths(~b.occupancy & b.indoor, b.resolution))
        groups[f"generated {family} ({args.generated})"] = np.concatenate(ws)
    for f in args.maps:
        b = planning.load_map(f)
        groups[pathlib.Path(f).name.split(".")[0]] = ridge_widths(~b.occupancy & b.indoor, b.resolution)
    if args.houses:
        ws = []
        for f in args.houses:
            b = planning.load_map(f, resolution=args.house_resolution, hatch_px=12, footprint="none")
            ws.append(ridge_widths(~b.occupancy, b.resolution))
        groups[f"HM3D houses ({len(args.houses)}, {args.house_resolution} m/px)"] = np.concatenate(ws)
    stats = {}
    for name, w in groups.items():
        stats[name] = {
            "ridge_cells": int(w.size),
            "width_m_p10_p25_p50_p75": [float(np.percentile(w, q)) for q in (10, 25, 50, 75)],
            "share_narrower_than_1_2m": float(np.mean(w < 1.2)),
        }
        print(name, stats[name])
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    bins = np.arange(0.0, 6.01, 0.2)
    for name, w in groups.items():
        ax.hist(np.clip(w, 0, 6), bins=bins, density=True, histtype="step", linewidth=1.5, label=name)
    ax.set_xlabel("free-space width at the medial ridge (m)")
    ax.set_ylabel("density")
    ax.set_title("Passage widths: the LSD generator against real maps")
    ax.legend(fontsize=7)
    fig.tight_layout()
    from jaxsem.scripting import atomic_savefig, atomic_write_text

    out = pathlib.Path(args.json)
    png = atomic_savefig(fig, out.with_suffix(".png"))
    plt.close(fig)
    atomic_write_text(
        out,
        json.dumps(
            {
                "command": "python benchmarks/lsd_map_stats.py " + " ".join(argv or sys.argv[1:]),
                "stats": stats,
                "figure": str(png),
            },
            indent=1,
        ),
    )
    print(f"wrote {out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

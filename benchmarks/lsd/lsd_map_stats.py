"""Benchmark: do the generated buildings look like the real maps? Free-space widths side by side.

The LSD network was trained on the generator's buildings (``planning.generate_building``, train
family). Issue 25 item 4 asks whether the generator's statistics cover the real maps'. This
script measures, on generated buildings and on real maps read with ``planning.load_map`` (0.1 m
cells), the width of the free space along its medial ridge (twice the distance to the nearest
obstacle at cells where that distance is a local maximum: a corridor's or a doorway's width, a
room's narrower side) and the share of free space in passages narrower than 1.2 m, and draws the
width distributions in one figure. Two more statistics, measured the same way on every map:
*room size*, the areas of the free space's cores (cells at least 0.5 m from any obstacle,
4-connected components of at least 0.5 m^2: a room or hall without its narrow margins and
doorways), and *door spacing*, the distance from each chokepoint (a cluster of ridge cells
0.5-1.0 m wide: a doorway or a gap between furniture) to the nearest other one. ``--families``
picks the generated families (``house``: the house-like family, issue 25 item 4);
``--examples K`` also draws K buildings of ``--examples-family`` (house by default).

    python benchmarks/lsd/lsd_map_stats.py --maps DATA/mrpt/2006-MalagaCampus.gridmap.gz \\
        DATA/mrpt/uwb_ro-localization_demo_map.gridmap.gz --houses DATA/hm3d/hm3d_{1..9}.png \\
        --house-resolution 0.03 --examples 8 --json benchmarks/results/lsd_map_stats_house.json

    python benchmarks/lsd/lsd_map_stats.py --maps DATA/mrpt/2006-MalagaCampus.gridmap.gz \\
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


def room_areas(free, resolution: float):
    """m^2: the areas of the free space's cores (see the module docstring)."""
    import numpy as np
    import scipy.ndimage as ndi

    dt = np.asarray(ndi.distance_transform_edt(free), float) * resolution
    labels, n = ndi.label(dt >= 0.5)
    areas = np.bincount(labels.ravel(), minlength=n + 1)[1:] * resolution**2
    return areas[areas >= 0.5]


def door_spacing(free, resolution: float):
    """Metres from each chokepoint to the nearest other one (see the module docstring)."""
    import numpy as np
    import scipy.ndimage as ndi

    dt = np.asarray(ndi.distance_transform_edt(free), float)
    ridge = free & (dt >= ndi.maximum_filter(dt, size=3) - 0.5) & (dt > 1.0)
    width = 2.0 * dt * resolution
    choke = ridge & (width >= 0.5) & (width <= 1.0)
    labels, n = ndi.label(choke, np.ones((3, 3), bool))
    if n < 2:
        return np.zeros(0)
    pts = np.asarray(ndi.center_of_mass(choke, labels, np.arange(1, n + 1))) * resolution
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def _measure(free, resolution: float) -> dict:
    return {
        "width": ridge_widths(free, resolution),
        "room": room_areas(free, resolution),
        "door": door_spacing(free, resolution),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maps", nargs="*", default=[], help="real maps (any load_map format)")
    p.add_argument("--houses", nargs="*", default=[], help="hatched house drawings (ir-sim HM3D)")
    p.add_argument("--house-resolution", type=float, default=0.03, help="metres per house pixel (assumed)")
    p.add_argument("--generated", type=int, default=12, help="generated buildings per family")
    p.add_argument("--families", nargs="*", default=["train", "test", "house"], help="generated families to measure")
    p.add_argument(
        "--examples", type=int, default=0, help="draw this many generated buildings (<json stem>_examples.png)"
    )
    p.add_argument(
        "--examples-family", default="house", choices=("train", "test", "house", "campus"), help="their family"
    )
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
    for family in args.families:
        ms = []
        for seed in range(args.generated):
            b = planning.generate_building(seed, family=family)
            ms.append(_measure(~b.occupancy & b.indoor, b.resolution))
        groups[f"generated {family} ({args.generated})"] = {k: np.concatenate([m[k] for m in ms]) for k in ms[0]}
    for f in args.maps:
        b = planning.load_map(f)
        groups[pathlib.Path(f).name.split(".")[0]] = _measure(~b.occupancy & b.indoor, b.resolution)
    if args.houses:
        ms = []
        for f in args.houses:
            b = planning.load_map(f, resolution=args.house_resolution, hatch_px=12, footprint="none")
            ms.append(_measure(~b.occupancy, b.resolution))
        name = f"HM3D houses ({len(args.houses)}, {args.house_resolution} m/px)"
        groups[name] = {k: np.concatenate([m[k] for m in ms]) for k in ms[0]}
    stats = {}
    q = (10, 25, 50, 75, 90)
    for name, g in groups.items():
        w = g["width"]
        stats[name] = {
            "ridge_cells": int(w.size),
            "width_m_p10_p25_p50_p75": [float(np.percentile(w, v)) for v in (10, 25, 50, 75)],
            "share_narrower_than_1_2m": float(np.mean(w < 1.2)),
            "rooms": int(g["room"].size),
            "room_m2_p10_p25_p50_p75_p90": [float(np.percentile(g["room"], v)) for v in q] if g["room"].size else [],
            "chokepoints": int(g["door"].size),
            "door_spacing_m_p10_p25_p50_p75_p90": [float(np.percentile(g["door"], v)) for v in q]
            if g["door"].size
            else [],
        }
        print(name, stats[name])
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2), dpi=100)
    panels = (
        ("width", np.arange(0.0, 6.01, 0.2), 6.0, "free-space width at the medial ridge (m)", "Passage width"),
        ("room", np.linspace(0.0, 3.0, 31), None, "log10 room core area (m^2)", "Room size"),
        ("door", np.arange(0.0, 10.01, 0.5), 10.0, "chokepoint to nearest chokepoint (m)", "Door spacing"),
    )
    for ax, (key, bins, clip, xlabel, title) in zip(axes, panels):
        for name, g in groups.items():
            v = g[key]
            if v.size == 0:
                continue
            v = np.log10(np.maximum(v, 1.0)) if clip is None else np.clip(v, 0, clip)
            ax.hist(v, bins=bins, density=True, histtype="step", linewidth=1.5, label=name)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("density")
        ax.set_title(f"{title}: the LSD generator against real maps", fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    from jaxsem.scripting import atomic_savefig, atomic_write_text

    out = pathlib.Path(args.json)
    png = atomic_savefig(fig, out.with_suffix(".png"))
    plt.close(fig)
    atomic_write_text(
        out,
        json.dumps(
            {
                "command": "python benchmarks/lsd/lsd_map_stats.py " + " ".join(argv or sys.argv[1:]),
                "stats": stats,
                "figure": str(png),
            },
            indent=1,
        ),
    )
    if args.examples:
        atomic_savefig(
            _examples_figure(args.examples, plt, np, planning, args.examples_family),
            out.with_name(out.stem + "_examples.png"),
        )
    print(f"wrote {out} and {png}")
    return 0


def _examples_figure(count: int, plt, np, planning, family: str = "house"):
    """Generated buildings of ``family``: free white, obstacles black, unknown grey, doors green,
    windows blue (ours, drawn by the generator: free to publish, unlike the HM3D drawings)."""
    cols = min(count, 4)
    rows = (count + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * rows), dpi=90, squeeze=False)
    for seed, ax in zip(range(count), axes.ravel()):
        b = planning.generate_building(seed, family=family)
        img = np.ones(b.shape + (3,))
        img[b.occupancy] = 0.0
        if b.known is not None:
            img[~b.known] = 0.6
        img[b.semantic == planning.DOOR] = (0.1, 0.75, 0.1)
        img[b.semantic == planning.WINDOW] = (0.2, 0.5, 1.0)
        free = (~b.occupancy & b.indoor).sum() * b.resolution**2
        ax.imshow(img, origin="lower", extent=(0, b.shape[1] * b.resolution, 0, b.shape[0] * b.resolution))
        ax.set_title(f"{family} {seed}: {free:.0f} m^2 of free floor", fontsize=9)
    for ax in axes.ravel()[count:]:
        ax.axis("off")
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    sys.exit(main())

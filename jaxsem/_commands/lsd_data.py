"""Generates the LSD expert dataset (thesis 3.3.2) as compressed npz shards, one per building.

    python infer/make_expert_data.py --out out/lsd_expert --family train --buildings 20 \\
        --samples-per-building 200 --workers 2

The shard schema is documented in ``jaxsem.lsd.EXPERT_SCHEMA`` (and ``schema.json`` in the
output folder). Existing shards are kept, so an interrupted run resumes. A figure of a few
samples (partial maps, expert path, goal direction) is saved as ``samples.png``. The run
directory (``--run-dir``) gets config.json and summary.json (shards, samples, samples per second,
the share of goals outdoors, the figure).

The same command: ``jaxsem lsd data`` (``python infer/make_expert_data.py``).
"""

from __future__ import annotations

import argparse
import pathlib
import time

from jaxsem import scripting as sc
from jaxsem.lsd import ExpertConfig

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.

# Convenience flags for ExpertConfig fields (help from the dataclass where it documents the field).
CONFIG_FLAGS = (
    sc.ConfigFlag("samples_per_building", type=sc.positive_int, help="expert samples per building"),
    sc.ConfigFlag("goals_per_moment", type=sc.positive_int, help="goals drawn at each sampling moment"),
    sc.ConfigFlag("sample_prob", type=sc.positive_probability, help="chance per step of a sampling moment"),
    sc.ConfigFlag("nav.n_samples", "--nav-samples", sc.positive_int, help="PRM samples of the navigating robot"),
)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    ap = sc.command_parser(prog, __doc__)
    ap.add_argument("--out", type=sc.output_dir, default="out/lsd_expert", help="output folder for the shards")
    ap.add_argument("--family", choices=("train", "test", "house", "campus"), default="train", help="building family")
    ap.add_argument("--buildings", type=sc.positive_int, default=20, help="number of buildings (seeds)")
    ap.add_argument("--first-seed", type=sc.nonnegative_int, default=0, help="seed of the first building")
    sc.add_config_flags(ap, ExpertConfig, CONFIG_FLAGS, base=ExpertConfig())
    ap.add_argument("--workers", type=sc.positive_int, default=2, help="processes (parallel over buildings)")
    ap.add_argument("--no-figure", action="store_true", help="do not draw samples.png")
    return ap


def main(argv=None, prog: str | None = None) -> int:
    args = build_parser(prog).parse_args(argv)
    from jaxsem import lsd

    cfg = sc.apply_config_flags(lsd.ExpertConfig(), args, CONFIG_FLAGS)
    seeds = range(args.first_seed, args.first_seed + args.buildings)
    t0 = time.perf_counter()
    paths = lsd.write_expert_dataset(args.out, args.family, seeds, cfg, workers=args.workers)
    data = lsd.load_expert_dataset(paths)
    n = len(data["context"])
    dt = time.perf_counter() - t0
    print(
        f"{len(paths)} shards, {n} samples in {args.out} ({dt:.1f} s, {n / max(dt, 1e-9):.1f} samples/s); "
        f"goals outdoors: {data['goal_outdoors'].mean():.0%}"
    )
    sc.record(
        shards=len(paths),
        samples=n,
        seconds=round(dt, 2),
        samples_per_second=round(n / max(dt, 1e-9), 2),
        goals_outdoors=float(data["goal_outdoors"].mean()) if n else None,
    )
    sc.record_output(*paths)
    if not args.no_figure and n:
        save_figure(data, pathlib.Path(args.out) / "samples.png")
    return 0


def save_figure(data, path, count=8):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    idx = np.linspace(0, len(data["context"]) - 1, min(count, len(data["context"]))).astype(int)
    fig, axes = plt.subplots(2, (len(idx) + 1) // 2, figsize=(3.2 * ((len(idx) + 1) // 2), 6.6))
    for ax, i in zip(np.ravel(axes), idx):
        img = np.full(data["occupancy"][i].shape + (3,), 0.65)
        img[data["occupancy"][i] == 0] = 1.0
        img[data["occupancy"][i] == 1] = 0.0
        for cls, colour in ((2, (0.1, 0.8, 0.1)), (3, (0.2, 0.5, 1.0)), (4, (0.9, 0.1, 0.9))):
            img[data["semantic"][i] == cls] = colour
        img[data["path_mask"][i]] = (0.9, 0.1, 0.1)
        ax.imshow(img, origin="lower")
        c = data["context"][i]
        k = img.shape[0] // 2
        ax.arrow(k, k, 40 * c[0], 40 * c[1], color="tab:blue", width=1.0)
        ax.set_title(f"d={c[2] * 20:.1f} m, {'outdoors' if c[3] else 'indoors'}", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(
        "expert samples: partial occupancy (grey unknown), doors green, windows blue, "
        "exit signs magenta, expert path red, goal direction blue",
        fontsize=9,
    )
    fig.tight_layout()
    sc.atomic_savefig(fig, path, dpi=90)
    plt.close(fig)
    print(f"figure: {path}")

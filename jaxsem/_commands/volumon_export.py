"""Export a VoluMon training run as the shipped model (weights, config, learning-curve figure).

    python train/export_volumon.py --workdir runs/vm_fast            # -> jaxsem/volumon/pretrained/
    python train/export_volumon.py --workdir runs/vm_fast --step 4000

Writes ``volumon_fast.npz`` (flax variables, float32), ``volumon_fast.json`` (config, step) and
``volumon_fast_curves.png`` (loss terms and held-out size / centre errors against the step, from
the run's ``metrics.jsonl``) atomically into ``--out``; the run directory (``--run-dir``) gets
config.json and summary.json (the exported files, the step, the size).

The same command: ``jaxsem volumon export`` (``python train/export_volumon.py``).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from jaxsem import scripting as sc

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument(
        "--workdir", type=sc.existing_dir, required=True, help="the training run (train/volumon.py --workdir)"
    )
    p.add_argument("--step", type=int, help="checkpoint step to export (default: the latest)")
    p.add_argument(
        "--out",
        type=sc.output_dir,
        help="folder for the model files (default: the package's pretrained folder)",
    )
    return p


def main(argv=None, prog: str | None = None) -> int:
    p = build_parser(prog)
    a = p.parse_args(argv)
    from jaxsem.volumon import PRETRAINED_DIR, export_pretrained

    out = pathlib.Path(a.out or PRETRAINED_DIR)
    try:
        path = export_pretrained(a.workdir, out, step=a.step)
    except ValueError as exc:
        if a.debug:
            raise
        sys.exit(f"error: --workdir: {exc}")
    _curves(a.workdir / "metrics.jsonl", out / "volumon_fast_curves.png")
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
    sc.record(model=str(path), megabytes=round(path.stat().st_size / 1e6, 3))
    sc.record_output(path, path.with_suffix(".json"))
    return 0


def _curves(metrics, png):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(x) for x in metrics.read_text().splitlines()]
    loss = [r for r in rows if "total" in r]
    ev = [r for r in rows if "eval" in r]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for k in ("dual", "primal", "size", "cls"):
        axes[0].semilogy([r["step"] for r in loss], [max(r[k], 1e-9) for r in loss], label=k)
    axes[0].set_title("training loss terms")
    axes[0].legend()
    st = [r["step"] for r in ev]
    axes[1].plot(
        st,
        [r["eval"]["median_size_rel_error"] for r in ev],
        marker="o",
        label="median size rel. error",
    )
    axes[1].plot(st, [r["eval"]["size_corr"] for r in ev], marker="o", label="size correlation")
    axes[1].axhline(0.25, color="gray", ls=":", lw=1)
    axes[1].axhline(0.6, color="gray", ls=":", lw=1)
    axes[1].set_title("held-out sizes (eval stream of the training seed)")
    axes[1].legend()
    axes[2].plot(
        st,
        [r["eval"]["median_center_error_m"] for r in ev],
        marker="o",
        label="median centre error (m)",
    )
    axes[2].plot(
        st,
        [r["eval"]["trans_auc"] / 10 for r in ev],
        marker="o",
        label="trans AUC / 10",
    )
    axes[2].set_title("held-out centre")
    axes[2].legend()
    sc.save_step_figure(fig, axes, png, dpi=80)

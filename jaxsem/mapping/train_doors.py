"""Train, score and export the VoluMon door model (thesis 5.8.1) on rendered building doors.

    python -m jaxsem.mapping.make_doors --out DATA --scenes 40 --frames-per-scene 50
    python -m jaxsem.mapping.make_doors --out DATA --scenes 4 --split val --frames-per-scene 25
    python -m jaxsem.mapping.train_doors --data DATA/train --eval-data DATA/val --workdir runs/door_dual
    python -m jaxsem.mapping.train_doors --data DATA/train --workdir runs/door_dual --score DATA/test
    python -m jaxsem.mapping.train_doors --data DATA/train --workdir runs/door_dual --export

A thin wrapper over :func:`jaxsem.mapping.train_door_model` with the ``door`` preset
(:func:`jaxsem.volumon._configs.door_config`; ``--variant dual`` is the thesis' Dual-Only, ``oracle`` the
fully supervised diagnostic). Re-running with the same ``--workdir`` resumes; ``--stop-after N``
trains N steps of this call (a chunk). ``--score DIR`` prints the door errors
(:func:`jaxsem.volumon.evaluate_doors`) of the workdir's latest checkpoint on DIR as JSON;
``--export`` writes the shipped ``volumon_door.npz`` / ``.json`` (and the learning-curve figure
``volumon_door_curves.png``) into ``--out`` (default: the package's pretrained folder).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from .. import scripting as sc
from ._doors import door_eval_batch, train_door_model

# Convenience flags for TrainConfig fields (type and help from the dataclass; --set reaches every field).
CONFIG_FLAGS = (
    sc.ConfigFlag("num_steps", "--steps", sc.positive_int),
    sc.ConfigFlag("learning_rate", "--lr", sc.positive_float),
    sc.ConfigFlag("batch_size", type=sc.positive_int),
    sc.ConfigFlag("seed"),
    sc.ConfigFlag("num_eval"),
)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=sc.HelpFormatter)
    p.add_argument("--data", type=sc.existing_dir, required=True, help="training doors (make_doors --split train)")
    p.add_argument("--workdir", type=sc.output_dir, required=True, help="run folder (an existing one resumes)")
    p.add_argument("--eval-data", type=sc.existing_dir, default=None, help="doors the periodic evaluation scores")
    p.add_argument("--variant", choices=("dual", "oracle"), default="dual", help="Dual-Only (thesis) or oracle")
    p.add_argument("--stop-after", type=sc.positive_int, default=None, help="steps of this call (a chunk)")
    from ..volumon import TrainConfig  # deferred: jaxsem.volumon is heavy; keeps this script's --help fast

    sc.add_config_flags(p, TrainConfig, CONFIG_FLAGS)
    sc.add_force_argument(p)
    p.add_argument("--score", type=sc.existing_dir, default=None, help="score the latest checkpoint on this directory")
    p.add_argument("--export", action="store_true", help="export the latest checkpoint as the shipped door model")
    p.add_argument("--out", type=sc.output_dir, default=None, help="--export folder (default: the package's)")
    p.add_argument(
        "--compare",
        type=sc.existing_dir,
        action="append",
        default=[],
        metavar="WORKDIR",
        help="--export: also draw this run's evaluation curve in the figure (repeatable)",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def main(argv=None) -> int:
    p = build_parser("python -m jaxsem.mapping.train_doors")
    a = p.parse_args(argv)
    # deferred: jaxsem.volumon is heavy; keeps this script's --help fast
    from ..volumon import PRETRAINED_DIR, evaluate_doors, export_pretrained, get_config, load_pretrained

    if a.score is not None or a.export:
        if not (a.workdir / "config.json").exists():
            p.error(f"--workdir: {a.workdir} is not a training run (no config.json)")
        model, variables, config, meta = load_pretrained(a.workdir)
        if a.score is not None:
            batch = door_eval_batch(a.score, config)
            res = {"step": meta["step"], "data": str(a.score), **evaluate_doors(model, variables, config, batch)}
            print(json.dumps(res, indent=1))
        if a.export:
            out = pathlib.Path(a.out or PRETRAINED_DIR)
            path = export_pretrained(a.workdir, out, name="volumon_door", extra={"data": str(a.data)})
            _curves(a.workdir / "metrics.jsonl", out / "volumon_door_curves.png", a.compare)
            print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
        return 0
    cfg = sc.apply_config_flags(get_config(a.variant, "door"), a, CONFIG_FLAGS)
    result = train_door_model(cfg, a.data, a.workdir, eval_data=a.eval_data, stop_after=a.stop_after, force=a.force)
    if result.get("eval") is not None:
        print(json.dumps(result["eval"], indent=1))
    _curves(a.workdir / "metrics.jsonl", a.workdir / "curves.png")
    return 0


def _eval_rows(metrics) -> list:
    rows = [json.loads(x) for x in pathlib.Path(metrics).read_text().splitlines() if x.strip()]
    return [r for r in rows if "eval" in r]


def _curves(metrics, png, compare=()):
    """Dual loss and held-out centre / size errors against the step (and the centre error of the
    ``compare`` workdirs' evaluations)."""
    import matplotlib  # deferred: matplotlib is optional (the sim extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)

    rows = [json.loads(x) for x in pathlib.Path(metrics).read_text().splitlines() if x.strip()]
    loss = [r for r in rows if "total" in r]
    ev = [r for r in rows if "eval" in r]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for k in ("total", "dual", "size"):
        if loss and k in loss[0] and any(r[k] > 0 for r in loss):  # a term switched off is left out
            axes[0].semilogy([r["step"] for r in loss], [max(r[k], 1e-9) for r in loss], label=k)
    axes[0].set_title("training loss")
    axes[0].legend()
    st = [r["step"] for r in ev]
    axes[1].plot(st, [r["eval"]["median_center_error_m"] for r in ev], marker="o", label="median centre error (m)")
    axes[1].plot(st, [r["eval"]["median_size_rel_error"] for r in ev], marker="o", label="median size rel. error")
    for other in compare:
        rows = _eval_rows(pathlib.Path(other) / "metrics.jsonl")
        name = pathlib.Path(other).name
        axes[1].plot(
            [r["step"] for r in rows],
            [r["eval"]["median_center_error_m"] for r in rows],
            ls="--",
            marker=".",
            label=f"{name}: median centre error (m)",
        )
    axes[1].set_title("periodic evaluation (val doors)")
    axes[1].legend()
    sc.save_step_figure(fig, axes, png, dpi=80)


if __name__ == "__main__":
    sys.exit(sc.run_main(main, prog="python -m jaxsem.mapping.train_doors"))

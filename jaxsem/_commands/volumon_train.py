"""Train VoluMon (thesis chapter 5) on the synthetic stereo set: a thin wrapper over
:func:`jaxsem.volumon.train_and_evaluate`.

Examples::

    python train/volumon.py --workdir runs/volumon_both                    # CPU config, Both
    python train/volumon.py --variant primal --steps 800 --workdir runs/p  # Primal only
    python train/volumon.py --size thesis --workdir runs/thesis            # 224x224, width 1.0 (GPU)

Re-running with the same ``--workdir`` resumes from the latest checkpoint. Writes
``metrics.jsonl``, ``eval.json``, ``config.json`` and ``loss.png`` into the workdir; the run
directory (``--run-dir``) gets this call's config.json (flags and the resolved training config)
and summary.json (the final evaluation, the figures).

The same command: ``jaxsem volumon train`` (``python train/volumon.py``).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
from typing import Any

from jaxsem import scripting as sc
from jaxsem.volumon import SIZES, VARIANTS, TrainConfig, get_config, train_and_evaluate

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.

NOT_RUN_DIR = ("workdir",)  # the workdir has its own config.json

# Convenience flags for TrainConfig fields (help from the dataclass; --set reaches every field).
CONFIG_FLAGS = (
    sc.ConfigFlag("num_steps", "--steps", sc.positive_int),
    sc.ConfigFlag("batch_size", type=sc.positive_int),
    sc.ConfigFlag("learning_rate", "--lr", sc.positive_float),
    sc.ConfigFlag("num_train", type=sc.positive_int),
    sc.ConfigFlag("seed"),
    sc.ConfigFlag("checkpoint_every", type=sc.positive_int),
    sc.ConfigFlag("eval_every"),
    sc.ConfigFlag("num_eval"),
)


def _size(text: str) -> str:
    """A preset name, or an existing .json file of config fields (checked before a run starts)."""
    if text in SIZES:
        return text
    if text.endswith(".json"):
        if not pathlib.Path(text).is_file():
            raise argparse.ArgumentTypeError(f"{text}: no such file")
        return text
    raise argparse.ArgumentTypeError(f"expected one of {list(SIZES)} or a .json file, got {text!r}")


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument(
        "--workdir",
        type=sc.output_dir,
        required=True,
        help="run folder: checkpoints, metrics.jsonl, eval.json, config.json, loss.png (an existing one resumes)",
    )
    p.add_argument(
        "--variant",
        choices=VARIANTS,
        default="both",
        help="training variant (thesis 5.5.1: Dual only, Primal only, Both, Both Noisy; oracle)",
    )
    p.add_argument(
        "--size",
        type=_size,
        default="fast",
        help=f"config preset ({', '.join(SIZES)}; fast: the shipped model's CPU preset) or a JSON file of "
        "TrainConfig fields over the default",
    )
    sc.add_force_argument(p)
    p.add_argument("--stop-after", type=sc.positive_int, help="stop after this many steps of this call (a chunk)")
    sc.add_config_flags(p, TrainConfig, CONFIG_FLAGS)
    p.add_argument(
        "--data",
        type=sc.existing_dir,
        help="train on a FAT-layout or make_synthetic directory (read by jaxsem.data) instead of the on-device "
        "generator (default: the generator)",
    )
    p.add_argument(
        "--eval-data",
        type=sc.existing_dir,
        help="with --data: directory whose objects the periodic evaluation scores (default: --data itself, a fit check)",
    )
    p.add_argument(
        "--init-from",
        metavar="MODEL",
        help="warm start a fresh run from a trained model of the same network ('object': the shipped object "
        "model, or a model path): every layer copied, each new class row from the source class of its shape "
        "(the shipped LM-O model started from 'object')",
    )
    sc.add_devices_argument(p)
    return p


def _warm_start(source: str, cfg):
    """Variables for ``--init-from``: the source model's, its class rows mapped by shape."""
    import numpy as np

    from jaxsem.volumon import SHAPE_IDS, load_pretrained, model_class_names, warm_start_variables

    from ..volumon.data import LMO_CLASS_SHAPES

    path = None if source in ("object", "door") else source
    _, variables, src_cfg, _ = load_pretrained(path, kind=source if path is None else "object")
    src_names = model_class_names(src_cfg)
    from jaxsem import classes

    src_shapes = [SHAPE_IDS[classes.get(n).shape] if n in classes.CLASS_NAMES else -1 for n in src_names]
    rows = []
    for name in cfg.class_names or ():
        want = LMO_CLASS_SHAPES.get(name, -2)
        rows.append(src_shapes.index(want) if want in src_shapes else 0)
    if not rows:
        rows = list(range(cfg.model.num_classes))
    return warm_start_variables(variables, cfg, np.asarray(rows) % int(src_cfg.model.num_classes))


def _loader_options(path) -> dict | None:
    """A door dataset (``python -m jaxsem.mapping.make_doors``) records its own stereo baseline;
    other directories use the reader's default."""
    if not any(pathlib.Path(path).rglob("_doors.json")):
        return None
    from ..mapping import door_data_baseline

    return {"baseline": door_data_baseline(path)}


def main(argv=None, prog: str | None = None) -> int:
    p = build_parser(prog)
    a = p.parse_args(argv)
    cfg = get_config(a.variant, a.size)
    cfg = sc.apply_config_flags(cfg, a, CONFIG_FLAGS)
    batch_fn = eval_batch = None
    if a.eval_data is not None and a.data is None:
        p.error("--eval-data: needs --data")
    if a.data is not None:
        cfg = cfg.replace(data="directory", data_dir=str(a.data.resolve()))
        from ..volumon.data import (
            desk_batch_source,
            desk_eval_batch,
            is_desk_detections,
            volumon_batch_source,
            volumon_eval_batch,
        )

        # class_names: e.g. the door preset's ("door",)
        sizes: dict[str, Any] = dict(cfg.data_sizes(), class_names=cfg.class_names or None)
        try:
            if is_desk_detections(a.data):  # rendered desk detections (python -m jaxsem.volumon.data.make_lmo_renders)
                batch_fn, n = desk_batch_source(a.data, batch_size=cfg.batch_size, seed=cfg.seed)
                if cfg.num_eval > 0:
                    eval_batch = desk_eval_batch(a.eval_data or a.data, num=cfg.num_eval)
            else:
                batch_fn, n = volumon_batch_source(
                    a.data, batch_size=cfg.batch_size, seed=cfg.seed, loader_options=_loader_options(a.data), **sizes
                )
                if cfg.num_eval > 0:
                    eval_dir = a.eval_data or a.data
                    eval_batch = volumon_eval_batch(
                        eval_dir, num=cfg.num_eval, loader_options=_loader_options(eval_dir), **sizes
                    )
        except (ValueError, OSError) as exc:
            if a.debug:
                raise
            sys.exit(f"error: {exc}")
        print(f"training on {n} objects of {a.data}", flush=True)
    init_variables = None
    if a.init_from is not None:
        try:
            init_variables = _warm_start(a.init_from, cfg)
        except ValueError as exc:
            if a.debug:
                raise
            sys.exit(f"error: --init-from: {exc}")
    mesh = sc.devices_mesh(a.devices, cfg.batch_size)
    sc.record_config(train_config=cfg)
    try:
        result = train_and_evaluate(
            cfg,
            a.workdir,
            log=lambda line: print(line, flush=True),
            force=a.force,
            stop_after=a.stop_after,
            progress=False,
            batch_fn=batch_fn,
            eval_batch=eval_batch,
            mesh=mesh,
            init_variables=init_variables,
        )
    except ValueError as exc:
        if a.debug:
            raise
        sys.exit(f"error: {exc}")
    if result["eval"] is not None:
        print(json.dumps(result["eval"], indent=1))
        sc.record(eval=result["eval"])
    _plot(a.workdir)
    sc.record_output(a.workdir)
    return 0


def _plot(workdir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recs = [json.loads(line) for line in (workdir / "metrics.jsonl").read_text().splitlines()]
    recs = [r for r in recs if "total" in r]
    if not recs:
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for k in ("total", "dual", "primal", "size"):
        ax.semilogy([r["step"] for r in recs], [max(r[k], 1e-12) for r in recs], label=k)
    ax.set_ylabel("loss")
    ax.legend()
    sc.save_step_figure(fig, [ax], workdir / "loss.png", dpi=100)

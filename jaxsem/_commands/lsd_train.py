"""Trains the LSD network in two stages on expert shards (thin wrapper over jaxsem.lsd).

Example:
    python infer/make_expert_data.py ...            # expert shards (jaxsem.planning)
    python train/lsd.py --data data/expert --workdir runs/lsd --config cpu
    python train/lsd.py --data data/expert --workdir runs/lsd --config cpu --stage1-steps 3000

Re-running with the same workdir resumes from its latest checkpoint; --chunk-steps K ends a run K
steps past it (run it in a loop to train in chunks, e.g. on data that is still being generated). Figures of predicted
distributions land in <workdir>/figures, metrics in <workdir>/metrics.jsonl.
The run directory (``--run-dir``) gets this call's config.json (flags and the resolved
TrainConfig) and summary.json (the last evaluation: step, stage, validation NLL against uniform;
the figures).

The same command: ``jaxsem lsd train`` (``python train/lsd.py``).
"""

from __future__ import annotations

import argparse
import pathlib

from jaxsem import scripting as sc
from jaxsem.lsd import PRESETS, TrainConfig

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.

NOT_RUN_DIR = ("workdir",)  # the workdir has its own config.json

# Convenience flags for TrainConfig fields (help from the dataclass; --set reaches every field).
CONFIG_FLAGS = (
    sc.ConfigFlag("stage1_steps", type=sc.nonnegative_int),
    sc.ConfigFlag("stage2_steps", type=sc.nonnegative_int),
    sc.ConfigFlag("batch_size", type=sc.positive_int),
    sc.ConfigFlag("learning_rate", type=sc.positive_float),
    sc.ConfigFlag("eval_every", type=sc.positive_int),
    sc.ConfigFlag("seed", type=sc.nonnegative_int),
)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument("--data", type=sc.existing_path, required=True, help="folder of expert_*.npz shards (or one shard)")
    p.add_argument("--workdir", type=sc.output_dir, required=True, help="checkpoints, figures, metrics")
    p.add_argument(
        "--config",
        default="default",
        help=f"a preset ({' | '.join(PRESETS.names)}) or a JSON file of TrainConfig fields",
    )
    sc.add_config_flags(p, TrainConfig, CONFIG_FLAGS)
    p.add_argument(
        "--chunk-steps",
        type=sc.positive_int,
        help="stop after this many steps past the latest checkpoint (a rerun resumes)",
    )
    sc.add_force_argument(p)
    sc.add_devices_argument(p)
    return p


def main(argv=None, prog: str | None = None) -> int:
    from jaxsem.lsd import get_config

    args = build_parser(prog).parse_args(argv)
    # Validate the inputs before any long work.
    if args.data.is_dir() and not any(args.data.glob("*.npz")):
        raise sc.UsageError(f"--data: {args.data}: no expert *.npz shards in this folder")

    from jaxsem.lsd import train_and_evaluate

    cfg = get_config(args.config)
    cfg = sc.apply_config_flags(cfg, args, CONFIG_FLAGS)
    mesh = sc.devices_mesh(args.devices, cfg.batch_size)
    sc.record_config(train_config=cfg)
    stop_at = None
    if args.chunk_steps is not None:
        from jaxsem.checkpoint import latest_step

        stop_at = (latest_step(pathlib.Path(args.workdir) / "checkpoints") or 0) + args.chunk_steps
    res = train_and_evaluate(cfg, args.workdir, data=args.data, stop_at=stop_at, force=args.force, log=print, mesh=mesh)
    for h in res.history:
        print(
            f"step {h['step']:6d} stage {h['stage']}: val NLL {h['val_nll']:.3f} "
            f"(uniform {h['uniform_nll']:.3f})  {h['figure']}"
        )
    if res.history:
        last = res.history[-1]
        sc.record(**{k: last[k] for k in ("step", "stage", "val_nll", "uniform_nll") if k in last})
    sc.record_output(*(h["figure"] for h in res.history if h.get("figure")))
    return 0

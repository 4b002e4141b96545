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
import dataclasses
import pathlib

from jaxsem import config as jcfg, scripting as sc

NOT_RUN_DIR = ("workdir",)  # the workdir has its own config.json


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument("--data", type=sc.existing_path, required=True, help="folder of expert_*.npz shards (or one shard)")
    p.add_argument("--workdir", type=sc.output_dir, required=True, help="checkpoints, figures, metrics")
    p.add_argument("--config", default="default", help="default | cpu | scale | tiny")
    p.add_argument("--stage1-steps", type=sc.nonnegative_int, default=None, help="override the config's stage-1 steps")
    p.add_argument("--stage2-steps", type=sc.nonnegative_int, default=None, help="override the config's stage-2 steps")
    p.add_argument("--batch-size", type=sc.positive_int, default=None, help="override the config's batch size")
    p.add_argument("--learning-rate", type=sc.positive_float, default=None, help="override the learning rate")
    p.add_argument("--eval-every", type=sc.positive_int, default=None, help="override the evaluation interval")
    p.add_argument("--seed", type=sc.nonnegative_int, default=None, help="override the seed")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any TrainConfig field by name (repeatable)",
    )
    p.add_argument(
        "--chunk-steps",
        type=sc.positive_int,
        default=None,
        help="stop after this many steps past the latest checkpoint (a rerun resumes)",
    )
    p.add_argument("--force", action="store_true", help="resume even if the config differs from the workdir's")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
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
    changes = {
        k: v
        for k, v in {
            "stage1_steps": args.stage1_steps,
            "stage2_steps": args.stage2_steps,
            "batch_size": args.batch_size,
            "learning_rate": args.learning_rate,
            "eval_every": args.eval_every,
            "seed": args.seed,
        }.items()
        if v is not None
    }
    cfg = jcfg.override(dataclasses.replace(cfg, **changes), args.overrides)
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

"""Scores the shipped VoluMon model (or a training run, --workdir) on held-out detections.

In: synthetic held-out detections of several classes drawn from --seed (a stream no training seed
uses), or the objects of a FAT-layout / make_synthetic directory (--data). Out: JSON figures
(median size and centre errors, size correlation, AUCs, per class) printed and, with --json,
written atomically.
"""

from __future__ import annotations

import argparse
import json
import pathlib

from jaxsem import scripting as sc


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=sc.HelpFormatter)
    p.add_argument("--seed", type=int, default=1, help="held-out seed (a stream no training seed uses)")
    p.add_argument("--num", type=int, default=256, help="number of detections")
    p.add_argument("--json", default=None, help="write the figures here (atomically)")
    p.add_argument("--workdir", default=None, help="a training run (config.json + checkpoints/) or a .npz model")
    p.add_argument("--postopt", type=int, default=0, help="also refine with PostOpt for this many steps")
    p.add_argument(
        "--data",
        default=None,
        help="score the objects of a FAT-layout or make_synthetic directory (the first --num) instead of "
        "synthetic held-out detections",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def main(argv=None, prog: str | None = None) -> int:
    """``jaxsem volumon eval``: held-out figures of the shipped model (or ``--workdir``) as JSON."""
    args = build_parser(prog).parse_args(argv)
    from jaxsem.cli import enable_compilation_cache
    from jaxsem.volumon import evaluate_held_out, load_pretrained

    if args.num < 1:
        raise SystemExit(f"jaxsem volumon eval: --num must be a positive number of detections, got {args.num}")
    if args.workdir is not None and not pathlib.Path(args.workdir).exists():
        raise SystemExit(f"jaxsem volumon eval: --workdir {args.workdir} does not exist")
    if args.data is not None and not pathlib.Path(args.data).is_dir():
        raise SystemExit(f"jaxsem volumon eval: --data {args.data} is not a directory")
    enable_compilation_cache()
    try:
        model, variables, config, meta = load_pretrained(args.workdir)
        batch = None
        if args.data is not None:
            from jaxsem.data import volumon_eval_batch

            batch = volumon_eval_batch(
                args.data,
                input_size=config.model.input_size,
                global_padding=config.model.global_padding,
                num_points=config.scene.num_points,
                num=args.num,
            )
        result = evaluate_held_out(
            model, variables, config, args.seed, args.num, postopt_steps=args.postopt, batch=batch
        )
    except ValueError as exc:
        if args.debug:
            raise
        raise SystemExit(f"jaxsem volumon eval: {exc}")
    result = {"model": str(meta.get("name")), "model_step": meta.get("step"), **result}
    text = json.dumps(result, indent=1)
    if args.json:
        out = pathlib.Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(text + "\n")
        tmp.replace(out)
    print(text)
    return 0

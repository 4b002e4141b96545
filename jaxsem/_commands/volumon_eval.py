"""Scores the shipped VoluMon model (or a training run, --workdir) on held-out detections.

In: synthetic held-out detections of several classes drawn from --seed (a stream no training seed
uses), or the objects of a FAT-layout / make_synthetic directory (--data). Out: JSON figures
(median size and centre errors, size correlation, AUCs, per class) printed, written atomically
with --json, and kept as the results of the run directory's summary.json.
"""

from __future__ import annotations

import argparse
import json

from jaxsem import scripting as sc


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument("--seed", type=int, default=1, help="held-out seed (a stream no training seed uses)")
    p.add_argument("--num", type=sc.positive_int, default=256, help="number of detections")
    p.add_argument("--json", type=sc.output_file, default=None, help="write the figures here (atomically)")
    p.add_argument(
        "--workdir",
        type=sc.existing_path,
        default=None,
        help="a training run (config.json + checkpoints/) or a .npz model (default: the shipped model)",
    )
    p.add_argument("--postopt", type=sc.nonnegative_int, default=0, help="also refine with PostOpt for this many steps")
    p.add_argument(
        "--data",
        type=sc.existing_dir,
        default=None,
        help="score the objects of a FAT-layout or make_synthetic directory (the first --num) instead of "
        "synthetic held-out detections",
    )
    return p


def main(argv=None, prog: str | None = None) -> int:
    """``jaxsem volumon eval``: held-out figures of the shipped model (or ``--workdir``) as JSON."""
    args = build_parser(prog).parse_args(argv)
    from jaxsem.volumon import evaluate_held_out, load_pretrained

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
        raise SystemExit(f"{prog or 'jaxsem volumon eval'}: {exc}")
    result = {"model": str(meta.get("name")), "model_step": meta.get("step"), **result}
    text = json.dumps(result, indent=1)
    if args.json:
        sc.atomic_write_text(args.json, text + "\n")
    sc.record(**result)
    print(text)
    return 0

"""The ``jaxsem`` command.

``jaxsem demo`` runs the main job on built-in synthetic data: each part of the library has a demo
module in :mod:`jaxsem.demos` with ``run(out_dir, quick) -> str`` that writes figures into
``out_dir`` and returns a printed table.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pathlib
import sys
import time

DEMO_PARTS = ("geometry", "roshan", "volumon", "lsd")


def enable_compilation_cache(cache_dir: str | None = None) -> None:
    """Turns on JAX's persistent compilation cache (compile time is part of the user's wait)."""
    import jax

    cache_dir = cache_dir or os.environ.get("JAXSEM_CACHE_DIR", str(pathlib.Path.home() / ".cache" / "jaxsem" / "jax"))
    try:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except Exception as exc:  # an old jax without the option: run uncached
        print(f"jaxsem: compilation cache disabled ({exc})", file=sys.stderr)


def _demo(args: argparse.Namespace) -> int:
    out_dir = pathlib.Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts = DEMO_PARTS if args.parts == "all" else tuple(p.strip() for p in args.parts.split(","))
    unknown = [p for p in parts if p not in DEMO_PARTS]
    if unknown:
        raise SystemExit(f"jaxsem demo: unknown part(s) {unknown}; expected some of {DEMO_PARTS}")
    enable_compilation_cache()
    for part in parts:
        start = time.perf_counter()
        print(f"=== jaxsem demo: {part} ===", flush=True)
        module = importlib.import_module(f"jaxsem.demos.{part}")
        table = module.run(out_dir, quick=args.quick)
        print(table)
        print(f"--- {part} done in {time.perf_counter() - start:.1f} s; figures in {out_dir}", flush=True)
    return 0


def _volumon_eval(args: argparse.Namespace) -> int:
    """``jaxsem volumon eval``: held-out figures of the shipped model (or ``--workdir``) as JSON."""
    import json

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="jaxsem", description=(__doc__ or "jaxsem").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the demo on built-in synthetic data")
    demo.add_argument("--out", default="jaxsem_demo", help="folder for figures and JSON")
    demo.add_argument("--parts", default="all", help=f"comma-separated subset of {','.join(DEMO_PARTS)}")
    demo.add_argument("--quick", action="store_true", help="smallest sizes (used by the tests)")
    demo.set_defaults(func=_demo)
    volumon = sub.add_parser("volumon", help="VoluMon: evaluate the shipped (or a trained) model")
    vsub = volumon.add_subparsers(dest="volumon_command", required=True)
    ev = vsub.add_parser("eval", help="held-out synthetic detections of several classes -> JSON figures")
    ev.add_argument("--seed", type=int, default=1, help="held-out seed (a stream no training seed uses)")
    ev.add_argument("--num", type=int, default=256, help="number of detections")
    ev.add_argument("--json", default=None, help="write the figures here (atomically)")
    ev.add_argument("--workdir", default=None, help="a training run (config.json + checkpoints/) or a .npz model")
    ev.add_argument("--postopt", type=int, default=0, help="also refine with PostOpt for this many steps")
    ev.add_argument(
        "--data",
        default=None,
        help="score the objects of a FAT-layout or make_synthetic directory (the first --num) instead of "
        "synthetic held-out detections",
    )
    ev.add_argument("--debug", action="store_true", help="show tracebacks")
    ev.set_defaults(func=_volumon_eval)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())

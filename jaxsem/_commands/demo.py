"""Runs the demo on built-in synthetic data: each part of the library (geometry, ROSHAN, VoluMon,
LSD) writes its figures into the run directory and prints a table.

In: nothing (data are generated, models are the shipped ones). Out: the run directory (--out,
default jaxsem_demo/; --run-dir names it too): PNG figures and JSON per part, config.json and
summary.json (per part: its wall time; the figures); the last line says where the figures are.
"""

from __future__ import annotations

import argparse
import importlib
import pathlib
import time

from jaxsem import scripting as sc

DEMO_PARTS = ("geometry", "roshan", "volumon", "lsd")
RUN_DIR_FLAG = "out"  # the demo's folder is its run directory


def parse_args(argv=None, prog: str | None = None) -> argparse.Namespace:
    """The flags, with ``--parts`` read into a tuple of :data:`DEMO_PARTS` (an unknown part exits
    with one line naming it, before any run starts)."""
    args = build_parser(prog).parse_args(argv)
    text = args.parts.strip()
    args.parts = DEMO_PARTS if text == "all" else tuple(p.strip() for p in text.split(",") if p.strip())
    unknown = [p for p in args.parts if p not in DEMO_PARTS] or ([] if args.parts else [text])
    if unknown:
        raise SystemExit(f"{prog or 'jaxsem demo'}: unknown part(s) {unknown}; expected some of {DEMO_PARTS}")
    return args


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__, run_dir_default="--out")
    p.add_argument(
        "--out", type=sc.output_dir, default="jaxsem_demo", help="folder for figures and JSON: the run directory"
    )
    p.add_argument("--parts", default="all", help=f"comma-separated subset of {','.join(DEMO_PARTS)}")
    p.add_argument("--quick", action="store_true", help="smallest sizes (a few minutes on a CPU; used by the tests)")
    return p


def main(argv=None, prog: str | None = None) -> int:
    args = parse_args(argv, prog)
    out_dir = pathlib.Path(args.run_dir or args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    seconds = {}
    for part in args.parts:
        start = time.perf_counter()
        print(f"=== jaxsem demo: {part} ===", flush=True)
        module = importlib.import_module(f"jaxsem.demos.{part}")
        table = module.run(out_dir, quick=args.quick)
        print(table)
        seconds[part] = round(time.perf_counter() - start, 1)
        print(f"--- {part} done in {seconds[part]:.1f} s", flush=True)
        sc.record(seconds=seconds)
    figures = sorted(out_dir.glob("*.png"))
    print(f"figures ({len(figures)}) are in {out_dir}/: {', '.join(f.name for f in figures)}", flush=True)
    return 0

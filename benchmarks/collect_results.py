"""Writes an index of the raw result files in benchmarks/results/ to benchmarks/results/INDEX.md.

python benchmarks/collect_results.py

Each benchmark script writes its tables and figures to ``benchmarks/results/<claim>.{md,json,png}``.
The index lists them by method (the file name's prefix), each ``.md`` file with its first heading
and the other files of the same name beside it. It never touches ``benchmarks/RESULTS.md`` (the
hand-written page of current figures) or the per-method ``benchmarks/<method>/HISTORY.md`` files.
"""

from __future__ import annotations

import argparse
import collections
import pathlib

HERE = pathlib.Path(__file__).parent
INDEX_NAME = "INDEX.md"
#: Section of the index by the file name's first word; anything else goes under "Integration and other".
METHODS = {"geometry": "Geometry core", "roshan": "ROSHAN", "volumon": "VoluMon", "lsd": "LSD"}
OTHER = "Integration and other"


def _title(path: pathlib.Path) -> str:
    """The first markdown heading of ``path`` without its ``#`` marks ('' if it has none)."""
    for line in path.read_text(errors="replace").splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return ""


def build_index(results: pathlib.Path) -> str:
    """The markdown index of the files in ``results`` (the index file itself left out)."""
    files = sorted(p for p in results.iterdir() if p.is_file() and p.name != INDEX_NAME and not p.name.startswith("."))
    by_stem: dict[str, list[pathlib.Path]] = collections.defaultdict(list)
    for p in files:
        by_stem[p.name.split(".", 1)[0]].append(p)
    sections: dict[str, list[str]] = {name: [] for name in [*METHODS.values(), OTHER]}
    for stem in sorted(by_stem):
        group = by_stem[stem]
        md = [p for p in group if p.suffix == ".md"]
        title = _title(md[0]) if md else ""
        links = ", ".join(f"[{p.name}]({p.name})" for p in group)
        line = f"- {links}" + (f": {title}" if title else "")
        sections[METHODS.get(stem.split("_", 1)[0], OTHER)].append(line)
    out = [
        "# Index of raw benchmark results",
        "",
        "Written by `python benchmarks/collect_results.py`; do not edit. Each file was written by a",
        "script in `benchmarks/` (the `.md` tables name their command, date and machine). The current",
        "figures are in `../RESULTS.md`; how they got there in `../<method>/HISTORY.md`.",
    ]
    for name, lines in sections.items():
        if lines:
            out += ["", f"## {name}", "", *lines]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=pathlib.Path, default=HERE / "results", help="folder of result files")
    args = parser.parse_args(argv)
    target = args.results / INDEX_NAME
    target.write_text(build_index(args.results))
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Assembles benchmarks/RESULTS.md from the per-claim sections in benchmarks/results/*.md.

python benchmarks/collect_results.py
"""

import pathlib

HERE = pathlib.Path(__file__).parent
ORDER = ["geometry", "roshan_speed", "roshan_table41", "roshan_views", "volumon_table51", "lsd_speed", "lsd_table31"]


def main():
    sections = {p.stem: p.read_text().strip() for p in sorted((HERE / "results").glob("*.md"))}
    names = [n for n in ORDER if n in sections] + sorted(n for n in sections if n not in ORDER)
    header = [
        "# Benchmark results",
        "",
        "Each section was written by its script in `benchmarks/` (the command is given with it) and",
        "collected here by `python benchmarks/collect_results.py`. Timings are medians after warm-up",
        "on a shared, noisy 2-core CPU; compare ratios measured in the same run, not absolute times.",
        "",
    ]
    body = "\n\n".join(sections[n] for n in names)
    (HERE / "RESULTS.md").write_text("\n".join(header) + body + "\n")
    print(f"wrote {HERE / 'RESULTS.md'} with sections: {', '.join(names)}")


if __name__ == "__main__":
    main()

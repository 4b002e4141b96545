"""Training curves of an LSD run: running train NLL (from the tqdm log of train/lsd.py) and the
validation NLL (from <workdir>/metrics.json), against the uniform distribution's NLL.

    python benchmarks/lsd_training_curves.py --log runs/lsd_big_train.log --workdir runs/lsd_big/train
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

RESULTS = pathlib.Path(__file__).resolve().parent / "results"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--log", required=True, help="stdout/stderr of train/lsd.py (tqdm lines)")
    ap.add_argument("--workdir", required=True, help="training workdir (metrics.json)")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--name", default="lsd_training")
    args = ap.parse_args(argv)
    for flag, path in (
        ("--log", args.log),
        ("--workdir", pathlib.Path(args.workdir) / "metrics.json"),
    ):
        if not pathlib.Path(path).exists():
            raise SystemExit(f"{flag}: no such file {str(path)!r}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    text = pathlib.Path(args.log).read_text(errors="replace")
    train = {}
    for m in re.finditer(r"\|\s*(\d+)/\d+ \[[^\]]*nll=([\d.]+), stage=(\d)\]", text):
        train[int(m.group(1))] = (float(m.group(2)), int(m.group(3)))
    metrics = json.loads((pathlib.Path(args.workdir) / "metrics.json").read_text())
    steps = sorted(train)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot(
        steps,
        [train[s][0] for s in steps],
        lw=0.8,
        label="train NLL (running mean of 50 steps)",
    )
    ax.plot(
        [h["step"] for h in metrics],
        [h["val_nll"] for h in metrics],
        "o-",
        label="validation NLL",
    )
    if metrics:
        ax.axhline(metrics[0]["uniform_nll"], color="k", ls="--", lw=0.8, label="uniform")
    stage2 = [s for s in steps if train[s][1] == 2]
    if stage2:
        ax.axvline(stage2[0], color="grey", lw=0.8)
        ax.text(stage2[0], ax.get_ylim()[1], " stage 2", va="top", fontsize=8)
    ax.set_xlabel("step")
    ax.set_ylabel("NLL per expert-path cell (nats)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / f"{args.name}.png", dpi=100)
    (out / f"{args.name}.json").write_text(
        json.dumps(
            {"train": {str(s): train[s][0] for s in steps}, "validation": metrics},
            indent=1,
        )
    )
    print(f"wrote {out / (args.name + '.png')}: {len(steps)} train points, {len(metrics)} validations")
    return 0


if __name__ == "__main__":
    sys.exit(main())

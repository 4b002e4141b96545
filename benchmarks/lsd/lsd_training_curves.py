"""Training curves of an LSD run: running train NLL (from the tqdm log of train/lsd.py) and the
validation NLL (from <workdir>/metrics.jsonl, or the metrics.json of runs made before the shared
training scaffold), against the uniform distribution's NLL. Without --log the train curve is the
running mean each evaluation row records.

    python benchmarks/lsd/lsd_training_curves.py --log runs/lsd_big_train.log --workdir runs/lsd_big/train
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"


def save_step_plot(fig, ax, ylabel: str, out, name: str) -> pathlib.Path:
    """Labels a plot over training steps (legend, light grid) and saves it as ``out/name.png``
    (100 dpi), making ``out`` if need be; returns ``out`` as a path. Also ``lsd_oracle.py``'s."""
    ax.set_xlabel("step")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / f"{name}.png", dpi=100)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--log", default=None, help="stdout/stderr of train/lsd.py (tqdm lines); optional")
    ap.add_argument("--workdir", required=True, help="training workdir (metrics.jsonl)")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--name", default="lsd_training")
    args = ap.parse_args(argv)
    if args.log is not None and not pathlib.Path(args.log).exists():
        raise SystemExit(f"--log: no such file {args.log!r}")
    wd = pathlib.Path(args.workdir)
    legacy = wd / "metrics.json"
    if not (wd / "metrics.jsonl").exists() and not legacy.exists():
        raise SystemExit(f"--workdir: no metrics.jsonl (or metrics.json) in {str(wd)!r}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsem.training import read_metrics

    metrics = read_metrics(wd) if (wd / "metrics.jsonl").exists() else json.loads(legacy.read_text())
    train = {}
    if args.log is not None:
        text = pathlib.Path(args.log).read_text(errors="replace")
        for m in re.finditer(r"\|\s*(\d+)/\d+ \[[^\]]*nll=([\d.]+), stage=(\d)\]", text):
            train[int(m.group(1))] = (float(m.group(2)), int(m.group(3)))
    else:
        train = {h["step"]: (h["train_nll"], h["stage"]) for h in metrics if "train_nll" in h}
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
    cfg = pathlib.Path(args.workdir) / "config.json"
    if cfg.exists():  # the stage boundary itself, not the first stage-two evaluation
        stage2 = [int(json.loads(cfg.read_text())["stage1_steps"])] if stage2 else []
    if stage2:
        ax.axvline(stage2[0], color="grey", lw=0.8)
        ax.text(stage2[0], ax.get_ylim()[1], " stage 2", va="top", fontsize=8)
    out = save_step_plot(fig, ax, "NLL per expert-path cell (nats)", args.out, args.name)
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

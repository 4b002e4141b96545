"""Export a VoluMon R-CNN training run as a shipped model: weights, config and curves.

    python train/export_volumon_rcnn.py --workdir runs/rcnn_plain --out jaxsem/volumon/pretrained/volumon_lmo_rcnn
    python train/export_volumon_rcnn.py --workdir runs/rcnn_448 --average-steps 2000,2500,3000 --out ...

Writes ``OUT.npz`` (float32 variables), ``OUT.json`` (the training config, the step, the data and
the last held-out figures of the run's ``metrics.jsonl``) and ``OUT_curves.png`` (the loss terms and
the held-out AP50 and centre error against the step), each atomically. ``--average-steps`` exports
the parameter average of those checkpoints of the run (``jaxsem.volumon.rcnn.average_models``)
instead of its latest one; ``--detector`` grafts the run's lift onto another network's detector
(``jaxsem.volumon.rcnn.graft_lift``). A run started from another
run's weights (``--init-from``) is drawn after that run's curves, its steps counted on from there.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from jaxsem import scripting as sc


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python train/export_volumon_rcnn.py", description=__doc__.split("\n")[0])
    p.add_argument("--workdir", type=sc.existing_dir, required=True, help="the training run (train/volumon_rcnn.py)")
    p.add_argument("--out", type=pathlib.Path, required=True, help="path stem of the exported model")
    p.add_argument(
        "--average-steps", type=sc.int_list, default=None, help="average these checkpoints (e.g. 2000,2500,3000)"
    )
    p.add_argument("--data", default="", help="a line saying what the run trained on (goes into the JSON)")
    p.add_argument(
        "--detector",
        default=None,
        help="graft the run's lift onto this detector (a shipped name or an exported .npz; "
        "jaxsem.volumon.rcnn.graft_lift): its boxes and classes, the run's ellipsoids",
    )
    a = p.parse_args(argv)
    metrics_path = a.workdir / "metrics.jsonl"
    if not metrics_path.is_file():
        p.error(f"--workdir: {a.workdir} holds no metrics.jsonl")
    if not a.out.parent.is_dir():
        p.error(f"--out: no folder {a.out.parent}")
    rows = [json.loads(line) for line in metrics_path.read_text().splitlines() if line.strip()]

    from jaxsem.volumon.rcnn import SHIPPED_RCNNS, average_models, export_rcnn, graft_lift, load_rcnn

    if a.detector is not None and a.detector not in SHIPPED_RCNNS and not pathlib.Path(a.detector).is_file():
        p.error(f"--detector: no model {a.detector}")

    if a.average_steps:
        missing = [s for s in a.average_steps if not (a.workdir / "checkpoints" / str(s)).is_dir()]
        if missing:
            p.error(f"--average-steps: no checkpoint {missing[0]} under {a.workdir / 'checkpoints'}")
        loaded = average_models(load_rcnn(a.workdir, step=s) for s in a.average_steps)
        loaded = loaded._replace(meta={**loaded.meta, "step": max(a.average_steps)})
    else:
        loaded = load_rcnn(a.workdir)
    if a.detector is not None:
        try:
            loaded = graft_lift(load_rcnn(a.detector), loaded)
        except ValueError as exc:
            p.error(f"--detector: {exc}")
    last = rows[-1] if rows else {}
    meta = {
        "name": a.out.name,
        "step": loaded.meta["step"],
        "seed": loaded.config.seed,
        "data": a.data,
        # an average's own validation figures are not in the run's log: only the last checkpoint's
        "heldout_last_checkpoint" if a.average_steps else "heldout": {
            k.removeprefix("heldout_"): v for k, v in last.items() if k.startswith("heldout_")
        },
        "heldout_step": last.get("step"),
    }
    if a.average_steps:
        meta["averaged_steps"] = sorted(a.average_steps)
    if "grafted" in loaded.meta:
        meta["grafted"] = {**loaded.meta["grafted"], "detector": a.detector}
    # a run started from another run's weights (init_from, followed back through every stage):
    # its curves continue those runs'
    before, restarts = _stages(loaded.config.init_from)
    offset = restarts[-1] if restarts else 0
    if before:
        rows = before + [{**r, "step": r["step"] + offset} for r in rows]
        meta["steps_before"] = offset
        meta["steps_total"] = offset + int(loaded.meta["step"])
        meta["stages"] = restarts
    export_rcnn(a.out, loaded.variables, loaded.config, meta)
    _curves(rows, a.out.with_name(a.out.name + "_curves.png"), restarts)
    print(json.dumps(meta, indent=1))
    return 0


def _stages(init_from: str) -> tuple[list, list]:
    """The metrics rows of the runs a run started from (oldest first, steps counted on across
    them) and the step at which each later stage began."""
    chain, path = [], pathlib.Path(init_from) if init_from else None
    while path is not None and (path / "metrics.jsonl").is_file() and len(chain) < 16:
        chain.append(path)
        try:
            parent = json.loads((path / "config.json").read_text()).get("init_from") or ""
        except (OSError, ValueError, AttributeError):
            parent = ""
        path = pathlib.Path(parent) if parent else None
    rows, restarts, offset = [], [], 0
    for run in reversed(chain):
        part = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines() if x.strip()]
        rows += [{**r, "step": r["step"] + offset} for r in part]
        offset += int(part[-1]["step"]) if part else 0
        restarts.append(offset)
    return rows, restarts


def _curves(rows, path: pathlib.Path, restarts: list) -> None:
    import matplotlib  # deferred: matplotlib is slow to import and only the figure needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [r["step"] for r in rows]
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    for k in ("rpn_cls", "rpn_box", "cls", "box"):
        ax[0].plot(steps, [r[k] for r in rows], label=k)
    ax[0].set_yscale("log")
    ax[0].set_title("detection terms (training batches)")
    for k in ("dual", "size", "oracle"):
        if rows and k in rows[0]:
            ax[1].plot(steps, [r[k] for r in rows], label=k)
    ax[1].set_yscale("log")
    ax[1].set_title("VoluMon terms (count after the burn-in)")
    ax[2].plot(steps, [r.get("heldout_ap50", float("nan")) for r in rows], label="AP50")
    ax[2].plot(steps, [r.get("heldout_recall50", float("nan")) for r in rows], label="recall50")
    ax2 = ax[2].twinx()
    ax2.plot(steps, [r.get("heldout_median_center_error_m", float("nan")) for r in rows], "k--", label="centre (m)")
    ax2.set_ylabel("median centre error (m)")
    ax[2].set_title("held-out validation photos")
    for a_ in ax:
        for k, restart in enumerate(restarts):
            a_.axvline(restart, color="grey", lw=0.8, ls=":", label="next stage (init_from)" if k == 0 else None)
        a_.set_xlabel("step")
        a_.legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    tmp.replace(path)


if __name__ == "__main__":
    sys.exit(sc.run_main(main))

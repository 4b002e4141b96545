"""Diagnose VoluMon's size collapse: learning curves of Dual / Primal / Both against a supervised oracle.

Trains, on the same device-made images (same seed, same steps), a fully supervised *oracle*
(3D labels: sizes, centre, axes) and the weakly supervised variants with the thesis' losses
(every class drawn as an ellipsoid) and with shape-aware losses (each class drawn with its own
shape: cuboid, ellipsoid, cylinder), then plots each loss term and the held-out size and centre
errors against the step. Workdirs are kept, so a rerun resumes and only re-plots.

    python benchmarks/volumon_diagnose.py --steps 500 --eval-every 100
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import pathlib
import sys
import time

# name: (variant, shape-aware losses, box fed to the heads, rotation init, primal distance)
RUNS = {
    "oracle": ("oracle", False, False, "identity", "algebraic"),
    "dual (ellipsoid)": ("dual", False, False, "identity", "algebraic"),
    "primal (ellipsoid)": ("primal", False, False, "identity", "algebraic"),
    "both (ellipsoid)": ("both", False, False, "identity", "algebraic"),
    "dual (shape-aware)": ("dual", True, False, "identity", "algebraic"),
    "both (shape-aware)": ("both", True, False, "identity", "algebraic"),
    "oracle (box input)": ("oracle", False, True, "identity", "algebraic"),
    "both (shape-aware, box input)": ("both", True, True, "identity", "algebraic"),
    "both (shape-aware, box input, short axis on ray)": (
        "both",
        True,
        True,
        "short_axis_along_ray",
        "algebraic",
    ),
    "dual (ellipsoid, short axis on ray)": (
        "dual",
        False,
        False,
        "short_axis_along_ray",
        "algebraic",
    ),
    "both (fast preset: shape-aware, box input, short axis on ray, radial)": (
        "both",
        True,
        True,
        "short_axis_along_ray",
        "radial",
    ),
}


def _slug(name: str) -> str:
    return name.replace(" ", "_").replace("(", "").replace(")", "").replace("-", "_").replace(",", "")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--eval-every", type=int, default=100)
    p.add_argument("--num-eval", type=int, default=96)
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="training seed (held-out curves use its eval stream)",
    )
    p.add_argument("--size", default="fast")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--runs", nargs="+", default=list(RUNS), choices=list(RUNS))
    p.add_argument("--workdir", type=pathlib.Path, default=pathlib.Path("runs/volumon_diagnose"))
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path(__file__).parent / "results")
    p.add_argument("--tag", default="volumon_diagnose")
    a = p.parse_args(argv)

    from jaxsem.volumon import get_config, train_and_evaluate

    curves = {}
    for name in a.runs:
        variant, shape, box, rot, dist = RUNS[name]
        cfg = get_config(variant, a.size)
        cfg = cfg.replace(
            loss=dataclasses.replace(cfg.loss, shape_aware=shape, primal_distance=dist),
            num_steps=a.steps,
            model=dataclasses.replace(cfg.model, box_input=box, rotation_init=rot),
            eval_every=a.eval_every,
            num_eval=a.num_eval,
            seed=a.seed,
            log_every=10,
            batch_size=a.batch_size,
            checkpoint_every=a.eval_every,
        )
        wd = a.workdir / _slug(name)
        t = time.perf_counter()
        train_and_evaluate(
            cfg,
            wd,
            progress=False,
            log=lambda line, n=name: print(f"[{n}] {line}", flush=True),
        )
        rows = [json.loads(x) for x in (wd / "metrics.jsonl").read_text().splitlines()]
        curves[name] = {
            "loss": [r for r in rows if "total" in r],
            "eval": [{"step": r["step"], **r["eval"]} for r in rows if "eval" in r],
            "wall_s": time.perf_counter() - t,
        }
    a.out.mkdir(parents=True, exist_ok=True)
    _figure(curves, a.out / f"{a.tag}.png")
    record = {
        "command": "python " + " ".join([os.path.relpath(__file__)] + (sys.argv[1:] if argv is None else list(argv))),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{os.cpu_count()}-core CPU (shared)",
        "steps": a.steps,
        "size": a.size,
        "seed": a.seed,
        "batch_size": a.batch_size,
        "final": {n: c["eval"][-1] if c["eval"] else None for n, c in curves.items()},
        "curves": curves,
    }
    tmp = a.out / f"{a.tag}.json.tmp"
    tmp.write_text(json.dumps(record, indent=1))
    tmp.replace(a.out / f"{a.tag}.json")
    lines = [
        "## VoluMon size collapse: oracle against weak supervision (learning curves)",
        "",
        f"Command: `{record['command']}`  ",
        f"Date: {record['date']}  ",
        f"Machine: {record['machine']}  ",
        (
            f"Config: `{a.size}` preset, batch {a.batch_size}, {a.steps} steps each, same seed ({a.seed}) and images; "
            f"held-out: {a.num_eval} samples of the eval stream. Figure: `{a.tag}.png`."
        ),
        "",
        "| run | median size rel. error | size corr | median centre error (m) | trans AUC | ADI AUC | 3D IoU |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, e in record["final"].items():
        if e:
            lines.append(
                f"| {n} | {e['median_size_rel_error']:.3f} | {e['size_corr']:.2f} | "
                f"{e['median_center_error_m']:.3f} | {e['trans_auc']:.2f} | {e['adi_auc']:.2f} | {e['iou']:.2f} |"
            )
    tmp = a.out / f"{a.tag}.md.tmp"
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(a.out / f"{a.tag}.md")
    print("\n".join(lines))
    return 0


def _figure(curves, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    for name, c in curves.items():
        ev = c["eval"]
        st = [e["step"] for e in ev]
        axes[0].plot(st, [e["median_size_rel_error"] for e in ev], marker="o", label=name)
        axes[1].plot(st, [e["size_corr"] for e in ev], marker="o", label=name)
        axes[2].plot(st, [e["median_center_error_m"] for e in ev], marker="o", label=name)
        loss = c["loss"]
        for term, ls in (("dual", "-"), ("primal", "--"), ("oracle", ":")):
            vals = [r[term] for r in loss]
            if any(v > 0 for v in vals):
                axes[3].semilogy(
                    [r["step"] for r in loss],
                    [max(v, 1e-9) for v in vals],
                    ls,
                    label=f"{name}: {term}",
                )
    axes[0].set_title("median size rel. error (held-out)")
    axes[1].set_title("size correlation (held-out)")
    axes[2].set_title("median centre error, m (held-out)")
    axes[3].set_title("loss terms (train)")
    for ax in axes:
        ax.set_xlabel("step")
    axes[0].legend(fontsize=7)
    axes[3].legend(fontsize=5)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())

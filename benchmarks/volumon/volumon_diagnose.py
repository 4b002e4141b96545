"""Diagnose VoluMon's size collapse: learning curves of Dual / Primal / Both against a supervised oracle.

Trains, on the same device-made images (same seed, same steps), a fully supervised *oracle*
(3D labels: sizes, centre, axes) and the weakly supervised variants, then plots the held-out
size and centre errors, translation AUC and every loss term (on the held-out samples) against the
step.

The default runs are the shipped model's preset unchanged (``get_config(variant, "fast")``: ray
primal distance, shape-aware losses, box input, shortest axis started along the ray, batch 32):
``dual``, ``primal``, ``both``, ``oracle``. The other run names are the earlier ablations (thesis
losses, radial distance, ...), which override some fields of the preset.

Runs are trained round-robin in chunks of ``--eval-every`` steps, so that all runs have the same
length at every moment; each chunk resumes from the orbax checkpoint in the run's workdir, so a
killed job continues where it stopped. ``--plot-only`` re-plots from the workdirs (up to
``--steps``) without training. The shipped model, evaluated on the same held-out samples, is
drawn as a reference line.

    python benchmarks/volumon/volumon_diagnose.py --steps 2500 --eval-every 250 --workdir runs/diag_long
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import json
import os
import pathlib
import shlex
import sys
import time

# name: None (the preset, unchanged) or (variant, shape-aware losses, box fed to the heads,
# rotation init, primal distance) overriding the preset's fields (the earlier ablations)
PRESET_RUNS = ("dual", "primal", "both", "oracle")
RUNS = {
    **{v: None for v in PRESET_RUNS},
    "oracle (ablation base)": ("oracle", False, False, "identity", "algebraic"),
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
LOSS_TERMS = ("dual", "primal", "oracle", "size")
LOSS_TITLES = {
    "dual": "dual (stereo box) loss",
    "primal": "primal (depth point) loss",
    "oracle": "oracle (3D label) loss",
    "size": "intra-class size-variance loss",
}
METRICS = (
    ("median_size_rel_error", "median size rel. error"),
    ("size_corr", "size correlation"),
    ("median_center_error_m", "median centre error (m)"),
    ("trans_auc", "translation AUC"),
)


def _slug(name: str) -> str:
    return name.replace(" ", "_").replace("(", "").replace(")", "").replace("-", "_").replace(",", "").replace(":", "")


def run_config(name: str, a):
    """The training config of run ``name``: the preset, with the run length / evaluation fields."""
    from jaxsem.volumon import get_config

    spec = RUNS[name]
    variant = name if spec is None else spec[0]
    cfg = get_config(variant, a.size)
    if spec is not None:
        _, shape, box, rot, dist = spec
        cfg = cfg.replace(
            loss=dataclasses.replace(cfg.loss, shape_aware=shape, primal_distance=dist),
            model=dataclasses.replace(cfg.model, box_input=box, rotation_init=rot),
        )
    changes = {
        "num_steps": a.steps,
        "eval_every": a.eval_every,
        "num_eval": a.num_eval,
        "seed": a.seed,
        "log_every": 10,
        "checkpoint_every": a.eval_every,
    }
    if a.batch_size is not None:
        changes["batch_size"] = a.batch_size
    return cfg.replace(**changes)


@functools.lru_cache(maxsize=16)
def _loss_fn(model, config):
    """Jitted ``(variables, batch) -> every loss term`` (all weights 1: a term of a run that does not
    train on it is still measured), in inference mode, no augmentation."""
    import jax

    from jaxsem.models import reconstruct
    from jaxsem.volumon import predict_params, volumon_loss

    loss_cfg = dataclasses.replace(config.loss, alpha_D=1.0, alpha_P=1.0, alpha_S=1.0, alpha_O=1.0, alpha_V=0.0)

    @jax.jit
    def fn(variables, batch):
        phi, logits, _ = predict_params(
            model,
            variables,
            batch["local"],
            batch["global"],
            batch["class_id"],
            config.class_mode,
            box=batch["box_input"],
            K=batch["K"],
        )
        ell = reconstruct(phi, batch["box_input"], batch["K"], config.recon)
        return volumon_loss(ell, batch, loss_cfg, model.config.num_classes, logits)._asdict()

    return fn


@functools.lru_cache(maxsize=4)
def _held_out(seed, num, scene, input_size, padding, noisy):
    from jaxsem.volumon import held_out_set

    return held_out_set(seed, num, scene, input_size, padding, noisy)


def held_out_losses(model, variables, config) -> dict:
    """Each loss term on the ``config.num_eval`` held-out samples of ``config.seed``'s eval stream."""
    b = _held_out(
        config.seed, config.num_eval, config.scene, config.model.input_size, config.model.global_padding, config.noisy
    )
    out = _loss_fn(model, config)(variables, b)
    return {k: float(v) for k, v in out.items() if k != "total"}


def axis_ratios(model, variables, config) -> dict:
    """Median ratio predicted / true of the sorted radii (smallest, middle, largest) on the held-out
    samples: which axis a size error sits on."""
    import numpy as np

    from jaxsem.volumon import predict_batch

    b = _held_out(
        config.seed, config.num_eval, config.scene, config.model.input_size, config.model.global_padding, config.noisy
    )
    _, ell, _ = predict_batch(model, config, variables, b)
    ratio = np.sort(np.asarray(ell.radii), -1) / np.sort(np.asarray(b["gt_half_extents"]), -1)
    keep = np.asarray(b["sample_mask"], bool)
    med = np.median(ratio[keep], 0)
    return {"ratio_small": float(med[0]), "ratio_mid": float(med[1]), "ratio_large": float(med[2])}


def final_ratios(names, curves, a) -> None:
    """:func:`axis_ratios` of each run at its last evaluated step (from its checkpoint)."""
    from jaxsem.checkpoint import Checkpointer
    from jaxsem.volumon import load_trained

    for name in names:
        ev = curves[name]["eval"]
        if not ev:
            continue
        wd = a.workdir / _slug(name)
        ckpt = Checkpointer(wd / "checkpoints", max_to_keep=None)
        try:
            have = ckpt.all_steps()
        finally:
            ckpt.close()
        if ev[-1]["step"] not in have:
            continue
        cfg = run_config(name, a)
        model, variables, _ = load_trained(wd, cfg, step=ev[-1]["step"])
        ev[-1].update(axis_ratios(model, variables, cfg))


def _read_jsonl(path: pathlib.Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def _append_jsonl(path: pathlib.Path, row: dict) -> None:
    rows = [r for r in _read_jsonl(path) if r["step"] != row["step"]] + [row]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in sorted(rows, key=lambda r: r["step"])))
    tmp.replace(path)


def train_round_robin(names, a, log=print) -> None:
    """Train every run to ``a.steps`` in chunks of ``a.eval_every`` steps, round-robin."""
    from jaxsem.checkpoint import latest_step
    from jaxsem.volumon import train_and_evaluate

    chunk_ends = list(range(a.eval_every, a.steps + 1, a.eval_every))
    if not chunk_ends or chunk_ends[-1] != a.steps:
        chunk_ends.append(a.steps)
    for chunk_end in chunk_ends:
        for name in names:
            cfg = run_config(name, a)
            wd = a.workdir / _slug(name)
            cur = latest_step(wd / "checkpoints") or 0
            if cur >= chunk_end:
                continue
            t = time.perf_counter()
            res = train_and_evaluate(
                cfg,
                wd,
                stop_after=chunk_end - cur,
                progress=False,
                log=lambda line, n=name: log(f"[{n}] {line}") if not line.startswith("step=") else None,
            )
            wall = time.perf_counter() - t
            variables = {"params": res["state"]["params"], "batch_stats": res["state"]["batch_stats"]}
            step = int(res["state"]["step"])
            _append_jsonl(
                wd / "heldout_loss.jsonl",
                {
                    "step": step,
                    "chunk_wall_s": wall,
                    "chunk_steps": step - cur,
                    **held_out_losses(res["model"], variables, cfg),
                },
            )
            log(
                f"[{name}] step {step}: chunk of {step - cur} steps in {wall:.0f} s ({wall / max(step - cur, 1):.3f} s/step)"
            )


def reference(a) -> dict | None:
    """The shipped model on the same held-out samples (metrics and loss terms)."""
    try:
        from jaxsem.volumon import load_pretrained
        from jaxsem.volumon._train import evaluate  # layers: white-box
    except ImportError:
        return None
    model, variables, config, meta = load_pretrained()
    config = config.replace(num_eval=a.num_eval, seed=a.seed, eval_every=0)
    ev = evaluate(model, variables, config)
    return {
        "step": meta.get("step"),
        **ev,
        **held_out_losses(model, variables, config),
        **axis_ratios(model, variables, config),
    }


def collect(names, a) -> dict:
    curves = {}
    for name in names:
        wd = a.workdir / _slug(name)
        rows = [r for r in _read_jsonl(wd / "metrics.jsonl") if r["step"] <= a.steps]
        held = {r["step"]: r for r in _read_jsonl(wd / "heldout_loss.jsonl") if r["step"] <= a.steps}
        ev = []
        for r in rows:
            if "eval" in r:
                h = held.get(r["step"], {})
                ev.append({"step": r["step"], **r["eval"], **{f"loss_{k}": h[k] for k in LOSS_TERMS if k in h}})
        curves[name] = {
            "train_loss": [r for r in rows if "total" in r],
            "eval": ev,
            "train_wall_s": sum(h.get("chunk_wall_s", 0.0) for h in held.values()),
            "train_steps": max(held, default=0),
        }
    return curves


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=2500)
    p.add_argument("--eval-every", type=int, default=250, help="evaluation interval and chunk length")
    p.add_argument("--num-eval", type=int, default=128)
    p.add_argument("--seed", type=int, default=0, help="training seed (held-out curves use its eval stream)")
    p.add_argument("--size", default="fast")
    p.add_argument("--batch-size", type=int, help="default: the preset's (32)")
    p.add_argument("--runs", nargs="+", default=list(PRESET_RUNS), choices=list(RUNS))
    p.add_argument("--workdir", type=pathlib.Path, default=pathlib.Path("runs/volumon_diagnose"))
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path(__file__).resolve().parents[1] / "results")
    p.add_argument("--tag", default="volumon_diagnose")
    p.add_argument("--plot-only", action="store_true", help="no training: tables and figure from the workdirs")
    p.add_argument("--no-reference", action="store_true", help="do not evaluate the shipped model")
    a = p.parse_args(argv)

    if not a.plot_only:
        train_round_robin(a.runs, a)
    curves = collect(a.runs, a)
    final_ratios(a.runs, curves, a)
    ref = None if a.no_reference else reference(a)
    a.out.mkdir(parents=True, exist_ok=True)
    _figure(curves, ref, a.out / f"{a.tag}.png")
    args = sys.argv[1:] if argv is None else list(argv)
    record = {
        "command": shlex.join(["python", os.path.relpath(__file__), *args]),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{os.cpu_count()}-core CPU (shared)",
        "steps": a.steps,
        "size": a.size,
        "seed": a.seed,
        "batch_size": a.batch_size or run_config(a.runs[0], a).batch_size,
        "num_eval": a.num_eval,
        "final": {n: c["eval"][-1] if c["eval"] else None for n, c in curves.items()},
        "reference_shipped": ref,
        "curves": curves,
    }
    tmp = a.out / f"{a.tag}.json.tmp"
    tmp.write_text(json.dumps(record, indent=1))
    tmp.replace(a.out / f"{a.tag}.json")
    lines = _table(record, a)
    tmp = a.out / f"{a.tag}.md.tmp"
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(a.out / f"{a.tag}.md")
    print("\n".join(lines))
    return 0


def _table(record, a) -> list[str]:
    lines = [
        "## VoluMon size collapse: oracle against weak supervision (learning curves)",
        "",
        f"Command: `{record['command']}`  ",
        f"Date: {record['date']}  ",
        f"Machine: {record['machine']}  ",
        (
            f"Config: `{a.size}` preset, batch {record['batch_size']}, {a.steps} steps each, same seed ({a.seed}) and "
            f"images; held-out: {a.num_eval} samples of the seed's eval stream, every {a.eval_every} steps. "
            f"Figure: `{a.tag}.png`."
        ),
        "",
        "| run | step | median size rel. error | size corr | median centre error (m) | trans AUC | ADI AUC | 3D IoU "
        "| radii pred / true (sorted: small, mid, large) | dual loss | primal loss | oracle loss "
        "| size-variance loss | train s/step |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def row(n, e, sps):
        ratios = (
            " / ".join(f"{e[k]:.2f}" for k in ("ratio_small", "ratio_mid", "ratio_large"))
            if "ratio_small" in e
            else "-"
        )
        losses = " | ".join(f"{e[k]:.4g}" if k in e else "-" for k in [f"loss_{t}" for t in LOSS_TERMS])
        return (
            f"| {n} | {e.get('step', '-')} | {e['median_size_rel_error']:.3f} | {e['size_corr']:.2f} | "
            f"{e['median_center_error_m']:.3f} | {e['trans_auc']:.2f} | {e['adi_auc']:.2f} | {e['iou']:.2f} | "
            f"{ratios} | {losses} | {sps} |"
        )

    for n, e in record["final"].items():
        if e:
            c = record["curves"][n]
            sps = f"{c['train_wall_s'] / c['train_steps']:.2f}" if c["train_steps"] else "-"
            lines.append(row(n, e, sps))
    ref = record.get("reference_shipped")
    if ref:
        e = {**ref, **{f"loss_{k}": ref[k] for k in LOSS_TERMS}}
        lines.append(row(f"shipped model (`volumon_fast`, step {ref['step']}), same samples", e, "-"))
    return lines


def _figure(curves, ref, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(18, 7.5))
    panels = [(k, f"{t} (held-out)", False) for k, t in METRICS] + [
        (f"loss_{t}", f"{LOSS_TITLES[t]} (held-out)", True) for t in LOSS_TERMS
    ]
    for ax, (key, title, log) in zip(axes.ravel(), panels):
        for name, c in curves.items():
            pts = [(e["step"], e[key]) for e in c["eval"] if key in e]
            if pts:
                st, v = zip(*pts)
                (ax.semilogy if log else ax.plot)(
                    st, [max(x, 1e-9) for x in v] if log else v, marker="o", ms=3, label=name
                )
        rk = key[5:] if key.startswith("loss_") else key
        if ref and rk in ref:
            ax.axhline(
                max(ref[rk], 1e-9) if log else ref[rk], color="k", ls="--", lw=1, label=f"shipped (step {ref['step']})"
            )
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("VoluMon `fast` preset, same images: held-out metrics and loss terms against the step", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())

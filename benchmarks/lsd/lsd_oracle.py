"""The fully supervised oracle of LSD: the same network trained on the same expert samples, but
seeing the *true* map around the robot instead of the partial one (``jaxsem.lsd.with_full_map``).

LSD learns from expert paths computed on the true map while it sees only what the robot has
mapped. The oracle removes that gap and nothing else (same goals, paths, context, network,
steps, seed, validation buildings), so the difference of the two validation NLLs is what the
partial map costs, and an oracle no better than the network would point at the plumbing (data,
loss, network) rather than at the missing information.

Three steps (the second is the ordinary training command, twice, with the ``pair`` preset):

    python benchmarks/lsd/lsd_oracle.py convert --data runs/exp240 --out runs/exp240_full
    jaxsem lsd train --data runs/exp240 --workdir runs/pair_partial --config pair
    jaxsem lsd train --data runs/exp240_full --workdir runs/pair_full --config pair
    python benchmarks/lsd/lsd_oracle.py report --partial runs/pair_partial --oracle runs/pair_full \\
        --data runs/exp240 --full-data runs/exp240_full --name lsd_oracle [--reference ""]

``report`` writes ``<out>/<name>.{md,json,png}``: the validation NLL curves of both runs and, for
the final models on the validation buildings, the NLL per expert-path cell, the probability mass
the window puts on the expert path's cells, and the same for the uniform window.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"


def convert(data_dir: pathlib.Path, out_dir: pathlib.Path, progress: bool = True) -> int:
    """Writes the full-map copy of every shard (skipping those done); returns the count."""
    import numpy as np

    from jaxsem.lsd import with_full_map
    from jaxsem.training import check_stamp

    shards = sorted(data_dir.glob("expert_*.npz"))
    out_dir.mkdir(parents=True, exist_ok=True)
    # The copies are skipped by name on a rerun: only when they were made from the same shards.
    check_stamp(
        out_dir / "stamp.json",
        {"what": "full-map shards", "from": str(data_dir.resolve())},
        adopt=True,
        hint="give another output folder",
    )
    todo = [
        p for p in shards if not (out_dir / p.name).exists() or os.path.getmtime(out_dir / p.name) < os.path.getmtime(p)
    ]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="full-map shards", unit="shard")
    for p in todo:
        with np.load(p) as z:
            full = with_full_map(dict(z))
        tmp = out_dir / (p.name + ".tmp.npz")
        np.savez_compressed(tmp, **full)
        os.replace(tmp, out_dir / p.name)  # atomic: a killed run leaves no half shard
        if bar:
            bar.update(1)
    if bar:
        bar.close()
    return len(shards)


def _val_metrics(workdir, data_dir, batch: int = 32, model_from=None) -> dict:
    """NLL per path cell and path mass of a run's final model on its validation buildings
    (``model_from``: another model to score on that run's validation samples; "" the shipped one)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxsem.lsd import load_expert_data, load_model
    from jaxsem.lsd._data import split_by_building  # layers: white-box

    model, params, cfg, _ = load_model(str(workdir))
    if model_from is not None:  # the split stays the run's, so the samples are the same
        model, params, _, _ = load_model(model_from or None)
    data = load_expert_data(data_dir)
    _, val = split_by_building(data, cfg.val_fraction, cfg.seed, cfg.val_every_nth_building)

    @jax.jit
    def fwd(occ, sem, ctx, mask):
        lp = model.apply({"params": params}, occ, sem, ctx, deterministic=True).log_prob
        m = mask.astype(lp.dtype)
        n = jnp.maximum(m.sum((-2, -1)), 1.0)
        nll = -(lp * m).sum((-2, -1)) / n
        mass = (jnp.exp(lp) * m).sum((-2, -1))
        return nll, mass, n

    nll, mass, cells = [], [], []
    for i in range(0, len(val), batch):
        idx = val[i : i + batch]
        a, b, c = fwd(
            jnp.asarray(data["occupancy"][idx]),
            jnp.asarray(data["semantic"][idx]),
            jnp.asarray(data["context"][idx]),
            jnp.asarray(data["path_mask"][idx]),
        )
        nll.append(np.asarray(a))
        mass.append(np.asarray(b))
        cells.append(np.asarray(c))
    nll, mass, cells = np.concatenate(nll), np.concatenate(mass), np.concatenate(cells)
    k = data["occupancy"].shape[-1]
    n = len(val)
    return {
        "samples": int(n),
        "buildings": int(len(np.unique(data["building_seed"][val]))),
        "nll_mean": float(nll.mean()),
        "nll_se": float(nll.std(ddof=1) / np.sqrt(n)),
        "path_mass_median": float(np.median(mass)),
        "path_mass_mean": float(mass.mean()),
        "uniform_nll": float(np.log(k * k)),
        "uniform_path_mass_median": float(np.median(cells / (k * k))),
        "per_sample_nll": nll,
    }


def report(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from jaxsem.training import read_metrics

    runs = {"partial map (LSD)": args.partial, "full map (oracle)": args.oracle}
    curves = {name: read_metrics(wd) for name, wd in runs.items()}
    t0 = time.time()
    final = {
        "partial map (LSD)": _val_metrics(args.partial, args.data),
        "full map (oracle)": _val_metrics(args.oracle, args.full_data),
    }
    if args.reference is not None:
        name = f"reference: {args.reference or 'the shipped model'}, partial map"
        final[name] = _val_metrics(args.partial, args.data, model_from=args.reference)
        final[name].pop("per_sample_nll")
    a = final["partial map (LSD)"].pop("per_sample_nll")
    b = final["full map (oracle)"].pop("per_sample_nll")
    if len(a) != len(b):
        raise SystemExit("--data / --full-data: the validation sets differ (not the same samples?)")
    d = a - b
    paired = {
        "nll_gap_mean": float(d.mean()),
        "nll_gap_se": float(d.std(ddof=1) / np.sqrt(len(d))),
        "oracle_better": float((d > 0).mean()),
    }
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for name, m in curves.items():
        ax.plot([h["step"] for h in m], [h["val_nll"] for h in m], "o-", label=name)
    if any(curves.values()):
        first = next(m for m in curves.values() if m)
        ax.axhline(first[0]["uniform_nll"], color="k", ls="--", lw=0.8, label="uniform")
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    from lsd_training_curves import save_step_plot

    out = save_step_plot(fig, ax, "validation NLL per expert-path cell (nats)", args.out, args.name)
    steps = sorted({h["step"] for m in curves.values() for h in m})
    lines = [
        f"# LSD against its full-map oracle ({time.strftime('%Y-%m-%d')})",
        "",
        f"Partial: `{args.partial}` on `{args.data}`; oracle: `{args.oracle}` on `{args.full_data}`.",
        "",
        "| step | " + " | ".join(f"{n} val NLL" for n in runs) + " |",
        "|---|" + "---|" * len(runs),
    ]
    for s in steps:
        row = [next((f"{h['val_nll']:.3f}" for h in curves[n] if h["step"] == s), "") for n in runs]
        lines.append(f"| {s:,} | " + " | ".join(row) + " |")
    lines += [
        "",
        "| final model, validation buildings | samples | NLL per path cell | median path mass | mean path mass |",
        "|---|---|---|---|---|",
    ]
    for n, f in final.items():
        lines.append(
            f"| {n} | {f['samples']} ({f['buildings']} buildings) | {f['nll_mean']:.3f} +- {f['nll_se']:.3f} | "
            f"{f['path_mass_median']:.3f} | {f['path_mass_mean']:.3f} |"
        )
    f0 = final["partial map (LSD)"]
    lines.append(f"| uniform window | | {f0['uniform_nll']:.3f} | {f0['uniform_path_mass_median']:.4f} | |")
    lines += [
        "",
        f"Paired NLL gap (partial - oracle) per sample: {paired['nll_gap_mean']:.3f} +- {paired['nll_gap_se']:.3f} "
        f"nats; the oracle is better on {100 * paired['oracle_better']:.0f} % of the samples. "
        f"Evaluation {time.time() - t0:.0f} s.",
    ]
    (out / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    (out / f"{args.name}.json").write_text(
        json.dumps(
            {"runs": {n: str(w) for n, w in runs.items()}, "curves": curves, "final": final, "paired": paired}, indent=1
        )
    )
    print("\n".join(lines))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("convert", help="full-map copies of expert shards")
    c.add_argument("--data", required=True, help="folder of expert_*.npz shards")
    c.add_argument("--out", required=True, help="folder for the full-map shards")
    c.add_argument("--no-progress", action="store_true")
    r = sub.add_parser("report", help="compare a partial-map run with its oracle")
    r.add_argument("--partial", required=True, help="workdir of the partial-map run")
    r.add_argument("--oracle", required=True, help="workdir of the full-map run")
    r.add_argument("--data", required=True, help="the partial-map shards")
    r.add_argument("--full-data", required=True, help="the full-map shards")
    r.add_argument(
        "--reference",
        default=None,
        help="also score this model ('' the shipped one; a workdir or .npz) on the partial run's validation samples",
    )
    r.add_argument("--out", default=str(RESULTS))
    r.add_argument("--name", default="lsd_oracle")
    args = ap.parse_args(argv)
    if args.cmd == "convert":
        data = pathlib.Path(args.data)
        if not data.is_dir() or not any(data.glob("expert_*.npz")):
            raise SystemExit(f"--data: no expert_*.npz shards in {args.data!r}")
        n = convert(data, pathlib.Path(args.out), not args.no_progress)
        print(f"{n} full-map shards in {args.out}")
        return 0
    for flag in ("partial", "oracle"):
        if not (pathlib.Path(getattr(args, flag)) / "metrics.jsonl").exists():
            raise SystemExit(f"--{flag}: no metrics.jsonl in {getattr(args, flag)!r}")
    for flag in ("data", "full_data"):
        if not pathlib.Path(getattr(args, flag)).is_dir():
            raise SystemExit(f"--{flag.replace('_', '-')}: no such folder {getattr(args, flag)!r}")
    return report(args)


if __name__ == "__main__":
    sys.exit(main())

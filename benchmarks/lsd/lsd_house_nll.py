"""Benchmark: held-out NLL per expert-path cell of the shipped, house and oracle LSD models.

Expert samples (thesis 3.3.2) on buildings no model trained on: ``house`` family seeds from 1000
(the house fine-tune used seeds below 200) and ``test`` family seeds from 600; each model scores
the same samples, the oracle on their full-map copies (``lsd.with_full_map``). Paired
differences per sample with their standard error.

    python benchmarks/lsd/lsd_house_nll.py --oracle OUT/lsd_house_oracle.npz --json benchmarks/results/lsd_house_nll.json

``--family campus --model OUT/lsd_campus.npz`` scores a campus fine-tune the same way, on
``campus`` family seeds from 1000 (its fine-tune used seeds below 100). Several families
(``--family house campus``) score each family's shipped model on every family; ``--extra
NAME=MODEL`` adds a model to every set with its paired difference to each of the others (one
model for every map against the specialised ones):

    python benchmarks/lsd/lsd_house_nll.py --family house campus --extra mixed=OUT/lsd_mixed.npz --json OUT.json
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from jaxsem.lsd._train import evaluate_nll  # layers: white-box


def per_sample_nll(model, params, data):
    """``(nll (S,), has_path (S,))``: each sample's NLL per path cell (``lsd.evaluate_nll`` on
    that sample alone; 0 where a sample's path leaves the window at once, masked by has_path)."""
    import numpy as np

    has = np.asarray(data["path_mask"]).reshape(len(data["context"]), -1).any(axis=1)
    nll = np.array([evaluate_nll(model, params, data, np.array([i]), 2, batch_size=1) for i in range(len(has))])
    return nll, has


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--family", nargs="+", default=["house"], choices=("house", "campus"), help="the fine-tunes' building families"
    )
    p.add_argument("--model", default=None, help="the one family's model (.npz or shipped name; default: its name)")
    p.add_argument("--extra", action="append", default=[], help="NAME=MODEL: another model scored on every set")
    p.add_argument("--house-seeds", "--family-seeds", type=int, nargs="+", default=[1000, 1001, 1002])
    p.add_argument("--test-seeds", type=int, nargs="+", default=[600])
    p.add_argument("--samples", type=int, default=100, help="expert samples per building")
    p.add_argument("--oracle", default=None, help="the full-map oracle model (.npz), optional")
    p.add_argument("--json", required=True)
    args = p.parse_args(argv)
    if args.model and len(args.family) > 1:
        p.error("--model: one --family only (several families use their shipped models)")
    extra = {}
    for item in args.extra:
        name, _, path = item.partition("=")
        if not name or not path or name in ("shipped", "oracle", *args.family):
            p.error(f"--extra: expected NAME=MODEL with a new name, got {item!r}")
        extra[name] = path

    import numpy as np

    from jaxsem import lsd, planning
    from jaxsem.scripting import atomic_write_text

    models = {"shipped": lsd.load_model("default")}
    models |= {f: lsd.load_model(args.model or f) for f in args.family}
    models |= {name: lsd.load_model(path) for name, path in extra.items()}
    cfg = lsd.ExpertConfig(samples_per_building=args.samples)
    result = {"command": "python benchmarks/lsd/lsd_house_nll.py " + " ".join(argv or sys.argv[1:]), "sets": {}}
    for family, seeds in (*((f, args.house_seeds) for f in args.family), ("test", args.test_seeds)):
        shards = []
        for s in seeds:
            b = planning.generate_building(s, family)
            d = lsd.generate_expert_samples(b, s, cfg)
            shards.append((d, lsd.with_full_map(d, b) if args.oracle else None))
        keys = [k for k in shards[0][0] if np.ndim(shards[0][0][k]) > 0 and k not in ("path_cells", "path_offsets")]
        data = {k: np.concatenate([d[k] for d, _ in shards]) for k in keys}
        scores = {}
        has = None
        for name, (model, params, _, _) in models.items():
            nll, h = per_sample_nll(model, params, data)
            scores[name], has = nll, h if has is None else has & h
        if args.oracle:
            full = {k: np.concatenate([f[k] for _, f in shards]) for k in keys}
            model, params, _, _ = lsd.load_model(args.oracle)
            scores["oracle"], h = per_sample_nll(model, params, full)
            has &= h
        row = {"buildings": seeds, "samples": int(has.sum()), "uniform": float(np.log(160 * 160))}
        for name, v in scores.items():
            row[name] = float(v[has].mean())
        pairs = [("shipped", f) for f in args.family] + [(f, "oracle") for f in args.family]
        pairs += [(x, m) for x in extra for m in scores if m != x]
        for a, b_ in pairs:
            if a in scores and b_ in scores:
                d = scores[a][has] - scores[b_][has]
                row[f"{a}_minus_{b_}"] = [float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d)))]
        result["sets"][family] = row
        print(family, row, flush=True)
    atomic_write_text(pathlib.Path(args.json), json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

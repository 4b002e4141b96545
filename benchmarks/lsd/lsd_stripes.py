"""Stripes in LSD distributions: the periodic block pattern of transposed-convolution upsampling,
measured as spectral peaks, for several models on the same expert samples (issue 11 item 5).

For each model the predicted log-distribution of every sample (160 x 160 window, context branch
on) is mean-removed and Fourier transformed; the power along each axis' frequency is averaged
over samples and axes. A 2 x 2 stride-2 transposed convolution gives each output cell one of four
kernels by its position parity, so each upsampling stage adds power at one frequency: periods of
2, 4, 8 and 16 cells for the four stages from the 10 x 10 latent. The table gives, at each of
those frequencies, the power over the mean power of the frequencies 2-3 bins either side (1 = no
peak). Also each model's NLL per expert-path cell on the same samples. The figure shows three
samples per model.

    jaxsem lsd data --out runs/stripes_data --family test --buildings 4 --first-seed 600 \\
        --samples-per-building 24 --workers 1 --no-figure
    python benchmarks/lsd/lsd_stripes.py --data runs/stripes_data --models train/checkpoints/lsd_scale shipped
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
PERIODS = (16, 8, 4, 2)


def _log_prob(model, params, data, batch=16):
    import jax
    import numpy as np

    @jax.jit
    def fwd(p, occ, sem, ctx):
        return model.apply({"params": p}, occ, sem, ctx, deterministic=True).log_prob

    out = []
    for i in range(0, len(data["context"]), batch):
        sl = slice(i, i + batch)
        out.append(np.asarray(fwd(params, data["occupancy"][sl], data["semantic"][sl], data["context"][sl])))
    return np.concatenate(out)


def peak_ratios(log_prob):
    """Power at the frequency of each period in :data:`PERIODS` over that of its neighbours."""
    import numpy as np

    x = log_prob - log_prob.mean(axis=(-2, -1), keepdims=True)
    p = np.abs(np.fft.fft2(x)) ** 2
    spec = (p.sum(-2) + p.sum(-1)).mean(0)
    k = x.shape[-1]
    ratios = []
    for period in PERIODS:
        f = k // period
        nb = [spec[f + d] for d in (-3, -2, 2, 3) if 0 < f + d <= k // 2]
        ratios.append(float(spec[f] / np.mean(nb)))
    return ratios


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--data", required=True, help="folder of expert_*.npz shards (jaxsem lsd data)")
    ap.add_argument("--models", nargs="+", default=["shipped"], help="'shipped' or exported .npz / training workdirs")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--name", default="lsd_stripes")
    args = ap.parse_args(argv)
    for m in args.models:
        if m != "shipped" and not pathlib.Path(m).exists():
            raise SystemExit(f"--models: no such model {m!r}")
    if not pathlib.Path(args.data).exists():
        raise SystemExit(f"--data: no such folder {args.data!r}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from jaxsem.lsd import load_expert_data, load_model
    from jaxsem.lsd._train import evaluate_nll  # layers: white-box

    data = load_expert_data(args.data)
    n = len(data["context"])
    rows, shown = [], []
    for m in args.models:
        model, params, cfg, _ = load_model(None if m == "shipped" else m)
        lp = _log_prob(model, params, data)
        nll = evaluate_nll(model, params, data, np.arange(n), stage=2)
        rows.append((m, cfg.model.upsample, peak_ratios(lp), nll))
        shown.append(lp[:: max(1, n // 3)][:3])
        print(f"{m}: upsample {cfg.model.upsample}, peaks {np.round(rows[-1][2], 2)}, NLL {nll:.3f}", flush=True)

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(len(rows), 3, figsize=(9, 3.1 * len(rows)), squeeze=False)
    for r, ((m, up, _, _), lps) in enumerate(zip(rows, shown)):
        for c, lp in enumerate(lps):
            axes[r, c].imshow(lp / np.log(10.0), origin="lower", cmap="viridis")
            axes[r, c].set_title(f"{pathlib.Path(m).name} ({up})", fontsize=8)
            axes[r, c].axis("off")
    fig.suptitle("log10 p over the window, same samples per column", fontsize=9)
    fig.tight_layout()
    tmp = out / f".{args.name}.png.tmp.png"
    fig.savefig(tmp, dpi=70)
    plt.close(fig)
    tmp.replace(out / f"{args.name}.png")

    lines = [
        f"## LSD distribution stripes (`{args.name}`)",
        "",
        f"Command: `python benchmarks/lsd/lsd_stripes.py {' '.join(argv if argv is not None else sys.argv[1:])}`",
        "",
        f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {n} expert samples from {args.data}",
        "",
        "| model | upsample | " + " | ".join(f"peak, period {p}" for p in PERIODS) + " | NLL / path cell |",
        "|---|---|" + "---|" * len(PERIODS) + "---|",
    ]
    for m, up, ratios, nll in rows:
        lines.append(f"| {m} | {up} | " + " | ".join(f"{v:.1f}" for v in ratios) + f" | {nll:.3f} |")
    lines += [
        "",
        "Peak: power at that period's frequency over its neighbours' (1 = none).",
        "",
        f"![samples]({args.name}.png)",
        "",
    ]
    tmp = out / f".{args.name}.md.tmp"
    tmp.write_text("\n".join(lines))
    tmp.replace(out / f"{args.name}.md")
    print(f"wrote {out / args.name}.md, .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

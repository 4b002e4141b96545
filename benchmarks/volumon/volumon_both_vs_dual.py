"""VoluMon "Both" against "Dual only" trained alike (issue 10: Both >= Dual, thesis Table 5.1).

Two training runs of the fast preset with the same seed, steps and learning-rate schedule, one
with every loss term (Both) and one with the stereo-box term only (Dual): their evaluation curves
on the training seed's held-out stream at equal steps, and both final models on held-out seeds
that no run or tuning used (network only, no PostOpt: Dual has no depth points to refine with).

    python benchmarks/volumon/volumon_both_vs_dual.py --both runs/vm_ray --dual runs/vm_dual --seeds 404 505 606
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import sys

import numpy as np

KEYS = ("median_size_rel_error", "size_corr", "median_center_error_m", "trans_auc", "adi_auc", "iou")


def _evals(workdir: pathlib.Path) -> dict[int, dict]:
    out = {}
    for line in (workdir / "metrics.jsonl").read_text().splitlines():
        rec = json.loads(line)
        if "eval" in rec:
            out[int(rec["step"])] = rec["eval"]
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--both", type=pathlib.Path, required=True, help="workdir of the Both run")
    p.add_argument("--dual", type=pathlib.Path, required=True, help="workdir of the Dual-only run")
    p.add_argument("--seeds", type=int, nargs="+", default=[404, 505, 606])
    p.add_argument("--num", type=int, default=256)
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path(__file__).resolve().parents[1] / "results")
    a = p.parse_args(argv)
    for flag, d in (("--both", a.both), ("--dual", a.dual)):
        if not (d / "metrics.jsonl").exists() or not (d / "config.json").exists():
            p.error(f"{flag}: {d} is not a training run (no metrics.jsonl / config.json)")

    from jaxsem.volumon import evaluate_held_out, load_pretrained

    curves = {"both": _evals(a.both), "dual": _evals(a.dual)}
    common = sorted(set(curves["both"]) & set(curves["dual"]))
    windows = [(lo, hi) for lo, hi in ((1000, 5000), (5000, 10000), (10000, 16000), (16000, 18500))]
    rows = []
    for lo, hi in windows:
        steps = [s for s in common if lo < s <= hi]
        if steps:
            rows.append(
                (
                    lo,
                    hi,
                    len(steps),
                    {v: {k: float(np.mean([curves[v][s][k] for s in steps])) for k in KEYS} for v in curves},
                )
            )
    held = {}
    for name, wd in (("both", a.both), ("dual", a.dual)):
        model, variables, cfg, meta = load_pretrained(wd)
        per = [evaluate_held_out(model, variables, cfg, s, a.num) for s in a.seeds]
        held[name] = {"step": meta.get("step"), **{k: float(np.mean([r[k] for r in per])) for k in KEYS}}
        held[name]["per_seed_trans_auc"] = [r["trans_auc"] for r in per]
        held[name]["per_seed_adi_auc"] = [r["adi_auc"] for r in per]
    cmd = "python " + " ".join([os.path.relpath(__file__)] + (sys.argv[1:] if argv is None else list(argv)))
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "## VoluMon Both against Dual only, trained alike (`volumon_both_vs_dual`)",
        "",
        f"Command: `{cmd}`  ",
        f"Date: {date}  ",
        f"Machine: {os.cpu_count()}-core CPU (shared)",
        "",
        "Curves: mean over the evaluations in each step window, training seed's held-out stream (128 detections each).",
        "",
        "| steps | evals | variant | size err | size corr | centre (m) | trans AUC | ADI AUC | mean IoU |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for lo, hi, n, m in rows:
        for v in ("both", "dual"):
            x = m[v]
            lines.append(
                f"| {lo}-{hi} | {n} | {v} | {x['median_size_rel_error']:.3f} | {x['size_corr']:.2f} | "
                f"{x['median_center_error_m']:.3f} | {x['trans_auc']:.2f} | {x['adi_auc']:.2f} | {x['iou']:.3f} |"
            )
    lines += [
        "",
        f"Final models on held-out seeds {a.seeds} x {a.num} (mean over seeds; network only):",
        "",
        "| variant | step | size err | size corr | centre (m) | trans AUC | ADI AUC | mean IoU | trans AUC per seed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for v in ("both", "dual"):
        x = held[v]
        lines.append(
            f"| {v} | {x['step']} | {x['median_size_rel_error']:.3f} | {x['size_corr']:.2f} | "
            f"{x['median_center_error_m']:.3f} | {x['trans_auc']:.2f} | {x['adi_auc']:.2f} | {x['iou']:.3f} | "
            f"{', '.join(f'{t:.2f}' for t in x['per_seed_trans_auc'])} |"
        )
    ok = all(held["both"][k] >= held["dual"][k] for k in ("trans_auc", "adi_auc", "iou"))
    lines += [
        "",
        f"Both >= Dual on translation AUC, ADI AUC and IoU (held-out, mean): {'yes' if ok else 'no'}. "
        "Thesis Table 5.1: Both 5.80 / 7.60 / 0.31 against Dual only 4.26 / 6.50 / 0.19 (trans / ADI / IoU AUC).",
    ]
    a.out.mkdir(parents=True, exist_ok=True)
    for suffix, text in (
        (".json", json.dumps({"command": cmd, "date": date, "windows": rows, "held_out": held}, indent=1)),
        (".md", "\n".join(lines) + "\n"),
    ):
        tmp = a.out / f"volumon_both_vs_dual{suffix}.tmp"
        tmp.write_text(text)
        tmp.replace(a.out / f"volumon_both_vs_dual{suffix}")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""VoluMon demo: train on a small synthetic stereo set, predict ellipsoids on held-out images.

The training set is rendered on the fly by :mod:`jaxsem.volumon`'s exact ray-caster (stereo
boxes, depth, masks of cracker-box-like cuboids over random backgrounds); the held-out split
has unseen backgrounds and poses. ``quick=True`` uses the test-sized network (a small CNN
backbone at 32 x 32, VoluMon Dual only) so it finishes in about a minute; the full demo trains the
CPU-sized MobileNetV2 network (VoluMon Both) for a few minutes and refines with PostOpt. The
checkpoint is cached in ``out_dir/volumon_run`` (a second run resumes / reuses it).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np


def run(out_dir: pathlib.Path, quick: bool) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsem.volumon import draw_predictions, evaluate_predictions, get_config, make_batch, make_predict_fn, postopt, train_and_evaluate

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if quick:
        cfg = get_config("dual", "tiny").replace(num_train=64, batch_size=8, num_steps=40, learning_rate=3e-3,
                                                 checkpoint_every=40, log_every=10)
        num_test = 16
    else:
        cfg = get_config("both", "cpu").replace(num_steps=300, batch_size=16, num_train=800, num_eval=0,
                                                checkpoint_every=100)
        num_test = 64
    res = train_and_evaluate(cfg, out_dir / "volumon_run", progress=False)
    st = res["state"]
    variables = {"params": st["params"], "batch_stats": st["batch_stats"]}
    b = make_batch(cfg.seed, np.arange(num_test), cfg.scene, cfg.model.input_size, cfg.model.global_padding, "test",
                   keep_images=True)
    phi, ell, _ = make_predict_fn(res["model"], cfg)(variables, b["local"], b["global"], b["box_input"], b["K"], b["class_id"])
    rows = {"network": evaluate_predictions(ell._asdict(), b)}
    if not quick:
        _, ell_po, _ = postopt(phi, b["box_input"], b["K"], b["points"], b["point_mask"], cfg.recon, cfg.loss, 50)
        rows["network + PostOpt(50)"] = evaluate_predictions(ell_po._asdict(), b)
    K = np.asarray(b["K"][0])
    fig, axes = plt.subplots(2, 4, figsize=(12, 5))
    for i, ax in enumerate(axes.ravel()):
        e = [np.asarray(x[i]) for x in ell]
        truth = [(np.asarray(b["gt_rotation"][i]), np.asarray(b["gt_center"][i]), np.asarray(b["gt_half_extents"][i]))]
        draw_predictions(ax, np.asarray(b["image"][i]), [e], K, np.asarray(b["box_input"][i:i + 1]), truth)
    fig.suptitle(f"VoluMon {cfg.variant} on held-out images (blue conic / orange box: prediction; dashed: truth)")
    fig.tight_layout()
    fig.savefig(out_dir / "volumon_predictions.png", dpi=100)
    plt.close(fig)
    hist = res["history"]
    if hist:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        steps = sorted(hist)
        for k in ("total", "dual", "primal"):
            ax.semilogy(steps, [max(hist[s][k], 1e-12) for s in steps], label=k)
        ax.set_xlabel("step")
        ax.legend()
        fig.tight_layout()
        fig.savefig(out_dir / "volumon_loss.png", dpi=100)
        plt.close(fig)
    (out_dir / "volumon.json").write_text(json.dumps({"variant": cfg.variant, "steps": cfg.num_steps, "rows": rows}, indent=1))
    lines = [f"VoluMon {cfg.variant}, {cfg.num_steps} steps, {rows['network']['n']} held-out detections",
             f"{'method':<24}{'trans AUC':>10}{'ADI AUC':>10}{'3D IoU':>9}{'trans med (m)':>15}"]
    for name, r in rows.items():
        lines.append(f"{name:<24}{r['trans_auc']:>10.2f}{r['adi_auc']:>10.2f}{r['iou']:>9.2f}{r['trans_median']:>15.3f}")
    return "\n".join(lines)

"""VoluMon demo: the shipped model on held-out synthetic images (or train one from scratch).

By default the demo loads the model that ships in the package (``jaxsem/volumon/pretrained``,
see its ``MODEL_CARD.md``), predicts ellipsoids for held-out detections of four classes (cracker
box, ball, melon, soup can; unseen backgrounds), refines them with PostOpt and draws them.
``train=True`` (or no shipped model) runs the older path below instead:

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

from jaxsem.quadrics import Ellipsoid
from jaxsem.volumon import (
    PRETRAINED_DIR,
    draw_predictions,
    evaluate_held_out,
    evaluate_predictions,
    get_config,
    held_out_set,
    load_pretrained,
    make_batch,
    postopt,
    predict_batch,
    train_and_evaluate,
)

from ..scripting import atomic_savefig, atomic_write_text


def run(out_dir: pathlib.Path, quick: bool, train: bool = False) -> str:
    if not train and (PRETRAINED_DIR / "volumon_fast.npz").exists():
        return _run_shipped(pathlib.Path(out_dir), quick)
    return _run_training(pathlib.Path(out_dir), quick)


def _save_predictions(path: pathlib.Path, b: dict, ell, title: str) -> None:
    """The first 8 held-out images of batch ``b`` with the predicted ellipsoids ``ell`` (camera
    frame) and the true cuboids drawn over them, saved as one figure."""
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)

    K = np.asarray(b["K"][0])
    fig, axes = plt.subplots(2, 4, figsize=(12, 5))
    for i, ax in enumerate(axes.ravel()):
        e = Ellipsoid(*(np.asarray(x[i]) for x in ell))
        truth = [Ellipsoid(*(np.asarray(b[k][i]) for k in ("gt_rotation", "gt_center", "gt_half_extents")))]
        draw_predictions(ax, np.asarray(b["image"][i]), [e], K, np.asarray(b["box_input"][i : i + 1]), truth)
    fig.suptitle(title)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=100)
    plt.close(fig)


def _run_shipped(out_dir: pathlib.Path, quick: bool) -> str:
    import matplotlib  # deferred: matplotlib is optional (the sim extra)

    matplotlib.use("Agg")

    out_dir.mkdir(parents=True, exist_ok=True)
    model, variables, cfg, meta = load_pretrained()
    num = 16 if quick else 64
    res = evaluate_held_out(model, variables, cfg, seed=1, num=num, postopt_steps=0 if quick else 50)
    b = held_out_set(1, 8, cfg.scene, cfg.model.input_size, cfg.model.global_padding, keep_images=True, batch_size=8)
    _, ell, _ = predict_batch(model, cfg, variables, b)
    _save_predictions(
        out_dir / "volumon_predictions.png",
        b,
        ell,
        f"VoluMon shipped model (step {meta.get('step')}) on held-out images (blue / orange: prediction; dashed: truth)",
    )
    atomic_write_text(
        out_dir / "volumon.json", json.dumps({"model": meta.get("name"), "step": meta.get("step"), **res}, indent=1)
    )
    lines = [
        f"VoluMon shipped model (step {meta.get('step')}), {res['num']} held-out detections of 4 classes",
        f"{'method':<22}{'size err':>9}{'size corr':>10}{'trans AUC':>10}{'ADI AUC':>9}{'centre (m)':>11}",
        (
            f"{'network':<22}{res['median_size_rel_error']:>9.2f}{res['size_corr']:>10.2f}{res['trans_auc']:>10.2f}"
            f"{res['adi_auc']:>9.2f}{res['median_center_error_m']:>11.3f}"
        ),
    ]
    if "postopt_trans_auc" in res:
        lines.append(
            f"{'network + PostOpt(50)':<22}{res['postopt_median_size_rel_error']:>9.2f}{res['postopt_size_corr']:>10.2f}"
            f"{res['postopt_trans_auc']:>10.2f}{res['postopt_adi_auc']:>9.2f}{res['postopt_median_center_error_m']:>11.3f}"
        )
    lines.append(f"constant mean-size baseline: size err {res['baseline_median_size_rel_error']:.2f}")
    return "\n".join(lines)


def _run_training(out_dir: pathlib.Path, quick: bool) -> str:
    import matplotlib  # deferred: matplotlib is optional (the sim extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)

    out_dir.mkdir(parents=True, exist_ok=True)
    if quick:
        cfg = get_config("dual", "tiny").replace(
            num_train=64, batch_size=8, num_steps=40, learning_rate=3e-3, checkpoint_every=40, log_every=10
        )
        num_test = 16
    else:
        cfg = get_config("both", "cpu").replace(
            num_steps=300, batch_size=16, num_train=800, num_eval=0, checkpoint_every=100, data="host"
        )
        num_test = 64
    res = train_and_evaluate(cfg, out_dir / "volumon_run", progress=False)
    st = res["state"]
    variables = {"params": st["params"], "batch_stats": st["batch_stats"]}
    b = make_batch(
        cfg.seed,
        np.arange(num_test),
        cfg.scene,
        cfg.model.input_size,
        cfg.model.global_padding,
        "test",
        keep_images=True,
    )
    phi, ell, _ = predict_batch(res["model"], cfg, variables, b)
    rows = {"network": evaluate_predictions(ell._asdict(), b)}
    if not quick:
        _, ell_po, _ = postopt(
            phi,
            b["box_input"],
            b["K"],
            b["points"],
            b["point_mask"],
            cfg.recon,
            cfg.loss,
            50,
            shape=b.get("class_shape"),
        )
        rows["network + PostOpt(50)"] = evaluate_predictions(ell_po._asdict(), b)
    _save_predictions(
        out_dir / "volumon_predictions.png",
        b,
        ell,
        f"VoluMon {cfg.variant} on held-out images (blue conic / orange box: prediction; dashed: truth)",
    )
    hist = res["history"]
    if hist:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        steps = sorted(hist)
        for k in ("total", "dual", "primal"):
            ax.semilogy(steps, [max(hist[s][k], 1e-12) for s in steps], label=k)
        ax.set_xlabel("step")
        ax.legend()
        fig.tight_layout()
        atomic_savefig(fig, out_dir / "volumon_loss.png", dpi=100)
        plt.close(fig)
    atomic_write_text(
        out_dir / "volumon.json", json.dumps({"variant": cfg.variant, "steps": cfg.num_steps, "rows": rows}, indent=1)
    )
    lines = [
        f"VoluMon {cfg.variant}, {cfg.num_steps} steps, {rows['network']['n']} held-out detections",
        f"{'method':<24}{'trans AUC':>10}{'ADI AUC':>10}{'3D IoU':>9}{'trans med (m)':>15}",
    ]
    for name, r in rows.items():
        lines.append(
            f"{name:<24}{r['trans_auc']:>10.2f}{r['adi_auc']:>10.2f}{r['iou']:>9.2f}{r['trans_median']:>15.3f}"
        )
    return "\n".join(lines)

"""VoluMon on your own images: predict an ellipsoid from an image and a box, then fine-tune the
shipped model on your own 2-D labels (boxes in a stereo pair; no 3-D ground truth).

A user has stereo photos of their objects, a detector's boxes in the left image and labelled boxes
in both images. Here the photos are rendered (so the answer is known): soup cans on the held-out
background style, 0.6-0.9 m from the camera. Then:

1. ``volumon.load_pretrained`` + ``volumon.prepare_inputs`` + ``volumon.make_predict_fn``: one
   ellipsoid per box, in the camera frame;
2. ``volumon.label_batch`` per stereo pair, joined with ``LabelBatch.concatenate``: the typed
   batch of 2-D labels (crops, boxes, K, baseline, class), nothing 3-D;
3. ``volumon.train_and_evaluate(..., batch_fn=..., init_variables=...)``: a short fine-tune that
   starts from the shipped weights and resumes from its checkpoints like any training run.

Run: ``python examples/volumon_on_my_images.py [WORKDIR]`` (about two minutes on a 2-core CPU).
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile

import jax
import numpy as np

from jaxsem import quadrics as q, volumon

K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])
BASELINE = 0.1
SOUP_CAN = volumon.VOLUMON_CLASS_NAMES.index("soup_can")
HALF = np.array([0.0335, 0.0335, 0.051])  # a soup can: 6.7 cm across, 10.2 cm tall


def my_photos(seed: int, count: int):
    """Stereo photos of a can with their boxes (rendered here; a user's come from a camera)."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        R = np.asarray(q.random_rotation(jax.random.PRNGKey(seed * 1000 + k)))
        center = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(0.6, 0.9)])
        view = volumon.render_object_stereo(
            R, center, HALF, SOUP_CAN, K, BASELINE, 240, 320, seed * 1000 + k, split_test=True
        )
        yield np.asarray(view.left), np.asarray(view.box_left), np.asarray(view.box_right), center


def centre_errors(predict, variables, config, photos) -> np.ndarray:
    out = []
    for image, box, _, center in photos:
        local, glob = volumon.prepare_inputs(image, box[None], config=config)
        _, ell, _ = predict(variables, local, glob, box[None], K[None], np.array([SOUP_CAN]))
        out.append(float(np.linalg.norm(np.asarray(ell.center)[0] - center)))
    return np.array(out)


def main(workdir=None) -> dict:
    model, variables, config, _ = volumon.load_pretrained()  # the shipped object model
    predict = volumon.make_predict_fn(model, config)
    held_out = list(my_photos(seed=2, count=6))

    # 1. Predict from an image and a box.
    before = centre_errors(predict, variables, config, held_out)
    print(f"shipped model: median centre error {100 * np.median(before):.1f} cm on {len(held_out)} photos")

    # 2. A typed batch of 2-D labels: one label_batch per stereo pair, joined.
    labelled = [
        volumon.label_batch(img, box_l[None], box_r[None], K, BASELINE, np.array([SOUP_CAN]), config=config)
        for img, box_l, box_r, _ in my_photos(seed=1, count=8)
    ]
    batch = volumon.LabelBatch.concatenate(labelled).as_train_batch()

    # 3. Fine-tune from the shipped weights on those labels (weak 'both' loss: boxes only here).
    tune = dataclasses.replace(
        config,
        data="directory",
        batch_size=8,
        num_steps=40,
        learning_rate=1e-4,
        checkpoint_every=20,
        num_eval=0,
        log_every=1,
    )
    workdir = workdir or tempfile.mkdtemp(prefix="volumon_finetune_")
    out = volumon.train_and_evaluate(
        tune, workdir, batch_fn=lambda step: batch, init_variables=variables, progress=False
    )
    tuned = {"params": out["state"]["params"], "batch_stats": out["state"]["batch_stats"]}
    after = centre_errors(predict, tuned, config, held_out)
    losses = [float(out["history"][s]["dual"]) for s in sorted(out["history"])]
    print(f"fine-tuned on 8 labelled pairs: dual loss {np.mean(losses[:5]):.3f} -> {np.mean(losses[-5:]):.3f}")
    print(f"fine-tuned model: median centre error {100 * np.median(after):.1f} cm")
    return {
        "before_m": before.tolist(),
        "after_m": after.tolist(),
        "first_dual": float(np.mean(losses[:5])),
        "last_dual": float(np.mean(losses[-5:])),
        "workdir": str(workdir),
    }


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)

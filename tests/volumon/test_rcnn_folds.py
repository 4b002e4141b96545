"""Cross-validation folds scored as one set (jaxsem.volumon.rcnn.evaluate_folds): two stand-in
detectors, each on its own frames, score exactly as one detector that answers every frame as the
fold's detector would, scored on all frames at once by evaluate_detections."""

import dataclasses
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem.models import RCNNConfig
from jaxsem.volumon import rcnn

N, D = 6, 3  # frames, detection slots


class _Centre(NamedTuple):
    center: jnp.ndarray


class _Dets(NamedTuple):
    box: jnp.ndarray
    class_id: jnp.ndarray
    score: jnp.ndarray
    ellipsoid: _Centre
    valid: jnp.ndarray


class _Table:
    """A stand-in network: the frame's index is written in its first pixel, and the variables
    hold each frame's detections."""

    def apply(self, v, img, K):
        i = jnp.round(img[:, 0, 0, 0] * 255).astype(jnp.int32)
        return _Dets(v["box"][i], v["class_id"][i], v["score"][i], _Centre(v["center"][i]), v["valid"][i])


def _frames():
    image = np.zeros((N, 8, 8, 3), np.uint8)
    image[:, 0, 0, 0] = np.arange(N)
    boxes = np.tile(np.array([[10.0, 10.0, 40.0, 50.0], [60.0, 20.0, 90.0, 70.0]]), (N, 1, 1))
    centre = np.tile(np.array([[0.1, 0.0, 1.0], [-0.1, 0.05, 1.2]]), (N, 1, 1))
    return {
        "image": image,
        "K": np.tile(np.eye(3), (N, 1, 1)),
        "boxes": boxes,
        "class_id": np.tile(np.array([0, 1]), (N, 1)),
        "box_valid": np.ones((N, 2), bool),
        "visible_fraction": np.ones((N, 2)),
        "gt_center": centre,
    }


def _table(arrays, offset_m, false_on=(), miss_on=()):
    """Each true object found with its exact box and its centre ``offset_m`` off along x; on the
    frames ``false_on`` also a confident class-0 box where there is nothing; on ``miss_on`` the
    class-1 object missed."""
    box = np.zeros((N, D, 4))
    box[:, :2] = arrays["boxes"]
    box[:, 2] = [120.0, 120.0, 150.0, 150.0]
    centre = np.zeros((N, D, 3))
    centre[:, :2] = arrays["gt_center"] + [offset_m, 0.0, 0.0]
    valid = np.zeros((N, D), bool)
    valid[:, :2] = True
    valid[list(false_on), 2] = True
    valid[list(miss_on), 1] = False
    return {
        "box": jnp.asarray(box),
        "class_id": jnp.zeros((N, D), jnp.int32).at[:, 1].set(1),
        "score": jnp.asarray(np.tile([0.8, 0.7, 0.95], (N, 1))),
        "center": jnp.asarray(centre),
        "valid": jnp.asarray(valid),
    }


def _part(arrays, lo, hi):
    return {k: v[lo:hi] for k, v in arrays.items()}


def test_folds_score_as_one_detector_on_all_frames(monkeypatch):
    monkeypatch.setattr(rcnn, "detect", lambda out, K, config: out)
    config = dataclasses.replace(RCNNConfig(), num_classes=2)
    arrays = _frames()
    a = _table(arrays, 0.01, false_on=(1,))
    b = _table(arrays, 0.03, miss_on=(4,))
    joined = {k: jnp.concatenate([a[k][:3], b[k][3:]]) for k in a}
    pooled = rcnn.evaluate_folds(
        [(_Table(), a, _part(arrays, 0, 3)), (_Table(), b, _part(arrays, 3, N))], config, batch=2
    )
    whole = rcnn.evaluate_detections(_Table(), joined, arrays, config, batch=4)
    assert pooled == pytest.approx(whole)
    assert pooled["num_matched"] == 2 * N - 1
    # six matches 1 cm off and five 3 cm off: the sixth of eleven is 1 cm; the second fold alone reads 3
    assert pooled["median_center_error_m"] == pytest.approx(0.01, abs=1e-6)
    second = rcnn.evaluate_folds([(_Table(), b, _part(arrays, 3, N))], config)
    assert second["median_center_error_m"] == pytest.approx(0.03, abs=1e-6)
    # one fold alone knows nothing of the other's miss or false box
    alone = rcnn.evaluate_folds([(_Table(), a, _part(arrays, 0, 3))], config)
    assert alone["num_matched"] == 6 and alone["ap50"] != pooled["ap50"]


def test_no_fold_is_refused():
    with pytest.raises(ValueError, match="folds"):
        rcnn.evaluate_folds([], RCNNConfig())

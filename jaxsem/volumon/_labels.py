"""2-D labels as a typed training batch: what a user can label, with no 3-D ground truth.

VoluMon's weak supervision (thesis 5.3) needs, per object, the box it is cut from, its labelled
boxes in a stereo pair (the dual loss, eq. 5.10-5.11), the intrinsics and baseline, its class,
and optionally surface points from depth (the primal loss, eq. 5.12). :class:`LabelBatch` holds
exactly that, and :func:`label_batch` builds it from one image, its boxes and ``K``:

    batch = volumon.label_batch(left_image, boxes_left, boxes_right, K, baseline, class_id,
                                config=config)
    train_and_evaluate(config, workdir, batch_fn=lambda step: batch.as_train_batch(), ...)

``as_train_batch`` fills the training loop's 3-D ground-truth keys (``gt_*``) with placeholders
and marks the batch as 2-D only, so a config whose loss needs them (the fully supervised oracle,
``alpha_O > 0``) is refused with a ``ValueError`` instead of training on placeholders.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np

from ._pretrained import prepare_inputs
from ._synthetic import CLASSES, SHAPE_IDS
from ._train import LABELS_2D_ONLY

#: a field of a label batch: numpy on the host (as built), jax arrays once put on a device
Array = np.ndarray | jax.Array


class LabelBatch(NamedTuple):
    """A batch of B objects labelled in 2-D (a pytree; B leads every field).

    local, global_image: (B, S, S, 3) float32 network inputs (:func:`prepare_inputs`);
    box_input: (B, 4) the box the inputs were cut from (a detector's); box_left, box_right:
    (B, 4) the labelled boxes in the left and right image; K: (B, 3, 3); baseline: (B,) metres
    (right camera at +x of the left one); class_id: (B,) int32 row of the network's class head;
    class_shape: (B,) int32 ``SHAPE_IDS`` of each class; points: (B, J, 3) surface points in the
    left camera frame with point_mask (B, J); sample_mask: (B,) bool, samples that count.
    """

    local: Array
    global_image: Array
    box_input: Array
    box_left: Array
    box_right: Array
    K: Array
    baseline: Array
    class_id: Array
    class_shape: Array
    points: Array
    point_mask: Array
    sample_mask: Array

    def as_train_batch(self) -> dict:
        """The dict :func:`jaxsem.volumon.train_and_evaluate`'s ``batch_fn`` returns: the keys of
        :data:`jaxsem.volumon._train.TRAIN_KEYS`, the 3-D ground truth as placeholders (identity
        rotation, zero centre, unit half extents; no loss of a weak config reads them) and
        ``labels_2d_only`` set."""
        b = int(np.shape(self.box_left)[0])
        return {
            "local": np.asarray(self.local, np.float32),
            "global": np.asarray(self.global_image, np.float32),
            "box_input": np.asarray(self.box_input, np.float32),
            "box_left": np.asarray(self.box_left, np.float32),
            "box_right": np.asarray(self.box_right, np.float32),
            "K": np.asarray(self.K, np.float32),
            "baseline": np.asarray(self.baseline, np.float32),
            "points": np.asarray(self.points, np.float32),
            "point_mask": np.asarray(self.point_mask, bool),
            "class_id": np.asarray(self.class_id, np.int32),
            "sample_mask": np.asarray(self.sample_mask, bool),
            "class_shape": np.asarray(self.class_shape, np.int32),
            "gt_rotation": np.broadcast_to(np.eye(3, dtype=np.float32), (b, 3, 3)).copy(),
            "gt_center": np.zeros((b, 3), np.float32),
            "gt_half_extents": np.ones((b, 3), np.float32),
            LABELS_2D_ONLY: True,
        }

    @staticmethod
    def concatenate(batches: Sequence[LabelBatch]) -> LabelBatch:
        """One batch of the samples of several (e.g. one :func:`label_batch` per image)."""
        if not batches:
            raise ValueError("batches: expected at least one LabelBatch, got none")
        return jax.tree.map(lambda *x: np.concatenate([np.asarray(a) for a in x]), *batches)


def _boxes(name: str, boxes, n: int | None) -> np.ndarray:
    arr = np.asarray(boxes, np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4 or (n is not None and arr.shape[0] != n):
        want = f"({n}, 4)" if n is not None else "(N, 4)"
        raise ValueError(f"{name}: expected {want} boxes [u_min, v_min, u_max, v_max], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr[:, 2:] <= arr[:, :2]):
        raise ValueError(f"{name}: expected finite boxes with u_max > u_min and v_max > v_min, got {arr.tolist()}")
    return arr


def label_batch(
    image,
    boxes_left,
    boxes_right,
    K,
    baseline: float,
    class_id,
    *,
    input_boxes=None,
    class_shape=None,
    points=None,
    point_mask=None,
    config=None,
) -> LabelBatch:
    """A :class:`LabelBatch` of the N objects labelled in one stereo pair.

    Args:
      image: (H, W, 3) left image (uint8 or float in [0, 1]); the network sees only this one.
      boxes_left, boxes_right: (N, 4) labelled boxes of each object in the left and right image.
      K: (3, 3) intrinsics of both cameras; baseline: metres from the left to the right camera
        (along the left camera's +x).
      class_id: (N,) int rows of the network's class head.
      input_boxes: (N, 4) the boxes the network's inputs are cut from (a detector's boxes);
        default ``boxes_left``.
      class_shape: (N,) ``SHAPE_IDS`` of the classes; default from the shipped class table
        (:data:`jaxsem.volumon._device_data.CLASSES`) for ids below its length, else the ellipsoid.
      points, point_mask: (N, J, 3) surface points in the left camera frame (e.g. back-projected
        depth inside each object's mask) and (N, J) bool; default none (the primal loss then
        skips these samples).
      config: the VoluMon config (or its ``model`` part) of the network being trained: it sets
        the input crop size and padding (:func:`prepare_inputs`).

    Raises ValueError naming the argument for wrong shapes, inverted or non-finite boxes, a
    non-positive baseline or bad intrinsics.
    """
    left = _boxes("boxes_left", boxes_left, None)
    n = left.shape[0]
    right = _boxes("boxes_right", boxes_right, n)
    inp = left if input_boxes is None else _boxes("input_boxes", input_boxes, n)
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected (3, 3) finite intrinsics with positive focal lengths, got {K.tolist()}")
    if not (np.isfinite(baseline) and baseline > 0):
        raise ValueError(f"baseline: expected metres > 0, got {baseline!r}")
    cid = np.asarray(class_id)
    if cid.shape != (n,) or not np.issubdtype(cid.dtype, np.integer) or np.any(cid < 0):
        raise ValueError(f"class_id: expected ({n},) non-negative integers, got {cid!r}")
    if class_shape is None:
        table = [SHAPE_IDS[c[1]] for c in CLASSES]
        shape = np.array([table[c] if c < len(table) else SHAPE_IDS["ellipsoid"] for c in cid], np.int32)
    else:
        shape = np.asarray(class_shape, np.int32).reshape(n)
    if points is None:
        pts, pmask = np.zeros((n, 1, 3), np.float32), np.zeros((n, 1), bool)
    else:
        pts = np.asarray(points, np.float32)
        if pts.ndim != 3 or pts.shape[0] != n or pts.shape[2] != 3:
            raise ValueError(f"points: expected ({n}, J, 3) camera-frame points, got shape {pts.shape}")
        pmask = np.ones(pts.shape[:2], bool) if point_mask is None else np.asarray(point_mask, bool)
        if pmask.shape != pts.shape[:2]:
            raise ValueError(f"point_mask: expected shape {pts.shape[:2]}, got {pmask.shape}")
        pmask = pmask & np.all(np.isfinite(pts), -1)
        pts = np.where(pmask[..., None], pts, 0.0).astype(np.float32)
    local, glob = prepare_inputs(image, inp, config=config)
    return LabelBatch(
        local=np.asarray(local),
        global_image=np.asarray(glob),
        box_input=inp.astype(np.float32),
        box_left=left.astype(np.float32),
        box_right=right.astype(np.float32),
        K=np.broadcast_to(K.astype(np.float32), (n, 3, 3)).copy(),
        baseline=np.full((n,), baseline, np.float32),
        class_id=cid.astype(np.int32),
        class_shape=shape,
        points=pts,
        point_mask=pmask,
        sample_mask=np.ones((n,), bool),
    )

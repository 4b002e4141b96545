"""The door model of thesis 5.8.1: scoring and single-view estimates.

(Training on rendered building doors is :func:`jaxsem.mapping.train_door_model`: the data layer
reads the directories, this package stays below it.)

- :func:`door_errors` / :func:`evaluate_doors`: centre, size, yaw and orientation errors of door
  estimates against the building generator's door boxes (held-out: test-family buildings; the
  batch from :func:`jaxsem.mapping.door_eval_batch`).
- :class:`SingleViewEstimator`: the shipped model as a detector-to-ellipsoid function for maps
  and planning: image + boxes + camera -> world ellipsoids (:func:`jaxsem.volumon.load_pretrained`
  ``kind="door"``).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from .. import metrics, quadrics as Q
from ._configs import TrainConfig
from ._inputs import prepare_inputs
from ._train import make_predict_fn, predict_batch

__all__ = ["SingleViewEstimator", "door_errors", "evaluate_doors"]


def _horizontal_angle(a, b, up) -> np.ndarray:
    """Angle (deg, 0-90) between the lines of ``a`` and ``b`` (..., 3) projected on the plane normal to ``up``."""
    pa = a - np.sum(a * up, -1, keepdims=True) * up
    pb = b - np.sum(b * up, -1, keepdims=True) * up
    na, nb = np.linalg.norm(pa, axis=-1), np.linalg.norm(pb, axis=-1)
    cos = np.abs(np.sum(pa * pb, -1)) / np.maximum(na * nb, 1e-12)
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def door_errors(pred: dict, gt: dict) -> dict:
    """Per-door errors of estimates ``pred`` (``rotation`` (B, 3, 3), ``center`` (B, 3), ``radii``
    (B, 3), camera frame) against ``gt`` (``gt_rotation`` object-to-camera with the object frame
    the world's axes, ``gt_center``, ``gt_half_extents``: :func:`jaxsem.volumon.data.volumon_eval_batch`
    of a door directory).

    Returns numpy arrays (B,): ``center`` (m, distance of centres), ``depth`` (m, |z| difference in
    the camera), ``size`` (m, norm of the difference of the sorted full extents), ``width`` and
    ``height`` (m, signed: estimate minus truth, of the sorted middle and largest full extents: a
    door's width and height), ``yaw`` (deg, 0-90: the estimate's thinnest axis against the wall
    normal, both projected on the floor plane) and ``orientation`` (deg,
    :func:`jaxsem.metrics.ellipsoid_errors`, the ellipsoid's symmetries handled).
    """
    R, c, r = (np.asarray(pred[k], np.float64) for k in ("rotation", "center", "radii"))
    Rt, ct, ht = (np.asarray(gt[k], np.float64) for k in ("gt_rotation", "gt_center", "gt_half_extents"))
    up = Rt[..., :, 2]  # world z in the camera frame
    thin_true = np.take_along_axis(Rt, np.argmin(ht, -1)[:, None, None].repeat(3, 1), -1)[..., 0]
    thin_pred = np.take_along_axis(R, np.argmin(np.abs(r), -1)[:, None, None].repeat(3, 1), -1)[..., 0]
    dp, dt = 2 * np.sort(np.abs(r), -1), 2 * np.sort(ht, -1)
    orient = np.asarray(metrics.ellipsoid_errors(R, c, np.abs(r), Rt, ct, ht)["orientation"])
    return {
        "center": np.linalg.norm(c - ct, axis=-1),
        "depth": np.abs(c[:, 2] - ct[:, 2]),
        "size": np.linalg.norm(dp - dt, axis=-1),
        "width": dp[:, 1] - dt[:, 1],
        "height": dp[:, 2] - dt[:, 2],
        "yaw": _horizontal_angle(thin_pred, thin_true, up),
        "orientation": orient,
    }


def evaluate_doors(model, variables, config: TrainConfig, batch: dict) -> dict:
    """Medians (and 90th percentiles) of :func:`door_errors` over the doors of ``batch`` (network
    inputs and ground truth, :func:`jaxsem.mapping.door_eval_batch`), with the true depth range and
    the errors of a constant baseline (every door the batch's mean true size, centred on the ray
    through its box centre at the batch's median true depth: what box position alone gives)."""
    b = batch
    _, ell, _ = predict_batch(model, config, variables, b)
    pred = jax.tree.map(np.asarray, ell._asdict())
    e = door_errors(pred, b)
    out: dict[str, Any] = {"num": int(len(e["center"]))}
    for k, v in e.items():
        a = np.abs(v) if k in ("width", "height") else v
        out[f"median_{k}"] = float(np.median(a))
        out[f"p90_{k}"] = float(np.percentile(a, 90))
    out["mean_width_bias"] = float(np.mean(e["width"]))
    out["mean_height_bias"] = float(np.mean(e["height"]))
    z = np.asarray(b["gt_center"])[:, 2]
    out["true_depth_range"] = [float(z.min()), float(z.max())]
    # constant baseline: mean true size, depth the median true depth, on the box-centre ray
    K = np.asarray(b["K"], np.float64)
    box = np.asarray(b["box_input"], np.float64)
    uv = 0.5 * (box[:, :2] + box[:, 2:])
    rays = np.asarray(Q.back_project(uv, np.ones(len(uv)), K, np.eye(4), xp=np))
    base = {
        "rotation": np.asarray(b["gt_rotation"]),  # the true orientation: only centre and size are scored
        "center": rays * np.median(z),
        "radii": np.broadcast_to(np.asarray(b["gt_half_extents"]).mean(0), (len(z), 3)),
    }
    eb = door_errors(base, b)
    out["baseline_median_center"] = float(np.median(eb["center"]))
    out["baseline_median_size"] = float(np.median(eb["size"]))
    return out


class SingleViewEstimator:
    """VoluMon as a box-to-ellipsoid estimator: ``estimator(image, boxes, K, camera_T_world)``.

    Args:
      model, variables, config: a VoluMon model (e.g. ``load_pretrained(kind="door")[:3]``).
      capacity: boxes are padded to a multiple of this (fewer compiles for varying counts).

    Calling returns ``(rotation (N, 3, 3), center (N, 3), radii (N, 3))`` numpy float64 in the
    world frame (``camera_T_world`` (4, 4), OpenCV axes; identity: the camera frame) for the boxes
    (N, 4) ``[u_min, v_min, u_max, v_max]`` of ``image`` (H, W, 3) uint8 or float in [0, 1];
    ``class_id`` (N,) row of a multi-class head (default 0).
    """

    def __init__(self, model, variables, config: TrainConfig, capacity: int = 8):
        self.model, self.variables, self.config = model, variables, config
        self.capacity = max(int(capacity), 1)
        self._predict = make_predict_fn(model, config)

    def __call__(self, image, boxes, K, camera_T_world=None, class_id=None):
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        n = boxes.shape[0]
        if n == 0:
            return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros((0, 3))
        K = np.asarray(K, np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"K: expected (3, 3), got {K.shape}")
        cap = -(-n // self.capacity) * self.capacity
        padded = np.concatenate([boxes, np.repeat(boxes[-1:], cap - n, 0)])
        cid = np.zeros(cap, np.int32) if class_id is None else np.pad(np.asarray(class_id, np.int32), (0, cap - n))
        size, pad = self.config.model.input_size, self.config.model.global_padding
        local, glob = prepare_inputs(image, padded.astype(np.float32), size, pad)
        Kb = np.broadcast_to(K.astype(np.float32), (cap, 3, 3))
        _, ell, _ = self._predict(self.variables, local, glob, padded.astype(np.float32), Kb, cid)
        R = np.asarray(ell.rotation, np.float64)[:n]
        c = np.asarray(ell.center, np.float64)[:n]
        r = np.abs(np.asarray(ell.radii, np.float64)[:n])
        if camera_T_world is not None:
            world_T_cam = Q.invert_pose(np.asarray(camera_T_world, np.float64), xp=np)
            R = world_T_cam[:3, :3] @ R
            c = Q.transform_points(world_T_cam, c, xp=np)
        return R, c, r

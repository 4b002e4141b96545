"""Scoring ellipsoids on real annotated frames (a BOP scene) and the known-size geometric baseline.

The batch is built by the data layer (:func:`jaxsem.volumon.data.bop_eval_batch`): network inputs of the
visible boxes, the true pose and mesh extent of each object, its mesh points in the camera frame
(so ADI is ADD-S) and per detection its class name and visible fraction. This module only scores:

- :func:`known_size_ellipsoid`: the baseline given each object's *true* size: the ellipsoid of the
  mesh's half extents, axis-aligned to the camera, centred on the ray through the box centre at
  the depth where its projected box (:func:`jaxsem.quadrics.project_bbox`) has the observed box's
  size. Jittable, vmappable, no NaN.
- :func:`summarise_detections`: the figures of ``jaxsem volumon eval`` on any set of predictions,
  overall, per class and per visible-fraction bin.
- :func:`evaluate_scene_batch`: the network on the batch (each object's class row, or the class
  head's expectation over the model's classes where the model does not know the class), timed.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import classes as class_table, quadrics as Q
from ._eval import detection_errors, evaluate_predictions
from ._pretrained import _summary
from ._synthetic import VOLUMON_CLASS_NAMES
from ._train import make_predict_fn

__all__ = [
    "CLASS_MAPPINGS",
    "VISIBILITY_BINS",
    "class_rows",
    "evaluate_scene_batch",
    "known_size_ellipsoid",
    "model_class_names",
    "summarise_detections",
]

#: Edges of the visible-fraction bins of ``by_visibility`` (last bin closed at 1).
VISIBILITY_BINS = (0.0, 0.25, 0.5, 0.7, 0.9, 1.0)


def known_size_ellipsoid(box, K, radii, iterations: int = 12, match_aspect: bool = True):
    """The known-size geometric baseline: ``(rotation, center, radii)`` of an ellipsoid of the given
    semi-axes, axis-aligned to the camera (identity rotation: object axes along camera x, y, z),
    centred on the ray through the box centre (:func:`jaxsem.quadrics.single_view_ellipsoid`) at
    the depth where its projected box (:func:`jaxsem.quadrics.project_bbox`) has the box's size
    (geometric mean of width and height).

    The depth is a fixed-point iteration ``z <- z * s(z) / s_box`` (a projected size is about
    inversely proportional to depth), started at the pinhole guess ``f * 2 sqrt(r_x r_y) / s_box``
    and kept in front of the camera (``z >= 1.05 * max(radii) + 1 mm``), so the result is finite
    for any finite box with positive size. The same iteration moves the ray by the offset between
    the projected box's centre and the box's (off the optical axis an ellipsoid's outline is not
    centred on its centre's image), so a box that is the exact projection of such an ellipsoid
    gives it back.

    ``match_aspect`` (static): which of the object's axes lies along which camera axis is unknown
    from a box; True puts the pair of semi-axes whose ratio is nearest (in log) to the box's aspect
    ratio across the image (the larger along the box's longer side) and the third along the ray;
    False keeps the object's own axis order (mesh x, y, z along camera x, y, z). The returned
    radii are in that order (the rotation stays the identity).

    Args:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]``; K: (..., 3, 3); radii: (..., 3) semi-axes (m).
      iterations: static number of fixed-point steps (12 converge to well under a millimetre).

    Returns:
      rotation (..., 3, 3), center (..., 3) camera frame, radii (..., 3).
    """
    box = jnp.asarray(box)
    dtype = jnp.result_type(box, K, radii, float)
    box, K, radii = (jnp.asarray(x, dtype) for x in (box, K, radii))
    batch = jnp.broadcast_shapes(box.shape[:-1], K.shape[:-2], radii.shape[:-1])
    box = jnp.broadcast_to(box, batch + (4,))
    K = jnp.broadcast_to(K, batch + (3, 3))
    radii = jnp.broadcast_to(radii, batch + (3,))
    eye = jnp.broadcast_to(jnp.eye(4, dtype=dtype), batch + (4, 4))
    if match_aspect:
        radii = _aspect_matched(box, radii)

    def size(b):
        return Q.safe_sqrt(jnp.maximum(b[..., 2] - b[..., 0], 0.0) * jnp.maximum(b[..., 3] - b[..., 1], 0.0))

    s_box = jnp.maximum(size(box), 1e-6)
    focal = Q.safe_sqrt(K[..., 0, 0] * K[..., 1, 1])
    z_min = 1.05 * jnp.max(radii, -1) + 1e-3
    z0 = jnp.maximum(focal * 2.0 * Q.safe_sqrt(radii[..., 0] * radii[..., 1]) / s_box, z_min)

    def step(_, state):
        z, shift = state
        R, c, r = Q.single_view_ellipsoid(box + shift, K, eye, z, radii)
        projected, valid = Q.project_bbox(R, c, r, K, eye)
        z_new = jnp.maximum(z * Q.safe_div(size(projected), s_box), z_min)
        miss = 0.5 * (box[..., :2] + box[..., 2:] - projected[..., :2] - projected[..., 2:])
        shift_new = shift + jnp.concatenate([miss, miss], -1)
        ok = valid & jnp.isfinite(z_new) & jnp.all(jnp.isfinite(shift_new), -1)
        return jnp.where(ok, z_new, z), jnp.where(ok[..., None], shift_new, shift)

    z, shift = jax.lax.fori_loop(0, int(iterations), step, (z0, jnp.zeros_like(box)))
    return Q.single_view_ellipsoid(box + shift, K, eye, z, radii)


_PERMUTATIONS = np.array([[0, 1, 2], [1, 0, 2], [0, 2, 1], [2, 0, 1], [1, 2, 0], [2, 1, 0]])


def _aspect_matched(box, radii):
    """``radii`` (..., 3) permuted so that ``r_x / r_y`` is nearest in log to the box's ``w / h``."""
    w = jnp.maximum(box[..., 2] - box[..., 0], 1e-6)
    h = jnp.maximum(box[..., 3] - box[..., 1], 1e-6)
    perm = radii[..., _PERMUTATIONS]  # (..., 6, 3)
    r = jnp.maximum(perm, 1e-9)
    miss = jnp.abs(jnp.log(r[..., 0] / r[..., 1]) - jnp.log(w / h)[..., None])
    best = jnp.argmin(miss, -1)
    return jnp.take_along_axis(perm, best[..., None, None], axis=-2)[..., 0, :]


def _figures(pred: Mapping, gt: Mapping, keep: np.ndarray) -> dict:
    """The figures of ``jaxsem volumon eval`` (``num`` and the summary keys) over the rows ``keep``."""
    mask = np.asarray(gt.get("sample_mask", np.ones(len(keep), bool)), bool) & keep
    n = int(mask.sum())
    if n == 0:
        return {"num": 0}
    g = {
        k: v for k, v in gt.items() if k in ("gt_rotation", "gt_center", "gt_half_extents", "gt_shape_id", "gt_points")
    }
    g["sample_mask"] = mask
    return {"num": n, **_summary(pred, g, evaluate_predictions, detection_errors)}


def summarise_detections(pred: Mapping, gt: Mapping) -> dict:
    """The figures of ``jaxsem volumon eval`` for predictions ``pred`` (``rotation`` (B, 3, 3),
    ``center`` (B, 3), ``radii`` (B, 3), camera frame) against ``gt`` (``gt_rotation``,
    ``gt_center``, ``gt_half_extents``, ``gt_shape_id``, optionally ``gt_points`` (B, N, 3) for
    ADD-S and ``sample_mask``; ``class_name`` (B,) and ``visible_fraction`` (B,) for the groups).

    Returns ``num``, ``median_size_rel_error``, ``size_corr``, ``median_center_error_m``,
    ``trans_auc``, ``adi_auc``, ``iou_auc``, ``iou``; ``per_class`` (class name -> the same
    figures) when ``class_name`` is given; ``by_visibility`` (``"lo-hi"`` of
    :data:`VISIBILITY_BINS` -> the same figures, non-empty bins only) when ``visible_fraction``
    is given.
    """
    pred = {k: np.asarray(pred[k]) for k in ("rotation", "center", "radii")}
    B = len(np.asarray(gt["gt_center"]))
    for k, v in pred.items():
        if len(v) != B:
            raise ValueError(f"pred[{k!r}]: expected {B} rows like gt['gt_center'], got shape {v.shape}")
    out: dict[str, Any] = _figures(pred, gt, np.ones(B, bool))
    if "class_name" in gt:
        names = np.asarray(gt["class_name"]).astype(str)
        out["per_class"] = {str(c): _figures(pred, gt, names == c) for c in sorted(set(names.tolist()))}
    if "visible_fraction" in gt:
        frac = np.asarray(gt["visible_fraction"], np.float64)
        bins = {}
        edges = VISIBILITY_BINS
        for lo, hi in zip(edges[:-1], edges[1:]):
            inside = (frac >= lo) & ((frac < hi) if hi < edges[-1] else (frac <= hi))
            fig = _figures(pred, gt, inside)
            if fig["num"]:
                bins[f"{lo:g}-{hi:g}"] = fig
        out["by_visibility"] = bins
    return out


def evaluate_scene_batch(model, variables, config, batch: Mapping, class_rows, repeats: int = 5) -> dict:
    """The network's figures on a scene batch (:func:`jaxsem.volumon.data.bop_eval_batch`).

    Args:
      model, variables, config: a VoluMon model (:func:`jaxsem.volumon.load_pretrained`).
      batch: ``local``, ``global``, ``box_input``, ``K`` and the ground truth of
        :func:`summarise_detections`.
      class_rows: (B,) int: the model's class row for each detection, or -1 where the class head's
        expectation over the model's classes is used (thesis eq. 5.18: the row weights are the
        predicted class probabilities; the model does not know the object's class).
      repeats: timed forward passes after a warm-up (``network_ms_per_detection``: their median
        over the batch size).

    Returns:
      the dict of :func:`summarise_detections` plus ``network_ms_per_detection``, and the
      predictions (``pred``: numpy ``rotation``, ``center``, ``radii``) for drawing.
    """
    rows = np.asarray(class_rows, np.int64)
    B = int(np.asarray(batch["box_input"]).shape[0])
    if rows.shape != (B,):
        raise ValueError(f"class_rows: expected shape ({B},), got {rows.shape}")
    n = int(config.model.num_classes)
    if np.any((rows < -1) | (rows >= n)):
        raise ValueError(f"class_rows: expected -1 or a class row 0..{n - 1}, got {sorted(set(rows.tolist()))}")
    predict = make_predict_fn(model, config)
    f32 = lambda k: jnp.asarray(batch[k], jnp.float32)
    args = (variables, f32("local"), f32("global"), f32("box_input"), f32("K"))
    run = lambda: predict_by_rows(predict, args, rows)
    ell = jax.block_until_ready(run())  # warm-up (compiles)
    times = []
    for _ in range(int(repeats)):
        t = time.perf_counter()
        jax.block_until_ready(run())
        times.append(time.perf_counter() - t)
    pred = {k: np.asarray(v, np.float64) for k, v in ell._asdict().items() if k in ("rotation", "center", "radii")}
    out = summarise_detections(pred, batch)
    out["network_ms_per_detection"] = 1000.0 * float(np.median(times)) / max(B, 1)
    out["pred"] = pred
    return out


def predict_by_rows(predict, args, rows):
    """The ellipsoids of :func:`jaxsem.volumon.make_predict_fn`'s ``predict(*args, class_id)``
    with each detection's class row ``rows`` (B,), or the class head's expectation where the row
    is -1 (both passes run only when both kinds of row are present)."""
    rows = np.asarray(rows, np.int64)
    _, ell_rows, _ = predict(*args, jnp.asarray(np.maximum(rows, 0), jnp.int32))
    if np.all(rows >= 0):
        return ell_rows
    _, ell_mean, _ = predict(*args, None)
    if np.all(rows < 0):
        return ell_mean
    pick = jnp.asarray(rows >= 0)
    return jax.tree.map(lambda a, b: jnp.where(pick.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), ell_rows, ell_mean)


#: ``class_mapping`` modes of :func:`class_rows` for objects whose class the model does not have.
CLASS_MAPPINGS = ("generic", "nearest")


def model_class_names(config) -> tuple[str, ...]:
    """The class names of a VoluMon model's class head, in row order (the shipped object model's
    four when its config does not list them; ``()`` when unknown)."""
    n = int(config.model.num_classes)
    names = tuple(config.class_names)
    if names:
        return names
    return VOLUMON_CLASS_NAMES if n == len(VOLUMON_CLASS_NAMES) else ()


def class_rows(object_classes, config, mode: str = "generic", extents: Mapping | None = None):
    """Which row of the model's class head scores each detection, and a record of the choice.

    A class the model has uses its own row. Other classes follow ``mode``: ``"generic"``, the
    class head's expectation over the model's classes (row -1 for :func:`evaluate_scene_batch`;
    the network's own class probabilities weigh the rows, nothing about the object is given) or
    ``"nearest"``, the model class whose sorted full extents (:mod:`jaxsem.classes`) are nearest
    (Euclidean) to the object's (``extents``: class name -> full extents (3,), metres). A
    one-class model uses its one row for everything.

    Returns:
      rows (B,) int, and the ``class_mapping`` dict: ``mode``, ``model_classes`` and ``classes``
      (object class -> what was used, in words).
    """
    if mode not in CLASS_MAPPINGS:
        raise ValueError(f"mode: expected one of {CLASS_MAPPINGS}, got {mode!r}")
    names = model_class_names(config)
    n = int(config.model.num_classes)
    objects = [str(c) for c in np.asarray(object_classes).astype(str).tolist()]
    used: dict[str, tuple[int, str]] = {}
    for c in sorted(set(objects)):
        if n == 1:
            used[c] = (0, f"the model's only class{f' {names[0]!r}' if names else ''} (row 0)")
        elif c in names:
            used[c] = (names.index(c), f"its own class {c!r} (row {names.index(c)})")
        elif mode == "generic" or not names:
            used[c] = (-1, "generic: the class head's expectation over the model's classes (eq. 5.18)")
        else:
            if extents is None or c not in extents:
                raise ValueError(f"extents: mode 'nearest' needs the full extents of class {c!r}")
            ext = np.sort(np.asarray(extents[c], np.float64))
            known = [n_ for n_ in names if n_ in class_table.CLASS_NAMES]
            if not known:
                raise ValueError(f"mode: 'nearest' needs model classes of jaxsem.classes, got {list(names)}")
            dist = [np.linalg.norm(np.sort(class_table.get(k).dimensions) - ext) for k in known]
            best = known[int(np.argmin(dist))]
            used[c] = (names.index(best), f"nearest by size: {best!r} (row {names.index(best)})")
    rows = np.asarray([used[c][0] for c in objects], np.int64)
    mapping = {"mode": mode, "model_classes": list(names), "classes": {c: w for c, (_, w) in used.items()}}
    return rows, mapping

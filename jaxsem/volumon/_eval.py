"""Evaluation of ellipsoid predictions against ground-truth objects (thesis 5.5.2).

Translation error (centroid distance), ADI (eq. 5.16: mean over the true model's surface points
of the distance to the nearest point sampled on the predicted ellipsoid), 3D IoU of the true
cuboid (or an ellipsoid's bounding cuboid) with the prediction's bounding cuboid, and AUCs of the
pass-rate curves up to 10 cm (out of 10), all from :mod:`jaxsem.metrics`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import metrics

NUM_TRUE_POINTS = 300
NUM_PRED_POINTS = 600


def cuboid_surface_points(key, rotation, center, half_extents, n: int):
    """Area-uniform random points on the surface of cuboids: (..., 3, 3), (..., 3), (..., 3) -> (..., n, 3)."""
    batch = center.shape[:-1]
    k1, k2 = jax.random.split(key)
    h = half_extents[..., None, :]
    areas = jnp.stack([h[..., 1] * h[..., 2], h[..., 0] * h[..., 2], h[..., 0] * h[..., 1]], -1)  # (..., 1, 3)
    logits = jnp.log(jnp.broadcast_to(areas, batch + (n, 3)))
    axis = jax.random.categorical(k1, logits, axis=-1)
    u = jax.random.uniform(k2, batch + (n, 3), minval=-1.0, maxval=1.0, dtype=center.dtype)
    sign = jnp.where(jax.random.uniform(jax.random.fold_in(k2, 1), batch + (n,)) < 0.5, -1.0, 1.0).astype(u.dtype)
    onehot = jax.nn.one_hot(axis, 3, dtype=u.dtype)
    u = u * (1 - onehot) + onehot * sign[..., None]
    local = u * h
    return jnp.einsum("...ij,...nj->...ni", rotation, local) + center[..., None, :]


def _sphere_directions(n: int) -> np.ndarray:
    """Fibonacci-lattice unit vectors (n, 3): deterministic, near-uniform on the sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    rho = np.sqrt(1 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], -1)


def _cuboid_unit_points(n: int, half) -> np.ndarray:
    """Deterministic area-weighted points on a cuboid of half extents ``half`` (B, 3) -> (B, n, 3).
    Every row reads the same draws, so a row's points depend on its own extents alone (not on
    its place in the batch)."""
    rng = np.random.default_rng(12345)
    half = np.asarray(half, np.float64)
    areas = np.stack([half[:, 1] * half[:, 2], half[:, 0] * half[:, 2], half[:, 0] * half[:, 1]], -1)
    u = rng.uniform(-1, 1, size=(1, n, 3))
    sign = np.where(rng.uniform(size=(1, n)) < 0.5, -1.0, 1.0)
    c = np.cumsum(areas / areas.sum(-1, keepdims=True), -1)
    axis = (rng.uniform(size=(1, n))[..., None] > c[:, None, :]).sum(-1)
    onehot = np.eye(3)[axis]
    u = u * (1 - onehot) + onehot * sign[..., None]
    return u * half[:, None, :]


def _cylinder_unit_points(n: int, half) -> np.ndarray:
    """Deterministic area-weighted points on elliptic cylinders (axis z) of half extents (B, 3) ->
    (B, n, 3); every row reads the same draws (as :func:`_cuboid_unit_points`)."""
    rng = np.random.default_rng(54321)
    half = np.asarray(half, np.float64)
    a, b, c = half[:, 0], half[:, 1], half[:, 2]
    side = 2 * np.pi * np.sqrt(0.5 * (a * a + b * b)) * 2 * c  # Ramanujan-free approximation of the side area
    caps = 2 * np.pi * a * b
    p_side = side / (side + caps)
    theta = rng.uniform(0, 2 * np.pi, (1, n))
    on_side = rng.uniform(size=(1, n)) < p_side[:, None]
    rad = np.where(on_side, 1.0, np.sqrt(rng.uniform(size=(1, n))))
    z = np.where(on_side, rng.uniform(-1, 1, (1, n)), np.where(rng.uniform(size=(1, n)) < 0.5, -1.0, 1.0))
    return np.stack([rad * np.cos(theta), rad * np.sin(theta), z], -1) * half[:, None, :]


def size_errors(pred_radii, gt_half_extents):
    """Per-object relative size error (B,) and the Pearson correlation of all sorted radii.

    Each object's three radii are sorted, predicted and true; its error is the mean over the three
    of ``|r_pred - r_true| / r_true``. The correlation is over all 3B sorted radii pairs (0 when
    either side is constant).
    """
    p = np.sort(np.asarray(pred_radii, np.float64), -1)
    t = np.sort(np.asarray(gt_half_extents, np.float64), -1)
    rel = np.mean(np.abs(p - t) / t, -1)
    pf, tf = p.ravel(), t.ravel()
    if pf.size < 2 or np.ptp(pf) == 0 or np.ptp(tf) == 0:
        return rel, 0.0
    return rel, float(np.corrcoef(pf, tf)[0, 1])


@jax.jit
def _errors(pred_R, pred_t, pred_r, gt_R, gt_t, true_pts, pred_dirs, gt_h):
    # deterministic sample sets (no threefry: its hash is slow to compile on a CPU)
    trans = jnp.linalg.norm(pred_t - gt_t, axis=-1)
    pred_pts = jnp.einsum("bij,bnj->bni", pred_R, pred_dirs[None] * pred_r[:, None, :]) + pred_t[:, None, :]
    adi = metrics.adi(true_pts, pred_pts)
    iou = metrics.iou_3d_boxes(gt_R, gt_t, gt_h, pred_R, pred_t, pred_r)
    return trans, adi, iou


def evaluate_predictions(pred, gt, max_threshold: float = 0.1) -> dict:
    """Score predictions.

    Args:
      pred: dict with ``rotation`` (B, 3, 3), ``center`` (B, 3), ``radii`` (B, 3) (camera frame).
      gt: dict with ``gt_rotation``, ``gt_center``, ``gt_half_extents``, ``gt_shape_id`` (0 cuboid,
        1 ellipsoid, 2 cylinder along z) and optionally ``sample_mask`` (skipped samples are left out)
        and ``gt_points`` (B, N, 3): the object's model points in the camera frame, which ADI then
        uses instead of points sampled on the shape of ``gt_shape_id`` (ADD-S of the real mesh).

    Returns:
      dict of floats: ``trans_auc``, ``adi_auc`` (0-10, thresholds up to ``max_threshold`` m),
      ``iou`` (mean 3D IoU), ``trans_median``, ``adi_median`` (m), ``n``; the size figures of
      :func:`size_errors` (``median_size_rel_error``, ``size_corr``) and
      ``median_center_error_m`` (= ``trans_median``); summaries only (use
      :func:`detection_errors` for arrays).
    """
    trans, adi, iou = detection_errors(pred, gt)
    keep = np.asarray(gt.get("sample_mask", np.ones(len(gt["gt_center"]), bool)), bool)
    rel, corr = size_errors(np.asarray(pred["radii"])[keep], np.asarray(gt["gt_half_extents"])[keep])
    return {
        "median_size_rel_error": float(np.median(rel)) if rel.size else float("nan"),
        "size_corr": corr,
        "median_center_error_m": float(np.median(trans)) if trans.size else float("nan"),
        "trans_auc": float(metrics.auc_pass_rate(trans, max_threshold)),
        "adi_auc": float(metrics.auc_pass_rate(adi, max_threshold)),
        "iou": float(np.mean(iou)) if iou.size else 0.0,
        "trans_median": float(np.median(trans)) if trans.size else float("nan"),
        "adi_median": float(np.median(adi)) if adi.size else float("nan"),
        "n": int(trans.size),
    }


def detection_errors(pred, gt):
    """Per-detection (translation error, ADI, IoU) numpy arrays over the unskipped samples."""
    keep = np.asarray(gt.get("sample_mask", np.ones(len(gt["gt_center"]), bool)), bool)
    sel = lambda x: np.asarray(x)[keep]
    gt_h = sel(gt["gt_half_extents"]).astype(np.float64)
    shape = sel(gt["gt_shape_id"])
    dirs = _sphere_directions(NUM_TRUE_POINTS)
    local = np.where(
        (shape == 0)[:, None, None], _cuboid_unit_points(NUM_TRUE_POINTS, gt_h), dirs[None] * gt_h[:, None, :]
    )
    local = np.where((shape == 2)[:, None, None], _cylinder_unit_points(NUM_TRUE_POINTS, gt_h), local)
    if "gt_points" in gt:  # the object's own model points (camera frame): ADI is then ADD-S
        true_pts = sel(gt["gt_points"]).astype(np.float64)
    else:
        true_pts = np.einsum("bij,bnj->bni", sel(gt["gt_rotation"]), local) + sel(gt["gt_center"])[:, None, :]
    n = len(gt_h)
    if n == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    # The batch is padded (with copies of its first row) to a power of two of at least 16, so
    # scoring sets of other sizes reuses one compiled program per size class.
    rows = np.concatenate([np.arange(n), np.zeros(max(16, 1 << (n - 1).bit_length()) - n, np.int64)])
    f = lambda x: jnp.asarray(np.asarray(x)[rows], jnp.float32)
    trans, adi, iou = _errors(
        f(sel(pred["rotation"])),
        f(sel(pred["center"])),
        f(sel(pred["radii"])),
        f(sel(gt["gt_rotation"])),
        f(sel(gt["gt_center"])),
        f(true_pts),
        jnp.asarray(_sphere_directions(NUM_PRED_POINTS), jnp.float32),
        f(gt_h),
    )
    return np.asarray(trans)[:n], np.asarray(adi)[:n], np.asarray(iou)[:n]

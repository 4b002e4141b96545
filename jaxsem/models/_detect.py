"""Fixed-shape detection pieces for a two-stage detector under ``jit``: greedy non-maximum
suppression with a fixed number of outputs, and RoI features by bilinear sampling (RoIAlign).

Both keep every shape static (``max_detections``, ``output_size``, ``samples``), so a detector
built on them compiles once for a batch of images; what did not survive comes back masked, never
as a shorter array.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..quadrics import box_iou


def nms(boxes, scores, max_detections: int, iou_threshold: float = 0.5, score_threshold: float = 0.0):
    """Greedy non-maximum suppression with a fixed output size.

    Takes boxes in descending score order; a box is kept unless it overlaps an already kept box by
    IoU above ``iou_threshold``; boxes scoring at most ``score_threshold`` (and non-finite scores)
    are never kept. Same result as the usual greedy loop (ties broken by the lower index).

    Args:
      boxes: (..., N, 4) ``[u_min, v_min, u_max, v_max]``.
      scores: (..., N).
      max_detections: number of outputs (static).
    Returns:
      ``(index, valid)``: (..., max_detections) int32 indices into N in descending score order,
      and the mask of real detections (padding repeats index 0 with ``valid`` False).
    """
    boxes, scores = jnp.asarray(boxes), jnp.asarray(scores)
    if boxes.ndim < 2 or boxes.shape[-1] != 4:
        raise ValueError(f"boxes: expected shape (..., N, 4), got {boxes.shape}")
    if scores.shape != boxes.shape[:-1]:
        raise ValueError(f"scores: expected shape {boxes.shape[:-1]} (the boxes' leading shape), got {scores.shape}")
    if int(max_detections) < 1:
        raise ValueError(f"max_detections: expected >= 1, got {max_detections}")
    batch = boxes.shape[:-2]
    flat_b = boxes.reshape((-1, *boxes.shape[-2:]))
    flat_s = scores.reshape((-1, scores.shape[-1]))
    index, valid = jax.vmap(lambda b, s: _nms_one(b, s, int(max_detections), iou_threshold, score_threshold))(
        flat_b, flat_s
    )
    return index.reshape((*batch, int(max_detections))), valid.reshape((*batch, int(max_detections)))


def _nms_one(boxes, scores, max_detections, iou_threshold, score_threshold):
    n = boxes.shape[0]
    ok = jnp.isfinite(scores) & (scores > score_threshold)
    order = jnp.argsort(jnp.where(ok, -scores, jnp.inf), stable=True)
    boxes, ok = boxes[order], ok[order]
    overlap = box_iou(boxes[:, None], boxes[None]) > iou_threshold

    def visit(i, keep):  # box i survives if no kept box before it overlaps it
        suppressed = jnp.any(keep & overlap[i] & (jnp.arange(n) < i))
        return keep.at[i].set(ok[i] & ~suppressed)

    keep = jax.lax.fori_loop(0, n, visit, jnp.zeros(n, bool))
    rank = jnp.where(keep, jnp.arange(n), n)
    first = jnp.sort(rank)[:max_detections] if n >= max_detections else jnp.sort(rank)
    if n < max_detections:
        first = jnp.concatenate([first, jnp.full(max_detections - n, n, first.dtype)])
    valid = first < n
    index = jnp.where(valid, order[jnp.minimum(first, n - 1)], 0).astype(jnp.int32)
    return index, valid


def roi_align(features, boxes, output_size: tuple, spatial_scale: float = 1.0, samples: int = 2):
    """RoI features by bilinear sampling: each box split into ``output_size`` bins, each bin the
    mean of ``samples x samples`` bilinear samples at regular points inside it.

    Pixel centres sit at integer + 0.5 in image coordinates (the boxes' convention); samples
    outside the feature map read 0.

    Args:
      features: (H, W, C) one image's feature map.
      boxes: (R, 4) ``[u_min, v_min, u_max, v_max]`` in image pixels.
      output_size: ``(h, w)`` bins (static).
      spatial_scale: feature cells per image pixel (1/stride).
      samples: samples per bin side (static).
    Returns:
      (R, h, w, C).
    """
    features, boxes = jnp.asarray(features), jnp.asarray(boxes)
    if features.ndim != 3:
        raise ValueError(f"features: expected shape (H, W, C), got {features.shape}")
    if boxes.ndim != 2 or boxes.shape[-1] != 4:
        raise ValueError(f"boxes: expected shape (R, 4), got {boxes.shape}")
    h, w = (int(x) for x in output_size)
    if h < 1 or w < 1 or int(samples) < 1:
        raise ValueError(f"output_size, samples: expected positive sizes, got {output_size}, {samples}")
    s = int(samples)
    frac = (jnp.arange(s, dtype=features.dtype) + 0.5) / s

    def one(box):
        box = box.astype(features.dtype) * spatial_scale
        bin_w, bin_h = (box[2] - box[0]) / w, (box[3] - box[1]) / h
        u = box[0] + (jnp.arange(w, dtype=features.dtype)[:, None] + frac[None]) * bin_w  # (w, s)
        v = box[1] + (jnp.arange(h, dtype=features.dtype)[:, None] + frac[None]) * bin_h  # (h, s)
        vv, uu = v.reshape(-1)[:, None], u.reshape(-1)[None, :]
        vals = _bilinear(features, vv - 0.5, uu - 0.5)  # (h*s, w*s, C) at cell-centre coordinates
        return vals.reshape(h, s, w, s, -1).mean(axis=(1, 3))

    return jax.vmap(one)(boxes)


def _bilinear(features, y, x):
    """features sampled at fractional cell coordinates (y, x) broadcast; 0 outside the map."""
    H, W, _ = features.shape
    y0, x0 = jnp.floor(y), jnp.floor(x)
    out = 0.0
    for dy in (0, 1):
        for dx in (0, 1):
            yi, xi = y0 + dy, x0 + dx
            wgt = (1 - jnp.abs(y - yi)) * (1 - jnp.abs(x - xi))
            inside = (yi >= 0) & (yi <= H - 1) & (xi >= 0) & (xi <= W - 1)
            yc = jnp.clip(yi, 0, H - 1).astype(jnp.int32)
            xc = jnp.clip(xi, 0, W - 1).astype(jnp.int32)
            out = out + jnp.where(inside, wgt, 0.0)[..., None] * features[yc, xc]
    return out

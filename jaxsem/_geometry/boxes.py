"""Image boxes ``[u_min, v_min, u_max, v_max]``: areas and intersection over union.

One definition for every part that compares boxes (the simulator's association gate, detection
matching, non-maximum suppression). Empty or inverted boxes have area 0; the IoU of two empty
boxes is 0, with finite gradients everywhere (the union is clamped before dividing).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._checks import as_float_array


def box_area(boxes):
    """Area of boxes (..., 4) in pixels squared, 0 where the box is empty or inverted."""
    boxes = as_float_array("boxes", boxes, (4,))
    wh = jnp.maximum(boxes[..., 2:] - boxes[..., :2], 0.0)
    return wh[..., 0] * wh[..., 1]


def box_iou(a, b):
    """Intersection over union of boxes ``a`` (..., 4) and ``b`` (..., 4), broadcast against each
    other (``box_iou(a[:, None], b[None])`` is the pairwise matrix); 0 for empty or disjoint boxes."""
    a, b = as_float_array("a", a, (4,)), as_float_array("b", b, (4,))
    lo = jnp.maximum(a[..., :2], b[..., :2])
    hi = jnp.minimum(a[..., 2:], b[..., 2:])
    wh = jnp.maximum(hi - lo, 0.0)
    inter = wh[..., 0] * wh[..., 1]
    union = box_area(a) + box_area(b) - inter
    tiny = float(jnp.finfo(union.dtype).tiny) ** 0.5
    return inter / jnp.maximum(union, tiny)

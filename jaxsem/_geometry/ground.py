"""Footprints of ellipsoids on the ground plane, and their rasterisation into planning grids.

Re-exported by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from .._checks import (
    as_float_array as _as_float_array,
    is_concrete as _is_concrete,
)
from ._common import (
    _ellipsoid_args,
    _ellipsoid_ok,
    _finite,
    _finite_or_zero,
    _matmul3,
    safe_sqrt,
)
from .conics import dual_quadric

# --------------------------------------------------------------------------------------------
# Top-down (planning) view: orthographic projection along z onto the ground plane z = 0.

_P_ORTHO = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


def ground_conic(rotation, center, radii, *, xp: Any = jnp):
    """Dual conic of the ellipsoid's orthographic projection along z (``P_ortho Q* P_ortho^T``).

    ``P_ortho = [[1,0,0,0], [0,1,0,0], [0,0,0,1]]``, so the result is ``Q*`` restricted to the rows
    and columns (x, y, w). Its :func:`conic_bbox` is the footprint's extent in world x, y.
    ``xp``: ``jax.numpy`` (default) or ``numpy`` (host code).

    Returns:
      (..., 3, 3) dual conic in world metres (x, y).
    """
    Qs = dual_quadric(rotation, center, radii, xp=xp)
    idx = np.array([0, 1, 3])
    return Qs[..., idx[:, None], idx[None, :]]


def ground_bounds(rotation, center, radii, *, with_valid: bool = False) -> Any:  # a tuple with with_valid=True
    """Footprint extent ``[x_min, y_min, x_max, y_max]`` (..., 4) of an ellipsoid seen from above.

    ``with_valid=True`` also returns the (...) mask of :func:`ellipsoid_valid`: only the squares
    of the radii enter, so under ``jit`` (concrete arguments are checked eagerly) a negated radius
    would give the bounds of its magnitude, and a scaled rotation those of another ellipsoid.
    Where the mask is False the bounds are finite (non-finite entries are read as 0).
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    valid = None
    if with_valid:
        valid = jnp.broadcast_to(_ellipsoid_ok(rotation, center, radii), batch)
        rotation, center, radii = (_finite_or_zero(x) for x in (rotation, center, radii))
    shape = _matmul3(rotation * jnp.square(radii)[..., None, :], jnp.swapaxes(rotation, -1, -2))
    hx = safe_sqrt(shape[..., 0, 0])
    hy = safe_sqrt(shape[..., 1, 1])
    cx, cy = center[..., 0], center[..., 1]
    bounds = jnp.broadcast_to(jnp.stack([cx - hx, cy - hy, cx + hx, cy + hy], -1), batch + (4,))
    return bounds if valid is None else (bounds, valid)


def rasterize_footprint(
    rotation, center, radii, class_id, grid_shape, origin, resolution, mask=None, *, with_valid: bool = False
) -> Any:  # (grid, valid) with with_valid=True
    """Rasterises ellipsoid footprints (top-down, along z) into a class-id grid.

    A cell ``[row, col]`` has its centre at world ``(origin[0] + (col + 0.5) * resolution,
    origin[1] + (row + 0.5) * resolution)``; it takes the class id of an ellipsoid whose footprint
    ellipse (the 2x2 x-y block of ``R diag(r^2) R^T`` around the centre) contains that centre.
    Overlaps take the largest class id; cells covered by nothing are 0.

    Args:
      rotation: (..., 3, 3); center: (..., 3); radii: (..., 3): all ellipsoids of the batch are
        drawn into the same grid (``vmap`` for one grid per map).
      class_id: (...) int, the value to write (use ids >= 1).
      grid_shape: static ``(H, W)``.
      origin: (2,) world ``(x, y)`` of the grid corner at cell ``[0, 0]``.
      resolution: metres per cell.
      mask: optional (...) bool; False ellipsoids are not drawn.
      with_valid: also return the per-object validity (below).

    Returns:
      (H, W) int32 grid; with ``with_valid=True`` also ``valid`` (...) bool, False for an
      ellipsoid that is not a proper one (a non-finite centre or radius, a radius <= 0, a
      rotation that is not one; whatever ``mask`` says), and for every ellipsoid when the grid
      is not one (a non-finite ``origin``, a ``resolution`` not positive and finite). Such an
      ellipsoid is never drawn.

    A bad ellipsoid is not dropped silently: eagerly it raises ``ValueError`` naming the
    argument (as everywhere in the core); under ``jit`` it is left out of the grid and
    ``with_valid=True`` says which ones were (``mask & ~valid``: objects meant to be drawn that
    were not).
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    if len(grid_shape) != 2 or any(int(g) <= 0 for g in grid_shape):
        raise ValueError(f"grid_shape: expected (H, W) of positive ints, got {grid_shape}")
    origin = _as_float_array("origin", origin, (2,), check_finite=True)
    if origin.ndim != 1:
        raise ValueError(f"origin: expected shape (2,), got {tuple(origin.shape)}")
    res = jnp.asarray(resolution)
    if res.ndim != 0:
        raise ValueError(f"resolution: expected a scalar (metres per cell), got shape {tuple(res.shape)}")
    if _is_concrete(res) and not (np.isfinite(float(res)) and float(res) > 0):
        raise ValueError(f"resolution: expected a positive, finite number of metres per cell, got {float(res)}")
    class_id = jnp.broadcast_to(jnp.asarray(class_id, jnp.int32), batch)
    mask = jnp.ones(batch, bool) if mask is None else jnp.broadcast_to(jnp.asarray(mask, bool), batch)
    rotation = jnp.broadcast_to(rotation, batch + (3, 3))
    center = jnp.broadcast_to(center, batch + (3,))
    radii = jnp.broadcast_to(radii, batch + (3,))
    # Under jit (eagerly checked above): a bad ellipsoid, or a grid no ellipsoid can be drawn on.
    grid_ok = _finite(origin, 1) & (res > 0) & (res < jnp.inf)
    valid = _ellipsoid_ok(rotation, center, radii) & grid_ok
    origin = jnp.where(grid_ok, origin, jnp.zeros_like(origin))
    resolution = jnp.where(grid_ok, res, jnp.ones_like(res))  # keeps a Python number's weak type
    rot = _finite_or_zero(rotation).reshape(-1, 3, 3)
    ctr = _finite_or_zero(center).reshape(-1, 3)
    rad = _finite_or_zero(radii).reshape(-1, 3)
    shape = _matmul3(rot * jnp.square(rad)[..., None, :], jnp.swapaxes(rot, -1, -2))
    a, b, c = shape[:, 0, 0], shape[:, 0, 1], shape[:, 1, 1]
    det = a * c - b * b
    H, W = int(grid_shape[0]), int(grid_shape[1])
    xs = origin[0] + (jnp.arange(W, dtype=ctr.dtype) + 0.5) * resolution
    ys = origin[1] + (jnp.arange(H, dtype=ctr.dtype) + 0.5) * resolution
    dx = xs[None, None, :] - ctr[:, 0, None, None]
    dy = ys[None, :, None] - ctr[:, 1, None, None]
    # (d^T S_xy^{-1} d <= 1) multiplied through by det(S_xy) > 0: no division by a tiny det.
    quad = c[:, None, None] * dx * dx - 2 * b[:, None, None] * dx * dy + a[:, None, None] * dy * dy
    drawn = (mask & valid).reshape(-1)[:, None, None]
    inside = (quad <= det[:, None, None]) & (det[:, None, None] > 0) & drawn
    values = jnp.where(inside, class_id.reshape(-1)[:, None, None], 0)
    grid = jnp.max(values, axis=0, initial=0).astype(jnp.int32)
    return (grid, valid) if with_valid else grid

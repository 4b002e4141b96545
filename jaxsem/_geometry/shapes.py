"""Points against objects (eq. 5.5, 5.12): algebraic distance, ray entry and surface samples, and
objects drawn as cuboids, ellipsoids or cylinders (VoluMon's shape-aware losses, thesis 5.4).

Re-exported by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._checks import (
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
)
from ._common import (
    _ellipsoid_args,
    _finite_or_zero,
    _matvec,
    safe_div,
    safe_norm,
    safe_sqrt,
)
from .bbox import project_bbox
from .conics import _inverse_square_radii, cylinder_bbox
from .poses import cuboid_corners, project_points

# --------------------------------------------------------------------------------------------
# Points against an ellipsoid: inside-outside, where a viewing ray enters, surface samples.


def algebraic_distance(points, rotation, center, radii):
    """Primal algebraic distance ``x^T Q x`` of points to an ellipsoid (eq. 5.5, 5.12).

    Evaluated as ``|diag(1/r) R^T (x - t)|^2 - 1``, which equals ``[x, 1] Q [x, 1]^T`` exactly and
    keeps its precision far from the origin.

    Args:
      points: (..., N, 3) world points.
      rotation: (..., 3, 3); center: (..., 3); radii: (..., 3) (batch axes broadcast with the
        points' leading axes).

    Returns:
      (..., N): negative inside, zero on the surface, positive outside.
    """
    points = _as_float_array("points", points, (3,), check_finite=True)
    if points.ndim < 2:
        raise ValueError(f"points: expected shape (..., N, 3), got shape {tuple(points.shape)}")
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    _batch_shape(points=points.shape[:-2], ellipsoid=batch)
    dtype = jnp.result_type(points.dtype, rotation.dtype)
    local = _matvec(
        jnp.swapaxes(rotation, -1, -2)[..., None, :, :].astype(dtype),
        points.astype(dtype) - center[..., None, :].astype(dtype),
    )
    inv_sq = _inverse_square_radii(radii.astype(dtype))[..., None, :]
    return jnp.sum(local * local * inv_sq, axis=-1) - 1.0


def ray_entry_range(points, rotation, center, radii, shape):
    """Where each point's viewing ray first enters the object drawn with ``shape``.

    The ray of point ``x`` (camera frame, camera at the origin) is ``s x / |x|``, ``s >= 0``.
    ``shape``: 0 cuboid of half extents ``radii`` (slab test), 1 ellipsoid (the quadratic
    ``|diag(1/r) R^T (s u - t)| = 1``), 2 cylinder along the object's z axis (elliptic section of
    semi-axes ``radii[:2]``, slab ``|z| <= radii[2]``). A depth image's range minus ``s_entry`` is
    the distance from the object along the pixel's own ray.

    Args:
      points: (..., J, 3) camera frame; rotation (..., 3, 3) object-to-camera; center, radii
        (..., 3); shape (...) int.

    Returns:
      ``(s_entry (..., J), hit (..., J) bool)``: the range (m) at which the ray enters the object,
      and whether it does in front of the camera. Where ``hit`` is False ``s_entry`` is finite and
      meaningless; values and gradients are finite everywhere.
    """
    points = _as_float_array("points", points, (3,), check_finite=True)
    if points.ndim < 2:
        raise ValueError(f"points: expected shape (..., N, 3), got shape {tuple(points.shape)}")
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    _batch_shape(points=points.shape[:-2], ellipsoid=batch)
    rng = safe_norm(points)
    u = jnp.einsum("...ji,...nj->...ni", rotation, safe_div(points, rng[..., None]))  # ray, object frame
    o = -jnp.einsum("...ji,...j->...i", rotation, center)[..., None, :]  # camera centre, object frame
    r = radii[..., None, :]
    big = jnp.asarray(1e6, points.dtype)

    # ellipsoid: a s^2 + b s + c = 0 in coordinates scaled by the radii
    us, os_ = u / r, o / r
    a = jnp.sum(us * us, -1)
    b = 2.0 * jnp.sum(us * os_, -1)
    c = jnp.sum(os_ * os_, -1) - 1.0
    disc = b * b - 4.0 * a * c
    s_ell = safe_div(-b - safe_sqrt(disc), 2.0 * a)
    hit_ell = (disc > 0) & (s_ell > 0)

    # cuboid: slab test
    t1 = safe_div(-r - o, u)
    t2 = safe_div(r - o, u)
    lo, hi = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
    s_cub = jnp.max(lo, -1)
    hit_cub = (s_cub < jnp.min(hi, -1)) & (s_cub > 0)

    # cylinder: the section's quadratic on (x, y), the slab on z
    a2 = jnp.sum(us[..., :2] ** 2, -1)
    b2 = 2.0 * jnp.sum(us[..., :2] * os_[..., :2], -1)
    c2 = jnp.sum(os_[..., :2] ** 2, -1) - 1.0
    disc2 = b2 * b2 - 4.0 * a2 * c2
    parallel = a2 < 1e-12
    root = safe_sqrt(disc2)
    s_in = jnp.where(parallel, jnp.where(c2 < 0, -big, big), safe_div(-b2 - root, 2.0 * a2))
    s_out = jnp.where(parallel, jnp.where(c2 < 0, big, -big), safe_div(-b2 + root, 2.0 * a2))
    s_cyl = jnp.maximum(s_in, lo[..., 2])
    hit_cyl = ((disc2 > 0) | parallel) & (s_cyl < jnp.minimum(s_out, hi[..., 2])) & (s_cyl > 0)

    shape = jnp.asarray(shape)[..., None]
    s = jnp.where(shape == 0, s_cub, jnp.where(shape == 2, s_cyl, s_ell))
    hit = jnp.where(shape == 0, hit_cub, jnp.where(shape == 2, hit_cyl, hit_ell))
    return jnp.where(hit, s, 0.0), hit


def surface_points(key, rotation, center, radii, n: int):
    """Random points on the ellipsoid surface, (..., n, 3).

    Directions are uniform on the unit sphere, then scaled by the radii and moved to the world
    (so the density is uniform in the ellipsoid's parametric angle, not in area).
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    u = jax.random.normal(key, batch + (int(n), 3), dtype=center.dtype)
    norm = safe_norm(u, axis=-1, keepdims=True)
    fallback = jnp.array([1.0, 0.0, 0.0], u.dtype)
    u = jnp.where(norm > 0, u / jnp.where(norm > 0, norm, 1.0), fallback)
    local = u * radii[..., None, :]
    return _matvec(rotation[..., None, :, :], local) + center[..., None, :]


# --------------------------------------------------------------------------------------------
# Objects drawn as cuboids, ellipsoids or cylinders (VoluMon's shape-aware losses, thesis 5.4)

#: shape ids of :func:`shape_bbox`, :func:`shape_distance` and :func:`ray_entry_range`
SHAPE_CUBOID, SHAPE_ELLIPSOID, SHAPE_CYLINDER = 0, 1, 2
#: Solina-Bajcsy exponent of a cuboid's faces / a cylinder's caps in :func:`shape_distance`
SUPERQUADRIC_EPS = 0.1


def shape_bbox(rotation, center, radii, shape, K, camera_T_world):
    """Image box (..., 4) and validity (...) of the object of semi-axes ``radii`` drawn with ``shape``.

    ``shape`` (...) int: :data:`SHAPE_CUBOID` (box of the 8 corners of half extents ``radii``,
    :func:`cuboid_corners`), :data:`SHAPE_ELLIPSOID` (:func:`project_bbox`, eq. 4.10),
    :data:`SHAPE_CYLINDER` along the object's z axis (:func:`cylinder_bbox`, exact). Valid where
    the ellipsoid is projectable and all corners of the bounding cuboid lie in front of the camera
    (then so does the object, whatever its shape). Traceable; finite values and gradients.
    """
    ell, valid = project_bbox(rotation, center, radii, K, camera_T_world)  # valid folds the input checks
    # Non-finite entries read as 0 (valid is already False there): finite values and gradients
    # for the cuboid and cylinder branches too, which a select would not keep from a NaN.
    rotation, center, radii, K, camera_T_world = (
        _finite_or_zero(jnp.asarray(x)) for x in (rotation, center, radii, K, camera_T_world)
    )
    corners = cuboid_corners(rotation, center, radii)
    pose = camera_T_world[..., None, :, :]
    uv, depth = project_points(corners, K[..., None, :, :], pose)
    cub = jnp.concatenate([uv.min(-2), uv.max(-2)], -1)
    cyl, _ = cylinder_bbox(rotation, center, radii, K, camera_T_world)
    shape = jnp.asarray(shape)[..., None]
    box = jnp.where(shape == SHAPE_CUBOID, cub, jnp.where(shape == SHAPE_CYLINDER, cyl, ell))
    return box, valid & jnp.all(depth > 1e-3, -1)


def shape_distance(points, rotation, center, radii, shape):
    """Inside-outside function (..., J) of points (..., J, 3) for the object drawn with ``shape`` (...).

    Ellipsoid: ``x^T Q x`` (:func:`algebraic_distance`, eq. 4.2's quadric). Cuboid and cylinder:
    Solina and Bajcsy's superquadric ``F - 1`` with ``F = ((x/a)^(2/e2) + (y/b)^(2/e2))^(e2/e1) +
    (z/c)^(2/e1)`` raised to ``e1`` (so it is ``~ 2 delta / r`` near the surface, as the
    ellipsoid's), ``e1 = e2 =`` :data:`SUPERQUADRIC_EPS` for a cuboid, ``e1 = 0.1, e2 = 1`` for a
    cylinder; evaluated as a log-sum-exp (finite values and gradients for any point, also at the
    centre). Negative inside, zero on the surface, positive outside.
    """
    q_ell = algebraic_distance(points, rotation, center, radii)
    x = jnp.einsum("...ji,...nj->...ni", rotation, points - center[..., None, :]) / radii[..., None, :]
    tiny = jnp.finfo(x.dtype).tiny ** 0.5
    e = SUPERQUADRIC_EPS
    lx = jnp.log(jnp.square(x) + tiny)  # log x_i^2
    cub = jnp.exp(e * jax.nn.logsumexp(lx / e, axis=-1)) - 1.0
    lxy = jnp.log(jnp.square(x[..., 0]) + jnp.square(x[..., 1]) + tiny)
    cyl = jnp.exp(e * jnp.logaddexp(lxy / e, lx[..., 2] / e)) - 1.0
    shape = jnp.asarray(shape)[..., None]
    return jnp.where(shape == SHAPE_CUBOID, cub, jnp.where(shape == SHAPE_CYLINDER, cyl, q_ell))

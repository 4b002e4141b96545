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
    _ellipsoid_ok,
    _finite_or_zero,
    _matvec,
    _matvec_terms,
    _radii_ok,
    _sum3,
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
    local = _matvec_terms(
        jnp.swapaxes(rotation, -1, -2)[..., None, :, :].astype(dtype),
        points.astype(dtype) - center[..., None, :].astype(dtype),
    )
    inv_sq = _inverse_square_radii(radii.astype(dtype))[..., None, :]
    return _sum3(local * local * inv_sq) - 1.0


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
      meaningless; values and gradients are finite everywhere. Under ``jit`` an object the eager
      checks refuse (a rotation that is not one, a non-finite centre, radii not positive: only
      their squares or magnitudes enter, so a negated radius would draw the same object) is hit
      by no ray.
    """
    points = _as_float_array("points", points, (3,), check_finite=True)
    if points.ndim < 2:
        raise ValueError(f"points: expected shape (..., N, 3), got shape {tuple(points.shape)}")
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    _batch_shape(points=points.shape[:-2], ellipsoid=batch)
    ok = _ellipsoid_ok(rotation, center, radii)[..., None]  # the inputs, under jit
    rotation, center, radii = (_finite_or_zero(x) for x in (rotation, center, radii))
    rng = safe_norm(points)
    u = jnp.einsum("...ji,...nj->...ni", rotation, safe_div(points, rng[..., None]))  # ray, object frame
    o = -jnp.einsum("...ji,...j->...i", rotation, center)[..., None, :]  # camera centre, object frame
    s, hit, _ = ray_cast_local(o, u, radii[..., None, :], jnp.asarray(shape)[..., None])
    hit = hit & ok
    return jnp.where(hit, s, 0.0), hit


def ray_cast_local(origin, direction, radii, shape):
    """First entry of rays ``origin + s direction``, ``s > 0``, into an object in its own frame.

    The one ray-shape intersection of the package: :func:`ray_entry_range` (a loss's range to
    the object) and VoluMon's analytic renderer (depth, mask and shading of its training images)
    both use it. ``shape`` as :func:`ray_entry_range`: :data:`SHAPE_CUBOID` of half extents
    ``radii`` (slab test), :data:`SHAPE_ELLIPSOID` of semi-axes ``radii`` (the quadratic in
    coordinates scaled by the radii), :data:`SHAPE_CYLINDER` along z (elliptic section of
    semi-axes ``radii[:2]``, caps at ``z = +-radii[2]``). ``direction`` need not be a unit vector:
    ``s`` is in its units (a ray of camera z = 1 gives the z-depth).

    Args:
      origin, direction: (..., 3) object frame; radii (..., 3); shape (...) int (all broadcast).

    Returns:
      ``(s, hit, normal)``: ``s`` (...) the ray parameter of the entry, 0 where ``hit`` (...) is
      False; ``normal`` (..., 3) the outward unit normal there (meaningless where no hit). Values
      are finite everywhere and the gradients of ``s`` too. Radii that are not all positive and
      finite describe no object: no ray hits it (a negated radius would otherwise draw the
      object of its magnitude).
    """
    o, d, h = (jnp.asarray(x) for x in (origin, direction, radii))
    # cuboid: slab test; the entry face is the axis of the latest entering slab
    inv = 1.0 / jnp.where(jnp.abs(d) < 1e-9, 1e-9, d)
    t1 = (-h - o) * inv
    t2 = (h - o) * inv
    tmin = jnp.minimum(t1, t2)
    tmax = jnp.maximum(t1, t2)
    s_cub = jnp.max(tmin, -1)
    hit_cub = (jnp.min(tmax, -1) >= s_cub) & (s_cub > 0)
    axis = jnp.argmax(tmin, -1)
    p = o + s_cub[..., None] * d
    n_cub = jax.nn.one_hot(axis, 3, dtype=o.dtype) * jnp.sign(jnp.take_along_axis(p, axis[..., None], -1))

    # ellipsoid: a s^2 + b s + c = 0 in coordinates scaled by the radii
    os_, ds = o / h, d / h
    a = jnp.sum(ds * ds, -1)
    b = 2 * jnp.sum(os_ * ds, -1)
    c = jnp.sum(os_ * os_, -1) - 1
    disc = b * b - 4 * a * c
    s_ell = safe_div(-b - safe_sqrt(disc), 2 * a)
    hit_ell = (disc > 0) & (s_ell > 0)
    n_ell = (o + s_ell[..., None] * d) / (h * h)
    n_ell = n_ell / jnp.maximum(jnp.linalg.norm(n_ell, axis=-1, keepdims=True), 1e-9)

    # cylinder: the nearer of the side (the section's quadratic, within the caps) and the caps
    h0, h1, h2 = h[..., 0], h[..., 1], h[..., 2]
    a = (d[..., 0] / h0) ** 2 + (d[..., 1] / h1) ** 2
    b = 2 * (o[..., 0] * d[..., 0] / h0**2 + o[..., 1] * d[..., 1] / h1**2)
    c = (o[..., 0] / h0) ** 2 + (o[..., 1] / h1) ** 2 - 1
    disc = b * b - 4 * a * c
    s_side = (-b - safe_sqrt(disc)) / (2 * jnp.maximum(a, 1e-12))
    z_side = o[..., 2] + s_side * d[..., 2]
    side_ok = (disc > 0) & (s_side > 0) & (jnp.abs(z_side) <= h2)
    dz = jnp.where(jnp.abs(d[..., 2]) < 1e-9, 1e-9, d[..., 2])
    s_cap = jnp.minimum((h2 - o[..., 2]) / dz, (-h2 - o[..., 2]) / dz)
    pc = o + s_cap[..., None] * d
    cap_ok = (s_cap > 0) & ((pc[..., 0] / h0) ** 2 + (pc[..., 1] / h1) ** 2 <= 1)
    big = jnp.asarray(1e9, o.dtype)
    s_cyl = jnp.minimum(jnp.where(side_ok, s_side, big), jnp.where(cap_ok, s_cap, big))
    hit_cyl = side_ok | cap_ok
    p = o + s_cyl[..., None] * d
    n_side = jnp.stack([p[..., 0] / h0**2, p[..., 1] / h1**2, jnp.zeros_like(s_cyl)], -1)
    n_side = n_side / jnp.maximum(jnp.linalg.norm(n_side, axis=-1, keepdims=True), 1e-9)
    n_cap = jnp.stack([jnp.zeros_like(s_cyl), jnp.zeros_like(s_cyl), jnp.sign(p[..., 2])], -1)
    use_cap = cap_ok & (~side_ok | (s_cap <= s_side))
    n_cyl = jnp.where(use_cap[..., None], n_cap, n_side)

    shape = jnp.asarray(shape)
    is_cub, is_cyl = shape == SHAPE_CUBOID, shape == SHAPE_CYLINDER
    s = jnp.where(is_cub, s_cub, jnp.where(is_cyl, s_cyl, s_ell))
    hit = jnp.where(is_cub, hit_cub, jnp.where(is_cyl, hit_cyl, hit_ell)) & _radii_ok(h)
    normal = jnp.where(is_cub[..., None], n_cub, jnp.where(is_cyl[..., None], n_cyl, n_ell))
    return jnp.where(hit, s, 0.0), hit, normal


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

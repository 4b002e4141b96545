r"""ROSHAN residual functions (thesis eq. 4.13), robust losses and the class shape table.

Every factor is a pure function returning a *whitened* residual (divided by its standard
deviation), so that the cost is ``0.5 * sum(r**2)`` and Levenberg-Marquardt can be applied
directly. All functions broadcast over leading batch axes and work under ``jit``, ``vmap`` and
``grad``; none returns NaN values or NaN gradients for finite inputs.

The four factors of eq. 4.13, and odometry:

1. :func:`pose_prior_residual`: ``log(prior^-1 * pose)`` on SE(3) (jaxlie), ``[v, omega]``;
   :func:`between_residual`: the relative motion between two poses against an odometry step
   (GTSAM's ``BetweenFactor<Pose3>``), for sequences whose poses come from odometry.
2. :func:`box_residual`: the four box edges (eq. 4.10) of the projected ellipsoid against the
   measured box; an edge of the *measured* box within ``border_margin`` pixels of the image
   border is non-constraining and dropped by a mask (section 4.3.2), not truncated. Degenerate
   geometry (camera inside the ellipsoid, ellipsoid behind or straddling the principal plane,
   non-ellipse conic) gives a finite residual that grows with the violation, plus two barrier
   residuals (near-side depth below ``min_depth``, camera inside the ellipsoid) whose gradients
   lead back to valid geometry. Never a flat constant.
3. :func:`texture_residual`: depth of the camera-facing tangent plane (eq. 4.11) minus the
   measured texture-plane depth. It is a smooth function everywhere, degenerate or not.
4. :func:`shape_prior_residual`: radii against the class mean, per-axis sigma (section 4.3.4).
5. :func:`upright_residual` (optional, not in the thesis): the object's height axis along the
   world's up, for objects resting on a table or the ground.
6. :func:`support_residual` (optional, not in the thesis): the object's lowest point on a known
   horizontal support.

Radii are kept positive by the parameterisation ``radii = softplus(s)``
(:func:`radii_from_param` / :func:`param_from_radii`): linear for large radii (no overflow),
log-like for small ones, and never negative, unlike QuadricSLAM where only ``r**2`` enters.

The built-in class table :data:`SHAPE_PRIORS` (the rows of :data:`jaxsem.classes.DEFAULT_TABLE`;
a user's own table is a :class:`jaxsem.classes.ClassTable`, read by :func:`shape_prior_table`)
gives semi-axis *radii* in metres (half the full
dimensions) in the object frame ``x = length, y = width, z = height`` (z up for vehicles,
furniture and people), except the VoluMon (FAT) objects which keep the FAT object frame of
their ``cuboid_dimensions`` (x, y, z in that order).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jax.typing import ArrayLike

from . import classes as _classes
from .quadrics import (
    algebraic_distance,
    depth_from_box_size,
    half_extent,
    invert_pose,
    project_bbox,
    safe_div,
    safe_sqrt,
    single_view_ellipsoid,
    texture_plane_depth,
)

__all__ = [
    "CLASS_NAMES",
    "ROBUST_LOSSES",
    "SHAPE_PRIORS",
    "ShapePrior",
    "between_residual",
    "box_residual",
    "class_index",
    "edge_mask",
    "param_from_radii",
    "pose_prior_residual",
    "radii_from_param",
    "robust_residual",
    "shape_prior",
    "shape_prior_residual",
    "shape_prior_table",
    "single_view_init",
    "texture_residual",
    "support_residual",
    "upright_residual",
]


# --------------------------------------------------------------------------------------------
# Class shape table (section 4.3.4).


class ShapePrior(NamedTuple):
    """Gaussian prior on an object's semi-axis radii (metres), diagonal covariance."""

    mean: tuple[float, float, float]
    sigma: tuple[float, float, float]


# The rows come from the one class table, :mod:`jaxsem.classes` (full dimensions there, radii
# here: the residual of section 4.3.4 is on the semi-axes).
SHAPE_PRIORS: dict[str, ShapePrior] = {c.name: ShapePrior(c.radii, c.radii_sigma) for c in _classes.CLASSES}

CLASS_NAMES: tuple[str, ...] = _classes.CLASS_NAMES


def class_index(name: str) -> int:
    """Index of class ``name`` in :data:`CLASS_NAMES`; ``ValueError`` listing the known classes
    (:func:`jaxsem.classes.index`: the shape table's rows are the class table's, in its order)."""
    return _classes.index(name)


def shape_prior(name: str) -> ShapePrior:
    """The :class:`ShapePrior` of class ``name`` (``ValueError`` listing known classes)."""
    return SHAPE_PRIORS[CLASS_NAMES[class_index(name)]]


def shape_prior_table(dtype=None, classes: _classes.ClassTable | None = None):
    """Class table as arrays ``(mean (C, 3), sigma (C, 3))`` of semi-axis radii, in the order of
    ``classes`` (a :class:`jaxsem.classes.ClassTable`; default the built-in table, whose order
    is :data:`CLASS_NAMES`)."""
    dtype = dtype or jnp.result_type(float)
    if classes is None:
        mean = np.array([SHAPE_PRIORS[c].mean for c in CLASS_NAMES])
        sigma = np.array([SHAPE_PRIORS[c].sigma for c in CLASS_NAMES])
    else:
        mean, sigma = _classes.as_table(classes).radii_table()
    return jnp.asarray(mean, dtype), jnp.asarray(sigma, dtype)


# --------------------------------------------------------------------------------------------
# Positive radii and robust losses.


def radii_from_param(s):
    """``radii = softplus(s)``: positive, linear for large ``s``, no overflow. (..., 3)."""
    return jax.nn.softplus(s)


def param_from_radii(radii):
    """Inverse of :func:`radii_from_param`: ``s = r + log(-expm1(-r))`` (radii must be > 0)."""
    radii = jnp.asarray(radii)
    if not jnp.issubdtype(radii.dtype, jnp.inexact):
        radii = radii.astype(jnp.result_type(float))
    # A Python float (weak type): float32 radii stay float32 under x64.
    tiny = float(jnp.finfo(radii.dtype).tiny)
    r = jnp.maximum(radii, 1e-6)
    return r + jnp.log(jnp.maximum(-jnp.expm1(-r), tiny))


ROBUST_LOSSES = ("l2", "huber", "cauchy")


def robust_residual(r, loss: str = "l2", scale: ArrayLike = 1.0):
    """Reweights a whitened residual so that ``r'**2 = rho(r)`` (per component).

    ``huber``: ``rho = r^2`` for ``|r| <= k``, ``2k|r| - k^2`` beyond; ``cauchy``:
    ``rho = k^2 log(1 + r^2/k^2)``. ``k = scale`` in whitened units (sigmas). Because the
    reweighted residual keeps the sign of ``r``, Gauss-Newton / LM apply unchanged (the
    "square-root of the robust cost" trick); gradients are finite at ``r = 0``.
    """
    if loss == "l2":
        return r
    k = jnp.asarray(scale, jnp.result_type(r))
    if loss == "huber":
        a = jnp.abs(r)
        big = a > k
        # sqrt(2k|r| - k^2) on the linear branch; the other branch sees a safe argument.
        lin = jnp.sign(r) * safe_sqrt(jnp.where(big, 2.0 * k * a - k * k, k * k))
        return jnp.where(big, lin, r)
    if loss == "cauchy":
        x = jnp.square(r / k)
        small = x < 1e-6
        xs = jnp.where(small, 1.0, x)
        # r * sqrt(log1p(x) / x): the ratio is smooth and -> 1 - x/2 at 0 (no 0 * inf).
        ratio = jnp.where(small, 1.0 - 0.5 * x, jnp.log1p(xs) / xs)
        return r * jnp.sqrt(ratio)
    raise ValueError(f"loss: expected one of {list(ROBUST_LOSSES)}, got {loss!r}")


# --------------------------------------------------------------------------------------------
# Factors.


def pose_prior_residual(camera_T_world, prior, rotation_sigma, translation_sigma):
    """Pose prior factor: ``log(prior pose^-1) / sigma`` on SE(3), in the camera frame.

    The error is expressed in the camera (body) frame, as GTSAM's ``PriorFactor<Pose3>`` on
    ``world_T_camera`` does (``prior pose^-1 = world_T_prior^-1 world_T_camera``): odometry noise
    is a rotation about the camera's own centre plus a shift of that centre, so its whitened
    residual has unit variance whatever the camera's distance from the world origin. (The
    world-frame error ``log(prior^-1 pose)`` turns a 1 deg rotation 30 m from the origin into a
    0.5 m translation residual and over-weights the prior far from the origin.)

    Args:
      camera_T_world: (..., 4, 4) pose estimate; prior: (..., 4, 4) measured pose.
      rotation_sigma: radians (scalar or (..., 3)); translation_sigma: metres.

    Returns:
      (..., 6) whitened ``[translation part v (3), rotation part omega (3)]`` of jaxlie's log.
    """
    camera_T_world = jnp.asarray(camera_T_world)
    dtype = jnp.result_type(camera_T_world, prior)
    # Matrix product, then log in the default float dtype, cast back: jaxlie's SE3 log mixes
    # float32 with its own float64 constants under x64 (refused by strict dtype promotion).
    rel = jnp.asarray(prior, dtype) @ invert_pose(camera_T_world.astype(dtype))
    err = jaxlie.SE3.from_matrix(rel.astype(jnp.result_type(float))).log().astype(dtype)
    ts = jnp.broadcast_to(jnp.asarray(translation_sigma, err.dtype), err.shape[:-1] + (3,))
    rs = jnp.broadcast_to(jnp.asarray(rotation_sigma, err.dtype), err.shape[:-1] + (3,))
    return err / jnp.concatenate([ts, rs], axis=-1)


def between_residual(camera_T_world_a, camera_T_world_b, measured, rotation_sigma, translation_sigma):
    """Odometry (between) factor: the motion from pose ``a`` to pose ``b`` against a measured one.

    ``measured`` is camera ``b``'s pose in camera ``a``'s frame, ``a_T_b``
    (:func:`jaxsem.quadrics.relative_pose` of the true poses for a perfect odometry). The error
    is ``log(measured^-1 a_T_b)``: GTSAM's ``BetweenFactor<Pose3>`` on ``world_T_camera``,
    expressed in camera ``b``'s frame, so a step's noise is a rotation about the camera plus a
    shift of it whatever the distance from the world origin (the same convention as
    :func:`pose_prior_residual`, which is this factor with pose ``a`` the world origin).

    Args:
      camera_T_world_a, camera_T_world_b: (..., 4, 4) pose estimates; measured: (..., 4, 4).
      rotation_sigma: radians (scalar or (..., 3)); translation_sigma: metres.

    Returns:
      (..., 6) whitened ``[translation part v (3), rotation part omega (3)]`` of jaxlie's log;
      zero when the estimated relative motion equals ``measured``.
    """
    a = jnp.asarray(camera_T_world_a)
    dtype = jnp.result_type(a, camera_T_world_b, measured)
    a = a.astype(dtype)
    b = jnp.asarray(camera_T_world_b, dtype)
    # measured^-1 a_T_b = (b_T_a measured)^-1: one product chain, then log, cast back (jaxlie's
    # SE3 promotes float32 to float64 under x64).
    rel = invert_pose(jnp.asarray(measured, dtype)) @ a @ invert_pose(b)
    err = jaxlie.SE3.from_matrix(rel.astype(jnp.result_type(float))).log().astype(dtype)
    ts = jnp.broadcast_to(jnp.asarray(translation_sigma, err.dtype), err.shape[:-1] + (3,))
    rs = jnp.broadcast_to(jnp.asarray(rotation_sigma, err.dtype), err.shape[:-1] + (3,))
    return err / jnp.concatenate([ts, rs], axis=-1)


def edge_mask(box, image_size, border_margin):
    """Which edges of the measured box constrain the object (section 4.3.2).

    Args:
      box: (..., 4) measured ``[u_min, v_min, u_max, v_max]``.
      image_size: (..., 2) ``[width, height]``. border_margin: pixels.

    Returns:
      (..., 4) bool: False for an edge within ``border_margin`` of the image border on its side
      (``u_min`` near 0, ``v_min`` near 0, ``u_max`` near width, ``v_max`` near height).
    """
    box = jnp.asarray(box)
    image_size = jnp.asarray(image_size, box.dtype)
    w, h = image_size[..., 0], image_size[..., 1]
    return jnp.stack(
        [
            box[..., 0] > border_margin,
            box[..., 1] > border_margin,
            box[..., 2] < w - border_margin,
            box[..., 3] < h - border_margin,
        ],
        axis=-1,
    )


BOX_RESIDUAL_DIM = 6


def box_residual(
    camera_T_world,
    rotation,
    center,
    radii,
    box,
    K,
    image_size,
    *,
    box_sigma: ArrayLike = 3.0,
    border_margin: ArrayLike = 10.0,
    barrier_weight: ArrayLike = 10.0,
    min_depth: ArrayLike = 0.1,
    degenerate_residual: ArrayLike = 1000.0,
    loss: str = "l2",
    robust_scale: ArrayLike = 2.0,
    projection=None,
    outward_scale: ArrayLike = 1.0,
):
    """ROSHAN box factor (section 4.3.2) with barriers for degenerate geometry.

    Args:
      camera_T_world: (..., 4, 4); rotation (..., 3, 3), center (..., 3), radii (..., 3).
      box: (..., 4) measured box; K: (..., 3, 3); image_size: (..., 2) ``[width, height]``.
      box_sigma: pixels per edge. border_margin: pixels (edge classification).
      barrier_weight: weight of the two barrier residuals (whitened units per metre of depth
        deficit, and per unit of the camera's negative algebraic distance).
      min_depth: metres; the ellipsoid's near side should be at least this far in front.
      degenerate_residual: pixels. Valid edge errors are softly capped at this size
        (``c tanh(e / c)``, linear for errors far below it) and an invalid projection gives
        ``c + barrier_weight * (min_depth - near)`` per edge, so stepping into invalid geometry
        never lowers a factor's cost and the way out is always downhill.
      loss, robust_scale: robust reweighting of the edge residuals (:func:`robust_residual`).
      projection: optional ``(box (..., 4), valid (...))`` to use in place of
        :func:`jaxsem.quadrics.project_bbox` of these inputs. A solver that linearises the factor
        passes the box's first-order model built from
        :func:`jaxsem.quadrics.project_bbox_jacobian` (its derivative then comes from that closed
        form, not from differentiating the projection again).
      outward_scale: the sigma of an edge error is ``outward_scale`` times ``box_sigma`` where the
        predicted edge lies outside the measured box (left of its left edge, above its top ...):
        a measured box is the *visible* part of the object, and an occluder can only cut edges
        inwards, so a projection reaching past a measured edge is likelier than one falling
        short of it. 1.0: symmetric (the thesis' factor). The residual stays continuous at zero.

    Returns:
      (..., 6): 4 whitened edge residuals (zero where the measured edge is at the border), the
      near-depth barrier and the camera-inside barrier. Zero at the truth for exact boxes.
    """
    if projection is None:
        projection = project_bbox(rotation, center, radii, K, camera_T_world)
    pred, valid = projection
    box = jnp.asarray(box, pred.dtype)
    sigma = jnp.asarray(box_sigma, pred.dtype)
    cap = degenerate_residual / sigma
    d = pred - box
    # Edges [x0, y0, x1, y1]: outside the box is d < 0 for the first two, d > 0 for the others.
    outward = jnp.concatenate([d[..., :2] < 0, d[..., 2:] > 0], axis=-1)
    sigma = jnp.where(outward, sigma * jnp.asarray(outward_scale, pred.dtype), sigma)
    e = robust_residual(d / sigma, loss, robust_scale)
    e = cap * jnp.tanh(e / cap)
    near, _ = texture_plane_depth(rotation, center, radii, camera_T_world)
    deficit = jnp.maximum(min_depth - near, 0.0)
    invalid_edge = cap + barrier_weight * deficit
    edges = jnp.where(valid[..., None], e, invalid_edge[..., None])
    edges = jnp.where(edge_mask(box, image_size, border_margin), edges, 0.0)
    # Camera centre in the world: -R^T t; inside the ellipsoid when x^T Q x < 0.
    R = camera_T_world[..., :3, :3]
    t = camera_T_world[..., :3, 3:4]
    cam = -(
        R[..., 0, :] * t[..., 0, :] + R[..., 1, :] * t[..., 1, :] + R[..., 2, :] * t[..., 2, :]
    )  # no size-3 reduction
    alg = algebraic_distance(cam[..., None, :], rotation, center, radii)[..., 0]
    depth_barrier = barrier_weight * deficit
    inside_barrier = barrier_weight * jnp.maximum(-alg, 0.0)
    return jnp.concatenate([edges, depth_barrier[..., None], inside_barrier[..., None]], axis=-1)


def texture_residual(
    camera_T_world,
    rotation,
    center,
    radii,
    texture_depth,
    texture_sigma: ArrayLike = 0.3,
    plane_fraction: ArrayLike = 1.0,
):
    """Texture-plane factor (section 4.3.3): ``(near-plane depth - measured depth) / sigma``.

    The predicted plane is ``t_z - plane_fraction * sqrt(e3^T R_c diag(r^2) R_c^T e3)``:
    ``plane_fraction`` 1 is the thesis' tangent plane on the camera-facing side; 2/3 is the mean
    depth of the visible surface of an ellipsoid sampled uniformly over its image (orthographic
    approximation), which is what a mean of triangulated feature depths measures (checked on
    LM-O's real desk: ``benchmarks/roshan/HISTORY.md``, "ROSHAN on the real LM-O desk").

    Args:
      camera_T_world: (..., 4, 4); rotation (..., 3, 3); center (..., 3); radii (..., 3).
      texture_depth: (...) metres, the measured plane ``z_cam = depth``.
      plane_fraction: fraction of the half-depth extent between the centre and the tangent plane.

    Returns:
      (...) whitened residual; finite and smooth everywhere (the predicted depth is
      ``t_z - sqrt(e3^T R_c diag(r^2) R_c^T e3)``, defined even for invalid geometry).
    """
    depth, _ = texture_plane_depth(rotation, center, radii, camera_T_world)
    pose = jnp.asarray(camera_T_world, depth.dtype)
    tz = jnp.sum(pose[..., 2, :3] * jnp.asarray(center, depth.dtype), axis=-1) + pose[..., 2, 3]
    depth = tz - plane_fraction * (tz - depth)
    return (depth - jnp.asarray(texture_depth, depth.dtype)) / texture_sigma


def shape_prior_residual(radii, mean, sigma):
    """Semantic shape prior (section 4.3.4): ``(radii - mean) / sigma``, (..., 3)."""
    return safe_div(jnp.asarray(radii) - mean, sigma)


def upright_residual(rotation, up, sigma, axis: int = 2):
    """Upright prior: an object's ``axis`` (its height, the class table's third dimension) along
    the world's ``up`` (gravity's opposite: a VIO / IMU gives it; on a desk, the desk normal).

    Objects resting on a table or a floor stand on their base; boxes alone leave their tilt
    weakly observed (tens of degrees on the real LM-O desk). The residual is ``up`` expressed
    in the object frame, its two components along the other axes, over ``sigma``: about
    ``sin(tilt) / sigma``, zero for an upright object whatever its heading, and zero for the
    upside-down one too (an ellipsoid is unchanged by that flip), smooth everywhere.

    Args:
      rotation: (..., 3, 3) object-to-world. up: (3,) or (..., 3) unit vector in the world.
      sigma: radians (scalar or broadcastable): the tilt's standard deviation.
      axis: the object axis that stands up (0, 1 or 2).

    Returns:
      (..., 2) whitened residual.

    Raises:
      ValueError: ``axis`` not 0, 1 or 2.
    """
    if axis not in (0, 1, 2):
        raise ValueError(f"axis: expected 0, 1 or 2, got {axis!r}")
    rotation = jnp.asarray(rotation)
    up = jnp.asarray(up, rotation.dtype)
    local = jnp.einsum("...ji,...j->...i", rotation, up)  # R^T up
    others = [a for a in range(3) if a != axis]
    return safe_div(local[..., others], jnp.asarray(sigma, rotation.dtype))


def support_residual(rotation, center, radii, up, height, sigma):
    """Support prior: an object's lowest point on a known horizontal support (a desk, a floor).

    The lowest point of the ellipsoid along the world's ``up`` is at ``center . up -
    |diag(radii) R^T up|`` (the support function of the ellipsoid in the ``-up`` direction); the
    residual is its height above the support at ``height`` over ``sigma``. A tabletop user knows
    the support from a plane fit (a depth camera, an AR framework's plane anchor, or features on
    the desk around the objects); with boxes alone an object's depth along the viewing ray is
    tied to its size, and the support fixes both. Smooth everywhere (NaN-safe norm), finite for
    degenerate radii.

    Args:
      rotation: (..., 3, 3) object-to-world; center: (..., 3); radii: (..., 3).
      up: (3,) or (..., 3) unit vector in the world. height: the support's height along ``up``
        (metres, world). sigma: metres.

    Returns:
      (..., 1) whitened residual.
    """
    rotation = jnp.asarray(rotation)
    dtype = rotation.dtype
    up = jnp.asarray(up, dtype)
    reach = half_extent(rotation, jnp.asarray(radii, dtype), up)
    bottom = jnp.sum(jnp.asarray(center, dtype) * up, axis=-1) - reach
    return safe_div(bottom - jnp.asarray(height, dtype), jnp.asarray(sigma, dtype))[..., None]


def single_view_init(
    camera_T_world,
    box,
    K,
    mean_radii,
    texture_depth=None,
    texture_mask=None,
    default_depth: ArrayLike = 10.0,
    *,
    depth_from_box: bool = True,
    image_size=None,
    border_margin: ArrayLike = 10.0,
    silhouette_scale: ArrayLike = 1.0,
):
    """Single-image initialisation (section 4.3.5).

    The centre lies on the ray through the box centre. Where ``texture_mask`` is True, at the
    depth that makes the predicted texture plane equal the measured one: ``texture_depth +
    half-extent of the class-mean ellipsoid along the optical axis``. Elsewhere, with
    ``depth_from_box`` (the default), at the depth where the class-mean ellipsoid appears as
    large as the box (:func:`jaxsem.quadrics.depth_from_box_size`; box sides cut by the image
    border, within ``border_margin`` pixels of ``image_size``, are left out), so the start
    follows the scene's scale; at ``default_depth`` (metres, camera z) where no side constrains
    or ``depth_from_box`` is False (QuadricSLAM's fixed-depth start). Orientation is the
    identity (object axes = world axes); radii are the class mean. With ``silhouette_scale`` the
    box is the outline of the ellipsoid that many times the class mean
    (``SolverConfig.silhouette_scale``): that ellipsoid is placed, the class mean returned.

    Args:
      camera_T_world: (..., 4, 4); box: (..., 4); K: (..., 3, 3); mean_radii: (..., 3).
      texture_depth: optional (...) metres; texture_mask: optional (...) bool.
      default_depth: metres. depth_from_box: static bool.
      image_size: optional (..., 2) ``[width, height]`` (without it every edge constrains).

    Returns:
      rotation (..., 3, 3), center (..., 3), radii (..., 3).
    """
    box = jnp.asarray(box)
    dtype = jnp.result_type(box, camera_T_world, K, float)
    K = jnp.asarray(K, dtype)
    pose = jnp.asarray(camera_T_world, dtype)
    extent_radii = jnp.asarray(mean_radii, dtype)
    mean_radii = extent_radii * jnp.asarray(silhouette_scale, dtype)  # the outline's ellipsoid
    R_cw = pose[..., :3, :3]
    half_depth = safe_sqrt(jnp.sum(jnp.square(mean_radii * R_cw[..., 2, :]), axis=-1))
    depth = jnp.broadcast_to(jnp.asarray(default_depth, dtype), box.shape[:-1])
    if depth_from_box:
        edges = None if image_size is None else edge_mask(box, image_size, border_margin)
        size_depth, ok = depth_from_box_size(box.astype(dtype), K, pose, mean_radii, edge_mask=edges)
        depth = jnp.where(ok, size_depth, depth)
    if texture_depth is not None:
        tex = jnp.asarray(texture_depth, dtype)
        mask = jnp.ones(tex.shape, bool) if texture_mask is None else jnp.asarray(texture_mask)
        depth = jnp.where(mask & (tex > 0), tex + half_depth, depth)
    R, c, _ = single_view_ellipsoid(box.astype(dtype), K, pose, depth, mean_radii)
    return R, c, jnp.broadcast_to(extent_radii, c.shape)

"""Points and poses: rigid transforms, pinhole projection and back-projection (eq. 4.9), single-view
initialisation (section 4.3.5), cuboid corners and stereo rigs.

Re-exported by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from .._checks import (
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
    check_positive as _check_positive,
    check_rotation as _check_rotation,
    is_concrete as _is_concrete,
)
from ._common import (
    _camera_args,
    _eps,
    _finite,
    _finite_or_zero,
    _intrinsics_ok,
    _matvec,
    _namespace,
    _pose_ok,
    _radii_ok,
    _rotation_ok,
    _safe_norm,
)

# --------------------------------------------------------------------------------------------
# Points, poses and pinhole projection.


def rigid_transform(rotation, translation, *, xp: Any = jnp):
    """The (..., 4, 4) transform ``[[R, t], [0, 1]]`` of rotations (..., 3, 3) and translations (..., 3).

    E.g. an object's pose in the camera (``camera_T_object``) from its rotation and centre.
    ``rotation`` must be a proper rotation (checked when concrete).
    """
    xp = _namespace(xp)
    R = _as_float_array("rotation", rotation, (3, 3), check_finite=True, xp=xp)
    t = _as_float_array("translation", translation, (3,), check_finite=True, xp=xp)
    _check_rotation("rotation", R)
    batch = _batch_shape(rotation=R.shape[:-2], translation=t.shape[:-1])
    dtype = xp.result_type(R.dtype, t.dtype)
    R, t = xp.broadcast_to(R.astype(dtype), batch + (3, 3)), xp.broadcast_to(t.astype(dtype), batch + (3,))
    top = xp.concatenate([R, t[..., None]], -1)
    bottom = xp.broadcast_to(xp.array([0.0, 0.0, 0.0, 1.0], dtype), batch + (4,))
    return xp.concatenate([top, bottom[..., None, :]], -2)


def fit_rigid_transform(points_from, points_to, weights=None, *, xp: Any = jnp):
    """The rigid transform (4, 4) that best maps ``points_from`` (N, 3) onto ``points_to`` (N, 3)
    in the weighted least-squares sense (Kabsch / Umeyama without scale): ``T`` minimising
    ``sum_i w_i |R p_i + t - q_i|^2``, with ``det R = +1``.

    E.g. a camera pose ``camera_T_world`` from object points known in the world and seen in the
    camera. ``weights``: optional (N,) non-negative (default all 1); at least three points of
    positive weight not on one line are needed for a unique answer (fewer give a finite, not
    unique, transform). Leading batch axes broadcast; NaN-free for finite input (the SVD's
    gradient is not defined at repeated singular values, as for any such fit).
    """
    xp = _namespace(xp)
    P = _as_float_array("points_from", points_from, (3,), check_finite=True, xp=xp)
    Q = _as_float_array("points_to", points_to, (3,), check_finite=True, xp=xp)
    if P.ndim < 2 or Q.ndim < 2:
        raise ValueError(f"points_from, points_to: expected (..., N, 3), got {P.shape} and {Q.shape}")
    dtype = xp.result_type(P.dtype, Q.dtype)
    P, Q = P.astype(dtype), Q.astype(dtype)
    if weights is None:
        w = xp.ones(P.shape[:-1], dtype)
    else:
        w = _as_float_array("weights", weights, (), check_finite=True, xp=xp).astype(dtype)
        if _is_concrete(w) and bool(np.any(np.asarray(w) < 0)):
            raise ValueError("weights: must be non-negative")
    total = xp.maximum(xp.sum(w, axis=-1, keepdims=True), _eps(dtype))
    mp = xp.sum(w[..., None] * P, axis=-2) / total
    mq = xp.sum(w[..., None] * Q, axis=-2) / total
    H = xp.matmul(xp.swapaxes((P - mp[..., None, :]) * w[..., None], -1, -2), Q - mq[..., None, :])
    U, _, Vt = xp.linalg.svd(H)
    d = xp.sign(xp.linalg.det(xp.matmul(U, Vt)))
    d = xp.where(d == 0, 1.0, d)
    ones = xp.ones(d.shape, dtype)
    D = xp.stack([ones, ones, d.astype(dtype)], -1)
    R = xp.matmul(xp.swapaxes(Vt, -1, -2) * D[..., None, :], xp.swapaxes(U, -1, -2))
    t = mq - _matvec(R, mp)
    top = xp.concatenate([R, t[..., None]], -1)
    bottom = xp.broadcast_to(xp.array([0.0, 0.0, 0.0, 1.0], dtype), R.shape[:-2] + (4,))
    return xp.concatenate([top, bottom[..., None, :]], -2)


def transform_points(T, points, *, xp: Any = jnp):
    """Apply rigid transforms ``T`` (..., 4, 4) to points (..., 3): ``T[:3, :3] p + T[:3, 3]``."""
    xp = _namespace(xp)
    T = _as_float_array("T", T, (4, 4), check_finite=True, xp=xp)
    points = _as_float_array("points", points, (3,), check_finite=True, xp=xp)
    _batch_shape(T=T.shape[:-2], points=points.shape[:-1])
    dtype = xp.result_type(T.dtype, points.dtype)
    T, points = T.astype(dtype), points.astype(dtype)
    return _matvec(T[..., :3, :3], points) + T[..., :3, 3]


def invert_pose(T, *, xp: Any = jnp):
    """Inverse (..., 4, 4) of rigid transforms ``T`` (..., 4, 4): ``[[R^T, -R^T t], [0, 1]]``.

    Exact for rigid transforms (the same as ``jaxlie.SE3.from_matrix(T).inverse().as_matrix()``
    without the round trip through a quaternion)."""
    xp = _namespace(xp)
    T = _as_float_array("T", T, (4, 4), check_finite=True, xp=xp)
    Rt = xp.swapaxes(T[..., :3, :3], -1, -2)
    t = -_matvec(Rt, T[..., :3, 3])
    top = xp.concatenate([Rt, t[..., None]], -1)
    bottom = xp.broadcast_to(xp.array([0.0, 0.0, 0.0, 1.0], T.dtype), T.shape[:-2] + (4,))
    return xp.concatenate([top, bottom[..., None, :]], -2)


def project_points(
    points, K, camera_T_world, *, with_valid: bool = False, xp: Any = jnp
) -> Any:  # a tuple with with_valid=True
    """Pinhole projection of world points: ``uv = (K p_cam)[:2] / z``, with ``p_cam = camera_T_world p``.

    Args:
      points: (..., 3) world points.
      K: (..., 3, 3) intrinsics; camera_T_world: (..., 4, 4) (OpenCV axes).

    Returns:
      uv: (..., 2) pixels, finite everywhere (a point at or behind the principal plane is
        divided by a clamped depth, so its ``uv`` is meaningless: check ``depth``).
      depth: (...) camera z in metres; a point is in front of the camera iff ``depth > 0``.
      valid: (...) bool, only with ``with_valid=True``: the point is finite and in front of the
        camera (``depth`` above the clamp, ``8 eps``), ``K`` finite with ``fx, fy > 0`` and ``camera_T_world`` rigid;
        what the eager checks refuse reads False under ``jit`` (then ``uv`` and ``depth`` are
        finite too: non-finite entries are read as 0).
    """
    xp = _namespace(xp)
    points = _as_float_array("points", points, (3,), check_finite=True, xp=xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(points=points.shape[:-1], K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    dtype = xp.result_type(points.dtype, K.dtype, pose.dtype)
    points, K, pose = points.astype(dtype), K.astype(dtype), pose.astype(dtype)
    ok = None
    if with_valid:
        ok = _finite(points, 1, xp) & _intrinsics_ok(K, xp) & _pose_ok(pose, xp)
        points, K, pose = (_finite_or_zero(x, xp) for x in (points, K, pose))
    p = _matvec(pose[..., :3, :3], points) + pose[..., :3, 3]
    pix = _matvec(K, p)
    z = p[..., 2]
    z_safe = xp.where(xp.abs(z) > _eps(dtype), z, _eps(dtype))
    uv = pix[..., :2] / z_safe[..., None]
    if ok is not None:
        return uv, z, ok & (z > _eps(dtype))
    return uv, z


def back_project(uv, depth, K, camera_T_world, *, with_valid: bool = False, xp: Any = jnp) -> Any:
    """World points (..., 3) at camera depth ``depth`` (z, not range) on the rays through pixels ``uv``.

    The inverse of :func:`project_points`: ``project_points(back_project(uv, z, K, T), K, T)``
    gives back ``(uv, z)``.

    Args:
      uv: (..., 2) pixels; depth: (...) metres along the optical axis.
      K: (..., 3, 3) intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``; camera_T_world: (..., 4, 4).
      with_valid: also return a (...) bool mask, False (under ``jit``: concrete arguments are
        checked eagerly) for non-finite ``uv`` or ``depth`` and for intrinsics or a pose
        :func:`camera_valid` refuses; the formula reads only ``K``'s top rows, so without the
        mask a wrong bottom row gives finite points that look right.
    """
    xp = _namespace(xp)
    uv = _as_float_array("uv", uv, (2,), check_finite=True, xp=xp)
    # A Python number (``1.0``: unit-depth rays) takes the other arguments' dtype (a weak type).
    scalar_depth = isinstance(depth, (int, float)) and not isinstance(depth, bool)
    depth = xp.asarray(depth)
    if _is_concrete(depth) and not bool(np.all(np.isfinite(np.asarray(depth)))):
        raise ValueError("depth: must be finite, got non-finite values (NaN or inf)")
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(uv=uv.shape[:-1], depth=depth.shape, K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    dtypes = (uv.dtype, K.dtype, pose.dtype) if scalar_depth else (uv.dtype, depth.dtype, K.dtype, pose.dtype)
    dtype = xp.result_type(*dtypes, float)
    uv, depth, K, pose = uv.astype(dtype), depth.astype(dtype), K.astype(dtype), pose.astype(dtype)
    valid = None
    if with_valid:  # the mask, and finite stand-ins where it is False (values and gradients)
        ok_k, ok_pose = _intrinsics_ok(K, xp), _pose_ok(pose, xp)
        valid = _finite(uv, 1, xp) & xp.isfinite(depth) & ok_k & ok_pose
        uv, depth = _finite_or_zero(uv, xp), _finite_or_zero(depth, xp)
        K = xp.where(ok_k[..., None, None], K, xp.eye(3, dtype=dtype))
        pose = xp.where(ok_pose[..., None, None], pose, xp.eye(4, dtype=dtype))
    fx, s, cx = K[..., 0, 0], K[..., 0, 1], K[..., 0, 2]
    fy, cy = K[..., 1, 1], K[..., 1, 2]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    p_cam = xp.stack([x * depth, y * depth, xp.broadcast_to(depth, x.shape)], -1)
    # world p = R^T (p_cam - t)
    R = pose[..., :3, :3]
    points = _matvec(xp.swapaxes(R, -1, -2), p_cam - pose[..., :3, 3])
    if valid is None:
        return points
    return points, xp.broadcast_to(valid, points.shape[:-1])


def single_view_ellipsoid(box, K, camera_T_world, depth, radii, *, with_valid: bool = False) -> Any:
    """Single-view initialisation of an ellipsoid from one box (thesis section 4.3.5).

    The centre lies on the ray through the box centre at camera depth ``depth`` (z, not range),
    the rotation is the identity (object axes = world axes) and the radii are ``radii``.
    ROSHAN's :func:`jaxsem.factors.single_view_init` chooses the depth (texture plane or default)
    and calls this.

    Args:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]``; K: (..., 3, 3); camera_T_world: (..., 4, 4);
      depth: (...) metres; radii: (..., 3) semi-axes.

      with_valid: also return a (...) bool mask (below).

    Returns:
      rotation (..., 3, 3), center (..., 3), radii (..., 3), broadcast to one batch shape; with
      ``with_valid=True`` also ``valid`` (...) bool, False where an input is one the eager checks
      refuse or :func:`back_project`'s mask does (a non-finite box or depth, radii not positive,
      intrinsics or a pose :func:`camera_valid` refuses) or the depth is not positive (no
      ellipsoid in front of the camera). Concrete bad input raises ``ValueError`` naming the
      argument; under ``jit`` the outputs are then finite stand-ins that mean nothing.
    """
    box = _as_float_array("box", box, (4,), check_finite=True)
    radii = _as_float_array("radii", radii, (3,), check_finite=True)
    _check_positive("radii", radii)
    uv = 0.5 * (box[..., :2] + box[..., 2:])
    valid = None
    if not with_valid:
        center = back_project(uv, depth, K, camera_T_world)
    else:
        center, valid = back_project(uv, depth, K, camera_T_world, with_valid=True)
        valid = valid & (jnp.asarray(depth) > 0) & _radii_ok(radii)
        radii = _finite_or_zero(radii)
    batch = _batch_shape(center=center.shape[:-1], radii=radii.shape[:-1])
    center = jnp.broadcast_to(center, batch + (3,))
    rotation = jnp.broadcast_to(jnp.eye(3, dtype=center.dtype), batch + (3, 3))
    radii = jnp.broadcast_to(radii.astype(center.dtype), batch + (3,))
    if valid is None:
        return rotation, center, radii
    return rotation, center, radii, jnp.broadcast_to(valid, batch)


def relative_pose(camera_T_world_a, camera_T_world_b, *, xp: Any = jnp):
    """The pose of camera ``b`` in camera ``a``'s frame, ``a_T_b = camera_T_world_a @ world_T_camera_b``
    (..., 4, 4): what an odometry measures between two frames, and the mean of
    :func:`jaxsem.factors.between_residual`. ``camera_T_world_b = invert_pose(a_T_b) @ camera_T_world_a``."""
    xp = _namespace(xp)
    a = _as_float_array("camera_T_world_a", camera_T_world_a, (4, 4), check_finite=True, xp=xp)
    b = _as_float_array("camera_T_world_b", camera_T_world_b, (4, 4), check_finite=True, xp=xp)
    dtype = xp.result_type(a.dtype, b.dtype)
    return a.astype(dtype) @ invert_pose(b.astype(dtype), xp=xp)


def depth_from_box_size(box, K, camera_T_world, radii, rotation=None, edge_mask=None):
    """Camera depth (z) at which an ellipsoid of known size appears as large as a measured box.

    An object of size ``2 h`` whose box spans the angle ``a`` is at range ``h / sin(a / 2)``
    (about ``f * 2 h / box size`` in pixels): the depth a single-view initialisation needs when
    there is no depth measurement, so that a tabletop object starts near 0.8 m and a car in a
    street near 15 m. ``h`` is the half-extent of the ellipsoid (oriented by ``rotation``,
    default the identity: object axes = world axes, as :func:`single_view_ellipsoid` places
    it) along the camera's x (for the box width) and y (for its height); the two are combined
    by least squares in inverse range over the box sides whose two edges both constrain
    (``edge_mask``: a side cut by the image border only gives an upper bound and is left out).
    The range along the ray through the box centre is returned as camera z.

    Args:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]``; K: (..., 3, 3); camera_T_world: (..., 4, 4).
      radii: (..., 3) semi-axes; rotation: optional (..., 3, 3) object-to-world.
      edge_mask: optional (..., 4) bool, which edges constrain (default all).

    Returns:
      ``(depth (...), ok (...))``: depth in metres, at least 1.01 times the largest semi-axis
      beyond the camera (the camera outside the object); ``ok`` False where no side of the box
      constrains, or (under ``jit``) where an input is bad: a non-finite box, radii not positive,
      intrinsics or a pose :func:`camera_valid` refuses, a ``rotation`` that is not a proper one
      (then ``depth`` is a finite placeholder: use a default). Concrete bad input raises
      ``ValueError`` naming the argument. Jittable, finite gradients.
    """
    box = _as_float_array("box", box, (4,))
    radii = _as_float_array("radii", radii, (3,), check_finite=True)
    _check_positive("radii", radii)
    K, pose = _camera_args(K, camera_T_world)
    dtype = jnp.result_type(box.dtype, radii.dtype, K.dtype, pose.dtype, float)
    box, radii, K, pose = box.astype(dtype), radii.astype(dtype), K.astype(dtype), pose.astype(dtype)
    # Bad inputs (possible only under jit) read ok False, computed on finite stand-ins.
    inputs_ok = [_finite(box, 1), _radii_ok(radii), _intrinsics_ok(K), _pose_ok(pose)]
    box = jnp.where(inputs_ok[0][..., None], box, jnp.asarray([0.0, 0.0, 1.0, 1.0], dtype))
    radii = jnp.where(inputs_ok[1][..., None], radii, jnp.ones((), dtype))
    K = jnp.where(inputs_ok[2][..., None, None], K, jnp.eye(3, dtype=dtype))
    pose = jnp.where(inputs_ok[3][..., None, None], pose, jnp.eye(4, dtype=dtype))
    R = pose[..., :3, :3]
    if rotation is not None:
        rotation = _as_float_array("rotation", rotation, (3, 3), check_finite=True).astype(dtype)
        _check_rotation("rotation", rotation)
        rotation_ok = _rotation_ok(rotation)  # under jit: a scaled rotation scales the half-extents
        inputs_ok.append(rotation_ok)
        R = R @ jnp.where(rotation_ok[..., None, None], rotation, jnp.eye(3, dtype=dtype))
    # Half-extent of the ellipsoid along camera axis i: sqrt(sum_k (R_co[i, k] r_k)^2).
    half = _safe_norm(R * radii[..., None, :], jnp, axis=-1)  # (..., 3)
    fx, s, cx = K[..., 0, 0], K[..., 0, 1], K[..., 0, 2]
    fy, cy = K[..., 1, 1], K[..., 1, 2]
    y0, y1 = (box[..., 1] - cy) / fy, (box[..., 3] - cy) / fy
    yc = 0.5 * (y0 + y1)
    x0, x1 = (box[..., 0] - cx - s * yc) / fx, (box[..., 2] - cx - s * yc) / fx
    sin_u = jnp.sin(0.5 * jnp.clip(jnp.arctan(x1) - jnp.arctan(x0), 0.0, jnp.pi))
    sin_v = jnp.sin(0.5 * jnp.clip(jnp.arctan(y1) - jnp.arctan(y0), 0.0, jnp.pi))
    if edge_mask is None:
        wu = wv = jnp.ones(box.shape[:-1], dtype)
    else:
        edge_mask = jnp.asarray(edge_mask, bool)
        wu = (edge_mask[..., 0] & edge_mask[..., 2]).astype(dtype)
        wv = (edge_mask[..., 1] & edge_mask[..., 3]).astype(dtype)
    hx, hy = half[..., 0], half[..., 1]
    # Least squares of sin(a / 2) = h / range over the constraining sides, in 1 / range.
    num = wu * sin_u * hx + wv * sin_v * hy
    den = wu * hx * hx + wv * hy * hy
    ok = (den > 0) & (num > 0)
    for input_ok in inputs_ok:
        ok = ok & input_ok
    inv_range = jnp.where(ok, num / jnp.where(ok, den, 1.0), 1.0)
    rng = 1.0 / inv_range
    rng = jnp.maximum(rng, 1.01 * jnp.max(radii, axis=-1))
    # Camera z of the point at that range on the ray through the box centre.
    ray_z = 1.0 / _safe_norm(jnp.stack([0.5 * (x0 + x1), yc, jnp.ones_like(yc)], -1), jnp, axis=-1)
    return rng * ray_z, ok


# Corner order of NVIDIA's NDDS exporter, used by the Falling Things dataset (FAT) and DOPE:
# FrontTopRight, FrontTopLeft, FrontBottomLeft, FrontBottomRight, then the same four at the rear,
# in the cuboid frame x right, y down, z out of the front. Rows are the signs of (x, y, z).
CUBOID_CORNER_SIGNS = np.array(
    [
        [1, -1, 1],
        [-1, -1, 1],
        [-1, 1, 1],
        [1, 1, 1],
        [1, -1, -1],
        [-1, -1, -1],
        [-1, 1, -1],
        [1, 1, -1],
    ],
    dtype=np.float64,
)


def cuboid_corners(rotation, center, half_extents, *, xp: Any = jnp):
    """The 8 corners (..., 8, 3) of an oriented box, in :data:`CUBOID_CORNER_SIGNS` order (NDDS / FAT).

    Corner ``k`` is ``center + rotation @ (CUBOID_CORNER_SIGNS[k] * half_extents)``: the box's own
    axes are the columns of ``rotation`` (any right- or left-handed frame the caller chooses, e.g.
    FAT's x right, y down, z out of the front).

    Args:
      rotation: (..., 3, 3); center: (..., 3); half_extents: (..., 3) (an ellipsoid's radii give
        its bounding box).
    """
    xp = _namespace(xp)
    rotation = _as_float_array("rotation", rotation, (3, 3), check_finite=True, xp=xp)
    center = _as_float_array("center", center, (3,), check_finite=True, xp=xp)
    half = _as_float_array("half_extents", half_extents, (3,), check_finite=True, xp=xp)
    if _is_concrete(half) and bool(np.any(np.asarray(half) < 0)):
        raise ValueError("half_extents: expected non-negative values, got a negative one")
    _batch_shape(rotation=rotation.shape[:-2], center=center.shape[:-1], half_extents=half.shape[:-1])
    dtype = xp.result_type(rotation.dtype, center.dtype, half.dtype)
    local = xp.asarray(CUBOID_CORNER_SIGNS, dtype) * half.astype(dtype)[..., None, :]
    return _matvec(rotation.astype(dtype)[..., None, :, :], local) + center.astype(dtype)[..., None, :]


# --------------------------------------------------------------------------------------------
# Stereo rigs (VoluMon's rectified pairs).


def stereo_right_T_left(baseline, dtype=None):
    """``right_T_left`` (..., 4, 4) of a rectified stereo pair of ``baseline`` (...) metres: the right
    camera sits ``baseline`` along the left camera's +x, so a left-frame point ``p`` is
    ``p - [b, 0, 0]`` in the right frame.

    dtype: the result's; None (default): a floating array's own dtype (a float64 baseline is not
    rounded to float32, which strict dtype promotion would then refuse to mix with the float64
    geometry it came with), float32 for Python numbers and integer arrays."""
    if dtype is None:
        floating = isinstance(baseline, (np.ndarray, np.generic, jnp.ndarray)) and jnp.issubdtype(
            baseline.dtype, jnp.floating
        )
        dtype = baseline.dtype if floating else jnp.float32
    b = jnp.asarray(baseline, dtype)
    T = jnp.broadcast_to(jnp.eye(4, dtype=dtype), b.shape + (4, 4))
    return T.at[..., 0, 3].set(-b)

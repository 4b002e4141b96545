"""Rotations: quaternion conversions (the convention is in the name), random rotations,
:func:`look_at` and :func:`so3_exp`.

Re-exported by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from .._checks import (
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
    check_rotation as _check_rotation,
    is_concrete as _is_concrete,
)
from ._common import (
    _cross,
    _eager_compiled,
    _eps,
    _finite,
    _finite_or_zero,
    _matvec,
    _namespace,
    _rotation_ok,
    _safe_norm,
    _safe_sqrt,
    safe_div,
)

# --------------------------------------------------------------------------------------------
# Rotations.


def quaternion_wxyz_to_rotation(quaternion_wxyz, *, with_valid: bool = False, xp: Any = jnp) -> Any:
    """(..., 4) quaternion ``[w, x, y, z]`` (scalar first, jaxlie's order) -> (..., 3, 3) rotation.

    The quaternion is normalised here; a zero quaternion maps to the identity (a documented
    convention, e.g. for a network head before training). A non-finite concrete quaternion raises
    ``ValueError``; under ``jit`` a NaN propagates to the result (never a finite-looking matrix).
    ``with_valid=True`` returns ``(rotation, valid)``, ``valid`` (...) bool False for a
    quaternion with no direction (zero, or a squared norm below the dtype's smallest normal
    number) or a non-finite one; its rotation is then the identity (finite, and meaning nothing).
    """
    xp = _namespace(xp)
    q = _as_float_array("quaternion_wxyz", quaternion_wxyz, (4,), check_finite=True, xp=xp)
    if with_valid:
        return _quaternion_masked(q, 0, xp)
    return _quaternion_wxyz_to_rotation_compiled(q, xp)


def quaternion_xyzw_to_rotation(quaternion_xyzw, *, with_valid: bool = False, xp: Any = jnp) -> Any:
    """(..., 4) quaternion ``[x, y, z, w]`` (scalar last: ROS, scipy, FAT's ``quaternion_xyzw``)
    -> (..., 3, 3) rotation. Same rules and ``with_valid`` as :func:`quaternion_wxyz_to_rotation`."""
    xp = _namespace(xp)
    q = _as_float_array("quaternion_xyzw", quaternion_xyzw, (4,), check_finite=True, xp=xp)
    if with_valid:
        return _quaternion_masked(q, 3, xp)
    return _quaternion_xyzw_to_rotation_compiled(q, xp)


def _quaternion_masked(q, scalar_index, xp):
    """``(rotation, valid)`` of a quaternion whose scalar part is at ``scalar_index`` (0 or 3):
    where ``valid`` is False the rotation is the identity, finite in value and gradient (the
    quaternion is replaced before the arithmetic, not after)."""
    valid = _quaternion_ok(q, xp)
    identity = xp.asarray([1.0, 0.0, 0.0, 0.0] if scalar_index == 0 else [0.0, 0.0, 0.0, 1.0], q.dtype)
    q = xp.where(valid[..., None], q, identity)
    if scalar_index == 3:
        q = xp.roll(q, 1, axis=-1)
    return _quaternion_wxyz_to_rotation(q, xp), valid


def _quaternion_ok(q, xp):
    """(...) bool: finite, with a squared norm above the dtype's smallest normal number."""
    squared = q[..., 0] ** 2 + q[..., 1] ** 2 + q[..., 2] ** 2 + q[..., 3] ** 2
    return _finite(q, 1, xp) & (squared > float(np.finfo(q.dtype).tiny))


def _quaternion_wxyz_to_rotation(q, xp: Any = jnp):
    norm = _safe_norm(q, xp, axis=-1, keepdims=True)
    identity = xp.array([1.0, 0.0, 0.0, 0.0], q.dtype)
    # `norm > 0` is False for NaN too: keep NaN (honest) instead of mapping it to the identity.
    keep = (norm > 0) | xp.isnan(norm)
    q = xp.where(keep, q / xp.where(keep, norm, 1.0), identity)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.stack(
        [
            xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            xp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


_quaternion_wxyz_to_rotation_compiled = _eager_compiled(_quaternion_wxyz_to_rotation, static_argnums=(1,))
_quaternion_xyzw_to_rotation_compiled = _eager_compiled(
    lambda q, xp: _quaternion_wxyz_to_rotation(xp.roll(q, 1, axis=-1), xp), static_argnums=(1,)
)


def rotation_to_quaternion_wxyz(
    rotation, *, with_valid: bool = False, xp: Any = jnp
) -> Any:  # a tuple with with_valid=True
    """(..., 3, 3) rotation -> (..., 4) unit quaternion ``[w, x, y, z]`` (scalar first) with ``w >= 0``.

    Shepperd's method: of the four algebraically equal formulas the one with the largest
    square-root argument is taken, so no branch divides by a small number.

    A concrete ``rotation`` that is not a finite proper rotation (``R^T R = I`` to 1e-3,
    ``det R > 0``) raises ``ValueError``. ``with_valid=True`` adds a (...) bool mask that says
    the same under ``jit``, where the quaternion of a non-rotation is a finite unit quaternion
    that means nothing.
    """
    xp = _namespace(xp)
    R = _as_float_array("rotation", rotation, (3, 3), check_finite=True, xp=xp)
    _check_rotation("rotation", R)
    if not with_valid:
        return _rotation_to_quaternion_compiled(R, xp)
    return _rotation_to_quaternion_masked(R, xp)


def _rotation_to_quaternion_masked_plain(R, xp):
    return _rotation_to_quaternion_wxyz(_finite_or_zero(R, xp), xp), _rotation_ok(R, xp)


def _rotation_to_quaternion_wxyz(R, xp):
    r00, r11, r22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    trace = r00 + r11 + r22
    cands = []
    s = 2 * _safe_sqrt(1 + trace, xp)
    cands.append(
        (
            s,
            xp.stack(
                [s / 4, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1
            ),
            1 + trace,
        )
    )
    s = 2 * _safe_sqrt(1 + r00 - r11 - r22, xp)
    cands.append(
        (
            s,
            xp.stack(
                [R[..., 2, 1] - R[..., 1, 2], s / 4, R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0]], -1
            ),
            1 + r00 - r11 - r22,
        )
    )
    s = 2 * _safe_sqrt(1 - r00 + r11 - r22, xp)
    cands.append(
        (
            s,
            xp.stack(
                [R[..., 0, 2] - R[..., 2, 0], R[..., 0, 1] + R[..., 1, 0], s / 4, R[..., 1, 2] + R[..., 2, 1]], -1
            ),
            1 - r00 + r11 - r22,
        )
    )
    s = 2 * _safe_sqrt(1 - r00 - r11 + r22, xp)
    cands.append(
        (
            s,
            xp.stack(
                [R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1], s / 4], -1
            ),
            1 - r00 - r11 + r22,
        )
    )
    args = xp.stack([c[2] for c in cands], -1)
    best = xp.argmax(args, axis=-1)
    qs = []
    for i, (s_i, q_i, _) in enumerate(cands):
        s_safe = xp.where(best == i, s_i, 1.0)[..., None]
        # The s/4 entry was written unscaled; the others are divided by s.
        scale = (xp.arange(4) != i).astype(R.dtype)
        qs.append(q_i * (scale / s_safe + (1 - scale)))
    q = xp.take_along_axis(xp.stack(qs, -2), best[..., None, None], axis=-2)[..., 0, :]
    q = q * xp.where(q[..., :1] < 0, -1.0, 1.0)
    return q / xp.maximum(_safe_norm(q, xp, axis=-1, keepdims=True), xp.finfo(q.dtype).tiny)


_rotation_to_quaternion_compiled = _eager_compiled(_rotation_to_quaternion_wxyz, static_argnums=(1,))
_rotation_to_quaternion_masked = _eager_compiled(_rotation_to_quaternion_masked_plain, static_argnums=(1,))


# How far (entrywise) nearest_rotation's input may be from its result and still count as a
# rotation written with few digits rather than a wrong matrix.
_NEAREST_TOL = 0.1


def nearest_rotation(matrix, *, with_valid: bool = False, xp: Any = jnp) -> Any:
    """The proper rotation (..., 3, 3) nearest to ``matrix`` (..., 3, 3) in the Frobenius norm.

    For rotations read from files, written with a few digits (a BOP ``cam_R_m2c`` is a few
    thousandths from orthonormal, more than the core's rotation checks allow): the polar factor
    ``U diag(1, 1, det(U V^T)) V^T`` of the SVD ``matrix = U S V^T``. A rotation is returned
    unchanged (to rounding). A non-finite concrete ``matrix`` raises ``ValueError``.

    A matrix far from any rotation (singular, a reflection, a scaled one) is still projected,
    which hides the mistake: ``with_valid=True`` returns ``(rotation, valid)``, ``valid`` (...)
    bool saying ``matrix`` was within the core's rotation tolerance of the result
    (``|matrix - R| <= 1e-1`` entrywise) and had ``det > 0``. The result's gradient is not defined
    at repeated singular values, as for any SVD.
    """
    xp = _namespace(xp)
    M = _as_float_array("matrix", matrix, (3, 3), check_finite=True, xp=xp)
    return _nearest_rotation_compiled(M, with_valid, xp)


def _nearest_rotation(M, with_valid, xp):
    finite = _finite(M, 2, xp)
    M = _finite_or_zero(M, xp)
    U, _, Vt = xp.linalg.svd(M)
    d = xp.where(xp.linalg.det(xp.matmul(U, Vt)) < 0, -1.0, 1.0).astype(M.dtype)
    ones = xp.ones(d.shape, M.dtype)
    R = xp.matmul(U * xp.stack([ones, ones, d], -1)[..., None, :], Vt)
    if not with_valid:
        return R
    det = xp.linalg.det(M)
    close = xp.max(xp.abs(M - R), axis=(-2, -1)) <= _NEAREST_TOL
    return R, finite & close & (det > 0)


_nearest_rotation_compiled = _eager_compiled(_nearest_rotation, static_argnums=(1, 2))


def random_rotation(key, shape: tuple = (), dtype=None):
    """Uniformly random rotations (..., 3, 3) from normalised Gaussian quaternions."""
    dtype = dtype or jnp.result_type(float)
    q = jax.random.normal(key, tuple(shape) + (4,), dtype=dtype)
    return _quaternion_wxyz_to_rotation(q)


def look_at(
    eye, target, up=(0.0, 0.0, 1.0), *, with_valid: bool = False, xp: Any = jnp
) -> Any:  # a tuple with with_valid=True
    """``camera_T_world`` (..., 4, 4) of an OpenCV camera at ``eye`` looking at ``target``.

    The camera's z axis points at the target, its y axis down (against ``up``). When the view
    direction is parallel to ``up`` another up vector is used, so the result is always a rotation.

    Concrete arguments are checked: finite, ``target`` distinct from ``eye`` (a view direction
    whose squared length is above the dtype's smallest normal number), ``up`` non-zero; each
    failure is a ``ValueError`` naming the argument. ``with_valid=True`` returns
    ``(camera_T_world, valid)``, with ``valid`` (...) bool saying the same under ``jit``; where
    it is False the pose is the camera at the origin (``eye`` where finite) looking along the
    world +x axis, a finite rigid transform that means nothing. Without ``with_valid``, a traced
    ``eye == target`` gives a pose whose rotation block is zero: finite, clearly no rigid
    transform, and refused by every mask downstream (:func:`camera_valid`, :func:`project_bbox`).
    """
    xp = _namespace(xp)
    eye = _as_float_array("eye", eye, (3,), xp=xp)
    target = _as_float_array("target", target, (3,), xp=xp)
    if not hasattr(up, "dtype"):  # a Python sequence (the default): the dtype of eye and target
        up = xp.asarray(up, xp.result_type(eye.dtype, target.dtype))
    up = _as_float_array("up", up, (3,), xp=xp)
    dtype = xp.result_type(eye.dtype, target.dtype, up.dtype)
    eye, target, up = eye.astype(dtype), target.astype(dtype), up.astype(dtype)
    batch = _batch_shape(eye=eye.shape[:-1], target=target.shape[:-1], up=up.shape[:-1])
    for name, x in (("eye", eye), ("target", target), ("up", up)):
        if _is_concrete(x) and not bool(np.all(np.isfinite(np.asarray(x)))):
            raise ValueError(f"{name}: must be finite, got non-finite values (NaN or inf)")
    # The view direction must be normalisable: a squared length above the smallest normal number
    # (the same tests as the kernel's mask, made here in numpy on concrete values).
    if _is_concrete(eye) and _is_concrete(target):
        forward = np.asarray(target) - np.asarray(eye)
        if not bool(np.all(np.sum(np.square(forward), axis=-1) > float(np.finfo(dtype).tiny))):
            raise ValueError("target: must differ from eye (the view direction is undefined)")
    if _is_concrete(up) and not bool(np.all(np.sum(np.square(np.asarray(up)), axis=-1) > 0)):
        raise ValueError("up: must be a non-zero vector")
    return _look_at_compiled(eye, target, up, batch, with_valid, xp)


def _look_at(eye, target, up, batch, with_valid, xp):
    """The arithmetic of :func:`look_at` on checked arguments of one dtype."""
    dtype = eye.dtype
    forward = target - eye
    distinct = xp.sum(xp.square(forward), axis=-1) > float(np.finfo(dtype).tiny)
    up_ok = xp.sum(xp.square(up), axis=-1) > 0
    valid = distinct & up_ok & _finite(eye, 1, xp) & _finite(target, 1, xp) & _finite(up, 1, xp)
    if with_valid:  # a finite stand-in where not valid: at the eye (or origin), along +x
        eye = _finite_or_zero(eye, xp)
        forward = xp.where(valid[..., None], _finite_or_zero(forward, xp), xp.asarray([1.0, 0.0, 0.0], dtype))
        up = xp.where(valid[..., None], up, xp.asarray([0.0, 0.0, 1.0], dtype))
    norm = _safe_norm(forward, xp, keepdims=True)
    forward = forward / xp.where(norm > 0, norm, 1.0)
    right = _cross(forward, up, xp)
    alt = _cross(forward, xp.array([1.0, 0.0, 0.0], dtype), xp)
    alt = xp.where(
        _safe_norm(alt, xp, keepdims=True) > 1e-3, alt, _cross(forward, xp.array([0.0, 1.0, 0.0], dtype), xp)
    )
    right = xp.where(_safe_norm(right, xp, keepdims=True) > 1e-6, right, alt)
    right = right / xp.maximum(_safe_norm(right, xp, keepdims=True), _eps(dtype))
    down = _cross(forward, right, xp)
    world_R_cam = xp.stack([right, down, forward], axis=-1)
    cam_R_world = xp.swapaxes(world_R_cam, -1, -2)
    cam_R_world = xp.broadcast_to(cam_R_world, batch + (3, 3))
    t = -_matvec(cam_R_world, xp.broadcast_to(eye, batch + (3,)))
    top = xp.concatenate([cam_R_world, t[..., None]], -1)
    bottom = xp.broadcast_to(xp.array([0.0, 0.0, 0.0, 1.0], dtype), batch + (4,))
    pose = xp.concatenate([top, bottom[..., None, :]], -2)
    return (pose, xp.broadcast_to(valid, batch)) if with_valid else pose


_look_at_compiled = _eager_compiled(_look_at, static_argnums=(3, 4, 5))


def rotation_to_quaternion_xyzw(
    rotation, *, with_valid: bool = False, xp: Any = jnp
) -> Any:  # a tuple with with_valid=True
    """(..., 3, 3) rotation -> (..., 4) unit quaternion ``[x, y, z, w]`` (scalar last), ``w >= 0``.
    Same checks and ``with_valid`` as :func:`rotation_to_quaternion_wxyz`."""
    xp = _namespace(xp)
    if with_valid:
        q, valid = rotation_to_quaternion_wxyz(rotation, with_valid=True, xp=xp)
        return xp.roll(q, -1, axis=-1), valid
    return xp.roll(rotation_to_quaternion_wxyz(rotation, xp=xp), -1, axis=-1)


# Old names (scalar-first convention), kept so that existing code keeps working.
quaternion_to_rotation = quaternion_wxyz_to_rotation
rotation_to_quaternion = rotation_to_quaternion_wxyz


def so3_exp(omega):
    """Rotation (..., 3, 3) of the axis-angle vector ``omega`` (..., 3) (radians), through jaxlie.

    ``jaxlie.SO3.exp`` handles the small-angle case with a Taylor branch whose untaken side has
    finite gradients, so this is NaN-free at zero."""
    omega = _as_float_array("omega", omega, (3,), check_finite=True)
    return jaxlie.SO3.exp(omega).as_matrix()


# --------------------------------------------------------------------------------------------
# Small rotation helpers every method uses (moved here from ROSHAN's cost, VoluMon's network and
# the simulators, which each carried a copy).


def skew(w, xp=jnp):
    """The cross-product matrix ``[w]x`` (..., 3, 3) of ``w`` (..., 3): ``skew(w) @ v == w x v``."""
    xp = _namespace(xp)
    w = xp.asarray(w)
    z = xp.zeros_like(w[..., 0])
    return xp.stack(
        [
            xp.stack([z, -w[..., 2], w[..., 1]], -1),
            xp.stack([w[..., 2], z, -w[..., 0]], -1),
            xp.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def yaw_rotation(yaw):
    """Rotations (..., 3, 3) about the world z axis (up) by ``yaw`` (...) radians, counter-clockwise
    seen from above: objects standing on the ground, robots on the floor. (``so3_exp`` of
    ``(0, 0, yaw)``, so maps drawn with either are bit-identical.)"""
    yaw = jnp.asarray(yaw)
    if not jnp.issubdtype(yaw.dtype, jnp.floating):
        yaw = yaw.astype(jnp.result_type(float))
    zero = jnp.zeros_like(yaw)
    return so3_exp(jnp.stack([zero, zero, yaw], -1))


def ray_rotation(direction):
    """Smallest rotation (..., 3, 3) taking the optical axis ``e_z`` to ``direction`` (..., 3).

    ``R = I + [v]x + [v]x^2 / (1 + c)`` with ``v = e_z x n``, ``c = e_z . n`` (``n`` normalised).
    Finite for any direction with ``c > -1``; VoluMon's rays point forward (``c > 0``). A zero
    direction gives the identity. (The egocentric-allocentric conversion of thesis 5.2.)
    """
    n = jnp.asarray(direction)
    norm = _safe_norm(n, jnp, -1, True)
    ez = jnp.zeros_like(n).at[..., 2].set(1.0)
    n = jnp.where(norm > 0, n / jnp.where(norm > 0, norm, 1.0), ez)
    V = skew(jnp.stack([-n[..., 1], n[..., 0], jnp.zeros_like(n[..., 2])], -1))  # [e_z x n]x
    k = safe_div(1.0, 1.0 + n[..., 2])[..., None, None]
    return jnp.eye(3, dtype=n.dtype) + V + (V @ V) * k


def allocentric_rotation(rotation, center):
    """Allocentric rotation ``R_ray(center)^T R`` (..., 3, 3) of an object-to-camera ``rotation``
    seen at camera-frame ``center``: its orientation relative to the ray it is seen along, what
    VoluMon predicts (the inverse of ``ray_rotation(center) @ R_allo``)."""
    return jnp.swapaxes(ray_rotation(center), -1, -2) @ rotation

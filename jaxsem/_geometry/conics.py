"""Quadric matrices and their projection by a pinhole camera (thesis eq. 4.1-4.3, 4.9-4.12, 5.5).

The dual and primal quadric of an ellipsoid, the camera matrix, the projected dual conic, the
box and outline of a conic, the exact box of a cylinder, and the depth of an ellipsoid's
texture plane. Re-exported by :mod:`jaxsem.quadrics`, which documents the conventions.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import (
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
    check_rotation as _check_rotation,
)
from ._common import (
    _camera_args,
    _eager_compiled,
    _ellipsoid_args,
    _ellipsoid_ok,
    _eps,
    _finite,
    _finite_or_zero,
    _intrinsics_ok,
    _matmul3,
    _matvec,
    _matvec_terms,
    _namespace,
    _pose_ok,
    _rotation_ok,
    _safe_sqrt,
    safe_div,
    safe_norm,
)

# --------------------------------------------------------------------------------------------
# Quadric matrices.


def ellipsoid_valid(rotation, center, radii):
    """(...) bool mask under ``jit``: a finite proper rotation (orthonormal, det +1, to a
    dtype-aware tolerance), a finite centre and positive finite radii. The check every masked
    core function folds in; use it beside the unmasked algebra (:func:`dual_quadric`, ...)."""
    rotation, center, radii = jnp.asarray(rotation), jnp.asarray(center), jnp.asarray(radii)
    return _ellipsoid_ok_compiled(rotation, center, radii)


_ellipsoid_ok_compiled = _eager_compiled(_ellipsoid_ok)


def camera_valid(K, camera_T_world):
    """(...) bool mask under ``jit``: finite intrinsics with ``fx, fy > 0`` and a finite rigid
    ``camera_T_world`` (proper rotation block, last row ``[0, 0, 0, 1]``)."""
    return _intrinsics_ok(jnp.asarray(K)) & _pose_ok(jnp.asarray(camera_T_world))


def dual_quadric(rotation, center, radii, *, xp: Any = jnp, with_valid: bool = False) -> Any:
    """Dual quadric ``Q*`` of an ellipsoid (eq. 4.3).

    Args:
      rotation: (..., 3, 3) object-to-world rotation ``R``.
      center: (..., 3) centre ``t`` in the world.
      radii: (..., 3) semi-axes ``r`` in metres.
      xp: ``jax.numpy`` (default) or ``numpy`` (host code; see the module docstring).

    Returns:
      (..., 4, 4) ``[[R diag(r^2) R^T - t t^T, -t], [-t^T, -1]]``; with ``with_valid=True``
      also the (...) mask of :func:`ellipsoid_valid`.

    Where the ellipsoid is not valid (possible only under ``jit``: concrete arguments are checked
    eagerly) the matrix is all zeros: finite, and no ellipsoid's, so everything downstream
    (:func:`project_dual_conic`, then :func:`conic_bbox`'s ``valid``) reads it as invalid. A
    negated radius would otherwise give the very matrix of the positive one (only ``r^2``
    enters), and a scaled rotation that of another ellipsoid.
    """
    xp = _namespace(xp)
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii, xp)
    Qs, valid = _dual_quadric_masked_compiled(rotation, center, radii, batch, xp)
    return (Qs, valid) if with_valid else Qs


def _dual_quadric_masked(rotation, center, radii, batch, xp):
    valid = xp.broadcast_to(_ellipsoid_ok(rotation, center, radii, xp), batch)
    z = functools.partial(_finite_or_zero, xp=xp)
    Qs = _dual_quadric(z(rotation), z(center), z(radii), batch, xp)
    return xp.where(valid[..., None, None], Qs, xp.zeros((), Qs.dtype)), valid


def _dual_quadric(rotation, center, radii, batch, xp):
    # Also the dual quadric of a flat ellipse (one radius 0): see cylinder_bbox.
    rotation = xp.broadcast_to(rotation, batch + (3, 3))
    center = xp.broadcast_to(center, batch + (3,))
    radii = xp.broadcast_to(radii, batch + (3,))
    shape = _matmul3(rotation * xp.square(radii)[..., None, :], xp.swapaxes(rotation, -1, -2))
    top_left = shape - center[..., :, None] * center[..., None, :]
    top = xp.concatenate([top_left, -center[..., :, None]], axis=-1)
    bottom = xp.concatenate([-center, -xp.ones(batch + (1,), center.dtype)], axis=-1)
    return xp.concatenate([top, bottom[..., None, :]], axis=-2)


_dual_quadric_masked_compiled = _eager_compiled(_dual_quadric_masked, static_argnums=(3, 4))


def _inverse_square_radii(radii):
    # Radii below eps(dtype) are clamped so that 1/r^2 stays finite (and far from overflow).
    floor = jnp.finfo(radii.dtype).eps
    return 1.0 / jnp.square(jnp.maximum(jnp.abs(radii), floor))


def primal_quadric(rotation, center, radii):
    """Primal (point) quadric ``Q`` of an ellipsoid (eq. 5.2-5.5): ``x^T Q x = 0`` on the surface.

    Args:
      rotation: (..., 3, 3) object-to-world; center: (..., 3); radii: (..., 3) semi-axes.

    Returns:
      (..., 4, 4) ``[[A, -A t], [-t^T A, t^T A t - 1]]`` with ``A = R diag(1/r^2) R^T``; radii are
      clamped below at ``eps(dtype)`` so the matrix stays finite.
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    rotation = jnp.broadcast_to(rotation, batch + (3, 3))
    center = jnp.broadcast_to(center, batch + (3,))
    inv_sq = jnp.broadcast_to(_inverse_square_radii(radii), batch + (3,))
    A = _matmul3(rotation * inv_sq[..., None, :], jnp.swapaxes(rotation, -1, -2))
    At = _matvec(A, center)
    corner = jnp.sum(center * At, axis=-1, keepdims=True) - 1.0
    top = jnp.concatenate([A, -At[..., :, None]], axis=-1)
    bottom = jnp.concatenate([-At, corner], axis=-1)
    return jnp.concatenate([top, bottom[..., None, :]], axis=-2)


def camera_matrix(K, camera_T_world, *, xp: Any = jnp, with_valid: bool = False) -> Any:
    """Projection matrix ``P = K [I | 0] camera_T_world`` (..., 3, 4) (eq. 4.9): ``x ~ P X``.

    Args:
      K: (..., 3, 3) intrinsics; camera_T_world: (..., 4, 4) world-to-camera transform.
      xp: ``jax.numpy`` (default) or ``numpy`` (host code).
      with_valid: also return the (...) mask of :func:`camera_valid`.
    """
    xp = _namespace(xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    batch = _batch_shape(K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    if not with_valid:
        return _camera_matrix(K, pose, xp)
    valid = xp.broadcast_to(_intrinsics_ok(K, xp) & _pose_ok(pose, xp), batch)
    return _camera_matrix(_finite_or_zero(K, xp), _finite_or_zero(pose, xp), xp), valid


def _camera_matrix(K, pose, xp):
    return xp.matmul(K, pose[..., :3, :])


def project_dual_conic(dual_quadric, K, camera_T_world, *, xp: Any = jnp):
    """Dual conic ``C* = P Q* P^T`` with ``P = K [I | 0] camera_T_world`` (eq. 4.9, 5.9).

    Args:
      dual_quadric: (..., 4, 4) ``Q*``.
      K: (..., 3, 3) intrinsics.
      camera_T_world: (..., 4, 4) world-to-camera transform.
      xp: ``jax.numpy`` (default) or ``numpy`` (host code).

    Returns:
      (..., 3, 3) dual conic in pixels. Where the camera is not valid (:func:`camera_valid`;
      possible only under ``jit``, concrete arguments are checked eagerly) it is all zeros,
      which :func:`conic_bbox` reads as invalid, as it does the zero matrix :func:`dual_quadric`
      gives for an invalid ellipsoid. It is all zeros too where the quadric's centre is not in
      front of the camera: an ellipsoid behind the camera has the very conic of its mirror image
      in front (only the square of its depth enters), which :func:`conic_bbox` could not tell
      apart. The centre's depth is read off ``Q*`` itself (``-(T Q*)[2, 3] / Q*[3, 3]``, for
      ``Q*`` in jaxsem's normalisation or any positive multiple of it).
    """
    xp = _namespace(xp)
    Qs = _as_float_array("dual_quadric", dual_quadric, (4, 4), check_finite=True, xp=xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(dual_quadric=Qs.shape[:-2], K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    ok = _intrinsics_ok(K, xp) & _pose_ok(pose, xp)
    P = _camera_matrix(_finite_or_zero(K, xp), _finite_or_zero(pose, xp), xp)
    C = xp.matmul(xp.matmul(P, Qs), xp.swapaxes(P, -1, -2))
    # (T Q*)[2, 3] = -s t_z and Q*[3, 3] = -s for Q* = s [[.., -t], [-t^T, -1]], s > 0: their
    # product has the sign of the centre's depth t_z (the last row of a rigid T is e4).
    z_row = _finite_or_zero(pose, xp)[..., 2, :]
    front = xp.sum(z_row * Qs[..., :, 3], axis=-1) * Qs[..., 3, 3] > 0
    ok = xp.broadcast_to(ok & front, C.shape[:-2])
    return xp.where(ok[..., None, None], C, xp.zeros((), C.dtype))


def conic_bbox(dual_conic, *, xp: Any = jnp):
    """Axis-aligned box of a dual conic (eq. 4.8, 4.10, 5.10): the lines ``u = const`` and ``v = const``
    tangent to it.

    ``u_min, u_max = (C13 -+ sqrt(C13^2 - C11 C33)) / C33`` and likewise for ``v``.

    Args:
      dual_conic: (..., 3, 3) ``C*``, in jaxsem's normalisation (``P Q* P^T`` with ``Q*[3,3] = -1``,
        or any positive multiple of it; the sign tells a real ellipse from an imaginary one).

    Returns:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]``, finite everywhere.
      valid: (...) bool, False where the conic is not a real ellipse (``C33 >= 0`` or
        ``det C* >= 0``: camera inside the ellipsoid, or the image plane cutting it). A dual conic
        alone cannot tell an ellipsoid in front of the camera from its mirror image behind it:
        :func:`project_dual_conic` checks the depth (the zero conic behind the camera) and so
        does :func:`project_bbox`.
    """
    xp = _namespace(xp)
    C = _as_float_array("dual_conic", dual_conic, (3, 3), check_finite=True, xp=xp)
    return _conic_bbox_compiled(C, xp)


def _conic_bbox(C, xp):
    finite = _finite(C, 2, xp)
    C = _finite_or_zero(C, xp)  # a non-finite conic (valid False) gives a finite box too
    c13, c23, c33, disc_u, disc_v, det, det_scale = _conic_terms(C, xp)
    valid = _is_ellipse(c13, c23, c33, disc_u, disc_v, det, det_scale) & finite
    return _conic_box(c13, c23, c33, disc_u, disc_v, valid, xp), valid


_conic_bbox_compiled = _eager_compiled(_conic_bbox, static_argnums=(1,))


def _is_ellipse(c13, c23, c33, disc_u, disc_v, det, det_scale):
    """The ``valid`` test of :func:`conic_bbox` on the scaled terms of :func:`_conic_terms`.

    Scale-aware: each sign test is made against the rounding level of its own terms,
    not against a fixed fraction of the largest entry. A small object seen far off-centre has a
    pixel conic whose ``C33`` is 1e-7 of its largest entry and whose determinant is 1e-15 of it,
    below float32 resolution; fixed thresholds there marked ordinary valid views invalid in
    float32 (and only there). ``det < 0`` is tested to within ``8 eps`` of the sum of its terms'
    magnitudes (inside that band its sign is rounding noise, and ``C33 < 0`` with both
    discriminants positive already make the conic an ellipse or a degenerate one); ``C33 < 0``
    against ``eps`` times the entries it scales with (``C13 ~ C33 u0``, ``C23 ~ C33 v0``), which
    still rejects a principal plane tangent to the ellipsoid (``C33 -> 0`` while ``C13`` stays).
    """
    eps = _eps(c33.dtype)
    front = c33 < -eps * (abs(c13) + abs(c23))
    front = front & (c33 < -(float(np.finfo(c33.dtype).tiny) ** 0.5))  # a safe divisor
    return front & (det < eps * det_scale) & (disc_u > 0) & (disc_v > 0)


def _conic_terms(C, xp):
    """Scaled entries of a dual conic for its bounds: ``C13, C23, C33``, the two discriminants,
    det and the sum of the magnitudes of det's terms (its rounding scale)."""
    C = 0.5 * (C + xp.swapaxes(C, -1, -2))
    # Scale to O(1) by a positive factor: the box is scale-invariant and det() cannot overflow.
    # The box being scale-invariant, the factor is held constant for differentiation (exact, and
    # no 1 / scale^2 term to overflow in forward mode).
    scale = xp.max(xp.abs(C), axis=(-2, -1), keepdims=True)
    if xp is jnp:
        scale = jax.lax.stop_gradient(scale)
    C = C / xp.where(scale > 0, scale, 1.0)
    c11, c12, c13 = C[..., 0, 0], C[..., 0, 1], C[..., 0, 2]
    c22, c23, c33 = C[..., 1, 1], C[..., 1, 2], C[..., 2, 2]
    det = c11 * (c22 * c33 - c23 * c23) - c12 * (c12 * c33 - c23 * c13) + c13 * (c12 * c23 - c22 * c13)
    a = abs
    det_scale = (
        a(c11 * c22 * c33) + a(c11 * c23 * c23) + a(c12 * c12 * c33) + 2 * a(c12 * c23 * c13) + a(c22 * c13 * c13)
    )
    disc_u = c13 * c13 - c11 * c33
    disc_v = c23 * c23 - c22 * c33
    return c13, c23, c33, disc_u, disc_v, det, det_scale


def _conic_box(c13, c23, c33, disc_u, disc_v, ok, xp):
    """``[(C13 + su) / C33, (C23 + sv) / C33, (C13 - su) / C33, (C23 - sv) / C33]`` where ``ok``."""
    c33_safe = xp.where(ok, c33, -1.0)
    su = _safe_sqrt(xp.where(ok, disc_u, 0.0), xp)
    sv = _safe_sqrt(xp.where(ok, disc_v, 0.0), xp)
    return xp.stack(
        [(c13 + su) / c33_safe, (c23 + sv) / c33_safe, (c13 - su) / c33_safe, (c23 - sv) / c33_safe],
        axis=-1,
    )


def cylinder_bbox(rotation, center, radii, K, camera_T_world, *, xp: Any = jnp):
    """Exact image box of an elliptic cylinder: the box of its two rim ellipses' outlines.

    The cylinder's axis is the object z axis; ``radii[..., :2]`` are the semi-axes of its
    cross-section and ``radii[..., 2]`` its half length. Each rim is the flat ellipse with radii
    ``(r0, r1, 0)`` at ``center +- r2 R[:, 2]``, whose dual quadric is eq. 4.3's with a zero radius,
    ``Q* = Z diag(r0^2, r1^2, 0, -1) Z^T``; its image ``P Q* P^T`` is bounded as in eq. 4.10
    (a rim seen edge-on projects to a segment, still bounded by the same formula).

    Args:
      rotation: (..., 3, 3); center: (..., 3); radii: (..., 3) positive; K: (..., 3, 3);
      camera_T_world: (..., 4, 4). xp: ``jax.numpy`` (default) or ``numpy`` (host code).

    Returns:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]``, finite.
      valid: (...) bool, False unless both rims lie entirely in front of the camera (and, under
        ``jit``, where an input is one the eager checks refuse).
    """
    xp = _namespace(xp)
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii, xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(cylinder=batch, K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    ok = _ellipsoid_ok(rotation, center, radii, xp) & _intrinsics_ok(K, xp) & _pose_ok(pose, xp)  # the inputs
    rotation, center, radii, K, pose = (_finite_or_zero(x, xp) for x in (rotation, center, radii, K, pose))
    flat = radii * xp.asarray([1.0, 1.0, 0.0], radii.dtype)
    axis = rotation[..., :, 2] * radii[..., 2:]
    boxes, valid = [], ok
    for rim_center in (center - axis, center + axis):
        C = project_dual_conic(_dual_quadric(rotation, rim_center, flat, batch, xp), K, pose, xp=xp)
        c13, c23, c33, disc_u, disc_v, _, _ = _conic_terms(C, xp)
        front = c33 < -_eps(C.dtype)
        boxes.append(_conic_box(c13, c23, c33, xp.maximum(disc_u, 0.0), xp.maximum(disc_v, 0.0), front, xp))
        valid = valid & front
    a, b = boxes
    box = xp.concatenate([xp.minimum(a[..., :2], b[..., :2]), xp.maximum(a[..., 2:], b[..., 2:])], axis=-1)
    return box, valid


def conic_outline(dual_conic, num_points: int = 64, *, xp: Any = jnp):
    """Points on a dual conic's ellipse, for drawing: (..., num_points, 2) and a (...) valid mask.

    A real ellipse with centre ``x0`` and shape ``M`` (the points ``x`` with
    ``(x - x0)^T M^-1 (x - x0) = 1``) has the dual conic ``C* ~ [[M - x0 x0^T, -x0], [-x0^T, -1]]``
    (the 2D analogue of eq. 4.3), so after scaling ``C*`` to ``C*33 = -1`` both are read off
    directly: ``x0 = -C*[:2, 2]`` and ``M = C*[:2, :2] + x0 x0^T``. The points are
    ``x0 + L [cos t, sin t]`` with ``L`` the closed-form 2x2 Cholesky factor of ``M``: no
    adjugate, no determinant and no eigen-decomposition, so the gradients are finite in float32
    and correct for circles (where an eigenvector gradient is undefined). Where the conic is not
    a real ellipse the points collapse to a finite point and valid is False.

    ``xp``: ``jax.numpy`` (default) or ``numpy`` (host code, e.g. figures: no jit, nothing
    compiles).
    """
    xp = _namespace(xp)
    Cs = _as_float_array("dual_conic", dual_conic, (3, 3), check_finite=True, xp=xp)
    if int(num_points) < 1:
        raise ValueError(f"num_points: expected a positive integer, got {num_points}")
    _, valid = conic_bbox(Cs, xp=xp)
    Cs = _finite_or_zero(0.5 * (Cs + xp.swapaxes(Cs, -1, -2)), xp)
    # Scaled to O(1) first, by a factor held constant for differentiation (the points do not
    # depend on it): then -C33 is not tiny where valid, and forward mode has no 1 / C33^2 to
    # overflow in float32.
    scale = xp.max(xp.abs(Cs), axis=(-2, -1), keepdims=True)
    if xp is jnp:
        scale = jax.lax.stop_gradient(scale)
    Cs = Cs / xp.where(scale > 0, scale, 1.0)
    c33 = xp.where(valid, Cs[..., 2, 2], -1.0)
    Cn = Cs / (-c33)[..., None, None]
    x0 = -Cn[..., :2, 2]
    m11 = Cn[..., 0, 0] + x0[..., 0] * x0[..., 0]
    m12 = Cn[..., 0, 1] + x0[..., 0] * x0[..., 1]
    m22 = Cn[..., 1, 1] + x0[..., 1] * x0[..., 1]
    # M = L L^T, L = [[l11, 0], [l21, l22]]; on invalid conics the inputs are replaced by 1 so the
    # branch not taken has finite gradients.
    l11 = _safe_sqrt(xp.where(valid, m11, 1.0), xp)
    m12 = xp.where(valid, m12, 0.0)
    l21 = safe_div(m12, l11) if xp is jnp else m12 / np.where(l11 > 0, l11, 1.0)
    l22 = _safe_sqrt(xp.where(valid, m22 - l21 * l21, 1.0), xp)
    t = xp.linspace(0.0, 2 * np.pi, int(num_points), dtype=Cs.dtype)
    cos_t, sin_t = xp.cos(t), xp.sin(t)
    u = x0[..., 0, None] + l11[..., None] * cos_t
    v = x0[..., 1, None] + l21[..., None] * cos_t + l22[..., None] * sin_t
    pts = xp.stack([u, v], -1)
    return xp.where(valid[..., None, None], pts, 0.0), valid


def _matvec2(m, v):
    return jnp.sum(m * v[..., None, :], axis=-1)


def camera_frame(rotation, center, camera_T_world, *, with_valid: bool = False) -> Any:  # a tuple with with_valid=True
    """The ellipsoid's rotation (..., 3, 3) and centre (..., 3) in the camera frame.

    Concrete arguments are checked like the other functions' (``ValueError`` naming the
    argument: a finite proper ``rotation``, a finite ``center``, a finite rigid
    ``camera_T_world``). ``with_valid=True`` adds a third output, a (...) bool mask that says the
    same under ``jit`` (then the outputs are finite for non-finite inputs too).
    """
    rotation = _as_float_array("rotation", rotation, (3, 3), check_finite=True)
    center = _as_float_array("center", center, (3,), check_finite=True)
    _check_rotation("rotation", rotation)
    (pose,) = _camera_args(None, camera_T_world, need_K=False)
    dtype = jnp.result_type(rotation.dtype, center.dtype, pose.dtype)
    rotation, center, pose = rotation.astype(dtype), center.astype(dtype), pose.astype(dtype)
    _batch_shape(rotation=rotation.shape[:-2], center=center.shape[:-1], camera_T_world=pose.shape[:-2])
    if not with_valid:
        return _camera_frame(rotation, center, pose)
    valid = _rotation_ok(rotation) & _finite(center, 1) & _pose_ok(pose)
    R_c, t_c = _camera_frame(_finite_or_zero(rotation), _finite_or_zero(center), _finite_or_zero(pose))
    return R_c, t_c, valid


def _camera_frame(rotation, center, camera_T_world):
    R_cw = camera_T_world[..., :3, :3]
    return _matmul3(R_cw, rotation), _matvec_terms(R_cw, center) + camera_T_world[..., :3, 3]


# --------------------------------------------------------------------------------------------
# Depths seen by a camera: the texture plane (eq. 4.11-4.12) and the depth of a point.


def texture_plane_depth(rotation, center, radii, camera_T_world):
    """Depth of the camera-facing tangent plane parallel to the image plane (eq. 4.11-4.12).

    Solving ``[0, 0, 1, -z] Q*_cam [0, 0, 1, -z]^T = 0`` gives ``z = t_z -+ sqrt(S33)``; the
    texture plane is the smaller root, ``t_z - sqrt(e3^T R_c diag(r^2) R_c^T e3)``.

    Args:
      rotation: (..., 3, 3); center: (..., 3); radii: (..., 3); camera_T_world: (..., 4, 4).

    Returns:
      depth: (...) metres along the optical axis (finite everywhere).
      valid: (...) bool, False where the plane is not in front of the camera (camera inside the
        ellipsoid, or the ellipsoid behind or straddling the image plane), and under ``jit``
        where an input is one the eager checks refuse (then the depth is finite all the same).
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    (pose,) = _camera_args(None, camera_T_world, need_K=False)
    _batch_shape(ellipsoid=batch, camera_T_world=pose.shape[:-2])
    dtype = jnp.result_type(rotation.dtype, pose.dtype)
    rotation, center, radii, pose = (x.astype(dtype) for x in (rotation, center, radii, pose))
    ok = _ellipsoid_ok(rotation, center, radii) & _pose_ok(pose)  # the inputs, under jit
    rotation, center, radii, pose = (_finite_or_zero(x) for x in (rotation, center, radii, pose))
    Rc, tc = _camera_frame(rotation, center, pose)
    half_depth = safe_norm(radii * Rc[..., 2, :], axis=-1)
    depth = tc[..., 2] - half_depth
    valid = (depth > _eps(dtype) * (jnp.abs(tc[..., 2]) + half_depth)) & ok
    return depth, valid


def half_extent(rotation, radii, direction, *, xp: Any = jnp):
    """Half-extent of an ellipsoid along a unit ``direction``: ``|diag(radii) R^T d|``.

    The ellipsoid's support function about its centre: its surface reaches ``center . d +-
    half_extent`` along ``d`` (the lowest point above a support when ``d`` is up; the near
    tangent plane when ``d`` is a camera's optical axis).

    Args:
      rotation: (..., 3, 3) object-to-world; radii: (..., 3); direction: (..., 3) unit vector
        in the world. ``xp``: ``jax.numpy`` (default, with a NaN-safe norm: finite gradients
        for zero radii) or ``numpy`` (host code).

    Returns:
      (...) metres.
    """
    xp = _namespace(xp)
    rotation, radii, direction = (xp.asarray(x) for x in (rotation, radii, direction))
    local = xp.einsum("...ji,...j->...i", rotation, direction)  # R^T d
    if xp is np:
        return np.linalg.norm(radii * local, axis=-1)
    return safe_norm(radii * local, axis=-1)


def camera_depth(center, camera_T_world, *, xp: Any = jnp):
    """Depth (camera z) of world points ``center`` (..., 3) seen from ``camera_T_world`` (..., 4, 4).
    ``xp``: ``jax.numpy`` (default) or ``numpy`` (host code)."""
    xp = _namespace(xp)
    center = _as_float_array("center", center, (3,), check_finite=True, xp=xp)
    pose = _as_float_array("camera_T_world", camera_T_world, (4, 4), check_finite=True, xp=xp)
    return xp.sum(pose[..., 2, :3] * center, axis=-1) + pose[..., 2, 3]

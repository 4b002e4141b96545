r"""Geometry core: ellipsoids as dual and primal quadrics, and what a camera sees of them.

One file a reader can check against the equations of the thesis (chapter 4.2, 4.3.1-4.3.3 and
5.2). It imports nothing else of the package.

Conventions (the only ones in jaxsem):

- An ellipsoid is ``rotation`` (..., 3, 3) object-to-world, ``center`` (..., 3) in the world and
  ``radii`` (..., 3), the semi-axis lengths in metres. Chapter 5's "size d" is ``2 * radii``.
- Dual quadric (eq. 4.1-4.3): ``Q* = Z diag(r0^2, r1^2, r2^2, -1) Z^T`` with ``Z = [[R, t], [0, 1]]``.
- Primal quadric (eq. 5.5): ``Q = [[A, -A t], [-t^T A, t^T A t - 1]]``, ``A = R diag(1/r^2) R^T``;
  ``x^T Q x < 0`` inside, ``= 0`` on the surface, ``> 0`` outside.
- A camera is ``K`` (..., 3, 3) and ``camera_T_world`` (..., 4, 4), which maps world points into the
  camera frame (OpenCV axes: x right, y down, z forward). ``P = K [I | 0] camera_T_world`` and the
  projected dual conic is ``C* = P Q* P^T`` (eq. 4.9).
- Image boxes are ``[u_min, v_min, u_max, v_max]`` in pixels (eq. 4.10).

Every public function broadcasts leading batch axes numpy-style, works under ``jit``, ``vmap`` and
``grad`` in float32 and float64, and never returns NaN values or NaN gradients for finite inputs.
Where the closed form has no real answer (camera inside or on the ellipsoid, ellipsoid behind or
straddling the image plane, a conic that is not an ellipse) a ``valid`` mask is returned next to
a finite value. Wrong trailing shapes raise ``ValueError`` naming the argument; non-finite
concrete inputs where they would poison everything (``K``, poses) raise too.

Host code (dataset writers, the OpenCV front end) calls the same functions with ``xp=numpy``
where the option exists: the same formulas, evaluated by numpy in float64 without a jax dispatch
per call (which costs milliseconds in a per-object Python loop). The default is ``jax.numpy``.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

# Boundary checks live in the core's private helper module (re-exported for the package there).
from ._checks import (
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
    check_positive as _check_positive,
    check_rotation as _check_rotation,
    is_concrete as _is_concrete,
)

__all__ = [
    "Ellipsoid",
    "Camera",
    "dual_quadric",
    "primal_quadric",
    "project_dual_conic",
    "camera_matrix",
    "conic_bbox",
    "cylinder_bbox",
    "conic_outline",
    "project_bbox",
    "texture_plane_depth",
    "algebraic_distance",
    "ray_entry_range",
    "shape_bbox",
    "shape_distance",
    "stereo_right_T_left",
    "SHAPE_CUBOID",
    "SHAPE_ELLIPSOID",
    "SHAPE_CYLINDER",
    "SUPERQUADRIC_EPS",
    "ground_conic",
    "ground_bounds",
    "rasterize_footprint",
    "surface_points",
    "camera_depth",
    "camera_frame",
    "look_at",
    "rigid_transform",
    "transform_points",
    "invert_pose",
    "project_points",
    "back_project",
    "single_view_ellipsoid",
    "cuboid_corners",
    "CUBOID_CORNER_SIGNS",
    "so3_exp",
    "quaternion_wxyz_to_rotation",
    "rotation_to_quaternion_wxyz",
    "quaternion_xyzw_to_rotation",
    "rotation_to_quaternion_xyzw",
    "random_rotation",
    "safe_sqrt",
    "safe_div",
    "safe_norm",
]


# --------------------------------------------------------------------------------------------
# Boundary checks (re-exported for the rest of the package by jaxsem._checks).


def _ellipsoid_args(rotation, center, radii, xp: Any = jnp):
    """Ellipsoid arguments as arrays of one dtype, and their broadcast batch shape.

    Concrete (not traced) values are checked: finite, ``rotation`` a proper rotation, ``radii``
    positive; each failure is a ``ValueError`` naming the argument. Traced values are not checked
    (the functions' ``valid`` masks and result codes carry validity under ``jit``).
    """
    rotation = _as_float_array("rotation", rotation, (3, 3), check_finite=True, xp=xp)
    center = _as_float_array("center", center, (3,), check_finite=True, xp=xp)
    radii = _as_float_array("radii", radii, (3,), check_finite=True, xp=xp)
    _check_rotation("rotation", rotation)
    _check_positive("radii", radii)
    dtype = xp.result_type(rotation.dtype, center.dtype, radii.dtype)
    batch = _batch_shape(rotation=rotation.shape[:-2], center=center.shape[:-1], radii=radii.shape[:-1])
    return rotation.astype(dtype), center.astype(dtype), radii.astype(dtype), batch


def _camera_args(K, camera_T_world, *, need_K=True, xp: Any = jnp):
    out = []
    if need_K:
        K = _as_float_array("K", K, (3, 3), check_finite=True, xp=xp)
        if _is_concrete(K):
            Kn = np.asarray(K)
            bottom = Kn[..., 2, :]
            if not (np.allclose(bottom, [0.0, 0.0, 1.0]) and np.allclose(Kn[..., 1, 0], 0.0)):
                raise ValueError(
                    "K: expected intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got "
                    f"{Kn.reshape(-1, 3, 3)[0].tolist()} (first of batch)"
                )
            if Kn.size and not (np.all(Kn[..., 0, 0] > 0) and np.all(Kn[..., 1, 1] > 0)):
                raise ValueError(
                    f"K: expected positive focal lengths fx, fy, got fx min {float(np.min(Kn[..., 0, 0])):.3g}, "
                    f"fy min {float(np.min(Kn[..., 1, 1])):.3g}"
                )
        out.append(K)
    pose = _as_float_array("camera_T_world", camera_T_world, (4, 4), check_finite=True, xp=xp)
    _check_rotation("camera_T_world", pose[..., :3, :3])
    out.append(pose)
    return out


def _namespace(xp):
    """The array namespace of a public function's ``xp=`` option: ``jax.numpy`` or ``numpy``."""
    if xp is jnp or xp is np:
        return xp
    raise ValueError(f"xp: expected jax.numpy or numpy, got {xp!r}")


@functools.cache
def _eps(dtype) -> float:
    """Dtype-dependent tolerance: about 1e-6 in float32, 1e-15 in float64 (cached: host code calls
    it per object)."""
    return float(jnp.finfo(dtype).eps) * 8.0


# --------------------------------------------------------------------------------------------
# Typed pytrees. NamedTuples are pytrees, so they pass through jit / vmap / grad unchanged, and
# every function below also takes the plain arrays (``project_bbox(*ellipsoid, *camera)``).


class Ellipsoid(NamedTuple):
    """An ellipsoid in jaxsem's one representation.

    Attributes:
      rotation: (..., 3, 3) object-to-world (or -camera, for VoluMon's camera-frame outputs).
      center: (..., 3) metres.
      radii: (..., 3) semi-axes in metres (chapter 5's size ``d = 2 * radii``).
    """

    rotation: jax.Array
    center: jax.Array
    radii: jax.Array

    @classmethod
    def create(cls, rotation, center, radii) -> Ellipsoid:
        """Checked constructor: shapes, finiteness, proper rotations, positive radii."""
        rotation, center, radii, _ = _ellipsoid_args(rotation, center, radii)
        return cls(rotation, center, radii)

    @property
    def sizes(self):
        """Full axis lengths ``d = 2 * radii`` (chapter 5's size)."""
        return 2.0 * self.radii


class Camera(NamedTuple):
    """A pinhole camera: ``K`` (..., 3, 3) and ``camera_T_world`` (..., 4, 4), OpenCV axes."""

    K: jax.Array
    camera_T_world: jax.Array

    @classmethod
    def create(cls, K, camera_T_world) -> Camera:
        """Checked constructor: intrinsics with positive focal lengths, a rigid pose."""
        K, pose = _camera_args(K, camera_T_world)
        return cls(K, pose)


# --------------------------------------------------------------------------------------------
# NaN-safe primitives: the branch not taken by a `where` must have finite gradients too.


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` whose value and gradient are finite for finite ``x`` (gradient 0 for
    x <= 0). NaN stays NaN: a guard must not turn a poisoned input into a finite-looking 0."""
    return _safe_sqrt(jnp.asarray(x), jnp)


def _safe_sqrt(x, xp):
    positive = x > xp.finfo(xp.result_type(x, float)).tiny
    return xp.where(positive, xp.sqrt(xp.where(positive, x, 1.0)), xp.where(xp.isnan(x), x, 0.0))


def safe_div(numerator, denominator, eps=None):
    """``numerator / denominator`` with ``|denominator|`` clamped to at least ``eps`` (sign kept)."""
    denominator = jnp.asarray(denominator)
    if eps is None:
        eps = jnp.finfo(jnp.result_type(denominator, float)).tiny ** 0.5
    small = jnp.abs(denominator) < eps
    safe = jnp.where(small, jnp.where(denominator < 0, -eps, eps), denominator)
    return numerator / safe


def safe_norm(x, axis=-1, keepdims: bool = False):
    """Euclidean norm along ``axis`` with a zero (not NaN) gradient at the origin."""
    return _safe_norm(jnp.asarray(x), jnp, axis, keepdims)


def _safe_norm(x, xp, axis=-1, keepdims: bool = False):
    return _safe_sqrt(xp.sum(xp.square(x), axis=axis, keepdims=keepdims), xp)


def _matvec(m, v):
    """(..., 3, 3) @ (..., 3) as a broadcasted product and sum: fuses into elementwise loops.
    Written with array methods, so it serves numpy arrays as well as jax ones."""
    return (m * v[..., None, :]).sum(axis=-1)


def _matmul3(a, b):
    return (a[..., :, :, None] * b[..., None, :, :]).sum(axis=-2)


def _cross(a, b, xp: Any = jnp):
    return xp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


# --------------------------------------------------------------------------------------------
# Quadric matrices.


def dual_quadric(rotation, center, radii, *, xp: Any = jnp):
    """Dual quadric ``Q*`` of an ellipsoid (eq. 4.3).

    Args:
      rotation: (..., 3, 3) object-to-world rotation ``R``.
      center: (..., 3) centre ``t`` in the world.
      radii: (..., 3) semi-axes ``r`` in metres.
      xp: ``jax.numpy`` (default) or ``numpy`` (host code; see the module docstring).

    Returns:
      (..., 4, 4) ``[[R diag(r^2) R^T - t t^T, -t], [-t^T, -1]]``.
    """
    xp = _namespace(xp)
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii, xp)
    return _dual_quadric(rotation, center, radii, batch, xp)


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


def camera_matrix(K, camera_T_world, *, xp: Any = jnp):
    """Projection matrix ``P = K [I | 0] camera_T_world`` (..., 3, 4) (eq. 4.9): ``x ~ P X``.

    Args:
      K: (..., 3, 3) intrinsics; camera_T_world: (..., 4, 4) world-to-camera transform.
      xp: ``jax.numpy`` (default) or ``numpy`` (host code).
    """
    xp = _namespace(xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    return _camera_matrix(K, pose, xp)


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
      (..., 3, 3) dual conic in pixels.
    """
    xp = _namespace(xp)
    Qs = _as_float_array("dual_quadric", dual_quadric, (4, 4), check_finite=True, xp=xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(dual_quadric=Qs.shape[:-2], K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    P = _camera_matrix(K, pose, xp)
    return xp.matmul(xp.matmul(P, Qs), xp.swapaxes(P, -1, -2))


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
        alone cannot tell an ellipsoid in front of the camera from its mirror image behind it;
        :func:`project_bbox` checks the depth as well.
    """
    xp = _namespace(xp)
    C = _as_float_array("dual_conic", dual_conic, (3, 3), check_finite=True, xp=xp)
    c13, c23, c33, disc_u, disc_v, det = _conic_terms(C, xp)
    valid = (c33 < -_eps(C.dtype)) & (det < 0) & (disc_u > 0) & (disc_v > 0)
    return _conic_box(c13, c23, c33, disc_u, disc_v, valid, xp), valid


def _conic_terms(C, xp):
    """Scaled entries of a dual conic for its bounds: ``C13, C23, C33``, the two discriminants, det."""
    C = 0.5 * (C + xp.swapaxes(C, -1, -2))
    # Scale to O(1) by a positive factor: the box is scale-invariant and det() cannot overflow.
    scale = xp.max(xp.abs(C), axis=(-2, -1), keepdims=True)
    C = C / xp.where(scale > 0, scale, 1.0)
    c11, c12, c13 = C[..., 0, 0], C[..., 0, 1], C[..., 0, 2]
    c22, c23, c33 = C[..., 1, 1], C[..., 1, 2], C[..., 2, 2]
    det = c11 * (c22 * c33 - c23 * c23) - c12 * (c12 * c33 - c23 * c13) + c13 * (c12 * c23 - c22 * c13)
    disc_u = c13 * c13 - c11 * c33
    disc_v = c23 * c23 - c22 * c33
    return c13, c23, c33, disc_u, disc_v, det


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
      valid: (...) bool, False unless both rims lie entirely in front of the camera.
    """
    xp = _namespace(xp)
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii, xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(cylinder=batch, K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    flat = radii * xp.asarray([1.0, 1.0, 0.0], radii.dtype)
    axis = rotation[..., :, 2] * radii[..., 2:]
    boxes, valid = [], True
    for rim_center in (center - axis, center + axis):
        C = project_dual_conic(_dual_quadric(rotation, rim_center, flat, batch, xp), K, pose, xp=xp)
        c13, c23, c33, disc_u, disc_v, _ = _conic_terms(C, xp)
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
    Cs = 0.5 * (Cs + xp.swapaxes(Cs, -1, -2))
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


def camera_frame(rotation, center, camera_T_world):
    """The ellipsoid's rotation (..., 3, 3) and centre (..., 3) in the camera frame."""
    R_cw = camera_T_world[..., :3, :3]
    return _matmul3(R_cw, rotation), _matvec(R_cw, center) + camera_T_world[..., :3, 3]


# --------------------------------------------------------------------------------------------
# project_bbox: a fused private path.
#
# Why not conic_bbox(project_dual_conic(dual_quadric(...))): that composition is the readable
# reference (and the tests check this path against it), but XLA on the CPU runs batched (4, 4)
# matmuls and size-3/4 trailing axes as many small, badly vectorised loops. Here everything is
# written on (...,) components, so that XLA emits a few elementwise loops. Two XLA:CPU habits
# shape the code (benchmarks/geometry.py measures it; see benchmarks/results/geometry.md):
#
# - A loop fusion has one output. The four box edges are therefore computed in a (..., 4) space
#   (the inputs broadcast along a last axis of size 4, each lane computing its own edge), which
#   vectorises across the lanes and reads every input once; the mask is a second, separate loop.
# - A value shared by two loops is materialised in memory, or, when cheap, recomputed per use.
#   The reverse mode (the transpose of the custom JVP below) is arranged so that the only
#   materialised intermediate is one (..., 2, 9) array of cotangents, and input tangents are only
#   multiplied by primal arrays and summed over their own axes (so the transpose is elementwise
#   in each input's own shape, without reductions or scatters).
#
# Notation (per pair): C* = K M K^T, with M = [I | 0] T Q* T^T [I | 0]^T = S - t t^T the dual conic
# in normalised camera coordinates (S = Rc diag(r^2) Rc^T, Rc = W R, t = W c + t_w the centre in
# the camera frame, T = [[W, t_w], [0, 1]] = camera_T_world). For one image axis let
# a = (fx, s, 0) for u, (0, fy, 0) for v, and c0 = cx or cy; the row h = a [I | 0] T (4 entries)
# and the depth row h3 = e3 [I | 0] T. With R_k the k-th column of R:
#   ra_k = r_k (h[:3] . R_k),  r3_k = r_k (h3[:3] . R_k),  alpha = h . [c, 1],  tz = h3 . [c, 1],
#   num = a M e3 = ra . r3 - alpha tz,      den = M33 = C33 = |r3|^2 - tz^2,
#   disc = num^2 - (a M a) M33 = |tz ra - alpha r3|^2 - |ra x r3|^2   (= C13^2 - C11 C33 of the
#          pixel conic; Lagrange's identity makes it a difference of two non-negative terms,
#          without the cancellation of the pixel-space form),
#   edges = c0 + (num -+ sqrt(disc)) / den   (eq. 4.10 with the origin moved to c0).

_BOX_COL_IS_U = np.array([True, False, True, False])  # [u_min, v_min, u_max, v_max]
_BOX_COL_SIGN = np.array([1.0, 1.0, -1.0, -1.0])


def _dot3(a, b) -> Any:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross3(a, b) -> Any:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _bbox_valid(R, c, r, K, T):
    """The ``valid`` mask of :func:`project_bbox`: the whole ellipsoid strictly in front of the
    principal plane (near tangent plane ``tz - sqrt(S33) > 0``, eq. 4.11) and both discriminants
    non-negative in floating point. One elementwise loop over (...,) components."""
    W = [[T[..., i, j] for j in range(3)] for i in range(3)]
    Ro = [[R[..., i, j] for j in range(3)] for i in range(3)]
    cc = [c[..., i] for i in range(3)]
    rr = [r[..., i] for i in range(3)]
    Rc = [[W[i][0] * Ro[0][j] + W[i][1] * Ro[1][j] + W[i][2] * Ro[2][j] for j in range(3)] for i in range(3)]
    tx, ty, tz = [W[i][0] * cc[0] + W[i][1] * cc[1] + W[i][2] * cc[2] + T[..., i, 3] for i in range(3)]
    fx, s, fy = K[..., 0, 0], K[..., 0, 1], K[..., 1, 1]
    r3 = [rr[k] * Rc[2][k] for k in range(3)]
    ra = [rr[k] * (fx * Rc[0][k] + s * Rc[1][k]) for k in range(3)]
    rb = [rr[k] * (fy * Rc[1][k]) for k in range(3)]
    s33 = _dot3(r3, r3)
    half_depth = safe_sqrt(s33)
    near = tz - half_depth  # texture-plane depth: the camera-facing tangent plane
    alpha = fx * tx + s * ty
    beta = fy * ty
    wa = [tz * ra[k] - alpha * r3[k] for k in range(3)]
    wb = [tz * rb[k] - beta * r3[k] for k in range(3)]
    cu, cv = _cross3(ra, r3), _cross3(rb, r3)
    disc_u = _dot3(wa, wa) - _dot3(cu, cu)
    disc_v = _dot3(wb, wb) - _dot3(cv, cv)
    eps = _eps(near.dtype)
    return (near > eps * (jnp.abs(tz) + half_depth)) & (disc_u >= 0) & (disc_v >= 0)


def _bbox_axis(R, c, r, K, T, valid, lift, is_u):
    """Per image axis the quantities of eq. 4.10 (see the notation above), computed in a
    broadcast space: ``lift`` broadcasts a (...,) array into it, ``is_u`` selects the u axis."""
    zero = jnp.zeros((), R.dtype)
    a0 = jnp.where(is_u, lift(K[..., 0, 0]), zero)
    a1 = jnp.where(is_u, lift(K[..., 0, 1]), lift(K[..., 1, 1]))
    h = [a0 * lift(T[..., 0, j]) + a1 * lift(T[..., 1, j]) for j in range(4)]
    h3 = [lift(T[..., 2, j]) for j in range(4)]
    c0 = jnp.where(is_u, lift(K[..., 0, 2]), lift(K[..., 1, 2]))
    col = [[lift(R[..., i, k]) for i in range(3)] for k in range(3)]
    rr = [lift(r[..., k]) for k in range(3)]
    ch = [lift(c[..., i]) for i in range(3)]
    ra = [rr[k] * _dot3(h, col[k]) for k in range(3)]
    r3 = [rr[k] * _dot3(h3, col[k]) for k in range(3)]
    alpha = _dot3(h, ch) + h[3]
    tz = _dot3(h3, ch) + h3[3]
    num = _dot3(ra, r3) - alpha * tz
    wa = [tz * ra[k] - alpha * r3[k] for k in range(3)]
    cr = _cross3(ra, r3)
    disc = _dot3(wa, wa) - _dot3(cr, cr)
    V = lift(valid)
    pos = V & (disc > jnp.finfo(R.dtype).tiny)
    sq = jnp.where(pos, jnp.sqrt(jnp.where(pos, disc, 1.0)), 0.0)  # safe_sqrt of the masked disc
    fallback = tz * tz
    den = jnp.where(V, _dot3(r3, r3) - fallback, -jnp.maximum(fallback, 1.0))
    return dict(
        c0=c0, ra=ra, r3=r3, alpha=alpha, tz=tz, num=num, wa=wa, cr=cr, sq=sq, den=den, V=V, pos=pos, fallback=fallback
    )


def _bbox_edges(R, c, r, K, T, valid):
    """(..., 4) ``[u_min, v_min, u_max, v_max]``: one lane per edge."""
    shape = R.shape[:-2] + (4,)
    lift = lambda x: jnp.broadcast_to(x[..., None], shape)
    q = _bbox_axis(R, c, r, K, T, valid, lift, jnp.asarray(_BOX_COL_IS_U))
    sign = jnp.asarray(_BOX_COL_SIGN, R.dtype)
    # (sign num + sq) / (sign den) is (num + sign sq) / den exactly (sign flips are exact); the
    # divisor differs per lane, which keeps XLA from hoisting 1 / den into a loop of its own.
    return q["c0"] + (sign * q["num"] + q["sq"]) / (sign * q["den"])


def _bbox_sensitivities(R, c, r, K, T, valid):
    """``den * d edge / d x`` for the lower and the upper edge of each axis, with
    ``x = (ra_0, ra_1, ra_2, r3_0, r3_1, r3_2, alpha, tz, c0)``, and ``den``: three (..., 2, 9)
    arrays from one elementwise loop (axis along -2, entry of x along -1)."""
    shape = R.shape[:-2] + (2, 9)
    lift = lambda x: jnp.broadcast_to(x[..., None, None], shape)
    is_u = jnp.broadcast_to(jnp.asarray([[True], [False]]), (2, 9))
    q = _bbox_axis(R, c, r, K, T, valid, lift, is_u)
    ra, r3, alpha, tz, wa, cr = q["ra"], q["r3"], q["alpha"], q["tz"], q["wa"], q["cr"]
    num, sq, den, V, pos = q["num"], q["sq"], q["den"], q["V"], q["pos"]
    zero = jnp.zeros_like(tz)
    # Partial derivatives of num, disc and den with respect to the entries of x.
    d_num = r3 + ra + [-tz, -alpha, zero]
    r3_x_cr, cr_x_ra = _cross3(r3, cr), _cross3(cr, ra)  # d|ra x r3|^2 = 2 (r3 x cr) dra + 2 (cr x ra) dr3
    d_disc = (
        [2.0 * (tz * wa[k] - r3_x_cr[k]) for k in range(3)]
        + [2.0 * (-alpha * wa[k] - cr_x_ra[k]) for k in range(3)]
        + [-2.0 * _dot3(wa, r3), 2.0 * _dot3(wa, ra), zero]
    )
    fb = q["fallback"]  # where not valid, den = -max(tz^2, 1); jnp.maximum splits a tie evenly
    d_fb = jnp.where(fb > 1.0, 1.0, jnp.where(fb == 1.0, 0.5, 0.0))
    d_den = (
        [zero] * 3
        + [jnp.where(V, 2.0 * r3[k], 0.0) for k in range(3)]
        + [zero, -2.0 * tz * jnp.where(V, 1.0, d_fb), zero]
    )
    m = jnp.broadcast_to(jnp.arange(9), (2, 9))

    def pick(values):
        out = values[8]
        for i in range(7, -1, -1):
            out = jnp.where(m == i, values[i], out)
        return out

    dn, dd, dq = pick(d_num), pick(d_disc), pick(d_den)
    # d sqrt(disc) = d disc / (2 sqrt(disc)) where disc > tiny, else 0 (as safe_sqrt).
    ds = jnp.where(pos, 0.5 / jnp.where(pos, sq, 1.0), 0.0) * dd
    c0 = jnp.where(m == 8, den, 0.0)  # d edge / d c0 = 1
    lower = dn + ds - (num + sq) / den * dq + c0
    upper = dn - ds - (num - sq) / den * dq + c0
    return lower, upper, den


def _bbox_primitive_tangents(R, c, r, K, T, dR, dc, dr, dK, dT):
    """Tangents of x (see :func:`_bbox_sensitivities`) per axis, (..., 2, 9).

    Input tangents are only multiplied by primal arrays and summed over their own axes (or used
    one entry at a time), so that the transpose of this linear map (the reverse mode) is
    elementwise in each input's own shape: no reductions, and nothing but the (..., 2, 9)
    cotangent of x needs to be kept in memory."""
    zero = jnp.zeros(R.shape[:-2], R.dtype)
    fx, s, fy = K[..., 0, 0], K[..., 0, 1], K[..., 1, 1]
    dfx, ds, dfy = dK[..., 0, 0], dK[..., 0, 1], dK[..., 1, 1]
    W = [[T[..., j, i] for i in range(3)] for j in range(3)]
    tw = [T[..., j, 3] for j in range(3)]
    dW, dtw = dT[..., :3, :3], dT[..., :3, 3]
    # Rows h = A W (world axes) and h_t = A t_w of the u axis, the v axis and the depth row, as
    # (weights A, tangent of A) pairs; dh = A dW + dA W, dh_t = A dt_w + dA t_w.
    rows = [
        ([fx, s, zero], [dfx, ds, None]),
        ([zero, fy, zero], [None, dfy, None]),
        ([zero, zero, zero + 1.0], [None] * 3),
    ]
    proj, lin = [], []
    for A, dA in rows:
        h = [A[0] * W[0][i] + A[1] * W[1][i] + A[2] * W[2][i] for i in range(3)]
        Av = jnp.stack(A, -1)
        dh = jnp.sum(Av[..., :, None] * dW, -2)
        dht = jnp.sum(Av * dtw, -1)
        for j in range(3):
            if dA[j] is not None:
                dh = dh + jnp.stack([dA[j] * W[j][i] for i in range(3)], -1)
                dht = dht + dA[j] * tw[j]
        p = jnp.stack([h[0] * R[..., 0, k] + h[1] * R[..., 1, k] + h[2] * R[..., 2, k] for k in range(3)], -1)
        dp = jnp.stack([jnp.sum(dh * R[..., :, k], -1) for k in range(3)], -1) + jnp.sum(
            jnp.stack(h, -1)[..., :, None] * dR, -2
        )
        proj.append(dr * p + r * dp)  # d (r_k h . R_k)
        lin.append(jnp.sum(dh * c, -1) + dht + jnp.sum(jnp.stack(h, -1) * dc, -1))  # d (h . c + h_t)
    dx_u = jnp.concatenate([proj[0], proj[2], jnp.stack([lin[0], lin[2], dK[..., 0, 2]], -1)], -1)
    dx_v = jnp.concatenate([proj[1], proj[2], jnp.stack([lin[1], lin[2], dK[..., 1, 2]], -1)], -1)
    return jnp.stack([dx_u, dx_v], -2)


def _project_bbox_plain(R, c, r, K, T):
    """Eq. 4.9-4.10 in closed form on inputs that share one batch shape (see the notes above).
    Differentiating this directly is correct but slow; :func:`_project_bbox` adds the JVP rule."""
    valid = _bbox_valid(R, c, r, K, T)
    return _bbox_edges(R, c, r, K, T, valid), valid


_project_bbox = jax.custom_jvp(_project_bbox_plain)


@_project_bbox.defjvp
def _project_bbox_jvp(primals, tangents):
    R, c, r, K, T = primals
    box, valid = _project_bbox(R, c, r, K, T)
    lower, upper, den = _bbox_sensitivities(R, c, r, K, T, valid)
    # Dividing the tangent (not the sensitivities) by den puts the division at the end of the
    # reverse pass, which makes XLA keep that (..., 2, 9) cotangent in memory instead of
    # recomputing it in every consumer.
    dx = _bbox_primitive_tangents(*primals, *tangents) / den
    dbox = jnp.concatenate([jnp.sum(lower * dx, -1), jnp.sum(upper * dx, -1)], -1)
    return (box, valid), (dbox, np.zeros(valid.shape, jax.dtypes.float0))


def project_bbox(rotation, center, radii, K, camera_T_world):
    """Image box of an ellipsoid seen by a pinhole camera (eq. 4.5, 4.9-4.10 and 5.10 in closed form).

    Args:
      rotation: (..., 3, 3) object-to-world; center: (..., 3) world; radii: (..., 3) semi-axes.
      K: (..., 3, 3) intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
      camera_T_world: (..., 4, 4) world-to-camera transform (OpenCV axes).

    Returns:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]`` in pixels, finite everywhere, with finite
        gradients. It is not truncated to any image size.
      valid: (...) bool, True iff the whole ellipsoid lies strictly in front of the camera's
        principal plane (so the camera is outside it and the outline is a real ellipse). Where
        False (camera inside or on the ellipsoid, ellipsoid behind or straddling the image plane)
        the box is an arbitrary finite value.

    Only ``fx, s, cx, fy, cy`` of ``K`` and the first three rows of ``camera_T_world`` enter (the
    gradient with respect to the other entries is zero). The computation is a fused form of
    ``conic_bbox(project_dual_conic(dual_quadric(...)))`` written for speed (see the comment
    "project_bbox: a fused private path" in this module); the tests check that the two agree,
    gradients included. Its custom JVP serves both ``jvp``/``jacfwd`` and ``grad``/``jacrev``.
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    K, pose = _camera_args(K, camera_T_world)
    batch = _batch_shape(ellipsoid=batch, K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    dtype = jnp.result_type(rotation.dtype, K.dtype, pose.dtype)
    cast = lambda x, trailing: jnp.broadcast_to(x.astype(dtype), batch + trailing)
    return _project_bbox(
        cast(rotation, (3, 3)), cast(center, (3,)), cast(radii, (3,)), cast(K, (3, 3)), cast(pose, (4, 4))
    )


def texture_plane_depth(rotation, center, radii, camera_T_world):
    """Depth of the camera-facing tangent plane parallel to the image plane (eq. 4.11-4.12).

    Solving ``[0, 0, 1, -z] Q*_cam [0, 0, 1, -z]^T = 0`` gives ``z = t_z -+ sqrt(S33)``; the
    texture plane is the smaller root, ``t_z - sqrt(e3^T R_c diag(r^2) R_c^T e3)``.

    Args:
      rotation: (..., 3, 3); center: (..., 3); radii: (..., 3); camera_T_world: (..., 4, 4).

    Returns:
      depth: (...) metres along the optical axis (finite everywhere).
      valid: (...) bool, False where the plane is not in front of the camera (camera inside the
        ellipsoid, or the ellipsoid behind or straddling the image plane).
    """
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    (pose,) = _camera_args(None, camera_T_world, need_K=False)
    _batch_shape(ellipsoid=batch, camera_T_world=pose.shape[:-2])
    dtype = jnp.result_type(rotation.dtype, pose.dtype)
    pose = pose.astype(dtype)
    Rc, tc = camera_frame(rotation.astype(dtype), center.astype(dtype), pose)
    half_depth = safe_norm(radii.astype(dtype) * Rc[..., 2, :], axis=-1)
    depth = tc[..., 2] - half_depth
    valid = depth > _eps(dtype) * (jnp.abs(tc[..., 2]) + half_depth)
    return depth, valid


def camera_depth(center, camera_T_world, *, xp: Any = jnp):
    """Depth (camera z) of world points ``center`` (..., 3) seen from ``camera_T_world`` (..., 4, 4).
    ``xp``: ``jax.numpy`` (default) or ``numpy`` (host code)."""
    xp = _namespace(xp)
    center = _as_float_array("center", center, (3,), check_finite=True, xp=xp)
    pose = _as_float_array("camera_T_world", camera_T_world, (4, 4), check_finite=True, xp=xp)
    return xp.sum(pose[..., 2, :3] * center, axis=-1) + pose[..., 2, 3]


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


def ground_bounds(rotation, center, radii):
    """Footprint extent ``[x_min, y_min, x_max, y_max]`` (..., 4) of an ellipsoid seen from above."""
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    shape = _matmul3(rotation * jnp.square(radii)[..., None, :], jnp.swapaxes(rotation, -1, -2))
    hx = safe_sqrt(shape[..., 0, 0])
    hy = safe_sqrt(shape[..., 1, 1])
    cx, cy = center[..., 0], center[..., 1]
    return jnp.broadcast_to(jnp.stack([cx - hx, cy - hy, cx + hx, cy + hy], -1), batch + (4,))


def rasterize_footprint(rotation, center, radii, class_id, grid_shape, origin, resolution, mask=None):
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

    Returns:
      (H, W) int32 grid.
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
    rot = jnp.broadcast_to(rotation, batch + (3, 3)).reshape(-1, 3, 3)
    ctr = jnp.broadcast_to(center, batch + (3,)).reshape(-1, 3)
    rad = jnp.broadcast_to(radii, batch + (3,)).reshape(-1, 3)
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
    inside = (quad <= det[:, None, None]) & (det[:, None, None] > 0) & mask.reshape(-1)[:, None, None]
    values = jnp.where(inside, class_id.reshape(-1)[:, None, None], 0)
    return jnp.max(values, axis=0, initial=0).astype(jnp.int32)


# --------------------------------------------------------------------------------------------
# Sampling and rotations.


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


def quaternion_wxyz_to_rotation(quaternion_wxyz, *, xp: Any = jnp):
    """(..., 4) quaternion ``[w, x, y, z]`` (scalar first, jaxlie's order) -> (..., 3, 3) rotation.

    The quaternion is normalised here; a zero quaternion maps to the identity (a documented
    convention, e.g. for a network head before training). A non-finite concrete quaternion raises
    ``ValueError``; under ``jit`` a NaN propagates to the result (never a finite-looking matrix).
    """
    xp = _namespace(xp)
    q = _as_float_array("quaternion_wxyz", quaternion_wxyz, (4,), check_finite=True, xp=xp)
    return _quaternion_wxyz_to_rotation(q, xp)


def quaternion_xyzw_to_rotation(quaternion_xyzw, *, xp: Any = jnp):
    """(..., 4) quaternion ``[x, y, z, w]`` (scalar last: ROS, scipy, FAT's ``quaternion_xyzw``)
    -> (..., 3, 3) rotation. Same rules as :func:`quaternion_wxyz_to_rotation`."""
    xp = _namespace(xp)
    q = _as_float_array("quaternion_xyzw", quaternion_xyzw, (4,), check_finite=True, xp=xp)
    return _quaternion_wxyz_to_rotation(xp.roll(q, 1, axis=-1), xp)


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


def rotation_to_quaternion_wxyz(rotation, *, xp: Any = jnp):
    """(..., 3, 3) rotation -> (..., 4) unit quaternion ``[w, x, y, z]`` (scalar first) with ``w >= 0``.

    Shepperd's method: of the four algebraically equal formulas the one with the largest
    square-root argument is taken, so no branch divides by a small number.
    """
    xp = _namespace(xp)
    R = _as_float_array("rotation", rotation, (3, 3), xp=xp)
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


def random_rotation(key, shape: tuple = (), dtype=None):
    """Uniformly random rotations (..., 3, 3) from normalised Gaussian quaternions."""
    dtype = dtype or jnp.result_type(float)
    q = jax.random.normal(key, tuple(shape) + (4,), dtype=dtype)
    return _quaternion_wxyz_to_rotation(q)


def look_at(eye, target, up=(0.0, 0.0, 1.0), *, xp: Any = jnp):
    """``camera_T_world`` (..., 4, 4) of an OpenCV camera at ``eye`` looking at ``target``.

    The camera's z axis points at the target, its y axis down (against ``up``). When the view
    direction is parallel to ``up`` another up vector is used, so the result is always a rotation.
    """
    xp = _namespace(xp)
    eye = _as_float_array("eye", eye, (3,), xp=xp)
    target = _as_float_array("target", target, (3,), xp=xp)
    up = _as_float_array("up", up, (3,), xp=xp)
    dtype = xp.result_type(eye.dtype, target.dtype, up.dtype)
    eye, target, up = eye.astype(dtype), target.astype(dtype), up.astype(dtype)
    batch = _batch_shape(eye=eye.shape[:-1], target=target.shape[:-1], up=up.shape[:-1])
    for name, x in (("eye", eye), ("target", target), ("up", up)):
        if _is_concrete(x) and not bool(np.all(np.isfinite(np.asarray(x)))):
            raise ValueError(f"{name}: must be finite, got non-finite values (NaN or inf)")
    if _is_concrete(eye) and _is_concrete(target):
        gap = np.linalg.norm(np.asarray(target, np.float64) - np.asarray(eye, np.float64), axis=-1)
        if np.any(gap <= 0):
            raise ValueError("target: must differ from eye (the view direction is undefined)")
    if _is_concrete(up) and np.any(np.linalg.norm(np.asarray(up, np.float64), axis=-1) <= 0):
        raise ValueError("up: must be a non-zero vector")
    forward = target - eye
    forward = forward / xp.maximum(_safe_norm(forward, xp, keepdims=True), _eps(dtype))
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
    return xp.concatenate([top, bottom[..., None, :]], -2)


def rotation_to_quaternion_xyzw(rotation, *, xp: Any = jnp):
    """(..., 3, 3) rotation -> (..., 4) unit quaternion ``[x, y, z, w]`` (scalar last), ``w >= 0``."""
    xp = _namespace(xp)
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


def project_points(points, K, camera_T_world, *, xp: Any = jnp):
    """Pinhole projection of world points: ``uv = (K p_cam)[:2] / z``, with ``p_cam = camera_T_world p``.

    Args:
      points: (..., 3) world points.
      K: (..., 3, 3) intrinsics; camera_T_world: (..., 4, 4) (OpenCV axes).

    Returns:
      uv: (..., 2) pixels, finite everywhere (a point at or behind the principal plane is
        divided by a clamped depth, so its ``uv`` is meaningless: check ``depth``).
      depth: (...) camera z in metres; a point is in front of the camera iff ``depth > 0``.
    """
    xp = _namespace(xp)
    points = _as_float_array("points", points, (3,), check_finite=True, xp=xp)
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(points=points.shape[:-1], K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    dtype = xp.result_type(points.dtype, K.dtype, pose.dtype)
    p = _matvec(pose[..., :3, :3].astype(dtype), points.astype(dtype)) + pose[..., :3, 3].astype(dtype)
    pix = _matvec(K.astype(dtype), p)
    z = p[..., 2]
    z_safe = xp.where(xp.abs(z) > _eps(dtype), z, _eps(dtype))
    return pix[..., :2] / z_safe[..., None], z


def back_project(uv, depth, K, camera_T_world, *, xp: Any = jnp):
    """World points (..., 3) at camera depth ``depth`` (z, not range) on the rays through pixels ``uv``.

    The inverse of :func:`project_points`: ``project_points(back_project(uv, z, K, T), K, T)``
    gives back ``(uv, z)``.

    Args:
      uv: (..., 2) pixels; depth: (...) metres along the optical axis.
      K: (..., 3, 3) intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``; camera_T_world: (..., 4, 4).
    """
    xp = _namespace(xp)
    uv = _as_float_array("uv", uv, (2,), check_finite=True, xp=xp)
    depth = xp.asarray(depth)
    if _is_concrete(depth) and not bool(np.all(np.isfinite(np.asarray(depth)))):
        raise ValueError("depth: must be finite, got non-finite values (NaN or inf)")
    K, pose = _camera_args(K, camera_T_world, xp=xp)
    _batch_shape(uv=uv.shape[:-1], depth=depth.shape, K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    dtype = xp.result_type(uv.dtype, depth.dtype, K.dtype, pose.dtype, float)
    uv, depth, K, pose = uv.astype(dtype), depth.astype(dtype), K.astype(dtype), pose.astype(dtype)
    fx, s, cx = K[..., 0, 0], K[..., 0, 1], K[..., 0, 2]
    fy, cy = K[..., 1, 1], K[..., 1, 2]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    p_cam = xp.stack([x * depth, y * depth, xp.broadcast_to(depth, x.shape)], -1)
    # world p = R^T (p_cam - t)
    R = pose[..., :3, :3]
    return _matvec(xp.swapaxes(R, -1, -2), p_cam - pose[..., :3, 3])


def single_view_ellipsoid(box, K, camera_T_world, depth, radii):
    """Single-view initialisation of an ellipsoid from one box (thesis section 4.3.5).

    The centre lies on the ray through the box centre at camera depth ``depth`` (z, not range),
    the rotation is the identity (object axes = world axes) and the radii are ``radii``.
    ROSHAN's :func:`jaxsem.factors.single_view_init` chooses the depth (texture plane or default)
    and calls this.

    Args:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]``; K: (..., 3, 3); camera_T_world: (..., 4, 4);
      depth: (...) metres; radii: (..., 3) semi-axes.

    Returns:
      rotation (..., 3, 3), center (..., 3), radii (..., 3), broadcast to one batch shape.
    """
    box = _as_float_array("box", box, (4,), check_finite=True)
    radii = _as_float_array("radii", radii, (3,), check_finite=True)
    uv = 0.5 * (box[..., :2] + box[..., 2:])
    center = back_project(uv, depth, K, camera_T_world)
    batch = _batch_shape(center=center.shape[:-1], radii=radii.shape[:-1])
    center = jnp.broadcast_to(center, batch + (3,))
    rotation = jnp.broadcast_to(jnp.eye(3, dtype=center.dtype), batch + (3, 3))
    return rotation, center, jnp.broadcast_to(radii.astype(center.dtype), batch + (3,))


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
    ell, valid = project_bbox(rotation, center, radii, K, camera_T_world)
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


def stereo_right_T_left(baseline, dtype=jnp.float32):
    """``right_T_left`` (..., 4, 4) of a rectified stereo pair of ``baseline`` (...) metres: the right
    camera sits ``baseline`` along the left camera's +x, so a left-frame point ``p`` is
    ``p - [b, 0, 0]`` in the right frame."""
    b = jnp.asarray(baseline, dtype)
    T = jnp.broadcast_to(jnp.eye(4, dtype=dtype), b.shape + (4, 4))
    return T.at[..., 0, 3].set(-b)

"""What every module of the geometry core builds on (private to :mod:`jaxsem._geometry`).

Argument checks at the boundary (``ValueError`` naming the argument), the typed pytrees
:class:`Ellipsoid` and :class:`Camera`, and NaN-safe primitives. The public names are re-exported
by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import (
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
    check_positive as _check_positive,
    check_rotation as _check_rotation,
    is_concrete as _is_concrete,
)

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

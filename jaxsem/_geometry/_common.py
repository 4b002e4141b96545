"""What every module of the geometry core builds on (private to :mod:`jaxsem._geometry`).

Argument checks at the boundary (``ValueError`` naming the argument) and NaN-safe primitives
(the typed pytrees live in ``types.py``). The public names are re-exported
by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import (
    ROTATION_TOL as _ROTATION_TOL,
    as_float_array as _as_float_array,
    batch_shape as _batch_shape,
    check_positive as _check_positive,
    check_rigid as _check_rigid,
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
    _check_rigid("camera_T_world", pose)
    out.append(pose)
    return out


def _eager_compiled(kernel, static_argnums=()):
    """``kernel`` (a private core function of arrays, then shape-setting or namespace arguments
    at ``static_argnums``) called through one cached ``jax.jit`` program when every array argument
    is concrete, and called directly when one is traced (inside the user's ``jit``, ``vmap`` or
    ``grad``, where the caller's trace already compiles it) or the namespace is numpy.

    Why: a public core function called eagerly otherwise runs op by op, one dispatch per
    primitive (``project_bbox`` about 1,500 times slower eagerly than jitted). The public
    functions keep their eager argument checks in Python and only hand the kernel over.
    """
    jitted = jax.jit(kernel, static_argnums=static_argnums)

    @functools.wraps(kernel)
    def call(*args):
        if any(a is np for a in args) or any(not _is_concrete(a) for a in args):
            return kernel(*args)
        return jitted(*args)

    return call


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
# The same checks as masks, for traced values: each is a few elementwise operations on
# the trailing components, cheap next to the geometry it guards. Every public function with a
# ``valid`` output folds them in, so that under ``jit`` a bad input reads ``valid=False`` where an
# eager call raises ``ValueError``. They are False for NaN and inf (every comparison is).


def _check_tol(dtype) -> float:
    """Tolerance of the traced rotation and rigidity checks: the eager checks' ``ROTATION_TOL``
    (1e-3), widened to ``100 eps`` for dtypes coarser than float32 (float16: about 0.1)."""
    return max(_ROTATION_TOL, 100.0 * float(jnp.finfo(dtype).eps))


# Written on (...,) components, not with reductions over trailing (3, 3) axes: XLA:CPU then
# emits one elementwise loop (a reduction over small trailing axes made project_bbox 17 times
# slower in benchmarks/geometry.py's layout).


def _all(terms):
    out = terms[0]
    for t in terms[1:]:
        out = out & t
    return out


def _finite(x, ndim: int, xp: Any = jnp):
    """(...) bool: every entry of the trailing ``ndim`` (1 or 2) axes of ``x`` is finite."""
    if ndim == 1:
        return _all([xp.isfinite(x[..., i]) for i in range(x.shape[-1])])
    return _all([xp.isfinite(x[..., i, j]) for i in range(x.shape[-2]) for j in range(x.shape[-1])])


def _rotation_ok(R, xp: Any = jnp):
    """(...) bool for ``R`` (..., 3, 3): ``|R^T R - I| <= tol`` entrywise and ``det R > 0``
    (False for non-finite entries: every comparison with NaN is)."""
    tol = _check_tol(R.dtype)
    col = [[R[..., i, k] for i in range(3)] for k in range(3)]  # col[k][i] = R[i, k]
    terms = []
    for a in range(3):
        for b in range(a, 3):
            gram = col[a][0] * col[b][0] + col[a][1] * col[b][1] + col[a][2] * col[b][2]
            terms.append(xp.abs(gram - (1.0 if a == b else 0.0)) <= tol)
    c0, c1, c2 = col
    det = (
        c0[0] * (c1[1] * c2[2] - c1[2] * c2[1])
        - c1[0] * (c0[1] * c2[2] - c0[2] * c2[1])
        + c2[0] * (c0[1] * c1[2] - c0[2] * c1[1])
    )
    return _all(terms + [det > 0])


def _radii_ok(radii, xp: Any = jnp):
    """(...) bool for ``radii`` (..., 3): every semi-axis positive and finite."""
    return _all([(radii[..., i] > 0) & (radii[..., i] < xp.inf) for i in range(3)])


def _ellipsoid_ok(rotation, center, radii, xp: Any = jnp):
    """(batch) bool: a proper rotation, a finite centre, positive finite radii."""
    return _rotation_ok(rotation, xp) & _finite(center, 1, xp) & _radii_ok(radii, xp)


def _intrinsics_ok(K, xp: Any = jnp):
    """(...) bool for ``K`` (..., 3, 3): finite, with positive focal lengths ``fx``, ``fy`` and
    the zeros and one of ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (what the eager check asks;
    the closed forms read only the top rows, so a wrong bottom row would otherwise pass)."""
    tol = _check_tol(K.dtype)
    fixed = [xp.abs(K[..., 1, 0]) <= tol, xp.abs(K[..., 2, 0]) <= tol, xp.abs(K[..., 2, 1]) <= tol]
    fixed.append(xp.abs(K[..., 2, 2] - 1.0) <= tol)
    return _all([_finite(K, 2, xp), K[..., 0, 0] > 0, K[..., 1, 1] > 0] + fixed)


def _pose_ok(T, xp: Any = jnp):
    """(...) bool for ``T`` (..., 4, 4): finite and rigid (a proper rotation block, last row
    ``[0, 0, 0, 1]``)."""
    tol = _check_tol(T.dtype)
    last = [xp.abs(T[..., 3, j] - (1.0 if j == 3 else 0.0)) <= tol for j in range(4)]
    return _all([_finite(T, 2, xp), _rotation_ok(T[..., :3, :3], xp)] + last)


def _finite_or_zero(x, xp: Any = jnp):
    """``x`` with its non-finite entries replaced by 0: a function whose ``valid`` mask already
    says False for them (computed from the original) then returns finite values and gradients.
    The identity, value and gradient, on finite entries."""
    return xp.where(xp.isfinite(x), x, xp.zeros((), x.dtype))


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
    if x.shape[axis] == 3 and not keepdims and axis in (-1, x.ndim - 1):
        return _safe_sqrt(_sum3(xp.square(x)), xp)  # term by term, as _matvec_terms
    return _safe_sqrt(xp.sum(xp.square(x), axis=axis, keepdims=keepdims), xp)


def _matvec(m, v):
    """(..., 3, 3) @ (..., 3) as a broadcasted product and sum: fuses into elementwise loops.
    Written with array methods, so it serves numpy arrays as well as jax ones."""
    return (m * v[..., None, :]).sum(axis=-1)


def _matvec_terms(m, v):
    """:func:`_matvec` as broadcasted products summed term by term: elementwise loops only. On
    XLA:CPU a reduction over the size-3 axis becomes a slow reduction kernel of its own, most of
    all inside forward-mode Jacobians (a solver's linearisation). Used on those hot paths."""
    return m[..., :, 0] * v[..., None, 0] + m[..., :, 1] * v[..., None, 1] + m[..., :, 2] * v[..., None, 2]


def _matmul3(a, b):
    """(..., n, 3) @ (..., 3, k) summed term by term, as :func:`_matvec_terms`."""
    return (
        a[..., :, 0, None] * b[..., None, 0, :]
        + a[..., :, 1, None] * b[..., None, 1, :]
        + a[..., :, 2, None] * b[..., None, 2, :]
    )


def _sum3(x):
    """``x.sum(-1)`` of a (..., 3) array term by term, as :func:`_matvec_terms`."""
    return x[..., 0] + x[..., 1] + x[..., 2]


def _cross(a, b, xp: Any = jnp):
    return xp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )

"""Argument checks at the Python boundary, shared by the package (private to jaxsem).

Used by the geometry core (:mod:`jaxsem.quadrics`) and every other module that takes arrays from
a user: each failure is a ``ValueError`` naming the argument, its shape or value, and what was
expected. Only concrete values are checked; under ``jit`` the values are tracers and validity is
carried by masks and result codes instead. The config dataclasses check their fields' ranges with
:func:`check_fields`. This module imports nothing else of the package.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any, NoReturn

import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

__all__ = [
    "ROTATION_TOL",
    "MAX_BOX_SCALE",
    "as_float_array",
    "batch_shape",
    "check_box",
    "check_fields",
    "check_positive",
    "check_rigid",
    "check_rotation",
    "finite_nonnegative",
    "int_at_least",
    "is_concrete",
    "nonnegative",
    "positive",
    "require_type",
]

#: Tolerance of the rotation checks: ``|R^T R - I| <= ROTATION_TOL`` entrywise (and det R > 0).
#: Under ``jit`` the geometry core's masks use the same tolerance (widened for dtypes coarser than
#: float32), so an input accepted eagerly is also valid when traced.
ROTATION_TOL = 1e-3


def is_concrete(x) -> bool:
    return not isinstance(x, Tracer)


def as_float_array(name: str, x, trailing: Sequence[int], *, check_finite: bool = False, xp: Any = jnp):
    """``x`` as a floating array of shape ``(..., *trailing)``; ``ValueError`` naming ``name``.

    ``xp`` is the array namespace (``jax.numpy``, default, or ``numpy`` for host code: then the
    result is a numpy array, float64 unless ``x`` is already floating).
    jaxlie ``SO3`` / ``SE3`` objects are accepted where a (3, 3) or (4, 4) matrix is expected.
    Finiteness is checked only for concrete values (under ``jit`` the masks carry validity).
    """
    if hasattr(x, "as_matrix") and callable(x.as_matrix):  # jaxlie SO3 / SE3 at the boundary
        x = x.as_matrix()
    try:
        arr = xp.asarray(x)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to an array ({exc})") from None
    trailing = tuple(trailing)
    if arr.ndim < len(trailing) or tuple(arr.shape[arr.ndim - len(trailing) :]) != trailing:
        want = "(..., " + ", ".join(str(t) for t in trailing) + ")"
        raise ValueError(f"{name}: expected shape {want}, got shape {tuple(arr.shape)}")
    if jnp.issubdtype(arr.dtype, jnp.complexfloating):
        raise ValueError(f"{name}: expected a real floating array, got dtype {arr.dtype}")
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        try:
            arr = arr.astype(xp.result_type(float))
        except (TypeError, ValueError) as exc:  # numpy strings or objects
            raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if check_finite and is_concrete(arr):
        if not bool(np.all(np.isfinite(np.asarray(arr)))):
            raise ValueError(f"{name}: must be finite, got non-finite values (NaN or inf)")
    return arr


def batch_shape(**named: tuple) -> tuple:
    """Broadcast of several leading shapes; the error names every argument and its shape."""
    try:
        return tuple(np.broadcast_shapes(*named.values()))
    except ValueError:
        listing = ", ".join(f"{k} {tuple(v)}" for k, v in named.items())
        raise ValueError(f"batch shapes do not broadcast: {listing}") from None


def check_rotation(name: str, rotation) -> None:
    """Concrete ``rotation`` (..., 3, 3) must be a proper rotation: ``R^T R = I`` to
    :data:`ROTATION_TOL`, det > 0."""
    if not is_concrete(rotation):
        return
    R = np.asarray(rotation, np.float64)
    if R.size == 0:
        return
    err = np.abs(np.einsum("...ji,...jk->...ik", R, R) - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(R)
    bad = ~((err <= ROTATION_TOL) & (det > 0))  # NaN counts as bad
    if np.any(bad):
        i = np.unravel_index(int(np.argmax(bad)), bad.shape) if bad.ndim else ()
        raise ValueError(
            f"{name}: expected rotation matrices (R^T R = I, det R = +1), got one with "
            f"|R^T R - I| = {float(np.asarray(err)[i]):.3g} and det = {float(np.asarray(det)[i]):.3g}"
            + (f" at batch index {tuple(int(k) for k in i)}" if i else "")
        )


def check_rigid(name: str, transform) -> None:
    """Concrete ``transform`` (..., 4, 4) must be rigid: a proper rotation block (see
    :func:`check_rotation`) and the last row ``[0, 0, 0, 1]`` (to :data:`ROTATION_TOL`)."""
    if not is_concrete(transform):
        return
    T = np.asarray(transform, np.float64)  # numpy first: slicing a jax array eagerly dispatches ops
    if T.size == 0:
        return
    check_rotation(name, T[..., :3, :3])
    gap = np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    if not bool(np.all(gap <= ROTATION_TOL)):
        row = T.reshape(-1, 4, 4)[int(np.argmax(~(gap.reshape(-1) <= ROTATION_TOL))), 3]
        raise ValueError(f"{name}: expected a rigid transform with last row [0, 0, 0, 1], got {row.tolist()}")


def check_positive(name: str, x) -> None:
    if is_concrete(x) and np.asarray(x).size and not bool(np.all(np.asarray(x) > 0)):
        raise ValueError(f"{name}: expected positive values, got min {float(np.min(np.asarray(x))):.3g}")


MAX_BOX_SCALE = 10
"""A box wider or taller than this many times the image is refused (e.g. ``[0, 0, 1e9, 1e9]``)."""


def check_box(where: str, field: str, value, image_size) -> np.ndarray:
    """``value`` as a box ``[u_min, v_min, u_max, v_max]`` that overlaps the ``(W, H)`` image and is
    at most :data:`MAX_BOX_SCALE` times its size; else ``ValueError`` naming ``where`` and ``field``
    (a file and its JSON field, or a command-line flag and its entry). The one box rule of the
    package's readers: ``sequence.json``, TUM detections and the ``--boxes`` files."""

    def fail(message: str) -> NoReturn:
        raise ValueError(f"{where}: {field}: {message}")

    try:
        b = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        b = None
    if b is None or not (b.shape == (4,) and np.all(np.isfinite(b)) and b[2] > b[0] and b[3] > b[1]):
        fail(
            f"expected [u_min, v_min, u_max, v_max] (4 finite numbers, u_max > u_min, v_max > v_min), got {value!r:.80}"
        )
    W, H = image_size
    if b[2] <= 0 or b[3] <= 0 or b[0] >= W or b[1] >= H:
        fail(f"box {b.tolist()} lies outside the {W}x{H} image")
    if b[2] - b[0] > MAX_BOX_SCALE * W or b[3] - b[1] > MAX_BOX_SCALE * H:
        fail(
            f"box {b.tolist()} is over {MAX_BOX_SCALE} times the {W}x{H} image (a detection's box lies "
            "mostly in the image)"
        )
    return b


def require_type(name: str, value, kind: type) -> Any:
    """``value`` if it is a ``kind`` (a typed pytree of the core: ``Ellipsoid``, ``Camera``, ``Grid``),
    else a ``ValueError`` naming the argument and how to build one. The boundary check of every
    method-level function that takes a typed argument: loose arrays in its place are a call
    written for a loose signature, which would otherwise shift every later argument."""
    if isinstance(value, kind):
        return value
    fields = ", ".join(getattr(kind, "_fields", None) or [f.name for f in dataclasses.fields(kind)])
    raise ValueError(
        f"{name}: expected a jaxsem.quadrics.{kind.__name__}, got {type(value).__name__}; "
        f"build one as quadrics.{kind.__name__}({fields})"
    )


def check_fields(config, names: Iterable[str], expected: str, ok: Callable[[Any], bool], *, prefix: str = "") -> None:
    """The range check of a config dataclass's ``__post_init__``: each field of ``config`` named in
    ``names`` must pass ``ok``, else a ``ValueError`` naming the first that does not, as
    ``"{prefix}{name}: expected {expected}, got {value!r}"``. The predicates below are the ones
    several configs share."""
    for name in names:
        value = getattr(config, name)
        if not ok(value):
            raise ValueError(f"{prefix}{name}: expected {expected}, got {value!r}")


def int_at_least(low: int) -> Callable[[Any], bool]:
    """``ok`` of :func:`check_fields`: a Python or numpy int that is at least ``low``."""
    return lambda value: isinstance(value, (int, np.integer)) and bool(value >= low)


def finite_nonnegative(value) -> bool:
    """``ok`` of :func:`check_fields`: a finite Python number (or numpy float) >= 0."""
    return isinstance(value, (int, float)) and math.isfinite(value) and bool(value >= 0)


def positive(value) -> bool:
    """``ok`` of :func:`check_fields`: a value whose ``float`` is > 0 (NaN is not)."""
    return float(value) > 0


def nonnegative(value) -> bool:
    """``ok`` of :func:`check_fields`: a value whose ``float`` is >= 0 (NaN is not)."""
    return float(value) >= 0

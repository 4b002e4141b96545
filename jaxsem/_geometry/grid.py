"""Regular grids on the world plane: cell <-> world conversions and the :class:`Grid` pytree.

Grids are indexed ``[row, col] = [y, x]``. ``origin`` is the world (x, y) of the corner of cell
``[0, 0]`` and ``resolution`` is metres per cell, so the centre of cell ``[r, c]`` is
``origin + (c + 0.5, r + 0.5) * resolution`` and a world point lies in cell
``floor((y, x) - origin[::-1]) / resolution)``. The planner's maps, the object maps' top-down
grids and every dataset writer use these two functions; nothing else converts.

Host code passes ``xp=numpy`` (float64 arithmetic, int64 cells, no jax dispatch); the default is
``jax.numpy`` (int32 cells, traceable).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float_array, is_concrete
from ._common import _namespace


def _index_dtype(xp):
    return jnp.int32 if xp is jnp else np.int64


def _check_pairs(name, x, what):
    """A ValueError naming ``name`` unless its last axis holds pairs (a 3D point is a common slip:
    it would otherwise broadcast against the (2,) origin with an opaque message)."""
    if x.ndim < 1 or x.shape[-1] != 2:
        raise ValueError(f"{name}: expected shape (..., 2), {what}, got shape {tuple(x.shape)}")


def world_to_cell(xy, origin, resolution, xp=jnp):
    """World (x, y) (..., 2) -> integer cell (row, col) (..., 2): the cell the point lies in
    (floor; it may lie off the grid, see :func:`cell_in_grid`). int32 under jax, int64 under numpy.
    A last axis other than 2 (a 3D point: drop its z first) raises ValueError naming ``xy``.

    A coordinate that has no cell (non-finite ``xy`` or ``origin``, a ``resolution`` not positive
    and finite: possible under ``jit``, where nothing raises) gets the index ``-2**30`` (int32;
    ``-2**62`` in int64), off every grid, so :func:`cell_in_grid` reads False for it; an integer
    cast of NaN would otherwise give whatever the backend makes of it (0 on XLA's CPU: a cell on
    the grid). Indices are clipped to ``+-2**30`` (``+-2**62``), far beyond any grid, so that
    the cast never overflows.
    """
    xp = _namespace(xp)
    xy = xp.asarray(xy)
    _check_pairs("xy", xy, "world (x, y) points")
    if not xp.issubdtype(xy.dtype, xp.floating):
        xy = xy.astype(xp.result_type(float))
    origin = xp.asarray(origin, dtype=xy.dtype)
    _check_pairs("origin", origin, "a world (x, y) corner")
    resolution = xp.asarray(resolution, dtype=xy.dtype)
    cell = xp.floor((xy - origin) / resolution)
    big = float(2**30 if xp is jnp else 2**62)  # exact in float32 / float64
    placed = xp.isfinite(cell) & (resolution > 0)
    cell = xp.where(placed, xp.clip(cell, -big, big), -big)
    return cell.astype(_index_dtype(xp))[..., ::-1]


def cell_to_world(rc, origin, resolution, offset: float | jax.Array = 0.5, xp=jnp):
    """Cell (row, col) (..., 2) -> world (x, y) (..., 2) of the point ``offset`` cells into it
    along both axes (0.5: the centre; an array of (..., 2) offsets in [0, 1) for jittered points).
    The result has ``origin``'s floating dtype (float64 for a Python or int origin under x64)."""
    xp = _namespace(xp)
    origin = xp.asarray(origin)
    _check_pairs("origin", origin, "a world (x, y) corner")
    if not xp.issubdtype(origin.dtype, xp.floating):
        origin = origin.astype(xp.result_type(float))
    rc = xp.asarray(rc)
    _check_pairs("rc", rc, "(row, col) cells")
    offset = xp.asarray(offset, dtype=origin.dtype)
    return origin + (rc[..., ::-1].astype(origin.dtype) + offset) * xp.asarray(resolution, dtype=origin.dtype)


def cell_in_grid(rc, shape, xp=jnp):
    """(...,) bool: cell (row, col) (..., 2) lies on a grid of ``shape`` (H, W)."""
    xp = _namespace(xp)
    rc = xp.asarray(rc)
    h, w = (int(s) for s in shape)
    return (rc[..., 0] >= 0) & (rc[..., 0] < h) & (rc[..., 1] >= 0) & (rc[..., 1] < w)


def box_to_cells(box, origin, resolution, shape):
    """The cells a world box ``(x0, y0, x1, y1)`` (x0 <= x1, y0 <= y1) covers on a grid of
    ``shape`` (H, W), as the half-open ranges ``(r0, r1, c0, c1)`` (Python ints, clipped to the
    grid, ``r0 <= r1`` and ``c0 <= c1``): every cell whose open interior meets the closed box, so
    an edge lying on a cell boundary marks nothing past it. Host code (hand annotations)."""
    x0, y0, x1, y1 = (float(v) for v in box)
    ox, oy = (float(v) for v in np.asarray(origin, np.float64))
    res = float(resolution)
    h, w = (int(s) for s in shape)
    c0 = max(int(np.floor((x0 - ox) / res)), 0)
    r0 = max(int(np.floor((y0 - oy) / res)), 0)
    c1 = min(int(np.ceil((x1 - ox) / res)), w)
    r1 = min(int(np.ceil((y1 - oy) / res)), h)
    return r0, max(r1, r0), c0, max(c1, c0)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Grid:
    """A regular grid on the world plane, a pytree: ``origin`` (..., 2) world (x, y) of the corner
    of cell [0, 0] and ``resolution`` (...) metres per cell are leaves (batch axes may lead);
    ``shape`` (H, W) is static (it sets array shapes).

    The methods call this module's functions, so a grid converts as every other map does::

        grid = quadrics.Grid.create(origin=(-5.0, -5.0), resolution=0.1, shape=(100, 100))
        rc = grid.world_to_cell(xy)           # (..., 2) int32 (row, col)
        ok = grid.contains(rc)
        centres = grid.cell_to_world(rc)
    """

    origin: jax.Array | np.ndarray
    resolution: jax.Array | np.ndarray
    shape: tuple[int, int] = dataclasses.field(metadata={"static": True})

    @classmethod
    def create(cls, origin, resolution, shape) -> Grid:
        """Checked constructor: a finite (2,) origin, a finite positive resolution, (H, W) >= 1."""
        origin = as_float_array("origin", origin, (2,), check_finite=True)
        resolution = as_float_array("resolution", resolution, (), check_finite=True)
        if is_concrete(resolution) and not bool(np.all(np.asarray(resolution) > 0)):
            raise ValueError(f"resolution: expected metres per cell > 0, got {np.asarray(resolution)}")
        try:
            shape = tuple(int(s) for s in shape)
        except TypeError:
            raise ValueError(f"shape: expected (H, W) integers, got {shape!r}") from None
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape: expected (H, W) with H, W >= 1, got {shape}")
        return cls(jnp.asarray(origin), jnp.asarray(resolution, origin.dtype), (shape[0], shape[1]))

    @classmethod
    def host(cls, origin, resolution, shape) -> Grid:
        """:meth:`create` for host code (map files, numpy readers): the leaves are float64 numpy
        arrays, so a map's origin and resolution convert exactly whatever jax's default float
        is (under ``jit`` they become tracers as any numpy argument does)."""
        grid = cls.create(origin, resolution, shape)
        return cls(np.asarray(origin, np.float64), np.asarray(resolution, np.float64), grid.shape)

    @property
    def extent(self) -> jax.Array:
        """(..., 2) width and height in metres (x, y)."""
        return jnp.asarray((self.shape[1], self.shape[0]), self.resolution.dtype) * self.resolution[..., None]

    def world_to_cell(self, xy) -> jax.Array:
        """:func:`world_to_cell` on this grid (batch axes of the grid broadcast with ``xy``'s)."""
        return world_to_cell(xy, self.origin, self.resolution[..., None])

    def cell_to_world(self, rc, offset=0.5) -> jax.Array:
        """:func:`cell_to_world` on this grid."""
        return cell_to_world(rc, self.origin, self.resolution[..., None], offset)

    def contains(self, rc) -> jax.Array:
        """:func:`cell_in_grid` on this grid."""
        return cell_in_grid(rc, self.shape)

    def box_to_cells(self, box) -> tuple[int, int, int, int]:
        """:func:`box_to_cells` on this (unbatched, concrete) grid."""
        return box_to_cells(box, self.origin, self.resolution, self.shape)

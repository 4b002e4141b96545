"""Grid conventions shared by the planning world: class constants, the map state, conversions.

Grids are indexed ``[row, col] = [y, x]``. ``origin`` is the world (x, y) of the corner of cell
``[0, 0]`` and ``resolution`` is metres per cell, so the centre of cell ``[r, c]`` is
``origin + (c + 0.5, r + 0.5) * resolution``. World z is up; the robot moves on z = 0.
"""

from __future__ import annotations

import pathlib
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol, TypeAlias

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from .. import quadrics as Q
from .._files import MAX_CELLS as MAX_CELLS, read_text

# Semantic classes of the true world (int8). Walls, windows and exit signs are occupied cells;
# doors are free cells (open doorways).
NONE = 0
WALL = 1
DOOR = 2
WINDOW = 3
EXIT_SIGN = 4
SEMANTIC_NAMES = {NONE: "none", WALL: "wall", DOOR: "door", WINDOW: "window", EXIT_SIGN: "exit sign"}
#: Classes the object camera reports into the partial semantic map.
OBJECT_CLASSES = (DOOR, WINDOW, EXIT_SIGN)

# Partial occupancy map states (int8). Unknown is optimistically free for planning.
UNKNOWN = -1
FREE = 0
OCCUPIED = 1

DEFAULT_RESOLUTION = 0.1


class MapState(NamedTuple):
    """The robot's partial maps, a pytree (all leaves JAX arrays; batch axes may lead).

    occupancy: (..., H, W) int8 in {UNKNOWN, FREE, OCCUPIED}.
    semantic:  (..., H, W) int8, ``NONE`` where nothing has been seen, else one of
               ``OBJECT_CLASSES`` (door / window / exit sign) as seen by the object camera.
    """

    occupancy: jax.Array
    semantic: jax.Array


def empty_map_state(shape) -> MapState:
    """An all-unknown partial map of grid ``shape`` (H, W)."""
    shape = tuple(int(s) for s in shape)
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"shape: expected (H, W) with H, W >= 1, got {shape}")
    return MapState(occupancy=jnp.full(shape, UNKNOWN, jnp.int8), semantic=jnp.zeros(shape, jnp.int8))


def world_to_cell(xy, origin, resolution):
    """World (x, y) (..., 2) -> integer cell (row, col) (..., 2) (floor; may lie off the grid).
    The geometry core's :func:`jaxsem.quadrics.world_to_cell`."""
    return Q.world_to_cell(xy, origin, resolution)


def cell_to_world(rc, origin, resolution):
    """Cell (row, col) (..., 2) -> world (x, y) (..., 2) of the cell centre. The geometry core's
    :func:`jaxsem.quadrics.cell_to_world`."""
    return Q.cell_to_world(rc, origin, resolution)


def _grid(grid: Q.Grid, dtype) -> Q.Grid:
    """``grid`` with jax leaves of the points' ``dtype``: inside a jitted step (the PRM's, the
    sensors') a :func:`static_grid`'s values become constants, as the Python floats they are."""
    return Q.Grid(jnp.asarray(grid.origin, dtype), jnp.asarray(grid.resolution, dtype), grid.shape)


def static_grid(grid: Q.Grid) -> Q.Grid:
    """A host grid (:func:`host_grid`) as a static argument of a jitted step: Python-float leaves,
    so the grid hashes and its resolution stays a compile-time constant (it sets the step's
    array sizes, and the cell arithmetic is then the same as with the float it is)."""
    o = np.asarray(grid.origin, np.float64)
    return Q.Grid((float(o[0]), float(o[1])), float(grid.resolution), grid.shape)  # pyright: ignore[reportArgumentType]


class HasGrid(Protocol):
    """A map that holds its :class:`jaxsem.quadrics.Grid` (:class:`~jaxsem.planning.Building`,
    :class:`~jaxsem.planning.OccupancyGrid`, any ``GridMap``)."""

    @property
    def grid(self) -> Q.Grid: ...


#: What the planner's ``grid`` arguments take: a grid, or a map that holds one.
GridLike: TypeAlias = "Q.Grid | HasGrid"


def host_grid(name: str, grid: GridLike, shape=None) -> Q.Grid:
    """The Python-boundary check of a grid argument: ``grid`` a :class:`jaxsem.quadrics.Grid` or
    a map that holds one (``.grid``: :class:`~jaxsem.planning.Building`,
    :class:`~jaxsem.planning.OccupancyGrid`), returned with float64 numpy leaves (its resolution
    then sets the static sizes of the jitted steps); ``shape``: the (H, W) it must have (None: any).
    Anything else (a loose origin array) raises ``ValueError`` naming the argument."""
    g = getattr(grid, "grid", grid) if not isinstance(grid, Q.Grid) else grid
    if not isinstance(g, Q.Grid):
        raise ValueError(
            f"{name}: expected a jaxsem.quadrics.Grid (or a map with .grid: Building, OccupancyGrid), got "
            f"{type(grid).__name__}; build one as quadrics.Grid.host(origin, resolution, shape)"
        )
    if isinstance(g.origin, Tracer) or isinstance(g.resolution, Tracer):
        raise ValueError(f"{name}: expected a concrete grid at the Python boundary, got traced leaves")
    origin, resolution = np.asarray(g.origin, np.float64), np.asarray(g.resolution, np.float64)
    if origin.shape != (2,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"{name}: expected a finite (2,) origin, got {origin.tolist()}")
    if resolution.shape != () or not (np.isfinite(resolution) and resolution > 0):
        raise ValueError(f"{name}: expected a resolution > 0 metres per cell, got {resolution.tolist()}")
    if origin is not g.origin or resolution is not g.resolution:
        g = Q.Grid(origin, resolution, g.shape)
    if shape is not None and tuple(g.shape) != tuple(int(s) for s in shape):
        raise ValueError(f"{name}: expected a grid of shape {tuple(shape)} (the map's), got {g.shape}")
    return g


def read_text_as(path: pathlib.Path, parse: Callable[[str], Any], errors: tuple, what: str) -> Any:
    """``parse`` of the text file at ``path``; a one-line ``ValueError`` ("not a readable
    ``what``") when it cannot be read, decoded or parsed (``errors``: the parser's own
    exceptions), the check every map and annotation file goes through first. The file's size is
    bounded (:func:`jaxsem._files.read_text`) before it is read."""
    text = read_text(path, what)
    try:
        return parse(text)
    except errors as exc:  # a parser's message may span lines (YAML points at the column): one line
        raise ValueError(f"{path}: not a readable {what} ({' '.join(str(exc).split())})") from None


def check_grid(name: str, grid, dtype_kind: str, shape=None) -> np.ndarray:
    """Python-boundary check of a 2-D grid; returns it as numpy. ``dtype_kind``: 'bool' or 'int'."""
    try:
        arr = np.asarray(grid)
    except Exception as exc:  # pragma: no cover - exotic objects
        raise ValueError(f"{name}: cannot be converted to an array ({exc})") from None
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D grid (H, W), got shape {arr.shape}")
    if shape is not None and tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got shape {arr.shape}")
    if dtype_kind == "bool" and arr.dtype != np.bool_:
        raise ValueError(f"{name}: expected dtype bool, got dtype {arr.dtype}")
    if dtype_kind == "int" and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name}: expected an integer dtype (int8), got dtype {arr.dtype}")
    return arr


def check_point(name: str, xy, occupancy: np.ndarray, grid: Q.Grid) -> np.ndarray:
    """A world point (2,) that lies on ``grid`` (the cells of ``occupancy``) and in a free cell,
    else ``ValueError``."""
    try:
        p = np.asarray(xy, dtype=np.float64)
    except Exception as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if p.shape != (2,):
        raise ValueError(f"{name}: expected a world point (x, y) of shape (2,), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: must be finite, got {p.tolist()}")
    origin, resolution = np.asarray(grid.origin, np.float64), float(grid.resolution)
    rc = Q.world_to_cell(p, origin, resolution, xp=np)
    H, W = occupancy.shape
    if not Q.cell_in_grid(rc, (H, W), xp=np):
        raise ValueError(
            f"{name}: point {p.tolist()} (cell {rc.tolist()}) is off the map of {H}x{W} cells "
            f"with origin {origin.tolist()} and resolution {resolution}"
        )
    if occupancy[rc[0], rc[1]]:
        raise ValueError(f"{name}: point {p.tolist()} (cell {rc.tolist()}) lies in an occupied cell")
    return p

"""Ray-cast sensors with line of sight on the grid (jitted JAX).

Rays are marched at a fixed step (a fraction of a cell); a sample is *blocked* when its cell is
occupied or off the grid; the samples a ray sees are those up to and including its first blocked
sample, found with an argmax (no loop, so a whole fan of rays is one gather). Seen cells
take their true state:

- depth sensor (85.2 deg, 5 m): occupancy becomes FREE or OCCUPIED;
- object camera (69.4 deg, 10 m): doors (free cells the ray crosses), windows and exit signs
  (the occupied cells it stops at) are written into the partial semantic map.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from .. import quadrics as Q
from .._checks import require_type
from ._grid import DOOR, EXIT_SIGN, FREE, OCCUPIED, WINDOW, GridLike, MapState, _grid, host_grid, static_grid


class SensorConfig(NamedTuple):
    """Static sensor settings (hashable: changing one recompiles)."""

    depth_fov_deg: float = 85.2
    depth_range: float = 5.0
    object_fov_deg: float = 69.4
    object_range: float = 10.0
    rays: int = 192  # one fan over the wider field of view (0.45 deg apart: < a cell at 10 m)
    step_cells: float = 0.5  # march step as a fraction of a cell


def _samples(max_range, resolution, step_cells):
    return int(math.ceil(max_range / (resolution * step_cells)))


def _cast(occupancy, grid, xy, angles, max_range, n_samples):
    """Marches rays over ``occupancy`` on ``grid``; returns (rows, cols) (R, S) int32, visible
    (R, S), blocked (R, S), ranges (R,)."""
    H, W = occupancy.shape
    dtype = grid.origin.dtype
    step = max_range / n_samples
    t = (jnp.arange(n_samples, dtype=dtype) + 1.0) * step
    direction = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1).astype(dtype)  # (R, 2)
    pts = xy[None, None, :] + t[None, :, None] * direction[:, None, :]  # (R, S, 2)
    rc = Q.world_to_cell(pts, grid.origin, grid.resolution)
    rows, cols = rc[..., 0], rc[..., 1]
    on_map = Q.cell_in_grid(rc, (H, W))
    rows_c, cols_c = jnp.clip(rows, 0, H - 1), jnp.clip(cols, 0, W - 1)
    blocked = occupancy[rows_c, cols_c] | ~on_map
    # Seen: samples up to and including the first blocked one. The index of the first hit comes
    # from argmax, not a cumulative sum: XLA's CPU cumsum is a quadratic reduce-window (5x slower
    # here at 200 samples per ray).
    any_hit = jnp.any(blocked, -1)
    first = jnp.where(any_hit, jnp.argmax(blocked, axis=-1), n_samples)
    visible = jnp.arange(n_samples)[None, :] <= first[:, None]
    ranges = jnp.where(any_hit, t[jnp.minimum(first, n_samples - 1)], max_range)
    rows_out = jnp.where(on_map, rows, H)  # H: dropped by the scatter below
    return rows_out, cols_c, visible & on_map, blocked, ranges


def _fan(yaw, fov_deg, n_rays, dtype):
    half = 0.5 * math.radians(fov_deg)
    return yaw + jnp.linspace(-half, half, n_rays, dtype=dtype)


def sense(
    true_occupancy, true_semantic, state: MapState, pose, grid: GridLike, config: SensorConfig = SensorConfig()
) -> MapState:
    """Updates the partial maps with what both sensors see from ``pose``.

    true_occupancy: (H, W) bool; true_semantic: (H, W) int8 (class constants of the world);
    state: :class:`MapState` with (H, W) leaves; pose: (3,) world (x, y, yaw) in metres/radians;
    grid: the :class:`jaxsem.quadrics.Grid` of the true maps (or a map holding one, e.g. a
    :class:`~jaxsem.planning.Building`; concrete: its resolution sets the number of march
    samples and the sensors' window). Jitted; ``jax.vmap`` over ``state`` and ``pose``
    senses many robots at once. Returns the new :class:`MapState`.
    """
    # Cheap conversions only (numpy in, jit converts at dispatch): this wrapper runs every step
    # and a jnp.asarray per argument cost more than the sensing itself.
    dtype = np.dtype(jnp.result_type(float))
    _check_true_maps(true_occupancy, true_semantic)
    grid = host_grid("grid", grid, np.shape(true_occupancy))
    pose = _host_or_jax(pose, dtype)
    if tuple(pose.shape[-1:]) != (3,):
        raise ValueError(f"pose: expected shape (..., 3) = (x, y, yaw), got shape {tuple(pose.shape)}")
    occ_shape = tuple(np.shape(true_occupancy))
    for name, leaf in (("state.occupancy", state.occupancy), ("state.semantic", state.semantic)):
        if tuple(leaf.shape[-2:]) != occ_shape or leaf.dtype != jnp.int8:
            raise ValueError(
                f"{name}: expected int8 (..., {occ_shape[0]}, {occ_shape[1]}) like "
                f"true_occupancy, got shape {tuple(leaf.shape)} dtype {leaf.dtype}"
            )
    if not (isinstance(true_semantic, jax.Array) and true_semantic.dtype == jnp.int8):
        true_semantic = np.asarray(true_semantic, np.int8)
    return _sense_jit(
        true_occupancy, true_semantic, state, pose, static_grid(grid), config, **_sense_sizes(grid, config)
    )


def _sense_sizes(grid: Q.Grid, config: SensorConfig) -> dict:
    """The static sizes of :func:`_sense_jit` that a host ``grid``'s resolution sets: the half
    width of the sensors' window and the march samples per ray, in cells."""
    resolution = _check_resolution(grid.resolution)
    max_range = max(config.depth_range, config.object_range)
    return {
        "half": int(math.ceil(max_range / resolution)) + 2,
        "n_s": _samples(max_range, resolution, config.step_cells),
    }


def _host_or_jax(x, dtype):
    if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating):
        return x.astype(dtype) if x.dtype != dtype else x
    return np.asarray(x, dtype)


def _check_resolution(resolution):
    try:
        r = float(resolution)
    except TypeError:
        raise ValueError(
            f"resolution: expected a Python float (metres per cell), got {type(resolution).__name__}"
        ) from None
    if not (r > 0 and math.isfinite(r)):
        raise ValueError(f"resolution: expected a positive finite float, got {resolution!r}")
    return r


def _check_true_maps(true_occupancy, true_semantic):
    if isinstance(true_occupancy, Tracer):
        return
    occ = np.asarray(true_occupancy) if not isinstance(true_occupancy, jax.Array) else true_occupancy
    if occ.ndim != 2 or occ.dtype != np.bool_:
        raise ValueError(f"true_occupancy: expected a (H, W) bool grid, got shape {tuple(occ.shape)} dtype {occ.dtype}")
    sem = true_semantic
    if not isinstance(sem, Tracer):
        sem = np.asarray(sem) if not isinstance(sem, jax.Array) else sem
        if tuple(sem.shape) != tuple(occ.shape) or not np.issubdtype(sem.dtype, np.integer):
            raise ValueError(
                f"true_semantic: expected an integer (H, W) grid of shape {tuple(occ.shape)}, got "
                f"shape {tuple(sem.shape)} dtype {sem.dtype}"
            )


def _sense_impl(true_occupancy, true_semantic, state, pose, grid, config, *, half, n_s):
    if pose.ndim > 1:  # a batch of robots, each with its own state
        fn = lambda s, p: _sense_one(true_occupancy, true_semantic, s, p, grid, config, half, n_s)
        return jax.vmap(fn)(state, pose)
    return _sense_one(true_occupancy, true_semantic, state, pose, grid, config, half, n_s)


_sense_jit = functools.partial(jax.jit, static_argnames=("grid", "config", "half", "n_s"))(_sense_impl)

#: :func:`_sense_jit` that updates ``state`` in place (its buffers are donated, so the caller
#: must own them and not read them again): the navigation loop's, where a copy of the whole
#: partial map at every step cost more than the sensing. A buffer that numpy still views is
#: copied instead (JAX does not donate it).
_sense_in_place = functools.partial(
    jax.jit, static_argnames=("grid", "config", "half", "n_s"), donate_argnames=("state",)
)(_sense_impl)


def _sense_one(true_occupancy, true_semantic, state, pose, grid, config, half, n_s):
    """One robot's sensing on ``grid`` (a :func:`static_grid`); ``half``, ``n_s``:
    :func:`_sense_sizes` (static)."""
    H, W = true_occupancy.shape
    xy, yaw = pose[:2], pose[2]
    dtype = jnp.result_type(float)
    grid = _grid(grid, dtype)
    # Work in a window that holds every cell the sensors can reach: the full-grid updates would
    # otherwise dominate (a building map has ~2e5 cells, the sensors see a few thousand).
    max_range = max(config.depth_range, config.object_range)
    wh, ww = min(2 * half + 1, H), min(2 * half + 1, W)
    rc = Q.world_to_cell(xy, grid.origin, grid.resolution)
    start = jnp.clip(rc - half, 0, jnp.array([H - wh, W - ww], jnp.int32))
    win = lambda g: jax.lax.dynamic_slice(g, (start[0], start[1]), (wh, ww))
    occ_t, sem_t = win(true_occupancy), win(true_semantic)
    occ, sem = win(state.occupancy), win(state.semantic)
    window = Q.Grid(Q.cell_to_world(start, grid.origin, grid.resolution, offset=0.0), grid.resolution, (wh, ww))

    # One fan covering the wider field of view out to the longer range; each sensor keeps the
    # samples inside its own cone and range.
    wide = max(config.depth_fov_deg, config.object_fov_deg)
    n_rays = config.rays
    angles = _fan(yaw, wide, n_rays, dtype)
    rows, cols, vis, _, _ = _cast(occ_t, window, xy, angles, max_range, n_s)
    t = (jnp.arange(n_s, dtype=dtype) + 1.0) * (max_range / n_s)
    rel = jnp.abs(angles - yaw)[:, None]
    eps = 1e-6
    in_depth = (rel <= 0.5 * math.radians(config.depth_fov_deg) + eps) & (t <= config.depth_range + eps)
    in_obj = (rel <= 0.5 * math.radians(config.object_fov_deg) + eps) & (t <= config.object_range + eps)
    # One scatter for both sensors (bit 0: depth, bit 1: object camera): scatters dominate here.
    code = (vis & in_depth).astype(jnp.uint8) + 2 * (vis & in_obj).astype(jnp.uint8)
    hits = jnp.zeros((wh, ww), jnp.uint8).at[rows, cols].max(code, mode="drop")
    seen, seen_obj = (hits & 1) > 0, (hits & 2) > 0
    # The robot's own cell is known (it stands there).
    seen = seen.at[rc[0] - start[0], rc[1] - start[1]].set(True, mode="drop")
    truth = jnp.where(occ_t, OCCUPIED, FREE).astype(occ.dtype)
    occ = jnp.where(seen, truth, occ)
    is_object = (sem_t == DOOR) | (sem_t == WINDOW) | (sem_t == EXIT_SIGN)
    sem = jnp.where(seen_obj & is_object, sem_t.astype(sem.dtype), sem)
    return MapState(
        jax.lax.dynamic_update_slice(state.occupancy, occ, (start[0], start[1])),
        jax.lax.dynamic_update_slice(state.semantic, sem, (start[0], start[1])),
    )


def cast_rays(occupancy, grid: Q.Grid, xy, angles, max_range):
    """Ranges (R,) to the first occupied (or off-grid) cell along each ray, ``max_range`` if none.

    occupancy: (H, W) bool on ``grid`` (a concrete :class:`jaxsem.quadrics.Grid`: its resolution
    sets the number of march samples); xy: (2,) world start; angles: (R,) world headings in
    radians. Marched at half a cell, so a range is exact to half a cell. Jitted per (shape, ranges).
    """
    grid = require_type("grid", grid, Q.Grid)
    if tuple(grid.shape) != tuple(np.shape(occupancy)):
        raise ValueError(f"grid: expected occupancy's shape {tuple(np.shape(occupancy))}, got {grid.shape}")
    resolution = _check_resolution(grid.resolution)
    dtype = jnp.result_type(float)
    n = _samples(float(max_range), resolution, 0.5)
    return _cast_ranges(
        jnp.asarray(occupancy),
        static_grid(grid),
        jnp.asarray(xy, dtype),
        jnp.asarray(angles, dtype),
        float(max_range),
        n,
    )


@functools.partial(jax.jit, static_argnames=("grid", "max_range", "n"))
def _cast_ranges(occupancy, grid, xy, angles, max_range, n):
    return _cast(occupancy, _grid(grid, xy.dtype), xy, angles, max_range, n)[4]

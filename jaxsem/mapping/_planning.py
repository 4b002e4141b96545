"""Glue between object maps and the LSD planner of :mod:`jaxsem.planning` (thesis 5.8.3)."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from .._checks import require_type
from ..quadrics import Grid
from ._store import semantic_grid

__all__ = ["object_map_sampler", "with_object_map"]


def with_object_map(state, objects, grid: Grid):
    """A :class:`jaxsem.planning.MapState` whose semantic channel is the object map's raster.

    state: the robot's partial maps (its occupancy is kept); objects: :class:`ObjectMap` or
    :class:`Ellipsoids`; grid: the occupancy grid's :class:`jaxsem.quadrics.Grid` (e.g.
    ``building.grid``), of the state's shape.
    """
    shape = tuple(state.occupancy.shape[-2:])
    if tuple(require_type("grid", grid, Grid).shape) != shape:
        raise ValueError(f"grid: expected the state's shape {shape}, got {grid.shape}")
    return state._replace(semantic=semantic_grid(objects, grid))


def object_map_sampler(sampler: Callable, semantic) -> Callable:
    """Wraps an LSD sampler so that it sees ``semantic`` (H, W), e.g. an object map's raster,
    instead of the semantic crop of the robot's own object camera.

    sampler: a function of :class:`jaxsem.planning.LocalInputs` (such as
    :class:`jaxsem.lsd.LSDSampler`); semantic: (H, W) int8 on the navigation grid. The crop is
    the one ``jaxsem.planning.local_inputs`` takes: centred on ``inputs.center_cell`` (crop cell
    [size // 2, size // 2]), ``NONE`` off the map. Returns a sampler for
    :func:`jaxsem.planning.navigate` / :class:`jaxsem.planning.Trial`.
    """
    semantic = jnp.asarray(semantic, jnp.int8)
    if semantic.ndim != 2:
        raise ValueError(f"semantic: expected an (H, W) grid, got shape {tuple(semantic.shape)}")

    def wrapped(inputs):
        size = int(inputs.semantic.shape[-1])
        crop = _crop_jit(semantic, jnp.asarray(inputs.center_cell, jnp.int32), size)
        return sampler(inputs._replace(semantic=crop))

    return wrapped


def _crop_impl(semantic, center_cell, size):
    sem = jnp.pad(semantic, size, constant_values=0)  # 0 = NONE off the map
    r0 = center_cell[0] - size // 2 + size
    c0 = center_cell[1] - size // 2 + size
    return jax.lax.dynamic_slice(sem, (r0, c0), (size, size))


_crop_jit = jax.jit(_crop_impl, static_argnames=("size",))

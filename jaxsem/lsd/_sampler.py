"""The LSD network as the planner's sampling distribution (thesis 3.2.5).

:class:`LSDSampler` is the ``sampler`` callable of :func:`jaxsem.planning.navigate`: it takes the
robot-centred :class:`jaxsem.planning.LocalInputs` (160 x 160 crops + context) and returns the
network's probabilities over the window. The planner reads the window as the full map's
distribution (cells outside it get the window's minimum, then everything is renormalised:
:func:`jaxsem.planning.embed_local_distribution`, held as its window by
:class:`jaxsem.planning.LocalDistribution`), samples PRM vertices from it and weights edges by the
integral of ``-log p`` (``NavConfig.edge_weight='neglogp'``, eq. 3.3).
:func:`full_map_distribution` does the same embedding for a map state, for figures and users;
:func:`full_map_sampler` wraps a sampler to see the true map in its window (the oracle's use).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics as Q
from ..models import LSDNet, lsd_distribution
from ..planning import DEFAULT_RESOLUTION, embed_local_distribution, local_inputs
from ._expert import full_map_state


class LSDSampler:
    """``sampler(inputs) -> (k, k)`` probabilities from a trained LSD network (dropout off).

    model, params: the network and its parameters; use_context: False gives the general
    (stage one) distribution; uniform_mix: weight of a uniform distribution mixed into the
    network's (0 = the thesis' rule; a small value keeps every cell reachable by sampling even
    when the network is very confident). The forward pass is jitted once per input shape.
    cell_size: metres per cell of the maps the network was trained on (``meta["cell_size"]`` of
    :func:`jaxsem.lsd.load_model`; 0.1 m for every shipped model): :func:`jaxsem.planning.navigate`
    refuses a map whose cells differ (its 160-cell window would cover other metres than in
    training, and the network's distributions lose their edge) unless ``NavConfig.sampler_scale``
    says which cells the sampler sees.
    """

    def __init__(
        self,
        model: LSDNet,
        params,
        use_context: bool = True,
        uniform_mix: float = 0.0,
        cell_size: float = DEFAULT_RESOLUTION,
    ):
        if not 0.0 <= float(uniform_mix) < 1.0:
            raise ValueError(f"uniform_mix: expected in [0, 1), got {uniform_mix}")
        if not (math.isfinite(float(cell_size)) and float(cell_size) > 0):
            raise ValueError(f"cell_size: expected metres per cell > 0, got {cell_size}")
        self.cell_size = float(cell_size)
        self.model, self.params = model, params
        self.use_context, self.uniform_mix = bool(use_context), float(uniform_mix)
        self._dtype = jax.tree_util.tree_leaves(params)[0].dtype
        mix = self.uniform_mix

        def fn(p, occ, sem, ctx):
            prob = lsd_distribution(model, p, occ, sem, ctx, use_context=self.use_context)
            n = prob.shape[-1] * prob.shape[-2]
            return (1.0 - mix) * prob + mix / n

        self._fn = jax.jit(fn)

    def on_device(self, device) -> LSDSampler:
        """The same sampler with its parameters placed on ``device`` (a :class:`jax.Device`), so
        its forward pass runs there (:func:`jaxsem.lsd.run_trials` with a mesh); the jitted
        forward function is shared."""
        if not isinstance(device, jax.Device):
            raise ValueError(f"device: expected a jax.Device, got {device!r}")
        out = copy.copy(self)
        out.params = jax.device_put(self.params, device)
        return out

    def __call__(self, inputs) -> jax.Array:
        ctx = jnp.asarray(inputs.context, self._dtype)
        return self._fn(self.params, jnp.asarray(inputs.occupancy), jnp.asarray(inputs.semantic), ctx)


def full_map_distribution(
    sampler: LSDSampler, state, xy, goal, goal_outdoors: bool, grid: Any, max_distance: float = 20.0
) -> np.ndarray:
    """The planner's full-map distribution (H, W) (sums to 1) at robot position ``xy``.

    state: :class:`jaxsem.planning.MapState`; xy, goal: (2,) world (x, y); goal_outdoors: the
    context flag; grid: the state's :class:`jaxsem.quadrics.Grid` (or a map holding one). Crops and context exactly as in the online loop.
    """
    inputs = local_inputs(state, xy, goal, goal_outdoors, grid, sampler.model.config.map_size, max_distance)
    local = sampler(inputs)
    return np.asarray(embed_local_distribution(local, inputs.center_cell, state.occupancy.shape))


def full_map_sampler(sampler, world, max_distance: float = 20.0):
    """A sampler that gives ``sampler`` the *true* map's crops at the robot's window in place of
    its partial map's (the goal context unchanged): the fully supervised oracle network
    (trained on :func:`~jaxsem.lsd.with_full_map` crops) in the online loop, a diagnostic of how
    much shorter the drives of a network that saw the building around it would be. It still
    sees only its window, and the planner still plans on the robot's partial map.

    sampler: ``sampler(LocalInputs) -> (k, k)`` (e.g. an :class:`LSDSampler` of the oracle);
    world: the trial's world (a :class:`jaxsem.planning.Building`: ``occupancy``, ``semantic``,
    ``origin``, ``resolution``). For ``NavConfig.sampler_scale`` 1 (the window's centre cell is
    read as a cell of ``world``)."""
    state = full_map_state(world)
    origin = np.asarray(world.origin, np.float64)
    res = float(world.resolution)
    grid = Q.Grid.host(origin, res, state.occupancy.shape)

    def fn(inputs):
        centre = np.asarray(inputs.center_cell, np.float64)
        xy = Q.cell_to_world(centre, origin, res, xp=np)  # the centre cell's middle, world (x, y)
        size = int(np.shape(inputs.occupancy)[-1])
        true = local_inputs(state, xy, xy, False, grid, size, max_distance)
        return sampler(inputs._replace(occupancy=true.occupancy, semantic=true.semantic))

    return fn

"""Batch SLAM evaluation over every device: :func:`solve_maps` splits a batch of maps over a
one-axis mesh with :func:`jaxsem.parallel.sharded_vmap` (what ``jax.vmap(solve_batch)`` computes
on one device)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from jax.sharding import Mesh

from .. import parallel
from ._batch import SolveInfo, solve_batch
from ._problem import SlamEstimate, SlamProblem
from ._solver_config import SolverConfig


@functools.lru_cache(maxsize=32)
def _solve_maps_fn(mesh: Mesh, method: str, shard_method: str) -> Callable:
    def one(problem, init, config):
        return solve_batch(problem, init, config, method=method)

    return parallel.sharded_vmap(one, mesh, in_axes=(0, 0, None), method=shard_method)


def solve_maps(
    problems: SlamProblem,
    inits: SlamEstimate,
    config: SolverConfig | None = None,
    mesh: Mesh | None = None,
    *,
    method: str = "schur",
    shard_method: str = "shard_map",
) -> tuple[SlamEstimate, SolveInfo]:
    """Batch SLAM evaluation over every device: solves each map of a batch with
    :func:`solve_batch`, the maps split over ``mesh`` (default :func:`jaxsem.parallel.data_mesh`).

    Args:
      problems, inits: a batch of maps (every leaf with the same leading axis ``B``, e.g.
        ``jax.vmap(sim.to_problem)`` and ``jax.vmap(sim.initial_estimate)`` of
        :func:`jaxsem.slam.sim.simulate_batch`); ``B`` need not divide by the device count (padded by
        repeating the last map, the copies dropped).
      config: :class:`SolverConfig` shared by every map (default ROSHAN's); passed
        as a replicated pytree, so its traced fields do not recompile.
      method: ``solve_batch``'s solver (``"schur"`` or ``"optimistix"``).
      shard_method: :func:`jaxsem.parallel.sharded_vmap`'s method (``"shard_map"``: each device's solver loop stops
        when that device's maps are done).

    Returns:
      ``(estimates, infos)`` batched along ``B``: what ``jax.vmap(lambda p, i: solve_batch(p, i,
      config))(problems, inits)`` returns on one device. Per map the solve is the same program; a
      vmapped solver loop runs each map with the others of its batch, so results agree with a
      whole-batch vmap to the solver's own batch-dependence, and with a vmap over each device's
      slice to floating-point rounding, which XLA's compilation of the two programs decides and
      an unconverged solve can amplify (``tests/integration/test_parallel_training.py`` checks tightly
      converged solves).
    """
    if method not in ("schur", "optimistix"):
        raise ValueError(f"method: expected 'schur' or 'optimistix', got {method!r}")
    if shard_method not in ("shard_map", "jit"):
        raise ValueError(f"shard_method: expected 'shard_map' or 'jit', got {shard_method!r}")
    config = SolverConfig() if config is None else config
    fn: Any = _solve_maps_fn(parallel.data_mesh() if mesh is None else mesh, method, shard_method)
    return fn(problems, inits, config)

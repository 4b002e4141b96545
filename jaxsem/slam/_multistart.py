"""Several starting headings per object, the best kept per object: :func:`solve_yaw_starts`.

Boxes alone barely constrain an object's heading about the vertical, and the single-view
initialisation starts every object at the identity: LM then settles in the nearest basin.
Objects on a desk or a road stand upright in a gravity-aligned world (any VIO knows gravity), so
only the heading is open: solve from a few headings about ``up``, keep for each object the one
with the lowest cost of its own factors, and polish everything jointly from that start. It costs
one vmapped solve per heading; on LM-O's real desk it did not lower the orientation error
(``benchmarks/roshan/HISTORY.md``, "ROSHAN on the real LM-O desk"), so no solver uses it by
default.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._batch import solve_schur
from ._cost import residual_blocks
from ._problem import SlamEstimate, SlamProblem
from ._solver_config import SolverConfig

__all__ = ["object_costs", "solve_yaw_starts"]


def object_costs(problem: SlamProblem, estimate: SlamEstimate, config: SolverConfig):
    """(J,) ``0.5 * sum(r**2)`` of each object's own factors (its boxes and texture planes, its
    shape prior) at ``estimate``; zero for masked objects."""
    blocks = residual_blocks(problem, estimate, config)
    boxes, shapes = blocks[0], blocks[2]
    J = problem.object_class.shape[0]
    per_box = 0.5 * jnp.sum(boxes**2, axis=-1) * problem.box_mask.astype(boxes.dtype)
    cost = jax.ops.segment_sum(per_box, problem.box_object, num_segments=J)
    return jnp.where(problem.object_mask, cost + 0.5 * jnp.sum(shapes**2, axis=-1), 0.0)


def _about(axis, angle):
    """Rotation (3, 3) by ``angle`` (radians) about the unit ``axis`` (Rodrigues)."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]], axis.dtype)
    return jnp.eye(3, dtype=axis.dtype) + jnp.sin(angle) * k + (1.0 - jnp.cos(angle)) * (k @ k)


def solve_yaw_starts(
    problem: SlamProblem,
    init: SlamEstimate,
    config: SolverConfig,
    yaws_deg=(0.0, 45.0, 90.0, 135.0),
    up=(0.0, 0.0, 1.0),
):
    """``(estimate, info, start)``: :func:`jaxsem.slam._batch.solve_schur` from ``init`` with every
    object turned by each of ``yaws_deg`` about the world's ``up`` (one vmapped solve), then per
    object the start whose solve gave its own factors the lowest cost (:func:`object_costs`),
    the poses of the start with the lowest total cost, and one joint solve from there.
    ``start`` (J,) is the index of the heading kept for each object. Jittable (``yaws_deg`` and
    ``up`` are static tuples under ``jax.jit(..., static_argnames=...)`` or plain constants).

    Raises:
      ValueError: an empty ``yaws_deg`` or an ``up`` that is not a non-zero 3-vector.
    """
    yaws = jnp.radians(jnp.asarray(yaws_deg, init.center.dtype)).reshape(-1)
    if yaws.shape[0] == 0:
        raise ValueError("yaws_deg: expected at least one heading")
    axis = jnp.asarray(up, init.center.dtype).reshape(-1)
    if axis.shape != (3,):
        raise ValueError(f"up: expected a 3-vector, got shape {axis.shape}")
    axis = axis / jnp.maximum(jnp.linalg.norm(axis), jnp.finfo(axis.dtype).tiny)

    def start(yaw):
        turn = _about(axis, yaw)
        return SlamEstimate(init.camera_T_world, turn @ init.rotation, init.center, init.radii)

    inits = jax.vmap(start)(yaws)
    ests, _ = jax.vmap(solve_schur, in_axes=(None, 0, None))(problem, inits, config)
    costs = jax.vmap(object_costs, in_axes=(None, 0, None))(problem, ests, config)  # (S, J)
    best = jnp.argmin(costs, axis=0)
    J = best.shape[0]
    pick = lambda x: x[best, jnp.arange(J)]
    totals = jax.vmap(lambda e: sum(jnp.sum(b**2) for b in residual_blocks(problem, e, config)))(ests)
    poses = ests.camera_T_world[jnp.argmin(totals)]
    merged = SlamEstimate(poses, pick(ests.rotation), pick(ests.center), pick(ests.radii))
    est, info = solve_schur(problem, merged, config)
    return est, info, best

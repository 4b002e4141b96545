"""jaxls (brentyi/jaxls, the JAX nonlinear least-squares library) on jaxsem's SLAM problems.

The JAX anchor of ``roshan_vs_quadricslam.py``: the same factors, written as jaxls costs that call
jaxsem's own residual rows (``jaxsem.slam.box_rows`` / ``jaxsem.slam.pose_rows``), so both
libraries minimise exactly the same function of the same variables:

- camera poses: ``jaxls.SE3Var`` holding ``camera_T_world``, retracted on the right
  (``T @ exp(d)``), as ``jaxsem.slam.retract_pose``;
- object rotations: ``jaxls.SO3Var`` (``R @ exp(w)``, as ``jaxsem.slam.retract_object``);
- object centre and radii parameters: one 6-vector (``[c, factors.param_from_radii(r)]``).

Every pose, object and box slot of the padded ``SlamProblem`` becomes a variable or a cost (box
slots carry their mask into the residual, which zeroes it), so problems of one padded size share
one compiled solve. jaxls' own defaults otherwise: Levenberg-Marquardt with its trust region,
the conjugate-gradient linear solver with its automatic Schur elimination (it eliminates the
poses: a 90-dimensional reduced system for 10 objects), ``TerminationConfig()`` (relative cost
change 1e-5, at most 100 iterations).

jaxls is not a jaxsem dependency: install it from its public source (the brentyi/jaxls
repository's ``src/`` tree with ``pip install --no-deps``; measured at commit 50a58be).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from jaxsem import factors as F, slam
from jaxsem.slam._cost import box_rows, pose_rows  # layers: white-box

try:
    import jaxls
    from loguru import logger

    logger.disable("jaxls")  # its INFO lines on every analyse
except ImportError:  # pragma: no cover - optional peer
    jaxls = None


def available() -> bool:
    return jaxls is not None


def _var_types():
    class ObjectVec(jaxls.Var[jax.Array], default_factory=lambda: jnp.zeros(6)):
        """An object's centre (3) and radii parameters (3)."""

    return jaxls.SE3Var, jaxls.SO3Var, ObjectVec


_TYPES = None


def _types():
    global _TYPES
    if _TYPES is None:
        _TYPES = _var_types()
    return _TYPES


def build(problem: slam.SlamProblem, init: slam.SlamEstimate, config: slam.SolverConfig):
    """``(analysed jaxls problem, initial values)`` of one (unbatched) padded problem."""
    PoseVar, RotVar, VecVar = _types()
    T = problem.pose_prior.shape[0]
    J = init.center.shape[0]
    K, size = problem.K, problem.image_size

    def box_cost(vals, pv, rv, vv, box, td, tm, bm):
        v = vals[vv]
        return box_rows(
            vals[pv].as_matrix(),
            vals[rv].as_matrix(),
            v[:3],
            F.radii_from_param(v[3:]),
            box,
            td,
            tm,
            bm,
            K,
            size,
            config,
        )

    def prior_cost(vals, pv, prior, pm):
        return pose_rows(vals[pv].as_matrix(), prior, pm, config)

    bp, bo = problem.box_pose, problem.box_object
    bm = problem.box_mask & problem.object_mask[bo] & problem.pose_mask[bp]
    poses, objs = jnp.arange(T), jnp.arange(J)
    costs = [
        jaxls.Cost(
            box_cost,
            (PoseVar(bp), RotVar(bo), VecVar(bo), problem.box, problem.texture_depth, problem.texture_mask, bm),
            name="box",
        ),
        jaxls.Cost(prior_cost, (PoseVar(poses), problem.pose_prior, problem.pose_mask), name="pose prior"),
    ]
    analysed = jaxls.LeastSquaresProblem(costs, [PoseVar(poses), RotVar(objs), VecVar(objs)]).analyze()
    values = jaxls.VarValues.make(
        [
            PoseVar(poses).with_value(jaxlie.SE3.from_matrix(init.camera_T_world)),
            RotVar(objs).with_value(jaxlie.SO3.from_matrix(init.rotation)),
            VecVar(objs).with_value(jnp.concatenate([init.center, F.param_from_radii(init.radii)], -1)),
        ]
    )
    return analysed, values


@jax.jit
def _solve(analysed, values):
    return analysed.solve(values, verbose=False, return_summary=True)


def estimate(values, T: int, J: int) -> slam.SlamEstimate:
    PoseVar, RotVar, VecVar = _types()
    poses, objs = jnp.arange(T), jnp.arange(J)
    v = values[VecVar(objs)]
    return slam.SlamEstimate(
        values[PoseVar(poses)].as_matrix(),
        values[RotVar(objs)].as_matrix(),
        v[:, :3],
        F.radii_from_param(v[:, 3:]),
    )


def solve_maps(problems, inits, config, repeats: int = 2):
    """Solves each map of a batch with jaxls; returns ``(estimate (batched), ms per map, iterations
    per map, compile seconds)``. One compilation serves every map of the batch (same padded
    sizes); times are medians over ``repeats`` of each map's warm solve."""
    take = lambda tree, k: jax.tree_util.tree_map(lambda x: x[k], tree)
    M = problems.box.shape[0]
    T, J = inits.camera_T_world.shape[1], inits.center.shape[1]
    ests, ms, iters = [], [], []
    compile_s = 0.0
    for k in range(M):
        analysed, values = build(take(problems, k), take(inits, k), config)
        t = time.perf_counter()
        out, summary = jax.block_until_ready(_solve(analysed, values))
        if k == 0:
            compile_s = time.perf_counter() - t
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            out, summary = jax.block_until_ready(_solve(analysed, values))
            ts.append(time.perf_counter() - t)
        ms.append(1e3 * float(np.median(ts)))
        iters.append(int(summary.iterations))
        ests.append(estimate(out, T, J))
        # Each map is a new compilation (jaxls' problem analysis is static); drop the old ones so a
        # long run does not run out of memory (an earlier 20-map run did).
        _solve.clear_cache()
    est = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *ests)
    return est, ms, iters, compile_s

"""Batch solvers of eq. 4.13: optimistix Levenberg-Marquardt (reference, differentiable) and a
structure-exploiting Levenberg-Marquardt with a Schur complement (fast; used online).

Both minimise :func:`jaxsem.slam.total_cost` over the same residuals (``_cost.py``), solve for
tangent deltas around an anchor and retract with jaxlie; both are jittable and vmappable over
maps of equal padded size.

- :func:`solve_batch` (``method="optimistix"``, the default): ``optx.least_squares`` with
  ``optx.LevenbergMarquardt`` and ``throw=False``; the result code and step count are returned in
  ``info``. Dense Jacobian, so cost grows quickly with the problem (see FACTS.md), but gradients
  w.r.t. anything in ``problem``/``init``/``config`` flow through the solution by optimistix's
  implicit adjoint.
- :func:`solve_schur` (also ``solve_batch(..., method="schur")``): each box residual touches
  one pose and one ellipsoid, so its Jacobian blocks come from one vmapped ``jacfwd`` per factor
  (15 columns); the normal equations are reduced to the ellipsoids by eliminating the
  block-diagonal pose blocks (Schur complement), a dense (9J x 9J) Cholesky, and
  Marquardt-damped LM with relinearisation at every accepted step. Not differentiated implicitly
  (use the optimistix path for gradients).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .. import factors as F
from ._cost import (
    box_rows,
    class_table,
    pose_rows,
    residual_blocks,
    retract,
    first_order_object,
    first_order_pose,
    retract_object,
    retract_pose,
    shape_rows,
    total_cost,
    zero_delta,
)
from ._problem import SlamEstimate, SlamProblem, SolverConfig


class SolveInfo(eqx.Module):
    """What a solve reports (every field an array, so it stacks under ``vmap``).

    Attributes:
      success: () bool, the solver stopped on its convergence criterion.
      result: () int32 code: for optimistix, ``optx.RESULTS`` index (0 = successful); for the
        Schur LM, 0 = converged, 1 = step limit reached.
      steps: () int32 iterations taken.
      initial_cost, cost: () ``0.5 * sum(r**2)`` before and after.
    """

    success: jnp.ndarray
    result: jnp.ndarray
    steps: jnp.ndarray
    initial_cost: jnp.ndarray
    cost: jnp.ndarray


def _residual_fn(delta, args):
    problem, anchor, config = args
    return residual_blocks(problem, retract(anchor, delta), config)


def solve_batch(
    problem: SlamProblem,
    init: SlamEstimate,
    config: SolverConfig = SolverConfig(),
    *,
    method: str = "optimistix",
) -> tuple[SlamEstimate, SolveInfo]:
    """Solves one map (vmap it for many maps of equal padded size).

    Args:
      problem: :class:`SlamProblem` (T poses, M boxes, J objects, padded with masks).
      init: :class:`SlamEstimate` to start from (e.g. :func:`jaxsem.slam.initialize`).
      config: :class:`SolverConfig`; ``SolverConfig(use_texture=False, use_shape_prior=False)``
        is the thesis' baseline.
      method: ``"optimistix"`` (dense LM, differentiable by the implicit adjoint) or ``"schur"``
        (:func:`solve_schur`, faster on large maps).

    Returns:
      (estimate, info): the solved :class:`SlamEstimate` (radii positive) and :class:`SolveInfo`.
      Never raises on non-convergence (``throw=False``); read ``info.success`` / ``info.result``.
    """
    if method == "schur":
        return solve_schur(problem, init, config)
    if method != "optimistix":
        raise ValueError(f"method: expected 'optimistix' or 'schur', got {method!r}")
    solver = optx.LevenbergMarquardt(rtol=config.rtol, atol=config.atol)
    args = (problem, init, config)
    sol = optx.least_squares(
        _residual_fn, solver, zero_delta(init), args=args, max_steps=config.max_steps,
        throw=False,
    )
    estimate = retract(init, sol.value)
    ok = sol.result == optx.RESULTS.successful
    code = jnp.where(ok, 0, jnp.where((sol.result == optx.RESULTS.max_steps_reached)
                                  | (sol.result == optx.RESULTS.nonlinear_max_steps_reached), 1, 2))
    info = SolveInfo(
        success=ok,
        result=code.astype(jnp.int32),
        steps=jnp.asarray(sol.stats["num_steps"], jnp.int32),
        initial_cost=total_cost(problem, init, config),
        cost=total_cost(problem, estimate, config),
    )
    return estimate, info


# --------------------------------------------------------------------------------------------
# Structured Levenberg-Marquardt.


class _Normal(NamedTuple):
    Hpp: jnp.ndarray  # (T, 6, 6)
    Hoo: jnp.ndarray  # (J, 9, 9)
    Hpo: jnp.ndarray  # (T, J, 6, 9)
    gp: jnp.ndarray  # (T, 6)
    go: jnp.ndarray  # (J, 9)


def _linearize(problem: SlamProblem, est: SlamEstimate, config: SolverConfig, pose_free):
    """Normal equations ``J^T J`` and ``J^T r`` in block form, from per-factor ``jacfwd``."""
    dtype = est.center.dtype
    mean, sigma = class_table(config, dtype)
    bp, bo = problem.box_pose, problem.box_object
    T, J = est.camera_T_world.shape[0], est.center.shape[0]

    def box_fn(dp, dobj, pose, R, c, r, box, td, tm, bm):
        R2, c2, r2 = first_order_object(R, c, r, dobj)
        out = box_rows(first_order_pose(pose, dp), R2, c2, r2, box, td, tm, bm,
                       problem.K, problem.image_size, config)
        return out, out

    z6, z9 = jnp.zeros(6, dtype), jnp.zeros(9, dtype)
    (Jp, Jo), rb = jax.vmap(
        jax.jacfwd(box_fn, argnums=(0, 1), has_aux=True),
        in_axes=(None, None, 0, 0, 0, 0, 0, 0, 0, 0),
    )(z6, z9, est.camera_T_world[bp], est.rotation[bo], est.center[bo], est.radii[bo],
      problem.box, problem.texture_depth, problem.texture_mask, problem.box_mask)
    # Poses outside the optimised window are held fixed: their columns vanish.
    Jp = Jp * pose_free[bp][:, None, None]

    def pose_fn(dp, pose, prior, mask):
        out = pose_rows(first_order_pose(pose, dp), prior, mask, config)
        return out, out

    Jpp, rp = jax.vmap(jax.jacfwd(pose_fn, has_aux=True), in_axes=(None, 0, 0, 0))(
        z6, est.camera_T_world, problem.pose_prior, problem.pose_mask
    )

    def shape_fn(ds, radii, cls, mask):
        r2 = F.radii_from_param(F.param_from_radii(radii) + ds)
        out = shape_rows(r2, cls, mask, config, mean, sigma)
        return out, out

    Js3, rs = jax.vmap(jax.jacfwd(shape_fn, has_aux=True), in_axes=(None, 0, 0, 0))(
        jnp.zeros(3, dtype), est.radii, problem.object_class, problem.object_mask
    )
    Js = jnp.zeros((J, 3, 9), dtype).at[:, :, 6:9].set(Js3)

    JpT = jnp.swapaxes(Jp, -1, -2)
    JoT = jnp.swapaxes(Jo, -1, -2)
    Hpp = jnp.zeros((T, 6, 6), dtype).at[bp].add(JpT @ Jp)
    Hpp = Hpp + jnp.swapaxes(Jpp, -1, -2) @ Jpp
    gp = jnp.zeros((T, 6), dtype).at[bp].add(jnp.einsum("mij,mi->mj", Jp, rb))
    gp = gp + jnp.einsum("tij,ti->tj", Jpp, rp)
    Hoo = jnp.zeros((J, 9, 9), dtype).at[bo].add(JoT @ Jo)
    Hoo = Hoo + jnp.swapaxes(Js, -1, -2) @ Js
    go = jnp.zeros((J, 9), dtype).at[bo].add(jnp.einsum("mij,mi->mj", Jo, rb))
    go = go + jnp.einsum("jik,ji->jk", Js, rs)
    Hpo = jnp.zeros((T, J, 6, 9), dtype).at[bp, bo].add(JpT @ Jo)
    gp = gp * pose_free[:, None]
    return _Normal(Hpp, Hoo, Hpo, gp, go)


def _solve_damped(n: _Normal, lam, pose_free, obj_used):
    """Solves ``(H + lam * (diag(H) + delta)) x = -g`` by eliminating the pose blocks."""
    dtype = n.Hpp.dtype
    T, J = n.Hpo.shape[0], n.Hpo.shape[1]
    eye6, eye9 = jnp.eye(6, dtype=dtype), jnp.eye(9, dtype=dtype)
    small = 1e-9

    def damp(H, eye, used):
        d = jnp.diagonal(H, axis1=-2, axis2=-1)
        H = H + lam * (d[..., None] * eye + small * eye)
        # Unused / fixed variables: identity rows keep the system regular; their rhs is zero.
        return jnp.where(used[:, None, None], H, eye)

    Hpp = damp(n.Hpp, eye6, pose_free > 0)
    Hoo = damp(n.Hoo, eye9, obj_used)
    Hpo = n.Hpo * pose_free[:, None, None, None] * obj_used[None, :, None, None]
    Hpp_inv = jnp.linalg.inv(Hpp)
    A = jnp.einsum("tab,tkbc->tkac", Hpp_inv, Hpo)  # Hpp^-1 Hpo
    S = -jnp.einsum("tjab,tkac->jbkc", Hpo, A)
    S = S + jnp.einsum("jab,jk->jakb", Hoo, jnp.eye(J, dtype=dtype))
    S = S.reshape(J * 9, J * 9)
    y = jnp.einsum("tab,tb->ta", Hpp_inv, n.gp)
    rhs = -n.go + jnp.einsum("tjab,ta->jb", Hpo, y)
    chol = jax.scipy.linalg.cho_factor(S, lower=True)
    do = jax.scipy.linalg.cho_solve(chol, rhs.reshape(-1)).reshape(J, 9)
    dp = jnp.einsum("tab,tb->ta", Hpp_inv, -n.gp - jnp.einsum("tjab,jb->ta", Hpo, do))
    return dp * pose_free[:, None], do * obj_used[:, None]


def _apply(est: SlamEstimate, dp, do):
    R, c, r = retract_object(est.rotation, est.center, est.radii, do)
    return SlamEstimate(retract_pose(est.camera_T_world, dp), R, c, r)


def solve_schur(
    problem: SlamProblem,
    init: SlamEstimate,
    config: SolverConfig = SolverConfig(),
    *,
    max_steps: int | None = None,
    pose_free=None,
) -> tuple[SlamEstimate, SolveInfo]:
    """Structured Levenberg-Marquardt (Schur complement over the pose blocks).

    Args:
      problem, init, config: as :func:`solve_batch`.
      max_steps: static iteration cap (default ``config.max_steps``).
      pose_free: optional (T,) bool/float, poses held fixed where False (a sliding window).

    Returns:
      (estimate, :class:`SolveInfo`). Converged when an accepted step lowers the cost by less
      than ``config.rtol * cost + config.atol``, or when damping exceeds 1e10 (no step helps).
    """
    max_steps = config.max_steps if max_steps is None else max_steps
    dtype = init.center.dtype
    T, J = init.camera_T_world.shape[0], init.center.shape[0]
    if pose_free is None:
        pose_free = problem.pose_mask
    pose_free = jnp.asarray(pose_free, dtype) * problem.pose_mask
    obj_used = problem.object_mask
    cost0 = total_cost(problem, init, config)

    def cond(carry):
        _, _, _, step, done = carry
        return (step < max_steps) & ~done

    def body(carry):
        est, cost, lam, step, _ = carry
        n = _linearize(problem, est, config, pose_free)
        dp, do = _solve_damped(n, lam, pose_free, obj_used)
        cand = _apply(est, dp, do)
        c_new = total_cost(problem, cand, config)
        ok = jnp.isfinite(c_new) & (c_new < cost)
        est = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), cand, est)
        decrease = cost - c_new
        cost_next = jnp.where(ok, c_new, cost)
        lam = jnp.where(ok, jnp.maximum(lam * 0.3, 1e-10), lam * 10.0)
        done = (ok & (decrease <= config.rtol * cost + config.atol)) | (lam > 1e10)
        return est, cost_next, lam, step + 1, done

    carry = (init, cost0, jnp.asarray(1e-3, dtype), jnp.asarray(0, jnp.int32),
             jnp.asarray(False))
    est, cost, _, steps, done = jax.lax.while_loop(cond, body, carry)
    info = SolveInfo(
        success=done, result=jnp.where(done, 0, 1).astype(jnp.int32), steps=steps,
        initial_cost=cost0, cost=cost,
    )
    return est, info

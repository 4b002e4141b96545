"""The structured Levenberg-Marquardt of ROSHAN as an optimistix least-squares solver.

``SchurLevenbergMarquardt`` is assembled like ``optx.LevenbergMarquardt``: a *descent*
(:class:`DampedSchurDescent`, the Marquardt-damped Gauss-Newton step solved by eliminating the
pose blocks) and a *search* (:class:`DampingSearch`, accept a step that lowers the cost and
shrink the damping, else grow it), driven by ``optx.least_squares``::

    solver = slam.SchurLevenbergMarquardt(rtol=1e-5, atol=1e-5, structure=my_structure)
    sol = optx.least_squares(my_residuals, solver, (poses0, landmarks0), args, throw=False)
    sol.stats["result"]     # jaxsem.slam._results.RESULTS item (extends optx.RESULTS)

What ``fn`` must declare (the "pose / landmark" protocol)
--------------------------------------------------------
- The iterate ``y`` is a pair ``(poses (T, dp), landmarks (L, dl))`` of arrays, updated by
  addition, unless ``retract`` is given: then ``y`` is any pytree and a step is applied as
  ``retract(y, (pose_step (T, dp), landmark_step (L, dl)))`` (a manifold update; ROSHAN's
  estimate is a :class:`~jaxsem.slam.SlamEstimate` of 4x4 poses and ellipsoids).
- ``fn(y, args)`` returns three residual blocks ``(pair (M, a), pose (T, b), landmark (L, c))``
  (``b`` or ``c`` may be 0): row ``m`` of ``pair`` may depend on pose ``pose_index[m]`` and
  landmark ``landmark_index[m]`` only, row ``t`` of ``pose`` on pose ``t`` only, row ``j`` of
  ``landmark`` on landmark ``j`` only. :func:`jaxsem.slam.residual_blocks` (boxes, pose
  priors, shape priors) has exactly this form.
- ``structure(args)`` returns a :class:`SchurStructure`: the two index arrays, and optional
  masks of the free poses / landmarks (held ones do not move).
- Optionally a fourth block ``pose_pair (T, e)`` (odometry / between factors): row ``t < T - 1``
  may depend on poses ``t`` and ``t + 1``, the last row on pose ``T - 1`` only. The pose part of
  the normal equations is then block-tridiagonal (``Normal.Hpp_next``).

Nothing checks the declared sparsity (that would cost a dense Jacobian): a residual row that
depends on a variable it did not declare makes the Jacobian silently wrong. The block Jacobian
is recovered exactly by ``dp + dl`` forward-mode columns (each pose perturbed at once along one
tangent axis, then each landmark: the declared sparsity keeps the columns apart; ``2 dp + dl``
with a ``pose_pair`` block, even and odd poses apart), or given by
``linearise(y, args) -> Normal`` when the caller has a faster one (ROSHAN's box factors use
9 columns via the chain rule of ``camera_T_object``, :func:`jaxsem.slam._cost.linearize`).

Cost model: the pose blocks are block-diagonal (block-tridiagonal with odometry between
consecutive poses, ``Normal.Hpp_next``: then eliminated by a block-tridiagonal solve, a scan
over the poses) and eliminated; the reduced landmark system is
dense, ``(L dl) x (L dl)``, solved by Cholesky, and the coupling is stored densely (T, L, dp,
dl). That is right for object SLAM (tens of objects, hundreds of poses), wrong for bundle
adjustment with thousands of landmarks.

Stopping rule (GTSAM's ``LevenbergMarquardtParams``): an accepted step whose cost decrease is at
most ``atol`` or at most ``rtol`` times the cost before it ends the solve successfully; ``norm``
is kept for the optimistix interface and unused. The damping search fails once the damping
passes ``lambda_max`` (``RESULTS.damping_limit``, or ``ill_conditioned`` when the last step
was not finite). One optimistix step is one GTSAM iteration: a relinearisation (only after an
accepted trial) and then trials (one reduced solve and one cost evaluation each) until the
search accepts one or fails; the trials are an inner ``while_loop``, so under ``vmap`` the
Jacobian is never taken for a rejected trial. ``sol.stats`` holds
``result`` (the precise :data:`~jaxsem.slam._results.RESULTS` item), ``trials`` and ``accepted``.
``options={"max_trials": n}`` caps the trials (``n`` may be traced; ``max_steps`` of
``optx.least_squares`` caps the iterations).

Differentiating through the solution: with the additive iterate, optimistix's implicit adjoint
applies (the gradient of the cost vanishes at the optimum). With ``retract`` (a manifold
iterate such as 4x4 matrices) it does not: solve for the tangent delta from a fixed anchor
instead, additively, as ``solve_batch(..., method="optimistix")`` does for ROSHAN.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ._cost import Normal
from ._results import RESULTS

__all__ = [
    "DampedSchurDescent",
    "DampingSearch",
    "SchurLevenbergMarquardt",
    "SchurStructure",
    "damped_schur_step",
    "damping_search",
    "schur_normal",
]


class SchurStructure(eqx.Module):
    """The block structure a residual function declares (see the module docstring).

    Attributes:
      pose_index: (M,) int, the pose each row of the ``pair`` block depends on.
      landmark_index: (M,) int, the landmark each row of the ``pair`` block depends on.
      pose_free: optional (T,) bool / float, False (0) for held poses.
      landmark_free: optional (L,) bool, False for held landmarks.
    """

    pose_index: Any
    landmark_index: Any
    pose_free: Any = None
    landmark_free: Any = None


# --------------------------------------------------------------------------------------------
# The descent's and the search's arithmetic (free functions: also used on their own).


def _tridiagonal_solve(D, C, B):
    """``X`` with ``H X = B`` for the symmetric block-tridiagonal ``H``: diagonal blocks ``D``
    (T, n, n), block ``(t, t + 1)`` = ``C[t]`` (T, n, n; the last unused), right-hand sides
    ``B`` (T, n, k). Block Thomas elimination (block LDL^T without pivoting, stable for the
    positive-definite damped systems it sees), two scans over ``t``.

    Each step inverts the small (n, n) pivot and multiplies, instead of ``jnp.linalg.solve``
    with the k right-hand sides: XLA's CPU triangular solve with hundreds of right-hand sides
    (k is the object count times 9, plus one) was about 600 times slower."""
    C_prev = jnp.concatenate([jnp.zeros_like(C[:1]), C[:-1]])  # block (t - 1, t)

    def forward(carry, x):
        G_prev, Y_prev = carry
        D_t, C_t, Cp_t, B_t = x
        CpT = jnp.swapaxes(Cp_t, -1, -2)
        M_inv = jnp.linalg.inv(D_t - CpT @ G_prev)
        G, Y = M_inv @ C_t, M_inv @ (B_t - CpT @ Y_prev)
        return (G, Y), (G, Y)

    init = (jnp.zeros_like(D[0]), jnp.zeros_like(B[0]))
    _, (G, Y) = jax.lax.scan(forward, init, (D, C, C_prev, B))

    def backward(X_next, x):
        G_t, Y_t = x
        X = Y_t - G_t @ X_next
        return X, X

    _, X = jax.lax.scan(backward, jnp.zeros_like(B[0]), (G, Y), reverse=True)
    return X


def damped_schur_step(n: Normal, lam, pose_free, obj_free, pairs=None):
    """Solves ``(H + lam * (diag(H) + 1e-9)) x = -g`` by block elimination (a Schur complement).

    Which blocks are eliminated follows the shapes (static), so that the dense system factored is
    the smaller one: the pose blocks when ``T dp > L dl`` (the reduced ``(L dl)^2`` landmark system
    is factored), else the landmark blocks, block-diagonal, which leaves the ``(T dp)^2`` pose
    system. When every pose is held (the batch solver's rescue phase) it is one small solve per
    landmark.

    The pose-pose part is block-diagonal, or block-tridiagonal when ``n.Hpp_next`` is given
    (odometry between consecutive poses): eliminating the poses then applies ``Hpp^-1`` by a
    block-tridiagonal solve (:func:`_tridiagonal_solve`) instead of per-pose inverses.

    Args:
      n: :class:`~jaxsem.slam._cost.Normal` at the current estimate.
      lam: () Marquardt damping. pose_free: (T,) float, 0 for held poses. obj_free: (J,) bool.
      pairs: optional ``(pose_index (M,), landmark_index (M,))``, the pose and landmark of each
        row of the ``pair`` block (:class:`SchurStructure`). Given, the reduced landmark system
        is built from the M pose-landmark blocks those rows touch rather than from all T x L
        blocks of ``n.Hpo`` when M is below a sixth of T x L (the same system; fewer operations
        when most poses see few landmarks, or when T is padded).

    Returns:
      ``(dp (T, dp), do (J, dl))``; zero for held variables. Non-finite when the reduced system
      is not positive definite (the search then rejects the step).
    """
    dtype = n.Hpp.dtype
    pose_free = jnp.asarray(pose_free, dtype)
    obj_free = jnp.asarray(obj_free, bool)
    pose_used = pose_free > 0
    Hoo = _damp(n.Hoo, lam, obj_free)
    go = n.go * obj_free[:, None].astype(dtype)

    def objects_only():
        # Every pose held: the system is block-diagonal in the landmarks (one small solve each).
        chol = jnp.linalg.cholesky(Hoo)
        y = jax.scipy.linalg.solve_triangular(chol, -go[..., None], lower=True)
        do = jax.scipy.linalg.solve_triangular(chol, y, lower=True, trans="T")[..., 0]
        return jnp.zeros_like(n.gp), do * obj_free[:, None].astype(dtype)

    def joint():
        # Eliminate the side with the larger system, factor the smaller one (static shapes).
        if n.Hpp.shape[0] * n.Hpp.shape[-1] <= n.Hoo.shape[0] * n.Hoo.shape[-1]:
            return _landmarks_eliminated_step(n, lam, pose_free, obj_free, Hoo, go)
        return _joint_step(n, lam, pose_free, obj_free, Hoo, go, pairs)

    # Skipping the pose elimination when no pose is free (a rescue phase) is the same solution
    # at a fraction of the cost; under vmap the cond runs both branches and selects.
    return jax.lax.cond(jnp.any(pose_used), joint, objects_only)


def _damp(H, lam, used):
    """Marquardt's damping of diagonal blocks ``H`` (N, n, n): ``H + lam (diag(H) + 1e-9)``;
    the blocks of unused / held variables become the identity (their rhs is zero), which keeps
    the system regular."""
    eye = jnp.eye(H.shape[-1], dtype=H.dtype)
    d = jnp.diagonal(H, axis1=-2, axis2=-1)
    H = H + lam * (d[..., None] * eye + jnp.asarray(1e-9, H.dtype) * eye)
    return jnp.where(used[:, None, None], H, eye)


def _landmarks_eliminated_step(n: Normal, lam, pose_free, obj_free, Hoo, go):
    """:func:`damped_schur_step` with some pose free when the poses' system is the smaller one
    (``T dp <= L dl``): the landmark blocks, block-diagonal, are eliminated instead, and the
    dense (T dp)^2 reduced pose system (block-tridiagonal pose part included) is factored.
    ``Hoo`` and ``go`` are already damped and masked."""
    dtype = n.Hpp.dtype
    T, dpn = n.Hpp.shape[0], n.Hpp.shape[-1]
    pose_used = pose_free > 0
    Hpp = _damp(n.Hpp, lam, pose_used)
    Hpo = n.Hpo * pose_free[:, None, None, None] * obj_free[None, :, None, None].astype(dtype)
    gp = n.gp * pose_free[:, None]
    Hoo_inv = jnp.linalg.inv(Hoo)
    B = jnp.einsum("tjab,jbc->tjac", Hpo, Hoo_inv)  # Hpo Hoo^-1, (T, J, dp, dl)
    # Hpp - Hpo Hoo^-1 Hpo^T, the (t, s) blocks laid out as (T dp, T dp).
    S = -jnp.einsum("tjac,sjbc->tasb", B, Hpo)
    S = S + jnp.einsum("tab,ts->tasb", Hpp, jnp.eye(T, dtype=dtype))
    if n.Hpp_next is not None:
        used = pose_used.astype(dtype)
        C = n.Hpp_next * (used * jnp.roll(used, -1))[:, None, None]
        C = C.at[-1].set(0.0)
        upper = jnp.einsum("tab,ts->tasb", C, jnp.eye(T, k=1, dtype=dtype))  # block (t, t + 1)
        S = S + upper + jnp.transpose(upper, (2, 3, 0, 1))
    rhs = -gp + jnp.einsum("tjab,jb->ta", B, go)
    chol = jax.scipy.linalg.cho_factor(S.reshape(T * dpn, T * dpn), lower=True)
    dp = jax.scipy.linalg.cho_solve(chol, rhs.reshape(-1)).reshape(T, dpn)
    do = -jnp.einsum("jab,jb->ja", Hoo_inv, go + jnp.einsum("tjab,ta->jb", Hpo, dp))
    return dp * pose_free[:, None], do * obj_free[:, None].astype(dtype)


def _joint_step(n: Normal, lam, pose_free, obj_free, Hoo, go, pairs):
    """:func:`damped_schur_step` with some pose free when the landmarks' system is the smaller
    one: the pose blocks eliminated (``Hoo`` and ``go`` already damped and masked)."""
    dtype = n.Hpp.dtype
    dpn, dln = n.Hpp.shape[-1], n.Hoo.shape[-1]
    T, J = n.Hpo.shape[:2]
    pose_used = pose_free > 0
    Hpp = _damp(n.Hpp, lam, pose_used)
    Hpo = n.Hpo * pose_free[:, None, None, None] * obj_free[None, :, None, None].astype(dtype)
    gp = n.gp * pose_free[:, None]
    # One solve gives X = Hpp^-1 [Hpo | gp] = [A | y]; then dp = Hpp^-1 (-gp - Hpo do) = -y - A do.
    rhs_p = jnp.concatenate([jnp.moveaxis(Hpo, 1, 2).reshape(T, dpn, J * dln), gp[:, :, None]], -1)
    if n.Hpp_next is not None:
        # Odometry: block-tridiagonal pose part.
        used = pose_used.astype(dtype)
        C = n.Hpp_next * (used * jnp.roll(used, -1))[:, None, None]
        C = C.at[-1].set(0.0)
        X = _tridiagonal_solve(Hpp, C, rhs_p)
    else:
        X = jnp.linalg.inv(Hpp) @ rhs_p
    # The pair route's batched small products run about four times slower per multiply-add than
    # the dense product's one large matrix product (XLA on a CPU): taken when the pairs are
    # fewer than a sixth of the T * J blocks (a padded or long sequence), else the dense one.
    if pairs is not None and 6 * jnp.shape(pairs[0])[0] > T * J:
        pairs = None
    if pairs is None:
        # Hpo^T [A | y], dense over every (pose, landmark) block.
        HX = jnp.einsum("tak,tal->kl", rhs_p[:, :, : J * dln], X).reshape(J, dln, J * dln + 1)
    else:
        # The same product from the nonzero blocks only: block (t, j) of Hpo is nonzero only for a
        # pair (row) m with pose t and landmark j, so Hpo^T X sums Hpo[t_m, j_m]^T X[t_m] over the
        # first row of each pair (M blocks instead of T * J).
        pi, li = (jnp.asarray(x, jnp.int32) for x in pairs)
        M = pi.shape[0]
        rows = jnp.arange(M, dtype=jnp.int32)
        first = jnp.full((T, J), M, jnp.int32).at[pi, li].min(rows)
        H_m = jnp.where((first[pi, li] == rows)[:, None, None], Hpo[pi, li], 0.0)  # (M, dp, dl)
        HX = jax.ops.segment_sum(jnp.einsum("mab,mak->mbk", H_m, X[pi]), li, num_segments=J)
    S = -HX[:, :, : J * dln] + jnp.einsum("jab,jk->jakb", Hoo, jnp.eye(J, dtype=dtype)).reshape(J, dln, J * dln)
    rhs = -go + HX[:, :, -1]
    chol = jax.scipy.linalg.cho_factor(S.reshape(J * dln, J * dln), lower=True)
    do = jax.scipy.linalg.cho_solve(chol, rhs.reshape(-1))
    dp = -X[:, :, -1] - X[:, :, : J * dln] @ do
    return dp * pose_free[:, None], do.reshape(J, dln) * obj_free[:, None].astype(dtype)


def damping_search(cost, new_cost, lam, step_finite):
    """Accept a finite step that lowers the cost; shrink (x 0.3) or grow (x 10) the damping.
    Returns ``(accept, new_lam)``."""
    accept = step_finite & jnp.isfinite(new_cost) & (new_cost < cost)
    lam = jnp.where(accept, jnp.maximum(lam * 0.3, 1e-12), lam * 10.0)
    return accept, lam


def _sum_squares(blocks) -> jnp.ndarray:
    return jnp.asarray(0.5 * sum(jnp.sum(jnp.square(b)) for b in jax.tree_util.tree_leaves(blocks)))


def _all_finite(tree) -> jnp.ndarray:
    leaves = [x for x in jax.tree_util.tree_leaves(tree) if jnp.issubdtype(jnp.result_type(x), jnp.inexact)]
    if not leaves:
        return jnp.asarray(True)
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


def _add(y, step):
    return jax.tree_util.tree_map(lambda a, b: a + b.astype(a.dtype), y, step)


def _colour_columns(jx, index, colours: int, dim: int):
    """(R, a, dim): the Jacobian of each row w.r.t. the block it depends on, read from the
    forward-mode columns ``jx`` (n, R, a) whose first ``colours * dim`` columns move the
    blocks of one colour (``index % colours``) along one tangent axis each."""
    R = jx.shape[1]
    cols = jnp.moveaxis(jx[: colours * dim], 0, -1)  # (R, a, colours * dim)
    cols = cols.reshape(R, cols.shape[1], colours, dim)
    pick = (jnp.asarray(index) % colours).reshape(R, 1, 1, 1)
    return jnp.take_along_axis(cols, pick, axis=2)[:, :, 0]


def schur_normal(fn, y, args, structure: SchurStructure, retract=None, pose_dim=None, landmark_dim=None) -> Normal:
    """Block normal equations of ``fn`` at ``y`` from forward-mode columns.

    ``fn(y, args) -> (pair (M, a), pose (T, b), landmark (L, c))`` with the sparsity declared by
    ``structure`` (module docstring), optionally with a fourth block ``pose_pair (T, e)`` whose
    row ``t < T - 1`` may depend on poses ``t`` and ``t + 1`` (odometry / between factors; the
    last row on pose ``T - 1`` only): the pose blocks are then block-tridiagonal
    (``Normal.Hpp_next``). Columns: ``dp + dl`` (every pose moved at once along one tangent
    axis, then every landmark), or ``2 dp + dl`` with a ``pose_pair`` block (even and odd poses
    apart, so that the two poses of a row stay apart). Without ``retract``, ``y = (poses
    (T, dp), landmarks (L, dl))``; with it, ``pose_dim`` / ``landmark_dim`` give the tangent
    sizes and the derivative is taken of ``fn(retract(y, (dp, dl)))`` at zero.
    """
    if retract is None:
        poses, landmarks = y
        T, dpn = poses.shape
        L, dln = landmarks.shape
        dtype = jnp.result_type(poses)

        def g(d):
            return fn(_add(y, d), args)
    else:
        leaves = jax.tree_util.tree_leaves(y)
        dtype = jnp.result_type(leaves[0])
        T = structure.pose_free.shape[0] if structure.pose_free is not None else None
        L = structure.landmark_free.shape[0] if structure.landmark_free is not None else None
        if T is None or L is None or pose_dim is None or landmark_dim is None:
            raise ValueError("schur_normal: with retract, give pose_free / landmark_free and the tangent sizes")
        dpn, dln = int(pose_dim), int(landmark_dim)

        def g(d):
            return fn(retract(y, d), args)

    zero = (jnp.zeros((T, dpn), dtype), jnp.zeros((L, dln), dtype))
    blocks, lin = jax.linearize(g, zero)
    if not isinstance(blocks, (tuple, list)) or len(blocks) not in (3, 4):
        raise ValueError(
            "fn: expected a tuple of 3 residual blocks (pair, pose, landmark) or 4 (with pose_pair), "
            f"got {jax.tree_util.tree_structure(blocks)}"
        )
    colours = 2 if len(blocks) == 4 else 1
    n = colours * dpn + dln
    eye = jnp.eye(n, dtype=dtype)
    t_index = jnp.arange(T)
    # Column c * dp + k moves the poses of colour c (t % colours == c) along tangent axis k;
    # column colours * dp + k every landmark along axis k.
    pose_seed = eye[:, : colours * dpn].reshape(n, colours, dpn)[:, t_index % colours]  # (n, T, dp)
    seeds = (pose_seed, jnp.broadcast_to(eye[:, None, colours * dpn :], (n, L, dln)))
    cols = jax.vmap(lin)(seeds)
    rows = [jnp.reshape(r, r.shape[:1] + (-1,)) for r in blocks]
    cols = [jnp.reshape(c, c.shape[:2] + (-1,)) for c in cols]
    rb, rp, rl = rows[:3]
    jb, jp, jl = cols[:3]
    pi, li = structure.pose_index, structure.landmark_index
    Jbp = _colour_columns(jb, pi, colours, dpn)  # (M, a, dp)
    Jbl = jnp.moveaxis(jb[colours * dpn :], 0, -1)  # (M, a, dl)
    Jpp = _colour_columns(jp, t_index, colours, dpn)  # (T, b, dp)
    Jll = jnp.moveaxis(jl[colours * dpn :], 0, -1)  # (L, c, dl)
    tr = lambda x: jnp.swapaxes(x, -1, -2)
    Hpp = jnp.zeros((T, dpn, dpn), dtype).at[pi].add(tr(Jbp) @ Jbp) + tr(Jpp) @ Jpp
    Hoo = jnp.zeros((L, dln, dln), dtype).at[li].add(tr(Jbl) @ Jbl) + tr(Jll) @ Jll
    Hpo = jnp.zeros((T, L, dpn, dln), dtype).at[pi, li].add(tr(Jbp) @ Jbl)
    gp = jnp.zeros((T, dpn), dtype).at[pi].add(jnp.einsum("mij,mi->mj", Jbp, rb))
    gp = gp + jnp.einsum("tij,ti->tj", Jpp, rp)
    go = jnp.zeros((L, dln), dtype).at[li].add(jnp.einsum("mij,mi->mj", Jbl, rb))
    go = go + jnp.einsum("jik,ji->jk", Jll, rl)
    Hnext = None
    if colours == 2:
        ro, jo = rows[3], cols[3]
        Ja = _colour_columns(jo, t_index, 2, dpn)  # row t w.r.t. pose t
        Jb = _colour_columns(jo, t_index + 1, 2, dpn)  # row t w.r.t. pose t + 1
        Jb = Jb * (t_index < T - 1).astype(dtype)[:, None, None]  # the last row has no next pose
        Hpp = Hpp + tr(Ja) @ Ja + jnp.roll(tr(Jb) @ Jb, 1, axis=0)
        gp = gp + jnp.einsum("tij,ti->tj", Ja, ro) + jnp.roll(jnp.einsum("tij,ti->tj", Jb, ro), 1, axis=0)
        Hnext = tr(Ja) @ Jb
    return Normal(Hpp, Hoo, Hpo, gp, go, _sum_squares(rows), Hnext)


# --------------------------------------------------------------------------------------------
# Descent and search.


class SchurInfo(optx.FunctionInfo):
    """What the solver knows at an accepted point: the block normal equations (cost included),
    which variables are free, and the pose and landmark of each ``pair`` row (the structure's
    indices, which the damped step uses to visit only the nonzero coupling blocks)."""

    normal: Normal
    pose_free: jnp.ndarray
    landmark_free: jnp.ndarray
    pairs: tuple[jnp.ndarray, jnp.ndarray]

    def as_min(self):
        return self.normal.cost


class _DescentState(eqx.Module):
    info: SchurInfo


class DampedSchurDescent(optx.AbstractDescent):
    """The damped Schur step :func:`damped_schur_step`.

    Its ``step_size`` is the Marquardt damping ``lambda`` itself, as :class:`DampingSearch`
    hands it over (a larger value, a shorter step: the reverse of optimistix's
    ``DampedNewtonDescent``, which takes ``1 / lambda``). Passing ``lambda`` rather than its
    inverse keeps the damping sequence bit-for-bit that of GTSAM's rule (x 0.3 / x 10): a
    round trip through ``1 / (1 / lambda)`` changes the last bit, and on a slowly converging
    map that alone changes the answer at the step budget."""

    def init(self, y, f_info_struct):
        del y
        return _DescentState(jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), f_info_struct))

    def query(self, y, f_info, state):
        del y, state
        return _DescentState(f_info)

    def step(self, step_size, state):
        i = state.info
        lam = step_size  # the damping itself (see the class docstring)
        dp, dl = damped_schur_step(i.normal, lam, i.pose_free, i.landmark_free, i.pairs)
        finite = jnp.all(jnp.isfinite(dp)) & jnp.all(jnp.isfinite(dl))
        return (dp, dl), optx.RESULTS.where(finite, optx.RESULTS.successful, optx.RESULTS.singular)


class _SearchState(eqx.Module):
    lam: jnp.ndarray


class DampingSearch(optx.AbstractSearch):
    """Marquardt's damping rule (GTSAM's): a trial is accepted when its cost is finite and lower;
    then the damping shrinks (x 0.3, at least 1e-12), else it grows (x 10). Returns ``lambda`` as the step size (for :class:`DampedSchurDescent`) and fails
    (``optx.RESULTS.nonlinear_divergence``) once the damping passes ``lambda_max``."""

    lambda_init: Any = 1e-3
    lambda_max: Any = 1e10

    def init(self, y, f_info_struct):
        del f_info_struct
        dtype = jnp.result_type(jax.tree_util.tree_leaves(y)[0])
        return _SearchState(jnp.asarray(self.lambda_init, dtype))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        del y, y_eval
        cost, new_cost = f_info.as_min(), f_eval_info.as_min()
        # A non-finite descent step arrives as an infinite trial cost: rejected.
        accept, lam = damping_search(cost, new_cost, state.lam, jnp.asarray(True))
        accept = first_step | accept
        lam = jnp.where(first_step, state.lam, lam)
        exhausted = lam > jnp.asarray(self.lambda_max, lam.dtype)
        result = optx.RESULTS.where(exhausted, optx.RESULTS.nonlinear_divergence, optx.RESULTS.successful)
        return lam, accept, result, _SearchState(lam)


# --------------------------------------------------------------------------------------------
# The solver.


class _State(eqx.Module):
    needs_linearisation: jnp.ndarray
    search_state: _SearchState
    f_info: SchurInfo
    descent_state: _DescentState
    terminate: jnp.ndarray
    result: optx.RESULTS
    code: RESULTS
    trials: jnp.ndarray
    accepted: jnp.ndarray


class _Trial(eqx.Module):
    search_state: _SearchState
    trials: jnp.ndarray
    accept: jnp.ndarray
    step_finite: jnp.ndarray
    exhausted: jnp.ndarray
    y_eval: Any
    cost_eval: jnp.ndarray
    done: jnp.ndarray


class SchurLevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt over pose and landmark blocks (Schur complement on the poses).

    Args:
      rtol, atol: GTSAM's stopping rule on the cost decrease of an accepted step (floats or
        traced scalars).
      structure: ``structure(args) -> SchurStructure`` (module docstring).
      linearise: optional ``linearise(y, args) -> Normal``, a faster exact linearisation than
        the generic forward-mode one of :func:`schur_normal`.
      retract: optional ``retract(y, (pose_step, landmark_step)) -> y``; default ``y + step``
        with ``y = (poses, landmarks)``. pose_dim, landmark_dim: tangent sizes (with retract).
      lambda_init, lambda_max: initial damping and the limit of the search.

    Example, planar poses ``(x, y, theta)`` observing point landmarks, each observation a
    ``pair`` row of one pose and one landmark, plus pose priors (no landmark rows)::

        def residuals(y, args):
            poses, points = y
            p, l = poses[args["pose"]], points[args["point"]]
            c, s = jnp.cos(p[:, 2]), jnp.sin(p[:, 2])
            d = l - p[:, :2]
            seen = jnp.stack([c * d[:, 0] + s * d[:, 1], c * d[:, 1] - s * d[:, 0]], -1)
            return seen - args["z"], poses - args["prior"], jnp.zeros((points.shape[0], 0))

        solver = slam.SchurLevenbergMarquardt(
            1e-8, 1e-8, structure=lambda a: slam.SchurStructure(a["pose"], a["point"])
        )
        sol = optx.least_squares(residuals, solver, (poses0, points0), args, max_steps=100)

    ``tests/slam/test_schur_solver.py`` solves such a problem against ``optx.LevenbergMarquardt``.
    """

    rtol: Any
    atol: Any
    norm: Callable = eqx.field(static=True)
    descent: DampedSchurDescent
    search: DampingSearch
    structure: Callable = eqx.field(static=True)
    linearise: Callable | None = eqx.field(static=True)
    retract: Callable | None = eqx.field(static=True)
    pose_dim: int | None = eqx.field(static=True)
    landmark_dim: int | None = eqx.field(static=True)

    def __init__(
        self,
        rtol,
        atol,
        structure: Callable,
        *,
        linearise: Callable | None = None,
        retract: Callable | None = None,
        pose_dim: int | None = None,
        landmark_dim: int | None = None,
        lambda_init: Any = 1e-3,
        lambda_max: Any = 1e10,
    ):
        self.rtol = rtol
        self.atol = atol
        self.norm = optx.max_norm
        self.descent = DampedSchurDescent()
        self.search = DampingSearch(lambda_init, lambda_max)
        self.structure = structure
        self.linearise = linearise
        self.retract = retract
        self.pose_dim = pose_dim
        self.landmark_dim = landmark_dim

    def _info(self, fn, y, args) -> SchurInfo:
        s = self.structure(args)
        if self.linearise is not None:
            normal = self.linearise(y, args)
        else:
            f = lambda _y, _a: fn(_y, _a)[0]
            normal = schur_normal(f, y, args, s, self.retract, self.pose_dim, self.landmark_dim)
        dtype = normal.Hpp.dtype
        T, L = normal.Hpo.shape[:2]
        pf = jnp.ones(T, dtype) if s.pose_free is None else jnp.asarray(s.pose_free, dtype)
        lf = jnp.ones(L, bool) if s.landmark_free is None else jnp.asarray(s.landmark_free, bool)
        pairs = (jnp.asarray(s.pose_index, jnp.int32), jnp.asarray(s.landmark_index, jnp.int32))
        return SchurInfo(normal, pf, lf, pairs)

    def _apply(self, y, step):
        return _add(y, step) if self.retract is None else self.retract(y, step)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        del options, f_struct, aux_struct, tags
        info_struct = eqx.filter_eval_shape(self._info, fn, y, args)
        info = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), info_struct)
        s = self.structure(args)
        some_free = jnp.asarray(True)
        if s.pose_free is not None and s.landmark_free is not None:
            some_free = jnp.any(jnp.asarray(s.pose_free) > 0) | jnp.any(jnp.asarray(s.landmark_free))
        return _State(
            needs_linearisation=jnp.asarray(True),
            search_state=self.search.init(y, info_struct),
            f_info=info,
            descent_state=self.descent.init(y, info_struct),
            terminate=~some_free,  # nothing to solve for: done, successfully
            result=optx.RESULTS.successful,
            code=RESULTS.successful,  # pyright: ignore[reportArgumentType]
            trials=jnp.asarray(0, jnp.int32),
            accepted=jnp.asarray(0, jnp.int32),
        )

    def step(self, fn, y, args, options, state: _State, tags):
        """One iteration (GTSAM's layout): relinearise (after an accepted trial; one call
        site, so under ``vmap`` the Jacobian is never taken for a rejected trial), then
        trials of the descent at the search's damping until one is accepted, the damping
        passes its limit or the trial budget is spent."""
        del tags
        f_info = jax.lax.cond(state.needs_linearisation, lambda: self._info(fn, y, args), lambda: state.f_info)
        cost = f_info.normal.cost
        dtype = cost.dtype
        lin_ok = _all_finite(f_info.normal)
        at_zero = cost <= 0  # GTSAM's errorTol: an exact optimum
        descent_state = self.descent.query(y, f_info, state.descent_state)
        budget = options.get("max_trials")

        def trial(t: _Trial) -> _Trial:
            diff, _ = self.descent.step(t.search_state.lam, descent_state)
            finite = _all_finite(diff)
            diff = jax.tree_util.tree_map(lambda d: jnp.where(finite, d, 0.0), diff)
            y_eval = self._apply(y, diff)
            cost_eval = _sum_squares(fn(y_eval, args)[0]).astype(dtype)
            seen = optx.FunctionInfo.Eval(jnp.where(finite, cost_eval, jnp.inf))
            _, accept, search_result, search_state = self.search.step(
                jnp.asarray(False), y, y_eval, f_info, seen, t.search_state
            )
            trials = t.trials + 1
            exhausted = search_result != optx.RESULTS.successful
            done = accept | exhausted
            if budget is not None:
                done = done | (trials >= budget)
            return _Trial(search_state, trials, accept, finite, exhausted, y_eval, cost_eval, done)

        t0 = _Trial(
            state.search_state,
            state.trials,
            jnp.asarray(False),
            jnp.asarray(True),
            jnp.asarray(False),
            y,
            cost,
            ~lin_ok | at_zero,
        )
        t = jax.lax.while_loop(lambda t: ~t.done, trial, t0)
        accept = t.accept
        y_new = jax.tree_util.tree_map(lambda a, b: jnp.where(accept, a, b), t.y_eval, y)
        decrease = cost - t.cost_eval
        rtol = jnp.asarray(self.rtol, dtype)
        atol = jnp.asarray(self.atol, dtype)
        converged = accept & ((decrease <= atol) | (decrease <= rtol * cost))
        out_of_trials = jnp.asarray(False) if budget is None else t.trials >= budget
        done = converged | (at_zero & lin_ok)
        terminate = done | ~lin_ok | t.exhausted | out_of_trials
        # The precise code (jaxsem RESULTS) and its optimistix twin; later lines take precedence.
        code = RESULTS.where(t.step_finite, RESULTS.damping_limit, RESULTS.ill_conditioned)
        code = RESULTS.where(t.exhausted, code, RESULTS.max_steps_reached)
        code = RESULTS.where(done, RESULTS.successful, code)
        code = RESULTS.where(lin_ok, code, RESULTS.nonfinite)
        ill = optx.RESULTS.where(t.step_finite, optx.RESULTS.nonlinear_divergence, optx.RESULTS.singular)
        result = optx.RESULTS.where(t.exhausted, ill, optx.RESULTS.nonlinear_max_steps_reached)
        result = optx.RESULTS.where(done, optx.RESULTS.successful, result)
        result = optx.RESULTS.where(lin_ok, result, optx.RESULTS.nonfinite)
        state = _State(
            needs_linearisation=accept & ~terminate,
            search_state=t.search_state,
            f_info=f_info,
            descent_state=descent_state,
            terminate=terminate,
            result=optx.RESULTS.where(terminate & ~done, result, optx.RESULTS.successful),
            code=RESULTS.where(terminate, code, RESULTS.successful),
            trials=t.trials,
            accepted=state.accepted + accept.astype(jnp.int32),
        )
        return y_new, state, None

    def terminate(self, fn, y, args, options, state: _State, tags):
        del fn, y, args, options, tags
        return state.terminate, state.result

    def postprocess(self, fn, y, aux, args, options, state: _State, tags, result):
        del fn, args, options, tags
        code = RESULTS.where(state.terminate, state.code, RESULTS.max_steps_reached)
        code = RESULTS.where(result == optx.RESULTS.nonfinite, RESULTS.nonfinite, code)
        stats = {"result": code, "trials": state.trials, "accepted": state.accepted}
        return y, aux, stats

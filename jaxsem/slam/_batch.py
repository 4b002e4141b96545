"""Batch solvers of eq. 4.13: the structured Levenberg-Marquardt of ROSHAN (Schur complement) in
two forms, both ``optx.least_squares`` with :class:`~jaxsem.slam.SchurLevenbergMarquardt`.

The structured LM is :class:`~jaxsem.slam.SchurLevenbergMarquardt` (``_schur.py``), an
optimistix least-squares solver made of a descent (the damped Schur step,
:func:`damped_schur_step`) and a search (the damping rule, :func:`damping_search`), called
through ``optx.least_squares`` by :func:`levenberg_marquardt` with ROSHAN's residuals
(:func:`~jaxsem.slam.residual_blocks`), its 9-column linearisation
(:func:`~jaxsem.slam._cost.linearize`) and the manifold retraction (:func:`roshan_solver`).

Each trial costs one reduced solve and one cost evaluation; a relinearisation follows each
accepted trial. The stopping rule is GTSAM's (relative or absolute cost decrease of an accepted
step at most ``rtol`` / ``atol``, 1e-5 by default). Every solve returns a :data:`RESULTS` code
that never lies: success needs the stopping rule met *and* a finite state and cost.
:func:`solve_schur` wraps the solver with the rescue of stranded objects and the unfixable-object
logic.

``solve_batch(..., method="optimistix")`` is the differentiable form: the same solver on an
additive iterate, the tangent delta from the initial estimate, linearised by generic
forward-mode columns (:func:`~jaxsem.slam._schur.schur_normal`), so that optimistix's implicit adjoint
gives gradients through the solution (e.g. to learn the class table). It has no rescue phase.
It replaces optimistix's dense ``LevenbergMarquardt`` (one JVP per unknown and a dense QR per
step), which was too slow to be a usable reference on full maps.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jax.core import Tracer

from ..quadrics import back_project, invert_pose
from . import _aot
from ._cost import (
    Delta,
    Normal,
    box_health,
    linearize,
    residual_blocks,
    retract,
    retract_object,
    retract_pose,
    total_cost,
)
from ._init import initialize
from ._problem import SlamEstimate, SlamProblem, has_measurements
from ._results import RESULTS
from ._schur import (
    SchurLevenbergMarquardt,
    SchurStructure,
    _all_finite,
    damped_schur_step as damped_schur_step,
    damping_search as damping_search,
)
from ._solver_config import SolverConfig


class SolveInfo(eqx.Module):
    """What a solve reports (every field an array or a :data:`RESULTS` item, so it stacks under
    ``vmap``).

    Attributes:
      result: :data:`RESULTS` item (``info.result == RESULTS.successful``).
      success: () bool, the same as ``result == RESULTS.successful``.
      steps: () int32 trial steps (linear solves), rejected ones included, over all phases.
      accepted: () int32 accepted steps (what GTSAM counts as iterations).
      initial_cost, cost: () ``0.5 * sum(r**2)`` of the whole problem before and after.
      unfixable: (J,) bool, objects the data could not fix (still no valid projection in one of
        their frames, or a box-edge RMS above ``config.unfixable_rms`` after the rescue): they
        were held out of the joint solve, so they did not move the camera poses.
      rescued: (J,) bool, objects re-placed by multi-view triangulation before the solve.
    """

    result: RESULTS
    success: jnp.ndarray
    steps: jnp.ndarray
    accepted: jnp.ndarray
    initial_cost: jnp.ndarray
    cost: jnp.ndarray
    unfixable: jnp.ndarray
    rescued: jnp.ndarray


def _cast(problem: SlamProblem, init: SlamEstimate) -> SlamEstimate:
    """Float leaves of the estimate in the problem's dtype (float32 problems stay float32 under
    x64; the loop carries keep one dtype)."""
    dtype = problem.pose_prior.dtype
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), init)


def _code(item):
    """A :data:`RESULTS` item with a jax int32 value (a scan / loop carry of fixed type)."""
    return jax.tree_util.tree_map(lambda v: jnp.asarray(v, jnp.int32), item)


def _throw(result, tree, throw: bool):
    if not throw:
        return tree
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    leaves = [result.error_if(x, result != RESULTS.successful) for x in leaves]
    return jax.tree_util.tree_unflatten(treedef, leaves)


# --------------------------------------------------------------------------------------------
# The differentiable path: the same solver on the additive tangent delta (implicit adjoint).


def _delta_residuals(y, args):
    """ROSHAN's residual blocks at ``anchor`` moved by the tangent delta ``y = (pose (T, 6),
    object (J, 9))`` (rotation, centre, radii parameter per object)."""
    problem, anchor, config = args
    dp, do = y
    delta = Delta(dp, do[:, :3], do[:, 3:6], do[:, 6:])
    return residual_blocks(problem, retract(anchor, delta), config)


def _delta_structure(args) -> SchurStructure:
    problem, _, _ = args
    dtype = problem.pose_prior.dtype
    return SchurStructure(problem.box_pose, problem.box_object, problem.pose_mask.astype(dtype), problem.object_mask)


def _solve_implicit(problem: SlamProblem, init: SlamEstimate, config: SolverConfig):
    """:class:`SchurLevenbergMarquardt` on the tangent delta from ``init`` (an additive iterate,
    generic forward-mode linearisation: 15 columns, 21 with odometry), so that optimistix's
    implicit adjoint differentiates the solution. The adjoint's linear solve is a least-squares
    one (``well_posed=False``): padded poses and objects have no residuals, so the cost's Hessian
    is singular along them."""
    dtype = init.center.dtype
    stop = config.stopping
    solver = SchurLevenbergMarquardt(
        stop.rtol, stop.atol, _delta_structure, lambda_init=stop.lambda_init, lambda_max=stop.lambda_max
    )
    T, J = init.camera_T_world.shape[0], init.center.shape[0]
    y0 = (jnp.zeros((T, 6), dtype), jnp.zeros((J, 9), dtype))
    sol = optx.least_squares(
        _delta_residuals,
        solver,
        y0,
        args=(problem, init, config),
        options={"max_trials": config.max_steps},
        max_steps=None,
        adjoint=optx.ImplicitAdjoint(linear_solver=lx.AutoLinearSolver(well_posed=False)),
        throw=False,
    )
    dp, do = sol.value
    estimate = retract(init, Delta(dp, do[:, :3], do[:, 3:6], do[:, 6:]))
    return estimate, sol.stats


def solve_batch(
    problem: SlamProblem,
    init: SlamEstimate | None = None,
    config: SolverConfig = SolverConfig(),
    *,
    method: str = "schur",
    throw: bool = False,
) -> tuple[SlamEstimate, SolveInfo]:
    """Solves one map (vmap it for many maps of equal padded size).

    Args:
      problem: :class:`SlamProblem` (T poses, M boxes, J objects, padded with masks).
      init: :class:`SlamEstimate` to start from; None: :func:`jaxsem.slam.initialize` with this
        ``config`` (the solver's own class table, depth rule and texture use).
      config: :class:`SolverConfig`; :func:`jaxsem.slam.baseline_config` is the thesis' baseline.
      method: ``"schur"`` (:func:`solve_schur`, the default: rescue of stranded objects, then the
        structured LM on the manifold) or ``"optimistix"`` (the same solver on the tangent delta
        from ``init``, without the rescue phase, differentiable through the solution by
        optimistix's implicit adjoint: see the module docstring).
      throw: raise (``eqx.error_if``, a runtime error) when the result is not successful.

    Returns:
      (estimate, info): the solved :class:`SlamEstimate` (radii positive) and :class:`SolveInfo`.
      With ``throw=False`` it never raises on failure; read ``info.result`` / ``info.success``.

    Called outside a trace with ``init`` given, the Schur solve's traced program is kept on disk
    next to JAX's persistent compilation cache (:mod:`jaxsem.slam._aot`; on for library calls,
    ``JAXSEM_NO_COMPILATION_CACHE=1`` or ``jaxsem._cache.enable_compilation_cache`` with
    ``enabled=False`` turns both off): a new process loads it and the compiled executable
    instead of tracing and compiling the solver again.
    """
    if method == "schur":
        if throw or init is None:
            return solve_schur(problem, init, config, throw=throw)
        return _stored("solve_schur", solve_schur, problem, init, config)
    if method != "optimistix":
        raise ValueError(f"method: expected 'schur' or 'optimistix', got {method!r}")
    init = _cast(problem, initialize(problem, config) if init is None else init)
    dtype = init.center.dtype
    estimate, stats = _solve_implicit(problem, init, config)
    cost0 = total_cost(problem, init, config)
    cost = total_cost(problem, estimate, config)
    finite = _all_finite(estimate) & jnp.isfinite(cost) & _all_finite(problem) & jnp.isfinite(cost0)
    result = RESULTS.where(has_measurements(problem), stats["result"], RESULTS.no_measurements)
    result = RESULTS.where(finite, result, RESULTS.nonfinite)
    J = init.center.shape[0]
    info = SolveInfo(
        result=result,
        success=result == RESULTS.successful,
        steps=jnp.asarray(stats["trials"], jnp.int32),
        accepted=jnp.asarray(stats["accepted"], jnp.int32),
        initial_cost=cost0.astype(dtype),
        cost=cost.astype(dtype),
        unfixable=jnp.zeros(J, bool),
        rescued=jnp.zeros(J, bool),
    )
    return _throw(result, (estimate, info), throw)


# --------------------------------------------------------------------------------------------
# Structured Levenberg-Marquardt: descent + search over _cost.linearize.


_STORED: dict = {}  # (name, argument tree, avals) -> the callable of :func:`_aot.exported`


def _stored(name: str, fn, problem: SlamProblem, init: SlamEstimate, config: SolverConfig):
    """``fn(problem, init, config)`` (a jitted solve returning ``(estimate like init, SolveInfo)``)
    through its traced program kept on disk (:func:`jaxsem.slam._aot.exported`), so that a new
    process skips tracing the solver (most of a warm first call) when JAX's persistent
    compilation cache is on; the plain jitted call inside a trace, or when the cache is off."""
    leaves, tree = jax.tree_util.tree_flatten((problem, init, config))
    if _aot.cache_folder() is None or any(isinstance(x, Tracer) for x in leaves):
        return fn(problem, init, config)  # fn is jitted
    key = (name, tree, tuple(_aot._aval(x) for x in leaves))
    if key not in _STORED:
        z = jnp.zeros(())
        info = SolveInfo(RESULTS.successful, z, z, z, z, z, z, z)  # pyright: ignore[reportArgumentType]
        _STORED[key] = _aot.exported(name, fn, (problem, init, config), (init, info))
    return _STORED[key](problem, init, config)


def _apply(est: SlamEstimate, dp, do) -> SlamEstimate:
    R, c, r = retract_object(est.rotation, est.center, est.radii, do)
    return SlamEstimate(retract_pose(est.camera_T_world, dp), R, c, r)


def _roshan_residuals(est: SlamEstimate, args):
    problem, config, _, _ = args
    return residual_blocks(problem, est, config)


def _roshan_structure(args) -> SchurStructure:
    problem, _, pose_free, obj_free = args
    return SchurStructure(problem.box_pose, problem.box_object, pose_free, obj_free)


def _roshan_linearise(est: SlamEstimate, args) -> Normal:
    problem, config, pose_free, _ = args
    return linearize(problem, est, config, pose_free)


def _roshan_retract(est: SlamEstimate, step) -> SlamEstimate:
    return _apply(est, *step)


def roshan_solver(config: SolverConfig) -> SchurLevenbergMarquardt:
    """The :class:`SchurLevenbergMarquardt` of a ROSHAN problem: iterate a
    :class:`SlamEstimate`, residuals :func:`residual_blocks` with ``args = (problem, config,
    pose_free (T,) float, obj_free (J,) bool)``, ROSHAN's 9-column linearisation and the
    manifold retraction, ``config``'s stopping rule and damping."""
    stop = config.stopping
    return SchurLevenbergMarquardt(
        stop.rtol,
        stop.atol,
        _roshan_structure,
        linearise=_roshan_linearise,
        retract=_roshan_retract,
        pose_dim=6,
        landmark_dim=9,
        lambda_init=stop.lambda_init,
        lambda_max=stop.lambda_max,
    )


def levenberg_marquardt(
    problem: SlamProblem,
    init: SlamEstimate,
    config: SolverConfig,
    pose_free,
    obj_free,
    max_steps,
):
    """The structured LM on one ROSHAN problem: ``optx.least_squares`` with
    :func:`roshan_solver` (descent :func:`damped_schur_step`, search :func:`damping_search`).

    ``max_steps`` caps the trial steps (reduced solves; an int, traced or not). Everything
    stays on the device. Under ``vmap`` every member keeps its own damping, counters and
    stopping decision (a finished member's carry is frozen by the batched while loop).

    Returns ``(estimate, cost, steps, accepted, result)``: ``cost`` at the returned estimate,
    ``steps`` trials, ``accepted`` accepted trials, ``result`` a :data:`RESULTS` item.
    """
    dtype = init.center.dtype
    args = (problem, config, jnp.asarray(pose_free, dtype), jnp.asarray(obj_free, bool))
    sol = optx.least_squares(
        _roshan_residuals,
        roshan_solver(config),
        init,
        args,
        options={"max_trials": max_steps},
        max_steps=None,
        throw=False,
    )
    est = sol.value
    cost = sol.state.f_info.normal.cost
    return est, cost, sol.stats["trials"], sol.stats["accepted"], sol.stats["result"]


# --------------------------------------------------------------------------------------------
# Rescue of stranded objects (robust to a plain initialisation).


def _triangulate(problem: SlamProblem, est: SlamEstimate, min_depth):
    """Least-squares intersection of the rays through the box centres of each object.

    Returns ``(point (J, 3), ok (J,))``; ``ok`` when the rays are well spread (smallest
    eigenvalue of ``sum(I - d d^T)`` over the object's boxes at least 1e-3 per ray, i.e. about
    2 deg of parallax) and the point is at least ``min_depth`` (``SolverConfig.min_depth``) in
    front of every camera that saw it.
    """
    dtype = est.center.dtype
    J = est.center.shape[0]
    bp, bo, bm = problem.box_pose, problem.box_object, problem.box_mask
    poses = est.camera_T_world[bp]
    uv = 0.5 * (problem.box[:, :2] + problem.box[:, 2:])
    origin = invert_pose(poses)[:, :3, 3]
    far = back_project(uv, jnp.ones(uv.shape[:-1], dtype), problem.K, poses)
    d = far - origin
    d = d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    P = jnp.eye(3, dtype=dtype) - d[:, :, None] * d[:, None, :]
    w = bm.astype(dtype)[:, None, None]
    A = jnp.zeros((J, 3, 3), dtype).at[bo].add(w * P)
    b = jnp.zeros((J, 3), dtype).at[bo].add(w[..., 0] * jnp.einsum("mij,mj->mi", P, origin))
    n = jnp.zeros(J, dtype).at[bo].add(bm.astype(dtype))
    eig_min = jnp.linalg.eigvalsh(A)[:, 0]
    well = eig_min >= 1e-3 * jnp.maximum(n, 1.0)
    A_safe = jnp.where(well[:, None, None], A, jnp.eye(3, dtype=dtype))
    point = jnp.linalg.solve(A_safe, b[..., None])[..., 0]
    z = jnp.einsum("mj,mj->m", poses[:, 2, :3], point[bo]) + poses[:, 2, 3]
    behind = jnp.zeros(J, bool).at[bo].max(bm & (z < jnp.asarray(min_depth, dtype)))
    return point, well & ~behind & jnp.all(jnp.isfinite(point), -1)


def _rescue(problem: SlamProblem, est: SlamEstimate, config: SolverConfig):
    """Suspect objects: no valid projection in one of their frames, or a whitened box-edge RMS
    above ``config.unfixable_rms`` at ``est``. Those whose box-centre rays triangulate well are
    re-placed there (rotation and radii kept)."""
    invalid, rms = box_health(problem, est, config)
    suspect = (invalid | (rms > config.unfixable_rms)) & problem.object_mask
    point, ok = _triangulate(problem, est, config.min_depth)
    move = suspect & ok
    center = jnp.where(move[:, None], point, est.center)
    return (
        SlamEstimate(est.camera_T_world, est.rotation, center, est.radii),
        suspect,
        move,
    )


def _mask_objects(problem: SlamProblem, keep) -> SlamProblem:
    bm = problem.box_mask & keep[problem.box_object]
    return eqx.tree_at(lambda p: (p.box_mask, p.texture_mask), problem, (bm, problem.texture_mask & bm))


@functools.partial(jax.jit, static_argnames=("max_steps", "throw"))
def solve_schur(
    problem: SlamProblem,
    init: SlamEstimate | None = None,
    config: SolverConfig = SolverConfig(),
    *,
    max_steps: int | None = None,
    pose_free=None,
    throw: bool = False,
) -> tuple[SlamEstimate, SolveInfo]:
    """Structured Levenberg-Marquardt (Schur complement over the pose blocks).

    With ``config.robust_init`` (the default) a solve has up to three phases:

    1. objects with no valid projection in one of their frames at ``init`` (e.g. QuadricSLAM's
       plain initialisation 10 m along the first bearing, which the camera later passes), or
       whose box edges disagree with the data by more than ``config.unfixable_rms`` sigmas
       (RMS), are "stranded"; they are re-placed at the triangulated intersection of their
       box-centre rays when the rays are well spread (rotation and radii kept);
    2. the stranded objects alone are solved with every pose held (poses cannot be pulled);
       those still invalid, or with a box-edge RMS above ``config.unfixable_rms`` sigmas, are
       flagged ``info.unfixable`` and left out of phase 3 (their boxes are masked there);
    3. the joint solve of poses and the remaining objects.

    Without stranded objects phases 1-2 cost one health check and one linearisation.

    Args:
      problem, init, config: as :func:`solve_batch` (``init`` None: :func:`jaxsem.slam.initialize`
        with ``config``).
      max_steps: static step cap per phase (default ``config.max_steps``).
      pose_free: optional (T,) bool/float, poses held fixed where False (a sliding window).
      throw: raise at run time when the result is not successful.

    Jitted (``max_steps`` and ``throw`` static); call it inside ``jit`` / ``vmap`` freely.

    Returns:
      (estimate, :class:`SolveInfo`). ``info.result`` follows phase 3 (or phase 2 when it
      failed non-finitely), and is ``nonfinite`` whenever the input, the final state or the
      final cost is not finite; a phase 3 that met the stopping rule while some real object is
      unfixable reports ``RESULTS.unfixable_objects``, never ``successful``.
    """
    max_steps = config.max_steps if max_steps is None else int(max_steps)
    init = _cast(problem, initialize(problem, config) if init is None else init)
    dtype = init.center.dtype
    J = init.center.shape[0]
    if pose_free is None:
        pose_free = problem.pose_mask
    pose_free = jnp.asarray(pose_free, dtype) * problem.pose_mask.astype(dtype)
    obj_used = problem.object_mask
    input_finite = _all_finite(problem) & _all_finite(init)
    cost0 = total_cost(problem, init, config)

    if config.robust_init:
        est, stranded, rescued = _rescue(problem, init, config)

        def phase(carry, k):
            # k = 0: the stranded objects alone, poses held; k = 1: the joint solve without the
            # objects found unfixable in phase 0. One scan body: the LM compiles once.
            est, unfixable, steps, accepted, code_a = carry
            keep = ~unfixable
            sub = _mask_objects(problem, keep)
            pf = jnp.where(k == 0, jnp.zeros_like(pose_free), pose_free)
            of = jnp.where(k == 0, stranded, obj_used & keep)
            rtol = jnp.where(k == 0, jnp.maximum(config.rescue_rtol, config.rtol), config.rtol)
            cfg = config.replace(rtol=rtol)
            est, _, s, a, code = levenberg_marquardt(sub, est, cfg, pf, of, max_steps)
            invalid, rms = box_health(problem, est, config)
            found = stranded & (invalid | (rms > config.unfixable_rms))
            unfixable = jnp.where(k == 0, found, unfixable)
            code_a = RESULTS.where(k == 0, code, code_a)
            return (est, unfixable, steps + s, accepted + a, code_a), code

        zero = jnp.asarray(0, jnp.int32)
        carry0 = (est, jnp.zeros(J, bool), zero, zero, _code(RESULTS.successful))
        (est, unfixable, steps, accepted, code_a), codes = jax.lax.scan(phase, carry0, jnp.arange(2))
        code = jax.tree_util.tree_map(lambda v: v[1], codes)
    else:
        rescued = unfixable = jnp.zeros(J, bool)
        est, _, steps, accepted, code = levenberg_marquardt(problem, init, config, pose_free, obj_used, max_steps)
        code_a = RESULTS.successful
    cost = total_cost(problem, est, config)
    finite = input_finite & _all_finite(est) & jnp.isfinite(cost) & jnp.isfinite(cost0)
    result = RESULTS.where(code_a == RESULTS.nonfinite, RESULTS.nonfinite, code)
    some_unfixable = jnp.any(unfixable & obj_used)
    result = RESULTS.where((result == RESULTS.successful) & some_unfixable, RESULTS.unfixable_objects, result)
    result = RESULTS.where(has_measurements(problem), result, RESULTS.no_measurements)
    result = RESULTS.where(finite, result, RESULTS.nonfinite)
    info = SolveInfo(
        result=result,
        success=result == RESULTS.successful,
        steps=steps,
        accepted=accepted,
        initial_cost=cost0,
        cost=cost,
        unfixable=unfixable & obj_used,
        rescued=rescued,
    )
    return _throw(result, (est, info), throw)


# --------------------------------------------------------------------------------------------
# Many maps at once.

STRATEGIES = ("auto", "map", "vmap")


def default_strategy(backend: str | None = None) -> str:
    """``"map"`` on a CPU, ``"vmap"`` on an accelerator: what :func:`solve_many` picks for
    ``strategy="auto"``.

    Why: a vmapped Levenberg-Marquardt loop runs until its slowest member stops and pays for the
    batched linear algebra of every member at every step; on a CPU that is slower than solving
    the maps one after another (``benchmarks/RESULTS.md``, "ROSHAN object SLAM", "Solver
    speed"), while an accelerator has the lanes to spare."""
    return "map" if (backend or jax.default_backend()) == "cpu" else "vmap"


@functools.partial(jax.jit, static_argnames=("strategy", "method"))
def _solve_many(problems, inits, config, strategy: str, method: str):
    def one(pi):
        return solve_batch(pi[0], pi[1], config, method=method)

    if strategy == "vmap":
        return jax.vmap(one)((problems, inits))
    return jax.lax.map(one, (problems, inits))


def solve_many(
    problems: SlamProblem,
    inits: SlamEstimate,
    config: SolverConfig = SolverConfig(),
    *,
    strategy: str = "auto",
    method: str = "schur",
) -> tuple[SlamEstimate, SolveInfo]:
    """Solves a batch of maps (every leaf with the same leading axis ``B``; see
    :func:`jaxsem.slam.stack_problems`) in one compiled program.

    strategy: ``"map"`` solves the maps one after another inside the program (``lax.map``): each
      map gets exactly the answer it gets solved alone, and a CPU runs no slower than a Python
      loop of jitted solves; ``"vmap"`` solves them side by side (``jax.vmap``; the loop runs
      until the slowest map stops, batched kernels round differently in the last bits, so a
      map that stops on its step budget may end elsewhere than alone); ``"auto"``
      (:func:`default_strategy`): ``"map"`` on a CPU, ``"vmap"`` on an accelerator.
    method: :func:`solve_batch`'s solver.

    Returns ``(estimates, infos)`` batched along ``B``.
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    if method not in ("schur", "optimistix"):
        raise ValueError(f"method: expected 'schur' or 'optimistix', got {method!r}")
    leaves = jax.tree_util.tree_leaves(problems) + jax.tree_util.tree_leaves(inits)
    sizes = {jnp.shape(leaf)[0] if jnp.ndim(leaf) else None for leaf in leaves}
    if len(sizes) != 1 or None in sizes:
        raise ValueError(
            f"problems, inits: expected every leaf batched along one leading axis, got leading sizes {sorted(map(str, sizes))}"
        )
    chosen = default_strategy() if strategy == "auto" else strategy
    many = functools.partial(_solve_many, strategy=chosen, method=method)
    return _stored(f"solve_many_{chosen}_{method}", many, problems, inits, config)

"""The factor graph of eq. 4.13 assembled from :mod:`jaxsem.factors`, shared by every solver.

Variables are updated as tangent deltas around an anchor estimate (:class:`Delta`):
``pose <- pose_anchor @ SE3.exp(dp)`` (right perturbation, jaxlie), ``R <- R_anchor @ SO3.exp(dw)``,
``center <- center_anchor + dc``, ``radii <- softplus(softplus^-1(radii_anchor) + ds)``.

Residual blocks (whitened, masked entries exactly zero):

- boxes: (M, 7) = 4 edges, near-depth barrier, camera-inside barrier, texture plane;
- pose priors: (T, 6); shape priors: (J, 3), plus 2 columns with the optional upright prior
  and 1 with the optional support prior;
- odometry (only when the problem has it): (T, 6), row ``t`` between poses ``t`` and ``t + 1``.

Each box row touches exactly one pose and one ellipsoid, which the structured solver exploits;
an odometry row touches two consecutive poses (the pose blocks become block-tridiagonal,
:class:`Normal`'s ``Hpp_next``).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie

from .. import factors as F, quadrics as Q
from ..quadrics import project_bbox
from ._problem import SlamEstimate, SlamProblem
from ._solver_config import SolverConfig

BOX_ROWS = F.BOX_RESIDUAL_DIM + 1  # + texture plane


class Delta(eqx.Module):
    """Tangent-space update: pose (T, 6) ``[v, omega]``, rotation (J, 3), center (J, 3),
    radii parameter (J, 3)."""

    pose: jnp.ndarray
    rotation: jnp.ndarray
    center: jnp.ndarray
    radii: jnp.ndarray


def _jaxlie_dtype():
    """jaxlie computes in the default float dtype: its exp mixes float32 input with its own
    float64 constants under x64 (refused by strict dtype promotion; standard promotion did the
    same computation in float64). The result is cast back to the caller's dtype."""
    return jnp.result_type(float)


def zero_delta(estimate: SlamEstimate) -> Delta:
    dtype = estimate.center.dtype
    T = estimate.camera_T_world.shape[-3]
    J = estimate.center.shape[-2]
    return Delta(
        jnp.zeros((T, 6), dtype),
        jnp.zeros((J, 3), dtype),
        jnp.zeros((J, 3), dtype),
        jnp.zeros((J, 3), dtype),
    )


def retract_pose(pose, dp):
    """``pose @ SE3.exp(dp)`` on matrices, (..., 4, 4).

    Multiplying matrices (rather than ``SE3.from_matrix(pose) @ ...``) avoids the branchy
    matrix-to-quaternion conversion, which dominates compile time under ``jacfwd``.
    """
    # Cast: jaxlie's SE3.exp promotes float32 to float64 under x64.
    return pose @ jaxlie.SE3.exp(dp.astype(_jaxlie_dtype())).as_matrix().astype(pose.dtype)


def retract_object(rotation, center, radii, dobj):
    """Applies a 9-vector ``[dw, dc, ds]`` to one ellipsoid (or a batch of them)."""
    R = rotation @ jaxlie.SO3.exp(dobj[..., 0:3].astype(_jaxlie_dtype())).as_matrix().astype(rotation.dtype)
    c = center + dobj[..., 3:6]
    r = F.radii_from_param(F.param_from_radii(radii) + dobj[..., 6:9])
    return R, c, r


def first_order_pose(pose, dp):
    """``pose @ (I + hat(dp))``: equals :func:`retract_pose` to first order at ``dp = 0``.

    Jacobians are only ever taken at ``dp = 0`` (relinearisation), where this gives exactly the
    same derivative as the exponential map with a far smaller graph (faster compiles).
    """
    top = jnp.concatenate([Q.skew(dp[..., 3:6]), dp[..., 0:3, None]], -1)
    xi = jnp.concatenate([top, jnp.zeros_like(top[..., :1, :])], -2)
    return pose + pose @ xi


def first_order_object(rotation, center, radii, dobj):
    """First-order twin of :func:`retract_object` (exact derivative at ``dobj = 0``)."""
    R = rotation + rotation @ Q.skew(dobj[..., 0:3])
    r = F.radii_from_param(F.param_from_radii(radii) + dobj[..., 6:9])
    return R, center + dobj[..., 3:6], r


def retract(estimate: SlamEstimate, delta: Delta) -> SlamEstimate:
    R, c, r = retract_object(
        estimate.rotation,
        estimate.center,
        estimate.radii,
        jnp.concatenate([delta.rotation, delta.center, delta.radii], -1),
    )
    return SlamEstimate(retract_pose(estimate.camera_T_world, delta.pose), R, c, r)


def class_table(config: SolverConfig, dtype, problem: SlamProblem | None = None):
    """``(mean (C, 3), sigma (C, 3))`` semi-axis shape priors a solve uses: the problem's class
    table (``problem.classes``, the built-in one when None), each array overridden by the
    config's ``shape_prior_mean`` / ``shape_prior_sigma`` when set."""
    mean, sigma = F.shape_prior_table(dtype, None if problem is None else problem.classes)
    if config.shape_prior_mean is not None:
        mean = jnp.asarray(config.shape_prior_mean, dtype)
    if config.shape_prior_sigma is not None:
        sigma = jnp.asarray(config.shape_prior_sigma, dtype)
    return mean, sigma


def box_rows(
    pose,
    rotation,
    center,
    radii,
    box,
    texture_depth,
    texture_mask,
    box_mask,
    K,
    image_size,
    config: SolverConfig,
    projection=None,
    cut=None,
):
    """(7,) whitened residual rows of one box factor as every jaxsem solver sees them (unbatched;
    vmap over boxes): the six box rows of :func:`jaxsem.factors.box_residual` with the config's
    noise, barriers and robust loss, then the texture-plane row (zero when the config or
    ``texture_mask`` leaves it out); all zero where ``box_mask`` is False. Public so that other
    solvers (the jaxls anchor in ``benchmarks/``) minimise exactly jaxsem's cost.

    ``projection``: optional ``(box, valid)`` standing in for the projection of the ellipsoid with
    its radii times ``config.silhouette_scale`` (see :func:`jaxsem.factors.box_residual`).
    ``cut``: optional (4,) bool, the edges an occluder may have cut (``SlamProblem.box_cut``):
    ``config.box_outward_scale`` applies to those only (default: to every edge)."""
    n = config.noise
    outward = jnp.asarray(config.box_outward_scale, radii.dtype)
    if cut is not None:
        outward = jnp.where(cut, outward, jnp.ones((), radii.dtype))
    r = F.box_residual(
        pose,
        rotation,
        center,
        radii * jnp.asarray(config.silhouette_scale, radii.dtype),
        box,
        K,
        image_size,
        box_sigma=n.box_sigma,
        border_margin=config.border_margin,
        barrier_weight=config.barrier_weight,
        min_depth=config.min_depth,
        degenerate_residual=config.degenerate_residual,
        loss=config.box_loss,
        robust_scale=config.robust_scale,
        projection=projection,
        outward_scale=outward,
    )
    if config.use_texture:
        t = F.texture_residual(
            pose, rotation, center, radii, texture_depth, n.texture_sigma, config.texture_plane_fraction
        )
        t = F.robust_residual(t, config.texture_loss, config.robust_scale)
        t = jnp.where(texture_mask, t, 0.0)
    else:
        t = jnp.zeros((), r.dtype)
    rows = jnp.concatenate([r, t[None]])
    return jnp.where(box_mask, rows, 0.0)


def pose_rows(pose, prior, mask, config: SolverConfig, weight=None):
    """(6,) whitened pose-prior rows of one pose (:func:`jaxsem.factors.pose_prior_residual` with
    the config's sigmas and robust loss; zero where ``mask`` is False). ``weight``: optional (2,)
    ``[translation, rotation]`` multipliers of the whitened rows (the problem's
    ``pose_prior_weight`` row; 0 = no prior)."""
    n = config.noise
    r = F.pose_prior_residual(pose, prior, n.pose_rotation_sigma, n.pose_translation_sigma)
    if weight is not None:
        r = r * jnp.repeat(jnp.asarray(weight, r.dtype), 3)
    r = F.robust_residual(r, config.pose_loss, config.robust_scale)
    return jnp.where(mask, r, 0.0)


def prior_weight(problem: SlamProblem):
    """(T, 2) pose-prior weights of the problem (ones when it has none)."""
    if problem.pose_prior_weight is not None:
        return problem.pose_prior_weight
    return jnp.ones(problem.pose_prior.shape[:-2] + (2,), problem.pose_prior.dtype)


def odometry_rows(pose_a, pose_b, measured, mask, config: SolverConfig):
    """(6,) whitened odometry rows between two poses (:func:`jaxsem.factors.between_residual`
    with the config's odometry sigmas and the pose loss; zero where ``mask`` is False)."""
    n = config.noise
    r = F.between_residual(pose_a, pose_b, measured, n.odometry_rotation_sigma, n.odometry_translation_sigma)
    r = F.robust_residual(r, config.pose_loss, config.robust_scale)
    return jnp.where(mask, r, 0.0)


def _odometry_block(problem: SlamProblem, poses, config: SolverConfig):
    nxt = jnp.roll(poses, -1, axis=0)
    return jax.vmap(odometry_rows, in_axes=(0, 0, 0, 0, None))(
        poses, nxt, problem.odometry, problem.odometry_mask, config
    )


def shape_weight(config: SolverConfig, dtype):
    """Multiplier of the whitened shape residual: ROSHAN's prior, or the baseline's weak one."""
    if config.use_shape_prior:
        return 1.0 / jnp.asarray(config.noise.shape_prior_scale, dtype)
    bw = jnp.asarray(config.baseline_shape_weight, dtype)
    return jnp.where(bw > 0, 1.0 / jnp.where(bw > 0, bw, 1.0), 0.0)


def shape_rows(radii, object_class, mask, config: SolverConfig, mean, sigma):
    """(3,) shape-prior residual of one object (``mean``/``sigma`` are the (C, 3) table)."""
    r = F.shape_prior_residual(radii, mean[object_class], sigma[object_class])
    r = F.robust_residual(r * shape_weight(config, radii.dtype), config.shape_loss, config.robust_scale)
    return jnp.where(mask, r, 0.0)


def upright_rows(rotation, mask, config: SolverConfig):
    """(2,) whitened upright-prior rows of one object (:func:`jaxsem.factors.upright_residual`
    with the config's ``world_up`` / ``upright_sigma`` and the shape loss; zero where ``mask``
    is False)."""
    r = F.upright_residual(rotation, jnp.asarray(config.world_up, rotation.dtype), config.upright_sigma)
    r = F.robust_residual(r, config.shape_loss, config.robust_scale)
    return jnp.where(mask, r, 0.0)


def support_rows(rotation, center, radii, mask, config: SolverConfig):
    """(1,) whitened support-prior row of one object (:func:`jaxsem.factors.support_residual`
    with the config's ``world_up`` / ``support_height`` / ``support_sigma`` and the shape loss;
    zero where ``mask`` is False)."""
    r = F.support_residual(
        rotation,
        center,
        radii,
        jnp.asarray(config.world_up, rotation.dtype),
        config.support_height,
        config.support_sigma,
    )
    r = F.robust_residual(r, config.shape_loss, config.robust_scale)
    return jnp.where(mask, r, 0.0)


def residual_blocks(problem: SlamProblem, estimate: SlamEstimate, config: SolverConfig):
    """All residuals: ``(boxes (M, 7), poses (T, 6), shapes (J, 3), plus 2 columns with the
    upright prior and 1 with the support prior)``, and ``odometry (T, 6)``
    as a fourth block when the problem has odometry (``problem.odometry`` not None)."""
    dtype = estimate.center.dtype
    mean, sigma = class_table(config, dtype, problem)
    bp, bo = problem.box_pose, problem.box_object
    boxes = jax.vmap(box_rows, in_axes=(0, 0, 0, 0, 0, 0, 0, 0, None, None, None, None, 0))(
        estimate.camera_T_world[bp],
        estimate.rotation[bo],
        estimate.center[bo],
        estimate.radii[bo],
        problem.box,
        problem.texture_depth,
        problem.texture_mask,
        problem.box_mask,
        problem.K,
        problem.image_size,
        config,
        None,
        problem.box_cut,
    )
    poses = jax.vmap(pose_rows, in_axes=(0, 0, 0, None, 0))(
        estimate.camera_T_world, problem.pose_prior, problem.pose_mask, config, prior_weight(problem)
    )
    shapes = jax.vmap(shape_rows, in_axes=(0, 0, 0, None, None, None))(
        estimate.radii, problem.object_class, problem.object_mask, config, mean, sigma
    )
    if config.use_upright:
        up = jax.vmap(upright_rows, in_axes=(0, 0, None))(estimate.rotation, problem.object_mask, config)
        shapes = jnp.concatenate([shapes, up], axis=-1)
    if config.use_support:
        sup = jax.vmap(support_rows, in_axes=(0, 0, 0, 0, None))(
            estimate.rotation, estimate.center, estimate.radii, problem.object_mask, config
        )
        shapes = jnp.concatenate([shapes, sup], axis=-1)
    if problem.odometry is not None:
        return boxes, poses, shapes, _odometry_block(problem, estimate.camera_T_world, config)
    return boxes, poses, shapes


class RoshanArgs(NamedTuple):
    """The ``args`` that :func:`jaxsem.slam.roshan_solver`'s solver and :func:`roshan_residuals`
    take (``optx.least_squares(roshan_residuals, roshan_solver(config), init, args)``). A named
    tuple, so it unpacks as the plain 4-tuple ``(problem, config, pose_free, obj_free)`` did.

    Fields:
      problem: the :class:`SlamProblem`.
      config: the :class:`SolverConfig` (cost weights, stopping rule, damping).
      pose_free: (T,) float, 1 where a pose is optimised and 0 where it is held (e.g. the poses
        outside an online window); of the estimate's float dtype.
      obj_free: (J,) bool, True where an object is optimised.
    """

    problem: SlamProblem
    config: SolverConfig
    pose_free: jax.Array
    obj_free: jax.Array

    @classmethod
    def create(cls, problem: SlamProblem, config: SolverConfig, pose_free=None, obj_free=None) -> RoshanArgs:
        """Checked arguments: ``pose_free`` defaults to every real pose (as :func:`jaxsem.slam.solve_batch`:
        the pose priors fix the gauge), ``obj_free`` to every real object; a wrong shape raises
        ValueError naming the field."""
        T, J = problem.pose_mask.shape[-1], problem.object_mask.shape[-1]
        dtype = problem.box.dtype
        if pose_free is None:
            pose_free = problem.pose_mask
        if obj_free is None:
            obj_free = problem.object_mask
        pose_free, obj_free = jnp.asarray(pose_free, dtype), jnp.asarray(obj_free, bool)
        for name, value, n in (("pose_free", pose_free, T), ("obj_free", obj_free, J)):
            if value.shape != (n,):
                raise ValueError(f"{name}: expected shape ({n},) for this problem, got {tuple(value.shape)}")
        return cls(problem, config, pose_free, obj_free)


def roshan_residuals(estimate: SlamEstimate, args: RoshanArgs) -> tuple[jax.Array, ...]:
    """The residual function of :func:`jaxsem.slam.roshan_solver`'s least squares:
    :func:`residual_blocks` of ``args.problem`` at ``estimate`` under ``args.config`` (the
    ``pose_free`` / ``obj_free`` masks act in the solver's step, not here)."""
    return residual_blocks(args[0], estimate, args[1])


def total_cost(problem: SlamProblem, estimate: SlamEstimate, config: SolverConfig):
    """``0.5 * sum(r**2)`` over all factors (scalar): the quantity every solver minimises."""
    blocks = residual_blocks(problem, estimate, config)
    return jnp.asarray(0.5 * sum(jnp.sum(jnp.square(b)) for b in blocks))


# --------------------------------------------------------------------------------------------
# Linearisation in block form (the structured solvers' view of the same cost).


class Normal(NamedTuple):
    """Gauss-Newton normal equations ``J^T J`` and ``J^T r`` in block form.

    ``Hpp`` (T, 6, 6) pose blocks, ``Hoo`` (J, 9, 9) object blocks, ``Hpo`` (T, J, 6, 9) the
    pose-object coupling, ``gp`` (T, 6) and ``go`` (J, 9) the gradient. ``cost`` () is
    ``0.5 * sum(r**2)`` at the linearisation point (:func:`total_cost`). ``Hpp_next`` (T, 6, 6)
    (only with odometry, else None) couples consecutive poses: block ``(t, t + 1)`` of the
    pose-pose matrix, which is then block-tridiagonal (its transpose is block ``(t + 1, t)``).
    """

    Hpp: jnp.ndarray
    Hoo: jnp.ndarray
    Hpo: jnp.ndarray
    gp: jnp.ndarray
    go: jnp.ndarray
    cost: jnp.ndarray
    Hpp_next: jnp.ndarray | None = None


def linearize(problem: SlamProblem, est: SlamEstimate, config: SolverConfig, pose_free) -> Normal:
    """Block normal equations at ``est`` from per-factor ``jacfwd`` (9 columns per box factor).

    Every box residual touches one pose and one ellipsoid, every pose prior one pose and every
    shape prior one ellipsoid, so the Jacobian is recovered exactly by a fixed number of
    forward-mode columns and accumulated into the blocks with scatter-adds. Poses where
    ``pose_free`` (T,) is 0 are held: their columns vanish.
    """
    dtype = est.center.dtype
    mean, sigma = class_table(config, dtype, problem)
    bp, bo = problem.box_pose, problem.box_object
    T, J = est.camera_T_world.shape[0], est.center.shape[0]

    # A box factor sees only the object in the camera frame (camera_T_object = pose @ W, with
    # W = [R, c] the object's pose), so its Jacobian is taken with respect to a 6-vector right
    # perturbation ``xi = [v, omega]`` of camera_T_object plus the 3 radii parameters: 9
    # forward-mode columns instead of 15. The chain rule gives the pose and object columns:
    #   pose @ (I + dp^) @ W = camera_T_object @ (I + (Ad(W^-1) dp)^)       -> J_p = J_xi Ad(W^-1)
    #   pose @ [R (I + dw^), c + dc] = camera_T_object @ (I + [R^T dc, dw]^) -> J_w, J_c below.
    # The box itself enters as its first-order model from the closed-form Jacobian (the camera
    # at camera_T_object sees the object at the origin, unrotated): its columns cost one
    # elementwise pass, and forward mode only runs through the barriers, the texture plane and
    # the robust loss.
    eye3 = jnp.eye(3, dtype=dtype)
    zero3 = jnp.zeros(3, dtype)
    scale = jnp.asarray(config.silhouette_scale, dtype)

    def box_fn(xi, ds, rel, r, box, td, tm, bm, box0, valid0, J_rel, J_radii, cut):
        r2 = F.radii_from_param(F.param_from_radii(r) + ds)
        # Products summed by hand: a batched matrix-vector product becomes a slow dot on the CPU.
        pred = box0 + jnp.sum(J_rel * xi, -1) + jnp.sum(J_radii * ((r2 - r) * scale), -1)
        out = box_rows(
            first_order_pose(rel, xi),
            eye3,
            zero3,
            r2,
            box,
            td,
            tm,
            bm,
            problem.K,
            problem.image_size,
            config,
            projection=(pred, valid0),
            cut=cut,
        )
        return out, out

    R_o, c_o = est.rotation[bo], est.center[bo]
    pose_b = est.camera_T_world[bp]
    W = jnp.concatenate(
        [
            jnp.concatenate([R_o, c_o[:, :, None]], -1),
            jnp.broadcast_to(jnp.eye(4, dtype=dtype)[3:], (R_o.shape[0], 1, 4)),
        ],
        -2,
    )
    rel = pose_b @ W
    r_b = est.radii[bo]
    box0, valid0, J_obj, J_rel = Q.project_bbox_jacobian(eye3, zero3, r_b * scale, problem.K, rel)
    z6, z3 = jnp.zeros(6, dtype), jnp.zeros(3, dtype)
    (Jxi, Jds), rb = jax.vmap(
        jax.jacfwd(box_fn, argnums=(0, 1), has_aux=True),
        in_axes=(None, None, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
    )(
        z6,
        z3,
        rel,
        r_b,
        problem.box,
        problem.texture_depth,
        problem.texture_mask,
        problem.box_mask,
        box0,
        valid0,
        J_rel,
        J_obj[..., 6:9],
        problem.box_cut,
    )
    # Ad(W^-1) for [v, omega] tangents: W^-1 = (R^T, -R^T c); Ad(R', t') = [[R', t'^ R'], [0, R']].
    Rt = jnp.swapaxes(R_o, -1, -2)
    t_inv = -jnp.einsum("mij,mj->mi", Rt, c_o)
    Jv, Jw = Jxi[..., 0:3], Jxi[..., 3:6]
    Jp = jnp.concatenate([Jv @ Rt, Jv @ (Q.skew(t_inv) @ Rt) + Jw @ Rt], -1)
    Jo = jnp.concatenate([Jw, Jv @ Rt, Jds], -1)
    Jp = Jp * pose_free[bp][:, None, None]

    def pose_fn(dp, pose, prior, mask, weight):
        out = pose_rows(first_order_pose(pose, dp), prior, mask, config, weight)
        return out, out

    Jpp, rp = jax.vmap(jax.jacfwd(pose_fn, has_aux=True), in_axes=(None, 0, 0, 0, 0))(
        z6, est.camera_T_world, problem.pose_prior, problem.pose_mask, prior_weight(problem)
    )

    def shape_fn(ds, radii, cls, mask):
        r2 = F.radii_from_param(F.param_from_radii(radii) + ds)
        out = shape_rows(r2, cls, mask, config, mean, sigma)
        return out, out

    Js3, rs = jax.vmap(jax.jacfwd(shape_fn, has_aux=True), in_axes=(None, 0, 0, 0))(
        jnp.zeros(3, dtype), est.radii, problem.object_class, problem.object_mask
    )
    Js = jnp.zeros((J, 3, 9), dtype).at[:, :, 6:9].set(Js3)
    if config.use_upright:

        def up_fn(dw, R, mask):
            out = upright_rows(R @ jaxlie.SO3.exp(dw).as_matrix().astype(R.dtype), mask, config)
            return out, out

        Ju, ru = jax.vmap(jax.jacfwd(up_fn, has_aux=True), in_axes=(None, 0, 0))(
            jnp.zeros(3, dtype), est.rotation, problem.object_mask
        )
        Js = jnp.concatenate([Js, jnp.zeros((J, 2, 9), dtype).at[:, :, 0:3].set(Ju)], axis=1)
        rs = jnp.concatenate([rs, ru], axis=-1)
    if config.use_support:

        def sup_fn(d9, R, c, r, mask):
            out = support_rows(*first_order_object(R, c, r, d9), mask, config)
            return out, out

        Jsu, rsu = jax.vmap(jax.jacfwd(sup_fn, has_aux=True), in_axes=(None, 0, 0, 0, 0))(
            jnp.zeros(9, dtype), est.rotation, est.center, est.radii, problem.object_mask
        )
        Js = jnp.concatenate([Js, Jsu], axis=1)
        rs = jnp.concatenate([rs, rsu], axis=-1)

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
    cost = 0.5 * (jnp.sum(jnp.square(rb)) + jnp.sum(jnp.square(rp)) + jnp.sum(jnp.square(rs)))
    Hnext = None
    if problem.odometry is not None:
        # Row t ties pose t (columns a) to pose t + 1 (columns b); the last row is masked out.
        def odo_fn(da, db, pa, pb, meas, mask):
            out = odometry_rows(first_order_pose(pa, da), first_order_pose(pb, db), meas, mask, config)
            return out, out

        nxt = jnp.roll(est.camera_T_world, -1, axis=0)
        (Ja, Jb), ro = jax.vmap(jax.jacfwd(odo_fn, argnums=(0, 1), has_aux=True), in_axes=(None, None, 0, 0, 0, 0))(
            z6, z6, est.camera_T_world, nxt, problem.odometry, problem.odometry_mask
        )
        Ja = Ja * pose_free[:, None, None]
        Jb = Jb * jnp.roll(pose_free, -1)[:, None, None]
        JaT, JbT = jnp.swapaxes(Ja, -1, -2), jnp.swapaxes(Jb, -1, -2)
        Hpp = Hpp + JaT @ Ja + jnp.roll(JbT @ Jb, 1, axis=0)
        gp = gp + jnp.einsum("tij,ti->tj", Ja, ro) + jnp.roll(jnp.einsum("tij,ti->tj", Jb, ro), 1, axis=0)
        Hnext = JaT @ Jb
        cost = cost + 0.5 * jnp.sum(jnp.square(ro))
    gp = gp * pose_free[:, None]
    return Normal(Hpp, Hoo, Hpo, gp, go, cost, Hnext)


def box_health(problem: SlamProblem, est: SlamEstimate, config: SolverConfig):
    """Per-object diagnostics of the box factors at ``est``.

    Returns:
      ``(invalid, rms)``: (J,) bool, some real box of the object has no valid projection
      (ellipsoid behind or around that camera, camera inside it); (J,) root-mean-square of the
      object's whitened, constraining edge residuals (0 for objects without boxes).
    """
    dtype = est.center.dtype
    bp, bo, bm = problem.box_pose, problem.box_object, problem.box_mask
    J = est.center.shape[0]
    pred, valid = project_bbox(
        est.rotation[bo],
        est.center[bo],
        est.radii[bo],
        problem.K,
        est.camera_T_world[bp],
    )
    bad = bm & ~valid
    invalid = jnp.zeros(J, bool).at[bo].max(bad)
    emask = F.edge_mask(problem.box, problem.image_size, config.border_margin) & bm[:, None]
    sigma = jnp.asarray(config.noise.box_sigma, dtype)
    e = jnp.where(emask & valid[:, None], (pred - problem.box) / sigma, 0.0)
    sq = jnp.zeros(J, dtype).at[bo].add(jnp.sum(jnp.square(e), -1))
    n = jnp.zeros(J, dtype).at[bo].add(jnp.sum(emask, -1).astype(dtype))
    rms = jnp.sqrt(sq / jnp.maximum(n, 1.0))
    return invalid, rms

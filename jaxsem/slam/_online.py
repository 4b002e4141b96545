"""Online smoother (section 4.3.6) with an optax-like functional API.

    state = online_init(config, capacity, K, image_size)
    for frame in frames:                      # jaxsem.slam.Frame / make_frame(...)
        state = online_update(state, frame)   # one jitted step, compiled once per capacity
    state = online_optimize(state)            # optional final optimisation (the same step)
    estimate = online_estimate(state)

All buffers have the static sizes of :class:`~jaxsem.slam.Capacity` (poses, boxes, objects,
detections per frame) with masks, so nothing recompiles as frames arrive. Poses live in a ring
of ``max_poses`` slots: once it wraps, the oldest pose and its box factors are dropped (not
marginalised), so size ``max_poses`` to the horizon you want to keep. Boxes live in a ring of
``max_boxes``; when it wraps the oldest box factors are dropped. Object slots are the association
ids (``0 <= object_id < max_objects``); an id seen for the first time is initialised from that
single detection (section 4.3.5).

Every ``optimize_every`` frames the graph is relinearised and ``iterations`` steps of the
structured (Schur) Levenberg-Marquardt of :func:`jaxsem.slam._batch.solve_schur` are run over the poses
of the last ``window`` frames (older poses held fixed) and all objects.

Pose factors. By default every frame's ``pose_prior`` is an absolute prior at the noise model's
sigmas (``prior_weights`` all ones, no odometry). Integrated odometry drifts away from such priors,
which then pin the map to the drift; the batch solve reads it instead as a prior on the first
pose and between factors along the chain. ``online_init(..., odometry=True, prior_weights=
[[w_t, w_r], [0, 0]])`` builds the same graph online: a between factor
(:func:`jaxsem.slam._cost.odometry_rows`, the batch solve's) from each frame to the next whose
mean is the relative motion of their pose priors, ``prior_t @ inv(prior_t+1)``, an absolute prior
on the first frame only (row 0 of ``prior_weights``; row 1 weighs every later frame, 0 = none),
and each new pose started where the odometry carries the previous pose's current estimate (not at
its absolute prior). The object factors (boxes, texture planes, shape, upright and support priors)
are the batch solve's, from the same config. When the pose ring wraps, the pose that becomes the
oldest is anchored at its current estimate with row 0's weights (the dropped frames' information,
approximately); the between factor across the ring's end (slot ``max_poses - 1`` to slot 0) enters
the cost and the gradient exactly but its off-diagonal Hessian block is left out of the step (the
Schur step's pose part is block-tridiagonal, not cyclic), so those steps are approximate Gauss-Newton
steps that the damping rule still only accepts when they lower the cost.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import classes as _classes
from ..quadrics import invert_pose
from ._batch import levenberg_marquardt
from ._cost import class_table, prior_weight
from ._init import box_init
from ._problem import Capacity, Frame, SlamEstimate, SlamProblem, has_measurements
from ._results import RESULTS
from ._schur import _all_finite
from ._solver_config import SolverConfig


class OnlineState(eqx.Module):
    """State of the online smoother (a pytree; the int settings are static).

    Attributes:
      problem: :class:`SlamProblem` at capacity (pose slots, box ring, object slots).
      estimate: :class:`SlamEstimate` of the same sizes.
      pose_frame: (P,) int32 frame number held by each pose slot (-1 = empty).
      frame_count: () int32 frames seen. box_count: () int32 boxes written.
      result: :data:`jaxsem.slam._results.RESULTS` of this frame's update: ``successful`` when the
        frame needed no optimisation or its LM met the stopping rule with a finite state;
        ``iterations_reached`` when the ``iterations`` budget ran out first (normal online,
        the next optimisation continues); ``no_measurements`` while no frame has brought a
        usable box; a failure code otherwise.
      config: :class:`SolverConfig`.
      prior_weights: (2, 2) ``[translation, rotation]`` multipliers of the whitened absolute
        pose-prior rows: row 0 for the first frame (and the oldest kept pose once the ring wraps
        with odometry), row 1 for every later frame (0 = no absolute prior).
      optimize_every, iterations, window, max_detections: static ints.
      odometry: static bool, between factors from each frame to the next (module docstring).
    """

    problem: SlamProblem
    estimate: SlamEstimate
    pose_frame: jnp.ndarray
    frame_count: jnp.ndarray
    box_count: jnp.ndarray
    result: RESULTS
    config: SolverConfig
    prior_weights: jnp.ndarray
    optimize_every: int = eqx.field(static=True)
    iterations: int = eqx.field(static=True)
    window: int = eqx.field(static=True)
    max_detections: int = eqx.field(static=True)
    odometry: bool = eqx.field(static=True, default=False)


def online_init(
    config: SolverConfig,
    capacity: Capacity,
    K,
    image_size,
    *,
    optimize_every: int = 5,
    iterations: int = 3,
    window: int | None = None,
    dtype=None,
    classes=None,
    odometry: bool = False,
    prior_weights=None,
) -> OnlineState:
    """Empty smoother.

    Args:
      config: :class:`SolverConfig` (factors, noise, robust losses).
      capacity: :class:`Capacity` (static sizes).
      K: (3, 3) intrinsics; image_size: (2,) ``[width, height]``.
      optimize_every: relinearise and optimise every this many frames (>= 1).
      iterations: LM iterations per optimisation.
      window: number of most recent frames whose poses are optimised (default: all kept).
      classes: the :class:`jaxsem.classes.ClassTable` of the frames' ``box_class`` (default: the
        built-in table; build frames with ``make_frame(..., classes=...)`` of the same table).
      odometry: add a between factor from each frame to the next, measured as the relative
        motion of their ``pose_prior`` (integrated odometry), at the config's odometry sigmas.
      prior_weights: (2, 2) finite, >= 0: ``[translation, rotation]`` multipliers of the absolute
        pose priors, row 0 for the first frame, row 1 for the others (default: all ones, an
        absolute prior on every frame). With ``odometry``, e.g. ``[[w_t, w_r], [0, 0]]``: a prior
        on the first frame only, as the batch solve's ``pose_prior_weight`` of
        :func:`jaxsem.slam.pose_prior_weights` ``"first"``. A value, not a static setting: other
        weights reuse the compiled step.

    Raises:
      ValueError: a bad size, ``K``, ``image_size`` or ``prior_weights`` (naming it); no gauge
        (``prior_weights[0]`` zero in translation or rotation).
    """
    if optimize_every < 1 or iterations < 1:
        raise ValueError(f"optimize_every, iterations: expected >= 1, got {optimize_every}, {iterations}")
    P, J, B, D = capacity
    if min(P, J, B, D) < 1:
        raise ValueError(f"capacity: every size must be >= 1, got {capacity}")
    dtype = dtype or jnp.result_type(float)
    K = np.asarray(K, float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K: expected finite (3, 3) intrinsics, got shape {K.shape}")
    image_size = np.asarray(image_size, float)
    if image_size.shape != (2,) or not np.all(image_size > 0):
        raise ValueError(f"image_size: expected [width, height] > 0, got {image_size.tolist()}")
    weights = np.ones((2, 2)) if prior_weights is None else np.asarray(prior_weights, float)
    if weights.shape != (2, 2) or not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise ValueError(f"prior_weights: expected a finite (2, 2) array >= 0, got {weights.tolist()}")
    if not np.all(weights[0] > 0):
        raise ValueError(
            f"prior_weights: row 0 (the first frame) must be > 0 to fix the gauge, got {weights[0].tolist()}"
        )
    # Concrete, non-weak float leaves: the jitted update returns the same avals it was given,
    # so the second call hits the compilation cache. Everything is built on the host and put on
    # the device as is (eager jnp ops would each compile a small program: seconds in a CLI run).
    dtype = np.dtype(dtype)

    def put(x, dt: Any = dtype):
        return jax.device_put(np.asarray(x, dt))

    config = jax.tree_util.tree_map(
        lambda x: put(x) if isinstance(x, (float, int)) and not isinstance(x, bool) else x,
        config,
    )
    eye4 = put(np.broadcast_to(np.eye(4), (P, 4, 4)))
    problem = SlamProblem(
        K=put(K),
        image_size=put(image_size),
        pose_prior=eye4,
        pose_mask=put(np.zeros(P), bool),
        box=put(np.broadcast_to(np.asarray([0.0, 0.0, 1.0, 1.0]), (B, 4))),
        box_pose=put(np.zeros(B), np.int32),
        box_object=put(np.zeros(B), np.int32),
        box_mask=put(np.zeros(B), bool),
        texture_depth=put(np.zeros(B)),
        texture_mask=put(np.zeros(B), bool),
        object_class=put(np.zeros(J), np.int32),
        object_mask=put(np.zeros(J), bool),
        classes=None if classes is None else _classes.as_table(classes),
        odometry=eye4 if odometry else None,
        odometry_mask=put(np.zeros(P), bool) if odometry else None,
        pose_prior_weight=put(np.broadcast_to(weights[1], (P, 2))),
    )
    estimate = SlamEstimate(
        camera_T_world=eye4,
        rotation=put(np.broadcast_to(np.eye(3), (J, 3, 3))),
        center=put(np.zeros((J, 3))),
        radii=put(np.ones((J, 3))),
    )
    return OnlineState(
        problem=problem,
        estimate=estimate,
        pose_frame=put(np.full(P, -1), np.int32),
        frame_count=put(0, np.int32),
        box_count=put(0, np.int32),
        # A jax int32 code, not the enum's numpy constant: the second update hits the jit cache.
        result=jax.tree_util.tree_map(lambda v: put(v, np.int32), RESULTS.no_measurements),
        config=config,
        prior_weights=put(weights),
        optimize_every=int(optimize_every),
        iterations=int(iterations),
        window=int(P if window is None else window),
        max_detections=int(D),
        odometry=bool(odometry),
    )


def _pose_free(state: OnlineState):
    recent = state.pose_frame >= state.frame_count - state.window
    return state.problem.pose_mask & recent


def _optimize(state: OnlineState, iterations, free) -> OnlineState:
    """``iterations`` (an int, traced or not) LM steps over the poses where ``free`` and all objects."""
    dtype = state.problem.pose_prior.dtype
    # Plain LM (no rescue phases): online objects are initialised from one detection each.
    est, _, _, _, result = levenberg_marquardt(
        state.problem,
        state.estimate,
        state.config,
        free.astype(dtype),
        state.problem.object_mask,
        iterations,
    )
    # The budget here is `iterations` (not SolverConfig.max_steps): its own code and message.
    result = RESULTS.where(result == RESULTS.max_steps_reached, RESULTS.iterations_reached, result)
    return eqx.tree_at(lambda s: (s.estimate, s.result), state, (est, result))


def _pose_chain(state: OnlineState, slot, prior):
    """Pose factors and the new pose's start when frame ``state.frame_count`` enters ``slot``.

    Returns ``(pose_prior (P, 4, 4), weight (P, 2), odometry, odometry_mask, start (4, 4),
    cam (P, 4, 4))``: the frame's prior at its row of ``state.prior_weights`` (row 0 for the
    first frame); with odometry, the between factor from the previous slot to this one (its mean
    the pose priors' relative motion), none from the slot's old pose to the next, the new pose
    started at the previous pose's estimate moved by that motion, and, once the ring wraps, the
    oldest kept pose anchored at its estimate with row 0's weights (the module docstring)."""
    pb, est = state.problem, state.estimate
    P = pb.pose_prior.shape[0]
    first = state.frame_count == 0
    weight_row = jnp.where(first, state.prior_weights[0], state.prior_weights[1])
    pose_prior = pb.pose_prior.at[slot].set(prior)
    weight = prior_weight(pb).at[slot].set(weight_row)
    cam = est.camera_T_world
    if not state.odometry or pb.odometry is None or pb.odometry_mask is None:
        return pose_prior, weight, pb.odometry, pb.odometry_mask, prior, cam
    prev = (slot - 1) % P
    # camera_prev_T_camera_new from the two integrated poses (both camera_T_world).
    motion = pb.pose_prior[prev] @ invert_pose(prior)
    odometry = pb.odometry.at[prev].set(jnp.where(first, pb.odometry[prev], motion))
    odometry_mask = pb.odometry_mask.at[slot].set(False).at[prev].set(~first)
    start = jnp.where(first, prior, invert_pose(motion) @ est.camera_T_world[prev])
    # Wrapped: frame t - P + 1 (the next slot) is now the oldest pose, its chain to the dropped
    # frames is gone; it keeps the gauge at its current estimate.
    oldest = (slot + 1) % P
    wrapped = state.frame_count >= P
    pose_prior = pose_prior.at[oldest].set(jnp.where(wrapped, cam[oldest], pose_prior[oldest]))
    weight = weight.at[oldest].set(
        jnp.where(wrapped, jnp.maximum(weight[oldest], state.prior_weights[0]), weight[oldest])
    )
    return pose_prior, weight, odometry, odometry_mask, start, cam


def _insert(state: OnlineState, frame: Frame) -> OnlineState:
    pb, est, cfg = state.problem, state.estimate, state.config
    P = pb.pose_prior.shape[0]
    B = pb.box.shape[0]
    J = pb.object_class.shape[0]
    dtype = pb.pose_prior.dtype
    slot = state.frame_count % P
    # Reusing a slot drops the old pose's box factors.
    stale = pb.box_mask & (pb.box_pose == slot)
    box_mask = pb.box_mask & ~stale
    prior = jnp.asarray(frame.pose_prior, dtype)
    pose_prior, weight, odometry, odometry_mask, start, cam = _pose_chain(state, slot, prior)
    pose_mask = pb.pose_mask.at[slot].set(True)
    cam = cam.at[slot].set(start)
    pose_frame = state.pose_frame.at[slot].set(state.frame_count)

    # New objects: initialised from their (first) detection in this frame.
    det = frame.box_mask & (frame.object_id >= 0) & (frame.object_id < J)
    oid = jnp.clip(frame.object_id, 0, J - 1)
    is_new = det & ~pb.object_mask[oid]
    mean, _ = class_table(cfg, dtype, pb)
    tex_ok = frame.texture_mask & det if cfg.use_texture else jnp.zeros_like(det)
    det_box, det_depth = frame.box.astype(dtype), frame.texture_depth.astype(dtype)
    R0, c0, r0 = box_init(cfg, start, det_box, pb.K, mean[frame.box_class], det_depth, tex_ok, pb.image_size)
    # A detection that carries an initial ellipsoid (Frame.init_*) starts its new object there.
    given = frame.init_mask & is_new
    R0 = jnp.where(given[:, None, None], frame.init_rotation.astype(dtype), R0)
    c0 = jnp.where(given[:, None], frame.init_center.astype(dtype), c0)
    r0 = jnp.where(given[:, None], frame.init_radii.astype(dtype), r0)
    tgt = jnp.where(is_new, oid, J)  # J = out of range -> dropped
    rotation = est.rotation.at[tgt].set(R0, mode="drop")
    center = est.center.at[tgt].set(c0, mode="drop")
    radii = est.radii.at[tgt].set(r0, mode="drop")
    object_class = pb.object_class.at[tgt].set(frame.box_class, mode="drop")
    object_mask = pb.object_mask.at[tgt].set(True, mode="drop")

    # Box factors into the ring buffer.
    order = jnp.cumsum(det.astype(jnp.int32)) - 1
    pos = jnp.where(det, (state.box_count + order) % B, B)
    box = pb.box.at[pos].set(frame.box.astype(dtype), mode="drop")
    box_pose = pb.box_pose.at[pos].set(slot, mode="drop")
    box_object = pb.box_object.at[pos].set(oid, mode="drop")
    box_mask = box_mask.at[pos].set(True, mode="drop")
    tex_depth = pb.texture_depth.at[pos].set(frame.texture_depth.astype(dtype), mode="drop")
    tex_mask = pb.texture_mask.at[pos].set(frame.texture_mask & det, mode="drop")
    tex_mask = tex_mask & box_mask

    problem = SlamProblem(
        K=pb.K,
        image_size=pb.image_size,
        pose_prior=pose_prior,
        pose_mask=pose_mask,
        box=box,
        box_pose=box_pose,
        box_object=box_object,
        box_mask=box_mask,
        texture_depth=tex_depth,
        texture_mask=tex_mask,
        object_class=object_class,
        object_mask=object_mask,
        classes=pb.classes,
        odometry=odometry,
        odometry_mask=odometry_mask,
        pose_prior_weight=weight,
    )
    # The settings (config, prior weights, the static ints) carry over unchanged.
    return dataclasses.replace(
        state,
        problem=problem,
        estimate=SlamEstimate(cam, rotation, center, radii),
        pose_frame=pose_frame,
        frame_count=state.frame_count + 1,
        box_count=state.box_count + jnp.sum(det, dtype=jnp.int32),
        result=RESULTS.successful,
    )


def _check_frame(state: OnlineState, frame: Frame):
    if frame.box.shape != (state.max_detections, 4):
        raise ValueError(
            f"frame.box: expected shape ({state.max_detections}, 4) (capacity.max_detections), "
            f"got {frame.box.shape}; build frames with make_frame(..., max_detections=...)"
        )
    D = state.max_detections
    for name, shape in (
        ("init_rotation", (D, 3, 3)),
        ("init_center", (D, 3)),
        ("init_radii", (D, 3)),
        ("init_mask", (D,)),
    ):
        if getattr(frame, name).shape != shape:
            raise ValueError(f"frame.{name}: expected shape {shape}, got {getattr(frame, name).shape}")


def _online_step(state: OnlineState, frame: Frame, final, final_iterations) -> OnlineState:
    """One smoother step, the per-frame update and the final optimisation in one program.

    ``final`` () bool False: insert ``frame`` and, every ``optimize_every`` frames, run
    ``state.iterations`` LM steps over the window (:func:`online_update`). True: ``frame`` is
    ignored and ``final_iterations`` () int LM steps run over every kept pose
    (:func:`online_optimize`). Both modes share one LM call site, so a program that does both
    (:func:`jaxsem.slam.run_sequence`) traces and compiles the solver once.
    """
    _check_frame(state, frame)
    final = jnp.asarray(final, bool)
    state = jax.lax.cond(final, lambda s: s, lambda s: _insert(s, frame), state)
    due = final | ((state.frame_count % state.optimize_every) == 0)
    free = jnp.where(final, state.problem.pose_mask, _pose_free(state))
    iterations = jnp.where(final, jnp.asarray(final_iterations, jnp.int32), state.iterations)
    state = jax.lax.cond(due, lambda s: _optimize(s, iterations, free), lambda s: s, state)
    # Never success on non-finite data: this frame, the held graph or the estimate.
    finite = (final | _all_finite(frame)) & _all_finite(state.problem) & _all_finite(state.estimate)
    result = RESULTS.where(has_measurements(state.problem), state.result, RESULTS.no_measurements)
    result = RESULTS.where(finite, result, RESULTS.nonfinite)
    return eqx.tree_at(lambda s: s.result, state, result)


online_step = jax.jit(_online_step)
"""Jitted :func:`_online_step` ``(state, frame, final, final_iterations)``: the one executable
behind :func:`online_update` and :func:`online_optimize`."""


def online_update(state: OnlineState, frame: Frame) -> OnlineState:
    """Adds one :class:`Frame` and, every ``optimize_every`` frames, optimises.

    Runs :data:`online_step`, the one executable it shares with :func:`online_optimize`: the
    first call (of either) compiles it; later calls with the same capacity and dtype reuse it.
    Callable inside the user's ``jit`` too (then it is traced into that program).

    Args:
      state: :class:`OnlineState`; frame: :class:`Frame` with ``max_detections`` rows.

    Returns:
      the new :class:`OnlineState`; ``state.result`` is this frame's :data:`RESULTS` code.
    """
    _check_frame(state, frame)
    # The same argument types as online_optimize's (numpy bool and int32 scalars): one cache
    # entry of online_step for both. (A jit of its own around online_step would be a second
    # executable, so online_optimize would compile the step a second time.)
    return online_step(state, frame, np.asarray(False), np.asarray(0, np.int32))


def empty_frame(state: OnlineState) -> Frame:
    """A frame without detections of the state's size (host arrays only: nothing compiles)."""
    D = state.max_detections
    dtype = state.problem.pose_prior.dtype
    return Frame(
        pose_prior=jax.device_put(np.eye(4, dtype=dtype)),
        box=jax.device_put(np.tile(np.asarray([0.0, 0.0, 1.0, 1.0], dtype), (D, 1))),
        box_class=jax.device_put(np.zeros(D, np.int32)),
        texture_depth=jax.device_put(np.zeros(D, dtype)),
        texture_mask=jax.device_put(np.zeros(D, bool)),
        object_id=jax.device_put(np.zeros(D, np.int32)),
        box_mask=jax.device_put(np.zeros(D, bool)),
    )


def online_optimize(state: OnlineState, iterations: int = 50) -> OnlineState:
    """Relinearises and runs up to ``iterations`` LM steps over all kept poses and objects
    (the final optimisation after the last frame). ``state.result`` is the LM's code
    (``iterations_reached`` when the budget ran out first). Runs :data:`online_step`, the
    executable :func:`online_update` compiled: nothing new compiles."""
    if int(iterations) < 0:
        raise ValueError(f"iterations: expected >= 0, got {iterations}")
    return online_step(state, empty_frame(state), np.asarray(True), np.asarray(iterations, np.int32))


def online_estimate(state: OnlineState) -> SlamEstimate:
    """Current :class:`SlamEstimate` (pose slots in ring order; see ``state.pose_frame``)."""
    return state.estimate


def online_problem(state: OnlineState) -> SlamProblem:
    """The factor graph the smoother holds, as a :class:`SlamProblem` (e.g. to batch-solve it)."""
    return state.problem

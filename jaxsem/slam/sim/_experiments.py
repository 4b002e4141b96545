"""Running the ROSHAN estimators on simulated maps the way the thesis does (section 4.4).

The thesis evaluates an *online* system: frames arrive one at a time, a new object is initialised
from its first detection, and the graph is re-optimised periodically (section 4.3.6). The
experiments here reproduce that protocol on top of :func:`jaxsem.slam._batch.solve_schur` with fixed
padded shapes: after every ``every`` frames the problem restricted to the frames seen so far
(masks, so nothing recompiles) is re-solved, warm-started from the previous estimate.

One more rule, the lesson of QuadricSLAM's forward-path failure (position error 18.8 m on
Forward maps: the camera passes the 10 m initial guess and the box factors go flat): an object whose
estimate is behind (or around) the camera of its latest detection, so that it has no valid
projection there, is re-initialised from that detection (section 4.3.5, texture depth when the
system uses it) instead of being left stranded. Optionally (``reinit_iou > 0``) also an object
whose predicted box overlaps its latest measured box by less than that IoU.

Everything is jittable and vmappable over maps of one config.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from ...metrics import ellipsoid_errors
from ...quadrics import box_iou as _box_iou, project_bbox
from .._batch import solve_schur
from .._cost import total_cost
from .._init import box_init
from .._solver_config import NoiseModel, SolverConfig, baseline_config

__all__ = ["BASELINE", "ROSHAN", "solver_config", "solve_online", "map_errors", "box_iou"]

BASELINE = "baseline"
ROSHAN = "roshan"


def solver_config(system: str, sim_config, max_steps: int = 10, **changes):
    """The :class:`jaxsem.slam.SolverConfig` of ``system`` ("baseline" or "roshan") whose noise
    model matches the simulator's noise (box sigma; texture sigma at a typical 20 m depth).

    The baseline is ROSHAN without the texture-plane factor and with a weak shape regulariser
    (ten times the class sigma) in place of the semantic prior, as the thesis' baseline keeps
    "improvements on shape regularisation".
    """
    if system not in (BASELINE, ROSHAN):
        raise ValueError(f"system: expected 'baseline' or 'roshan', got {system!r}")
    noise = NoiseModel(
        pose_rotation_sigma=max(jnp.deg2rad(sim_config.pose_noise_deg).item(), 1e-4),
        pose_translation_sigma=max(sim_config.pose_noise_m, 1e-3),
        box_sigma=max(sim_config.box_noise_px, 0.5),
        texture_sigma=max(sim_config.texture_noise_m + 20.0 * sim_config.texture_noise_rel, 0.05),
    )
    kwargs: dict[str, Any] = dict(noise=noise, max_steps=max_steps, default_depth=sim_config.init_depth)
    kwargs.update(changes)
    if system == BASELINE:
        return baseline_config(**kwargs)
    return SolverConfig(**kwargs)


def box_iou(a, b):
    """IoU of boxes (..., 4) ``[u_min, v_min, u_max, v_max]`` (0 for empty or disjoint boxes): the
    core's :func:`jaxsem.quadrics.box_iou`."""
    return _box_iou(a, b)


def _replace(module, **fields):
    values = {name: getattr(module, name) for name in module.__dataclass_fields__}
    values.update(fields)
    return type(module)(**values)


def _reinitialise(problem, est, box_mask, config, init_radii, reinit_iou):
    """Re-initialises objects stranded behind (or lost by) the camera of their latest box."""
    M = problem.box.shape[0]
    J = problem.object_class.shape[0]
    idx = jnp.arange(M, dtype=jnp.int32)
    objects = jnp.arange(J, dtype=problem.box_object.dtype)
    hit = (problem.box_object[None, :] == objects[:, None]) & box_mask[None, :]
    last = jnp.max(jnp.where(hit, idx[None, :], -1), axis=1)
    has = last >= 0
    last = jnp.maximum(last, 0)
    pose = est.camera_T_world[problem.box_pose[last]]
    box = problem.box[last]
    pred, valid = project_bbox(est.rotation, est.center, est.radii, problem.K, pose)
    lost = has & (~valid | (box_iou(pred, box) < reinit_iou))  # IoU < 0 never holds
    tex_mask = problem.texture_mask[last] & config.use_texture
    # The batch initialisation's own rule (slam.box_init: depth, border margin, silhouette scale)
    R, c, r = box_init(
        config, pose, box, problem.K, init_radii, problem.texture_depth[last], tex_mask, problem.image_size
    )
    pick = lambda new, old: jnp.where(lost.reshape(lost.shape + (1,) * (old.ndim - 1)), new, old)
    return _replace(est, rotation=pick(R, est.rotation), center=pick(c, est.center), radii=pick(r, est.radii)), lost


def solve_online(
    problem, init, config, *, every: int = 10, reinit: bool = True, reinit_iou: float = 0.0, init_radii=None
):
    """Online protocol: re-solve after every ``every`` frames with the frames seen so far.

    Args:
      problem: :class:`jaxsem.slam.SlamProblem` (T poses; boxes in any order, ``box_pose`` says
        which frame saw each).
      init: :class:`jaxsem.slam.SlamEstimate`: pose priors and each object's initialisation from
        its first detection.
      config: :class:`jaxsem.slam.SolverConfig` (``max_steps`` per round).
      every: static, frames between two optimisations.
      reinit: static; re-initialise an object from its latest box when the estimate has no
        valid projection in that frame (behind or around the camera).
      reinit_iou: also re-initialise when the predicted box's IoU with the latest measured box is
        below this (0: only the validity rule).
      init_radii: (J, 3) radii of a re-initialised object (default: ``init.radii``).

    Returns:
      (estimate, info) with ``info = {"steps": (rounds,), "reinitialised": (J,) int32 count,
      "cost": final cost of the full problem}``.
    """
    T = problem.pose_prior.shape[0]
    init_radii = init.radii if init_radii is None else init_radii
    ks = jnp.arange(every, T + every, every, dtype=problem.box_pose.dtype).clip(max=T)

    def round_(carry, k):
        est, n_reinit = carry
        bm = problem.box_mask & (problem.box_pose < k)
        seen = jnp.zeros(problem.object_mask.shape, bool).at[problem.box_object].max(bm)
        sub = _replace(
            problem,
            box_mask=bm,
            texture_mask=problem.texture_mask & bm,
            object_mask=problem.object_mask & seen,
            pose_mask=problem.pose_mask & (jnp.arange(T, dtype=ks.dtype) < k),
        )
        if reinit:
            est, lost = _reinitialise(sub, est, bm, config, init_radii, reinit_iou)
            n_reinit = n_reinit + lost.astype(jnp.int32)
        est, info = solve_schur(sub, est, config)
        return (est, n_reinit), info.steps

    n0 = jnp.zeros(problem.object_class.shape, jnp.int32)
    (est, n_reinit), steps = jax.lax.scan(round_, (init, n0), ks)
    return est, {"steps": steps, "reinitialised": n_reinit, "cost": total_cost(problem, est, config)}


def map_errors(estimate, sim):
    """Per-map mean over detected objects of the shape (m), position (m) and orientation (deg)
    errors (:func:`jaxsem.metrics.ellipsoid_errors`, symmetry-aware). Returns a dict of scalars
    (or (B,) under ``vmap``); ``count`` is the number of objects scored."""
    e = ellipsoid_errors(
        estimate.rotation,
        estimate.center,
        estimate.radii,
        sim.object_rotation,
        sim.object_center,
        sim.object_radii,
    )
    w = sim.observed.astype(sim.object_center.dtype)
    n = jnp.sum(w, axis=-1)
    out = {k: jnp.sum(v * w, axis=-1) / jnp.maximum(n, 1.0) for k, v in e.items()}
    out["count"] = n
    return out

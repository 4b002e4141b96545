"""Single-view initialisation of a whole problem (section 4.3.5)."""

from __future__ import annotations

import jax.numpy as jnp

from .. import factors as F
from ._cost import class_table
from ._problem import SlamEstimate, SlamProblem
from ._solver_config import SolverConfig


def initialize(problem: SlamProblem, config: SolverConfig) -> SlamEstimate:
    """Initial estimate: poses = pose priors; each object from its first (lowest-index) box.

    ``config`` is required: it is the solver's (pass the config you solve with). The centre is
    on the ray through that box's centre, at the texture-plane depth plus the class-mean
    half-extent when ``config.use_texture`` and the box has a texture measurement, else where
    the class-mean ellipsoid appears as large as the box (``config.depth_from_box``, the
    default) or at ``config.default_depth``; identity rotation; class-mean radii of the
    problem's class table (or the config's override) (:func:`jaxsem.factors.single_view_init`;
    the box is read as the outline of the ellipsoid ``config.silhouette_scale`` times larger).
    Objects without any box (or masked) get a finite placeholder (class-mean radii at the world
    origin) and have no effect on the cost. Jittable and vmappable over problems.
    """
    dtype = problem.pose_prior.dtype
    mean, _ = class_table(config, dtype, problem)
    M = problem.box.shape[0]
    J = problem.object_class.shape[0]
    idx = jnp.arange(M, dtype=jnp.int32)
    objects = jnp.arange(J, dtype=problem.box_object.dtype)
    hit = (problem.box_object[None, :] == objects[:, None]) & problem.box_mask[None, :]
    first = jnp.min(jnp.where(hit, idx[None, :], M), axis=1)
    has_box = first < M
    first = jnp.minimum(first, M - 1)
    pose = problem.pose_prior[problem.box_pose[first]]
    tex_mask = problem.texture_mask[first] if config.use_texture else jnp.zeros(J, bool)
    radii = mean[problem.object_class]
    box, depth = problem.box[first], problem.texture_depth[first]
    R, c, r = box_init(config, pose, box, problem.K, radii, depth, tex_mask, problem.image_size)
    c = jnp.where(has_box[:, None], c, 0.0)
    return SlamEstimate(problem.pose_prior, R, c, r)


def box_init(config: SolverConfig, pose, box, K, radii, texture_depth, texture_mask, image_size):
    """Ellipsoids (R, c, r) from one box each (:func:`jaxsem.factors.single_view_init`) with the
    config's initialisation settings (default depth, depth from the box, border margin,
    silhouette scale): the one place the batch (:func:`initialize`) and online initialisations
    read them."""
    return F.single_view_init(
        pose,
        box,
        K,
        radii,
        texture_depth=texture_depth,
        texture_mask=texture_mask,
        default_depth=config.default_depth,
        depth_from_box=config.depth_from_box,
        image_size=image_size,
        border_margin=config.border_margin,
        silhouette_scale=config.silhouette_scale,
    )

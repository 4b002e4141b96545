"""ROSHAN's solver settings: the noise model, the cost model, the initialisation and the stopping
rule, and :class:`SolverConfig`, which holds the three parts flat (``config.cost_model`` /
``config.initialisation`` / ``config.stopping`` read them; :meth:`SolverConfig.from_parts` builds
one from them). Every field that is not static is a traced float, so configs vmap and a changed
weight or tolerance never recompiles.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from ..factors import ROBUST_LOSSES

__all__ = [
    "DETECTOR_BOX_LOSS",
    "DETECTOR_BOX_SIGMA",
    "CostModel",
    "InitConfig",
    "NoiseModel",
    "SolverConfig",
    "StoppingRule",
    "baseline_config",
]

#: :meth:`SolverConfig.for_detector`'s box sigma (pixels per edge) for a learned detector's boxes.
DETECTOR_BOX_SIGMA = 8.0
#: :meth:`SolverConfig.for_detector`'s loss on ROSHAN's box factors for a learned detector's boxes.
DETECTOR_BOX_LOSS = "cauchy"


def _scalar(x: Any) -> Any:
    """A concrete 0-d floating array as a Python float; anything else unchanged.

    A config field given as ``jnp.asarray(1e-4)`` then has the same ``jit`` signature (a weakly
    typed scalar) as one given as ``1e-4``: changing a tolerance or a weight never recompiles,
    whichever way it is written. Tracers and batched arrays (a vmapped config) pass unchanged."""
    if isinstance(x, Tracer) or not isinstance(x, (jax.Array, np.ndarray, np.generic)):
        return x
    if np.ndim(x) != 0 or not np.issubdtype(x.dtype, np.floating):
        return x
    return float(x)


class NoiseModel(eqx.Module):
    """Standard deviations that whiten the residuals (all traced floats, so vmappable).

    Attributes:
      pose_rotation_sigma: radians, pose-prior rotation noise (per tangent axis).
      pose_translation_sigma: metres, pose-prior translation noise (per axis).
      odometry_rotation_sigma: radians, noise of one odometry step's rotation (per tangent axis).
      odometry_translation_sigma: metres, noise of one odometry step's translation (per axis).
      box_sigma: pixels, per box edge.
      texture_sigma: metres, texture-plane depth.
      shape_prior_scale: multiplies the class table's per-axis sigmas (1.0 = the table).
    """

    pose_rotation_sigma: float | jnp.ndarray = eqx.field(default=0.0175, converter=_scalar)
    pose_translation_sigma: float | jnp.ndarray = eqx.field(default=0.05, converter=_scalar)
    odometry_rotation_sigma: float | jnp.ndarray = eqx.field(default=0.0087, converter=_scalar)
    odometry_translation_sigma: float | jnp.ndarray = eqx.field(default=0.02, converter=_scalar)
    box_sigma: float | jnp.ndarray = eqx.field(default=3.0, converter=_scalar)
    texture_sigma: float | jnp.ndarray = eqx.field(default=0.3, converter=_scalar)
    shape_prior_scale: float | jnp.ndarray = eqx.field(default=1.0, converter=_scalar)


# Each field is declared once, in one of five groups; the public classes below inherit the groups
# they hold. A dataclass takes its bases' fields in reverse MRO order, so each class lists its
# groups last first: every class keeps its field order (positional construction, pytree leaves,
# config JSON) and no public class is a subclass of another.


class _CostFactors(eqx.Module):
    """The factors, losses and scales: the first fields of :class:`CostModel`."""

    noise: NoiseModel = NoiseModel()
    use_texture: bool = eqx.field(static=True, default=True)
    use_shape_prior: bool = eqx.field(static=True, default=True)
    baseline_shape_weight: float | jnp.ndarray = eqx.field(default=10.0, converter=_scalar)
    border_margin: float | jnp.ndarray = eqx.field(default=10.0, converter=_scalar)
    box_loss: str = eqx.field(static=True, default="l2")
    texture_loss: str = eqx.field(static=True, default="l2")
    shape_loss: str = eqx.field(static=True, default="l2")
    pose_loss: str = eqx.field(static=True, default="l2")
    robust_scale: float | jnp.ndarray = eqx.field(default=2.0, converter=_scalar)
    texture_plane_fraction: float | jnp.ndarray = eqx.field(default=1.0, converter=_scalar)
    silhouette_scale: float | jnp.ndarray = eqx.field(default=1.0, converter=_scalar)
    box_outward_scale: float | jnp.ndarray = eqx.field(default=1.0, converter=_scalar)

    def __check_init__(self):
        for name in ("box_loss", "texture_loss", "shape_loss", "pose_loss"):
            if getattr(self, name) not in ROBUST_LOSSES:
                raise ValueError(f"{name}: expected one of {list(ROBUST_LOSSES)}, got {getattr(self, name)!r}")


class _CostGuards(eqx.Module):
    """Barriers, the optional priors and the class table: the last fields of :class:`CostModel`."""

    barrier_weight: float | jnp.ndarray = eqx.field(default=10.0, converter=_scalar)
    min_depth: float | jnp.ndarray = eqx.field(default=0.1, converter=_scalar)
    degenerate_residual: float | jnp.ndarray = eqx.field(default=1000.0, converter=_scalar)
    use_upright: bool = eqx.field(static=True, default=False)
    upright_sigma: float | jnp.ndarray = eqx.field(default=0.0873, converter=_scalar)
    world_up: tuple = eqx.field(static=True, default=(0.0, 0.0, 1.0))
    use_support: bool = eqx.field(static=True, default=False)
    support_height: float | jnp.ndarray = eqx.field(default=0.0, converter=_scalar)
    support_sigma: float | jnp.ndarray = eqx.field(default=0.005, converter=_scalar)
    shape_prior_mean: jnp.ndarray | None = None
    shape_prior_sigma: jnp.ndarray | None = None


class _InitStart(eqx.Module):
    """The single-view start: the first fields of :class:`InitConfig`."""

    default_depth: float | jnp.ndarray = eqx.field(default=10.0, converter=_scalar)
    depth_from_box: bool = eqx.field(static=True, default=True)


class _InitRescue(eqx.Module):
    """The batch solver's rescue: the last fields of :class:`InitConfig`."""

    robust_init: bool = eqx.field(static=True, default=True)
    unfixable_rms: float | jnp.ndarray = eqx.field(default=5.0, converter=_scalar)
    rescue_rtol: float | jnp.ndarray = eqx.field(default=1e-2, converter=_scalar)


class _Stopping(eqx.Module):
    """The fields of :class:`StoppingRule`."""

    max_steps: int = eqx.field(static=True, default=100)
    rtol: float | jnp.ndarray = eqx.field(default=1e-5, converter=_scalar)
    atol: float | jnp.ndarray = eqx.field(default=1e-5, converter=_scalar)
    lambda_init: float | jnp.ndarray = eqx.field(default=1e-3, converter=_scalar)
    lambda_max: float | jnp.ndarray = eqx.field(default=1e10, converter=_scalar)


class CostModel(_CostGuards, _CostFactors):
    """Which factors of eq. 4.13 are used and how they are weighted: the cost every solver
    minimises. Fields as the same-named ones of :class:`SolverConfig`."""


class InitConfig(_InitRescue, _InitStart):
    """How a solve starts: the single-view depth and the batch solver's rescue of stranded
    objects. Fields as the same-named ones of :class:`SolverConfig`."""


class StoppingRule(_Stopping):
    """When the Levenberg-Marquardt stops (GTSAM's rule) and its damping. Fields as the
    same-named ones of :class:`SolverConfig`."""


_PARTS = {"cost_model": CostModel, "initialisation": InitConfig, "stopping": StoppingRule}


class SolverConfig(_CostGuards, _InitRescue, _Stopping, _InitStart, _CostFactors):
    """Which factors are used, how they are weighted, and how the solvers iterate.

    Three parts, each its own module: :class:`CostModel` (the cost), :class:`InitConfig` (how a
    solve starts) and :class:`StoppingRule` (when the LM stops); ``config.cost_model`` /
    ``config.initialisation`` / ``config.stopping`` read them and
    :meth:`SolverConfig.from_parts` builds a config from them. The flat constructor below is
    the same config (kept for every existing caller).

    ROSHAN is the default; the thesis' baseline is :func:`baseline_config` (equivalently
    ``SolverConfig(use_texture=False, use_shape_prior=False)``): the same system with only the
    pose-prior and box factors plus a weak shape regulariser (``baseline_shape_weight``), the one
    definition of "baseline" used by the library, the CLI (``infer/roshan.py --baseline``) and
    the benchmarks. QuadricSLAM's own factor set (no shape term at all) is
    ``baseline_config(baseline_shape_weight=0.0)``. The class table (``shape_prior_mean``,
    ``shape_prior_sigma``, both (C, 3) semi-axis radii in metres) is a traced field so one can
    differentiate through it; ``None`` means the problem's own table (``problem.classes``, the
    table :func:`make_problem` was given; the built-in one by default).

    Stopping rule (as GTSAM's ``LevenbergMarquardtParams`` defaults): an accepted step whose
    cost decrease is at most ``atol`` (absolute, in units of ``0.5 * sum(r**2)``) or at most
    ``rtol`` times the cost before it (relative) ends the solve successfully; both default to
    1e-5, as GTSAM's ``absoluteErrorTol`` / ``relativeErrorTol``. :meth:`tight` gives 1e-10 and
    a larger step budget for reference solutions.

    Attributes (static ones set shapes / control flow; changing them recompiles):
      noise: :class:`NoiseModel`.
      use_texture, use_shape_prior: static bools, enable factors 3 and 4 of eq. 4.13.
      baseline_shape_weight: weak shape regulariser kept when ``use_shape_prior`` is False
        (the thesis keeps shape regularisation in the baseline), as a multiple of the
        class sigma (10.0 = ten times looser than ROSHAN's prior). 0 disables it.
      border_margin: pixels; a measured box edge within this distance of the image border is
        non-constraining and dropped (section 4.3.2).
      box_loss, texture_loss, shape_loss, pose_loss: static robust loss names per factor type,
        ``"l2"``, ``"huber"`` or ``"cauchy"``.
      robust_scale: threshold of the robust losses in whitened units (sigmas).
      texture_plane_fraction: where the texture factor puts the measured plane between the
        ellipsoid's centre depth (0) and its camera-facing tangent plane (1, the thesis);
        2/3 is the mean depth of the visible surface, what a mean of real feature depths
        measures (:func:`jaxsem.factors.texture_residual`).
      silhouette_scale: how much larger than its inscribed ellipsoid an object's outline is.
        A detector's box encloses the object's silhouette; a real object's corners and handles
        reach beyond the ellipsoid inscribed in its bounding box, so its box is wider than that
        ellipsoid's projected box (1.0: the thesis' model, exact for ellipsoidal objects; about
        1.1 for the LM-O desk objects, up to sqrt(3) for a cube seen along its diagonal). The
        box factor and the single-view start project the ellipsoid with radii scaled by it, so
        the estimate stays the object's extent ellipsoid (what the shape prior and the metrics
        describe).
      box_outward_scale: the box sigma, times this, where the projected edge lies outside the
        measured box (:func:`jaxsem.factors.box_residual`'s ``outward_scale``): a measured box
        is the object's visible part, which occluders only cut inwards. 1.0: symmetric, the
        thesis' factor. Where the problem says which edges an occluder may have cut
        (``SlamProblem.box_cut``), only those.
      default_depth: metres, single-view initialisation depth without a texture plane when
        ``depth_from_box`` is False, or when the box cannot give one (every edge at the border).
      depth_from_box: static; without a texture plane, a single-view initialisation places the
        object at the depth where the class-mean ellipsoid would project to the size of its box
        (:func:`jaxsem.quadrics.depth_from_box_size`): the solver follows the scene's scale (a
        tabletop at 0.8 m, a street at 15 m). False: the fixed ``default_depth`` (QuadricSLAM's
        initialisation).
      max_steps: static, Levenberg-Marquardt step cap (trial steps, rejected ones included) per
        phase of a solve.
      rtol, atol: the stopping rule above (traced floats: vmappable, no recompile).
      lambda_init, lambda_max: initial Marquardt damping and the limit at which a solve that
        finds no cost-lowering step stops with ``RESULTS.damping_limit``.
      robust_init: static; the batch Schur solver first rescues objects whose initial estimate
        has no valid projection in one of their frames (multi-view triangulation of the box
        centres, then an objects-only solve with the poses held), and objects the data still
        cannot fix are flagged (``SolveInfo.unfixable``) and left out of the joint solve, so
        they cannot drag camera poses off their priors.
      unfixable_rms: whitened RMS box-edge residual above which a rescued object counts as
        unfixable.
      rescue_rtol: relative-decrease stopping tolerance of the rescue phase (objects alone,
        poses held; at least ``rtol``). The joint solve after it polishes every object again,
        so the rescue need not converge tightly (1e-2 saves a third to a half of the iterations
        of a solve where every object was re-placed).
      barrier_weight: weight of the degenerate-geometry penalty (depth / camera-inside).
      min_depth: metres, the depth below which the near side of an ellipsoid counts as too close.
      degenerate_residual: pixels, soft cap of a box edge error and the base residual of an
        invalid projection (see :func:`jaxsem.factors.box_residual`).
      use_upright: static; adds the upright prior (:func:`jaxsem.factors.upright_residual`) to
        every object: its height axis (the class table's third dimension) along ``world_up``,
        tilt sigma ``upright_sigma`` (radians, default 5 degrees), under ``shape_loss``. For
        objects that rest on a table or the ground, in a world frame whose up is known (gravity
        from a VIO / IMU). Off by default (the thesis has no such factor); the object rows of
        :func:`jaxsem.slam.residual_blocks` then grow from 3 to 5.
      world_up: static unit 3-vector (tuple), the world's up.
      use_support: static; adds the support prior (:func:`jaxsem.factors.support_residual`) to
        every object: its lowest point along ``world_up`` at ``support_height`` (metres, the
        desk's or floor's height in the world), sigma ``support_sigma`` (metres, default 5 mm),
        under ``shape_loss``. For objects resting on one known horizontal surface (a plane fit
        from a depth camera or an AR framework, or :func:`jaxsem.slam._sequence_texture.support_height` from the images).
        Off by default; it adds one object row after the shape (and upright) rows.
    """

    def replace(self, **changes) -> SolverConfig:
        """A copy with some fields changed."""
        values = {name: getattr(self, name) for name in self.__dataclass_fields__}
        unknown = set(changes) - set(values)
        if unknown:
            raise ValueError(f"SolverConfig: unknown fields {sorted(unknown)}")
        values.update(changes)
        return SolverConfig(**values)

    def for_detector(self, *, box_sigma: float = DETECTOR_BOX_SIGMA, robust: bool = True) -> SolverConfig:
        """This config for boxes from a learned detector (:mod:`jaxsem.volumon.rcnn`) rather than
        annotated or rendered ones: the box factors' sigma ``box_sigma`` pixels and, when
        ``robust``, their loss Cauchy (:data:`DETECTOR_BOX_LOSS`; robust scale ``robust_scale`` sigmas).
        A network's boxes on photos it never saw are off by a few pixels an edge, several times
        an annotated box, and some of its tracks hold another object's boxes; the robust loss
        keeps those from pulling the map and the poses. The defaults were chosen on the LM-O
        tuning photos (``benchmarks/roshan/HISTORY.md``). The thesis' baseline keeps its L2 box
        factors: ``baseline_config().for_detector(robust=False)``."""
        if not isinstance(box_sigma, Tracer):  # a traced sigma (a vmapped config) is taken as it is
            try:
                value = float(box_sigma) if np.ndim(box_sigma) == 0 and not isinstance(box_sigma, (bool, str)) else None
            except (TypeError, ValueError):
                value = None
            if value is None or not (math.isfinite(value) and value > 0):
                raise ValueError(f"box_sigma: expected a positive number of pixels, got {box_sigma!r}")
            box_sigma = value
        noise = dataclasses.replace(self.noise, box_sigma=box_sigma)
        return self.replace(noise=noise, box_loss=DETECTOR_BOX_LOSS if robust else self.box_loss)

    @classmethod
    def from_parts(
        cls,
        cost_model: CostModel = CostModel(),
        initialisation: InitConfig = InitConfig(),
        stopping: StoppingRule = StoppingRule(),
    ) -> SolverConfig:
        """A config from its three parts (the flat constructor stays equivalent)."""
        values = {}
        for part in (cost_model, initialisation, stopping):
            values.update({name: getattr(part, name) for name in part.__dataclass_fields__})
        return cls(**values)

    def _part(self, kind):
        return kind(**{name: getattr(self, name) for name in kind.__dataclass_fields__})

    @property
    def cost_model(self) -> CostModel:
        """The :class:`CostModel` part (factors, noise, losses, barriers, class table)."""
        return self._part(CostModel)

    @property
    def initialisation(self) -> InitConfig:
        """The :class:`InitConfig` part (single-view depth, rescue of stranded objects)."""
        return self._part(InitConfig)

    @property
    def stopping(self) -> StoppingRule:
        """The :class:`StoppingRule` part (step budget, tolerances, damping)."""
        return self._part(StoppingRule)

    def tight(self, max_steps: int = 500) -> SolverConfig:
        """Tight stopping (``rtol = atol = 1e-10``, ``max_steps`` 500): reference solutions."""
        return self.replace(rtol=1e-10, atol=1e-10, max_steps=max_steps)


def baseline_config(**changes) -> SolverConfig:
    """The thesis' baseline: pose priors + box factors (no texture plane, no semantic prior) with
    the weak shape regulariser of :attr:`SolverConfig.baseline_shape_weight` (10 class sigmas).
    The one definition used by the library, ``infer/roshan.py --baseline`` and the benchmarks."""
    return SolverConfig(use_texture=False, use_shape_prior=False, **changes)

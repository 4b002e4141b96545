"""Object maps from detections (thesis 5.8.2): ROSHAN's online state as map
objects, and the error of a map against ground truth.

The building renderer (:class:`jaxsem.mapping.BuildingRenderer`) gives per-frame boxes, segmentation
and depth; this module turns what an estimator made of them into :class:`Ellipsoids` on the
planning world's semantic ids, so :func:`jaxsem.mapping.semantic_grid` can rasterise them:

- a per-frame estimator (VoluMon, or :func:`jaxsem.mapping.ellipsoids_from_depth` standing in for
  it) already yields :class:`Ellipsoids`: feed them to :func:`jaxsem.mapping.update`;
- ROSHAN (:mod:`jaxsem.slam`'s online smoother) is fed the boxes with the known camera poses:
  :func:`roshan_init` (a smoother whose shape-prior table has one row per building class,
  :data:`ROSHAN_CLASSES`), :func:`roshan_frame` (one frame of boxes, semantic ids and
  association ids) and :func:`roshan_objects` (its current ellipsoids, semantic ids attached);
- :func:`map_errors`: each ground-truth object's nearest same-class map object (global greedy
  centroid association, :func:`jaxsem.mapping.associate`) and their position / size errors
  (:func:`jaxsem.metrics.ellipsoid_errors`).

Shape priors. ROSHAN's semantic prior needs a class-mean size per class. The door row takes
the width and height of ``jaxsem.classes`` ' door (an interior door leaf, 0.9 x 2.03 m) and
their sigmas, but not its 4.5 cm thickness: the renderer labels the door *opening* (its frame
through the wall), as thick as the wall (0.2 m in the generated buildings), and a 4.5 cm
ellipsoid has a ground footprint thinner than half a 0.1 m cell, which the semantic grid would
not show at all. The class table has no window or exit sign, so their rows come from the
building generator's parameters (``jaxsem.planning._buildings.BuildingParams.window_length`` 1-2 m, one
wall layer 0.2 m thick, :class:`jaxsem.mapping.ObjectHeights`: windows 0.9-2.1 m, signs
1.9-2.2 m) with loose sigmas; see :func:`roshan_priors`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import classes as _classes, metrics, slam
from ._store import Ellipsoids, ObjectMap, associate

__all__ = [
    "ROSHAN_CLASSES",
    "map_errors",
    "roshan_frame",
    "roshan_init",
    "roshan_objects",
    "roshan_priors",
]

# Planning-world semantic ids (jaxsem.planning DOOR, WINDOW, EXIT_SIGN) in ROSHAN class order:
# ROSHAN class index i is semantic id ROSHAN_CLASSES[i] (the smoother's prior table has 3 rows).
ROSHAN_CLASSES = (2, 3, 4)

# Full extents (x along the wall, y through it, z up) and their sigmas, metres, for the classes
# jaxsem.classes does not have (see the module docstring).
_WALL_THICKNESS, _WALL_SIGMA = 0.2, 0.05
_WINDOW_DIMENSIONS, _WINDOW_SIGMA = (1.5, _WALL_THICKNESS, 1.2), (0.4, _WALL_SIGMA, 0.2)
_SIGN_DIMENSIONS, _SIGN_SIGMA = (0.2, 0.15, 0.3), (0.1, 0.1, 0.1)


def roshan_priors(dtype=np.float64):
    """``(mean_radii (3, 3), radii_sigma (3, 3))``: ROSHAN's shape prior per row of
    :data:`ROSHAN_CLASSES` (door width and height from :mod:`jaxsem.classes`, its thickness the
    wall's; window and exit sign from the building generator's sizes, as the class table has no
    such rows; see the module docstring)."""
    door = _classes.get("door")  # (width, thickness, height): the opening is as thick as the wall
    door_dims = (door.dimensions[0], _WALL_THICKNESS, door.dimensions[2])
    door_sigma = (door.sigma[0], _WALL_SIGMA, door.sigma[2])
    mean = np.array([door_dims, _WINDOW_DIMENSIONS, _SIGN_DIMENSIONS], dtype) / 2
    sigma = np.array([door_sigma, _WINDOW_SIGMA, _SIGN_SIGMA], dtype) / 2
    return mean, sigma


def _roshan_index(semantic_class) -> np.ndarray:
    sem = np.asarray(semantic_class).reshape(-1)
    lut = np.full(max(ROSHAN_CLASSES) + 1, -1, np.int64)
    lut[list(ROSHAN_CLASSES)] = np.arange(len(ROSHAN_CLASSES))
    bad = (sem < 0) | (sem >= len(lut))
    idx = np.where(bad, -1, lut[np.clip(sem, 0, len(lut) - 1)])
    if np.any(idx < 0):
        raise ValueError(
            f"semantic_class: expected ids in {ROSHAN_CLASSES} (door, window, exit sign), got {sem[idx < 0].tolist()}"
        )
    return idx


def roshan_init(K, image_size, capacity, config=None, *, optimize_every: int = 2, iterations: int = 3, window=4):
    """An online ROSHAN smoother (:func:`jaxsem.slam.online_init`) for building objects.

    K: (3, 3) intrinsics; image_size: ``[width, height]``; capacity: :class:`jaxsem.slam.Capacity`
    (``max_objects`` must exceed the largest association id); config:
    :class:`jaxsem.slam.SolverConfig` (default ROSHAN's) whose shape-prior table is replaced by
    :func:`roshan_priors`; optimize_every, iterations, window: as ``online_init`` (the poses are
    known, so a short pose window suffices). Returns a :class:`jaxsem.slam._online.OnlineState`.
    """

    mean, sigma = roshan_priors()
    config = (config or slam.SolverConfig()).replace(shape_prior_mean=mean, shape_prior_sigma=sigma)
    return slam.online_init(
        config, capacity, K, image_size, optimize_every=optimize_every, iterations=iterations, window=window
    )


def roshan_frame(
    camera_T_world, box, semantic_class, object_id, texture_depth=None, *, max_detections: int, image_size=None
):
    """One :class:`jaxsem.slam.Frame` for :func:`roshan_init` 's smoother.

    camera_T_world: (4, 4) known camera pose; box: (N, 4) pixel boxes; semantic_class: (N,)
    planning ids in :data:`ROSHAN_CLASSES`; object_id: (N,) association ids (e.g. the renderer's
    object index); texture_depth: optional (N,) metres of the object's near surface (NaN: none);
    max_detections: the smoother's ``Capacity.max_detections`` (extra detections: ValueError);
    image_size: optional ``[width, height]`` of the image (the ``roshan_init`` one); given, a box
    off the image raises ``ValueError`` (:func:`jaxsem.slam.make_frame`) before it reaches the
    smoother.
    """

    box = np.asarray(box, np.float64).reshape(-1, 4)
    frame = slam.make_frame(
        camera_T_world,
        box,
        np.zeros(box.shape[0], np.int64),  # validated against the library's class table below
        object_id,
        texture_depth,
        max_detections=max_detections,
        image_size=image_size,
    )
    cls = np.zeros(max_detections, np.int32)
    cls[: box.shape[0]] = _roshan_index(semantic_class)
    return slam.Frame(
        pose_prior=frame.pose_prior,
        box=frame.box,
        box_class=jax.device_put(cls),
        texture_depth=frame.texture_depth,
        texture_mask=frame.texture_mask,
        object_id=frame.object_id,
        box_mask=frame.box_mask,
    )


def roshan_objects(state) -> Ellipsoids:
    """The smoother's current ellipsoids (:class:`jaxsem.slam._online.OnlineState`) as
    :class:`Ellipsoids` with planning semantic ids; slot ``j`` is association id ``j``.
    Objects not yet seen, or with a non-finite estimate, are invalid."""

    est, pb = slam.online_estimate(state), state.problem
    rot, ctr, rad = (np.asarray(a) for a in (est.rotation, est.center, est.radii))
    finite = np.isfinite(rot).all((-1, -2)) & np.isfinite(ctr).all(-1) & np.isfinite(rad).all(-1)
    valid = np.asarray(pb.object_mask) & finite
    sem = np.asarray(ROSHAN_CLASSES, np.int32)[np.clip(np.asarray(pb.object_class), 0, len(ROSHAN_CLASSES) - 1)]
    eye = np.broadcast_to(np.eye(3), rot.shape)
    dtype = ctr.dtype
    return Ellipsoids(
        rotation=jax.device_put(np.where(valid[:, None, None], rot, eye).astype(dtype)),
        center=jax.device_put(np.where(valid[:, None], ctr, 0.0).astype(dtype)),
        radii=jax.device_put(np.where(valid[:, None], np.abs(rad), 1.0).astype(dtype)),
        class_id=jax.device_put(sem),
        valid=jax.device_put(valid),
    )


def map_errors(objects, truth: Ellipsoids, *, gate: float = 2.0) -> dict:
    """Errors of an object map against ground-truth ellipsoids.

    objects: :class:`ObjectMap` or :class:`Ellipsoids` (the map); truth: :class:`Ellipsoids`
    (e.g. the seen objects of :meth:`jaxsem.mapping.BuildingObjects.ellipsoids`, ``valid``
    marking which count); gate: metres between centres within which a map object can match.

    Each true object is matched to at most one map object of its class (global greedy by centre
    distance, :func:`jaxsem.mapping.associate`). Returns numpy arrays over the true slots:
    ``matched`` (M,) bool, ``position`` and ``shape`` (M,) metres
    (:func:`jaxsem.metrics.ellipsoid_errors`; NaN where unmatched or invalid), and ``slot`` (M,)
    the matched map slot (``N`` where none).
    """
    if isinstance(objects, Ellipsoids):  # slot j holds object j (no association, nothing to compile)
        n = objects.valid.shape[-1]
        objects = ObjectMap(
            objects.rotation,
            objects.center,
            objects.radii,
            objects.class_id,
            objects.valid,
            observations=jnp.ones((n,), jnp.int32),
            dropped=jnp.zeros((), jnp.int32),
        )
    if not isinstance(objects, ObjectMap):
        raise ValueError(f"objects: expected an ObjectMap or Ellipsoids, got {type(objects).__name__}")
    if not isinstance(truth, Ellipsoids):
        raise ValueError(f"truth: expected Ellipsoids, got {type(truth).__name__}")
    assoc = associate(objects, truth, gate=gate)
    slot = np.asarray(assoc.slot)
    matched = np.asarray(assoc.matched)
    idx = np.clip(slot, 0, objects.capacity - 1)
    err = jax.jit(metrics.ellipsoid_errors)(  # one program, not dozens of eager ones
        objects.rotation[idx],
        objects.center[idx],
        objects.radii[idx],
        truth.rotation,
        truth.center,
        truth.radii,
    )
    nan = np.float64(np.nan)
    return {
        "matched": matched,
        "position": np.where(matched, np.asarray(err["position"], np.float64), nan),
        "shape": np.where(matched, np.asarray(err["shape"], np.float64), nan),
        "slot": slot,
    }

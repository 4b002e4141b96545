"""Object maps for planning (thesis 5.8.2-5.8.3): ellipsoid estimates in, LSD's semantic grid out.

A functional store with a fixed capacity (an equinox pytree; jit once, ``vmap`` over robots):

- :func:`init` (capacity) -> :class:`ObjectMap`; :func:`update` (state, :class:`Ellipsoids` of
  one frame) -> state: greedy class-aware association by centroid distance with a gate, then
  fusion (``"latest"`` as the thesis, or ``"mean"``); :func:`associate` alone.
- :func:`semantic_grid`: each object's ground footprint (orthographic projection along z,
  :func:`jaxsem.quadrics.rasterize_footprint`) with its class id, on the occupancy grid's cells.
  Use the planning world's ids (``jaxsem.planning.DOOR``, ``WINDOW``, ``EXIT_SIGN``).
- Planning glue: :func:`with_object_map` (a ``MapState`` whose semantic channel is the raster),
  :func:`object_map_sampler` (an LSD sampler that reads the object map).
- From detections (:class:`BuildingRenderer` renders them): :func:`roshan_init` / :func:`roshan_frame` /
  :func:`roshan_objects` (ROSHAN's online smoother on building classes, its current ellipsoids
  as map objects); :func:`map_errors` (a map's position / size errors against ground truth).
- Ground truth: :func:`building_objects` / :func:`ground_truth_map` turn a generated building's
  doors, windows and exit signs into boxes and inscribed ellipsoids.

Example::

    from jaxsem import mapping, planning, quadrics
    state = mapping.init(64)
    dets = mapping.ellipsoids(quadrics.Ellipsoid(rotation, center, radii), class_id=[planning.DOOR] * len(center))
    state = mapping.update(state, dets, gate=1.0)
    grid = mapping.semantic_grid(state, building.grid)

The rest of the face, by job: the store's :data:`FUSIONS`, :class:`Association`; buildings'
objects :class:`BuildingObjects`, :class:`ObjectHeights`, :func:`box_ellipsoids`; the rendered
building :func:`building_mjcf`, :class:`SceneDetections`, :func:`detect_from_segmentation`,
:func:`ellipsoids_from_depth`, :func:`robot_camera`, :func:`robot_intrinsics`; ROSHAN on
buildings :data:`ROSHAN_CLASSES`, :func:`roshan_priors`, and VoluMon's start
:func:`volumon_initial_ellipsoids`; doors :func:`door_building`, :func:`write_door_dataset`,
:func:`train_door_model`, :func:`door_data_baseline`, :func:`door_eval_batch`,
:data:`DOOR_BASELINE`.
"""

from ._building import (
    BuildingObjects,
    ObjectHeights,
    box_ellipsoids,
    building_objects,
    ground_truth_map,
)
from ._building_scene import (
    BuildingRenderer as BuildingRenderer,
    SceneDetections as SceneDetections,
    building_mjcf as building_mjcf,
    detect_from_segmentation as detect_from_segmentation,
    ellipsoids_from_depth as ellipsoids_from_depth,
    robot_camera as robot_camera,
    robot_intrinsics as robot_intrinsics,
)
from ._detections import (
    ROSHAN_CLASSES,
    map_errors,
    roshan_frame,
    roshan_init,
    roshan_objects,
    roshan_priors,
)
from ._doors import (
    DOOR_BASELINE as DOOR_BASELINE,
    door_building as door_building,
    door_data_baseline as door_data_baseline,
    door_eval_batch as door_eval_batch,
    train_door_model as train_door_model,
    write_door_dataset as write_door_dataset,
)
from ._planning import object_map_sampler, with_object_map
from ._store import (
    FUSIONS,
    Association,
    Ellipsoids,
    ObjectMap,
    associate,
    ellipsoids,
    init,
    semantic_grid,
    update,
)
from ._volumon_init import volumon_initial_ellipsoids

__all__ = [
    "DOOR_BASELINE",
    "FUSIONS",
    "ROSHAN_CLASSES",
    "Association",
    "BuildingObjects",
    "BuildingRenderer",
    "Ellipsoids",
    "ObjectHeights",
    "ObjectMap",
    "SceneDetections",
    "associate",
    "box_ellipsoids",
    "building_mjcf",
    "building_objects",
    "detect_from_segmentation",
    "door_building",
    "door_data_baseline",
    "door_eval_batch",
    "ellipsoids",
    "ellipsoids_from_depth",
    "ground_truth_map",
    "init",
    "map_errors",
    "object_map_sampler",
    "robot_camera",
    "robot_intrinsics",
    "roshan_frame",
    "roshan_init",
    "roshan_objects",
    "roshan_priors",
    "semantic_grid",
    "train_door_model",
    "update",
    "volumon_initial_ellipsoids",
    "with_object_map",
    "write_door_dataset",
]

"""LSD planning world: procedural buildings, ray-cast sensors, soft-cost shortest paths, PRM,
the online navigation loop and the test tasks (thesis chapter 3). LSD's expert data and training
live in :mod:`jaxsem.lsd`.

Conventions: grids are ``[row, col] = [y, x]`` with an explicit ``origin`` (world x, y of the
corner of cell [0, 0]) and ``resolution`` (metres per cell, 0.1 by default), bundled as a
:class:`jaxsem.quadrics.Grid` that every function here takes as ``grid`` (or a map holding one:
``building.grid``, so ``PRM(building.occupancy, building, capacity=500)``); world z is up.

What a user calls, by job:

- world (:func:`generate_building`, :func:`generate_house`, :class:`Building`): ``occupancy``
  (H, W) bool, ``semantic`` (H, W) int8 with ``NONE, WALL, DOOR, WINDOW, EXIT_SIGN = 0, 1, 2, 3,
  4`` (:data:`OBJECT_CLASSES`), ``indoor`` mask; families 'train' / 'test' (disjoint seed streams,
  different size and room ranges); cells and world points: :func:`world_to_cell`,
  :func:`cell_to_world`, :data:`DEFAULT_RESOLUTION`;
- partial maps (:class:`MapState`, :func:`empty_map_state`): occupancy int8 ``UNKNOWN, FREE,
  OCCUPIED = -1, 0, 1`` and a semantic int8 map of the objects seen; :func:`sense` updates them
  (jitted, vmappable; :class:`SensorConfig`);
- expert / C*: :class:`SoftCostGraph` (scipy Dijkstra, cost rising near walls),
  :func:`shortest_path`;
- PRM: :class:`PRM` (build once, grow, update the map, many queries; :func:`clear_map_cache`
  drops the per-map setup it keeps for the latest maps), :func:`build_roadmap` (one shot),
  :func:`make_roadmap_builder` (pure, vmappable), :func:`roadmap_shortest_path` (scipy, host),
  :func:`embed_local_distribution` (section 3.2.5) and :class:`LocalDistribution` (the same
  distribution held as its window, which the PRM samples and weighs from directly);
- online loop: :func:`navigate` / :class:`Trial` (:class:`NavConfig`) with ``sampler=None``
  (uniform) or a function of :class:`LocalInputs` (:data:`CROP_SIZE` crops + context, built by
  :func:`local_inputs`) returning a distribution of the same size;
- real maps: :func:`load_map` (ROS map_server YAML + image, MRPT ``.gridmap(.gz)``, a plain
  image) into a :class:`Building` on the planner's 0.1 m cells, with doors found from the
  occupancy and hand annotations, and a figure (:func:`plot_semantics`); :func:`load_occupancy`
  for the raw three-state grid, :class:`OccupancyGrid` / :func:`grid_to_building` for a grid of
  your own;
- tasks: :func:`sample_tasks` ('II' / 'IO', with C*), their pools :func:`task_pools`.

The building blocks (the pure roadmap steps ``roadmap_init`` / ``roadmap_grow`` / ...,
``soft_cost``, ``sample_points``, ``knn_within_radius``, the real-map steps ``find_doors`` /
``building_footprint`` / ``read_annotations``, the building parameters, ...) stay importable from
their private modules, e.g. ``jaxsem.planning._roadmap``, for tests and benchmarks.
"""

from ._buildings import (
    Building as Building,
    generate_building as generate_building,
    generate_house as generate_house,
)
from ._grid import (
    DEFAULT_RESOLUTION as DEFAULT_RESOLUTION,
    DOOR as DOOR,
    EXIT_SIGN as EXIT_SIGN,
    FREE as FREE,
    NONE as NONE,
    OBJECT_CLASSES as OBJECT_CLASSES,
    OCCUPIED as OCCUPIED,
    UNKNOWN as UNKNOWN,
    WALL as WALL,
    WINDOW as WINDOW,
    MapState as MapState,
    cell_to_world as cell_to_world,
    empty_map_state as empty_map_state,
    world_to_cell as world_to_cell,
)
from ._map_setup import clear_map_cache as clear_map_cache
from ._maps import (
    OccupancyGrid as OccupancyGrid,
    grid_to_building as grid_to_building,
    load_map as load_map,
    load_occupancy as load_occupancy,
)
from ._navigate import (
    CROP_SIZE as CROP_SIZE,
    LocalInputs as LocalInputs,
    NavConfig as NavConfig,
    Trial as Trial,
    local_inputs as local_inputs,
    navigate as navigate,
)
from ._prm import (
    PRM as PRM,
)
from ._roadmap import build_roadmap as build_roadmap, make_roadmap_builder as make_roadmap_builder
from ._roadmap_search import roadmap_shortest_path as roadmap_shortest_path
from ._sampling import (
    LocalDistribution as LocalDistribution,
    embed_local_distribution as embed_local_distribution,
)
from ._semantics import plot_semantics as plot_semantics
from ._sensors import SensorConfig as SensorConfig, sense as sense
from ._shortest_path import SoftCostGraph as SoftCostGraph, shortest_path as shortest_path
from ._tasks import sample_tasks as sample_tasks, task_pools as task_pools

#: Names that moved to :mod:`jaxsem.lsd` (LSD's expert data is the method's, not the planner's).
_MOVED_TO_LSD = (
    "EXPERT_SCHEMA",
    "SCHEMA_KEYS",
    "ExpertConfig",
    "full_map_state",
    "generate_expert_samples",
    "load_expert_dataset",
    "with_full_map",
    "write_expert_dataset",
)


def __getattr__(name: str):
    if name in _MOVED_TO_LSD:
        raise AttributeError(
            f"jaxsem.planning.{name} moved to jaxsem.lsd.{name} (same arguments): expert data is LSD's "
            "training data, and jaxsem.planning (the planner every method calls) imports no method"
        )
    raise AttributeError(f"module 'jaxsem.planning' has no attribute {name!r}")

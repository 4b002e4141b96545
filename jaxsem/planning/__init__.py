"""LSD planning world: procedural buildings, ray-cast sensors, soft-cost shortest paths, PRM,
the online navigation loop and the test tasks (thesis chapter 3). LSD's expert data and training
live in :mod:`jaxsem.lsd`.

Conventions: grids are ``[row, col] = [y, x]`` with an explicit ``origin`` (world x, y of the
corner of cell [0, 0]) and ``resolution`` (metres per cell, 0.1 by default); world z is up.

- World (:func:`generate_building`, :class:`Building`): ``occupancy`` (H, W) bool, ``semantic``
  (H, W) int8 with ``NONE, WALL, DOOR, WINDOW, EXIT_SIGN = 0, 1, 2, 3, 4``, ``indoor`` mask;
  families 'train' / 'test' (disjoint seed streams, different size and room ranges).
- Partial maps (:class:`MapState`): occupancy int8 ``UNKNOWN, FREE, OCCUPIED = -1, 0, 1`` and a
  semantic int8 map of the objects seen; :func:`sense` updates them (jitted, vmappable).
- Expert / C*: :class:`SoftCostGraph` (scipy Dijkstra, cost rising near walls),
  :func:`shortest_path`.
- PRM: :class:`PRM` (build once, grow, update the map, many queries; :func:`clear_map_cache`
  drops the per-map setup it keeps for the latest maps), the pure pieces
  :func:`roadmap_init` / :func:`roadmap_grow` / :func:`roadmap_recheck` / :func:`roadmap_connect`,
  :func:`build_roadmap` (one shot), :func:`make_roadmap_builder` (pure, vmappable),
  :func:`roadmap_shortest_path` (scipy, host), :func:`embed_local_distribution` (section 3.2.5).
- Online loop: :func:`navigate` / :class:`Trial` with ``sampler=None`` (uniform) or a function
  of :class:`LocalInputs` (160 x 160 crops + context) returning a 160 x 160 distribution.
- Real maps: :func:`load_map` (ROS map_server YAML + image, MRPT ``.gridmap(.gz)``, a plain
  image) into a :class:`Building` on the planner's 0.1 m cells (:func:`resample_occupancy`),
  with doors found from the occupancy (:func:`find_doors`), the footprint
  (:func:`building_footprint`; the largest open area stands in for a missing outside,
  :func:`largest_open_region`), hand annotations (:func:`read_annotations`,
  :func:`apply_annotations`) and a figure (:func:`plot_semantics`); :func:`load_occupancy` for
  the raw three-state grid.
- Tasks: :func:`sample_tasks` ('II' / 'IO', with C*), their pools :func:`task_pools`.
"""

from ._buildings import (
    HOUSE_PARAMS as HOUSE_PARAMS,
    TEST_PARAMS as TEST_PARAMS,
    TRAIN_PARAMS as TRAIN_PARAMS,
    Building as Building,
    BuildingParams as BuildingParams,
    HouseParams as HouseParams,
    building_family as building_family,
    generate_building as generate_building,
    generate_house as generate_house,
)
from ._edges import (
    polyline_clear as polyline_clear,
    query_reach as query_reach,
)
from ._grid import (
    DEFAULT_RESOLUTION as DEFAULT_RESOLUTION,
    DOOR as DOOR,
    EXIT_SIGN as EXIT_SIGN,
    FREE as FREE,
    NONE as NONE,
    OBJECT_CLASSES as OBJECT_CLASSES,
    OCCUPIED as OCCUPIED,
    SEMANTIC_NAMES as SEMANTIC_NAMES,
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
    MIN_OUTSIDE_AREA as MIN_OUTSIDE_AREA,
    OccupancyGrid as OccupancyGrid,
    grid_to_building as grid_to_building,
    load_map as load_map,
    load_occupancy as load_occupancy,
    resample_occupancy as resample_occupancy,
)
from ._navigate import (
    CONTEXT_SIZE as CONTEXT_SIZE,
    CROP_SIZE as CROP_SIZE,
    LocalInputs as LocalInputs,
    NavConfig as NavConfig,
    NavResult as NavResult,
    Trial as Trial,
    local_inputs as local_inputs,
    navigate as navigate,
)
from ._neighbours import (
    knn_within_radius as knn_within_radius,
)
from ._prm import (
    PRM as PRM,
)
from ._roadmap import (
    DEFAULT_SECTORS as DEFAULT_SECTORS,
    LEARNED_RADIUS_FACTOR as LEARNED_RADIUS_FACTOR,
    Roadmap as Roadmap,
    build_roadmap as build_roadmap,
    default_radius as default_radius,
    make_roadmap_builder as make_roadmap_builder,
    prm_star_k as prm_star_k,
    roadmap_connect as roadmap_connect,
    roadmap_grow as roadmap_grow,
    roadmap_init as roadmap_init,
    roadmap_recheck as roadmap_recheck,
)
from ._roadmap_search import (
    RoadmapPath as RoadmapPath,
    roadmap_shortest_path as roadmap_shortest_path,
)
from ._sampling import (
    embed_local_distribution as embed_local_distribution,
    sample_points as sample_points,
)
from ._semantics import (
    DOOR_WIDTH as DOOR_WIDTH,
    apply_annotations as apply_annotations,
    building_footprint as building_footprint,
    find_doors as find_doors,
    largest_open_region as largest_open_region,
    plot_semantics as plot_semantics,
    read_annotations as read_annotations,
    semantic_grid as semantic_grid,
)
from ._sensors import (
    SensorConfig as SensorConfig,
    cast_rays as cast_rays,
    sense as sense,
)
from ._shortest_path import (
    GridPath as GridPath,
    SearchTree as SearchTree,
    SoftCostGraph as SoftCostGraph,
    shortest_path as shortest_path,
    soft_cost as soft_cost,
)
from ._tasks import (
    Task as Task,
    sample_tasks as sample_tasks,
    task_pools as task_pools,
)

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

"""Inside-Inside / Inside-Outside test tasks (thesis 3.3.3): start and goal pools and the
resolution-optimal C* of each task on the true map.

The pools are free cells at least ``clearance`` metres from any obstacle, inside the building's
``indoor`` region (starts, II goals) or outside it (IO goals).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import scipy.ndimage

from ._buildings import Building
from ._navigate import NavConfig, NavResult, navigate
from ._shortest_path import SoftCostGraph


def task_pools(building: Building, clearance: float) -> tuple[np.ndarray, np.ndarray]:
    """(inside, outside): (M, 2) int cells that are free and at least ``clearance`` metres from
    the nearest obstacle, inside and outside the building's ``indoor`` region. The start and goal
    pools of :func:`sample_tasks` and of LSD's expert data."""
    d = np.asarray(scipy.ndimage.distance_transform_edt(~building.occupancy)) * building.resolution
    ok = d >= clearance
    return np.argwhere(ok & building.indoor), np.argwhere(ok & ~building.indoor)


class Task(NamedTuple):
    """A test task: start/goal world (x, y) (2,), initial yaw, goal_outdoors (the network's
    context flag: an Inside-Outside goal, unless the map's outside is a stand-in,
    ``Building.outside_is_outdoors``), c_star (metres of the soft-cost optimal path on the true
    map), c_star_cost (its soft cost)."""

    start: np.ndarray
    goal: np.ndarray
    yaw0: float
    goal_outdoors: bool
    c_star: float
    c_star_cost: float

    def navigate(self, world, key, config: NavConfig = NavConfig(), sampler: Callable | None = None) -> NavResult:
        """Runs this task as one online navigation trial in ``world`` from its start, initial yaw
        and context flag to its goal (:func:`~jaxsem.planning.navigate`)."""
        return navigate(world, self.start, self.goal, key, config, sampler, self.yaw0, self.goal_outdoors)


def sample_tasks(
    building: Building,
    kind: str,
    count: int,
    seed: int,
    min_distance: float = 8.0,
    clearance: float = 0.3,
    graph: SoftCostGraph | None = None,
    max_distance: float | None = None,
    max_tries: int | None = None,
) -> list:
    """``count`` test tasks of ``kind`` 'II' (start and goal indoors) or 'IO' (start indoors,
    goal outdoors), each with its resolution-optimal C*.

    min_distance, max_distance: bounds (metres) on the straight-line start-goal distance (None:
    no upper bound; on a campus-sized map a bound keeps tasks the size of the thesis' buildings);
    clearance: metres from the nearest obstacle for start and goal (keeps them out of a laser
    map's thin slivers); graph: the map's :class:`SoftCostGraph` when one is already built;
    max_tries: candidate pairs drawn before giving up (default ``50 * count``). Fewer than
    ``count`` tasks come back when the pools cannot give them (check ``len``); none at all comes
    with a ``UserWarning`` saying why (no free cell with that clearance, or how many pairs fell
    outside the distance bounds or had no path), as an empty list is otherwise easy to miss.
    """
    if kind not in ("II", "IO"):
        raise ValueError(f"kind: expected 'II' or 'IO', got {kind!r}")
    if not (min_distance >= 0 and (max_distance is None or max_distance > min_distance)):
        raise ValueError(f"max_distance: expected None or more than min_distance ({min_distance}), got {max_distance}")
    if not clearance >= 0:
        raise ValueError(f"clearance: expected >= 0 metres, got {clearance}")
    # A scanned map has seed -1: the stream takes the seed's low 32 bits (a generated building's
    # seeds are small and non-negative, so their tasks are unchanged).
    rng = np.random.default_rng([int(seed), int(building.seed) & 0xFFFFFFFF, 0x7A5C])
    inside, outside = task_pools(building, clearance)
    pool = inside if kind == "II" else outside
    if len(inside) == 0 or len(pool) == 0:
        where = "indoor" if len(inside) == 0 else "outdoor"
        warnings.warn(
            f"sample_tasks: no {kind} task: the map has no {where} free cell {clearance:g} m from an obstacle "
            "(lower clearance, or check the map's inside / outside)",
            stacklevel=2,
        )
        return []
    graph = graph or SoftCostGraph(building.occupancy, building)
    tasks = []
    tries = 50 * count if max_tries is None else int(max_tries)
    far, unreachable = 0, 0
    for _ in range(tries):
        if len(tasks) == count:
            break
        s = building.cell_center(inside[rng.integers(len(inside))])
        g = building.cell_center(pool[rng.integers(len(pool))])
        d = np.linalg.norm(g - s)
        if d < min_distance or (max_distance is not None and d > max_distance):
            far += 1
            continue
        p = graph.path(s, g)
        if not p.found:
            unreachable += 1
            continue
        outdoors = kind == "IO" and bool(getattr(building, "outside_is_outdoors", True))
        tasks.append(Task(s, g, float(rng.uniform(-math.pi, math.pi)), outdoors, p.length, p.cost))
    if count > 0 and not tasks:
        bounds = f"[{min_distance:g}, {'inf' if max_distance is None else f'{max_distance:g}'}] m"
        warnings.warn(
            f"sample_tasks: no {kind} task in {tries} tries: {far} start-goal pairs outside the distance "
            f"bounds {bounds} (min_distance, max_distance), {unreachable} with no path between them "
            "(raise max_tries, or widen the bounds)",
            stacklevel=2,
        )
    return tasks

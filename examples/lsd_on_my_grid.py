"""Plan with LSD on your own occupancy grid, with the same defaults as the benchmarks.

A user's map is a boolean grid (True = blocked), its origin and its resolution: here two rooms
joined by a 1 m door, drawn with numpy. ``planning.OccupancyGrid`` + ``grid_to_building`` make
it the planner's world (a ROS or MRPT map file would come from ``planning.load_map``), and one
``planning.navigate`` call runs the online loop with the shipped LSD sampler: the robot senses
as it goes, replans every 20 steps and reaches the goal. ``sampler=None`` runs the uniform PRM on
the same world; ``NavConfig()`` holds the same defaults either way (for a learned sampler the PRM
radius is ``learned_radius_factor`` = 2 times the uniform one, chosen by ``navigate`` itself).

Run: ``python examples/lsd_on_my_grid.py`` (about a minute on a 2-core CPU).
"""

from __future__ import annotations

import jax
import numpy as np

from jaxsem import lsd, planning


def two_rooms(resolution: float = 0.1) -> planning.OccupancyGrid:
    """A 16 x 10 m floor: outer walls, a dividing wall at x = 8 m with a 1 m door at y = 8.5 m."""
    h, w = int(10 / resolution), int(16 / resolution)
    cells = np.zeros((h, w), np.int8)  # FREE
    cells[:2], cells[-2:], cells[:, :2], cells[:, -2:] = 1, 1, 1, 1  # OCCUPIED walls, 0.2 m thick
    wall = int(8 / resolution)
    cells[:, wall : wall + 2] = 1
    door = slice(int(8.0 / resolution), int(9.0 / resolution))
    cells[door, wall : wall + 2] = 0
    return planning.OccupancyGrid(cells, origin=np.zeros(2), resolution=resolution)


def main(seed: int = 0) -> dict:
    world = planning.grid_to_building(two_rooms())
    start, goal = np.array([3.0, 3.0]), np.array([13.0, 7.0])
    model, params, _, _ = lsd.load_model()  # the shipped network
    sampler = lsd.LSDSampler(model, params)
    result = planning.navigate(world, start, goal, jax.random.PRNGKey(seed), sampler=sampler)
    out = {
        "success": bool(result.success),
        "reason": result.reason,
        "travelled_m": float(result.cost),
        "straight_line_m": float(np.linalg.norm(goal - start)),
        "end": result.path[-1].tolist(),
    }
    print(out)
    return out


if __name__ == "__main__":
    main()

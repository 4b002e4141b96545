"""Soft-cost, 8-connected shortest paths on the true map (scipy Dijkstra on a sparse grid graph).

This is the expert and the resolution-optimal reference C*: a per-cell cost that rises near
walls (``1 + weight * exp(-d / scale)`` per metre, ``d`` the distance to the nearest occupied
cell from a Euclidean distance transform), edges between 8-neighbours weighted by their length
times the mean cost of their two cells, and no diagonal step that cuts an occupied corner. It
runs on the host (numpy/scipy): one single-source search gives the optimal paths to every goal,
which is what the expert data generator needs. scipy's Dijkstra is many times faster here than a
jittable JAX min-plus sweep (``benchmarks/RESULTS.md``, "Other: devices and design
measurements").
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.ndimage
import scipy.sparse
import scipy.sparse.csgraph

from .. import quadrics as Q
from ._grid import GridLike, check_grid, check_point, host_grid

_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))  # the other four are the same edges reversed
# Knight moves (16-connected) and the two cells each one's segment crosses between its ends: the
# segment spends a quarter of its length in each of the four cells.
_KNIGHTS = (
    ((1, 2), ((0, 1), (1, 1))),
    ((2, 1), ((1, 0), (1, 1))),
    ((1, -2), ((0, -1), (1, -1))),
    ((2, -1), ((1, 0), (1, -1))),
)


def soft_cost(occupancy, resolution: float, weight: float = 4.0, scale: float = 0.4) -> np.ndarray:
    """(H, W) cost per metre: ``1 + weight * exp(-d / scale)``, ``inf`` on occupied cells.

    occupancy: (H, W) bool; d: metres from the cell centre to the nearest occupied cell centre.
    """
    occ = check_grid("occupancy", occupancy, "bool")
    d = np.asarray(scipy.ndimage.distance_transform_edt(~occ)) * float(resolution)
    cost = 1.0 + float(weight) * np.exp(-d / float(scale))
    return np.where(occ, np.inf, cost)


def _grid_edges(occ: np.ndarray, cost: np.ndarray, resolution: float, connectivity: int = 8):
    H, W = occ.shape
    idx = np.arange(H * W).reshape(H, W)
    src, dst, wts = [], [], []

    def shifted(a, dr, dc):  # a[r + dr, c + dc] over the block of sources below
        return a[r0 + dr : r1 + dr, c0 + dc : c1 + dc]

    moves = [((dr, dc), ()) for dr, dc in _OFFSETS] + (list(_KNIGHTS) if connectivity == 16 else [])
    for (dr, dc), crossed in moves:
        r0, r1 = max(0, -dr), H - max(0, dr)
        c0, c1 = max(0, -dc), W - max(0, dc)
        ok = ~shifted(occ, 0, 0) & ~shifted(occ, dr, dc)
        if dr and dc and not crossed:  # no corner cutting: both side cells must be free too
            ok &= ~shifted(occ, dr, 0) & ~shifted(occ, 0, dc)
        for mr, mc in crossed:
            ok &= ~shifted(occ, mr, mc)
        step = resolution * float(np.hypot(dr, dc))
        if crossed:  # a quarter of the segment in each cell it crosses
            cells = (shifted(cost, 0, 0), shifted(cost, dr, dc)) + tuple(shifted(cost, *m) for m in crossed)
            mean = sum(c[ok] for c in cells) / 4.0
        else:
            mean = 0.5 * (shifted(cost, 0, 0)[ok] + shifted(cost, dr, dc)[ok])
        src.append(shifted(idx, 0, 0)[ok])
        dst.append(shifted(idx, dr, dc)[ok])
        wts.append(step * mean)
    return np.concatenate(src), np.concatenate(dst), np.concatenate(wts)


@dataclasses.dataclass(frozen=True)
class GridPath:
    """A path on the grid. cells: (K, 2) int [row, col] from start to goal; points: (K, 2) world
    (x, y) of the cell centres; cost: soft cost (metres weighted by cell costs); length: metres;
    found: False when the goal is unreachable (then cells is empty and cost/length are inf)."""

    cells: np.ndarray
    points: np.ndarray
    cost: float
    length: float
    found: bool


class SoftCostGraph:
    """The 8-connected soft-cost graph of one true map, built once and searched many times.

    ``SoftCostGraph(occupancy, grid)`` (``grid``: the map's :class:`jaxsem.quadrics.Grid`, or a
    map holding one: ``SoftCostGraph(building.occupancy, building)``); ``search(start)`` runs one single-source
    Dijkstra and returns a :class:`SearchTree` from which ``path_to(goal)`` reads any path.

    connectivity: 8 (the expert's and C*'s graph) or 16, which adds the knight moves (a cell two
    along and one across, when the two cells its segment crosses are free; weighted by the mean
    cost of the four cells it passes). A straight line in free space comes out at most 8.2 %
    long on the 8-connected grid and 2.7 % on the 16-connected one, so ``weight=0,
    connectivity=16`` gives a near floor for the length any path between two cells can have
    (what the LSD benchmarks use to say how much room a target leaves).
    """

    def __init__(
        self,
        occupancy,
        grid: GridLike,
        weight: float = 4.0,
        scale: float = 0.4,
        connectivity: int = 8,
    ):
        if connectivity not in (8, 16):
            raise ValueError(f"connectivity: expected 8 or 16, got {connectivity!r}")
        occ = check_grid("occupancy", occupancy, "bool")
        self.occupancy = occ
        self.grid = host_grid("grid", grid, occ.shape)
        self.origin = self.grid.origin
        self.resolution = float(self.grid.resolution)
        self.cost = soft_cost(occ, self.resolution, weight, scale)
        H, W = occ.shape
        src, dst, wts = _grid_edges(occ, self.cost, self.resolution, connectivity)
        self.graph = scipy.sparse.csr_matrix((wts, (src, dst)), shape=(H * W, H * W))

    @property
    def shape(self):
        return self.occupancy.shape

    def cell_of(self, name, xy):
        p = check_point(name, xy, self.occupancy, self.grid)
        return Q.world_to_cell(p, self.origin, self.resolution, xp=np)

    def search(self, start, limit: float | None = None) -> SearchTree:
        """Single-source Dijkstra from the world point ``start`` (2,) (must be a free cell).

        limit: stop at this cost (cells farther away read as unreachable); None: the whole map.
        """
        rc = self.cell_of("start", start)
        if limit is not None and not limit > 0:
            raise ValueError(f"limit: expected None or a cost > 0, got {limit!r}")
        W = self.shape[1]
        dist, pred = scipy.sparse.csgraph.dijkstra(
            self.graph,
            directed=False,
            indices=int(rc[0] * W + rc[1]),
            return_predecessors=True,
            limit=np.inf if limit is None else float(limit),
        )
        return SearchTree(self, rc, dist.reshape(self.shape), pred)

    def path(self, start, goal) -> GridPath:
        """The soft-cost optimal path between two world points (2,)."""
        self.cell_of("goal", goal)
        return self.search(start).path_to(goal)


@dataclasses.dataclass(frozen=True)
class SearchTree:
    """Result of a single-source search. dist: (H, W) soft cost to every cell (inf unreachable)."""

    graph: SoftCostGraph
    start_cell: np.ndarray
    dist: np.ndarray
    predecessors: np.ndarray

    def path_to(self, goal) -> GridPath:
        """Path from the search's start to the world point ``goal`` (2,)."""
        rc = self.graph.cell_of("goal", goal)
        return self.path_to_cell(rc)

    def path_to_cell(self, rc) -> GridPath:
        g = self.graph
        H, W = g.shape
        node = int(rc[0]) * W + int(rc[1])
        if not np.isfinite(self.dist.flat[node]):
            empty = np.zeros((0, 2), np.int64)
            return GridPath(empty, np.zeros((0, 2)), float("inf"), float("inf"), False)
        nodes = [node]
        while nodes[-1] >= 0 and nodes[-1] != int(self.start_cell[0]) * W + int(self.start_cell[1]):
            nodes.append(int(self.predecessors[nodes[-1]]))
        nodes = np.array(nodes[::-1], np.int64)
        cells = np.stack([nodes // W, nodes % W], -1)
        points = Q.cell_to_world(cells, g.origin, g.resolution, xp=np)
        length = float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=-1)))
        return GridPath(cells, points, float(self.dist.flat[node]), length, True)


def shortest_path(occupancy, start, goal, grid: GridLike, weight: float = 4.0, scale: float = 0.4) -> GridPath:
    """Soft-cost optimal path from ``start`` to ``goal`` (world (x, y), (2,)) on a bool grid
    ``occupancy`` whose :class:`jaxsem.quadrics.Grid` is ``grid`` (or a map holding one).

    Builds the graph each call; keep a :class:`SoftCostGraph` for many queries on one map.
    """
    g = SoftCostGraph(occupancy, grid, weight, scale)
    return g.path(start, goal)

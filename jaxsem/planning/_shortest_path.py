"""Soft-cost, 8-connected shortest paths on the true map (scipy Dijkstra on a sparse grid graph).

This is the expert and the resolution-optimal reference C*: a per-cell cost that rises near
walls (``1 + weight * exp(-d / scale)`` per metre, ``d`` the distance to the nearest occupied
cell from a Euclidean distance transform), edges between 8-neighbours weighted by their length
times the mean cost of their two cells, and no diagonal step that cuts an occupied corner. It
runs on the host (numpy/scipy): one single-source search gives the optimal paths to every goal,
which is what the expert data generator needs. scipy's Dijkstra is many times faster here than a
jittable JAX min-plus sweep (``benchmarks/RESULTS.md``, "Design measurements").
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.ndimage
import scipy.sparse
import scipy.sparse.csgraph

from .. import quadrics as Q
from ._grid import check_grid, check_point

_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))  # the other four are the same edges reversed


def soft_cost(occupancy, resolution: float, weight: float = 4.0, scale: float = 0.4) -> np.ndarray:
    """(H, W) cost per metre: ``1 + weight * exp(-d / scale)``, ``inf`` on occupied cells.

    occupancy: (H, W) bool; d: metres from the cell centre to the nearest occupied cell centre.
    """
    occ = check_grid("occupancy", occupancy, "bool")
    d = np.asarray(scipy.ndimage.distance_transform_edt(~occ)) * float(resolution)
    cost = 1.0 + float(weight) * np.exp(-d / float(scale))
    return np.where(occ, np.inf, cost)


def _grid_edges(occ: np.ndarray, cost: np.ndarray, resolution: float):
    H, W = occ.shape
    idx = np.arange(H * W).reshape(H, W)
    src, dst, wts = [], [], []
    for dr, dc in _OFFSETS:
        r0, r1 = max(0, -dr), H - max(0, dr)
        c0, c1 = max(0, -dc), W - max(0, dc)
        a = (slice(r0, r1), slice(c0, c1))
        b = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
        ok = ~occ[a] & ~occ[b]
        if dr and dc:  # no corner cutting: both side cells must be free too
            ok &= ~occ[r0 + dr : r1 + dr, c0:c1] & ~occ[r0:r1, c0 + dc : c1 + dc]
        step = resolution * (np.sqrt(2.0) if (dr and dc) else 1.0)
        src.append(idx[a][ok])
        dst.append(idx[b][ok])
        wts.append(step * 0.5 * (cost[a][ok] + cost[b][ok]))
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

    ``SoftCostGraph(occupancy, origin, resolution)``; ``search(start)`` runs one single-source
    Dijkstra and returns a :class:`SearchTree` from which ``path_to(goal)`` reads any path.
    """

    def __init__(self, occupancy, origin, resolution: float, weight: float = 4.0, scale: float = 0.4):
        occ = check_grid("occupancy", occupancy, "bool")
        self.occupancy = occ
        self.origin = np.asarray(origin, np.float64)
        if self.origin.shape != (2,):
            raise ValueError(f"origin: expected shape (2,), got shape {self.origin.shape}")
        self.resolution = float(resolution)
        self.cost = soft_cost(occ, self.resolution, weight, scale)
        H, W = occ.shape
        src, dst, wts = _grid_edges(occ, self.cost, self.resolution)
        self.graph = scipy.sparse.csr_matrix((wts, (src, dst)), shape=(H * W, H * W))

    @property
    def shape(self):
        return self.occupancy.shape

    def cell_of(self, name, xy):
        p = check_point(name, xy, self.occupancy, self.origin, self.resolution)
        return Q.world_to_cell(p, self.origin, self.resolution, xp=np)

    def search(self, start) -> SearchTree:
        """Single-source Dijkstra from the world point ``start`` (2,) (must be a free cell)."""
        rc = self.cell_of("start", start)
        W = self.shape[1]
        dist, pred = scipy.sparse.csgraph.dijkstra(
            self.graph, directed=False, indices=int(rc[0] * W + rc[1]), return_predecessors=True
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


def shortest_path(
    occupancy, start, goal, origin, resolution: float, weight: float = 4.0, scale: float = 0.4
) -> GridPath:
    """Soft-cost optimal path from ``start`` to ``goal`` (world (x, y), (2,)) on a bool grid.

    Builds the graph each call; keep a :class:`SoftCostGraph` for many queries on one map.
    """
    g = SoftCostGraph(occupancy, origin, resolution, weight, scale)
    return g.path(start, goal)

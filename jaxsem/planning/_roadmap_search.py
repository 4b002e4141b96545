"""Shortest paths on a roadmap: the samples' edges kept on the host (made once per roadmap), a
query adding only its start's and goal's edges, a compiled A* (:mod:`jaxsem.planning._astar`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from ._astar import astar_path, search_graph
from ._roadmap import _QUERY, GOAL, START, Roadmap

# ----------------------------------------------------------------------------- search (host)


class RoadmapPath(NamedTuple):
    """vertices: (K,) roadmap slots from start (0) to goal (1); points: (K, 2) world;
    cost: summed edge weights; length: metres; found: bool (False: empty path, inf cost)."""

    vertices: np.ndarray
    points: np.ndarray
    cost: float
    length: float
    found: bool


class RoadmapPaths(NamedTuple):
    """Paths of a batch of queries (:meth:`~jaxsem.planning.PRM.query_many`), padded to the
    longest: vertices (Q, L) roadmap slots (-1 past each path's end); points (Q, L, 2) world
    (NaN past the end); size (Q,) vertices per path (0: none found); cost, length (Q,) (inf
    where none); found (Q,) bool."""

    vertices: np.ndarray
    points: np.ndarray
    size: np.ndarray
    cost: np.ndarray
    length: np.ndarray
    found: np.ndarray

    @classmethod
    def stack(cls, paths: list[RoadmapPath]) -> RoadmapPaths:
        L = max(len(p.vertices) for p in paths)
        Qn = len(paths)
        dtype = next((p.points.dtype for p in paths if p.found), np.dtype(np.float64))
        vertices = np.full((Qn, L), -1, np.int64)
        points = np.full((Qn, L, 2), np.nan, dtype)
        for i, p in enumerate(paths):
            vertices[i, : len(p.vertices)] = p.vertices
            points[i, : len(p.vertices)] = p.points
        return cls(
            vertices,
            points,
            np.array([len(p.vertices) for p in paths], np.int64),
            np.array([p.cost for p in paths], np.float64),
            np.array([p.length for p in paths], np.float64),
            np.array([p.found for p in paths], bool),
        )

    def path(self, i: int) -> RoadmapPath:
        """Query ``i``'s path as :meth:`~jaxsem.planning.PRM.query` returns it."""
        n = int(self.size[i])
        if not self.found[i]:
            return _NOT_FOUND
        return RoadmapPath(
            self.vertices[i, :n].copy(),
            self.points[i, :n].copy(),
            float(self.cost[i]),
            float(self.length[i]),
            True,
        )


_NOT_FOUND = RoadmapPath(np.zeros(0, np.int64), np.zeros((0, 2)), float("inf"), float("inf"), False)


def _edge_list(nbr, ok, w, rows):
    src = np.repeat(rows, nbr.shape[1])[ok.ravel()]
    dst = nbr.ravel()[ok.ravel()]
    # A zero weight would vanish from the sparse matrix; clamp tiny ones.
    return src, dst, np.maximum(w.ravel()[ok.ravel()], 1e-12)


class _SampleGraph:
    """The samples' edges of an eager roadmap as a :class:`~jaxsem.planning._astar.SearchGraph`
    (made once per roadmap; each query adds only its start's and goal's edges), from its
    points (M, 2), neighbours, valid flags and weights (M, k) (numpy or device arrays: the
    query rows 0 and 1 are not read)."""

    def __init__(self, points, neighbors, edge_valid, edge_weight):
        nbr = np.asarray(neighbors)
        M = nbr.shape[0]
        ok = np.asarray(edge_valid) & (nbr >= _QUERY) & (nbr < M)
        ok[:_QUERY] = False
        # float64 weights, tiny ones clamped (a zero weight would make a path's cost ambiguous).
        w = np.where(ok, np.maximum(np.asarray(edge_weight, np.float64), 1e-12), np.inf)
        self.points = np.asarray(points)
        self.graph = search_graph(nbr, ok, w, self.points, ok, fixed=True)


def _query_edges(nq, okq, wq):
    """A query's start edges and goal entries (destinations, float64 weights, tiny ones clamped)
    from its rows ``nq``, ``okq``, ``wq`` (2, k); None if the start has no edge, or neither the
    goal nor the start reaches the goal."""
    s_ok, g_ok = np.asarray(okq[0], bool), np.asarray(okq[1], bool)
    s_dst, s_w = nq[0][s_ok], np.maximum(np.asarray(wq[0], np.float64)[s_ok], 1e-12)
    g_dst, g_w = nq[1][g_ok], np.maximum(np.asarray(wq[1], np.float64)[g_ok], 1e-12)
    if len(s_dst) == 0 or (len(g_dst) == 0 and GOAL not in s_dst):
        return None
    return s_dst, s_w, g_dst, g_w


def _search(graph: _SampleGraph, roadmap: Roadmap) -> RoadmapPath:
    """Shortest path from the start of ``roadmap`` (its rows 0 and 1 linked) over ``graph``."""
    return _search_rows(
        graph,
        np.asarray(roadmap.points[:_QUERY]),
        np.asarray(roadmap.neighbors[:_QUERY]),
        np.asarray(roadmap.edge_valid[:_QUERY]),
        np.asarray(roadmap.edge_weight[:_QUERY]),
    )


def _search_rows(graph: _SampleGraph, q, nq, okq, wq) -> RoadmapPath:
    """A* (:func:`~jaxsem.planning._astar.astar_path`) from the start over the sample graph plus
    the start's edges; the goal is only entered. ``q``: (2, 2) the start and goal; ``nq``,
    ``okq``, ``wq``: their rows (2, k) of neighbours, flags and weights."""
    edges = _query_edges(nq, okq, wq)
    if edges is None:
        return _NOT_FOUND
    cost, path = astar_path(graph.graph, q, *edges)
    if not len(path):
        return _NOT_FOUND
    pts = graph.points[path]
    pts[path < _QUERY] = np.asarray(q, pts.dtype)[path[path < _QUERY]]
    length = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=-1)))
    return RoadmapPath(path, pts, cost, length, True)


def roadmap_shortest_path(roadmap: Roadmap, source: int = START, target: int = GOAL) -> RoadmapPath:
    """Shortest path on the roadmap (host). Default: start (0) to goal (1), by the queries'
    A*; between other slots, scipy's Dijkstra over the whole undirected edge list."""
    if (source, target) == (START, GOAL):
        graph = _SampleGraph(roadmap.points, roadmap.neighbors, roadmap.edge_valid, roadmap.edge_weight)
        return _search(graph, roadmap)
    pts = np.asarray(roadmap.points)
    M = pts.shape[0]
    src, dst, wt = _edge_list(
        np.asarray(roadmap.neighbors),
        np.asarray(roadmap.edge_valid),
        np.asarray(roadmap.edge_weight),
        np.arange(M),
    )
    graph = scipy.sparse.csr_matrix((wt, (src, dst)), shape=(M, M))
    dist, pred = scipy.sparse.csgraph.dijkstra(graph, directed=False, indices=int(source), return_predecessors=True)
    if not np.isfinite(dist[target]):
        return _NOT_FOUND
    path = [int(target)]
    while path[-1] != source:
        path.append(int(pred[path[-1]]))
    path = np.array(path[::-1])
    p = pts[path]
    length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=-1)))
    return RoadmapPath(path, p, float(dist[target]), length, True)

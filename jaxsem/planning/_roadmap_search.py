"""Shortest paths on a roadmap: the samples' edges kept in CSR form on the host, a query adding
only its start's and goal's edges, scipy's Dijkstra.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

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


_NOT_FOUND = RoadmapPath(np.zeros(0, np.int64), np.zeros((0, 2)), float("inf"), float("inf"), False)


def _edge_list(nbr, ok, w, rows):
    src = np.repeat(rows, nbr.shape[1])[ok.ravel()]
    dst = nbr.ravel()[ok.ravel()]
    # A zero weight would vanish from the sparse matrix; clamp tiny ones.
    return src, dst, np.maximum(w.ravel()[ok.ravel()], 1e-12)


class _SampleGraph:
    """The samples' edges as a CSR in the direction each was made (row i: the edges in vertex
    i's own list, in list order, so no sort is needed), rows 0 and 1 empty; searched as an
    undirected graph."""

    def __init__(self, roadmap: Roadmap):
        nbr = np.asarray(roadmap.neighbors)[_QUERY:]
        ok = np.asarray(roadmap.edge_valid)[_QUERY:]
        w = np.asarray(roadmap.edge_weight)[_QUERY:]
        M = nbr.shape[0] + _QUERY
        # A zero weight would vanish from the sparse matrix; clamp tiny ones. float64: scipy's
        # Dijkstra converts other dtypes through a copy that sums duplicate entries (an edge
        # that both endpoints list once doubled its weight when both directions were stored).
        self.indices = nbr[ok].astype(np.int32)
        self.data = np.maximum(w[ok].astype(np.float64), 1e-12)
        self.indptr = np.concatenate([np.zeros(_QUERY + 1, np.int64), np.cumsum(ok.sum(1))]).astype(np.int32)
        self.M = M


def _goal_entry(dist, goal_nodes, goal_weights) -> tuple[float, int]:
    """``(distance, via)`` of the goal, which is only entered: straight (``via`` -1), or through
    the one of its neighbours ``goal_nodes`` (weights ``goal_weights``) that is shortest in all,
    given the start's distances ``dist``."""
    best, via = dist[GOAL], -1
    if len(goal_nodes):
        through = dist[goal_nodes] + goal_weights
        i = int(np.argmin(through))
        if through[i] < best:
            best, via = float(through[i]), int(goal_nodes[i])
    return best, via


def _trace_back(pred, via: int) -> np.ndarray:
    """The node path START ... (via) GOAL of a Dijkstra from the start (predecessors ``pred``)."""
    path = [GOAL] if via < 0 else [GOAL, via]
    node = path[-1]
    while node != START:
        node = int(pred[node])
        path.append(node)
    return np.array(path[::-1])


def _search(graph: _SampleGraph, roadmap: Roadmap) -> RoadmapPath:
    """Dijkstra from the start over the sample graph (undirected) plus the start's edges; the
    goal's edges are read off the distances (the goal is only entered, never left)."""
    M = graph.M
    nbr = np.asarray(roadmap.neighbors[:_QUERY])
    ok = np.asarray(roadmap.edge_valid[:_QUERY])
    w = np.asarray(roadmap.edge_weight[:_QUERY])
    s_dst, s_w = nbr[0][ok[0]], np.maximum(w[0][ok[0]].astype(np.float64), 1e-12)
    g_dst, g_w = nbr[1][ok[1]], np.maximum(w[1][ok[1]].astype(np.float64), 1e-12)
    if len(s_dst) == 0 or (len(g_dst) == 0 and GOAL not in s_dst):
        return _NOT_FOUND
    n0 = len(s_dst)
    indptr = graph.indptr + n0
    indptr[0] = 0
    csr = scipy.sparse.csr_matrix(
        (
            np.concatenate([s_w, graph.data]),
            np.concatenate([s_dst.astype(np.int32), graph.indices]),
            indptr,
        ),
        shape=(M, M),
    )
    dist, pred = scipy.sparse.csgraph.dijkstra(csr, directed=False, indices=START, return_predecessors=True)
    best, via = _goal_entry(dist, g_dst, g_w)
    if not np.isfinite(best):
        return _NOT_FOUND
    path = _trace_back(pred, via)
    pts = np.asarray(roadmap.points)[path]
    length = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=-1)))
    return RoadmapPath(path, pts, float(best), length, True)


def roadmap_shortest_path(roadmap: Roadmap, source: int = START, target: int = GOAL) -> RoadmapPath:
    """Shortest path on the roadmap by scipy Dijkstra (host). Default: start (0) to goal (1);
    other slots search the whole undirected edge list."""
    if (source, target) == (START, GOAL):
        return _search(_SampleGraph(roadmap), roadmap)
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

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
    """The samples' edges as a CSR searched as a directed graph: each edge in both directions
    (a vertex's own list in list order, then the entries of the lists that name it), so scipy's
    Dijkstra needs no transpose per query (its undirected mode makes one: most of a query's
    search time at 5000 vertices). Row 0, the start, holds ``k`` slots that each query fills
    with its start's edges (unused slots: a loop on the start, which never shortens a path);
    row 1, the goal, is empty (the goal is only entered, read off the distances)."""

    def __init__(self, roadmap: Roadmap):
        nbr = np.asarray(roadmap.neighbors)[_QUERY:]
        ok = np.asarray(roadmap.edge_valid)[_QUERY:] & (nbr >= _QUERY) & (nbr < roadmap.neighbors.shape[0])
        w = np.asarray(roadmap.edge_weight)[_QUERY:]
        M, k = roadmap.neighbors.shape
        self.M, self.k = M, k
        self.points = np.asarray(roadmap.points)
        # A zero weight would vanish from the sparse matrix; clamp tiny ones. float64: scipy's
        # Dijkstra converts other dtypes through a copy that sums duplicate entries (an edge
        # that both endpoints list: the same weight twice, a parallel edge, harmless as is).
        cnt = np.concatenate([np.zeros(_QUERY, np.int64), ok.sum(1)])
        own_ip = np.zeros(M + 1, np.int64)
        np.cumsum(cnt, out=own_ip[1:])
        dst = nbr[ok].astype(np.int32)
        wt = np.maximum(w[ok].astype(np.float64), 1e-12)
        own = scipy.sparse.csr_matrix((wt, dst, own_ip), shape=(M, M))
        rev = own.transpose().tocsr()  # the entries that name each vertex, by source (linear time)
        fwd = cnt.copy()
        fwd[START] = k  # the start's slots
        rcnt = np.diff(rev.indptr).astype(np.int64)
        indptr = np.zeros(M + 1, np.int64)
        np.cumsum(fwd + rcnt, out=indptr[1:])
        own_at = np.arange(len(dst)) + np.repeat(indptr[:-1] - own_ip[:-1] + (fwd - cnt), cnt)
        rev_at = np.arange(len(rev.indices)) + np.repeat(indptr[:-1] + fwd - rev.indptr[:-1], rcnt)
        indices = np.empty(indptr[-1], np.int32)
        data = np.empty(indptr[-1], np.float64)
        indices[:k], data[:k] = START, 1.0
        indices[own_at], data[own_at] = dst, wt
        indices[rev_at], data[rev_at] = rev.indices, rev.data
        self.csr = scipy.sparse.csr_matrix((data, indices, indptr.astype(np.int32)), shape=(M, M))
        self.total = float(wt.sum())


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
    """Dijkstra from the start of ``roadmap`` (its rows 0 and 1 linked) over ``graph``."""
    return _search_rows(
        graph,
        np.asarray(roadmap.points[:_QUERY]),
        np.asarray(roadmap.neighbors[:_QUERY]),
        np.asarray(roadmap.edge_valid[:_QUERY]),
        np.asarray(roadmap.edge_weight[:_QUERY]),
    )


def _search_rows(graph: _SampleGraph, q, nq, okq, wq) -> RoadmapPath:
    """Dijkstra from the start over the sample graph plus the start's edges; the goal's edges
    are read off the distances (the goal is only entered, never left). ``q``: (2, 2) the start
    and goal; ``nq``, ``okq``, ``wq``: their rows (2, k) of neighbours, flags and weights.

    The search stops at a distance ``limit`` (scipy settles only the nodes within it) that starts
    a little above the straight-line distance and grows until the goal is reached within it:
    a node within the limit has its exact distance and predecessor, so the path is the full
    search's, at the cost of the nodes within the path's own length rather than the whole map's."""
    s_ok, g_ok = okq[0], okq[1]
    s_dst, s_w = nq[0][s_ok], np.maximum(wq[0][s_ok].astype(np.float64), 1e-12)
    g_dst, g_w = nq[1][g_ok], np.maximum(wq[1][g_ok].astype(np.float64), 1e-12)
    if len(s_dst) == 0 or (len(g_dst) == 0 and GOAL not in s_dst):
        return _NOT_FOUND
    csr = graph.csr
    k = graph.k
    csr.indices[:k] = START
    csr.data[:k] = 1.0
    csr.indices[: len(s_dst)] = s_dst
    csr.data[: len(s_dst)] = s_w
    q64 = np.asarray(q, np.float64)
    D = float(np.linalg.norm(q64[1] - q64[0]))
    reach = float(s_w.max()) + (float(g_w.max()) if len(g_w) else 0.0)
    limit = 1.25 * D + 2.0 * reach
    while True:
        if limit >= graph.total + reach:
            limit = np.inf
        dist, pred = scipy.sparse.csgraph.dijkstra(
            csr, directed=True, indices=START, return_predecessors=True, limit=limit
        )
        best, via = _goal_entry(dist, g_dst, g_w)
        if best <= limit or limit == np.inf:
            break
        limit *= 2.0
    if not np.isfinite(best):
        return _NOT_FOUND
    path = _trace_back(pred, via)
    pts = graph.points[path]
    pts[path < _QUERY] = np.asarray(q, pts.dtype)[path[path < _QUERY]]
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

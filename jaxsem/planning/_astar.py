"""Compiled A* over a roadmap's sample edges (host, numba): the search of every roadmap query,
eager and lazy.

A roadmap's edges are its rows: vertex ``r`` lists up to ``K`` neighbours ``nbr[r]`` with weights
``w[r]`` and a flag ``usable[r]`` (an eager roadmap: the edge is valid; a lazy one: the edge may
still be in the roadmap). Edges are undirected, so a vertex's edges are its own row and the
entries of other rows that name it; :class:`SearchGraph` keeps both in one CSR (made once per
roadmap, in linear time), each edge with the index of its flag, which the search reads in
place: a lazy search that learns an edge is blocked only flips its flag.

The start (slot 0) is given as its edges, the goal (slot 1) as the edges that enter it; the goal is
only entered, never left. The heuristic is ``c * |x - goal|`` with ``c`` the smallest ratio of
weight to straight-line length over every edge the search may use, shaved by 1e-6 for the
rounding of float32 weights: admissible and consistent, so the first time the cheapest open
vertex's estimate reaches the best goal entry found, that entry is the shortest path (the
search stops there, at the ellipse-like region a path can cross, not the whole roadmap).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

#: Relative shave of the heuristic's ratio: weights are float32, lengths float64.
_SHAVE = 1e-6


@functools.cache
def _kernels():
    """The compiled kernels (numba is imported, and the kernels loaded from numba's cache or
    compiled, on first use: ``import jaxsem`` does not pay for them)."""
    from . import _astar_kernels as k

    return (k.adjacency_count, k.adjacency_scatter, k.adjacency_lists), k.astar


class SearchGraph(NamedTuple):
    """A roadmap's sample edges for :func:`astar_path`, both ways, listed by vertex: vertex
    ``v``'s entries lie from start[v] to stop[v] (M,) (a list may end before the next one
    starts) in adj (E,) int32 the other end, wt (E,) float64 the weight, eid (E,) the entry's
    index into ``usable`` (M * K,) bool, read at each search (a lazy roadmap updates it in
    place); points (M, 2) float64; ratio: the smallest weight / length over the entries (the
    heuristic's factor before the query's own edges).

    The search numbers the vertices in Z-order of their points (``order``: search id -> slot,
    ``rank``: slot -> search id; the query's slots 0 and 1 keep theirs): a search reads each
    vertex's cost, state and point where it reads its neighbours', in the same cache lines
    (slot order is the order samples were drawn: neighbours anywhere). start, stop, adj and px, py (the
    points' columns) are in search ids; eid, points are the roadmap's."""

    start: np.ndarray
    stop: np.ndarray
    adj: np.ndarray
    wt: np.ndarray
    eid: np.ndarray
    usable: np.ndarray
    points: np.ndarray
    px: np.ndarray
    py: np.ndarray
    ratio: float
    order: np.ndarray
    rank: np.ndarray


def _z_order(points) -> np.ndarray:
    """Slot ids (M,) sorted by the Z-order (Morton) code of their points on a 1024 x 1024 grid
    over the samples' box, slots 0 and 1 (the query's) first: neighbours in the plane get
    nearby ids (:func:`~jaxsem.planning._astar_kernels.z_order`)."""
    from . import _astar_kernels

    return _astar_kernels.z_order(np.ascontiguousarray(np.nan_to_num(np.asarray(points, np.float64))), 2)


def search_graph(nbr, usable, w, points, entries, ratio: float | None = None, *, fixed: bool = False) -> SearchGraph:
    """A :class:`SearchGraph` of the rows ``nbr`` (M, K) int32 and vertex ``points`` (M, 2).
    ``entries`` (M, K) bool: the entries that are edges, now or later (each names a vertex
    2 <= v < M); ``usable`` (M, K) bool, C-ordered, kept by reference (flattened as a view):
    those that may be used now. ``w`` (M, K): the weights (float64, positive), or None: the
    entries' lengths in the points' dtype, as the roadmap computes an edge's length (then the
    heuristic's ratio is 1). ``ratio``: the smallest weight / length when the caller knows it,
    else measured here. ``fixed``: ``usable`` is ``entries`` and never changes (an eager
    roadmap), so of a vertex's entries to one other end with one weight (an edge both its ends
    chose) one is kept: the searches' answers are the same, and they read half as many."""
    if fixed and usable is not entries and not np.array_equal(usable, entries):
        raise ValueError("usable: with fixed=True expected the entries themselves")
    entries = np.asarray(entries, bool)
    if not (usable.dtype == np.bool_ and usable.flags.c_contiguous and usable.shape == nbr.shape):
        raise ValueError(f"usable: expected a C-ordered bool array of shape {nbr.shape}")
    (count, scatter, lists), _ = _kernels()
    points = np.ascontiguousarray(points)
    M, K = nbr.shape
    order = _z_order(points)
    rank = np.empty_like(order)
    rank[order] = np.arange(M)
    lengths = w is None
    w = np.zeros((1, 1)) if lengths else np.ascontiguousarray(w, np.float64)
    nb = np.ascontiguousarray(nbr, np.int32)
    entries = np.ascontiguousarray(entries)
    args = (nb, entries, w, points, order, rank, lengths)
    # Three passes, each over blocks of search ids (on threads for a large roadmap).
    from ._edges import _each_block

    blocks = _vertex_blocks(M, nb.size)
    counts = np.zeros((len(blocks), M + 1), np.int64)  # entries of each block naming each vertex
    own = np.zeros(M, np.int64)
    measured = min(_each_block(blocks, lambda t, a, b: count(*args, a, b, counts[t], own)))
    into = np.cumsum(counts.sum(0))  # where the entries naming each vertex start
    R = int(into[M])
    fills = into[:M] + np.cumsum(counts[:, 1:], axis=0) - counts[:, 1:]  # each block's place among them
    src, rwt, reid = np.empty(R, np.int32), np.empty(R, np.float64), np.empty(R, np.int32)
    _each_block(blocks, lambda t, a, b: scatter(*args, a, b, fills[t], src, rwt, reid))
    start = into[:M] + np.cumsum(own) - own  # room for each vertex's entries
    adj, wt, eid = np.empty(2 * R, np.int32), np.empty(2 * R, np.float64), np.empty(2 * R, np.int32)
    stop = np.empty(M, np.int64)
    _each_block(blocks, lambda t, a, b: lists(*args, fixed, a, b, into, src, rwt, reid, start, adj, wt, eid, stop))
    if lengths:
        ratio = 1.0
    elif ratio is None:
        ratio = float(measured) if np.isfinite(measured) else 1.0
    p = points.astype(np.float64)
    px, py = p[order, 0].copy(), p[order, 1].copy()
    return SearchGraph(start, stop, adj, wt, eid, usable.reshape(-1), p, px, py, ratio, order, rank)


#: Blocks of search ids the search graph is made in (None: one per thread of the host's edge
#: rule for roadmaps of :data:`_THREADS_FROM` entries or more, else one).
_PARTS: int | None = None

#: Roadmap entries (rows x slots) from which the search graph is made on threads.
_THREADS_FROM = 2**18


def _vertex_blocks(M: int, entries: int) -> list[tuple[int, int]]:
    """The blocks of search ids ``[a, b)`` (:data:`_PARTS`)."""
    from ._edges import _blocks, _workers

    return _blocks(M, _PARTS if _PARTS is not None else _workers() if entries >= _THREADS_FROM else 1)


def astar_path(graph: SearchGraph, q, s_dst, s_w, g_dst, g_w) -> tuple[float, np.ndarray]:
    """Shortest path from the start to the goal (``q``: (2, 2) their points) over ``graph`` plus
    the start's edges ``s_dst``, ``s_w`` and the goal's ``g_dst``, ``g_w`` (the goal is only
    entered). Returns (cost, vertex path START ... GOAL), or (inf, empty) if there is none."""
    q = np.asarray(q, np.float64)
    s_dst = np.asarray(s_dst, np.int64)
    g_dst = np.asarray(g_dst, np.int64)
    s_w = np.asarray(s_w, np.float64)
    g_w = np.asarray(g_w, np.float64)
    ratio = graph.ratio
    for dst, wt, at in ((s_dst, s_w, q[0]), (g_dst, g_w, q[1])):
        other = np.where((dst == 1)[:, None], q[1], graph.points[np.clip(dst, 0, len(graph.points) - 1)])
        length = np.hypot(other[:, 0] - at[0], other[:, 1] - at[1])
        pos = length > 0
        if pos.any():
            ratio = min(ratio, float(np.min(wt[pos] / length[pos])))
    c = max(ratio, 0.0) * (1.0 - _SHAVE)
    _, astar = _kernels()
    M = len(graph.rank)
    cost, path = astar(
        graph.start,
        graph.stop,
        graph.adj,
        graph.wt,
        graph.eid,
        graph.usable,
        graph.px,
        graph.py,
        c,
        np.where(s_dst < M, graph.rank[np.clip(s_dst, 0, M - 1)], s_dst),
        s_w,
        np.where(g_dst < M, graph.rank[np.clip(g_dst, 0, M - 1)], g_dst),
        g_w,
        float(q[1, 0]),
        float(q[1, 1]),
    )
    return float(cost), graph.order[path]

"""Lazy edge checking for :class:`~jaxsem.planning.PRM` (``lazy=True``; Bohlin and Kavraki's
Lazy PRM): a grow finds each new vertex's candidates (the eager grow's samples and candidate
sets, in its order where the order decides a link: :func:`_grow_lazy`)
but checks no edge; a query searches the graph of every edge that may still be in the roadmap,
checks the edges that decide the path it found (and, in the check call's spare slots, the path
vertices' nearest unknown edges: a detour often runs over them), drops those that are not in
the roadmap, and searches again until the path is all in or none is left. Checked edges are
remembered, so later queries on the roadmap reuse them.

The answer is the eager roadmap's. The eager grow keeps, of each vertex's candidates in
preference order, the first ``k`` whose edge is clear. An edge of slot ``s`` of row ``r`` is
*possible* while it is not known blocked and fewer than ``k`` edges before it in its row are
known clear, and *in the roadmap* once it is clear and every slot before it is checked with
fewer than ``k`` clear (slots below ``k`` need only their own check). The possible edges hold
every edge of the eager roadmap, so a shortest path over them whose edges are all in the
roadmap is a shortest path of the eager roadmap (same cost; equal-cost ties may pick another).

The search is the compiled A* of :mod:`jaxsem.planning._astar` over every candidate edge, the
graph made once per grow and the edges' flags read in place: a check that drops an edge costs the
next search nothing to learn, and each search stops at the goal.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._astar import SearchGraph, astar_path, search_graph
from ._edges import (
    _edge_samples,
    _edges,
    _edges_clear_host,
    _edges_dense,
    _extent,
    _first_clear_host,
    _grid,
    _host_edges,
)
from ._grid import static_grid
from ._neighbours import _bucket_ids, _candidates_host, _grid_dims, _host_order, _knn_grid, _knn_rows
from ._roadmap import _QUERY, Roadmap, _density, _sample_lazy_jit, _weigh_links
from ._roadmap_search import _NOT_FOUND, RoadmapPath, _query_edges

#: Edge status codes.
UNKNOWN, CLEAR, BLOCKED = 0, 1, 2

#: Edges checked per call of the jitted check (one compiled shape for the query loop).
_CHUNK = 128


# ------------------------------------------------------------------ growing without edge checks


#: Vertices the lazy grow ranks on the device per call: two compiled shapes, whatever their
#: count (the host leaves a few rows of a grow to the device, now and then hundreds).
_RANK_CHUNKS = (16, 256)


@functools.partial(jax.jit, static_argnames=("radius", "extent"))
def _grid_jit(points, valid, origin, guess, *, radius, extent):
    """:func:`_knn_grid` of the roadmap's usable samples (the eager grow's own). ``guess`` (M,)
    int32: the host's bucket order (:func:`~jaxsem.planning._neighbours._host_order`), used where it is the device's own (its
    bucket ids sorted, ties in index order), else the device sorts (a sort costs milliseconds
    on a CPU; the check, microseconds)."""
    M = points.shape[0]
    db = points - origin
    ok = valid & (jnp.arange(M) >= _QUERY)
    s = _bucket_ids(db, ok, radius, extent)[guess]
    agree = jnp.all((s[1:] > s[:-1]) | ((s[1:] == s[:-1]) & (guess[1:] > guess[:-1])))

    def own():
        order, sorted_bid = _knn_grid(db, ok, radius, extent)
        return order.astype(guess.dtype), sorted_bid

    return jax.lax.cond(agree, lambda: (guess, s), own)


@functools.partial(jax.jit, static_argnames=("grid",))
def _density_jit(points, distribution, grid):
    """The samples' densities (M,) as the grow's neighbour search reads them (:func:`_density`)."""
    return _density(points, distribution, _grid(grid, points.dtype), sectors=1)  # any sectors: read them


@functools.partial(jax.jit, static_argnames=("grid", "k", "radius", "extent", "cap", "sectors", "keep"))
def _knn_some_jit(points, valid, rows, order, sorted_bid, distribution, grid, *, k, radius, extent, cap, sectors, keep):
    """The eager grow's neighbour search (:func:`_knn_rows`, ranked) for the vertices ``rows``
    alone (``order``, ``sorted_bid``: :func:`_grid_jit`, unused when ``cap`` is None: brute
    force): their rows as a search of every new vertex gives them."""
    M = points.shape[0]
    db_ok = valid & (jnp.arange(M) >= _QUERY)
    grid = _grid(grid, points.dtype)
    db = points - grid.origin
    density = _density(points, distribution, grid, sectors)
    grid = None if cap is None else (*_grid_dims(radius, extent), order, sorted_bid)
    return _knn_rows(
        db, db_ok, db[rows], rows, k=k, radius=radius, cap=cap, sectors=sectors, keep=keep, density=density, grid=grid
    )


def _grow_lazy(
    roadmap, key, blocked, dist, grid, n, radius, cap, sectors, uniform_samples, aids
) -> tuple[tuple[Roadmap, np.ndarray], int]:
    """A grow that checks no edge (lazy PRM, :mod:`jaxsem.planning._lazy`): the eager grow's
    samples (on the device), each new vertex's candidates (n, K) (``M`` where none or where the
    vertex is not valid): the eager grow's set, in its order where the order decides a link.
    Rows with at most k candidates keep every clear one whatever the order, so the host finds
    their sets (:func:`_candidates_host`); the host ranks the others as the eager search does
    where no rounding or sector border could change their order, the device the rest.
    ``grid``: the map's host grid (:func:`~jaxsem.planning._grid.host_grid`).
    Returns ((roadmap with the new points and no new edges, candidates), the cap that sufficed)."""
    M, k = roadmap.neighbors.shape
    s0 = _QUERY + int(roadmap.num_samples)
    origin_j = jnp.asarray(grid.origin, roadmap.points.dtype)
    rm, _, ok_new, _ = _sample_lazy_jit(
        roadmap,
        key,
        blocked,
        dist,
        static_grid(grid),
        n=n,
        uniform_samples=uniform_samples,
        aids=aids,
    )
    pts = np.asarray(rm.points)
    db_ok = np.asarray(rm.valid) & (np.arange(M) >= _QUERY)
    rows = np.arange(s0, s0 + n)
    extent = _extent(grid)
    keep = 2 * k if sectors else k
    # The host ranks a row as the device does, with the samples' densities as the device reads
    # them where they play a part (a distribution's samples, with sectors).
    density = None if dist is None or not sectors else np.asarray(_density_jit(rm.points, dist, static_grid(grid)))
    local = pts - np.asarray(origin_j)
    cand, need, cap = _candidates_host(local, db_ok, rows, k, radius, extent, keep, cap, sectors, density)
    if need.any():
        some = rows[need].astype(np.int32)
        chunk = _RANK_CHUNKS[0] if len(some) <= _RANK_CHUNKS[0] else _RANK_CHUNKS[1]
        padded = np.concatenate([some, np.full(-len(some) % chunk, some[-1], np.int32)])
        guess = _host_order(local, db_ok, radius, extent)
        order, sorted_bid = _grid_jit(rm.points, rm.valid, origin_j, guess, radius=radius, extent=extent)
        while True:
            use = cap if 3 * cap < M else None
            parts = [
                _knn_some_jit(
                    rm.points,
                    rm.valid,
                    padded[i : i + chunk],
                    order,
                    sorted_bid,
                    dist,
                    static_grid(grid),
                    k=k,
                    radius=radius,
                    extent=extent,
                    cap=use,
                    sectors=sectors,
                    keep=keep,
                )
                for i in range(0, len(padded), chunk)
            ]
            if use is None or not any(bool(o) for _, o in parts):
                break
            cap *= 4  # the host's strip counts said no overflow: not expected, but never drop one
        cand[need] = np.concatenate([np.asarray(nb) for nb, _ in parts])[: len(some)]
    cand[~np.asarray(ok_new)] = M
    return (rm, cand), cap


def _grow_checked_host(
    roadmap, key, blocked, blocked_j, dist, grid, n, radius, cap, sectors, uniform_samples, aids, table, bits
) -> tuple[Roadmap, int, tuple]:
    """The eager grow with its edges checked on the host (Euclidean weights, float32 points:
    :func:`~jaxsem.planning._edges._host_edges`): the lazy grow's samples and candidates (the
    eager grow's), each new vertex's candidates read in preference order until ``k`` are clear
    (the rule compiled on the host, the edges after the ``k``-th clear one unread), the first
    ``k`` clear ones kept and weighed by their lengths: the eager grow's edges and weights
    (:meth:`_LazyEdges.links`' rule). ``blocked``: the numpy grid of ``blocked_j``; ``table``:
    its clearance table (numpy), ``bits`` its bits (:func:`~jaxsem.planning._edges._bit_grids`).
    Returns (roadmap, the cap that sufficed, (the first new row, the roadmap's points, the new
    rows' neighbours, valid flags and weights) as numpy arrays: the host's copy of what it wrote)."""
    k = roadmap.neighbors.shape[1]
    s0 = _QUERY + int(roadmap.num_samples)
    (rm, cand), cap = _grow_lazy(roadmap, key, blocked_j, dist, grid, n, radius, cap, sectors, uniform_samples, aids)
    samples = _edge_samples(radius, float(grid.resolution))
    pts = np.asarray(rm.points)
    nbr, ev, w = _first_clear_host(blocked, pts, cand, s0, k, samples, grid, table, bits)
    return _set_rows_jit(rm, np.int32(s0), nbr, ev, w), cap, (s0, pts, nbr, ev, w)


def _grow_host_weighed(
    roadmap, key, blocked, blocked_j, dist, grid, n, radius, cap, sectors, uniform_samples, aids, table, cost
) -> tuple[Roadmap, int]:
    """The eager grow with its edges checked on the host and weighed on the device (weights
    that integrate a cell ``cost``, :func:`~jaxsem.planning._roadmap._edge_cost`; float32
    points: :func:`~jaxsem.planning._edges._host_edges`): the device's samples, the eager
    grow's candidates (:func:`_grow_lazy`: ranked on the host with the samples' densities, the
    device's search for the rows a rounding could reorder), each row read on the host in
    preference order until ``k`` are clear (the rule compiled on the host: the eager grow's
    first ``k`` clear candidates; a row of at most ``k`` candidates may keep them in another
    slot order), the kept links weighed as the eager grow weighs them. The map's bits are not
    made (a navigation loop's map changes every replan): edges are read by samples.
    ``blocked``: the numpy grid of ``blocked_j``; ``table``: its clearance table (numpy).
    Returns (roadmap, the cap that sufficed)."""
    M, k = roadmap.neighbors.shape
    s0 = _QUERY + int(roadmap.num_samples)
    (rm, cand), cap = _grow_lazy(roadmap, key, blocked_j, dist, grid, n, radius, cap, sectors, uniform_samples, aids)
    samples = _edge_samples(radius, float(grid.resolution))
    nbr, ev, _ = _first_clear_host(
        blocked, np.asarray(rm.points), np.asarray(cand), s0, k, samples, grid, table, _NO_BITS
    )
    # Only the clear links are weighed.
    w = _weigh_links(rm.points, s0, nbr, ev, cost, static_grid(grid), samples)
    rm = _set_rows_jit(rm, np.int32(s0), nbr, ev, w)
    return rm, cap


#: The host rule's "no bits" (every edge read by samples: :func:`~jaxsem.planning._edges._host_grids`).
_NO_BITS = (np.zeros((0, 0), np.uint64), np.zeros((0, 0), np.uint64), np.zeros((0, 0), np.uint16))


@jax.jit
def _set_rows_jit(rm: Roadmap, s0, nbr, ev, w) -> Roadmap:
    """``rm`` with rows ``s0 ..`` of its links replaced (one compiled call per row count)."""
    at = (s0, jnp.int32(0))
    return rm._replace(
        neighbors=jax.lax.dynamic_update_slice(rm.neighbors, nbr, at),
        edge_valid=jax.lax.dynamic_update_slice(rm.edge_valid, ev, at),
        edge_weight=jax.lax.dynamic_update_slice(rm.edge_weight, w, at),
    )


@functools.partial(jax.jit, static_argnames=("grid", "edge_samples", "dense"))
def _pairs_clear(blocked, a, b, mask, grid, table, *, edge_samples, dense=False):
    grid = _grid(grid, a.dtype)
    """The edge rule on segments a -> b (E, 2). ``dense``: every sample read (a few hundred
    edges: one fused pass, ~3x cheaper per call than the clearance-table path's work lists);
    otherwise the clearance-table path (many edges). The same answers (:func:`_edges_clear`)."""
    if dense:
        clear, _, _ = _edges_dense(blocked, a, b, grid, edge_samples)
        return clear & mask
    clear, _ = _edges(blocked, None, a, b, grid, edge_samples, mask, table=table)
    return clear


class _LazyEdges:
    """Host state of a lazy roadmap's sample edges.

    cand: (M, K) int32 each vertex's candidates in preference order (``M``: none; rows 0 and 1,
    the query slots, have none); status: (M, K) int8 UNKNOWN / CLEAR / BLOCKED (BLOCKED where
    there is no candidate); possible: (M, K) bool (module docstring); k: links kept per vertex.
    The search graph (:meth:`_search_graph`) is made again after a grow.
    """

    def __init__(self, M: int, K: int, k: int):
        self.M, self.K, self.k = int(M), int(K), int(k)
        self.cand = np.full((self.M, self.K), self.M, np.int32)
        self.status = np.full((self.M, self.K), BLOCKED, np.int8)
        self.possible = np.zeros((self.M, self.K), bool)
        self._graph = None

    def add_rows(self, s0: int, cand) -> None:
        cand = np.asarray(cand, np.int32)
        self.cand[s0 : s0 + len(cand)] = cand
        self.status[s0 : s0 + len(cand)] = np.where(cand < self.M, UNKNOWN, BLOCKED)
        self.possible[s0 : s0 + len(cand)] = cand < self.M
        self._graph = None

    def settle(self, check_fn) -> None:
        """Before the map changes: decides every row on the map the edges were chosen on (checks
        what is still unknown), keeps the edges in the roadmap as unknown (to be rechecked on the
        newer map) and drops the rest. The eager PRM drops what a newer map blocks without
        promoting later candidates; this keeps the two roadmaps equal."""
        self.check_all(check_fn)
        _, in_rm = self._in_rows(np.arange(self.M))
        self.status = np.where(in_rm, UNKNOWN, BLOCKED).astype(np.int8)

    def forget_clear(self, valid) -> None:
        """A newer map only adds obstacles: clear edges go back to unknown, edges at vertices
        that are no longer valid become blocked."""
        valid = np.asarray(valid, bool)
        c = np.minimum(self.cand, self.M - 1)
        gone = ~valid[:, None] | ~valid[c]
        self.status = np.where(self.status == CLEAR, UNKNOWN, self.status).astype(np.int8)
        self.status[gone & (self.cand < self.M)] = BLOCKED
        self.possible, _ = self._in_rows(np.arange(self.M))
        self._graph = None

    # ------------------------------------------------------------------ the edge rule per row

    def _in_rows(self, rows):
        """(possible, in_roadmap) (R, K) for ``rows`` (module docstring)."""
        st = self.status[rows]
        clear = st == CLEAR
        before = np.cumsum(clear, axis=1) - clear  # clear slots before each slot
        free_slot = before < self.k
        possible = (st != BLOCKED) & free_slot
        unknown_before = np.cumsum(st == UNKNOWN, axis=1) - (st == UNKNOWN)
        low = np.arange(self.K)[None, :] < self.k
        in_rm = clear & free_slot & (low | (unknown_before == 0))
        return possible, in_rm

    def _needed(self, rows, slots):
        """Flat (row, slot) of the unknown edges that decide whether slot ``slots`` of ``rows``
        is in the roadmap: the slot itself, and below it too when it is at or past ``k``."""
        j = np.arange(self.K)[None, :]
        s = slots[:, None]
        need = (self.status[rows] == UNKNOWN) & ((j == s) | ((s >= self.k) & (j < s)))
        r, c = np.nonzero(need)
        flat = np.unique(rows[r].astype(np.int64) * self.K + c)
        return flat // self.K, flat % self.K

    def check(self, rows, slots, check_fn) -> None:
        """Checks the edges (rows, slots) with ``check_fn(a_rows, slots) -> clear`` and records
        the answers."""
        if len(rows):
            self.status[rows, slots] = np.where(check_fn(rows, slots), CLEAR, BLOCKED)
            touched = np.unique(rows)
            self.possible[touched], _ = self._in_rows(touched)

    # ------------------------------------------------------------------ query

    def search_rows(self, pts, nq, okq, wq, check_fn) -> RoadmapPath:
        """Shortest path of the eager roadmap from the start to the goal, checking only the edges
        the search needs: from the host points ``pts`` (M, 2) (slots 0 and 1: the start and
        goal) and the query rows ``nq``, ``okq``, ``wq`` (2, k): A* over the possible edges,
        the path's deciding edges checked, again until the path found is all in the roadmap."""
        edges = _query_edges(nq, okq, wq)
        if edges is None:
            return _NOT_FOUND
        graph = self._search_graph(pts)
        while True:
            cost, path = astar_path(graph, pts[:_QUERY], *edges)
            if not len(path):
                return _NOT_FOUND
            u, v = path[:-1], path[1:]
            inner = (u >= _QUERY) & (v >= _QUERY)
            done, _ = self._certify(u[inner], v[inner], check_fn)
            if done:
                p = pts[path]
                length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=-1)))
                return RoadmapPath(path, p, cost, length, True)

    def _search_graph(self, pts) -> SearchGraph:
        """The candidate edges as a search graph over :attr:`possible` (read in place), made
        once per grow from the samples' points (rows from 2 of ``pts``), weighed as the eager
        grow weighs its edges (the length in the points' dtype, then float64)."""
        if self._graph is None:
            entries = (self.cand >= _QUERY) & (self.cand < self.M)
            entries[:_QUERY] = False
            # Weighed by their lengths: the heuristic's ratio is 1 (astar_path shaves it).
            self._graph = search_graph(self.cand, self.possible, None, pts, entries)
        return self._graph

    def _certify(self, u, v, check_fn):
        """Checks what decides the sample edges (u, v) of a path. Returns (True if all are in
        the roadmap, the rows whose edges were checked)."""
        if len(u) == 0:
            return True, np.zeros(0, np.int64)
        L = len(u)
        ru, su = np.nonzero(self.cand[u] == v[:, None])
        rv, sv = np.nonzero(self.cand[v] == u[:, None])
        reps_e = np.concatenate([ru, rv])  # which path edge
        reps_r = np.concatenate([u[ru], v[rv]])
        reps_s = np.concatenate([su, sv])
        possible, _ = self._in_rows(reps_r)
        keep = possible[np.arange(len(reps_r)), reps_s]
        reps_e, reps_r, reps_s = reps_e[keep], reps_r[keep], reps_s[keep]
        rows, slots = self._needed(reps_r, reps_s)
        if len(rows) % _CHUNK:
            rows, slots = self._with_spares(rows, slots, np.concatenate([u, v]), _CHUNK - len(rows) % _CHUNK)
        self.check(rows, slots, check_fn)
        _, in_rm = self._in_rows(reps_r)
        ok = np.zeros(L, bool)
        ok[reps_e[in_rm[np.arange(len(reps_r)), reps_s]]] = True
        return bool(ok.all()), np.unique(rows)

    def _with_spares(self, rows, slots, near, spare: int):
        """(rows, slots) and up to ``spare`` more unknown, possible edges of the vertices
        ``near`` (a path's), nearest slots first: a check call reads a fixed number of edges, so
        these cost no device time, and a path's next detour often runs over them (fewer search
        rounds)."""
        w = np.unique(near)
        unk = (self.status[w] == UNKNOWN) & self.possible[w]
        s_, i_ = np.nonzero(unk.T)  # slot-major: every vertex's nearest first
        er, es = w[i_], s_
        fresh = ~np.isin(er.astype(np.int64) * self.K + es, rows.astype(np.int64) * self.K + slots)
        er, es = er[fresh][:spare], es[fresh][:spare]
        return np.concatenate([rows, er]), np.concatenate([slots, es])

    def check_all(self, check_fn) -> None:
        rows, slots = np.nonzero(self.status == UNKNOWN)
        self.check(rows, slots, check_fn)

    def links(self, points, dtype):
        """The eager roadmap's (neighbors, edge_valid, edge_weight) rows of the samples, from
        fully checked rows (call :meth:`check_all` first)."""
        M, K, k = self.M, self.K, self.k
        _, in_rm = self._in_rows(np.arange(M))
        pos = np.cumsum(in_rm, axis=1) - 1
        rows = np.broadcast_to(np.arange(M)[:, None], (M, K))
        nbr = np.full((M, k), M, np.int32)
        ev = np.zeros((M, k), bool)
        w = np.full((M, k), np.inf, np.dtype(dtype))
        sel = in_rm & (pos < k)
        p = np.asarray(points)
        c = np.minimum(self.cand, M - 1)
        d = p[c] - p[:, None, :]
        ww = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + np.asarray(1e-30, p.dtype))
        if K == k:  # no preference order to apply: every candidate keeps its slot
            return self.cand.copy(), in_rm, np.where(in_rm, ww, np.inf).astype(w.dtype)
        nbr[rows[sel], pos[sel]] = self.cand[sel]
        ev[rows[sel], pos[sel]] = True
        w[rows[sel], pos[sel]] = ww[sel]
        return nbr, ev, w


def _checker(blocked, blocked_j, points, cand, grid, table, edge_samples: int, chunk: int = _CHUNK, bits=None):
    """``check(rows, slots) -> clear`` (numpy bool) for the edges from ``points[rows]`` to
    their candidates on ``grid`` (a :func:`~jaxsem.planning._grid.static_grid`) of the numpy
    bool grid ``blocked`` (``blocked_j``: its device copy): by the host's compiled rule where it
    matches the device's arithmetic (:func:`~jaxsem.planning._edges._edges_clear_host`), else
    ``chunk`` edges per call of the jitted rule (one compiled shape). ``table``: the clearance
    table (None: every sample read); ``bits``: the host rule's bits of ``blocked`` (None: made
    at each call)."""
    pts = np.asarray(points)
    dtype = pts.dtype
    host = _host_edges(dtype)
    table_np = None if table is None or not host else np.asarray(table)

    def check(rows, slots):
        if host:
            n = np.full(len(rows), edge_samples, np.int64)
            out = _edges_clear_host(
                blocked, pts[rows], pts[cand[rows, slots]], n, np.ones(len(rows), bool), grid, table_np, bits=bits
            )
            return np.asarray(out)
        out = np.zeros(len(rows), bool)
        for s in range(0, len(rows), chunk):
            r, sl = rows[s : s + chunk], slots[s : s + chunk]
            m = len(r)
            a = np.zeros((chunk, 2), dtype)
            b = np.zeros((chunk, 2), dtype)
            a[:m] = pts[r]
            b[:m] = pts[cand[r, sl]]
            mask = np.arange(chunk) < m
            ok = _pairs_clear(
                blocked_j,
                a,  # numpy into the jitted rule: no conversion call of its own per chunk
                b,
                mask,
                grid,
                table,
                edge_samples=edge_samples,
                dense=chunk <= _CHUNK,
            )
            out[s : s + m] = np.asarray(ok)[:m]
        return out

    return check

"""Probabilistic roadmap on a partial grid map: built once, grown, rechecked, queried many times.

A :class:`Roadmap` is a pytree of fixed capacity (so growing it never recompiles): slots 0 and 1
hold the current query's start and goal, slots ``2 .. 2 + count`` the samples. The pieces are
pure jitted functions (:func:`roadmap_init`, :func:`roadmap_grow`, :func:`roadmap_recheck`,
:func:`roadmap_connect`) and :class:`PRM` is the host-side object most users want::

    prm = PRM(known_map, origin, resolution, capacity=2000)
    prm.grow(key, 1000)                    # uniform over cells not known occupied
    path = prm.query(start, goal)          # many queries on one roadmap
    prm.update_map(newer_map)              # a partial map only gains obstacles: drop what they hit
    prm.grow(key2, 1000, distribution=p)   # densify (e.g. from a learned distribution)

Sampling. A vertex is drawn from the distribution over cells *restricted to cells that are not
known occupied* (inverse CDF over the flattened grid), then placed uniformly inside its cell.
That is rejection sampling done exactly: ``N`` counts valid vertices, as OMPL's PRM counts
milestones (its valid-state sampler retries until a state is valid). Unknown cells are free.

Connection policy (documented, tested against brute force). With ``sectors=0`` every vertex added in a batch links
to its ``k`` nearest vertices within ``radius`` among all vertices present once the batch is in
(its own batch included); the graph is undirected, so a vertex's degree is its own ``k`` plus
the links later vertices make to it. For one batch this is "k nearest of the final vertex set";
OMPL's PRM is the same rule with batches of one milestone (k = 10, no radius). With
``sectors=S > 0`` (the default, :data:`DEFAULT_SECTORS` = 8, also the navigation planner's) the ``k`` links are chosen by
direction first: the nearest ``m = ceil(k / 2S)`` in each of ``S`` equal angular sectors around
the vertex (within ``radius``) and its nearest ``2m`` among samples drawn no more densely than
itself come first, then the nearest of the rest; of the first ``2k`` candidates in that order the
first ``k`` whose edge is clear are kept. Why: under a learned distribution the samples are dense
in a few places and sparse elsewhere, and the plain k nearest of a vertex near a dense cluster
all lie inside the cluster (or behind the wall beside it), so clusters a door or a gap apart, and
the sparse samples beyond them, were never linked (see ``benchmarks/lsd_diagnose_finding.md``). A query's start links to its ``k`` nearest samples and
the goal, the goal to its ``k`` nearest samples, chosen by the same rule but at *any* distance
(not bounded by ``radius``; such long edges are checked over :func:`query_reach`): a goal outside
a sparse region still reaches the roadmap. Samples never link to the query slots, so queries do
not change the roadmap.

Neighbour search is exact. Vertices are bucketed on a grid of cell size ``radius`` and each
query point reads the 3 x 3 buckets around its own, which hold every point within ``radius``.
A bucket is read through ``bucket_cap`` slots; the search reports ``overflow`` (a result code
in :attr:`Roadmap.overflow`) when any bucket holds more, and the Python entry points then rerun
with enough slots, so nothing is dropped silently (samples concentrated by a learned
distribution put hundreds of vertices in one bucket). When ``9 * bucket_cap`` would reach the
vertex count, the search is brute force over all vertices (same result, no cap at all).

Edge check: ``edge_samples`` points along each edge, at most half a cell apart, must lie in
cells that are not known occupied, and so must both side cells of any diagonal step between
consecutive samples, so a valid edge touches no known-occupied cell. Edge weight: Euclidean
length, or the integral of ``-log p`` along the edge (mean over the samples times the length,
thesis eq. 3.3) with ``weight='neglogp'``.

Search (:func:`roadmap_shortest_path`, :meth:`PRM.query`) is scipy's Dijkstra on the host; the
PRM keeps the roadmap's edge list in CSR form, so a query only adds its start's and goal's
edges (a few milliseconds at 5000 vertices).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from jax.core import Tracer

from ._grid import OCCUPIED, check_point

#: The connection policy of every public builder (:class:`PRM`, :func:`build_roadmap`,
#: :func:`roadmap_grow`, :func:`roadmap_connect`, :func:`make_roadmap_builder`) and of the
#: navigation planner (``NavConfig.sectors``): direction first over 8 sectors. Measured against
#: OMPL's PRM (k = 10) on test buildings 300-307 (tuning seeds), 6 queries x 3 roadmaps each at
#: N = 500: the plain k nearest (``sectors=0``) found 66 of 144 paths (OMPL 35) with length / C*
#: 1.26 against OMPL's 1.13 on the 23 both found; 8 sectors found 71 with 1.23 against 1.24 on
#: the 25 both found (``benchmarks/lsd_prm.py`` reports held-out buildings).
DEFAULT_SECTORS = 8

#: Query slots: the start and goal of the current query.
START, GOAL = 0, 1
_QUERY = 2


class Roadmap(NamedTuple):
    """A roadmap (pytree) of capacity ``M - 2`` samples; ``M`` slots in all.

    points: (M, 2) world (x, y); slot 0 the query start, slot 1 the goal, then the samples.
    valid: (M,) bool, the slot holds a vertex whose cell is not known occupied.
    neighbors: (M, k) int32 slot indices (``M`` where there is none).
    edge_valid: (M, k) bool; edge_weight: (M, k) float (inf where invalid).
    num_samples: () int32, samples so far (slots ``2 .. 2 + num_samples``).
    overflow: () bool result code: a neighbour search had fewer candidate slots than a bucket
        held, so some lists may miss a neighbour. :class:`PRM`, :func:`build_roadmap` and
        :func:`roadmap_grow` rerun with more slots and never return it set.
    """

    points: jax.Array
    valid: jax.Array
    neighbors: jax.Array
    edge_valid: jax.Array
    edge_weight: jax.Array
    num_samples: jax.Array
    overflow: jax.Array


#: A learned sampler's roadmap links over this many times the uniform radius (see
#: :class:`~jaxsem.planning.NavConfig`'s ``learned_radius_factor``, whose default it is).
LEARNED_RADIUS_FACTOR = 2.0


def default_radius(n: int, shape, resolution: float, weight: str = "euclidean") -> float:
    """Connection radius (m) for ``n`` samples on a map of ``shape`` cells: 3 x the mean sample
    spacing, within [1, 8] m, rounded up to 0.5 m so that few distinct values (each a compile)
    occur. It only bounds the search; the ``k`` nearest are usually closer (see
    ``benchmarks/lsd_prm.py`` for the quality this gives against OMPL). ``weight='neglogp'`` (a
    learned sampler's roadmap) gives ``LEARNED_RADIUS_FACTOR`` times that, rounded up to 0.5 m:
    the navigation loop's rule (:meth:`~jaxsem.planning.Trial.connection_radius`), so that a
    one-shot LSD roadmap links like the loop's (a concentrated distribution leaves the few samples
    outside its window farther apart than the uniform radius)."""
    area = shape[0] * shape[1] * resolution**2
    r = math.ceil(min(8.0, max(1.0, 3.0 * math.sqrt(area / max(n, 1)))) * 2.0) / 2.0
    if weight == "neglogp":
        r = math.ceil(2.0 * r * LEARNED_RADIUS_FACTOR) / 2.0
    return r


def prm_star_k(n: int) -> int:
    """Neighbours per vertex for ``n`` samples: PRM*'s ``ceil(e (1 + 1/d) ln n)`` with d = 2
    (Karaman and Frazzoli 2011; OMPL's ``PRMstar`` uses the same rule): 26 at n = 500, 29 at
    1000, 35 at 5000. Measured on 4 held-out test buildings x 6 Inside-Inside queries x 3
    roadmaps (tuning seeds 50-53): at n = 500 k = 15 solved 32 of 72 queries (length / C* 1.27),
    k = 25 solved 43 (1.16); at n = 1000, 56 vs 63. Growing in OMPL-like batches of increasing
    size (early vertices linking far) solved fewer (19 at n = 500)."""
    return max(1, int(math.ceil(math.e * 1.5 * math.log(max(int(n), 2)))))


def _edge_samples(radius: float, resolution: float) -> int:
    return max(2, int(math.ceil(radius / (0.5 * resolution))) + 1)


def sample_points(key, distribution, n: int, origin, resolution: float):
    """``n`` world points (n, 2): a cell drawn with probability ``distribution`` (H, W) (need
    not be normalised, must be >= 0), then a uniform point inside the cell. Jittable."""
    H, W = distribution.shape
    k_cell, k_in = jax.random.split(key)
    p = distribution.reshape(-1).astype(origin.dtype)
    # associative_scan, not cumsum: XLA's CPU cumsum is a quadratic reduce-window.
    cdf = jax.lax.associative_scan(jnp.add, p)
    u = jax.random.uniform(k_cell, (n,), origin.dtype) * cdf[-1]
    flat = jnp.clip(jnp.searchsorted(cdf, u, side="right"), 0, H * W - 1)
    rc = jnp.stack([flat // W, flat % W], -1)
    jitter = jax.random.uniform(k_in, (n, 2), origin.dtype)
    return origin + (rc[:, ::-1].astype(origin.dtype) + jitter) * resolution


def _cells(points, origin, resolution, shape):
    H, W = shape
    cr = jnp.floor((points - origin) / resolution).astype(jnp.int32)
    on = (cr[..., 0] >= 0) & (cr[..., 0] < W) & (cr[..., 1] >= 0) & (cr[..., 1] < H)
    return jnp.clip(cr[..., 1], 0, H - 1), jnp.clip(cr[..., 0], 0, W - 1), on


def _per_sector(k: int, sectors: int) -> int:
    """Neighbours reserved per direction sector: ceil(k / (2 * sectors)) (2 of 26 with 8 sectors)."""
    return max(1, -(-int(k) // (2 * int(sectors))))


def _select(d2, diff, k: int, sectors: int, keep: int | None = None, sparser=None):
    """Positions (Q, k) of the chosen candidates of each query row and their finite flags.

    d2: (Q, C) squared distances (inf: not a candidate); diff: (Q, C, 2) candidate - query.
    ``sectors=0``: the k nearest. Otherwise the nearest ``_per_sector(k, sectors)`` candidates in
    each of ``sectors`` equal angular sectors around the query come first, the other slots go to
    the nearest of the rest (see the module docstring, "connection policy"). ``keep`` (>= k):
    return the first ``keep`` candidates in that order instead of ``k``. ``sparser`` (Q, C) bool:
    candidates sampled no more densely than the query; its nearest ``_per_sector(k, sectors)
    * 2`` also come first (so sparse samples link to each other, not only to a dense cluster).
    """
    Q, C = d2.shape
    kk = min(keep or k, C)
    if sectors:
        m = min(_per_sector(k, sectors), C)
        ang = jnp.arctan2(diff[..., 1], diff[..., 0])
        sec = jnp.clip(jnp.floor((ang + math.pi) * (sectors / (2 * math.pi))).astype(jnp.int32), 0, sectors - 1)
        prio = jnp.zeros((Q, C), bool)
        rows = jnp.arange(Q)[:, None]
        for s_i in range(int(sectors)):
            neg, pos = jax.lax.top_k(-jnp.where(sec == s_i, d2, jnp.inf), m)
            prio = prio.at[rows, pos].max(jnp.isfinite(neg))
        if sparser is not None:
            neg, pos = jax.lax.top_k(-jnp.where(sparser, d2, jnp.inf), min(2 * m, C))
            prio = prio.at[rows, pos].max(jnp.isfinite(neg))
        # Reserved candidates rank before all others; within each group, by distance.
        span = jnp.max(jnp.where(jnp.isfinite(d2), d2, 0.0), axis=1, keepdims=True) + 1.0
        key = jnp.where(prio, d2, d2 + span)
    else:
        key = d2
    neg, pos = jax.lax.top_k(-key, kk)
    return pos, jnp.isfinite(neg)


def _knn(
    db,
    db_ok,
    queries,
    q_self,
    k: int,
    radius: float,
    extent,
    cap,
    sectors: int = 0,
    keep: int | None = None,
    density=None,
):
    """k nearest ``db_ok`` points of ``db`` (M, 2) within ``radius`` of each query (Q, 2),
    excluding index ``q_self`` (Q,) (-1: none). Returns ((Q, k) indices, ``M`` where fewer;
    overflow). ``cap=None``: brute force. Local coordinates in [0, extent)."""
    M = db.shape[0]
    Q = queries.shape[0]
    if cap is None or 9 * cap >= M:
        cand = jnp.broadcast_to(jnp.arange(M)[None, :], (Q, M))
        ok = jnp.broadcast_to(db_ok[None, :], (Q, M))
        overflow = jnp.zeros((), bool)
    else:
        gx = max(1, int(math.ceil(extent[0] / radius)))
        gy = max(1, int(math.ceil(extent[1] / radius)))

        def bucket(p):
            b = jnp.floor(p / radius).astype(jnp.int32)
            return jnp.clip(b[:, 0], 0, gx - 1), jnp.clip(b[:, 1], 0, gy - 1)

        bx, by = bucket(db)
        bid = jnp.where(db_ok, by * gx + bx, gx * gy)  # unusable points: a bucket never read
        order = jnp.argsort(bid)
        sorted_bid = bid[order]
        ids = jnp.arange(gx * gy)
        start = jnp.searchsorted(sorted_bid, ids, side="left")
        count = jnp.searchsorted(sorted_bid, ids, side="right") - start
        overflow = jnp.max(count) > cap
        qx, qy = bucket(queries)
        off = jnp.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], jnp.int32)  # (9, 2)
        nx, ny = qx[:, None] + off[None, :, 0], qy[:, None] + off[None, :, 1]  # (Q, 9)
        inside = (nx >= 0) & (nx < gx) & (ny >= 0) & (ny < gy)
        nb = jnp.where(inside, ny * gx + nx, 0)
        j = jnp.arange(cap)
        slot = start[nb][..., None] + j  # (Q, 9, cap)
        ok = (inside[..., None] & (j < count[nb][..., None])).reshape(Q, -1)
        cand = order[jnp.clip(slot, 0, M - 1)].reshape(Q, -1)
    ok = ok & (cand != q_self[:, None])
    diff = db[cand] - queries[:, None, :]
    d2 = jnp.sum(diff**2, -1)
    d2 = jnp.where(ok & (d2 <= radius**2), d2, jnp.inf)
    want = keep or k
    kk = min(want, cand.shape[1])
    sparser = None
    if density is not None:  # (M,) sampling density of db points; queries are db[q_self]
        sparser = density[cand] <= density[jnp.maximum(q_self, 0)][:, None] * 1.001
    pos, fin = _select(d2, diff, k, sectors, want, sparser)
    idx = jnp.where(fin, jnp.take_along_axis(cand, pos, axis=1), M)
    if kk < want:
        idx = jnp.concatenate([idx, jnp.full((Q, want - kk), M, idx.dtype)], 1)
    return idx.astype(jnp.int32), overflow


def knn_within_radius(points, valid, k: int, radius: float, extent, bucket_cap: int | None = None, sectors: int = 0):
    """(M, k) indices of the k nearest valid points within ``radius`` of every valid point (``M``
    where fewer; invalid points get none) and the overflow flag (see :class:`Roadmap`).

    points: (M, 2) local coordinates in [0, extent); extent: (2,) Python floats; bucket_cap: slots
    per bucket (None: brute force); sectors: 0 (the k nearest) or the number of direction sectors
    whose nearest points come first (module docstring). Jittable with k, radius, extent,
    bucket_cap, sectors static.
    """
    M = points.shape[0]
    idx, overflow = _knn(points, valid, points, jnp.arange(M), k, radius, extent, bucket_cap, sectors)
    return jnp.where(valid[:, None], idx, M), overflow


def _edges(blocked, cost, a, b, origin, resolution, edge_samples):
    """Clear flag and weight of segments a -> b (..., 2) on the grid (see the module docstring).

    With ``cost=None`` (Euclidean weights) the rule is decided by :func:`_edges_clear` (the same
    answer, most edges from a few dozen reads); with a cost grid every sample is read (the
    weight needs them all)."""
    if cost is None:
        clear = _edges_clear(blocked, a, b, origin, resolution, edge_samples)
        return clear, _length(a, b)
    clear, er, ec = _edges_dense(blocked, a, b, origin, resolution, edge_samples)
    return clear, _length(a, b) * jnp.mean(cost[er, ec], axis=-1)


def _length(a, b):
    # Safe norm: a zero-length edge (a vertex drawn twice at one point) has weight ~0, no NaN.
    return jnp.sqrt(jnp.sum((b - a) ** 2, -1) + 1e-30)


def _edges_dense(blocked, a, b, origin, resolution, edge_samples):
    """The edge rule read at every one of the ``edge_samples`` points (module docstring)."""
    dtype = a.dtype
    t = jnp.arange(edge_samples, dtype=dtype) / (edge_samples - 1)
    along = a[..., None, :] + t[:, None] * (b - a)[..., None, :]  # (..., S, 2)
    er, ec, eon = _cells(along, origin, resolution, blocked.shape)
    clear = jnp.all(eon & ~blocked[er, ec], axis=-1)
    # Consecutive samples are at most half a cell apart, so they lie in the same or 8-adjacent
    # cells and the segment between them stays inside the 2 x 2 block they span; on a diagonal
    # move it may cross either side cell, so both must be free: the check is then exact
    # (conservative), no edge passes through a known-occupied cell.
    diag = (er[..., 1:] != er[..., :-1]) & (ec[..., 1:] != ec[..., :-1])
    sides = blocked[er[..., :-1], ec[..., 1:]] | blocked[er[..., 1:], ec[..., :-1]]
    clear &= ~jnp.any(diag & sides, axis=-1)
    return clear, er, ec


#: Clearance table: blocks of 2**_BASE cells, levels up to blocks of 2**_TOP cells.
_BASE, _TOP = 1, 5


def _clearance_table(blocked):
    """(H', W') lower bounds (in cells) on the distance from any point of each block of
    ``2**_BASE`` x ``2**_BASE`` cells to the nearest cell that is blocked, 8-adjacent to a
    blocked cell, or off the map. A block whose 3 x 3 neighbourhood of level-l blocks (``2**l``
    cells each) holds no such cell is at least ``2**l`` cells from one. Jittable; a few
    reductions of the grid (no distance transform)."""
    H, W = blocked.shape
    top = 1 << _TOP
    Hp, Wp = -(-H // top) * top, -(-W // top) * top
    grid = jnp.pad(blocked, ((1, Hp - H + 1), (1, Wp - W + 1)), constant_values=True)
    # Dilate by the 8 neighbours (separable); off-map cells count as blocked.
    grid = grid[:, :-2] | grid[:, 1:-1] | grid[:, 2:]
    grid = grid[:-2] | grid[1:-1] | grid[2:]  # (Hp, Wp)
    free = ~grid
    for _ in range(_BASE):
        free = free.reshape(free.shape[0] // 2, 2, free.shape[1] // 2, 2).all(axis=(1, 3))
    out = jnp.zeros(free.shape, jnp.int32)
    for lev in range(_BASE, _TOP + 1):
        f = jnp.pad(free, 1, constant_values=False)
        nb = f[:, :-2] & f[:, 1:-1] & f[:, 2:]
        nb = nb[:-2] & nb[1:-1] & nb[2:]
        up = 1 << (lev - _BASE)
        nb = jnp.repeat(jnp.repeat(nb, up, axis=0), up, axis=1)
        out = jnp.maximum(out, jnp.where(nb, 1 << lev, 0))
        if lev < _TOP:
            free = free.reshape(free.shape[0] // 2, 2, free.shape[1] // 2, 2).all(axis=(1, 3))
    return out


def _edges_clear(blocked, a, b, origin, resolution, edge_samples, chunk: int = 2048):
    """The edge rule of :func:`_edges_dense`, decided for most edges from a few reads.

    A subset of the rule's own samples (about one per 4 cells of the longest edge) is read
    twice: in the grid (one sample in a blocked or off-map cell rejects the edge, as the full
    rule does) and in :func:`_clearance_table` (a disc around each sample free of blocked cells
    and their neighbours). Where the discs of consecutive subset samples overlap along the edge,
    every sample of the full rule and its side cells lie in free cells: the edge is accepted.
    The rest (edges grazing a wall) get the full rule, ``chunk`` edges at a time."""
    shape = jnp.broadcast_shapes(a.shape, b.shape)[:-1]
    a, b = jnp.broadcast_to(a, shape + (2,)), jnp.broadcast_to(b, shape + (2,))
    fa, fb = a.reshape(-1, 2), b.reshape(-1, 2)
    E = fa.shape[0]
    dtype = a.dtype
    S = int(edge_samples)
    C = min(S, max(2, -(-(S - 1) // 8) + 1))  # every ~8th sample: ~4 cells apart on the longest edge
    pick = np.unique(np.round(np.linspace(0, S - 1, C)).astype(np.int64))
    t = (jnp.arange(S, dtype=dtype) / (S - 1))[pick]
    along = fa[:, None, :] + t[:, None] * (fb - fa)[:, None, :]  # (E, C, 2): samples of the rule
    er, ec, eon = _cells(along, origin, resolution, blocked.shape)
    hit = jnp.any(~eon | blocked[er, ec], axis=-1)
    table = _clearance_table(blocked)
    lo = (table[er >> _BASE, ec >> _BASE].astype(dtype) - 1e-3) * resolution
    lo = jnp.where(eon, lo, -1.0)
    gap = _length(fa, fb)[:, None] * jnp.asarray(np.diff(pick) / (S - 1), dtype)
    covered = jnp.all(lo[:, :-1] + lo[:, 1:] > gap, axis=-1)
    clear = ~hit & covered
    todo = ~hit & ~covered
    n_todo = jnp.sum(todo)
    F = min(int(chunk), E)
    order = jnp.nonzero(todo, size=E, fill_value=E)[0]
    order = jnp.concatenate([order, jnp.full((F,), E, order.dtype)])

    def body(i, clear):
        ids = jax.lax.dynamic_slice(order, (i * F,), (F,))
        j = jnp.minimum(ids, E - 1)
        ok, _, _ = _edges_dense(blocked, fa[j], fb[j], origin, resolution, S)
        return clear.at[ids].set(ok, mode="drop")

    clear = jax.lax.fori_loop(0, (n_todo + F - 1) // F, body, clear)
    return clear.reshape(shape)


@functools.partial(jax.jit, static_argnames=("resolution", "edge_samples"))
def _segments_clear(blocked, a, b, origin, *, resolution, edge_samples):
    clear, _ = _edges(blocked, None, a, b, origin, resolution, edge_samples)
    return jnp.all(clear)


def polyline_clear(points, blocked, origin, resolution: float, radius: float, dtype=None) -> bool:
    """True when every segment of the polyline ``points`` (K, 2) passes the roadmap's own edge
    check on the bool grid ``blocked``: the same samples as the PRM used for an edge of that
    length (segments up to ``radius``: the roadmap's; longer ones, a query's start or goal
    edges: :func:`query_reach`'s), same precision ``dtype``, so a plan the PRM found clear is
    never judged blocked on the same map (a looser or stricter second test made robots stand
    still, replanning the same path)."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 2:
        return True
    blocked = np.asarray(blocked)
    dtype = dtype or jnp.result_type(float)
    a, b = pts[:-1], pts[1:]
    length = np.linalg.norm(b - a, axis=1)
    short = length <= radius * (1 + 1e-6)
    reach = query_reach(blocked.shape, resolution)
    blocked_j = jnp.asarray(blocked)
    origin_j = jnp.asarray(np.asarray(origin, np.float64), dtype)
    for sel, r in ((short, radius), (~short, max(reach, 2.0 ** math.ceil(math.log2(max(length.max(), 1e-9)))))):
        if not sel.any():
            continue
        aa, bb = a[sel], b[sel]
        m = 1 << max(0, (len(aa) - 1).bit_length())  # pad to a power of two: few compiles
        aa = np.concatenate([aa, np.repeat(bb[-1:], m - len(aa), 0)])
        bb = np.concatenate([bb, np.repeat(bb[-1:], m - len(bb), 0)])
        ok = _segments_clear(
            blocked_j,
            jnp.asarray(aa, dtype),
            jnp.asarray(bb, dtype),
            origin_j,
            resolution=float(resolution),
            edge_samples=_edge_samples(r, resolution),
        )
        if not bool(ok):
            return False
    return True


def _cost_grid(distribution):
    p = distribution / jnp.sum(distribution)
    return -jnp.log(jnp.maximum(p, 1e-30))


def _sampling_weights(blocked, distribution):
    """Cell weights restricted to cells not known occupied (falls back to all free cells when
    the distribution has no mass there, and to the whole map when nothing is free)."""
    free = (~blocked).astype(jnp.result_type(float))
    if distribution is None:
        w = free
    else:
        w = distribution * free
        w = jnp.where(jnp.sum(w) > 0, w, free)
    return jnp.where(jnp.sum(w) > 0, w, jnp.ones_like(w))


def roadmap_init(capacity: int, k: int, dtype=None) -> Roadmap:
    """An empty roadmap with room for ``capacity`` samples and ``k`` neighbours per vertex."""
    if not (isinstance(capacity, (int, np.integer)) and capacity >= 1):
        raise ValueError(f"capacity: expected a positive int, got {capacity!r}")
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"k: expected a positive int number of neighbours, got {k!r}")
    dtype = dtype or jnp.result_type(float)
    M = int(capacity) + _QUERY
    return Roadmap(
        points=jnp.zeros((M, 2), dtype),
        valid=jnp.zeros(M, bool),
        neighbors=jnp.full((M, int(k)), M, jnp.int32),
        edge_valid=jnp.zeros((M, int(k)), bool),
        edge_weight=jnp.full((M, int(k)), jnp.inf, dtype),
        num_samples=jnp.zeros((), jnp.int32),
        overflow=jnp.zeros((), bool),
    )


def _grow_impl(
    rm, key, blocked, distribution, origin, *, n, radius, resolution, cap, neglogp, sectors=0, uniform_samples=False
):
    M, k = rm.neighbors.shape
    H, W = blocked.shape
    dtype = rm.points.dtype
    weights = _sampling_weights(blocked, None if uniform_samples else distribution)
    new = sample_points(key, weights, n, origin, resolution)
    r, c, on = _cells(new, origin, resolution, (H, W))
    ok_new = on & ~blocked[r, c]
    s0 = (_QUERY + rm.num_samples).astype(jnp.int32)
    z = jnp.zeros((), jnp.int32)
    points = jax.lax.dynamic_update_slice(rm.points, new.astype(dtype), (s0, z))
    valid = jax.lax.dynamic_update_slice(rm.valid, ok_new, (s0,))
    slots = s0 + jnp.arange(n, dtype=jnp.int32)
    db_ok = valid & (jnp.arange(M) >= _QUERY)
    extent = (W * resolution, H * resolution)
    # Direction-first policy (sectors > 0): the first k *clear* links among 2k candidates.
    keep = 2 * k if sectors else k
    density = None
    if sectors and distribution is not None:
        pr, pc, _ = _cells(points, origin, resolution, (H, W))
        density = distribution[pr, pc]
    nbr, ovf = _knn(points - origin, db_ok, new - origin, slots, k, radius, extent, cap, sectors, keep, density)
    other = points[jnp.minimum(nbr, M - 1)]
    cost = _cost_grid(distribution) if neglogp else None
    clear, w = _edges(
        blocked,
        cost,
        new[:, None, :],
        other,
        origin,
        resolution,
        _edge_samples(radius, resolution),
    )
    ev = (nbr < M) & clear & ok_new[:, None]
    w = jnp.where(ev, w, jnp.inf)
    if keep > k:
        nbr, ev, w = _clear_first(nbr, ev, w, k)
        nbr = jnp.where(ev, nbr, M)
    return Roadmap(
        points,
        valid,
        jax.lax.dynamic_update_slice(rm.neighbors, nbr, (s0, z)),
        jax.lax.dynamic_update_slice(rm.edge_valid, ev, (s0, z)),
        jax.lax.dynamic_update_slice(rm.edge_weight, w.astype(dtype), (s0, z)),
        rm.num_samples + n,
        rm.overflow | ovf,
    )


_grow_jit = functools.partial(
    jax.jit, static_argnames=("n", "radius", "resolution", "cap", "neglogp", "sectors", "uniform_samples")
)(_grow_impl)


def _recheck_impl(rm, blocked, origin, *, radius, resolution):
    M, _ = rm.neighbors.shape
    r, c, on = _cells(rm.points, origin, resolution, blocked.shape)
    valid = rm.valid & on & ~blocked[r, c]
    j = jnp.minimum(rm.neighbors, M - 1)
    clear, _ = _edges(
        blocked,
        None,
        rm.points[:, None, :],
        rm.points[j],
        origin,
        resolution,
        _edge_samples(radius, resolution),
    )
    ev = rm.edge_valid & clear & valid[:, None] & valid[j]
    return rm._replace(valid=valid, edge_valid=ev, edge_weight=jnp.where(ev, rm.edge_weight, jnp.inf))


_recheck_jit = functools.partial(jax.jit, static_argnames=("radius", "resolution"))(_recheck_impl)


def query_reach(shape, resolution: float) -> float:
    """Longest query edge (m): the map's diagonal rounded up to a power of two. A query's start
    and goal link to samples at any distance on the map; such edges are checked with samples at
    most half a cell apart over this length (and so are long plan segments,
    :func:`polyline_clear`)."""
    diag = math.hypot(shape[0] * resolution, shape[1] * resolution)
    return 2.0 ** math.ceil(math.log2(max(diag, resolution)))


def _connect_impl(rm, start, goal, blocked, distribution, origin, *, radius, resolution, neglogp, sectors=0):
    M, k = rm.neighbors.shape
    dtype = rm.points.dtype
    q = jnp.stack([start, goal]).astype(dtype)
    points = rm.points.at[:_QUERY].set(q)
    valid = rm.valid.at[:_QUERY].set(True)
    # Brute force over all slots (2 x M distances), at any distance (the query's edges are not
    # bounded by ``radius``: a goal far from a sparse region still links to its nearest samples);
    # the start may link to the goal, the goal not back to the start (one edge), neither to itself.
    ok = jnp.broadcast_to((valid & (jnp.arange(M) >= _QUERY))[None, :], (2, M))
    ok = ok.at[0, GOAL].set(True)
    diff = points[None, :, :] - q[:, None, :]
    d2 = jnp.sum(diff**2, -1)
    d2 = jnp.where(ok, d2, jnp.inf)
    keep = 2 * k if sectors else k
    kk = min(keep, M)
    pos, fin = _select(d2, diff, k, sectors, keep)
    nbr = jnp.where(fin, pos, M).astype(jnp.int32)
    if kk < keep:
        nbr = jnp.concatenate([nbr, jnp.full((2, keep - kk), M, jnp.int32)], 1)
    other = points[jnp.minimum(nbr, M - 1)]
    cost = _cost_grid(distribution) if neglogp else None
    # Each edge is checked with the samples polyline_clear uses for a segment of its length:
    # the roadmap's own for edges up to ``radius``, the query reach's for longer ones.
    clear_s, w_s = _edges(blocked, cost, q[:, None, :], other, origin, resolution, _edge_samples(radius, resolution))
    reach = query_reach(blocked.shape, resolution)
    clear_l, w_l = _edges(blocked, cost, q[:, None, :], other, origin, resolution, _edge_samples(reach, resolution))
    short = jnp.sum((other - q[:, None, :]) ** 2, -1) <= (radius * (1 + 1e-6)) ** 2
    clear, w = jnp.where(short, clear_s, clear_l), jnp.where(short, w_s, w_l)
    ev = (nbr < M) & clear
    w = jnp.where(ev, w, jnp.inf).astype(dtype)
    if keep > k:
        nbr, ev, w = _clear_first(nbr, ev, w, k)
        nbr = jnp.where(ev, nbr, M)
    return rm._replace(
        points=points,
        valid=valid,
        neighbors=rm.neighbors.at[:_QUERY].set(nbr),
        edge_valid=rm.edge_valid.at[:_QUERY].set(ev),
        edge_weight=rm.edge_weight.at[:_QUERY].set(w),
    )


_connect_jit = functools.partial(jax.jit, static_argnames=("radius", "resolution", "neglogp", "sectors"))(_connect_impl)


# ----------------------------------------------------------------------------- boundary checks


def _blocked_from(name, known_map):
    if isinstance(known_map, Tracer):
        raise ValueError(f"{name}: the roadmap entry points run at the Python boundary; pass a concrete map")
    arr = np.asarray(known_map)
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D grid (H, W), got shape {arr.shape}")
    if arr.dtype == np.bool_:
        return arr
    if arr.dtype == np.int8:
        return arr == OCCUPIED
    raise ValueError(
        f"{name}: expected a bool obstacle grid or an int8 partial map (UNKNOWN/FREE/OCCUPIED), got dtype {arr.dtype}"
    )


def _check_distribution(distribution, shape):
    if distribution is None or isinstance(distribution, Tracer):
        return distribution
    d = np.asarray(distribution)
    if d.shape != tuple(shape):
        raise ValueError(f"distribution: expected shape {tuple(shape)} (the map's), got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.floating):
        raise ValueError(f"distribution: expected a float grid, got dtype {d.dtype}")
    if not (np.all(np.isfinite(d)) and np.all(d >= 0) and d.sum() > 0):
        raise ValueError("distribution: expected finite, non-negative weights with a positive sum")
    return distribution


def _clear_first(nbr, ev, w, k: int):
    """Of candidate links (Q, K) in preference order, the first ``k`` that are clear (then the
    rest, marked invalid): a blocked near candidate does not take a slot from a clear farther
    one."""
    K = nbr.shape[1]
    rank = jnp.where(ev, 0, K) + jnp.arange(K)[None, :]
    _, pos = jax.lax.top_k(-rank, k)
    take = functools.partial(jnp.take_along_axis, indices=pos, axis=1)
    return take(nbr), take(ev), take(w)


def _check_sectors(sectors) -> int:
    if not (isinstance(sectors, (int, np.integer)) and not isinstance(sectors, bool) and 0 <= sectors <= 64):
        raise ValueError(f"sectors: expected an int in [0, 64] (0: the k nearest), got {sectors!r}")
    return int(sectors)


def _initial_cap(n_total: int, shape, resolution, radius) -> int:
    """Bucket slots for uniform samples: 4 x the mean bucket load, a power of two, >= 16."""
    buckets = max(1.0, shape[0] * shape[1] * resolution**2 / radius**2)
    return max(16, 1 << int(math.ceil(math.log2(max(1.0, 4.0 * n_total / buckets)))))


def roadmap_grow(
    roadmap: Roadmap,
    key,
    known_map,
    n: int,
    origin,
    resolution: float,
    *,
    distribution=None,
    radius: float,
    weight: str = "euclidean",
    bucket_cap: int | None = None,
    sectors: int = DEFAULT_SECTORS,
) -> Roadmap:
    """Adds ``n`` samples (valid vertices) to ``roadmap`` and links them (module docstring).

    known_map: (H, W) int8 partial map or bool obstacle grid; distribution: (H, W) cell weights
    (None: uniform over the cells not known occupied); radius: connection radius in metres (keep
    it fixed for one roadmap); weight: 'euclidean' or 'neglogp' (needs ``distribution``);
    bucket_cap: neighbour-search slots per bucket to start with (None: a size for uniform
    samples); on overflow the search reruns with enough slots; sectors: 0 (the k nearest) or the
    direction sectors whose nearest come first (module docstring). Returns the grown roadmap.
    """
    sectors = _check_sectors(sectors)
    blocked = _blocked_from("known_map", known_map)
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n: expected a positive int number of samples, got {n!r}")
    if weight not in ("euclidean", "neglogp"):
        raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
    if weight == "neglogp" and distribution is None:
        raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
    distribution = _check_distribution(distribution, blocked.shape)
    M = roadmap.points.shape[0]
    count = int(roadmap.num_samples)
    if count + int(n) > M - _QUERY:
        raise ValueError(f"n: {n} more samples exceed the roadmap's capacity ({M - _QUERY}, {count} used)")
    origin_j = jnp.asarray(np.asarray(origin, np.float64), roadmap.points.dtype)
    cap = bucket_cap or _initial_cap(count + int(n), blocked.shape, resolution, radius)
    dist = None if distribution is None else jnp.asarray(distribution, roadmap.points.dtype)
    return _grow_exact(
        roadmap,
        key,
        jnp.asarray(blocked),
        dist,
        origin_j,
        int(n),
        float(radius),
        float(resolution),
        cap,
        weight == "neglogp",
        sectors,
    )[0]


def _grow_exact(
    roadmap, key, blocked, dist, origin, n, radius, resolution, cap, neglogp, sectors=0, uniform_samples=False
):
    """Grows with ``cap`` bucket slots, rerunning with 4x more while a bucket overflows.
    Returns (roadmap, the cap that sufficed)."""
    M = roadmap.points.shape[0]
    before = bool(roadmap.overflow)
    while True:
        out = _grow_jit(
            roadmap,
            key,
            blocked,
            dist,
            origin,
            n=n,
            radius=radius,
            resolution=resolution,
            cap=cap if 9 * cap < M else None,
            neglogp=neglogp,
            sectors=sectors,
            uniform_samples=uniform_samples,
        )
        if 9 * cap >= M or before or not bool(out.overflow):
            return out, cap
        cap *= 4  # a bucket held more than ``cap`` vertices: rerun, nothing dropped


def roadmap_recheck(roadmap: Roadmap, known_map, origin, resolution: float, *, radius: float) -> Roadmap:
    """Drops the vertices and edges of ``roadmap`` that a newer partial map ``known_map`` shows
    blocked. A partial map only gains obstacles (unknown -> occupied), so nothing is added back;
    when cells are freed, build a new roadmap. ``radius`` as when the roadmap was grown."""
    blocked = _blocked_from("known_map", known_map)
    origin_j = jnp.asarray(np.asarray(origin, np.float64), roadmap.points.dtype)
    return _recheck_jit(
        roadmap,
        jnp.asarray(blocked),
        origin_j,
        radius=float(radius),
        resolution=float(resolution),
    )


def roadmap_connect(
    roadmap: Roadmap,
    start,
    goal,
    known_map,
    origin,
    resolution: float,
    *,
    radius: float,
    distribution=None,
    weight: str = "euclidean",
    sectors: int = DEFAULT_SECTORS,
) -> Roadmap:
    """Puts a query's ``start`` and ``goal`` (world (2,), not known occupied) into slots 0 and 1
    and links them to samples at any distance (module docstring); the samples' own links are
    unchanged. ``radius``: the roadmap's (which of its edges count as short); ``sectors`` as in
    :func:`roadmap_grow`."""
    sectors = _check_sectors(sectors)
    blocked = _blocked_from("known_map", known_map)
    origin_np = np.asarray(origin, np.float64)
    start = check_point("start", start, blocked, origin_np, resolution)
    goal = check_point("goal", goal, blocked, origin_np, resolution)
    if weight == "neglogp" and distribution is None:
        raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
    distribution = _check_distribution(distribution, blocked.shape)
    dtype = roadmap.points.dtype
    dist = None if distribution is None else jnp.asarray(distribution, dtype)
    return _connect_jit(
        roadmap,
        jnp.asarray(start, dtype),
        jnp.asarray(goal, dtype),
        jnp.asarray(blocked),
        dist,
        jnp.asarray(origin_np, dtype),
        radius=float(radius),
        resolution=float(resolution),
        neglogp=weight == "neglogp",
        sectors=sectors,
    )


def build_roadmap(
    key,
    known_map,
    start,
    goal,
    n: int,
    origin,
    resolution: float,
    *,
    distribution=None,
    k: int | None = None,
    radius: float | None = None,
    weight: str = "euclidean",
    bucket_cap: int | None = None,
    sectors: int = DEFAULT_SECTORS,
) -> Roadmap:
    """One-shot PRM: ``n`` samples plus the start (slot 0) and goal (slot 1) on a partial map.

    known_map: (H, W) int8 partial map (OCCUPIED blocks; UNKNOWN and FREE are free) or a bool
    obstacle grid; start, goal: (2,) world (x, y), on the map, not known occupied; distribution:
    (H, W) non-negative cell weights (None: uniform); k: neighbours per vertex (None: :func:`prm_star_k` of n);
    radius: connection radius in metres (None: :func:`default_radius`); weight: 'euclidean' or
    'neglogp' (needs ``distribution``). Search it with :func:`roadmap_shortest_path`; to reuse
    one roadmap for many queries use :class:`PRM`.
    """
    blocked = _blocked_from("known_map", known_map)
    origin_np = np.asarray(origin, np.float64)
    if origin_np.shape != (2,):
        raise ValueError(f"origin: expected shape (2,), got shape {origin_np.shape}")
    check_point("start", start, blocked, origin_np, resolution)
    check_point("goal", goal, blocked, origin_np, resolution)
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n: expected a positive int number of samples, got {n!r}")
    if weight not in ("euclidean", "neglogp"):
        raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
    radius = float(radius) if radius is not None else default_radius(n, blocked.shape, resolution, weight)
    rm = roadmap_init(int(n), prm_star_k(n) if k is None else k)
    rm = roadmap_grow(
        rm,
        key,
        blocked,
        int(n),
        origin_np,
        resolution,
        distribution=distribution,
        radius=radius,
        weight=weight,
        bucket_cap=bucket_cap,
        sectors=sectors,
    )
    return roadmap_connect(
        rm,
        start,
        goal,
        blocked,
        origin_np,
        resolution,
        radius=radius,
        distribution=distribution,
        weight=weight,
        sectors=sectors,
    )


def make_roadmap_builder(
    n: int,
    shape,
    resolution: float,
    *,
    k: int | None = None,
    radius: float | None = None,
    weight: str = "euclidean",
    uniform: bool = True,
    bucket_cap: int | None = None,
    sectors: int = DEFAULT_SECTORS,
):
    """A pure, jittable and vmappable one-shot builder for a fixed ``n`` and map ``shape``.

    Returns ``build(key, blocked, distribution, start, goal, origin) -> Roadmap`` with
    blocked: (H, W) bool known obstacles; distribution: (H, W) cell weights (ignored when
    ``uniform``); start, goal: (2,); origin: (2,) float. No input checks (use
    :func:`build_roadmap` at the Python boundary). ``bucket_cap=None`` searches neighbours by
    brute force (exact, O(n^2)); with a cap, read :attr:`Roadmap.overflow` (a result code: when
    set, rerun with a larger cap). E.g. ``jax.vmap(build)(keys, maps, dists, starts, goals, origins)``.
    """
    if weight not in ("euclidean", "neglogp"):
        raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
    if weight == "neglogp" and uniform:
        raise ValueError("uniform: weight='neglogp' needs a distribution (uniform=False)")
    H, W = (int(s) for s in shape)
    radius = float(radius) if radius is not None else default_radius(n, (H, W), resolution, weight)
    kk = prm_star_k(n) if k is None else int(k)
    sectors = _check_sectors(sectors)

    def build(key, blocked, distribution, start, goal, origin):
        rm = roadmap_init(int(n), kk, origin.dtype)
        dist = None if uniform else distribution
        rm = _grow_impl(
            rm,
            key,
            blocked,
            dist,
            origin,
            n=int(n),
            radius=radius,
            resolution=float(resolution),
            cap=bucket_cap,
            neglogp=weight == "neglogp",
            sectors=sectors,
        )
        return _connect_impl(
            rm,
            start,
            goal,
            blocked,
            dist,
            origin,
            radius=radius,
            resolution=float(resolution),
            neglogp=weight == "neglogp",
            sectors=sectors,
        )

    return build


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
    """The samples' edges as a symmetric CSR (both directions), rows 0 and 1 empty."""

    def __init__(self, roadmap: Roadmap):
        nbr = np.asarray(roadmap.neighbors)[_QUERY:]
        ok = np.asarray(roadmap.edge_valid)[_QUERY:]
        w = np.asarray(roadmap.edge_weight)[_QUERY:]
        M = nbr.shape[0] + _QUERY
        src, dst, wt = _edge_list(nbr, ok, w, np.arange(_QUERY, M))
        s = np.concatenate([src, dst])
        d = np.concatenate([dst, src])
        ww = np.concatenate([wt, wt])
        order = np.argsort(s, kind="stable")
        self.indices = d[order].astype(np.int32)
        self.data = ww[order]
        self.indptr = np.searchsorted(s[order], np.arange(M + 1)).astype(np.int32)
        self.M = M


def _search(graph: _SampleGraph, roadmap: Roadmap) -> RoadmapPath:
    """Dijkstra from the start over the sample graph plus the start's edges; the goal's edges
    are read off the distances (the goal is only entered, never left)."""
    M = graph.M
    nbr = np.asarray(roadmap.neighbors[:_QUERY])
    ok = np.asarray(roadmap.edge_valid[:_QUERY])
    w = np.asarray(roadmap.edge_weight[:_QUERY])
    s_dst, s_w = nbr[0][ok[0]], np.maximum(w[0][ok[0]], 1e-12)
    g_dst, g_w = nbr[1][ok[1]], np.maximum(w[1][ok[1]], 1e-12)
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
    dist, pred = scipy.sparse.csgraph.dijkstra(csr, directed=True, indices=START, return_predecessors=True)
    best, via = dist[GOAL], -1
    if len(g_dst):
        through = dist[g_dst] + g_w
        i = int(np.argmin(through))
        if through[i] < best:
            best, via = float(through[i]), int(g_dst[i])
    if not np.isfinite(best):
        return _NOT_FOUND
    path = [GOAL] if via < 0 else [GOAL, via]
    node = path[-1] if via >= 0 else GOAL
    while node != START:
        node = int(pred[node])
        path.append(node)
    path = np.array(path[::-1])
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


class PRM:
    """A roadmap on a partial map that is built once, grown, rechecked and queried many times.

    known_map: (H, W) int8 partial map or bool obstacle grid; origin: (2,) world (x, y) of cell
    [0, 0]'s corner; resolution: metres per cell; capacity: most samples it will hold (fixed
    shapes: growing never recompiles); k: neighbours per vertex (None: :func:`prm_star_k` of
    ``capacity``); radius: connection radius in
    metres (None: :func:`default_radius` of ``capacity``); weight: 'euclidean' or 'neglogp'
    (edge weights from the distribution given to :meth:`grow`; the latest one also weights the
    query's edges); sectors: 0 (each vertex links to its k nearest) or the direction sectors
    whose nearest come first (module docstring). Methods: :meth:`grow`, :meth:`update_map`, :meth:`query`; the pytree is
    :attr:`roadmap`.
    """

    def __init__(
        self,
        known_map,
        origin,
        resolution: float,
        *,
        capacity: int,
        k: int | None = None,
        radius: float | None = None,
        weight: str = "euclidean",
        sectors: int = DEFAULT_SECTORS,
    ):
        blocked = _blocked_from("known_map", known_map)
        self.sectors = _check_sectors(sectors)
        origin_np = np.asarray(origin, np.float64)
        if origin_np.shape != (2,) or not np.all(np.isfinite(origin_np)):
            raise ValueError(f"origin: expected a finite (2,) world point, got {origin_np.tolist()}")
        if not (isinstance(resolution, (int, float)) and resolution > 0):
            raise ValueError(f"resolution: expected metres per cell > 0, got {resolution!r}")
        if weight not in ("euclidean", "neglogp"):
            raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
        self.roadmap = roadmap_init(capacity, prm_star_k(capacity) if k is None else k)
        self.blocked = blocked
        self._blocked_j = jnp.asarray(blocked)
        self.origin = origin_np
        self.resolution = float(resolution)
        self.radius = (
            float(radius) if radius is not None else default_radius(capacity, blocked.shape, resolution, weight)
        )
        self.weight = weight
        self.distribution = None
        self._cap: int | None = None
        self._graph: _SampleGraph | None = None

    @property
    def count(self) -> int:
        """Samples in the roadmap."""
        return int(self.roadmap.num_samples)

    @property
    def capacity(self) -> int:
        return int(self.roadmap.points.shape[0]) - _QUERY

    def grow(self, key, n: int, distribution=None, *, uniform_samples: bool = False) -> int:
        """Adds ``n`` samples from ``distribution`` ((H, W) cell weights; None: uniform over the
        cells not known occupied). ``uniform_samples``: draw the samples uniformly even so (the
        distribution still weights the edges under ``weight='neglogp'``). Returns the sample
        count."""
        if self.weight == "neglogp" and distribution is None:
            distribution = self.distribution
        if self.weight == "neglogp" and distribution is None:
            raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
        if not (isinstance(n, (int, np.integer)) and n >= 1):
            raise ValueError(f"n: expected a positive int number of samples, got {n!r}")
        if self.count + int(n) > self.capacity:
            raise ValueError(f"n: {n} more samples exceed the capacity ({self.capacity}, {self.count} used)")
        distribution = _check_distribution(distribution, self.blocked.shape)
        dtype = self.roadmap.points.dtype
        dist = None if distribution is None else jnp.asarray(distribution, dtype)
        cap = self._cap or _initial_cap(self.capacity, self.blocked.shape, self.resolution, self.radius)
        self.roadmap, self._cap = _grow_exact(
            self.roadmap,
            key,
            self._blocked_j,
            dist,
            jnp.asarray(self.origin, dtype),
            int(n),
            self.radius,
            self.resolution,
            cap,
            self.weight == "neglogp",
            self.sectors,
            bool(uniform_samples),
        )
        if distribution is not None:
            self.distribution = distribution
        self._graph = None
        return self.count

    def update_map(self, known_map) -> bool:
        """Adopts a newer partial map; drops vertices and edges it blocks (only where something
        changed: an unchanged map costs nothing). Returns True if the map changed."""
        blocked = _blocked_from("known_map", known_map)
        if blocked.shape != self.blocked.shape:
            raise ValueError(f"known_map: expected shape {self.blocked.shape}, got shape {blocked.shape}")
        if np.array_equal(blocked, self.blocked):
            return False
        self.blocked = blocked
        self._blocked_j = jnp.asarray(blocked)
        self.roadmap = roadmap_recheck(self.roadmap, blocked, self.origin, self.resolution, radius=self.radius)
        self._graph = None
        return True

    def query(self, start, goal) -> RoadmapPath:
        """Shortest roadmap path from ``start`` to ``goal`` (world (2,), not known occupied)."""
        self.roadmap = roadmap_connect(
            self.roadmap,
            start,
            goal,
            self.blocked,
            self.origin,
            self.resolution,
            radius=self.radius,
            distribution=self.distribution,
            weight=self.weight,
            sectors=self.sectors,
        )
        if self._graph is None:
            self._graph = _SampleGraph(self.roadmap)
        return _search(self._graph, self.roadmap)


def embed_local_distribution(local, center_cell, full_shape, outside_mass=None):
    """Embeds a robot-centred local distribution into the full map (thesis section 3.2.5).

    local: (h, w) probabilities (e.g. the network's 160 x 160 softmax), centred on the robot's
    cell ``center_cell`` (row, col) of the full map (the local cell [h // 2, w // 2] is the
    robot's); full_shape: (H, W). Cells outside the window get the window's minimum; the result
    (H, W) is renormalised to sum to 1. Jittable (``center_cell`` may be traced).

    outside_mass: None (the thesis' rule above) or a share ``q`` in [0, 1) (a variant): the
    cells outside the window share ``q`` equally and the window's on-map cells keep the rest in
    their own proportions (when the window covers the whole map, the window alone, renormalised).
    """
    local = jnp.asarray(local)
    h, w = local.shape
    H, W = full_shape
    pad_r, pad_c = h, w
    if outside_mass is not None and not isinstance(outside_mass, jax.Array):
        if not 0.0 <= float(outside_mass) < 1.0:
            raise ValueError(f"outside_mass: expected None or a share in [0, 1), got {outside_mass}")
    fill = jnp.min(local)
    big = jnp.full((H + 2 * pad_r, W + 2 * pad_c), fill, local.dtype)
    r0 = jnp.asarray(center_cell[0], jnp.int32) - h // 2 + pad_r
    c0 = jnp.asarray(center_cell[1], jnp.int32) - w // 2 + pad_c
    # Clamp only so that dynamic_update_slice never shifts the window (the pad covers +-h, w).
    r0 = jnp.clip(r0, 0, H + 2 * pad_r - h)
    c0 = jnp.clip(c0, 0, W + 2 * pad_c - w)
    big = jax.lax.dynamic_update_slice(big, local, (r0, c0))
    full = big[pad_r : pad_r + H, pad_c : pad_c + W]
    if outside_mass is None:
        return full / jnp.sum(full)
    window = jnp.zeros((H + 2 * pad_r, W + 2 * pad_c), bool)
    window = jax.lax.dynamic_update_slice(window, jnp.ones((h, w), bool), (r0, c0))[
        pad_r : pad_r + H, pad_c : pad_c + W
    ]
    q = jnp.asarray(outside_mass, local.dtype)
    n_out = jnp.sum(~window)
    q = jnp.where(n_out > 0, q, 0.0)
    inner = jnp.where(window, full, 0.0)
    inner = inner / jnp.maximum(jnp.sum(inner), jnp.finfo(local.dtype).tiny)
    return jnp.where(window, (1.0 - q) * inner, q / jnp.maximum(n_out, 1).astype(local.dtype))

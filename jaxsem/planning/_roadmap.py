"""Probabilistic roadmap on a partial grid map: built once, grown, rechecked, queried many times.

A :class:`Roadmap` is a pytree of fixed capacity (so growing it never recompiles): slots 0 and 1
hold the current query's start and goal, slots ``2 .. 2 + count`` the samples. The pieces are
pure jitted functions (:func:`roadmap_init`, :func:`roadmap_grow`, :func:`roadmap_recheck`,
:func:`roadmap_connect`) and :class:`PRM` is the host-side object most users want::

    prm = PRM(known_map, grid, capacity=2000)  # grid: a quadrics.Grid (or a Building's .grid)
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
the sparse samples beyond them, were never linked (see ``benchmarks/lsd/lsd_diagnose_finding.md``). A query's start links to its ``k`` nearest samples and
the goal, the goal to its ``k`` nearest samples, chosen by the same rule but at *any* distance
(not bounded by ``radius``; such long edges are checked over :func:`query_reach`): a goal outside
a sparse region still reaches the roadmap. Samples never link to the query slots, so queries do
not change the roadmap.

Neighbour search is exact. Vertices are bucketed on a grid of cell size ``radius`` and each
query point reads the 3 x 3 buckets around its own, which hold every point within ``radius``:
three strips of three buckets, each contiguous in bucket order. A strip is read through
``bucket_cap`` slots, and at most ``bucket_cap`` candidates within ``radius`` are kept; the
search reports ``overflow`` (a result code in :attr:`Roadmap.overflow`) when a strip or a
vertex's neighbourhood holds more, and the Python entry points then rerun with enough slots,
so nothing is dropped silently (samples concentrated by a learned distribution put hundreds of
vertices in one bucket). When ``3 * bucket_cap`` would reach the vertex count, the search is
brute force over all vertices (same result, no cap at all). The candidates are ranked by
counting (each one's rank is the number before it) rather than by sorting: XLA's CPU sort and
a wide top_k cost 10-20x more on rows of a few dozen.

Edge check: ``edge_samples`` points along each edge, at most half a cell apart, must lie in
cells that are not known occupied, and so must both side cells of any diagonal step between
consecutive samples, so a valid edge touches no known-occupied cell. Edge weight: Euclidean
length, or the integral of ``-log p`` along the edge (mean over the samples times the length,
thesis eq. 3.3) with ``weight='neglogp'``.

Search (:func:`roadmap_shortest_path`, :meth:`PRM.query`) is a compiled A* on the host
(:mod:`jaxsem.planning._astar`); the PRM keeps the roadmap's edges in CSR form, so a query only
adds its start's and goal's edges. ``PRM(lazy=True)`` checks no edge when growing and
only those a query's shortest path needs (:mod:`jaxsem.planning._lazy`): the same roadmap and
shortest paths, cheaper to build and query once, dearer per reused query.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from .. import quadrics as Q
from ._edges import (
    _cells,
    _coarse,
    _edge_samples,
    _edges,
    _edges_clear_host,
    _edges_dense,
    _extent,
    _grid,
    _host_edges,
    _intervals_clear,
    _subset,
    _weights,
    query_reach,
)
from ._grid import OCCUPIED, GridLike, check_point, host_grid, static_grid
from ._map_setup import _MapAids
from ._neighbours import _knn, _per_sector, _select
from ._sampling import (
    LocalDistribution,
    _cost_grid,
    _local_cost,
    _local_values,
    _sampling_weights,
    check_local_distribution,
    sample_free_cells,
    sample_local,
    sample_points,
)

#: The connection policy of every public builder (:class:`PRM`, :func:`build_roadmap`,
#: :func:`roadmap_grow`, :func:`roadmap_connect`, :func:`make_roadmap_builder`) and of the
#: navigation planner (``NavConfig.sectors``): direction first over 8 sectors, which found more
#: paths than the plain k nearest, no longer (``benchmarks/RESULTS.md``, "Other: devices and
#: design measurements";
#: ``benchmarks/lsd/lsd_prm.py`` reports held-out buildings).
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
    overflow: () bool result code: a neighbour search had fewer candidate slots than a strip of
        buckets or a vertex's neighbourhood held, so some lists may miss a neighbour. :class:`PRM`, :func:`build_roadmap` and
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


def default_radius(
    n: int, shape, resolution: float, weight: str = "euclidean", *, free_cells: int | None = None
) -> float:
    """Connection radius (m) for ``n`` samples on a map of ``shape`` cells: 3 x the mean sample
    spacing, within [1, 8] m, rounded up to 0.5 m so that few distinct values (each a compile)
    occur. ``free_cells``: the cells samples can land in (None: the whole map); the spacing is
    that of ``n`` samples over them, since samples never land in known-occupied cells (on a
    scanned campus two thirds of the map is blocked: the whole map's area overstates the spacing
    by 1.7x and the radius reads 3x more candidates than it needs). It only bounds the search; the ``k`` nearest are usually closer (see
    ``benchmarks/lsd/lsd_prm.py`` for the quality this gives against OMPL). ``weight='neglogp'`` (a
    learned sampler's roadmap) gives ``LEARNED_RADIUS_FACTOR`` times that, rounded up to 0.5 m:
    the navigation loop's rule (:meth:`~jaxsem.planning.Trial.connection_radius`), so that a
    one-shot LSD roadmap links like the loop's (a concentrated distribution leaves the few samples
    outside its window farther apart than the uniform radius)."""
    cells = shape[0] * shape[1] if free_cells is None else max(1, int(free_cells))
    area = cells * resolution**2
    r = math.ceil(min(8.0, max(1.0, 3.0 * math.sqrt(area / max(n, 1)))) * 2.0) / 2.0
    if weight == "neglogp":
        r = math.ceil(2.0 * r * LEARNED_RADIUS_FACTOR) / 2.0
    return r


def prm_star_k(n: int) -> int:
    """Neighbours per vertex for ``n`` samples: PRM*'s ``ceil(e (1 + 1/d) ln n)`` with d = 2
    (Karaman and Frazzoli 2011; OMPL's ``PRMstar`` uses the same rule): 26 at n = 500, 29 at
    1000, 35 at 5000. Fewer neighbours, or OMPL-like growing batches, solved fewer queries
    (``benchmarks/RESULTS.md``, "Other: devices and design measurements")."""
    return max(1, int(math.ceil(math.e * 1.5 * math.log(max(int(n), 2)))))


def roadmap_init(capacity: int, k: int, dtype=None) -> Roadmap:
    """An empty roadmap with room for ``capacity`` samples and ``k`` neighbours per vertex."""
    if not (isinstance(capacity, (int, np.integer)) and capacity >= 1):
        raise ValueError(f"capacity: expected a positive int, got {capacity!r}")
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"k: expected a positive int number of neighbours, got {k!r}")
    dtype = np.dtype(dtype or jnp.result_type(float))
    return _empty_roadmap(int(capacity) + _QUERY, int(k), dtype)


@functools.partial(jax.jit, static_argnums=(0, 1, 2))
def _empty_roadmap(M: int, k: int, dtype) -> Roadmap:
    """:func:`roadmap_init`'s arrays in one compiled call (seven eager ones cost ~1.3 ms)."""
    return Roadmap(
        points=jnp.zeros((M, 2), dtype),
        valid=jnp.zeros(M, bool),
        neighbors=jnp.full((M, int(k)), M, jnp.int32),
        edge_valid=jnp.zeros((M, int(k)), bool),
        edge_weight=jnp.full((M, int(k)), jnp.inf, dtype),
        num_samples=jnp.zeros((), jnp.int32),
        overflow=jnp.zeros((), bool),
    )


def _sample_into(rm, key, blocked, distribution, grid, *, n, uniform_samples, aids):
    """``n`` new samples written into the roadmap's points and valid flags (``grid``: the map's,
    leaves of the points' dtype), no edge: the first half of the eager grow, and jitted alone
    the lazy grow's device half. Returns (the roadmap with the samples, the new points, their
    valid flags, their first slot)."""
    dtype = rm.points.dtype
    grid = _grid(grid, dtype)
    uniform = distribution is None or uniform_samples
    words = None if aids is None or aids.free_words is None else (aids.free_words, aids.free_counts)
    if words is not None and uniform:
        new = sample_free_cells(key, *words, n, grid)
    elif words is not None and isinstance(distribution, LocalDistribution):
        new = sample_local(key, distribution, blocked, *words, n, grid)
    else:
        if isinstance(distribution, LocalDistribution):
            distribution = distribution.full(grid.shape)
        weights = _sampling_weights(blocked, None if uniform_samples else distribution)
        cdf = aids.uniform_cdf if aids is not None and uniform else None
        new = sample_points(key, weights, n, grid, cdf)
    r, c, on = _cells(new, grid)
    ok_new = on & ~blocked[r, c]
    s0 = (_QUERY + rm.num_samples).astype(jnp.int32)
    z = jnp.zeros((), jnp.int32)
    points = jax.lax.dynamic_update_slice(rm.points, new.astype(dtype), (s0, z))
    valid = jax.lax.dynamic_update_slice(rm.valid, ok_new, (s0,))
    return rm._replace(points=points, valid=valid, num_samples=rm.num_samples + n), new, ok_new, s0


def _density(points, distribution, grid, sectors):
    """Each vertex's sampling density (the direction-first policy's "sparser" test), None
    when it plays no part (no sectors, or uniform samples)."""
    if not sectors or distribution is None:
        return None
    pr, pc, _ = _cells(points, grid)
    if isinstance(distribution, LocalDistribution):
        return _local_values(distribution, pr, pc)
    return distribution[pr, pc]


def _edge_cost(distribution, factor, neglogp):
    """The cell cost that edge weights integrate: ``-log p`` of the distribution (``neglogp``)
    or 1, times ``factor`` ((H, W) per-cell multipliers, e.g. :class:`PRM`'s ``unknown_weight``
    on unknown cells; None: none). None when both are off: the weight is the Euclidean length,
    decided by the fast clear check. A :class:`LocalDistribution`'s cost is read from its window
    (:class:`~jaxsem.planning._sampling.WindowCost`) unless a factor grid multiplies it."""
    if isinstance(distribution, LocalDistribution):
        if factor is None:
            return _local_cost(distribution) if neglogp else None
        distribution = distribution.full(factor.shape)
    if factor is None:
        return _cost_grid(distribution) if neglogp else None
    return (_cost_grid(distribution) if neglogp else 1.0) * factor


def _grow_candidates(
    rm,
    key,
    blocked,
    distribution,
    grid,
    *,
    n,
    radius,
    extent,
    cap,
    sectors=0,
    uniform_samples=False,
    aids: _MapAids | None = None,
    narrow=True,
):
    """The first half of a grow (:func:`_grow_impl`): ``n`` new samples written into the
    roadmap's points and valid flags, and each new vertex's candidates (n, K) in preference
    order (K = 2k with sectors, k without; ``M`` where none). Returns (the roadmap with the
    samples, the new points, the candidates, the new vertices' valid flags, their first slot,
    whether a strip overflowed)."""
    M, k = rm.neighbors.shape
    dtype = rm.points.dtype
    grid = _grid(grid, dtype)
    sampled, new, ok_new, s0 = _sample_into(
        rm,
        key,
        blocked,
        distribution,
        grid,
        n=n,
        uniform_samples=uniform_samples,
        aids=aids,
    )
    points = sampled.points
    slots = s0 + jnp.arange(n, dtype=jnp.int32)
    db_ok = sampled.valid & (jnp.arange(M) >= _QUERY)
    # Direction-first policy (sectors > 0): the first k *clear* links among 2k candidates.
    keep = 2 * k if sectors else k
    density = _density(points, distribution, grid, sectors)
    origin = grid.origin
    search = functools.partial(
        _knn, k=k, radius=radius, extent=extent, cap=cap, sectors=sectors, keep=keep, narrow=narrow
    )
    A = _ACTIVE_STEP
    if cap is None and n + _QUERY <= A < M:
        # Brute force over the first A slots while the roadmap fits in them (a fresh roadmap of
        # navigate's: 502 of 1,502 slots): the empty slots past them are never candidates.
        def prefix(_):
            dens = None if density is None else density[:A]
            nb, ov = search(points[:A] - origin, db_ok[:A], new - origin, slots, density=dens)
            return jnp.where(nb >= A, M, nb), ov

        def every(_):
            return search(points - origin, db_ok, new - origin, slots, density=density)

        nbr, ovf = jax.lax.cond(s0 + n <= A, prefix, every, None)
    else:
        nbr, ovf = search(points - origin, db_ok, new - origin, slots, density=density)
    return sampled, new, nbr, ok_new, s0, ovf


def _grow_impl(
    rm,
    key,
    blocked,
    distribution,
    grid,
    *,
    n,
    radius,
    edge_samples,
    extent,
    cap,
    neglogp,
    sectors=0,
    uniform_samples=False,
    aids: _MapAids | None = None,
    factor=None,
    cost=None,
    narrow=True,
):
    """One grow: ``n`` new samples written into the roadmap's points and valid flags, each new
    vertex's candidates (n, K) in preference order (K = 2k with sectors, k without; ``M`` where
    none), then their links checked. ``grid``: the map's (:func:`static_grid` under jit);
    ``edge_samples`` (:func:`_edge_samples` of the radius) and ``extent`` (:func:`_extent`): the
    sizes its resolution sets, static. A brute-force search (``cap=None``) of a batch that leaves
    the roadmap within its first :data:`_ACTIVE_STEP` slots reads only those (the same
    candidates in the same order: the slots past them are empty), chosen inside the program
    (one program whatever the count). ``cost``: the cell cost the edge weights integrate,
    :func:`_edge_cost` of ``distribution`` and ``factor`` made beforehand (None: made here).
    ``narrow``: the neighbour search picks its row width by a switch (:func:`_knn`; False in
    a program that is vmapped, where a switch runs every branch). Returns the grown roadmap."""
    M, k = rm.neighbors.shape
    dtype = rm.points.dtype
    z = jnp.zeros((), jnp.int32)
    sampled, new, nbr, ok_new, s0, ovf = _grow_candidates(
        rm,
        key,
        blocked,
        distribution,
        grid,
        n=n,
        radius=radius,
        extent=extent,
        cap=cap,
        sectors=sectors,
        uniform_samples=uniform_samples,
        aids=aids,
        narrow=narrow,
    )
    if cost is None:
        cost = _edge_cost(distribution, factor, neglogp)
    cand = (nbr < M) & ok_new[:, None]
    table = None if aids is None else aids.table
    S = edge_samples
    grid = _grid(grid, dtype)
    nbr, ev, w = _link_by_rows(blocked, cost, sampled.points, new, nbr, grid, S, cand, table, k)
    return sampled._replace(
        neighbors=jax.lax.dynamic_update_slice(rm.neighbors, nbr, (s0, z)),
        edge_valid=jax.lax.dynamic_update_slice(rm.edge_valid, ev, (s0, z)),
        edge_weight=jax.lax.dynamic_update_slice(rm.edge_weight, w.astype(dtype), (s0, z)),
        overflow=rm.overflow | ovf,
    )


#: Vertices whose candidate edges are checked at a time (the check's work lists then stay in
#: cache).
_EDGE_ROWS = 1024

#: Work-list width of a grow's link checks. A row holds 2k candidate slots of which
#: a fresh roadmap fills about a third, and every step of a work list reads its whole width: at
#: 8192 the last step of a 500-vertex grow read mostly padding (``benchmarks/lsd/HISTORY.md``).
_GROW_CHUNK = 2048


def _link_by_rows(blocked, cost, points, new, nbr, grid, S, cand, table, k: int):
    """The links of each new vertex (n, 2) to its candidates ``nbr`` (n, K) among ``points``
    (M, 2), checked where ``cand``: (n, k) neighbours (``M`` where none), clear flags and
    weights, the first ``k`` clear candidates when K > k. ``_EDGE_ROWS`` vertices at a time
    (each vertex's links depend only on its own row)."""
    n, K = nbr.shape
    M = points.shape[0]

    def rows(args):
        nw, nb, cd = args
        ot = points[jnp.minimum(nb, M - 1)]
        clear, w = _edges(blocked, None, nw[:, None, :], ot, grid, S, cd, table=table, chunk=_GROW_CHUNK)
        ev = cd & clear
        w = jnp.where(ev, w, jnp.inf)
        if K > k:
            nb, ev, w = _clear_first(nb, ev, w, k, M)
        if cost is not None:  # the cost integral only on the links kept (it reads every sample)
            w = jnp.where(ev, _weights(cost, nw[:, None, :], points[jnp.minimum(nb, M - 1)], grid, S), jnp.inf)
        return nb, ev, w

    if n <= 2 * _EDGE_ROWS:
        return rows((new, nbr, cand))
    blocks = -(-n // _EDGE_ROWS)
    pad = blocks * _EDGE_ROWS - n

    def split(x, fill):
        x = jnp.concatenate([x, jnp.full((pad, *x.shape[1:]), fill, x.dtype)])
        return x.reshape(blocks, _EDGE_ROWS, *x.shape[1:])

    out = jax.lax.map(rows, (split(new, 0), split(nbr, M), split(cand, False)))
    return tuple(x.reshape(blocks * _EDGE_ROWS, -1)[:n] for x in out)


#: :func:`_edge_cost` as a program of its own. Inside the grow's program XLA fuses the cost's
#: ``-log`` into the weights' gather and computes it again for every sample read (the links'
#: samples cross each cell several times, and the gather is the grow's costliest step), where
#: made apart it is computed once per cell; the values read are the same.
_edge_cost_jit = jax.jit(_edge_cost, static_argnums=2)


@functools.partial(jax.jit, static_argnames=("grid", "edge_samples"), donate_argnames=("w",))
def _weigh_chunk_jit(w, points, s0, nbr, rows, slots, cost, grid, *, edge_samples):
    """``w`` (n, k) with the links at ``rows``, ``slots`` (a chunk; rows past ``n`` are padding)
    of vertices ``s0 ..`` to their neighbours ``nbr`` (n, k) set to their weights under the cell
    ``cost`` (:func:`_edge_cost`), read as the grow reads them."""
    M = points.shape[0]
    n = nbr.shape[0]
    g = _grid(grid, points.dtype)
    r = jnp.minimum(rows, n - 1)
    a = points[s0 + r]
    b = points[jnp.minimum(nbr[r, slots], M - 1)]
    return w.at[rows, slots].set(_weights(cost, a, b, g, edge_samples).astype(w.dtype), mode="drop")


def _weigh_links(points, s0: int, nbr, ev, cost, grid_s, edge_samples: int) -> jax.Array:
    """The weights (n, k) of the links ``ev`` of vertices ``s0 ..`` to ``nbr`` (n, k) (numpy),
    inf elsewhere: only the links weighed, in chunks of a size fixed by (n, k) (one compiled
    program however many links a grow keeps)."""
    n, k = nbr.shape
    per = -(-(n * k) // 8)  # an eighth of the slots, rounded up to a multiple of 8
    chunk = -(-per // 8) * 8
    rows, slots = np.nonzero(ev)
    w = jnp.full((n, k), jnp.inf, points.dtype)
    for i in range(0, max(len(rows), 1), chunk):
        r = np.full(chunk, n, np.int32)
        c = np.zeros(chunk, np.int32)
        part = slice(i, min(i + chunk, len(rows)))
        r[: part.stop - part.start] = rows[part]
        c[: part.stop - part.start] = slots[part]
        w = _weigh_chunk_jit(w, points, np.int32(s0), nbr, r, c, cost, grid_s, edge_samples=edge_samples)
    return w


_grow_jit = functools.partial(
    jax.jit,
    static_argnames=("grid", "n", "radius", "edge_samples", "extent", "cap", "neglogp", "sectors", "uniform_samples"),
)(_grow_impl)


#: A brute-force neighbour search of a roadmap whose vertices all lie in its first this many
#: slots reads only those (:func:`_grow_impl`).
_ACTIVE_STEP = 512


_sample_lazy_jit = functools.partial(jax.jit, static_argnames=("grid", "n", "uniform_samples"))(_sample_into)


def _recheck_impl(rm, blocked, grid, distribution=None, factor=None, *, edge_samples, neglogp=False):
    """Drops what ``blocked`` blocks; with a ``factor`` grid (weights that follow the map, e.g.
    unknown cells charged more) the kept edges' weights are read again on the new map.
    ``edge_samples``: :func:`_edge_samples` of the roadmap's radius on ``grid``."""
    M, _ = rm.neighbors.shape
    grid = _grid(grid, rm.points.dtype)
    r, c, on = _cells(rm.points, grid)
    valid = rm.valid & on & ~blocked[r, c]
    j = jnp.minimum(rm.neighbors, M - 1)
    ev = rm.edge_valid & valid[:, None] & valid[j]
    cost = None if factor is None else _edge_cost(distribution, factor, neglogp)
    clear, w = _edges(blocked, cost, rm.points[:, None, :], rm.points[j], grid, edge_samples, ev)
    ev = ev & clear
    w = rm.edge_weight if cost is None else w.astype(rm.edge_weight.dtype)
    return rm._replace(valid=valid, edge_valid=ev, edge_weight=jnp.where(ev, w, jnp.inf))


_recheck_jit = functools.partial(jax.jit, static_argnames=("grid", "edge_samples", "neglogp"))(_recheck_impl)


#: Work-list width of a query's long-edge check: at most 2 x 2k edges whose grazing intervals
#: read dozens of samples each; the default width (8192 intervals a step) read ~450 k samples
#: per step for the few dozen intervals a query needs.
_LONG_CHUNK = 128


def _query_candidates(rm, start, goal, sectors):
    """A query's start and goal in the roadmap's points and valid flags, and their candidates
    (2, keep) in preference order (``M`` where none). Returns (points, valid, q, nbr)."""
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
    return points, valid, q, nbr


@functools.partial(jax.jit, static_argnames=("sectors",))
def _query_candidates_jit(rm, start, goal, *, sectors):
    return _query_candidates(rm, start, goal, sectors)[3]


def _query_links(
    rm,
    start,
    goal,
    blocked,
    distribution,
    grid,
    *,
    radius,
    edge_samples,
    long_samples,
    neglogp,
    sectors=0,
    aids=None,
    factor=None,
):
    """The links of queries (Q, 2) ``start`` and ``goal`` to the roadmap ``rm`` (module
    docstring), each query on its own: (q (Q, 2, 2) start and goal, neighbors (Q, 2, k),
    edge_valid, edge_weight), the rows 0 and 1 :func:`_connect_impl` writes. Every query's
    edges are checked in one work list, so a batch costs about one query's fixed part."""
    M, k = rm.neighbors.shape
    Qn = start.shape[0]
    dtype = rm.points.dtype
    grid = _grid(grid, dtype)
    keep = 2 * k if sectors else k
    nbr = jax.vmap(lambda s, g: _query_candidates(rm, s, g, sectors)[3])(start, goal)  # (Q, 2, keep)
    q = jnp.stack([start, goal], 1).astype(dtype)  # (Q, 2, 2)
    # The candidates' points as each query's roadmap holds them (its goal in slot 1).
    other = jnp.where((nbr == GOAL)[..., None], q[:, None, 1:2, :], rm.points[jnp.minimum(nbr, M - 1)])
    cost = _edge_cost(distribution, factor, neglogp)
    # Each edge is checked with the samples polyline_clear uses for a segment of its length:
    # the roadmap's own for edges up to ``radius``, the query reach's for longer ones.
    short = jnp.sum((other - q[:, :, None, :]) ** 2, -1) <= (radius * (1 + 1e-6)) ** 2
    cand = nbr < M
    s_short = edge_samples
    table = None if aids is None else aids.table
    clear_s, w_s = _edges(blocked, cost, q[:, :, None, :], other, grid, s_short, cand & short, table=table)
    # Long edges: the rule's samples over the query reach, a subset about one per 4 cells of an
    # edge 16 x the radius (longer edges get sparser subsets, so more intervals read densely).
    s_long = long_samples
    sub = min(s_long, 16 * (_subset(s_short)[0].size - 1) + 1)
    clear_l, w_l = _edges(
        blocked,
        cost,
        q[:, :, None, :],
        other,
        grid,
        s_long,
        cand & ~short,
        sub,
        table=table,
        chunk=_LONG_CHUNK,
    )
    clear, w = jnp.where(short, clear_s, clear_l), jnp.where(short, w_s, w_l)
    ev = (nbr < M) & clear
    w = jnp.where(ev, w, jnp.inf).astype(dtype)
    if keep > k:
        nbr, ev, w = (x.reshape(Qn, 2, k) for x in _clear_first(*(x.reshape(2 * Qn, keep) for x in (nbr, ev, w)), k, M))
    return q, nbr, ev, w


def _connect_impl(rm, start, goal, blocked, distribution, grid, **links):
    """A query's start and goal linked (module docstring) on ``grid`` (:func:`static_grid` under
    jit): :func:`_query_links` of the one query (``links``: its keywords; ``edge_samples``,
    ``long_samples``: :func:`_query_samples` of the radius, static), written into rows 0 and 1."""
    q, nbr, ev, w = _query_links(rm, start[None], goal[None], blocked, distribution, grid, **links)
    return _with_query(rm, q[0], nbr[0], ev[0], w[0])


def _with_query(rm, q, nbr, ev, w):
    """``rm`` with the query rows 0 and 1: points ``q`` (2, 2) and links (2, k)."""
    return rm._replace(
        points=rm.points.at[:_QUERY].set(q),
        valid=rm.valid.at[:_QUERY].set(True),
        neighbors=rm.neighbors.at[:_QUERY].set(nbr),
        edge_valid=rm.edge_valid.at[:_QUERY].set(ev),
        edge_weight=rm.edge_weight.at[:_QUERY].set(w),
    )


_with_query_jit = jax.jit(_with_query)

_links_jit = functools.partial(
    jax.jit, static_argnames=("grid", "radius", "edge_samples", "long_samples", "neglogp", "sectors")
)(_query_links)


_connect_jit = functools.partial(
    jax.jit, static_argnames=("grid", "radius", "edge_samples", "long_samples", "neglogp", "sectors")
)(_connect_impl)


def _query_samples(radius: float, grid, reach: float | None = None) -> dict:
    """The static sample counts of :func:`_connect_impl` on a host ``grid``: a short edge's (up
    to ``radius``) and a long one's (over ``reach``; None: :func:`query_reach` of the grid)."""
    res = float(grid.resolution)
    reach = query_reach(grid.shape, res) if reach is None else float(reach)
    return {
        "edge_samples": _edge_samples(radius, res),
        "long_samples": _edge_samples(reach, res),
    }


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


@jax.jit
def _weights_ok(d):
    """Finite, non-negative and a positive sum: one pass over a device grid."""
    return jnp.all(jnp.isfinite(d) & (d >= 0)) & (jnp.sum(d) > 0)


def _as_dist(distribution, dtype):
    """A checked distribution (an (H, W) grid or a :class:`LocalDistribution`) on the device in
    ``dtype`` (None stays None)."""
    if distribution is None:
        return None
    if isinstance(distribution, LocalDistribution):
        return distribution._replace(local=jnp.asarray(distribution.local, dtype))
    return jnp.asarray(distribution, dtype)


def _check_distribution(distribution, shape):
    if distribution is None or isinstance(distribution, Tracer):
        return distribution
    if isinstance(distribution, LocalDistribution):
        if isinstance(distribution.local, Tracer):
            return distribution
        check_local_distribution(distribution, shape)
        return distribution
    d = distribution if isinstance(distribution, jax.Array) else np.asarray(distribution)
    if d.shape != tuple(shape):
        raise ValueError(f"distribution: expected shape {tuple(shape)} (the map's), got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.floating):
        raise ValueError(f"distribution: expected a float grid, got dtype {d.dtype}")
    if isinstance(d, jax.Array):
        ok = bool(_weights_ok(d))
    else:
        ok = bool(np.all(np.isfinite(d)) and np.all(d >= 0) and d.sum() > 0)
    if not ok:
        raise ValueError("distribution: expected finite, non-negative weights with a positive sum")
    return distribution


def _clear_first(nbr, ev, w, k: int, none: int):
    """Of candidate links (Q, K) in preference order, the first ``k`` that are clear, moved to
    the front in order; the other slots hold no link (``none``, False, inf), so a blocked near
    candidate does not take a slot from a clear farther one. Each clear link's slot is the count
    of clear links before it (a running sum and one scatter: cheaper than a top_k over the rows
    on XLA's CPU)."""
    Q, K = nbr.shape
    pos = jax.lax.associative_scan(jnp.add, ev.astype(jnp.int32), axis=1) - 1
    rows = jnp.broadcast_to(jnp.arange(Q)[:, None], (Q, K))
    slot = jnp.where(ev & (pos < k), pos, k)
    out_n = jnp.full((Q, k), none, nbr.dtype).at[rows, slot].set(nbr, mode="drop")
    out_w = jnp.full((Q, k), jnp.inf, w.dtype).at[rows, slot].set(w, mode="drop")
    out_e = jnp.zeros((Q, k), bool).at[rows, slot].set(True, mode="drop")
    return out_n, out_e, out_w


def _check_sectors(sectors) -> int:
    if not (isinstance(sectors, (int, np.integer)) and not isinstance(sectors, bool) and 0 <= sectors <= 64):
        raise ValueError(f"sectors: expected an int in [0, 64] (0: the k nearest), got {sectors!r}")
    return int(sectors)


def _initial_cap(n_total: int, shape, resolution, radius, free_cells: int | None = None) -> int:
    """Strip slots for uniform samples: 2 x the mean load of a strip of 3 buckets (over the
    ``free_cells`` samples land in; None: the whole map), rounded up to 16 times 1, 2, 3, 4, 6,
    8, 12, ... (a power of two or 1.5 times one): maps of similar free area share one compile."""
    cells = shape[0] * shape[1] if free_cells is None else max(1, int(free_cells))
    buckets = max(1.0, cells * resolution**2 / radius**2)
    units = max(1, int(math.ceil(2.0 * 3.0 * n_total / buckets / 16.0)))
    p = 1 << (units.bit_length() - 1)  # the power of two at or below
    return 16 * (p if units == p else 3 * p // 2 if units <= 3 * p // 2 and p > 1 else 2 * p)


def _strip_cap(weights: np.ndarray, n_total: int, resolution: float, radius: float) -> int:
    """Strip slots for ``n_total`` samples drawn from the cell ``weights`` (H, W) (host, >= 0):
    the expected count of the fullest strip of 3 buckets plus four standard deviations, rounded
    up to 16 times a power of two (few compiles). A distribution concentrated in a window (LSD's)
    fills a few strips far past :func:`_initial_cap`'s uniform estimate, and each overflow reruns
    the whole grow."""
    H, W = weights.shape
    total = float(weights.sum())
    if not total > 0:
        return 16
    bucket = lambda count: ((np.arange(count) + 0.5) * resolution / radius).astype(np.int64)  # cell centres
    by, bx = bucket(H), bucket(W)
    rows = np.add.reduceat(weights, np.flatnonzero(np.diff(by, prepend=-1)), axis=0)
    mass = np.add.reduceat(rows, np.flatnonzero(np.diff(bx, prepend=-1)), axis=1) / total
    padded = np.pad(mass, ((0, 0), (1, 1)))
    strips = padded[:, :-2] + padded[:, 1:-1] + padded[:, 2:]
    e = float(n_total) * float(strips.max())
    need = e + 4.0 * math.sqrt(e) + 8.0
    return 16 * (1 << max(0, math.ceil(math.log2(max(need / 16.0, 1.0)))))


def roadmap_grow(
    roadmap: Roadmap,
    key,
    known_map,
    n: int,
    grid: GridLike,
    *,
    distribution=None,
    radius: float,
    weight: str = "euclidean",
    bucket_cap: int | None = None,
    sectors: int = DEFAULT_SECTORS,
) -> Roadmap:
    """Adds ``n`` samples (valid vertices) to ``roadmap`` and links them (module docstring).

    known_map: (H, W) int8 partial map or bool obstacle grid; grid: its
    :class:`jaxsem.quadrics.Grid` (or a map holding one, ``.grid``); distribution: (H, W) cell weights
    (None: uniform over the cells not known occupied); radius: connection radius in metres (keep
    it fixed for one roadmap); weight: 'euclidean' or 'neglogp' (needs ``distribution``);
    bucket_cap: neighbour-search slots per strip of 3 buckets to start with (None: a size for uniform
    samples); on overflow the search reruns with enough slots; sectors: 0 (the k nearest) or the
    direction sectors whose nearest come first (module docstring). Returns the grown roadmap.
    """
    sectors = _check_sectors(sectors)
    blocked = _blocked_from("known_map", known_map)
    grid = host_grid("grid", grid, blocked.shape)
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
    cap = bucket_cap or _initial_cap(count + int(n), blocked.shape, float(grid.resolution), radius)
    dist = _as_dist(distribution, roadmap.points.dtype)
    return _grow_exact(
        roadmap,
        key,
        jnp.asarray(blocked),
        dist,
        grid,
        int(n),
        float(radius),
        cap,
        weight == "neglogp",
        sectors,
    )[0]


def _grow_exact(
    roadmap,
    key,
    blocked,
    dist,
    grid,
    n,
    radius,
    cap,
    neglogp,
    sectors=0,
    uniform_samples=False,
    aids=None,
    factor=None,
    cost=None,
):
    """Grows with ``cap`` strip slots on the host ``grid``, rerunning with 4x more while a strip
    overflows (``cost``: :func:`_edge_cost_jit` of ``dist`` and ``factor`` when the caller keeps
    it; None: made here). Returns (roadmap, the cap that sufficed)."""
    M = roadmap.points.shape[0]
    before = bool(roadmap.overflow)
    if cost is None and (neglogp or factor is not None):
        cost = _edge_cost_jit(dist, factor, neglogp)  # None otherwise: the weights are lengths
    while True:
        out = _grow_jit(
            roadmap,
            key,
            blocked,
            dist,
            static_grid(grid),
            n=n,
            radius=radius,
            edge_samples=_edge_samples(radius, float(grid.resolution)),
            extent=_extent(grid),
            cap=cap if 3 * cap < M else None,
            neglogp=neglogp,
            sectors=sectors,
            uniform_samples=uniform_samples,
            aids=aids,
            factor=factor,
            cost=cost,
        )
        if 3 * cap >= M or before or not bool(out.overflow):
            return out, cap
        cap *= 4  # a strip held more than ``cap`` vertices: rerun, nothing dropped


def roadmap_recheck(roadmap: Roadmap, known_map, grid: GridLike, *, radius: float) -> Roadmap:
    """Drops the vertices and edges of ``roadmap`` that a newer partial map ``known_map`` (on
    ``grid``, a :class:`jaxsem.quadrics.Grid` or a map holding one) shows blocked. A partial map
    only gains obstacles (unknown -> occupied), so nothing is added back; when cells are freed,
    build a new roadmap. ``radius`` as when the roadmap was grown."""
    blocked = _blocked_from("known_map", known_map)
    grid = host_grid("grid", grid, blocked.shape)
    return _recheck_jit(
        roadmap,
        jnp.asarray(blocked),
        static_grid(grid),
        edge_samples=_edge_samples(float(radius), float(grid.resolution)),
    )


def roadmap_connect(
    roadmap: Roadmap,
    start,
    goal,
    known_map,
    grid: GridLike,
    *,
    radius: float,
    distribution=None,
    weight: str = "euclidean",
    sectors: int = DEFAULT_SECTORS,
) -> Roadmap:
    """Puts a query's ``start`` and ``goal`` (world (2,), not known occupied) into slots 0 and 1
    and links them to samples at any distance (module docstring); the samples' own links are
    unchanged. ``grid``: the map's :class:`jaxsem.quadrics.Grid` (or a map holding one); ``radius``: the roadmap's (which of its edges count as short); ``sectors`` as in
    :func:`roadmap_grow`."""
    sectors = _check_sectors(sectors)
    blocked = _blocked_from("known_map", known_map)
    return _connect_checked(
        roadmap,
        start,
        goal,
        blocked,
        jnp.asarray(blocked),
        host_grid("grid", grid, blocked.shape),
        radius=radius,
        distribution=distribution,
        weight=weight,
        sectors=sectors,
    )


def _query_table(roadmap, start, goal, setup, grid, sectors):
    """The clearance table a query's links read: the map's own when ``setup`` has made it, else
    one only where the query's edges run (the box of each end and its candidates)."""
    if setup.has_table:
        return setup.table()
    dtype = roadmap.points.dtype
    nbr = np.asarray(_query_candidates_jit(roadmap, np.asarray(start, dtype), np.asarray(goal, dtype), sectors=sectors))
    pts = np.asarray(roadmap.points, np.float64)
    ends = np.stack([start, goal]).astype(np.float64)
    boxes = []
    for i in range(2):
        c = nbr[i][nbr[i] < len(pts)]
        xy = np.concatenate([ends[i : i + 1], np.where((c == GOAL)[:, None], ends[1], pts[c])])
        cell = Q.world_to_cell(xy, grid.origin, float(grid.resolution), xp=np)
        lo, hi = cell.min(0) - 1, cell.max(0) + 2
        boxes.append((lo[0], hi[0], lo[1], hi[1]))
    return setup.query_table(boxes)


def _connect_checked(
    roadmap,
    start,
    goal,
    blocked,
    blocked_j,
    grid,
    *,
    radius,
    distribution,
    weight,
    sectors,
    setup=None,
    factor=None,
    checked=False,
):
    """:func:`roadmap_connect` on a checked ``blocked`` grid (numpy), its device copy and its
    host ``grid`` (:func:`host_grid`); ``setup``: the map's :class:`_MapSetup` (None: the table
    is made inside); ``checked``: the distribution passed its checks already (a :class:`PRM`'s,
    checked when it grew: a second pass over a map of millions of cells is skipped)."""
    start = check_point("start", start, blocked, grid)
    goal = check_point("goal", goal, blocked, grid)
    if weight == "neglogp" and distribution is None:
        raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
    if not checked:
        distribution = _check_distribution(distribution, blocked.shape)
    dtype = roadmap.points.dtype
    dist = _as_dist(distribution, dtype)
    start_j, goal_j = np.asarray(start, dtype), np.asarray(goal, dtype)
    aids = None
    if setup is not None:
        aids = _MapAids(_query_table(roadmap, start, goal, setup, grid, sectors), None, None, None)
    return _connect_jit(
        roadmap,
        start_j,
        goal_j,
        blocked_j,
        dist,
        static_grid(grid),
        radius=float(radius),
        **_query_samples(float(radius), grid),
        neglogp=weight == "neglogp",
        sectors=sectors,
        aids=aids,
        factor=factor,
    )


def _links_ends(rm, start, goal, cost, grid, *, radius, edge_samples, long_samples, sectors):
    """Queries' (Q, 2) candidates in preference order (Q, 2, keep), their points (start and
    goal (Q, 2, 2), the edges' ends a, other (Q, 2, keep, 2)), which edges are short (up to
    ``radius``), which name a candidate, and the weights (``cost``: the cell cost the weights
    integrate, :func:`_edge_cost`, made once per distribution by the caller; None: lengths)."""
    M, _ = rm.neighbors.shape
    dtype = rm.points.dtype
    grid = _grid(grid, dtype)
    nbr = jax.vmap(lambda s, g: _query_candidates(rm, s, g, sectors)[3])(start, goal)  # (Q, 2, keep)
    q = jnp.stack([start, goal], 1).astype(dtype)  # (Q, 2, 2)
    other = jnp.where((nbr == GOAL)[..., None], q[:, None, 1:2, :], rm.points[jnp.minimum(nbr, M - 1)])
    a = jnp.broadcast_to(q[:, :, None, :], other.shape)
    short = jnp.sum((other - a) ** 2, -1) <= (radius * (1 + 1e-6)) ** 2
    w = jnp.where(short, _weights(cost, a, other, grid, edge_samples), _weights(cost, a, other, grid, long_samples))
    return q, nbr, a, other, short, nbr < M, w


#: The device part of :func:`_links_checked` when the host checks the edges (:func:`_links_ends`).
_links_ends_jit = jax.jit(_links_ends, static_argnames=("grid", "radius", "edge_samples", "long_samples", "sectors"))


def _warm_once(call, signature) -> None:
    """Runs ``call`` (a compiled program, its answer unused) the first time this process meets
    ``signature``: the device's query links are the host's rare fallback (a sample on a sector
    border), and compiled at that moment they would stall a query many trials later."""
    if signature not in _WARM:
        _WARM.add(signature)
        call()


#: Signatures :func:`_warm_once` has run.
_WARM: set = set()


def _links_ends_host(points, valid, starts, goals, k: int, *, radius, sectors, choice):
    """:func:`_links_ends` with lengths as weights, on the host: the same candidates, ends and
    flags, and the weights to a unit in the last place (numpy), for float32 ``points`` (M, 2),
    ``valid`` (M,), ``starts``, ``goals`` (Q, 2), from the compiled choice ``choice``
    (:func:`_host_choice`). None where a sample on a sector border could change a query's
    candidates (the device decides those)."""
    kernels, mode = choice
    M = points.shape[0]
    keep = 2 * k if sectors else k
    m = _per_sector(k, sectors) if sectors else 0
    starts, goals = np.ascontiguousarray(starts, np.float32), np.ascontiguousarray(goals, np.float32)
    nbr, d2, unsure = kernels.query_candidates(points, valid, starts, goals, m, int(sectors), keep, mode)
    if unsure.any():
        return None
    q = np.stack([starts, goals], 1)  # (Q, 2, 2)
    other = np.where((nbr == GOAL)[..., None], q[:, None, 1:2, :], points[np.minimum(nbr, M - 1)])
    a = np.broadcast_to(q[:, :, None, :], other.shape)
    # The squared length the choice read and the radius' square rounded once, as the device
    # compares them; the length sqrt(d2 + 1e-30) rounded after each operation, as the host's own
    # edges' (entry_length): a device program that fuses a product into the sum (XLA decides
    # per program) reads some lengths one unit in the last place apart.
    short = d2 <= np.float32((radius * (1 + 1e-6)) ** 2)
    w = np.sqrt(d2 + np.float32(1e-30))
    return q, nbr, a, other, short, nbr < M, w


def _unlinked(points, valid, k: int) -> Roadmap:
    """A roadmap of the samples ``points`` (M, 2) (slots 0 and 1 the query's) and their flags,
    with room for ``k`` links each and none made: what a query's choice reads."""
    M = len(points)
    return _empty_roadmap(M, int(k), np.dtype(points.dtype))._replace(
        points=jnp.asarray(points), valid=jnp.asarray(valid), num_samples=jnp.asarray(M - _QUERY, jnp.int32)
    )


@functools.cache
def _host_choice():
    """``(kernels, mode)``: the compiled host choice of a query's candidates
    (:mod:`jaxsem.planning._neighbours_kernels`) and the rounding of its squared distances that
    gives the device's choice (:func:`_links_ends_jit`), or None when none does on the probe
    (callers then ask the device).

    Whether XLA rounds ``dx * dx + dy * dy`` after each operation or fuses a product into the
    sum is its compiler's choice. The probe places pairs of samples whose squared distances from
    their query tie under one rounding and not under another, each pair alone in a sector of
    its query (so its nearer one is the sector's reserved candidate), reads the device's
    choice, and keeps the rounding that gives it."""
    from . import _neighbours_kernels as kern

    rng = np.random.default_rng(0)
    n, k = 24, 16  # 8 sectors of one reserved candidate each
    qs = np.stack([100.0 + 8.0 * np.arange(n), np.zeros(n)], 1).astype(np.float32)
    goals = (qs + np.array([-500.0, -900.0], np.float32)).astype(np.float32)
    pairs = []
    for i in range(n):
        # Offsets in the sector from 0.2 to 0.6 rad, on a thin ring: many squared distances tie.
        ang = rng.uniform(0.2, 0.6, 4096)
        rad = 1.0 + rng.uniform(0.0, 2e-5, 4096)
        p = (qs[i] + np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)).astype(np.float32)
        d = p - qs[i]
        dx, dy = d[:, 0].astype(np.float64), d[:, 1].astype(np.float64)
        fx, fy = (d[:, 0] * d[:, 0]).astype(np.float64), (d[:, 1] * d[:, 1]).astype(np.float64)  # float32 products
        ways = [(fx + fy).astype(np.float32), (dx * dx + fy).astype(np.float32), (dy * dy + fx).astype(np.float32)]
        # A pair tied under way i % 3 that neither other way ties.
        w0 = ways[i % 3]
        _, first, counts = np.unique(w0, return_index=True, return_counts=True)
        found = None
        for f in first[counts > 1]:
            for j in np.flatnonzero(w0 == w0[f]):
                if j != f and all(w[j] != w[f] for t, w in enumerate(ways) if t != i % 3):
                    found = (f, j)
                    break
            if found:
                break
        if found is None:
            return None
        pairs.append(p[list(found)])
    M = 2 + 2 * n
    points = np.zeros((M, 2), np.float32)
    points[2:] = np.concatenate(pairs)
    valid = np.ones(M, bool)
    valid[:2] = False
    outs = [kern.query_candidates(points, valid, qs, goals, 1, 8, 2 * k, mode) for mode in range(3)]
    if any(o[2].any() for o in outs) or any(
        np.array_equal(outs[i][0], outs[j][0]) for i in range(3) for j in range(i + 1, 3)
    ):
        return None  # the probe tells nothing (cannot happen with the fixed draw)
    rm = _unlinked(points, valid, k)
    grid = Q.Grid.host((0.0, -1024.0), 1.0, (2048, 2048))
    device = np.asarray(
        _links_ends_jit(rm, qs, goals, None, static_grid(grid), radius=4.0, edge_samples=9, long_samples=9, sectors=8)[
            1
        ]
    )
    for mode, out in enumerate(outs):
        if np.array_equal(out[0], device):
            return kern, mode
    return None


@functools.partial(jax.jit, static_argnames=("grid", "radius", "edge_samples", "long_samples", "sectors"))
def _links_coarse(rm, start, goal, blocked, cost, grid, table, *, radius, edge_samples, long_samples, sectors):
    """The device part of :func:`_links_checked` when the device checks the edges: the
    candidates, ends and weights of :func:`_links_ends`, the short edges' clear flags (every
    sample read: the rule's answer), and the long edges' first pass
    (:func:`~jaxsem.planning._edges._coarse`: hit (E,), uncovered intervals (E, C - 1) over the
    flat (Q * 2 * keep) edges)."""
    q, nbr, a, other, short, cand, w = _links_ends(
        rm,
        start,
        goal,
        cost,
        grid,
        radius=radius,
        edge_samples=edge_samples,
        long_samples=long_samples,
        sectors=sectors,
    )
    grid = _grid(grid, rm.points.dtype)
    clear_s, _, _ = _edges_dense(blocked, a, other, grid, edge_samples)
    fa, fb = a.reshape(-1, 2), other.reshape(-1, 2)
    hit, unc = _coarse(
        blocked,
        fa,
        fb,
        grid,
        long_samples,
        (cand & ~short).reshape(-1),
        subset=_long_subset(edge_samples, long_samples),
        table=table,
    )
    return q, nbr, short, cand & short & clear_s, w, fa, fb, hit, unc


def _long_subset(edge_samples: int, long_samples: int) -> int:
    """The subset a query's long edges read first (:func:`_connect_impl`'s)."""
    return min(long_samples, 16 * (_subset(edge_samples)[0].size - 1) + 1)


@functools.partial(jax.jit, static_argnames=("grid", "long_samples", "subset"))
def _intervals_jit(blocked, fa, fb, edge, interval, grid, *, long_samples, subset):
    return _intervals_clear(blocked, fa, fb, edge, interval, _grid(grid, fa.dtype), long_samples, subset=subset)


#: Uncovered intervals of long query edges read per call: one query's (a few hundred), and a
#: batch's (thousands), a wider call at a time.
_INTERVALS, _INTERVALS_WIDE = 1024, 8192


def _weigh_kept(cost, a, other, short, ev, w, k: int, grid_s, samples) -> np.ndarray:
    """The weights ``w`` (Q, 2, K) (lengths) of the query links each end keeps (its first ``k``
    clear ones, :func:`_clear_first_np`'s) replaced by their ``cost`` integrals on the device:
    the short links' (``edge_samples``) as one list of every slot's size, the long links'
    (``long_samples``, few, each reading thousands of samples) in chunks of 8; the rest of the
    candidates unread. Fixed sizes: no program compiled after a query's first."""
    rows = ev.reshape(-1, ev.shape[-1])
    keep = (rows & (np.cumsum(rows, axis=1) <= k)).reshape(-1)
    w = np.array(w, copy=True)
    flat = w.reshape(-1)
    fa, fb = a.reshape(-1, 2), other.reshape(-1, 2)
    for sel, size, n_samples in (
        (keep & short.reshape(-1), keep.size, samples["edge_samples"]),
        (keep & ~short.reshape(-1), 8, samples["long_samples"]),
    ):
        idx = np.flatnonzero(sel)
        for i in range(0, len(idx), size):
            part = idx[i : i + size]
            pick = np.concatenate([part, np.full(size - len(part), part[0])])
            got = _weigh_list_jit(cost, fa[pick], fb[pick], grid_s, edge_samples=n_samples)
            flat[part] = np.asarray(got)[: len(part)]
    return w


@functools.partial(jax.jit, static_argnames=("grid", "edge_samples"))
def _weigh_list_jit(cost, a, b, grid, *, edge_samples):
    """:func:`_weights` of the segments a -> b (E, 2) with ``edge_samples`` samples."""
    return _weights(cost, a, b, _grid(grid, a.dtype), edge_samples)


def _clear_first_np(nbr, ev, w, k: int, none: int):
    """:func:`_clear_first` on the host (the same selection)."""
    Qr, K = nbr.shape
    pos = np.cumsum(ev, axis=1) - 1
    sel = ev & (pos < k)
    rows = np.broadcast_to(np.arange(Qr)[:, None], (Qr, K))
    out_n = np.full((Qr, k), none, nbr.dtype)
    out_w = np.full((Qr, k), np.inf, w.dtype)
    out_e = np.zeros((Qr, k), bool)
    out_n[rows[sel], pos[sel]] = nbr[sel]
    out_w[rows[sel], pos[sel]] = w[sel]
    out_e[rows[sel], pos[sel]] = True
    return out_n, out_e, out_w


def _links_checked(
    roadmap,
    starts,
    goals,
    blocked,
    blocked_j,
    grid,
    *,
    radius,
    distribution,
    weight,
    sectors,
    table,
    factor=None,
    reach=None,
    cost=None,
    bits=None,
):
    """:func:`_query_links` of queries ``starts``, ``goals`` (Q, 2) (float64, checked) on a
    checked ``blocked`` grid (numpy), its device copy and its host ``grid``, the distribution
    already checked (a :class:`PRM`'s); ``table``: a clearance table for the queries' edges;
    ``reach``: the long edges' length rule (:func:`_query_samples`); ``cost``: the cell cost of
    ``distribution`` and ``factor`` (:func:`_edge_cost_jit`) when the caller keeps it (None:
    made here); ``bits``: the host rule's bits of ``blocked`` (None: made here).
    The candidates and weights come from one compiled call; the edges are checked by the host's
    compiled rule (:func:`~jaxsem.planning._edges._edges_clear_host`: most query edges are
    blocked within a few cells of their start, and it stops there) where its float32
    arithmetic is the device's, else by the device (:func:`_links_device`). Returns (q,
    neighbors, edge_valid, edge_weight) on the host, each (Q, 2, ...)."""
    if weight == "neglogp" and distribution is None:
        raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
    dtype = roadmap.points.dtype
    neglogp = weight == "neglogp"
    if cost is None and (neglogp or factor is not None):
        cost = _edge_cost_jit(_as_dist(distribution, dtype), factor, neglogp)
    samples = _query_samples(float(radius), grid, reach)
    grid_s = static_grid(grid)
    M, k = roadmap.neighbors.shape
    starts_d, goals_d = np.asarray(starts, dtype), np.asarray(goals, dtype)  # numpy into the jitted calls
    if _host_edges(dtype):
        ends = None
        choice = _host_choice()
        if choice is not None:
            pts, valid = roadmap.points, roadmap.valid
            ends = _links_ends_host(
                np.asarray(pts), np.asarray(valid), starts_d, goals_d, k, radius=radius, sectors=sectors, choice=choice
            )
        device = functools.partial(
            _links_ends_jit, roadmap, starts_d, goals_d, None, grid_s, radius=float(radius), **samples, sectors=sectors
        )
        if ends is None:
            ends = tuple(np.asarray(x) for x in device())
        else:
            _warm_once(device, (roadmap.points.shape, roadmap.neighbors.shape, starts_d.shape, grid_s, radius, sectors))
        q, nbr, a, other, short, cand, w = ends
        fa, fb = a.reshape(-1, 2), other.reshape(-1, 2)
        n = np.where(short, samples["edge_samples"], samples["long_samples"]).reshape(-1)
        # Each end keeps its first k clear candidates (_clear_first_np): the rest go unread.
        keep_k = (nbr.shape[-1], k) if nbr.shape[-1] > k else (None, None)
        clear = _edges_clear_host(
            blocked, fa, fb, n, cand.reshape(-1), grid, np.asarray(table), row=keep_k[0], k=keep_k[1], bits=bits
        )
        ev = clear.reshape(nbr.shape)
        if cost is not None:  # weighed on the device, only the links each end keeps
            w = _weigh_kept(cost, a, other, short, ev, w, k, grid_s, samples)
    else:
        q, nbr, w, ev = _links_device(
            roadmap,
            starts_d,
            goals_d,
            blocked_j,
            cost,
            grid_s,
            table,
            radius=float(radius),
            samples=samples,
            sectors=sectors,
        )
    w = np.where(ev, w, np.inf).astype(w.dtype)
    Qn, _, keep = nbr.shape
    if keep > k:
        nbr, ev, w = (
            x.reshape(Qn, 2, k)
            for x in _clear_first_np(nbr.reshape(-1, keep), ev.reshape(-1, keep), w.reshape(-1, keep), k, M)
        )
    return np.asarray(q), nbr, ev, w


def _links_device(roadmap, starts, goals, blocked_j, cost, grid_s, table, *, radius, samples, sectors):
    """The links of :func:`_links_checked` checked by the device's rule, in two compiled calls
    with the host between them: the first reads every short edge's samples and the long edges'
    subsets, the host lists the long edges' uncovered intervals (a few hundred per query), the
    second reads those (padded to a power of two: one program per size). Returns (q, neighbors,
    weights, edge_valid) on the host, each (Q, 2, ...)."""
    q, nbr, short, clear_s, w, fa, fb, hit, unc = _links_coarse(
        roadmap,
        starts,
        goals,
        blocked_j,
        cost,
        grid_s,
        table,
        radius=radius,
        **samples,
        sectors=sectors,
    )
    nbr, short, clear_s, w, hit, unc = (np.asarray(x) for x in (nbr, short, clear_s, w, hit, unc))
    M, _ = roadmap.neighbors.shape
    edge, interval = np.nonzero(unc)
    bad = np.zeros(hit.shape, bool)
    # Fixed widths (one program each): a query's few hundred intervals in one call, a batch's
    # in calls of the wider one.
    U = _INTERVALS if len(starts) == 1 or len(edge) <= _INTERVALS else _INTERVALS_WIDE
    for i in range(0, len(edge), U):
        e, iv = edge[i : i + U], interval[i : i + U]
        pad = U - len(e)
        ok = _intervals_jit(
            blocked_j,
            fa,
            fb,
            np.concatenate([e, np.full(pad, e[0])]).astype(np.int32),
            np.concatenate([iv, np.full(pad, iv[0])]).astype(np.int32),
            grid_s,
            long_samples=samples["long_samples"],
            subset=_long_subset(samples["edge_samples"], samples["long_samples"]),
        )
        np.logical_or.at(bad, e, ~np.asarray(ok)[: len(e)])
    cand = nbr < M
    clear_l = (cand & ~short).reshape(-1) & ~hit & ~bad
    return q, nbr, w, np.where(short, clear_s, clear_l.reshape(nbr.shape)) & cand


def build_roadmap(
    key,
    known_map,
    start,
    goal,
    n: int,
    grid: GridLike,
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
    obstacle grid; grid: its :class:`jaxsem.quadrics.Grid` (or a map holding one: a
    :class:`~jaxsem.planning.Building`); start, goal: (2,) world (x, y), on the map, not known
    occupied; distribution:
    (H, W) non-negative cell weights (None: uniform); k: neighbours per vertex (None: :func:`prm_star_k` of n);
    radius: connection radius in metres (None: :func:`default_radius`); weight: 'euclidean' or
    'neglogp' (needs ``distribution``). Search it with :func:`roadmap_shortest_path`; to reuse
    one roadmap for many queries use :class:`PRM`.
    """
    blocked = _blocked_from("known_map", known_map)
    grid = host_grid("grid", grid, blocked.shape)
    check_point("start", start, blocked, grid)
    check_point("goal", goal, blocked, grid)
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n: expected a positive int number of samples, got {n!r}")
    if weight not in ("euclidean", "neglogp"):
        raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
    radius = float(radius) if radius is not None else default_radius(n, blocked.shape, float(grid.resolution), weight)
    rm = roadmap_init(int(n), prm_star_k(n) if k is None else k)
    rm = roadmap_grow(
        rm,
        key,
        blocked,
        int(n),
        grid,
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
        grid,
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
    sizes = Q.Grid.host((0.0, 0.0), float(resolution), (H, W))  # the static sizes its resolution sets

    def build(key, blocked, distribution, start, goal, origin):
        rm = roadmap_init(int(n), kk, origin.dtype)
        dist = None if uniform else distribution
        grid = Q.Grid(origin, float(resolution), (H, W))  # pyright: ignore[reportArgumentType]
        rm = _grow_impl(
            rm,
            key,
            blocked,
            dist,
            grid,
            n=int(n),
            radius=radius,
            edge_samples=_edge_samples(radius, float(resolution)),
            extent=_extent(sizes),
            cap=bucket_cap,
            neglogp=weight == "neglogp",
            sectors=sectors,
            narrow=False,  # vmapped: a switch would run every branch
        )
        return _connect_impl(
            rm,
            start,
            goal,
            blocked,
            dist,
            grid,
            radius=radius,
            **_query_samples(radius, sizes),
            neglogp=weight == "neglogp",
            sectors=sectors,
        )

    return build

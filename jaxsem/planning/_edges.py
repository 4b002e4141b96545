"""The PRM's edge check on a grid: samples at most half a cell apart, both side cells of a
diagonal step, most edges decided from a few reads through a clearance table (see
:mod:`jaxsem.planning._roadmap`).
"""

from __future__ import annotations

import concurrent.futures
import functools
import math
import os

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics as Q
from ._grid import OCCUPIED, GridLike, _grid, host_grid, static_grid
from ._sampling import WindowCost, _read_cost


def _edge_samples(radius: float, resolution: float) -> int:
    return max(2, int(math.ceil(radius / (0.5 * resolution))) + 1)


def _extent(grid) -> tuple[float, float]:
    """(width, height) in metres of a host grid (Python floats: the neighbour search's static
    bucket extent)."""
    res = float(grid.resolution)
    return (grid.shape[1] * res, grid.shape[0] * res)


def _cells(points, grid):
    """(row, col, on-grid) of world ``points`` (..., 2) on ``grid``, rows and columns clipped
    to it (read them only where ``on``)."""
    H, W = grid.shape
    rc = Q.world_to_cell(points, grid.origin, grid.resolution)
    on = Q.cell_in_grid(rc, grid.shape)
    return jnp.clip(rc[..., 0], 0, H - 1), jnp.clip(rc[..., 1], 0, W - 1), on


def _edges(blocked, cost, a, b, grid, edge_samples, mask=None, subset=None, table=None, chunk=8192):
    """Clear flag and weight of segments a -> b (..., 2) on the ``grid`` of ``blocked`` (see the
    module docstring).

    The rule is decided by :func:`_edges_clear` (the answer of :func:`_edges_dense`, most edges
    from a few dozen reads), the weight :func:`_weights`'s. ``mask``: the edges worth checking
    (the rest may come back either way; None: all); ``subset``, ``table``, ``chunk``: see
    :func:`_edges_clear`."""
    clear = _edges_clear(blocked, a, b, grid, edge_samples, mask, subset=subset, table=table, chunk=chunk)
    return clear, _weights(cost, a, b, grid, edge_samples)


def _weights(cost, a, b, grid, edge_samples):
    """Weights of segments a -> b (..., 2): the length (``cost=None``), or the length times the
    mean of the cost grid over the edge rule's ``edge_samples`` points (every one is read)."""
    if cost is None:
        return _length(a, b)
    t = jnp.arange(edge_samples, dtype=a.dtype) / (edge_samples - 1)
    er, ec, _ = _cells(a[..., None, :] + t[:, None] * (b - a)[..., None, :], grid)
    return _length(a, b) * jnp.mean(_read(cost, er, ec), axis=-1)


def _read(values, rows, cols):
    """``values[rows, cols]`` of a 2-D grid (indices on the grid) through one flat index.
    ``take``'s default mode (the indices are on the grid: nothing is filled); its "clip" mode
    was slower. The optimisation barrier asks XLA to make the index apart from the read, but
    XLA's CPU pipeline removes barriers before fusion (jax 0.10): the compiled read still
    computes each index inside the gather. The values are the same either way; indices made by
    a program of their own cost more than they save in the grow (the list is written to memory
    and read back). A :class:`~jaxsem.planning._sampling.WindowCost` is read as the grid it
    stands for."""
    if isinstance(values, WindowCost):
        return _read_cost(values, rows, cols)
    flat = jax.lax.optimization_barrier(rows * values.shape[1] + cols)
    return jnp.take(values.reshape(-1), flat)


def _length(a, b):
    # Safe norm: a zero-length edge (a vertex drawn twice at one point) has weight ~0, no NaN.
    return jnp.sqrt(jnp.sum((b - a) ** 2, -1) + 1e-30)


def _edges_dense(blocked, a, b, grid, edge_samples):
    """The edge rule read at every one of the ``edge_samples`` points (module docstring)."""
    er, ec, eon = _cells(_along(a, b, edge_samples), grid)
    clear = _cells_clear(blocked, er, ec, eon)
    return clear, er, ec


def _along(a, b, edge_samples: int):
    """The rule's ``edge_samples`` samples (..., S, 2) of segments a -> b (..., 2)."""
    t = jnp.arange(edge_samples, dtype=a.dtype) / (edge_samples - 1)
    return a[..., None, :] + t[:, None] * (b - a)[..., None, :]


def _samples_clear(blocked, along, grid):
    """The edge rule on consecutive samples ``along`` (..., S, 2) of a segment."""
    er, ec, eon = _cells(along, grid)
    return _cells_clear(blocked, er, ec, eon)


def _cells_clear(blocked, er, ec, eon):
    clear = jnp.all(eon & ~blocked[er, ec], axis=-1)
    # Consecutive samples are at most half a cell apart, so they lie in the same or 8-adjacent
    # cells and the segment between them stays inside the 2 x 2 block they span; on a diagonal
    # move it may cross either side cell, so both must be free: the check is then exact
    # (conservative), no edge passes through a known-occupied cell.
    diag = (er[..., 1:] != er[..., :-1]) & (ec[..., 1:] != ec[..., :-1])
    sides = blocked[er[..., :-1], ec[..., 1:]] | blocked[er[..., 1:], ec[..., :-1]]
    return clear & ~jnp.any(diag & sides, axis=-1)


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


def _clearance_table_np(blocked: np.ndarray) -> np.ndarray:
    """:func:`_clearance_table` of a numpy bool grid, value for value, on the host: per-map setup
    that a PRM does once per map, where XLA's CPU strided bool reductions cost ~2.5x numpy's.
    The dilation and the first 2 x 2 reduction are one strided 4 x 4 window per block; each
    level's 3 x 3 test is made at its own resolution and the levels are merged coarse to fine
    (a block whose neighbourhood is free at level l + 1 is free at level l too, so the finest
    resolution's maximum is the top level that holds)."""
    blocked = np.asarray(blocked, bool)
    H, W = blocked.shape
    top = 1 << _TOP
    Hp, Wp = -(-H // top) * top, -(-W // top) * top
    b = 1 << _BASE
    grid = np.ones((Hp + 2 * b, Wp + 2 * b), bool)  # off-map cells count as blocked
    grid[1 : H + 1, 1 : W + 1] = blocked
    # Level-0 block i (b cells) with its 8-neighbour dilation spans padded rows b*i .. b*i + b + 1:
    # OR the rows in runs of b, then b + 2 rows = 2 runs (_BASE = 1); the same over the columns.
    runs = grid[0::b].copy()
    for d in range(1, b):
        runs |= grid[d::b]
    rows = runs[:-1] | runs[1:]  # (Hp / b + 1, .): keep Hp / b
    rows = rows[: Hp // b]
    runs = rows[:, 0::b].copy()
    for d in range(1, b):
        runs |= rows[:, d::b]
    cols = (runs[:, :-1] | runs[:, 1:])[:, : Wp // b]
    free = ~cols
    levels = []
    for lev in range(_BASE, _TOP + 1):
        f = np.zeros((free.shape[0] + 2, free.shape[1] + 2), bool)
        f[1:-1, 1:-1] = free
        nb = f[:, :-2] & f[:, 1:-1]
        nb &= f[:, 2:]
        nb3 = nb[:-2] & nb[1:-1]
        nb3 &= nb[2:]
        levels.append(nb3)
        if lev < _TOP:
            free = free[0::2, 0::2] & free[1::2, 0::2] & free[0::2, 1::2] & free[1::2, 1::2]
    # Count the levels that hold (uint8: cheap to upsample); they are the lowest ones.
    count = levels[-1].astype(np.uint8)
    for nb in levels[-2::-1]:
        count = np.repeat(np.repeat(count, 2, axis=0), 2, axis=1)
        count += nb
    value = np.array([0] + [1 << (_BASE + i) for i in range(len(levels))], np.int32)
    return value[count]


def _subset(S: int, C: int | None = None):
    """The rule's samples read first: every ``G``-th of the ``S`` (the last one too), ``C`` of
    them (default about one per 4 cells of the longest edge). Returns (pick, G)."""
    if C is None:
        C = min(S, max(2, -(-(S - 1) // 8) + 1))
    G = max(1, -(-(S - 1) // max(1, C - 1)))
    C = -(-(S - 1) // G) + 1
    return np.minimum(np.arange(C) * G, S - 1), G


def _compact(mask, pad: int):
    """Indices (n + pad,) of the set entries of the flat bool ``mask`` (n,), in order, then
    ``n``; and each entry's place among them (n,) (jnp.nonzero without its cumsum: XLA's CPU
    cumsum is slow on long arrays)."""
    n = mask.shape[0]
    pos = jax.lax.associative_scan(jnp.add, mask.astype(jnp.int32)) - 1
    out = jnp.full((n + pad,), n, jnp.int32)
    return out.at[jnp.where(mask, pos, n + pad)].set(jnp.arange(n, dtype=jnp.int32), mode="drop"), pos


def _edges_clear(blocked, a, b, grid, edge_samples, mask=None, *, subset=None, table=None, chunk: int = 8192):
    """The edge rule of :func:`_edges_dense`, decided from a few reads where the map allows.

    Only edges where ``mask`` (broadcast to the edges; None: all) is set are checked (the rest
    come back False), ``chunk`` at a time. A subset of the rule's own samples (``subset`` of
    them, default about one per 4 cells of the longest edge) is read twice: in the grid (one
    sample in a blocked or off-map cell rejects the edge, as the full rule does) and in
    :func:`_clearance_table` (a disc around each sample free of blocked cells and their
    neighbours). Where the discs of two consecutive subset samples overlap along the edge, every
    rule sample between them and every side cell of their diagonal steps is free. Only the
    intervals between subset samples that are not covered so (an edge grazing a wall: usually
    one or two of a dozen) read the rule's samples in between, with their diagonal side cells;
    one of them blocked rejects the edge. Long edges (subsets of ``_SPARSE_FROM`` samples and
    more) first try the discs of every ``_SPARSE_STEP``-th subset sample alone: an edge they
    cover end to end is clear without a work list (:func:`_covered_whole`). The answer is the
    full rule's, sample for sample.
    ``table``: :func:`_clearance_table` of ``blocked`` when the caller keeps it (None: made here).
    ``chunk``: the work lists' static width (edges, then intervals, per loop step); every step
    reads the whole width, so a few edges with many samples each (a query's long edges: a few
    grazing intervals of dozens of samples) want a narrow one.
    The work lists are kept compact (edges to check, then edges with an uncovered interval,
    then, a chunk at a time, those intervals), so the cost follows what needs reading rather
    than the static shapes."""
    shape = jnp.broadcast_shapes(a.shape, b.shape)[:-1]
    a, b = jnp.broadcast_to(a, shape + (2,)), jnp.broadcast_to(b, shape + (2,))
    fa, fb = a.reshape(-1, 2), b.reshape(-1, 2)
    E = fa.shape[0]
    dtype = a.dtype
    S = int(edge_samples)
    pick, G = _subset(S, subset)
    C = len(pick)
    t_all = jnp.arange(S, dtype=dtype) / (S - 1)  # the rule's own parameters (_edges_dense)
    t_pick = t_all[pick]
    gap_t = jnp.asarray(np.diff(pick) / (S - 1), dtype)
    table = _clearance_table(blocked) if table is None else table
    want = jnp.ones(E, bool) if mask is None else jnp.broadcast_to(mask, shape).reshape(-1)
    # Long edges: a sparser subset's discs first (table reads only, no work lists). In open
    # space they cover most edges whole, and only the rest go through the work lists below;
    # on short edges the work lists cost little and the extra reads do not pay.
    if C >= _SPARSE_FROM:
        sparse = _sparse_subset(pick)
        t_sp = t_all[sparse]
        gap_sp = jnp.asarray(np.diff(sparse) / (S - 1), dtype)
        settled = _covered_whole(table, fa, fb, grid, t_sp, gap_sp) & want
    else:
        settled = jnp.zeros(E, bool)
    todo = want & ~settled
    F = min(int(chunk), E)
    order, place = _compact(todo, F)  # order[p]: the p-th edge to check
    n_todo = jnp.sum(todo)

    def coarse(i, carry):
        clear, unc = carry
        ids = jax.lax.dynamic_slice(order, (i * F,), (F,))
        j = jnp.minimum(ids, E - 1)
        hit, covered = _subset_pass(blocked, table, fa[j], fb[j], grid, t_pick, gap_t)
        live = (ids < E)[:, None]
        clear = jax.lax.dynamic_update_slice(clear, ~hit, (i * F,))
        unc = jax.lax.dynamic_update_slice(unc, ~covered & ~hit[:, None] & live, (i * F, 0))
        return clear, unc

    # Results in the compact order p (E + F rows: the last chunk may run past E).
    init = (jnp.zeros(E + F, bool), jnp.zeros((E + F, C - 1), bool))
    clear, unc = jax.lax.fori_loop(0, (n_todo + F - 1) // F, coarse, init)
    # Uncovered intervals: the rule's G + 1 samples from one subset sample to the next.
    has = jnp.any(unc, axis=1)
    Fe = min(int(chunk), E + F)
    grazing, _ = _compact(has, Fe)  # compact positions p of edges with an uncovered interval
    I = Fe * (C - 1)
    F2 = min(int(chunk), I)
    pick_j = jnp.asarray(pick[:-1], jnp.int32)
    step = jnp.arange(G + 1, dtype=jnp.int32)

    def outer(i, bad):
        ps = jax.lax.dynamic_slice(grazing, (i * Fe,), (Fe,))  # (Fe,) compact positions
        u = unc[jnp.minimum(ps, E + F - 1)] & (ps < E + F)[:, None]
        intervals, _ = _compact(u.reshape(-1), F2)
        ps_pad = jnp.concatenate([ps, jnp.full((1,), E + F, ps.dtype)])

        def inner(t, bad):
            q = jax.lax.dynamic_slice(intervals, (t * F2,), (F2,))
            p = ps_pad[q // (C - 1)]  # E + F for padding: dropped below
            e = order[jnp.minimum(p, E + F - 1)]
            j = jnp.minimum(e, E - 1)
            idx = jnp.minimum(pick_j[q % (C - 1)][:, None] + step, S - 1)  # (F2, G + 1)
            pa, pb = fa[j], fb[j]
            along = pa[:, None, :] + t_all[idx][..., None] * (pb - pa)[:, None, :]
            ok = _samples_clear(blocked, along, grid)
            return bad.at[p].max(~ok, mode="drop")

        return jax.lax.fori_loop(0, (jnp.sum(u) + F2 - 1) // F2, inner, bad)

    bad = jax.lax.fori_loop(0, (jnp.sum(has) + Fe - 1) // Fe, outer, jnp.zeros(E + F, bool))
    ok = clear & ~bad
    return (settled | (todo & ok[jnp.clip(place, 0, E + F - 1)])).reshape(shape)


#: :func:`_edges_clear` first reads every this-many-th sample of its subset (and the last) in
#: the clearance table alone, on subsets of at least ``_SPARSE_FROM`` samples (edges of about
#: 6.5 m and more on 0.1 m cells; ``benchmarks/lsd/HISTORY.md``): an edge whose discs there
#: overlap end to end is clear.
_SPARSE_STEP, _SPARSE_FROM = 4, 17


def _sparse_subset(pick: np.ndarray) -> np.ndarray:
    """The samples of the sparse first pass: every ``_SPARSE_STEP``-th of the subset ``pick``
    (:func:`_subset`), and its last (the edge's end)."""
    sparse = pick[::_SPARSE_STEP]
    return sparse if sparse[-1] == pick[-1] else np.append(sparse, pick[-1])


def _covered_whole(table, pa, pb, grid, t, gap_t):
    """(E,) edges pa -> pb (E, 2) whose clearance discs at the samples ``t`` (C,) overlap
    along the whole edge (consecutive ones ``gap_t`` apart, in edge parameter): every cell the
    edge rule reads (samples and diagonal side cells) is then free, so the edge is clear."""
    dtype = pa.dtype
    along = pa[:, None, :] + t[:, None] * (pb - pa)[:, None, :]
    er, ec, eon = _cells(along, grid)
    lo = (_read(table, er >> _BASE, ec >> _BASE).astype(dtype) - 1e-3) * grid.resolution.astype(dtype)
    lo = jnp.where(eon, lo, -1.0)
    return jnp.all(lo[:, :-1] + lo[:, 1:] > _length(pa, pb)[:, None] * gap_t, axis=1)


def _coarse(blocked, fa, fb, grid, edge_samples, todo, *, subset, table):
    """The first pass of :func:`_edges_clear` over every edge a -> b (E, 2) at once (the same
    expressions, the same values): ``hit`` (E,), a subset sample in a blocked or off-map cell,
    and ``unc`` (E, C - 1), the intervals between subset samples that the table does not vouch
    for, on the edges ``todo`` (E,) not hit. An edge is clear when it is not hit and every
    sample of its uncovered intervals passes (:func:`_intervals_clear`). For a few edges (a
    query's) this pass and a host list of the uncovered intervals cost far less than the work
    lists' loops, whose every step compacts every interval."""
    dtype = fa.dtype
    S = int(edge_samples)
    pick, _ = _subset(S, subset)
    t_all = jnp.arange(S, dtype=dtype) / (S - 1)  # the rule's own parameters (_edges_dense)
    t_pick = t_all[pick]
    gap_t = jnp.asarray(np.diff(pick) / (S - 1), dtype)
    hit, covered = _subset_pass(blocked, table, fa, fb, grid, t_pick, gap_t)
    return hit, ~covered & ~hit[:, None] & todo[:, None]


def _subset_pass(blocked, table, pa, pb, grid, t_pick, gap_t):
    """The subset samples ``t_pick`` (C,) of edges pa -> pb (E, 2): ``hit`` (E,), one in a
    blocked or off-map cell, and ``covered`` (E, C - 1), the intervals between them (``gap_t``
    long, in edge parameter) whose ends' clearances (``table``) vouch for every cell between."""
    dtype = pa.dtype
    along = pa[:, None, :] + t_pick[:, None] * (pb - pa)[:, None, :]  # (E, C, 2)
    er, ec, eon = _cells(along, grid)
    hit = jnp.any(~eon | _read(blocked, er, ec), axis=-1)
    lo = (_read(table, er >> _BASE, ec >> _BASE).astype(dtype) - 1e-3) * grid.resolution.astype(dtype)
    lo = jnp.where(eon, lo, -1.0)
    return hit, lo[:, :-1] + lo[:, 1:] > _length(pa, pb)[:, None] * gap_t


def _intervals_clear(blocked, fa, fb, edge, interval, grid, edge_samples, *, subset):
    """The rule's samples of the intervals ``interval`` (U,) of the edges ``edge`` (U,) (indices
    into a -> b (E, 2), :func:`_coarse`'s intervals), read as the inner loop of
    :func:`_edges_clear` reads them: (U,) each interval clear."""
    S = int(edge_samples)
    pick, G = _subset(S, subset)
    t_all = jnp.arange(S, dtype=fa.dtype) / (S - 1)
    idx = jnp.minimum(jnp.asarray(pick[:-1], jnp.int32)[interval][:, None] + jnp.arange(G + 1, dtype=jnp.int32), S - 1)
    pa, pb = fa[edge], fb[edge]
    return _samples_clear(blocked, pa[:, None, :] + t_all[idx][..., None] * (pb - pa)[:, None, :], grid)


@functools.partial(jax.jit, static_argnames=("edge_samples",))
def _segments_clear(blocked, a, b, grid, *, edge_samples):
    # A polyline has a few segments: every sample read (the same rule as the fast check) costs
    # less than the fast check's clearance table over the whole map. An int8 partial map is
    # read as its OCCUPIED cells (only where the samples fall).
    if blocked.dtype != jnp.bool_:
        blocked = blocked == OCCUPIED
    clear, _, _ = _edges_dense(blocked, a, b, grid, edge_samples)
    return jnp.all(clear)


#: The fewest segments of each kind :func:`polyline_clear` checks in one call (the rest padding).
_LEAST_SHORT, _LEAST_LONG = 8, 2


def polyline_clear(points, blocked, grid: GridLike, radius: float, dtype=None, reach: float | None = None) -> bool:
    """True when every segment of the polyline ``points`` (K, 2) passes the roadmap's own edge
    check on the bool grid ``blocked``: the same samples as the PRM used for an edge of that
    length (segments up to ``radius``: the roadmap's; longer ones, a query's start or goal
    edges: :func:`query_reach`'s), same precision ``dtype``, so a plan the PRM found clear is
    never judged blocked on the same map (a looser or stricter second test made robots stand
    still, replanning the same path). ``blocked`` may also be an int8 partial map (its OCCUPIED
    cells block, as in the PRM); a JAX array stays on the device (the navigation loop checks
    its plan every step against a map of millions of cells: no copy of it is made).
    ``grid``: the :class:`jaxsem.quadrics.Grid` of ``blocked`` (or a map holding one);
    ``reach``: the PRM's (:class:`~jaxsem.planning.PRM`; None: :func:`query_reach` of the grid)."""
    if isinstance(blocked, jax.Array):
        blocked_j = blocked
    else:
        blocked = np.asarray(blocked)
        blocked_j = jnp.asarray(blocked)
    if blocked_j.ndim != 2 or blocked_j.dtype not in (jnp.bool_, jnp.int8):
        raise ValueError(
            f"blocked: expected a (H, W) bool grid or int8 partial map, got shape {tuple(blocked_j.shape)} "
            f"dtype {blocked_j.dtype}"
        )
    shape = tuple(blocked_j.shape)
    grid = host_grid("grid", grid, shape)
    resolution = float(grid.resolution)
    pts = np.asarray(points, np.float64)
    if len(pts) < 2:
        return True
    dtype = dtype or jnp.result_type(float)
    a, b = pts[:-1], pts[1:]
    length = np.linalg.norm(b - a, axis=1)
    short = length <= radius * (1 + 1e-6)
    reach = query_reach(shape, resolution) if reach is None else float(reach)
    grid_j = _device_grid(static_grid(grid), jnp.dtype(dtype))
    long_reach = max(reach, 2.0 ** math.ceil(math.log2(max(length.max(), 1e-9))))
    for sel, r, least in ((short, radius, _LEAST_SHORT), (~short, long_reach, _LEAST_LONG)):
        if not sel.any():
            continue
        aa, bb = a[sel], b[sel]
        # Padded to a power of two, at least ``least``: a plan's segments of either kind share a
        # few programs (a plan holds tens of short ones, its start and goal links the long ones).
        m = max(least, 1 << max(0, (len(aa) - 1).bit_length()))
        aa = np.concatenate([aa, np.repeat(bb[-1:], m - len(aa), 0)])
        bb = np.concatenate([bb, np.repeat(bb[-1:], m - len(bb), 0)])
        # numpy arrays of the step's dtype go in as they are: no conversion dispatched per step.
        ok = _segments_clear(
            blocked_j,
            np.asarray(aa, dtype),
            np.asarray(bb, dtype),
            grid_j,
            edge_samples=_edge_samples(r, resolution),
        )
        if not bool(ok):
            return False
    return True


@functools.lru_cache(maxsize=16)
def _device_grid(grid: Q.Grid, dtype) -> Q.Grid:
    """:func:`_grid` of a :func:`static_grid`, kept: the navigation loop checks its plan on the
    same grid every step."""
    return _grid(grid, dtype)


def query_reach(shape, resolution: float) -> float:
    """Longest query edge (m): the map's diagonal rounded up to a power of two. A query's start
    and goal link to samples at any distance on the map; such edges are checked with samples at
    most half a cell apart over this length (and so are long plan segments,
    :func:`polyline_clear`)."""
    diag = math.hypot(shape[0] * resolution, shape[1] * resolution)
    return 2.0 ** math.ceil(math.log2(max(diag, resolution)))


#: The probe of :func:`_host_rule`: edges over a few kilometres (float32 samples a few
#: hundredths of a millimetre apart), an origin and a resolution that are not powers of two.
_PROBE_GRID = Q.Grid.host((-1234.5, 987.6), 0.05, (1 << 16, 1 << 16))
_PROBE_SAMPLES, _PROBE_EDGES = 257, 64


@functools.partial(jax.jit, static_argnames=("grid", "edge_samples"))
def _rule_cells(a, b, grid, *, edge_samples):
    """The cells (..., S, 2), not clipped, of the samples :func:`_edges_dense` reads."""
    grid = _grid(grid, a.dtype)
    return Q.world_to_cell(_along(a, b, edge_samples), grid.origin, grid.resolution)


@functools.cache
def _host_rule():
    """``(kernels, fused, recip)``: the compiled host edge rule's module and the arithmetic that makes
    its float32 samples fall in the cells the device's rule reads, or None when none of the four
    ways agrees with the device on the probe (callers then use the device's rule).

    A float32 sample may fall on either side of a cell border depending on whether ``a + t *
    (b - a)`` is rounded once or twice and on whether the division by the resolution became a
    multiplication by its reciprocal; the compiled rule's choice is its compiler's. The probe
    draws edges whose cells differ between the ways, reads the device's cells for them, and
    keeps the way that matches every one."""
    from . import _edges_kernels as k

    g = _PROBE_GRID
    S = _PROBE_SAMPLES
    origin = np.asarray(g.origin, np.float32)
    res = np.float32(g.resolution)
    inv = np.float32(1) / res
    rng = np.random.default_rng(0)
    a = (origin + rng.uniform(0, 3000, (4096, 2))).astype(np.float32)
    b = (a + rng.normal(0, 50, (4096, 2))).astype(np.float32)
    ways = [(f, r) for f in (True, False) for r in (True, False)]
    cells = [k.sample_cells(a, b, S, origin, inv, res, f, r) for f, r in ways]
    # Edges that tell each pair of ways apart, a few per pair.
    pick = []
    for i in range(len(ways)):
        for j in range(i + 1, len(ways)):
            d = np.any((cells[i][0] != cells[j][0]) | (cells[i][1] != cells[j][1]), axis=1)
            pick.extend(np.flatnonzero(d)[:8])
    n = _PROBE_EDGES
    pick = np.concatenate([np.unique(np.asarray(pick, np.int64)), np.arange(n)])[:n]  # fixed width
    rc = np.asarray(_rule_cells(a[pick], b[pick], static_grid(g), edge_samples=S))
    for (f, r), (rows, cols) in zip(ways, cells):
        if np.array_equal(rows[pick], rc[..., 0]) and np.array_equal(cols[pick], rc[..., 1]):
            return k, f, r
    return None


def _host_edges(dtype) -> bool:
    """Whether the edges of points of ``dtype`` are checked on the host: float32 points (a
    float64 sample's single rounding is not emulated), where :func:`_host_rule` matched the
    device's arithmetic."""
    return np.dtype(dtype) == np.float32 and _host_rule() is not None


def _edges_clear_host(blocked, a, b, samples, want, grid, table=None, *, row=None, k=None, bits=None):
    """The edge rule of :func:`_edges_dense` on the host for float32 edges ``a`` -> ``b``
    (E, 2) with ``samples`` (E,) samples each (:func:`_edge_samples`), on the numpy bool grid
    ``blocked`` of the host ``grid``: (E,) bool, False where ``want`` (E,) is not set. The same
    answers as the device's rule, read from the start of each edge and skipping what the
    clearance ``table`` (:func:`_clearance_table`, numpy; None: none) vouches for. ``row``,
    ``k``: the edges come in rows of ``row`` in preference order, of which the caller keeps the
    first ``k`` clear ones: the rest are not read (False). ``bits``: :func:`_bit_grids` of
    ``blocked`` (the per-map setup's), or None: every edge read by samples (a few edges on a
    map seen once cost less so than the bits). Only where :func:`_host_edges`."""
    kernels, consts = _host_call(grid)
    row = 1 if row is None else int(row)  # each edge a row of its own: every wanted one read
    k = 1 if k is None else int(k)
    grids = _host_grids(blocked, table, bits)
    a, b = np.ascontiguousarray(a, np.float32), np.ascontiguousarray(b, np.float32)
    samples, want = np.ascontiguousarray(samples, np.int64), np.ascontiguousarray(want, bool)
    E = len(a)

    def run(r0: int, r1: int) -> np.ndarray:
        e0, e1 = r0 * row, min(E, r1 * row)
        return kernels.edges_clear(*grids, a[e0:e1], b[e0:e1], samples[e0:e1], want[e0:e1], *consts, row, k)

    return np.concatenate(_in_blocks(-(-E // row), E, run))


def _first_clear_host(blocked, pts, cand, s0: int, k: int, samples: int, grid, table, bits=None):
    """Each row of ``cand`` (n, K) (the candidates of vertices ``s0 ..`` in preference order,
    ``len(pts)`` where none) read on the host until ``k`` edges from the vertex are clear (the
    rule with ``samples`` samples, :func:`_edges_clear_host`; ``pts`` (M, 2) float32): the
    eager grow's first ``k`` clear candidates, as (neighbours (n, k), valid, weights: the edges'
    lengths). ``bits``: :func:`_bit_grids` of ``blocked`` (the per-map setup's; made here if
    None). Only where :func:`_host_edges`."""
    from ._astar_kernels import z_order

    kernels, consts = _host_call(grid)
    grids = _host_grids(blocked, table, _bit_grids(blocked) if bits is None else bits)
    pts = np.ascontiguousarray(pts, np.float32)
    n, M = len(cand), len(pts)
    # The rows in Z-order of their vertices: a row's second pass reads the rows of its nearby
    # vertices, and those lie near it in memory.
    vert = z_order(np.asarray(pts[s0 : s0 + n], np.float64), 0)
    row_of = np.empty(n, np.int64)
    row_of[vert] = np.arange(n)
    cand = np.ascontiguousarray(np.asarray(cand, np.int32)[vert])
    vert += s0
    # An edge between two new vertices is read once where its reversal reads the same cells: a
    # first pass over every row, then a second (:func:`first_clear_pairs`).
    state = np.zeros(cand.shape, np.uint8)
    out = (np.full((n, k), M, np.int32), np.zeros((n, k), bool), np.full((n, k), np.inf, np.float32))
    # Each thread takes every W-th run of 64 rows, not one contiguous block (the first pass of
    # a row reads more edges the later its vertex).
    perm = np.argsort((np.arange(n) // 64) % _workers(), kind="stable")
    for second in (False, True):

        def run(r0: int, r1: int, second=second):
            kernels.first_clear_pairs(
                *grids, pts, cand, vert, row_of, s0, int(k), int(samples), *consts, perm[r0:r1], state, out, second
            )

        _in_blocks(n, cand.size, run)
    return out


def _host_call(grid):
    """The host rule's kernels module and its constants on the host ``grid``: (origin, the
    float32 reciprocal of the resolution, the resolution, fused, recip) (:func:`_host_rule`)."""
    rule = _host_rule()
    assert rule is not None  # internal: callers check _host_edges first
    _, fused, recip = rule
    from . import _edges_kernels

    res = np.float32(grid.resolution)
    return _edges_kernels, (np.asarray(grid.origin, np.float32), np.float32(1) / res, res, fused, recip)


def _host_grids(blocked, table, bits=None):
    """(blocked, table, its block level, the grid's rows and columns as bits, its box sums) as
    the kernels read them (table None: none; ``bits``: :func:`_bit_grids` of ``blocked``, or
    None: empty, every edge read by samples)."""
    tab = np.zeros((0, 0), np.int32) if table is None else np.ascontiguousarray(table, np.int32)
    none = np.zeros((0, 0), np.uint64)
    rows, cols, sums = (none, none, np.zeros((0, 0), np.uint16)) if bits is None else bits
    return np.ascontiguousarray(blocked, bool), tab, _BASE, rows, cols, sums


def _bit_grids(blocked) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bool grid ``blocked`` (H, W) as the host rule reads it by lines and boxes: its rows
    as bits (H + 2, ceil((W + 2) / 64)) uint64, bit ``c + 1`` of word row ``r + 1`` set where
    cell (r, c) is blocked, and the cells around the map set (off the map counts as blocked);
    its columns (W + 2, ceil((H + 2) / 64)) so; and its blocked cells counted over boxes
    (:func:`~jaxsem.planning._edges_kernels.box_sums`: an edge whose box of cells holds none
    is clear without a read). Per-map setup (:class:`~jaxsem.planning._map_setup._MapSetup`)."""
    from ._edges_kernels import box_sums

    blocked = np.asarray(blocked, bool)
    H, W = blocked.shape

    def bits(g: np.ndarray) -> np.ndarray:
        h, w = g.shape
        padded = np.zeros((h, -(-w // 64) * 64), bool)
        padded[:, :w] = g
        return np.ascontiguousarray(np.packbits(padded, axis=1, bitorder="little").view("<u8"), np.uint64)

    g = np.ones((H + 2, W + 2), bool)
    g[1:-1, 1:-1] = blocked
    return bits(g), bits(np.ascontiguousarray(g.T)), box_sums(np.ascontiguousarray(blocked))


def _in_blocks(rows: int, edges: int, run) -> list:
    """``run(r0, r1)`` over ``rows`` rows: in one call, or, from :data:`_THREADS_FROM` ``edges``,
    in blocks of rows on threads (the kernels release the GIL). Returns the results in order."""
    blocks = _blocks(rows, _workers() if edges >= _THREADS_FROM else 1)
    return _each_block(blocks, lambda t, r0, r1: run(r0, r1))


def _blocks(rows: int, parts: int) -> list[tuple[int, int]]:
    """``rows`` rows cut into at most ``parts`` blocks ``[r0, r1)`` of nearly equal size."""
    cut = [rows * i // parts for i in range(parts + 1)]
    return [(r0, r1) for r0, r1 in zip(cut[:-1], cut[1:], strict=True) if r1 > r0] or [(0, rows)]


def _each_block(blocks: list[tuple[int, int]], run) -> list:
    """``run(t, r0, r1)`` for each block ``t`` = [r0, r1): in this thread for one block, else on
    the host rule's threads (the kernels release the GIL). Returns the results in order."""
    if len(blocks) == 1:
        return [run(0, *blocks[0])]
    return [job.result() for job in [_pool().submit(run, t, r0, r1) for t, (r0, r1) in enumerate(blocks)]]


#: Edges from which the host rule spreads its rows over threads (a grow's thousands; a query's
#: hundred read on one: waking threads costs more than they save).
_THREADS_FROM = 4096


def _workers() -> int:
    """Threads for the host rule: the processors this process may use, at most 8."""
    return max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


@functools.cache
def _pool_of(pid: int) -> concurrent.futures.ThreadPoolExecutor:
    del pid  # the key: a forked child makes its own (its parent's threads are not in it)
    return concurrent.futures.ThreadPoolExecutor(_workers(), thread_name_prefix="jaxsem-edges")


def _pool() -> concurrent.futures.ThreadPoolExecutor:
    """This process's thread pool for the host rule's blocks of rows."""
    return _pool_of(os.getpid())

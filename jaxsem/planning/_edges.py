"""The PRM's edge check on a grid: samples at most half a cell apart, both side cells of a
diagonal step, most edges decided from a few reads through a clearance table (see
:mod:`jaxsem.planning._roadmap`).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np


def _edge_samples(radius: float, resolution: float) -> int:
    return max(2, int(math.ceil(radius / (0.5 * resolution))) + 1)


def _cells(points, origin, resolution, shape):
    H, W = shape
    cr = jnp.floor((points - origin) / resolution).astype(jnp.int32)
    on = (cr[..., 0] >= 0) & (cr[..., 0] < W) & (cr[..., 1] >= 0) & (cr[..., 1] < H)
    return jnp.clip(cr[..., 1], 0, H - 1), jnp.clip(cr[..., 0], 0, W - 1), on


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


def query_reach(shape, resolution: float) -> float:
    """Longest query edge (m): the map's diagonal rounded up to a power of two. A query's start
    and goal link to samples at any distance on the map; such edges are checked with samples at
    most half a cell apart over this length (and so are long plan segments,
    :func:`polyline_clear`)."""
    diag = math.hypot(shape[0] * resolution, shape[1] * resolution)
    return 2.0 ** math.ceil(math.log2(max(diag, resolution)))

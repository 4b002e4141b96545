"""Exact neighbour search of the PRM: buckets of the connection radius, the direction-first
connection policy (sectors), brute force where buckets would not pay (see
:mod:`jaxsem.planning._roadmap` for the policy).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ._edges import _in_blocks


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


def _count_before(key, groups, cols: int = 32):
    """For each entry i of each row of ``key`` (Q, C): how many entries j of the same row come
    before it, (key_j, j) < (key_i, i), within each bool mask of ``groups`` (a list of (Q, C, C)
    -> bool callables on (i, j) blocks; None: all j). Blocks of ``cols`` columns keep XLA's CPU
    reduction fast (a single (Q, C, C) reduction is 20x slower at C = 64)."""
    Q, C = key.shape
    idx = jnp.arange(C, dtype=jnp.int32)
    out = [jnp.zeros((Q, C), jnp.int32) for _ in groups]
    for s in range(0, C, cols):
        kj, ij = key[:, None, s : s + cols], idx[None, None, s : s + cols]
        ki, ii = key[:, :, None], idx[None, :, None]
        before = (kj < ki) | ((kj == ki) & (ij < ii))
        for g, grp in enumerate(groups):
            m = before if grp is None else before & grp(slice(s, s + cols))
            out[g] = out[g] + jnp.sum(m, -1, dtype=jnp.int32)
    return out


def _select_ranked(d2, diff, k: int, sectors: int, keep: int, sparser=None):
    """:func:`_select` (the same candidates in the same order) by counting, not sorting: each
    candidate's rank is the number of candidates before it, and XLA's CPU sort and wide top_k
    cost 10-20x more than the counts on rows of up to ~128 candidates. Returns (Q, keep)
    candidate positions (C where none) in preference order."""
    Q, C = d2.shape
    kk = min(keep, C)
    fin = jnp.isfinite(d2)
    if sectors:
        m = min(_per_sector(k, sectors), C)
        ang = jnp.arctan2(diff[..., 1], diff[..., 0])
        sec = jnp.clip(jnp.floor((ang + math.pi) * (sectors / (2 * math.pi))).astype(jnp.int32), 0, sectors - 1)
        groups = [lambda j: sec[:, None, j] == sec[:, :, None]]
        if sparser is not None:
            groups.append(lambda j: sparser[:, None, j])
        counts = _count_before(d2, groups)
        prio = fin & (counts[0] < m)
        if sparser is not None:
            prio = prio | (fin & sparser & (counts[1] < min(2 * m, C)))
        span = jnp.max(jnp.where(fin, d2, 0.0), axis=1, keepdims=True) + 1.0
        key = jnp.where(prio, d2, d2 + span)
    else:
        key = d2
    (rank,) = _count_before(key, [None])
    rows = jnp.broadcast_to(jnp.arange(Q)[:, None], (Q, C))
    col = jnp.broadcast_to(jnp.arange(C, dtype=jnp.int32)[None, :], (Q, C))
    rank = jnp.where(jnp.isfinite(key) & (rank < kk), rank, kk)
    return jnp.full((Q, kk), C, jnp.int32).at[rows, rank].set(col, mode="drop")


#: Widest candidate rows ranked by counting (:func:`_select_ranked`); wider ones use top_k.
_RANKED_MAX = 128

#: Widths a brute-force candidate row is narrowed to when its candidates within the radius fit
#: (:func:`_knn_rows`): the narrowest that holds every row of a block.
_NARROW = (32, 64, _RANKED_MAX)

#: Rows of a brute-force search ranked together, sorted by their candidates within the radius.
_SORTED_ROWS = 128


#: Query rows searched at a time: the candidate arrays of a block (rows x 3 strips x slots)
#: stay in cache, where all rows at once do not (``benchmarks/lsd/HISTORY.md``, "PRM on the
#: campus map against OMPL's C++ PRM").
_ROWS = 512


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
    narrow: bool = True,
):
    """k nearest ``db_ok`` points of ``db`` (M, 2) within ``radius`` of each query (Q, 2),
    excluding index ``q_self`` (Q,) (-1: none). Returns ((Q, k) indices, ``M`` where fewer;
    overflow). ``cap=None``: brute force. Local coordinates in [0, extent). Rows are searched
    ``_ROWS`` at a time (each row's answer depends only on the row). ``narrow``: a brute-force
    search ranks wide rows in the narrowest width that holds their candidates, chosen by a
    switch (:func:`_knn_rows`); a vmapped caller passes False (under ``vmap`` a switch runs
    every branch), ranking the whole width (the same answers)."""
    M = db.shape[0]
    Q = queries.shape[0]
    grid = None
    if not (cap is None or 3 * cap >= M):
        grid = (*_grid_dims(radius, extent), *_knn_grid(db, db_ok, radius, extent))
    rows = functools.partial(
        _knn_rows,
        db,
        db_ok,
        k=k,
        radius=radius,
        cap=cap,
        sectors=sectors,
        keep=keep,
        density=density,
        grid=grid,
        narrow=narrow,
    )
    if Q <= _ROWS:
        return rows(queries, q_self)
    n_blocks = -(-Q // _ROWS)
    pad = n_blocks * _ROWS - Q
    # Padding repeats the last row (a real query: it cannot raise a false overflow).
    qp = jnp.concatenate([queries, jnp.broadcast_to(queries[-1:], (pad, 2))]).reshape(n_blocks, _ROWS, 2)
    sp = jnp.concatenate([q_self, jnp.broadcast_to(q_self[-1:], (pad,))]).reshape(n_blocks, _ROWS)
    idx, overflow = jax.lax.map(lambda a: rows(*a), (qp, sp))
    return idx.reshape(n_blocks * _ROWS, -1)[:Q], jnp.any(overflow)


def _grid_dims(radius: float, extent) -> tuple[int, int]:
    """Buckets (gx, gy) of side ``radius`` over the local extent."""
    return max(1, int(math.ceil(extent[0] / radius))), max(1, int(math.ceil(extent[1] / radius)))


def _knn_grid(db, db_ok, radius: float, extent):
    """The bucketed search's (order, sorted bucket ids): ``db``'s points in bucket order (ties in
    index order), unusable ones last."""
    bid = _bucket_ids(db, db_ok, radius, extent)
    order = jnp.argsort(bid)
    return order, bid[order]


def _bucket_ids(db, db_ok, radius: float, extent):
    """Each point's bucket id ``by * gx + bx``; unusable points ``gx * gy``, a bucket never read."""
    gx, gy = _grid_dims(radius, extent)
    bx, by = _bucket(db, radius, gx, gy)
    return jnp.where(db_ok, by * gx + bx, gx * gy)


def _host_buckets(db, radius: float, extent):
    """:func:`_bucket` of the numpy points ``db`` (M, 2) on the host, in their dtype: (bx, by,
    gx, gy); the device's but where a point lies within a rounding of a bucket's edge."""
    gx, gy = _grid_dims(radius, extent)
    cell = np.floor(db / db.dtype.type(radius)).astype(np.int64)
    return np.clip(cell[:, 0], 0, gx - 1), np.clip(cell[:, 1], 0, gy - 1), gx, gy


def _host_order(db, db_ok, radius: float, extent) -> np.ndarray:
    """:func:`_knn_grid`'s bucket order of ``db`` (M, 2) as the host computes it (int32): a
    guess the device checks (:func:`_host_buckets`)."""
    bx, by, gx, gy = _host_buckets(db, radius, extent)
    bid = np.where(db_ok, by * gx + bx, gx * gy)
    return np.argsort(bid, kind="stable").astype(np.int32)


def _bucket(p, radius: float, gx: int, gy: int):
    b = jnp.floor(p / radius).astype(jnp.int32)
    return jnp.clip(b[:, 0], 0, gx - 1), jnp.clip(b[:, 1], 0, gy - 1)


def _knn_rows(db, db_ok, queries, q_self, *, k, radius, cap, sectors, keep, density, grid, narrow=True):
    """:func:`_knn` on one block of query rows; ``grid``: (gx, gy, bucket order, sorted bucket
    ids) of the bucketed search, None for brute force."""
    M = db.shape[0]
    Q = queries.shape[0]
    if grid is None:
        cand = jnp.broadcast_to(jnp.arange(M)[None, :], (Q, M))
        ok = jnp.broadcast_to(db_ok[None, :], (Q, M))
        overflow = jnp.zeros((), bool)
    else:
        gx, gy, order, sorted_bid = grid
        # The 3 x 3 buckets around a query are 3 strips of 3 buckets, each contiguous in the
        # bucket order: read ``cap`` slots per strip.
        qx, qy = _bucket(queries, radius, gx, gy)
        ny = qy[:, None] + jnp.arange(-1, 2, dtype=jnp.int32)[None, :]  # (Q, 3)
        inside = (ny >= 0) & (ny < gy)
        lo = ny * gx + jnp.maximum(qx - 1, 0)[:, None]
        hi = ny * gx + jnp.minimum(qx + 1, gx - 1)[:, None]
        start = jnp.searchsorted(sorted_bid, lo, side="left")
        count = jnp.where(inside, jnp.searchsorted(sorted_bid, hi, side="right") - start, 0)
        overflow = jnp.max(count) > cap
        j = jnp.arange(cap, dtype=start.dtype)
        slot = start[..., None] + j  # (Q, 3, cap)
        ok = (j < count[..., None]).reshape(Q, -1)
        cand = order[jnp.clip(slot, 0, M - 1)].reshape(Q, -1)
    want = keep or k
    kw = dict(k=k, radius=radius, sectors=sectors, want=want, density=density)
    if grid is not None:
        # Keep the candidates within the radius (about pi/3 of a strip's): at most ``cap`` of
        # them, a row with more is an overflow too (rerun with more slots).
        idx, most = _rank_rows(db, queries, q_self, cand, ok, width=cap, **kw)
        return idx, overflow | (most > cap)
    if M <= _RANKED_MAX or want > _RANKED_MAX or not narrow:
        return _rank_rows(db, queries, q_self, cand, ok, width=None, **kw)[0], overflow

    # Brute force over more slots than rank by counting: a row usually holds far fewer
    # candidates within the radius. They rank by counting (the same candidates in the same
    # order) in a row of the narrowest width of _NARROW that holds the fullest row of its
    # block (counting costs the width squared); a block with a row of more than _RANKED_MAX
    # ranks the whole width by top_k (an order of magnitude dearer on the CPU). The rows go
    # in blocks of _SORTED_ROWS sorted by their counts, so a dense cluster's few full rows
    # set the width of their own block only. Each branch makes its candidates from its
    # inputs: handed wide arrays made outside, a branch costs more.
    def brute(width, qb, sb):
        slots = jnp.broadcast_to(jnp.arange(M)[None, :], (qb.shape[0], M))
        ok_b = jnp.broadcast_to(db_ok[None, :], slots.shape)
        return _rank_rows(db, qb, sb, slots, ok_b, width=width, **kw)[0]

    # Each row's count, over-counted at the border: the ranking's own distances may round
    # otherwise (fused differently), and a width that holds more costs only time.
    d2 = jnp.sum((db[None, :, :] - queries[:, None, :]) ** 2, -1)
    near = d2 <= radius**2 * (1 + _BORDER)
    inr = db_ok[None, :] & (jnp.arange(M, dtype=q_self.dtype)[None, :] != q_self[:, None]) & near
    counts = jnp.sum(inr, axis=1, dtype=jnp.int32)
    widths = jnp.asarray(_NARROW, jnp.int32)
    branches = [functools.partial(brute, w) for w in _NARROW] + [functools.partial(brute, None)]

    def block(args):
        qb, sb, cb = args
        return jax.lax.switch(jnp.sum(jnp.max(cb) > widths), branches, qb, sb)

    B = _SORTED_ROWS
    if Q <= B:
        return block((queries, q_self, counts)), overflow
    order = jnp.argsort(counts)
    n_blocks = -(-Q // B)
    pad = jnp.concatenate([order, jnp.broadcast_to(order[-1:], (n_blocks * B - Q,))]).reshape(n_blocks, B)
    got = jax.lax.map(block, (queries[pad], q_self[pad], counts[pad]))
    idx = jnp.zeros((Q, want), got.dtype).at[order].set(got.reshape(n_blocks * B, want)[:Q])
    return idx, overflow


def _rank_rows(db, queries, q_self, cand, ok, *, k, radius, sectors, want, density, width):
    """The chosen candidates (Q, want) (``M``: none) among the slots ``cand`` (Q, C) where ``ok``
    of each query row, and the fullest row's count of candidates within the radius. ``width``:
    first move each row's candidates within the radius to its first ``width`` columns (in
    order; a row with more loses the rest: the caller checks the count); None: rank the C
    slots as they are."""
    M = db.shape[0]
    Q = queries.shape[0]
    ok = ok & (cand != q_self.astype(cand.dtype)[:, None])
    diff = db[cand] - queries[:, None, :]
    d2 = jnp.sum(diff**2, -1)
    d2 = jnp.where(ok & (d2 <= radius**2), d2, jnp.inf)
    sparser = None
    if density is not None:  # (M,) sampling density of db points; queries are db[q_self]
        sparser = density[cand] <= density[jnp.maximum(q_self, 0)][:, None] * 1.001
    most = jnp.zeros((), jnp.int32)
    if width is not None:
        inr = jnp.isfinite(d2)
        pos = jax.lax.associative_scan(jnp.add, inr.astype(jnp.int32), axis=1) - 1
        most = jnp.max(pos[:, -1]) + 1
        rows = jnp.broadcast_to(jnp.arange(Q)[:, None], inr.shape)
        C0 = cand.shape[1]
        col = (
            jnp.full((Q, width), C0, jnp.int32)
            .at[rows, jnp.where(inr, pos, width)]
            .set(jnp.broadcast_to(jnp.arange(C0, dtype=jnp.int32)[None, :], inr.shape), mode="drop")
        )
        live = col < C0
        col = jnp.minimum(col, C0 - 1)
        cand = jnp.take_along_axis(cand, col, axis=1)
        d2 = jnp.where(live, jnp.take_along_axis(d2, col, axis=1), jnp.inf)
        diff = jnp.take_along_axis(diff, col[..., None], axis=1)
        if sparser is not None:
            sparser = jnp.take_along_axis(sparser, col, axis=1)
    kk = min(want, cand.shape[1])
    if cand.shape[1] <= _RANKED_MAX:
        pos = _select_ranked(d2, diff, k, sectors, want, sparser)
        fin = pos < cand.shape[1]
        pos = jnp.minimum(pos, cand.shape[1] - 1)
    else:
        pos, fin = _select(d2, diff, k, sectors, want, sparser)
    idx = jnp.where(fin, jnp.take_along_axis(cand, pos, axis=1), M)
    if kk < want:
        idx = jnp.concatenate([idx, jnp.full((Q, want - kk), M, idx.dtype)], 1)
    return idx.astype(jnp.int32), most


def knn_within_radius(points, valid, k: int, radius: float, extent, bucket_cap: int | None = None, sectors: int = 0):
    """(M, k) indices of the k nearest valid points within ``radius`` of every valid point (``M``
    where fewer; invalid points get none) and the overflow flag (see :class:`Roadmap`).

    points: (M, 2) local coordinates in [0, extent); extent: (2,) Python floats; bucket_cap: slots
    per strip of 3 buckets (None: brute force); sectors: 0 (the k nearest) or the number of direction sectors
    whose nearest points come first (module docstring). Jittable with k, radius, extent,
    bucket_cap, sectors static.
    """
    M = points.shape[0]
    idx, overflow = _knn(points, valid, points, jnp.arange(M), k, radius, extent, bucket_cap, sectors)
    return jnp.where(valid[:, None], idx, M), overflow


#: Relative band around ``radius**2`` where the host's float32 squared distance is not trusted
#: to fall on the device's side (the two differ by at most a couple of ulp, ~2e-7).
_BORDER = 1e-5


def _candidates_host(
    db, db_ok, rows, k: int, radius: float, extent, keep: int, cap: int, sectors: int | None = None, density=None
):
    """The lazy grow's neighbour search on the host (compiled, buckets of the radius:
    :mod:`jaxsem.planning._neighbours_kernels`), for the rows where the order of the candidates
    decides nothing: a row with at most ``k`` candidates keeps every clear one, whatever the
    order, so it needs only its candidate set, which is :func:`_knn`'s exactly.

    db: (M, 2) local coordinates (numpy, the roadmap's dtype); db_ok: (M,) bool usable points; rows: (n,)
    the query rows' indices into ``db`` (their own points). A candidate of row ``q`` is a usable
    point ``j != q`` with ``sum((db[j] - db[q])**2) <= radius**2`` in that dtype, :func:`_knn_rows`'
    own arithmetic (products rounded, then summed). Rows with more than ``k`` candidates, and
    rows with a candidate within ``_BORDER`` of the radius (where the device might round the other
    way), are left to the device (:func:`_knn`, ``need``). ``cap``: the strip slots the device
    search would start with (brute force once 3 x cap reaches M); returned as the slots it ends
    with after its overflow reruns (x4 while a strip or a row holds more), so the device search
    of the ``need`` rows takes the same path, with the same candidate order, as a search of
    every row. ``sectors`` (not None: the grow's own, its samples' densities playing no part):
    the rows with more than ``k`` candidates are ranked here too, the device's order
    (:func:`~jaxsem.planning._neighbours_kernels.rank_rows`), but for those whose order a
    rounding or a sector border could change. ``density``: (M,) float32, the samples' densities
    as the device reads them (the grow's distribution at each sample), when they play a part
    (learned samples with sectors). Returns (cand (n, keep) int32, ``M`` where none
    and in every ``need`` row, in index order in a row of at most ``k``; need (n,) bool; the
    cap)."""
    M = db.shape[0]
    n = len(rows)
    rows = np.asarray(rows, np.int64)
    db_ok = np.asarray(db_ok, bool)
    if n == 0 or np.count_nonzero(db_ok) < 2:
        return np.full((n, keep), M, np.int32), np.zeros(n, bool), cap
    from . import _neighbours_kernels as kern

    db = np.asarray(db)
    x, y = np.ascontiguousarray(db[:, 0]), np.ascontiguousarray(db[:, 1])
    r2 = float(db.dtype.type(radius**2))
    side = float(radius) * (1.0 + 1e-3)  # a bucket a hair wider than the radius: 3 x 3 hold every candidate
    grid = kern.buckets(x, y, db_ok, side)

    def run(r0: int, r1: int):
        return kern.row_candidates(
            x, y, db_ok, rows[r0:r1], *grid, side, r2 * (1.0 - _BORDER), r2 * (1.0 + _BORDER), keep
        )

    parts = _in_blocks(n, n * keep, run)  # blocks of rows on threads (the kernel releases the GIL)
    cand, count, border = (np.concatenate([p[i] for p in parts]) for i in range(3))
    need = (count > k) | border
    cand[need] = M
    many = np.flatnonzero((count > k) & ~border)
    if sectors is not None and len(many):
        m = _per_sector(k, sectors) if sectors else 0
        todo = rows[many]

        dens = np.zeros(0, np.float32) if density is None or not sectors else np.asarray(density, np.float32)

        def rank(r0: int, r1: int):
            return kern.rank_rows(x, y, db_ok, todo[r0:r1], *grid, side, r2, keep, m, int(sectors), dens)

        parts = _in_blocks(len(todo), len(todo) * keep, rank)
        ranked, unsure = (np.concatenate([p[i] for p in parts]) for i in range(2))
        cand[many] = ranked
        need[many] = unsure
        cand[many[unsure]] = M
    return cand, need, _strip_cap(db, db_ok, rows, count, radius, extent, cap)


def _strip_cap(db, db_ok, rows, count, radius: float, extent, cap: int) -> int:
    """The strip slots the device's bucketed search of ``rows`` ends with (:func:`_candidates_host`):
    ``cap`` times 4 while a strip of 3 buckets around a row, or a row's ``count`` of candidates,
    holds more (the device's buckets: ``floor(db / radius)`` in the points' dtype, clipped)."""
    M = db.shape[0]
    if not 3 * cap < M:
        return cap
    bx, by, gx, gy = _host_buckets(db, radius, extent)
    ids = np.flatnonzero(db_ok)
    grid = np.bincount((by[ids] + 1) * (gx + 2) + bx[ids] + 1, minlength=(gy + 2) * (gx + 2))
    grid = grid.reshape(gy + 2, gx + 2)
    strips = grid[:, :-2] + grid[:, 1:-1] + grid[:, 2:]  # (gy + 2, gx): 3 buckets from x - 1
    qx, qy = bx[rows], by[rows]
    most = max(int(strips[qy[:, None] + np.arange(3)[None, :], qx[:, None]].max()), int(count.max()))
    while most > cap and 3 * cap < M:
        cap *= 4
    return cap

"""The compiled host kernels of the roadmap's neighbour search (:mod:`jaxsem.planning._neighbours`;
numba, cached on disk by numba: a module of its own, imported on first use, so that ``import
jaxsem`` does not import numba): a grow's candidate sets (:func:`row_candidates`) and a query's
choice (:func:`query_candidates`).

The query's kernel chooses what the device's brute-force choice chooses (``_query_candidates`` of
:mod:`jaxsem.planning._roadmap`: squared distances in float32, the direction-first policy of
:func:`jaxsem.planning._neighbours._select`, ties to the lower slot) in one pass over the
samples instead of a program over every sample and sector. Two things are the device's own: how
its float32 squared distance rounds (measured, :func:`jaxsem.planning._roadmap._host_choice`)
and its ``arctan2``, whose last bits no host function repeats. A sample whose direction lies
within a hair of a sector border (far wider than any ``arctan2``'s error) could fall on either
side; where such a sample could change the choice the kernel says so and the caller asks the
device.
"""

import math

import numba
import numpy as np

#: Relative width of the band around a sector border within which a direction counts as on it.
_BORDER = 1e-4

#: The eighth sector of a direction by (dy < 0, dx < 0, |dx| > |dy|), bits high to low.
_OCTANT = np.array([5, 4, 6, 7, 2, 3, 1, 0], np.int64)


@numba.njit(cache=True, nogil=True, inline="always")
def _d2(dx, dy, mode):
    """``dx * dx + dy * dy`` in float32: rounded after each operation (``mode`` 0), or with one of
    the products fused into the sum (1: ``dx * dx``, 2: ``dy * dy``; a float32 product is exact in
    float64)."""
    if mode == 0:
        return np.float32(dx * dx) + np.float32(dy * dy)
    if mode == 1:
        return np.float32(np.float64(dx) * np.float64(dx) + np.float64(np.float32(dy * dy)))
    return np.float32(np.float64(dy) * np.float64(dy) + np.float64(np.float32(dx * dx)))


@numba.njit(cache=True, nogil=True, inline="always")
def _sector(dx, dy, S):
    """The sector ``floor((atan2(dy, dx) + pi) * S / (2 pi))`` (at most ``S - 1``) of a direction,
    and whether it lies within :data:`_BORDER` of a sector border (then either side may be the
    device's). Eight sectors (the default) by comparisons alone; one sector has no border."""
    if S == 1:
        return 0, False
    if S == 8:
        ax = abs(np.float64(dx))
        ay = abs(np.float64(dy))
        hi = max(ax, ay)
        lo = min(ax, ay)
        near = hi == 0 or lo < _BORDER * hi or hi - lo < _BORDER * hi
        # By the signs and which of |dx|, |dy| is larger (no branch: directions are random).
        return _OCTANT[(dy < 0) * 4 + (dx < 0) * 2 + (ax > ay)], near
    v = (math.atan2(np.float64(dy), np.float64(dx)) + math.pi) * S / (2 * math.pi)
    s = min(max(np.int64(math.floor(v)), 0), S - 1)
    return s, abs(v - math.floor(v + 0.5)) < _BORDER


@numba.njit(cache=True, nogil=True, inline="always")
def _insert(keys, ids, count, size, key, j):
    """Adds (key, j) to the list ``keys``, ``ids`` sorted by key (ties in arrival order: the lower
    slot first), holding at most ``size``; ``count`` in use. Returns the new count."""
    if count == size:
        if not key < keys[size - 1]:
            return count
        count -= 1
    i = count
    while i > 0 and key < keys[i - 1]:
        keys[i] = keys[i - 1]
        ids[i] = ids[i - 1]
        i -= 1
    keys[i] = key
    ids[i] = j
    return count + 1


@numba.njit(cache=True, nogil=True)
def query_candidates(points, valid, starts, goals, m, sectors, keep, mode):
    """The candidates of queries ``starts``, ``goals`` (Q, 2) float32 among the roadmap's slots
    (``points`` (M, 2) float32, ``valid`` (M,); slots 0 and 1 are the query's own): each end's
    first ``keep`` in preference order (``M`` past the last) and their squared distances (inf
    there), (Q, 2, keep) each, and per query whether a sample on a sector border could change
    them (then the caller asks the device). The start may link to the goal (slot 1); neither
    end to itself or the other's slot otherwise. ``m``: candidates reserved per sector (0 or
    ``sectors`` 0: the nearest alone); ``mode``: :func:`_d2`'s."""
    M = points.shape[0]
    Qn = starts.shape[0]
    kk = min(keep, M)
    S = max(sectors, 1)
    nbr = np.full((Qn, 2, keep), M, np.int32)
    dist = np.full((Qn, 2, keep), np.inf, np.float32)
    unsure = np.zeros(Qn, np.bool_)
    d2 = np.empty(M, np.float32)
    sec = np.empty(M, np.int64)
    near = np.zeros(M, np.bool_)
    prio = np.zeros(M, np.bool_)
    m = max(m, 1)
    bd = np.empty((S, m), np.float32)
    bi = np.empty((S, m), np.int64)
    cnt = np.zeros(S, np.int64)
    tk = np.empty(kk, np.float32)
    ti = np.empty(kk, np.int64)
    inf = np.float32(np.inf)
    span = np.float32(0)
    for qi in range(Qn):
        for end in range(2):
            qx = starts[qi, 0] if end == 0 else goals[qi, 0]
            qy = starts[qi, 1] if end == 0 else goals[qi, 1]
            cnt[:] = 0
            top = np.float32(0)
            for j in range(M):
                if j < 2:
                    ok = end == 0 and j == 1
                    px, py = goals[qi, 0], goals[qi, 1]
                else:
                    ok = valid[j]
                    px, py = points[j, 0], points[j, 1]
                if not ok:
                    d2[j] = inf
                    continue
                dx = px - qx
                dy = py - qy
                d = _d2(dx, dy, mode)
                d2[j] = d
                top = max(top, d)
                if sectors:
                    s, nr = _sector(dx, dy, sectors)
                    sec[j] = s
                    near[j] = nr
                    cnt[s] = _insert(bd[s], bi[s], cnt[s], m, d, j)
            if sectors:
                prio[:] = False
                for s in range(S):
                    for i in range(cnt[s]):
                        prio[bi[s, i]] = True
                # A sample on a border matters if it is among its sector's reserved ones, or
                # would be among the neighbouring sector's.
                for j in range(1, M):
                    if near[j] and d2[j] < inf and not unsure[qi]:
                        px = goals[qi, 0] if j == 1 else points[j, 0]
                        py = goals[qi, 1] if j == 1 else points[j, 1]
                        v = math.atan2(np.float64(py - qy), np.float64(px - qx)) + math.pi
                        c = np.int64(math.floor(v * S / (2 * math.pi) + 0.5))
                        for s in ((c - 1) % S, c % S):
                            if cnt[s] < m or d2[j] <= bd[s, m - 1]:
                                unsure[qi] = True
                    near[j] = False
                span = top + np.float32(1.0)
            n = 0
            for j in range(M):
                d = d2[j]
                if d < inf:
                    key = d if (not sectors or prio[j]) else np.float32(d + span)
                    n = _insert(tk, ti, n, kk, key, j)
            for i in range(n):
                nbr[qi, end, i] = ti[i]
                dist[qi, end, i] = d2[ti[i]]
    return nbr, dist, unsure


@numba.njit(cache=True, nogil=True)
def buckets(x, y, ok, side):
    """The usable points (``ok``) of ``x``, ``y`` (M,) in square buckets of ``side``
    (float64, off the points' rounding: a bucket holds what it holds, and a caller reading the
    3 x 3 buckets around a point reads every point within ``side`` of it): (gx, gy, start
    (gx * gy + 1,), the points bucket by bucket (in index order within each))."""
    M = x.shape[0]
    gx = 1
    gy = 1
    for j in range(M):
        if ok[j]:
            gx = max(gx, np.int64(math.floor(np.float64(x[j]) / side)) + 1)
            gy = max(gy, np.int64(math.floor(np.float64(y[j]) / side)) + 1)
    bid = np.full(M, -1, np.int64)
    start = np.zeros(gx * gy + 1, np.int64)
    for j in range(M):
        if ok[j]:
            bx, by = _home(x[j], y[j], side, gx, gy)
            bid[j] = by * gx + bx
            start[bid[j] + 1] += 1
    for b in range(gx * gy):
        start[b + 1] += start[b]
    items = np.empty(start[gx * gy], np.int32)
    fill = start[:-1].copy()
    for j in range(M):
        if bid[j] >= 0:
            items[fill[bid[j]]] = j
            fill[bid[j]] += 1
    return gx, gy, start, items


@numba.njit(cache=True, nogil=True, inline="always")
def _home(qx, qy, side, gx, gy):
    """The bucket (bx, by) of the point (qx, qy) (:func:`buckets`' arithmetic, clipped)."""
    bx = min(max(np.int64(math.floor(np.float64(qx) / side)), 0), gx - 1)
    by = min(max(np.int64(math.floor(np.float64(qy) / side)), 0), gy - 1)
    return bx, by


@numba.njit(cache=True, nogil=True, inline="always")
def _strip(ry, bx, gx, start):
    """The bucket-order positions [t0, t1) of the buckets bx - 1 .. bx + 1 of row ``ry`` (the 3
    buckets of a row are contiguous)."""
    return start[ry * gx + max(bx - 1, 0)], start[ry * gx + min(bx + 1, gx - 1) + 1]


@numba.njit(cache=True, nogil=True)
def row_candidates(x, y, ok, rows, gx, gy, start, items, side, lo2, hi2, keep):
    """The candidates of the points ``rows`` (n,) among the usable points bucketed by
    :func:`buckets`: the usable points ``j`` other than the row's own with the squared distance
    ``dx * dx + dy * dy`` in the points' dtype (rounded after each operation) at most ``hi2`` (a
    hair over the radius' square), as (cand (n, keep) int32, ``M`` past the last, the first ``keep`` in
    index order; count (n,) of them; border (n,): one lies above ``lo2``, where another rounding
    might leave it out). A row whose own point is not usable has none."""
    M = x.shape[0]
    n = rows.shape[0]
    sx = x[items]  # the points' coordinates in bucket order: each row reads them in sequence
    sy = y[items]
    cand = np.full((n, keep), M, np.int32)
    count = np.zeros(n, np.int64)
    border = np.zeros(n, np.bool_)
    ids, d2 = _buffers(gx, gy, start, x.dtype)
    for i in range(n):
        q = rows[i]
        if not ok[q]:
            continue
        c = _collect(x, y, q, sx, sy, items, gx, gy, start, side, hi2, ids, d2)
        for a in range(c):
            if d2[a] > lo2:
                border[i] = True
        for a in range(min(c, keep)):
            cand[i, a] = ids[a]
        count[i] = c
    return cand, count, border


@numba.njit(cache=True, nogil=True)
def _buffers(gx, gy, start, dtype):
    """Buffers (ids int64, squared distances) with room for the points of any 3 x 3 buckets
    (:func:`buckets`): three times the fullest strip of three buckets in a row."""
    most = 0
    for ry in range(gy):
        for bx in range(gx):
            t0, t1 = _strip(ry, bx, gx, start)
            most = max(most, t1 - t0)
    return np.empty(3 * most + 1, np.int64), np.empty(3 * most + 1, dtype)


@numba.njit(cache=True, nogil=True)
def _collect(x, y, q, sx, sy, items, gx, gy, start, side, bound, ids, d2):
    """Point ``q``'s candidates among the bucketed points (``sx``, ``sy``: their coordinates in
    bucket order): every usable ``j != q`` with ``dx * dx + dy * dy`` in the points' dtype
    (rounded after each operation, as numba keeps float32 float32) at most ``bound``, in bucket
    order, into the buffers ``ids``, ``d2`` (:func:`_buffers`: room for any 3 x 3 buckets).
    Returns the count."""
    qx, qy = x[q], y[q]
    bx, by = _home(qx, qy, side, gx, gy)
    c = 0
    for ry in range(max(by - 1, 0), min(by + 2, gy)):
        t0, t1 = _strip(ry, bx, gx, start)
        for t in range(t0, t1):
            dx = sx[t] - qx
            dy = sy[t] - qy
            d = dx * dx + dy * dy
            if d <= bound and items[t] != q:
                ids[c] = items[t]
                d2[c] = d
                c += 1
    return c


#: Relative gap below which two squared distances or keys of a row count as tied: the device's
#: rounding of ``dx * dx + dy * dy`` (a product may be fused into the sum) and of ``d2 + span``
#: moves each by a few units in the last place, so closer values could come in either order.
_TIE = 16.0 * 2.0**-23


@numba.njit(cache=True, nogil=True, inline="always")
def _ties(v):
    """Whether two of the sorted values ``v`` lie within :data:`_TIE` of each other."""
    for i in range(1, v.shape[0]):
        if v[i] - v[i - 1] <= _TIE * max(abs(np.float64(v[i])), abs(np.float64(v[i - 1]))):
            return True
    return False


@numba.njit(cache=True, nogil=True)
def rank_rows(x, y, ok, rows, gx, gy, start, items, side, r2, keep, m, sectors, dens):
    """The device's ranked candidates of the points ``rows`` (n,) (:func:`_select` of
    :mod:`jaxsem.planning._neighbours` over their candidates within the radius, ``r2`` its
    square: with ``sectors``, the ``m`` nearest of each direction sector first, then the rest by
    ``d2 + span``; without, by ``d2``), bucketed as :func:`buckets`: (cand (n, keep) int32 in
    preference order, ``M`` past the last; unsure (n,)). The device breaks exact ties by its
    own slot order, and rounds the keys its own way: a row whose squared distances or keys come
    within :data:`_TIE` of each other, or with a candidate on a sector border that could be
    reserved on either side, is unsure (the caller asks the device). Rows must have no candidate
    within a hair of the radius (their sets are the device's). ``dens`` (M,) float32: the
    samples' densities (the device's values), whose sparser candidates' ``2 m`` nearest come
    first too (:func:`_select`'s ``sparser``; a density within a hair of the test's bound makes
    the row unsure); empty: none."""
    M = x.shape[0]
    n = rows.shape[0]
    sx = x[items]
    sy = y[items]
    cand = np.full((n, keep), M, np.int32)
    unsure = np.zeros(n, np.bool_)
    S = max(sectors, 1)
    mm = max(m, 1)
    bd = np.empty((S, mm), x.dtype)
    bi = np.empty((S, mm), np.int64)
    cnt = np.zeros(S, np.int64)
    ids, d2 = _buffers(gx, gy, start, x.dtype)
    near = np.empty(ids.shape[0], np.bool_)
    for i in range(n):
        q = rows[i]
        if not ok[q]:
            continue
        qx, qy = x[q], y[q]
        c = _collect(x, y, q, sx, sy, items, gx, gy, start, side, r2, ids, d2)
        cnt[:] = 0
        if sectors:
            for a in range(c):  # each sector's m nearest, ties in arrival order (the device's slots)
                s, near[a] = _sector(x[ids[a]] - qx, y[ids[a]] - qy, sectors)
                cnt[s] = _insert(bd[s], bi[s], cnt[s], m, d2[a], a)
        if c == 0:
            continue
        if _ties(np.sort(d2[:c])):
            unsure[i] = True
            continue
        key = d2[:c].copy()
        if sectors:
            top = d2[0]
            for a in range(c):
                top = max(top, d2[a])
            span = top + x.dtype.type(1.0)
            prio = np.zeros(c, np.bool_)
            for s in range(S):
                for a in range(cnt[s]):
                    prio[bi[s, a]] = True
            if dens.shape[0] > 0:
                # The 2 m nearest candidates sampled no more densely than the query (float32,
                # the device's test: density <= the query's x 1.001). No two d2 tie here.
                bound = dens[q] * np.float32(1.001)
                sp = np.zeros(c, np.bool_)
                for a in range(c):
                    v = dens[ids[a]]
                    if abs(np.float64(v) - np.float64(bound)) <= 1e-6 * abs(np.float64(bound)):
                        unsure[i] = True
                    sp[a] = v <= bound
                taken = 0
                for a in np.argsort(np.where(sp, d2[:c], np.inf)):
                    if taken >= min(2 * m, c) or not sp[a]:
                        break
                    prio[a] = True
                    taken += 1
            for a in range(c):
                if near[a]:
                    dxa = x[ids[a]] - qx
                    dya = y[ids[a]] - qy
                    v = math.atan2(np.float64(dya), np.float64(dxa)) + math.pi
                    b = np.int64(math.floor(v * S / (2 * math.pi) + 0.5))
                    for s in ((b - 1) % S, b % S):
                        if cnt[s] < m or d2[a] <= bd[s, m - 1]:
                            unsure[i] = True
                if not prio[a]:
                    key[a] = d2[a] + span
            if unsure[i]:
                continue
        order = np.argsort(key)
        if _ties(key[order]):
            unsure[i] = True
            continue
        for a in range(min(keep, c)):
            cand[i, a] = ids[order[a]]
    return cand, unsure

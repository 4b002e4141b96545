"""The compiled host kernel of a query's candidates (:mod:`jaxsem.planning._neighbours`; numba,
cached on disk by numba: a module of its own, imported on first use, so that ``import jaxsem``
does not import numba).

It chooses what the device's brute-force choice chooses (``_query_candidates`` of
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

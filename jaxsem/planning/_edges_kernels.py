"""The compiled host kernels of :mod:`jaxsem.planning._edges` (numba, cached on disk by numba: a
module of their own, imported on first use, so that ``import jaxsem`` does not import numba).

They read the edge rule's samples as the compiled rule computes them, in float32: the sample
``a + t * (b - a)`` (``t = k / (S - 1)``) either fused (one rounding, as XLA's CPU code does on a
processor with fused multiply-add) or not, and its cell ``floor((p - origin) * inv)`` (``inv``
the float32 reciprocal of the resolution, as XLA folds a division by a constant) or
``floor((p - origin) / resolution)``. Which of the four the device's rule uses is measured, not
assumed (:func:`jaxsem.planning._edges._host_rule`).
"""

import numba
import numpy as np

from ._astar_kernels import entry_length


@numba.njit(cache=True, nogil=True, inline="always")
def _along(t, d, a, fused):
    """``a + t * d`` in float32: one rounding when ``fused`` (the product of two float32 is exact
    in float64; the sum's rounding to float64 before float32 differs from a fused multiply-add
    only where it lands exactly halfway between two float32, about once in 2**28 samples, and
    then by one unit in the last place), else two."""
    if fused:
        return np.float32(np.float64(t) * np.float64(d) + np.float64(a))
    return np.float32(t * d) + a


@numba.njit(cache=True, nogil=True, inline="always")
def _cell(p, o, inv, res, recip):
    """The float32 cell coordinate of world coordinate ``p`` (floored by the caller)."""
    if recip:
        return np.floor(np.float32(p - o) * inv)
    return np.floor(np.float32(p - o) / res)


@numba.njit(cache=True, nogil=True)
def sample_cells(a, b, S, origin, inv, res, fused, recip):
    """Rows and columns (E, S) int64 of the ``S`` samples of each edge ``a`` -> ``b`` (E, 2)
    float32 (off the grid as they fall: nothing clipped)."""
    E = a.shape[0]
    rows = np.empty((E, S), np.int64)
    cols = np.empty((E, S), np.int64)
    denom = np.float32(S - 1)
    for e in range(E):
        dx = b[e, 0] - a[e, 0]
        dy = b[e, 1] - a[e, 1]
        for k in range(S):
            t = np.float32(k) / denom
            cols[e, k] = np.int64(_cell(_along(t, dx, a[e, 0], fused), origin[0], inv, res, recip))
            rows[e, k] = np.int64(_cell(_along(t, dy, a[e, 1], fused), origin[1], inv, res, recip))
    return rows, cols


@numba.njit(cache=True, nogil=True)
def edges_clear(blocked, table, base, a, b, samples, want, origin, inv, res, fused, recip, row, k):
    """The edge rule on edges ``a`` -> ``b`` (E, 2) float32 with ``samples`` (E,) samples each,
    on the bool grid ``blocked`` (H, W): (E,) clear flags (False where ``want`` is not set).
    The edges come in rows of ``row`` (a vertex's candidates in preference order); in each
    row, the edges after its ``k``-th clear one are not read (False: a caller keeping the first
    ``k`` clear ones drops them anyway).

    ``table``: clearance lower bounds in cells, one per block of ``2**base`` x ``2**base``
    cells (shape (0, 0): none); see :func:`edge_clear`. It releases the GIL: callers run
    blocks of rows on threads of their own."""
    E = a.shape[0]
    out = np.zeros(E, np.bool_)
    for ri in range(-(-E // row)):
        _row(
            out,
            ri * row,
            min(ri * row + row, E),
            k,
            blocked,
            table,
            base,
            a,
            b,
            samples,
            want,
            origin,
            inv,
            res,
            fused,
            recip,
        )
    return out


#: :func:`first_clear_pairs`' states of an edge: read, clear, and the reversed edge's answer too.
_READ, _CLEAR, _BOTH = 1, 2, 4


@numba.njit(cache=True, nogil=True)
def first_clear_pairs(blocked, table, base, pts, cand, s0, k, S, origin, inv, res, fused, recip, rows, state, out):
    """Each row ``i`` in ``rows`` (int64) of ``cand`` (n, K) (vertex ``s0 + i``'s candidates in
    preference order, ``M = len(pts)`` where none) read in order until ``k`` edges from the
    vertex are clear (the rule with ``S`` samples; see :func:`edges_clear`), in two passes over
    every row, each edge between two of these rows read once where its reversal would read the
    same (:func:`_walk`).

    ``state`` (n, K) uint8, zeros before the first pass; ``out``: None in the first pass, which
    reads each row's edges to vertices earlier than its own vertex's (and to vertices outside
    ``s0 .. s0 + n``) until ``k`` of them are clear, noting for each whether the reversed edge
    is sure to agree. The second pass (``out`` = (neighbours (n, k) int32, ``M`` past the last;
    valid (n, k); weights (n, k): the edges' lengths in the points' dtype, as the roadmap weighs
    an edge, inf past the last), filled in rows ``rows``) reads each row in order until ``k`` are clear, taking an edge's answer
    from the first pass, from the other end's row where that row read the reversal surely, or
    else reading it. Every pass of a row reads only ``state``'s rows written by earlier passes:
    blocks of rows may run on threads of their own, the passes one after the other."""
    n, K = cand.shape
    M = pts.shape[0]
    for i in rows:
        v = s0 + i
        ax, ay = pts[v, 0], pts[v, 1]
        found = 0
        for j in range(K):
            if found >= k:
                break
            c = cand[i, j]
            if c >= M:
                continue
            mine = not (s0 <= c < v)  # the first pass' edges: the other end is not an earlier new row
            if out is None:
                if not mine:
                    continue
                clear, sure = _walk(
                    blocked,
                    table,
                    base,
                    ax,
                    ay,
                    pts[c, 0],
                    pts[c, 1],
                    S,
                    origin,
                    inv,
                    res,
                    fused,
                    recip,
                    s0 <= c < s0 + n,
                )
                state[i, j] = _READ | (_CLEAR if clear else 0) | (_BOTH if sure else 0)
            else:
                st = state[i, j]
                if not st & _READ:
                    st = 0
                    if not mine:
                        other = c - s0
                        for jj in range(K):
                            if cand[other, jj] == v:
                                st = state[other, jj]
                                break
                    if not (st & _READ and st & _BOTH):
                        clear = edge_clear(
                            blocked, table, base, ax, ay, pts[c, 0], pts[c, 1], S, origin, inv, res, fused, recip
                        )
                        st = _READ | (_CLEAR if clear else 0)
                clear = bool(st & _CLEAR)
                if clear:
                    nbr, ok, w = out
                    nbr[i, found] = c
                    ok[i, found] = True
                    w[i, found] = entry_length(pts, v, c)
            found += clear


@numba.njit(cache=True, nogil=True, inline="always")
def _row(out, e0, e1, k, blocked, table, base, a, b, samples, want, origin, inv, res, fused, recip):
    """The edges ``e0 .. e1`` of one row into ``out``, until ``k`` are clear."""
    found = 0
    for e in range(e0, e1):
        if found >= k:
            break
        if want[e]:
            out[e] = edge_clear(
                blocked, table, base, a[e, 0], a[e, 1], b[e, 0], b[e, 1], samples[e], origin, inv, res, fused, recip
            )
            found += out[e]


@numba.njit(cache=True, nogil=True)
def edge_clear(blocked, table, base, ax, ay, bx, by, S, origin, inv, res, fused, recip):
    """The edge rule on the edge (ax, ay) -> (bx, by) with ``S`` samples on the bool grid
    ``blocked`` (H, W): see :func:`_walk`."""
    return _walk(blocked, table, base, ax, ay, bx, by, S, origin, inv, res, fused, recip, False)[0]


@numba.njit(cache=True, nogil=True, inline="always")
def _walk(blocked, table, base, ax, ay, bx, by, S, origin, inv, res, fused, recip, both):
    """The edge rule on the edge (ax, ay) -> (bx, by) with ``S`` samples on the bool grid
    ``blocked`` (H, W), and (with ``both``) whether the reversed edge (bx, by) -> (ax, ay) has
    the same answer for sure: (clear, sure).

    An edge is clear when every sample lies in a free cell on the grid and, where two consecutive
    samples differ in both row and column, both side cells of that step are free. Read from the
    start, it stops at its first blocked read. ``table`` lets the walk skip the samples within a
    sample's clearance disc: no cell there is blocked or next to a blocked cell, so those samples
    and their steps' side cells are free (the skip stays a sample short of the disc's edge,
    which also covers the float32 samples' rounding). The answer is the rule's, read at every
    sample.

    The reversed edge's sample ``S - 1 - i`` is this one's sample ``i`` but for its rounding:
    where every sample read here lies in the cell the reversed edge's own arithmetic puts it in
    (the skipped ones lie inside clearance discs either way), the reversed edge reads the same
    cells and steps, so its answer is this one's; a blocked answer needs only its blocking
    samples to agree. Reads that gallop through a cell (long edges) are not compared: unsure."""
    sure = both
    H, W = blocked.shape
    TH, TW = table.shape
    ox, oy = origin[0], origin[1]
    dx = bx - ax
    dy = by - ay
    denom = np.float32(S - 1)
    step = np.sqrt(np.float64(dx) ** 2 + np.float64(dy) ** 2) / max(S - 1, 1)
    prev = False
    psame = True
    pr = 0
    pc = 0
    k = 0
    while k < S:
        t = np.float32(k) / denom
        c = np.int64(_cell(_along(t, dx, ax, fused), ox, inv, res, recip))
        r = np.int64(_cell(_along(t, dy, ay, fused), oy, inv, res, recip))
        same = True
        if both:
            u = np.float32(S - 1 - k) / denom  # the reversed edge's sample at this one
            same = np.int64(_cell(_along(u, -dx, bx, fused), ox, inv, res, recip)) == c
            same = same and np.int64(_cell(_along(u, -dy, by, fused), oy, inv, res, recip)) == r
        if r < 0 or r >= H or c < 0 or c >= W or blocked[r, c]:
            return False, same
        if prev and r != pr and c != pc and (blocked[pr, c] or blocked[r, pc]):
            return False, same and psame
        pr, pc, prev, psame = r, c, True, same
        sure = sure and same
        m = 0
        if TH > 0 and step > 0:
            tr, tc = r >> base, c >> base
            if tr < TH and tc < TW and table[tr, tc] > 0:
                m = np.int64((np.float64(table[tr, tc]) - 0.01) * np.float64(res) / step) - 1
        if m > 1:
            # Samples k + 1 .. k + m lie inside the disc; the step into k + m leaves a cell
            # whose neighbours are free, so it needs no side read.
            k += m
            prev = False
            continue
        if step * 4 > res:
            k += 1  # a few samples a cell (the roadmap's own edges): read the next one
            continue
        # Each coordinate's cell is monotone in k (every operation rounds monotonically): the
        # samples up to the last one in this cell add nothing. Gallop to the first one past it
        # (a query's long edges: hundreds of samples a cell).
        sure = False
        lo = k
        hi = k + 1
        run = 1
        while hi < S and _same(hi, denom, dx, dy, ax, ay, ox, oy, inv, res, fused, recip, r, c):
            lo = hi
            run *= 2
            hi = k + run
        hi = min(hi, S)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if _same(mid, denom, dx, dy, ax, ay, ox, oy, inv, res, fused, recip, r, c):
                lo = mid
            else:
                hi = mid
        k = hi
    return True, sure


@numba.njit(cache=True, nogil=True, inline="always")
def _same(k, denom, dx, dy, ax, ay, ox, oy, inv, res, fused, recip, r, c):
    """Whether sample ``k`` lies in cell (r, c)."""
    t = np.float32(k) / denom
    if np.int64(_cell(_along(t, dx, ax, fused), ox, inv, res, recip)) != c:
        return False
    return np.int64(_cell(_along(t, dy, ay, fused), oy, inv, res, recip)) == r

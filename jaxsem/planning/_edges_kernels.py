"""The compiled host kernels of :mod:`jaxsem.planning._edges` (numba, cached on disk by numba: a
module of their own, imported on first use, so that ``import jaxsem`` does not import numba).

They read the edge rule's samples as the compiled rule computes them, in float32: the sample
``a + t * (b - a)`` (``t = k / (S - 1)``) either fused (one rounding, as XLA's CPU code does on a
processor with fused multiply-add) or not, and its cell ``floor((p - origin) * inv)`` (``inv``
the float32 reciprocal of the resolution, as XLA folds a division by a constant) or
``floor((p - origin) / resolution)``. Which of the four the device's rule uses is measured, not
assumed (:func:`jaxsem.planning._edges._host_rule`).

An edge whose box of cells holds no blocked cell is clear without a read (:func:`_box_free`: four
reads of the map's box sums); others are read a line of cells at a time (:func:`_lines`: the
rule's cells in one grid row, or column, are one range of bits), each sample's cell taken from
real-number arithmetic except near a border, where the float32 rule decides; long edges, and
edges too close to a row or column for that, are read by samples (:func:`_walk`).
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
            cols[e, k] = _exact(k, denom, dx, a[e, 0], origin[0], inv, res, fused, recip)
            rows[e, k] = _exact(k, denom, dy, a[e, 1], origin[1], inv, res, fused, recip)
    return rows, cols


@numba.njit(cache=True, nogil=True)
def edges_clear(
    blocked, table, base, rowbits, colbits, boxsum, a, b, samples, want, origin, inv, res, fused, recip, row, k
):
    """The edge rule on edges ``a`` -> ``b`` (E, 2) float32 with ``samples`` (E,) samples each,
    on the bool grid ``blocked`` (H, W): (E,) clear flags (False where ``want`` is not set).
    The edges come in rows of ``row`` (a vertex's candidates in preference order); in each
    row, the edges after its ``k``-th clear one are not read (False: a caller keeping the first
    ``k`` clear ones drops them anyway).

    ``rowbits``, ``colbits``: the grid as bits (:func:`_lines`; shape (0, 0): none, every edge
    read by samples); ``boxsum``: its box sums (:func:`box_sums`; shape (0, 0): none, no edge
    settled by its box); ``table``: clearance lower
    bounds in cells, one per block of ``2**base`` x ``2**base`` cells (shape (0, 0): none), for
    the edges read by samples (:func:`edge_clear`). It releases the GIL: callers run blocks of
    rows on threads of their own."""
    E = a.shape[0]
    out = np.zeros(E, np.bool_)
    for ri in range(-(-E // row)):
        found = 0
        for e in range(ri * row, min(ri * row + row, E)):
            if found >= k:
                break
            if want[e]:
                out[e] = edge_clear(
                    blocked,
                    table,
                    base,
                    rowbits,
                    colbits,
                    boxsum,
                    a[e, 0],
                    a[e, 1],
                    b[e, 0],
                    b[e, 1],
                    samples[e],
                    origin,
                    inv,
                    res,
                    fused,
                    recip,
                )
                found += out[e]
    return out


#: :func:`first_clear_pairs`' states of an edge: read, clear, and the reversed edge's answer too.
_READ, _CLEAR, _BOTH = 1, 2, 4


@numba.njit(cache=True, nogil=True)
def first_clear_pairs(
    blocked,
    table,
    base,
    rowbits,
    colbits,
    boxsum,
    pts,
    cand,
    vert,
    row_of,
    s0,
    k,
    S,
    origin,
    inv,
    res,
    fused,
    recip,
    rows,
    state,
    out,
    second,
):
    """Each row ``i`` in ``rows`` (int64) of ``cand`` (n, K) (vertex ``vert[i]``'s candidates in
    preference order, ``M = len(pts)`` where none; the vertices are ``s0 .. s0 + n``, vertex
    ``s0 + x`` in row ``row_of[x]``) read in order until ``k`` edges from the vertex are clear
    (the rule with ``S`` samples; see :func:`edges_clear`), in two passes over every row, each
    edge between two of these rows read once where its reversal surely reads the same cells
    (:func:`_lines`). Rows of vertices near each other in the plane placed near each other make
    a row's reads of the other rows cheap.

    ``state`` (n, K) uint8, zeros before the first pass. The first pass (``second`` False)
    reads each row's edges to vertices earlier than its own vertex's (and to vertices outside
    ``s0 .. s0 + n``) until ``k`` of them are clear, noting for each whether the reversed edge
    is sure to agree. The second pass (``second`` True) fills ``out`` = (neighbours (n, k) int32,
    ``M`` past the last; valid (n, k); weights (n, k): the edges' lengths in the points' dtype,
    as the roadmap weighs an edge, inf past the last) in the rows of the vertices of rows
    ``rows`` (vertex ``s0 + x`` in row ``x``): it reads each row in order until ``k`` are clear,
    taking an edge's answer from the first pass, from the other end's row where that row read
    the reversal surely, or else reading it. Every pass of a row reads only ``state``'s rows
    written by earlier passes: blocks of rows may run on threads of their own, the passes one
    after the other. (One compiled function serves both passes: ``out`` is the same tuple in
    both, ``second`` a flag, so numba compiles it once.)"""
    n, K = cand.shape
    M = pts.shape[0]
    for i in rows:
        v = vert[i]
        ax, ay = pts[v, 0], pts[v, 1]
        found = 0
        for j in range(K):
            if found >= k:
                break
            c = cand[i, j]
            if c >= M:
                continue
            mine = not (s0 <= c < v)  # the first pass' edges: the other end is not an earlier new row
            bx, by = pts[c, 0], pts[c, 1]
            if not second:
                if not mine:
                    continue
                clear, sure = _clear(
                    blocked,
                    table,
                    base,
                    rowbits,
                    colbits,
                    boxsum,
                    ax,
                    ay,
                    bx,
                    by,
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
                        other = row_of[c - s0]
                        for jj in range(K):
                            if cand[other, jj] == v:
                                st = state[other, jj]
                                break
                    if not (st & _READ and st & _BOTH):
                        clear = edge_clear(
                            blocked,
                            table,
                            base,
                            rowbits,
                            colbits,
                            boxsum,
                            ax,
                            ay,
                            bx,
                            by,
                            S,
                            origin,
                            inv,
                            res,
                            fused,
                            recip,
                        )
                        st = _READ | (_CLEAR if clear else 0)
                clear = bool(st & _CLEAR)
                if clear:
                    nbr, ok, w = out
                    nbr[v - s0, found] = c
                    ok[v - s0, found] = True
                    w[v - s0, found] = entry_length(pts, v, c)
            found += clear


@numba.njit(cache=True, nogil=True)
def edge_clear(blocked, table, base, rowbits, colbits, boxsum, ax, ay, bx, by, S, origin, inv, res, fused, recip):
    """The edge rule on the edge (ax, ay) -> (bx, by) with ``S`` samples on the bool grid
    ``blocked`` (H, W): see :func:`_clear`."""
    return _clear(
        blocked, table, base, rowbits, colbits, boxsum, ax, ay, bx, by, S, origin, inv, res, fused, recip, False
    )[0]


@numba.njit(cache=True, nogil=True, inline="always")
def _clear(blocked, table, base, rowbits, colbits, boxsum, ax, ay, bx, by, S, origin, inv, res, fused, recip, both):
    """(the edge rule on the edge (ax, ay) -> (bx, by), and with ``both`` whether the reversed
    edge surely reads the same): clear at once where the box of cells the edge can read holds
    no blocked cell (:func:`_box_free`; both ways, surely), else by lines of cells
    (:func:`_lines`), or by samples (:func:`_walk`; not sure) where a line's first sample is
    unsure over too much of a step, the edge is long, or no bits are given (``rowbits`` of
    shape (0, 0))."""
    H, W = blocked.shape
    if boxsum.shape[0] > 0 and _box_free(boxsum, H, W, ax, ay, bx, by, S, origin, inv, res, fused, recip, both):
        return True, True
    st = -1
    sure = False
    if rowbits.shape[0] > 0:
        st, sure = _lines(rowbits, colbits, H, W, ax, ay, bx, by, S, origin, inv, res, fused, recip, both)
    if st < 0:
        return _walk(blocked, table, base, ax, ay, bx, by, S, origin, inv, res, fused, recip), False
    return st == 1, sure


#: The most cells a box may hold for :func:`_box_free` (its sums are kept modulo 2**16).
_BOX_CELLS = 65535


@numba.njit(cache=True, nogil=True)
def box_sums(blocked):
    """The blocked cells of ``blocked`` (H, W) counted over every box from the map's corner:
    (H + 1, W + 1) uint16, entry (r, c) the count over rows < r and columns < c, modulo 2**16
    (a box's count by four entries is exact modulo 2**16, so exact for a box of at most
    :data:`_BOX_CELLS` cells)."""
    H, W = blocked.shape
    out = np.zeros((H + 1, W + 1), np.uint16)
    for r in range(H):
        run = 0
        for c in range(W):
            run += blocked[r, c]
            out[r + 1, c + 1] = (np.int64(out[r, c + 1]) + run) & 0xFFFF
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _box_free(boxsum, H, W, ax, ay, bx, by, S, origin, inv, res, fused, recip, both):
    """Whether the box of cells spanned by the edge's first and last samples' cells (and, with
    ``both``, the reversed edge's) lies on the map and holds no blocked cell (``boxsum``:
    :func:`box_sums`). Each coordinate's cell is monotone along the samples (every operation
    rounds monotonically), so every sample's cell, and both side cells of every diagonal step,
    lie in that box: the rule reads the edge clear (and the reversed edge, with ``both``)."""
    if S < 2:
        return False
    ox, oy = origin[0], origin[1]
    dx = bx - ax
    dy = by - ay
    denom = np.float32(S - 1)
    c0 = _exact(0, denom, dx, ax, ox, inv, res, fused, recip)
    c1 = _exact(S - 1, denom, dx, ax, ox, inv, res, fused, recip)
    r0 = _exact(0, denom, dy, ay, oy, inv, res, fused, recip)
    r1 = _exact(S - 1, denom, dy, ay, oy, inv, res, fused, recip)
    c0, c1 = min(c0, c1), max(c0, c1)
    r0, r1 = min(r0, r1), max(r0, r1)
    if both:
        for k in (0, S - 1):
            c = _reversed(k, denom, dx, bx, ox, inv, res, fused, recip)
            r = _reversed(k, denom, dy, by, oy, inv, res, fused, recip)
            c0, c1 = min(c0, c), max(c1, c)
            r0, r1 = min(r0, r), max(r1, r)
    if r0 < 0 or c0 < 0 or r1 >= H or c1 >= W or (r1 - r0 + 1) * (c1 - c0 + 1) > _BOX_CELLS:
        return False
    n = (
        np.int64(boxsum[r1 + 1, c1 + 1])
        - np.int64(boxsum[r0, c1 + 1])
        - np.int64(boxsum[r1 + 1, c0])
        + np.int64(boxsum[r0, c0])
    )
    return (n & 0xFFFF) == 0


@numba.njit(cache=True, nogil=True)
def _walk(blocked, table, base, ax, ay, bx, by, S, origin, inv, res, fused, recip):
    """The edge rule on the edge (ax, ay) -> (bx, by) with ``S`` samples on the bool grid
    ``blocked`` (H, W), read sample by sample.

    An edge is clear when every sample lies in a free cell on the grid and, where two consecutive
    samples differ in both row and column, both side cells of that step are free. Read from the
    start, it stops at its first blocked read. ``table`` lets the walk skip the samples within a
    sample's clearance disc: no cell there is blocked or next to a blocked cell, so those samples
    and their steps' side cells are free (the skip stays a sample short of the disc's edge,
    which also covers the float32 samples' rounding). The answer is the rule's, read at every
    sample. A function of its own, called, not inlined: numba compiles its body once for every
    kernel that reads edges (long edges and maps without bits only; inlined everywhere, a cold
    compile of the edge kernels took twice as long)."""
    H, W = blocked.shape
    TH, TW = table.shape
    ox, oy = origin[0], origin[1]
    dx = bx - ax
    dy = by - ay
    denom = np.float32(S - 1)
    step = np.sqrt(np.float64(dx) ** 2 + np.float64(dy) ** 2) / max(S - 1, 1)
    prev = False
    pr = 0
    pc = 0
    k = 0
    while k < S:
        c = _exact(k, denom, dx, ax, ox, inv, res, fused, recip)
        r = _exact(k, denom, dy, ay, oy, inv, res, fused, recip)
        if r < 0 or r >= H or c < 0 or c >= W or blocked[r, c]:
            return False
        if prev and r != pr and c != pc and (blocked[pr, c] or blocked[r, pc]):
            return False
        pr, pc, prev = r, c, True
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
            k += 1  # a few samples a cell: read the next one
            continue
        # Each coordinate's cell is monotone in k (every operation rounds monotonically): the
        # samples up to the last one in this cell add nothing. Gallop to the first one past it
        # (a query's long edges: hundreds of samples a cell).
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
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _same(k, denom, dx, dy, ax, ay, ox, oy, inv, res, fused, recip, r, c):
    """Whether sample ``k`` lies in cell (r, c)."""
    if _exact(k, denom, dx, ax, ox, inv, res, fused, recip) != c:
        return False
    return _exact(k, denom, dy, ay, oy, inv, res, fused, recip) == r


#: The real-number sample (cells) ``(a - o) / res + k * d / res / (S - 1)`` lies within this
#: many cells times ``|a| + |d| + |o|`` (metres) / ``res`` of the float32 rule's, either way of
#: rounding it: six roundings of at most 2**-24 each, with a margin of 2.7.
_SLACK = 2.0**-20

#: Where a real-number sample's cell is unsure for more than this share of the way from one
#: sample to the next, the walk by lines leaves the edge to :func:`_walk`.
_SLOW = 0.25

#: Edges spanning more cells than this along a row or column are read by :func:`_walk`: in open
#: space its clearance table skips most of a long edge, where lines read every cell.
_LONG = 64.0


@numba.njit(cache=True, nogil=True, inline="always")
def _exact(k, denom, d, a, o, inv, res, fused, recip):
    """The float32 rule's cell of sample ``k`` along one axis."""
    t = np.float32(k) / denom
    return np.int64(_cell(_along(t, d, a, fused), o, inv, res, recip))


@numba.njit(cache=True, nogil=True, inline="always")
def _reversed(k, denom, d, b, o, inv, res, fused, recip):
    """The float32 rule's cell, along one axis, of the reversed edge's sample at this edge's
    sample ``k`` (the reversed edge starts at ``b`` and goes by ``-d``)."""
    u = np.float32(np.float32(denom) - np.float32(k)) / denom
    return np.int64(_cell(_along(u, -d, b, fused), o, inv, res, recip))


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_at(k, f0, df, slack, denom, d, a, b, o, inv, res, fused, recip, both):
    """(the rule's cell of sample ``k`` along one axis, whether the reversed edge puts it in the
    same cell): the real-number sample's cell, or the float32 rule's where the sample lies
    within ``slack`` cells of a border (only there can the reversed edge's differ; compared
    when ``both``)."""
    f = f0 + k * df
    c = np.floor(f)
    if f - c < slack or c + 1.0 - f < slack:
        e = _exact(k, denom, d, a, o, inv, res, fused, recip)
        return e, not both or _reversed(k, denom, d, b, o, inv, res, fused, recip) == e
    return np.int64(c), True


@numba.njit(cache=True, nogil=True, inline="always")
def _any_bit(bits, v, c0, c1):
    """Whether any of bits ``c0 .. c1`` (0 <= c0 <= c1) of row ``v`` of the bit rows ``bits``
    is set."""
    w0 = c0 >> 6
    w1 = c1 >> 6
    lo = np.uint64(0xFFFFFFFFFFFFFFFF) << np.uint64(c0 & 63)
    hi = np.uint64(0xFFFFFFFFFFFFFFFF) >> np.uint64(63 - (c1 & 63))
    if w0 == w1:
        return (bits[v, w0] & lo & hi) != 0
    if bits[v, w0] & lo:
        return True
    for w in range(w0 + 1, w1):
        if bits[v, w]:
            return True
    return (bits[v, w1] & hi) != 0


@numba.njit(cache=True, nogil=True, inline="always")
def _lines(rowbits, colbits, H, W, ax, ay, bx, by, S, origin, inv, res, fused, recip, both):
    """The edge rule (:func:`_walk`) on the edge (ax, ay) -> (bx, by) read a line of cells at a
    time: (1 clear, 0 blocked, -1 where a line's first sample is unsure over too much of a step
    (:data:`_SLOW`) or the edge is long (:data:`_LONG`): the caller reads it by samples; with
    ``both``, whether the reversed edge (bx, by) -> (ax, ay) surely has the same answer).

    Lines are the grid's rows for an edge flatter than 45 degrees, else its columns. The samples
    of one line lie in a run of cells, one cell apart at most (samples are at most half a cell
    apart); with both side cells of each diagonal step, the rule reads in line ``v`` every cell
    from the one of the last sample of the line before to the one of the first sample of the
    line after (a straight step adds nothing): one test of a bit range. ``rowbits`` (H + 2, .)
    uint64: the grid's rows as bits, off-map cells around it set; ``colbits`` (W + 2, .): its
    columns so. Each sample's cell is the real-number sample's, made exact by the float32 rule
    where the sample lies within :data:`_SLACK` of a border.

    The reversed edge's samples are these but for their rounding, which can move only a sample
    near a border. Its lines hold the same samples where the samples next to each change of line
    (and the first and last) lie in the same line either way, and read the same cells where the
    samples that end each line's range lie in the same cell either way: only those are compared.
    A blocked answer needs only the lines read up to its blocked one to agree (the reversed edge
    reads that line the same, or stops before it)."""
    ox, oy = origin[0], origin[1]
    dx = bx - ax
    dy = by - ay
    denom = np.float32(S - 1)
    ir = 1.0 / np.float64(res)
    per = ir / (S - 1)
    fx0 = (np.float64(ax) - np.float64(ox)) * ir
    fy0 = (np.float64(ay) - np.float64(oy)) * ir
    dfx = np.float64(dx) * per
    dfy = np.float64(dy) * per
    ex = _SLACK * ir * (abs(np.float64(ax)) + abs(np.float64(dx)) + abs(np.float64(ox)))
    ey = _SLACK * ir * (abs(np.float64(ay)) + abs(np.float64(dy)) + abs(np.float64(oy)))
    if abs(dfy) <= abs(dfx):  # lines are rows
        bits, HV, HU = rowbits, H, W
        u0, du, eu, ua, ub, ud, uo = fx0, dfx, ex, ax, bx, dx, ox
        v0, dv, ev, va, vb, vd, vo = fy0, dfy, ey, ay, by, dy, oy
    else:
        bits, HV, HU = colbits, W, H
        u0, du, eu, ua, ub, ud, uo = fy0, dfy, ey, ay, by, dy, oy
        v0, dv, ev, va, vb, vd, vo = fx0, dfx, ex, ax, bx, dx, ox
    iv = 1.0 / dv if dv != 0 else 0.0
    mv = ev * abs(iv)
    if mv > _SLOW or abs(du) * (S - 1) > _LONG:
        return -1, False
    v, sure = _cell_at(0, v0, dv, ev, denom, vd, va, vb, vo, inv, res, fused, recip, both)
    lo, same = _cell_at(0, u0, du, eu, denom, ud, ua, ub, uo, inv, res, fused, recip, both)
    sure = sure and same
    step = 1 if dv > 0 else -1
    k = 0
    while True:
        kn = S
        if dv != 0:
            ks = (v + (1 if dv > 0 else 0) - v0) * iv  # the real sample index at the next border
            if ks < S + 1:
                kr = np.floor(ks + 0.5)
                if abs(ks - kr) > mv:
                    kn = np.int64(np.ceil(ks))
                elif kr > S - 1:
                    kn = S
                else:
                    i = np.int64(kr)
                    e = _exact(i, denom, vd, va, vo, inv, res, fused, recip)
                    kn = i if e != v else i + 1
                    if both:
                        sure = sure and _reversed(i, denom, vd, vb, vo, inv, res, fused, recip) == e
                kn = min(max(kn, k + 1), S)
        hi, same = _cell_at(min(kn, S - 1), u0, du, eu, denom, ud, ua, ub, uo, inv, res, fused, recip, both)
        sure = sure and same
        c0, c1 = (lo, hi) if lo <= hi else (hi, lo)
        if v < 0 or v >= HV or c0 < -1 or c1 > HU:
            return 0, sure
        if _any_bit(bits, v + 1, c0 + 1, c1 + 1):
            return 0, sure
        if kn >= S:
            return 1, sure
        lo, same = _cell_at(kn - 1, u0, du, eu, denom, ud, ua, ub, uo, inv, res, fused, recip, both)
        sure = sure and same
        v += step
        k = kn

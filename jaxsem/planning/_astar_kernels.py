"""The compiled kernels of :mod:`jaxsem.planning._astar` (numba, cached on disk by numba: a
module of their own, imported on first use, so that ``import jaxsem`` does not import numba)."""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def entry_length(p, r, c):
    """The length of the edge between points ``p[r]`` and ``p[c]`` in their dtype, as the
    roadmap computes an edge's (``sqrt(dx * dx + dy * dy + 1e-30)``), as float64."""
    dx = p[c, 0] - p[r, 0]
    dy = p[c, 1] - p[r, 1]
    return np.float64(np.sqrt(dx * dx + dy * dy + p.dtype.type(1e-30)))


# A roadmap's search graph (:func:`jaxsem.planning._astar.search_graph`) is made in three passes,
# each over a block of search ids at a time (blocks may run on threads of their own, one pass
# after the other): every kept entry (r, s) of ``nbr`` (M, K) (slots) becomes an edge both ways,
# listed by search id (``order``: search id -> slot, ``rank``: slot -> search id) with the other
# end's search id, its weight and its entry id r * K + s in the roadmap's rows. Weights:
# ``w[r, s]``, or with ``use_lengths`` the entries' lengths (:func:`entry_length`, at least 1e-12;
# ``w`` is not read). A vertex lists the entries of rows earlier in search order that name it,
# then its own row's, then those of later rows, each list at its own place in one buffer
# (``start``, ``stop``: a list may end before the next one starts).


@numba.njit(cache=True, nogil=True)
def adjacency_count(nbr, keep, w, p, order, rank, use_lengths, i0, i1, into, own):
    """The first pass over search ids ``i0 .. i1``: ``into[rank[c] + 1]`` counts the entries
    naming each vertex ``c`` (added to what ``into`` holds), ``own[i]`` the kept entries of row
    ``order[i]``. Returns the smallest weight / length over the block's entries (inf if none
    has a length; 1 with ``use_lengths``)."""
    K = nbr.shape[1]
    ratio = np.inf
    for i in range(i0, i1):
        r = order[i]
        n = 0
        for s in range(K):
            if keep[r, s]:
                c = nbr[r, s]
                into[rank[c] + 1] += 1
                n += 1
                if not use_lengths:
                    dx = np.float64(p[c, 0]) - np.float64(p[r, 0])
                    dy = np.float64(p[c, 1]) - np.float64(p[r, 1])
                    length = np.sqrt(dx * dx + dy * dy)
                    if length > 0:
                        ratio = min(ratio, w[r, s] / length)
        own[i] = n
    return ratio


@numba.njit(cache=True, nogil=True)
def adjacency_scatter(nbr, keep, w, p, order, rank, use_lengths, i0, i1, fill, src, rwt, reid):
    """The second pass over search ids ``i0 .. i1``: each kept entry written at ``fill`` of the
    vertex it names (then moved on): the naming row's search id ``src``, the weight ``rwt``, the
    entry id ``reid`` (a counting sort by the named vertex)."""
    K = nbr.shape[1]
    for i in range(i0, i1):
        r = order[i]
        for s in range(K):
            if keep[r, s]:
                c = np.int64(nbr[r, s])
                j = np.int64(rank[c])
                at = fill[j]
                src[at] = i
                rwt[at] = max(entry_length(p, r, c), 1e-12) if use_lengths else w[r, s]
                reid[at] = r * K + s
                fill[j] += 1


@numba.njit(cache=True, nogil=True)
def adjacency_lists(
    nbr, keep, w, p, order, rank, use_lengths, once, i0, i1, into, src, rwt, reid, start, adj, wt, eid, stop
):
    """The third pass: the lists of search ids ``i0 .. i1``, vertex ``i``'s written from
    ``start[i]`` (room for the ``into[i + 1] - into[i]`` entries naming it and its own row's) to
    ``stop[i]``. ``once``: of a vertex's entries to one other end with one weight (an edge both
    its ends chose) only the first stays; a search that never skips an entry reads the same
    (the second relaxes nothing the first did not)."""
    M, K = nbr.shape
    last = np.full(M, -1, np.int64)  # the vertex whose list last named each end
    first = np.zeros(M, np.int64)  # where that entry went
    for i in range(i0, i1):
        r = order[i]
        e = into[i]
        n = start[i]
        # Rows earlier than i that name it, its own row, then later rows.
        while e < into[i + 1] and src[e] < i:
            n = _put(adj, wt, eid, last, first, n, i, src[e], rwt[e], reid[e], once)
            e += 1
        for s in range(K):
            if keep[r, s]:
                c = np.int64(nbr[r, s])
                x = max(entry_length(p, r, c), 1e-12) if use_lengths else w[r, s]
                n = _put(adj, wt, eid, last, first, n, i, rank[c], x, r * K + s, once)
        while e < into[i + 1]:
            n = _put(adj, wt, eid, last, first, n, i, src[e], rwt[e], reid[e], once)
            e += 1
        stop[i] = n


@numba.njit(cache=True, nogil=True, inline="always")
def _put(adj, wt, eid, last, first, n, a, b, x, e, once):
    """Appends the entry (other end ``b``, weight ``x``, entry id ``e``) to vertex ``a``'s list
    (written at ``n``) unless ``once`` and the list already holds ``b`` with weight ``x``.
    Returns the new count."""
    if once and last[b] == a and wt[first[b]] == x:
        return n
    last[b] = a
    first[b] = n
    adj[n] = b
    wt[n] = x
    eid[n] = e
    return n + 1


@numba.njit(cache=True, nogil=True)
def z_order(p, fixed):
    """Slot ids (M,) of the points ``p`` (M, 2) float64 (finite): the first ``fixed`` in place,
    the rest sorted by the Z-order (Morton) code of each point's cell on a 1024 x 1024 grid over
    their box; ties keep slot order (a stable radix sort of the 20-bit codes, 10 bits a pass)."""
    M = p.shape[0]
    out = np.arange(M)
    if M <= fixed:
        return out
    lo0, lo1, hi0, hi1 = p[fixed, 0], p[fixed, 1], p[fixed, 0], p[fixed, 1]
    for i in range(fixed + 1, M):
        lo0, hi0 = min(lo0, p[i, 0]), max(hi0, p[i, 0])
        lo1, hi1 = min(lo1, p[i, 1]), max(hi1, p[i, 1])
    span = max(max(hi0 - lo0, hi1 - lo1), 1e-300)
    code = np.zeros(M, np.int64)
    for i in range(fixed, M):
        cx = np.int64(min(max((p[i, 0] - lo0) / span * 1023.0, 0.0), 1023.0))
        cy = np.int64(min(max((p[i, 1] - lo1) / span * 1023.0, 0.0), 1023.0))
        z = 0
        for bit in range(10):
            z |= ((cx >> bit) & 1) << (2 * bit)
            z |= ((cy >> bit) & 1) << (2 * bit + 1)
        code[i] = z
    tmp = np.empty(M - fixed, np.int64)
    keys = out[fixed:].copy()
    for shift in (0, 10):
        count = np.zeros(1025, np.int64)
        for i in range(M - fixed):
            count[((code[keys[i]] >> shift) & 1023) + 1] += 1
        for d in range(1024):
            count[d + 1] += count[d]
        for i in range(M - fixed):
            d = (code[keys[i]] >> shift) & 1023
            tmp[count[d]] = keys[i]
            count[d] += 1
        keys, tmp = tmp, keys
    out[fixed:] = keys
    return out


#: ``where`` of a vertex never queued / closed (else its slot in the heap).
_NEW, _CLOSED = -1, -2


@numba.njit(cache=True, nogil=True, inline="always")
def push(hf, hn, where, size, f, v):
    """Gives vertex ``v`` the key ``f`` in the binary min-heap (keys ``hf``, vertices ``hn``, the
    first ``size`` in use; ``where[v]``: v's slot, :data:`_NEW` if not queued): added, or moved
    up when queued with a larger key (a vertex is queued once, so the heap never holds more
    than the vertices). Returns the new size. Only sizes go in and out: arrays handed back
    from a compiled call are reference-counted on every call."""
    j = where[v]
    if j < 0:
        j = size
        size += 1
    while j > 0:
        p = (j - 1) >> 1
        if hf[p] <= f:
            break
        hf[j] = hf[p]
        hn[j] = hn[p]
        where[hn[j]] = j
        j = p
    hf[j] = f
    hn[j] = v
    where[v] = j
    return size


@numba.njit(cache=True, nogil=True)
def to_goal(px, py, v, gx, gy):
    """The straight-line distance from vertex ``v`` to the goal (gx, gy)."""
    dx = px[v] - gx
    dy = py[v] - gy
    return np.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, nogil=True, inline="always")
def pop(hf, hn, where, size):
    """Removes the heap's smallest key; its vertex is marked :data:`_CLOSED`. Returns (key,
    vertex, size)."""
    f = hf[0]
    u = hn[0]
    where[u] = _CLOSED
    size -= 1
    if size == 0:
        return f, u, size
    last_f = hf[size]
    last_n = hn[size]
    j = 0
    while 2 * j + 1 < size:
        ch = 2 * j + 1
        if ch + 1 < size and hf[ch + 1] < hf[ch]:
            ch += 1
        if hf[ch] >= last_f:
            break
        hf[j] = hf[ch]
        hn[j] = hn[ch]
        where[hn[j]] = j
        j = ch
    hf[j] = last_f
    hn[j] = last_n
    where[last_n] = j
    return f, u, size


@numba.njit(cache=True, nogil=True)
def astar(start, stop, adj, wt, eid, usable, px, py, c, s_dst, s_w, g_dst, g_w, gx, gy):
    """(cost, path START ... GOAL) of the shortest path over the lists ``start``, ``stop``,
    ``adj``, ``wt`` (vertex ``v``'s entries from ``start[v]`` to ``stop[v]``; those whose flag
    ``usable[eid]`` is set) plus the start's edges ``s_dst``, ``s_w`` and the
    goal's entries ``g_dst``, ``g_w``, by A* with the heuristic ``c * |x - (gx, gy)|``;
    (inf, empty) if there is none."""
    M = px.shape[0]
    g = np.full(M, np.inf)
    pred = np.full(M, -1, np.int64)
    where = np.full(M, _NEW, np.int64)
    enter = np.full(M, np.inf)
    for i in range(g_dst.shape[0]):
        if g_w[i] < enter[g_dst[i]]:
            enter[g_dst[i]] = g_w[i]
    hf = np.empty(M, np.float64)
    hn = np.empty(M, np.int64)
    size = 0
    best = np.inf
    via = -2  # -2: none; -1: the start's own edge to the goal; else the vertex entering it
    for i in range(s_dst.shape[0]):
        v = s_dst[i]
        if v == 1:
            if s_w[i] < best:
                best = s_w[i]
                via = -1
        elif 2 <= v < M and s_w[i] < g[v]:
            g[v] = s_w[i]
            pred[v] = 0
            size = push(hf, hn, where, size, s_w[i] + c * to_goal(px, py, v, gx, gy), v)
    while size > 0 and hf[0] < best:
        _, u, size = pop(hf, hn, where, size)
        gu = g[u]
        if gu + enter[u] < best:
            best = gu + enter[u]
            via = u
        for e in range(start[u], stop[u]):
            v = adj[e]
            if where[v] != _CLOSED and usable[eid[e]]:
                nd = gu + wt[e]
                if nd < g[v]:
                    g[v] = nd
                    pred[v] = u
                    size = push(hf, hn, where, size, nd + c * to_goal(px, py, v, gx, gy), v)
    if via == -2:
        return np.inf, np.zeros(0, np.int64)
    n = 2
    node = via
    while node > 0:
        n += 1
        node = pred[node]
    path = np.empty(n, np.int64)
    path[0] = 0
    path[n - 1] = 1
    node = via
    i = n - 2
    while node > 0:
        path[i] = node
        i -= 1
        node = pred[node]
    return best, path

"""The per-map setup a roadmap reads (made once per known map and kept for the latest two):
the map on the device, uniform sampling's free-cell words, and the edge check's clearance table,
whole or in windows around a query (:class:`_MapSetup`, :func:`_map_setup`,
:func:`clear_map_cache`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from ._edges import _BASE, _TOP, _bit_grids, _clearance_table_np
from ._sampling import _cdf, _free_words_of_blocked, _sampling_weights


class _MapAids(NamedTuple):
    """What a jitted grow or query reads of the per-map setup (:class:`_MapSetup`; None where
    that step needs no such part): the edge check's clearance table, and uniform sampling's
    free-cell words and their running counts (:func:`_free_words`) or, on maps where those do
    not apply, its cumulative weights."""

    table: jax.Array | None
    free_words: jax.Array | None
    free_counts: jax.Array | None
    uniform_cdf: jax.Array | None


_uniform_cdf_jit = jax.jit(lambda blocked, dtype: _cdf(_sampling_weights(blocked, None), dtype), static_argnums=1)


def _aligned(a: np.ndarray) -> jax.Array:
    """``a`` on the device. On a CPU backend a 64-byte aligned array is taken without a copy
    (an unaligned one costs a copy into fresh pages: milliseconds for a map); only for arrays
    nobody writes to afterwards."""
    a = np.ascontiguousarray(a)
    if a.ctypes.data % 64:
        buf = np.empty(a.nbytes + 64, np.uint8)
        off = (-buf.ctypes.data) % 64
        out = buf[off : off + a.nbytes].view(a.dtype).reshape(a.shape)
        out[...] = a
        a = out
    return jax.device_put(a)


def _aligned_zeros(shape, dtype) -> np.ndarray:
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    buf = np.zeros(nbytes + 64, np.uint8)
    off = (-buf.ctypes.data) % 64
    return buf[off : off + nbytes].view(dtype).reshape(shape)


#: A query's windows covering more than 1 / this of the map make the whole table instead.
_WHOLE_TABLE_SHARE = 4


class _MapSetup:
    """The per-map setup of one known map (bool grid ``blocked``, kept as a private copy: the
    cache's key), made once and shared by the roadmaps on that map: its device copy, uniform
    sampling's free-cell words (made at once: a fraction of a millisecond), and the edge
    check's clearance table, made on first use (:meth:`table`): a lazy PRM checks no edge
    while it grows, and its query's start and goal edges need the table only around them
    (:meth:`query_table`), so a first lazy build on a new map does without the whole table."""

    def __init__(self, blocked: np.ndarray, dtype, near: _MapSetup | None = None, owned: bool = False):
        if owned:  # the caller's fresh grid, kept as it is (and made read-only: it is the key)
            self.blocked = np.asarray(blocked, bool)
            self.blocked.flags.writeable = False
        else:
            self.blocked = np.array(blocked, bool)
        self.dtype = np.dtype(dtype)
        self.blocked_j = _aligned(self.blocked)
        self._words = self._counts = self._cdf = None
        words, counts = _free_words_of_blocked(self.blocked) if self.blocked.size < 2**24 else (None, None)
        if words is not None and counts is not None and counts[-1] > 0:
            self.free_cells = int(counts[-1])
            self._words, self._counts = _aligned(words), _aligned(counts)
        else:  # nothing free (sampling falls back to every cell) or counts past float32's integers
            self.free_cells = int(self.blocked.size - np.count_nonzero(self.blocked))
            self._cdf = _uniform_cdf_jit(self.blocked_j, self.dtype)
        self._table: jax.Array | None = None
        self._table_np: np.ndarray | None = None
        self._bits: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        # A map of the same shape seen lately whose table is made (a robot's map between two
        # looks differs in a window): that table is updated there instead of made anew, if
        # this map's is needed. Held until then only (never a chain of maps).
        same = near is not None and near._table_np is not None and near.blocked.shape == self.blocked.shape
        self._near = near if same else None

    def bits(self, make: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The map's rows and columns as bits for the host's edge rule
        (:func:`~jaxsem.planning._edges._bit_grids`), made on the first call with ``make`` (a
        grow's thousands of edges; a query's few on a map seen once are read without: None)."""
        if self._bits is None and make:
            self._bits = _bit_grids(self.blocked)
        return self._bits

    @property
    def has_table(self) -> bool:
        return self._table is not None

    def table(self) -> jax.Array:
        """The clearance table of the whole map (:func:`_clearance_table_np`: the jitted
        table's values), made on the first call."""
        if self._table is None:
            near = self._near
            if near is not None and near._table_np is not None:  # (set with its table)
                self._table_np = _table_update(near._table_np, near.blocked, self.blocked)
            else:
                self._table_np = _clearance_table_np(self.blocked)
            self._table = _aligned(self._table_np)
            self._near = None
        return self._table

    def aids(self, table: bool) -> _MapAids:
        """The sampling parts, and the whole table when ``table``."""
        return _MapAids(self.table() if table else None, self._words, self._counts, self._cdf)

    def query_table(self, boxes) -> jax.Array:
        """A clearance table for edges inside ``boxes`` ((row0, row1, col0, col1) cell ranges,
        ends excluded): the whole map's when it is made (or the boxes cover a quarter of the
        map, :data:`_WHOLE_TABLE_SHARE`: then it is made and kept), else one with values only in the boxes (widened to
        whole top-level blocks), each made on its own window with the cells outside the window
        counted as blocked, and 0 elsewhere. Every value is a lower bound of the whole table's
        (the window's obstacles include the map's), and the edge check reads the rule's samples
        wherever the table cannot vouch for them, so its answers are the same with either
        table; only what it reads differs."""
        H, W = self.blocked.shape
        top = 1 << _TOP
        wins = []
        for r0, r1, c0, c1 in boxes:
            r0, c0 = max(0, int(r0)) // top * top, max(0, int(c0)) // top * top
            r1, c1 = min(H, -(-int(r1) // top) * top), min(W, -(-int(c1) // top) * top)
            if r0 < r1 and c0 < c1:
                wins.append((r0, r1, c0, c1))
        area = sum((r1 - r0) * (c1 - c0) for r0, r1, c0, c1 in wins)
        if self._table is not None or _WHOLE_TABLE_SHARE * area >= H * W:
            return self.table()
        b = 1 << _BASE
        out = _aligned_zeros((-(-H // top) * top // b, -(-W // top) * top // b), np.int32)
        for r0, r1, c0, c1 in wins:
            sub = _clearance_table_np(self.blocked[r0:r1, c0:c1])
            h, w = -(-(r1 - r0) // b), -(-(c1 - c0) // b)
            dst = out[r0 // b : r0 // b + h, c0 // b : c0 // b + w]
            np.maximum(dst, sub[:h, :w], out=dst)
        return jax.device_put(out)


#: Cells past a changed cell whose clearance-table entries can change: a level-``_TOP`` block's
#: 3 x 3 neighbourhood reaches ``2 * 2**_TOP - 1`` cells past a cell of its middle block, and
#: the 8-neighbour dilation one more.
_TABLE_REACH = 2 * (1 << _TOP) + 1


def _table_update(table: np.ndarray, old: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """:func:`_clearance_table_np` of ``blocked`` from ``table``, that of ``old`` (same shape):
    the entries within :data:`_TABLE_REACH` cells of a changed cell are made again, from a
    window of the map reaching as far again past them (aligned to top-level blocks, so its
    blocks are the map's; the cells it leaves out count as blocked there, which can lower only
    entries beyond the ones kept). The same values as making it anew."""
    diff = old != blocked
    rows, cols = np.flatnonzero(diff.any(axis=1)), np.flatnonzero(diff.any(axis=0))
    if len(rows) == 0:
        return table
    H, W = blocked.shape
    top, b = 1 << _TOP, 1 << _BASE
    lo = lambda x: max(0, x) // top * top
    hi = lambda x, n: min(-(-n // top) * top, -(-x // top) * top)
    # Entries to remake (cells [r0, r1) x [c0, c1)), and the window they are made from.
    r0, r1 = lo(rows[0] - _TABLE_REACH), hi(rows[-1] + 1 + _TABLE_REACH, H)
    c0, c1 = lo(cols[0] - _TABLE_REACH), hi(cols[-1] + 1 + _TABLE_REACH, W)
    wr0, wr1 = lo(r0 - _TABLE_REACH), hi(r1 + _TABLE_REACH, H)
    wc0, wc1 = lo(c0 - _TABLE_REACH), hi(c1 + _TABLE_REACH, W)
    sub = _clearance_table_np(blocked[wr0 : min(wr1, H), wc0 : min(wc1, W)])
    out = table.copy()
    out[r0 // b : r1 // b, c0 // b : c1 // b] = sub[
        (r0 - wr0) // b : (r1 - wr0) // b, (c0 - wc0) // b : (c1 - wc0) // b
    ]
    return out


#: Per-map setup of the latest maps, newest first. A user who builds several roadmaps on one
#: map (or a map that comes back) makes it once.
_AIDS_CACHE: list[_MapSetup] = []
#: Maps whose setup is kept (each costs ~6 bytes per cell).
_AIDS_CACHE_SIZE = 2


def clear_map_cache() -> None:
    """Forgets the per-map setup (clearance table, sampling aids) that :class:`PRM` keeps
    for the latest maps it was built or updated on: frees their memory, and lets a timing see
    what a PRM on a map not seen before costs."""
    _AIDS_CACHE.clear()


def _same_cells(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the bool grids ``a`` and ``b`` are the same cell for cell, compared eight cells
    to a word (a map of millions of cells: a tenth of a cell-by-cell compare's time)."""
    if a.shape != b.shape:
        return False
    a, b = np.ascontiguousarray(a, bool).reshape(-1), np.ascontiguousarray(b, bool).reshape(-1)
    n = a.size // 8 * 8
    return np.array_equal(a[:n].view(np.uint64), b[:n].view(np.uint64)) and np.array_equal(a[n:], b[n:])


def _map_setup(blocked: np.ndarray, dtype, owned: bool = False) -> _MapSetup:
    """The :class:`_MapSetup` of the bool grid ``blocked`` (numpy): from :data:`_AIDS_CACHE`
    when the same map (cell for cell) and dtype were seen lately, else made and kept.
    ``owned``: ``blocked`` is the caller's own fresh grid, which nobody changes afterwards
    (kept without a copy, made read-only)."""
    dt = np.dtype(dtype)
    for i, setup in enumerate(_AIDS_CACHE):
        if setup.dtype == dt and _same_cells(setup.blocked, blocked):
            _AIDS_CACHE.insert(0, _AIDS_CACHE.pop(i))
            return setup
    near = next((x for x in _AIDS_CACHE if x.blocked.shape == blocked.shape and x.has_table), None)
    setup = _MapSetup(blocked, dt, near, owned=owned)
    _AIDS_CACHE.insert(0, setup)
    del _AIDS_CACHE[_AIDS_CACHE_SIZE:]
    return setup

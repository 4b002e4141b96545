"""Where a roadmap's vertices come from: inverse-CDF sampling of a cell distribution restricted to
cells not known occupied, the ``-log p`` cost grid, and a robot-centred (LSD) window embedded
in the full map (thesis 3.2.5). Part of the PRM (:mod:`jaxsem.planning._roadmap` has the design).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics as Q
from .._checks import require_type


def _cdf(distribution, dtype):
    """The flattened cumulative weights :func:`sample_points` draws from."""
    # associative_scan, not cumsum: XLA's CPU cumsum is a quadratic reduce-window.
    return jax.lax.associative_scan(jnp.add, distribution.reshape(-1).astype(dtype))


def sample_points(key, distribution, n: int, grid: Q.Grid, cdf=None):
    """``n`` world points (n, 2): a cell drawn with probability ``distribution`` (H, W) (need
    not be normalised, must be >= 0), then a uniform point inside the cell of ``grid`` (a
    :class:`jaxsem.quadrics.Grid` of ``distribution``'s shape; the points take its origin's
    dtype). ``cdf``: its :func:`_cdf` when the caller keeps it. Without it the same inverse-CDF
    search runs in two levels (rows, then inside the row), which reads the map once instead of
    scanning it; a draw may then land in the next cell where rounding of the running sums
    differs at a cell boundary (a cell without weight is never drawn: where the rounding raises
    a running mass at one, the draw goes to the last weighted cell before it). Jittable."""
    grid = require_type("grid", grid, Q.Grid)
    if tuple(grid.shape) != tuple(distribution.shape):
        raise ValueError(f"grid: expected the distribution's shape {tuple(distribution.shape)}, got {grid.shape}")
    H, W = distribution.shape
    dtype = grid.origin.dtype
    k_cell, k_in = jax.random.split(key)
    if cdf is not None:
        u = jax.random.uniform(k_cell, (n,), dtype) * cdf[-1]
        flat = jnp.clip(jnp.searchsorted(cdf, u, side="right"), 0, H * W - 1)
        return _in_cells(k_in, flat, grid)
    return _in_cells(k_in, _grid_cells(k_cell, distribution, n, dtype), grid)


def _grid_cells(k_cell, distribution, n: int, dtype):
    """The flat cells (n,) int32 of :func:`sample_points`' two-level draws (before each is given
    a uniform point inside its cell): the rows' running masses, then the running mass inside
    each draw's row, n x W sums instead of a scan over every cell of the map."""
    H, W = distribution.shape
    w = distribution.astype(dtype)
    row = jnp.sum(w, axis=1)
    rows_cdf = jax.lax.associative_scan(jnp.add, row)
    u = jax.random.uniform(k_cell, (n,), dtype) * rows_cdf[-1]
    r = jnp.clip(jnp.searchsorted(rows_cdf, u, side="right"), 0, H - 1).astype(jnp.int32)
    # The scans' rounding can raise a running mass at a row or cell without weight (or leave
    # the target past a total): a draw then goes to the last one with weight at or before it
    # (the first one, if none is), so a cell without weight is never drawn.
    r = _weighted_at_or_before(row > 0, r)
    before = jnp.where(r > 0, rows_cdf[jnp.maximum(r - 1, 0)], 0.0)
    wr = w[r]  # (n, W)
    inside = jax.lax.associative_scan(jnp.add, wr, axis=1)
    c = jnp.minimum(jnp.sum(inside <= (u - before)[:, None], axis=1, dtype=jnp.int32), W - 1)
    c = jax.vmap(_weighted_at_or_before)(wr > 0, c)
    return r * W + c


def _weighted_at_or_before(has, i):
    """For indices ``i`` into the flags ``has`` (m,): the last index at or before each with a
    flag set, or the first set one when none is."""
    idx = jnp.arange(has.shape[0], dtype=jnp.int32)
    at_or_before = jax.lax.associative_scan(jnp.maximum, jnp.where(has, idx, -1))
    return jnp.where(at_or_before[i] >= 0, at_or_before[i], jnp.argmax(has).astype(jnp.int32))


def _in_cells(k_in, flat, grid):
    """A uniform point inside each of the flat cell indices ``flat`` (n,) of ``grid``."""
    n, W = flat.shape[0], grid.shape[1]
    rc = jnp.stack([flat // W, flat % W], -1)
    jitter = jax.random.uniform(k_in, (n, 2), grid.origin.dtype)
    return Q.cell_to_world(rc, grid.origin, grid.resolution, offset=jitter)


def _free_words(free) -> tuple[np.ndarray, np.ndarray]:
    """Uniform sampling's per-map setup for a flat bool grid ``free`` (the cells samples may
    land in): the cells as bits of uint32 words (bit ``i`` of word ``j``: cell ``32 j + i``) and
    each word's running count of free cells, inclusive (int32). A few hundred kilobytes for a
    map of millions of cells, made in well under a millisecond: the CDF over every cell that
    :func:`sample_points` searches is 4 bytes a cell and its cumsum costs ~10x more."""
    return _words_and_counts(np.packbits(np.asarray(free, bool).reshape(-1), bitorder="little"))


def _free_words_of_blocked(blocked) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_free_words` of the cells not ``blocked`` (a bool grid), without a negated copy of
    the grid: its bits packed and flipped, the bits past its last cell cleared."""
    blocked = np.asarray(blocked, bool).reshape(-1)
    b = np.packbits(blocked, bitorder="little")
    np.invert(b, out=b)
    tail = blocked.size % 8
    if tail:
        b[-1] &= np.uint8((1 << tail) - 1)
    return _words_and_counts(b)


def _words_and_counts(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Packed bytes of free flags (little bit order) as :func:`_free_words`' words and counts."""
    b = np.concatenate([b, np.zeros(-len(b) % 4, np.uint8)])
    words = b.view("<u4").astype(np.uint32)
    if hasattr(np, "bitwise_count"):  # numpy >= 2
        per = np.bitwise_count(words)
    else:  # each byte's count, the 4 summed into the top byte by one multiply
        per = (_POPCOUNT[b].view("<u4").astype(np.uint32) * np.uint32(0x01010101)) >> np.uint32(24)
    return words, np.cumsum(per, dtype=np.int32)


#: Set bits of each byte value.
_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], np.uint8)
#: Masks of bits 0 .. j of a uint32 word, j = 0 .. 31.
_LOW_BITS = np.array([(1 << (j + 1)) - 1 for j in range(32)], np.uint64).astype(np.uint32)


def _rank_to_flat(words, counts, rank):
    """The flat index of the free cell of each rank ``rank`` (n,) int32 (0 is the first free cell
    in flat order), from :func:`_free_words` ``(words, counts)``; ranks at or past the free count
    give the last word's bits past its last free cell (callers clip)."""
    wi = jnp.minimum(jnp.searchsorted(counts, rank, side="right"), counts.shape[0] - 1)
    word = words[wi]
    below = rank - (counts[wi] - jax.lax.population_count(word).astype(jnp.int32))  # rank in the word
    upto = jax.lax.population_count(word[:, None] & jnp.asarray(_LOW_BITS)[None, :]).astype(jnp.int32)
    bit = jnp.sum(upto <= below[:, None], axis=1, dtype=jnp.int32)
    return wi * 32 + bit


def _free_before(words, counts, flat):
    """How many free cells come before each flat index ``flat`` (int32, on the grid) in flat
    order (:func:`_free_words`' ``(words, counts)``)."""
    wi = flat // 32
    word = words[wi]
    low = jnp.where(flat % 32 > 0, jnp.asarray(_LOW_BITS)[jnp.maximum(flat % 32 - 1, 0)], jnp.uint32(0))
    before_word = counts[wi] - jax.lax.population_count(word).astype(jnp.int32)
    return before_word + jax.lax.population_count(word & low).astype(jnp.int32)


def sample_free_cells(key, words, counts, n: int, grid):
    """The draws of :func:`sample_points` over the uniform weights of the free cells, point for
    point (same ``key``, same cells, same jitter), from :func:`_free_words` ``(words, counts)``
    of a map on ``grid`` (H, W) with fewer than 2**24 cells and at least one free: there the CDF
    holds exact integers, so the cell the CDF search finds for a draw ``u`` is the free cell of
    rank ``floor(u)`` (the last cell when ``u`` rounds up to the free count, as the search's
    clip gives). Jittable."""
    H, W = grid.shape
    dtype = grid.origin.dtype
    k_cell, k_in = jax.random.split(key)
    total = counts[-1]
    u = jax.random.uniform(k_cell, (n,), dtype) * total.astype(dtype)
    rank = jnp.floor(u).astype(jnp.int32)
    flat = jnp.where(rank < total, _rank_to_flat(words, counts, rank), H * W - 1)
    return _in_cells(k_in, flat, grid)


def _cost_grid(distribution):
    p = distribution / jnp.sum(distribution)
    return -jnp.log(jnp.maximum(p, 1e-30))


def _sampling_weights(blocked, distribution):
    """Cell weights restricted to cells not known occupied (falls back to all free cells when
    the distribution has no mass there, and to the whole map when nothing is free)."""
    free = (~blocked).astype(jnp.result_type(float))
    if distribution is None:
        w = free
    else:
        w = distribution * free
        w = jnp.where(jnp.sum(w) > 0, w, free)
    return jnp.where(jnp.sum(w) > 0, w, jnp.ones_like(w))


def embed_local_distribution(local, center_cell, full_shape, outside_mass=None, on_map=None):
    """Embeds a robot-centred local distribution into the full map (thesis section 3.2.5).

    local: (h, w) probabilities (e.g. the network's 160 x 160 softmax), centred on the robot's
    cell ``center_cell`` (row, col) of the full map (the local cell [h // 2, w // 2] is the
    robot's); full_shape: (H, W). Cells outside the window get the window's minimum; the result
    (H, W) is renormalised to sum to 1. Jittable (``center_cell`` may be traced).

    outside_mass: None (the thesis' rule above) or a share ``q`` in [0, 1) (a variant): the
    cells outside the window share ``q`` equally and the window's on-map cells keep the rest in
    their own proportions (when the window covers the whole map, the window alone, renormalised).

    on_map: None (every cell of ``full_shape`` is the map's) or (2,) ints (rows, cols), maybe
    traced: the map fills only those leading rows and columns of a padded ``full_shape`` (the
    navigation loop pads maps to a size bucket so that one compiled program serves several
    shapes); the padding gets no mass and is not counted among the cells outside the window.
    """
    local = jnp.asarray(local)
    h, w = local.shape
    H, W = full_shape
    pad_r, pad_c = h, w
    if outside_mass is not None and not isinstance(outside_mass, jax.Array):
        if not 0.0 <= float(outside_mass) < 1.0:
            raise ValueError(f"outside_mass: expected None or a share in [0, 1), got {outside_mass}")
    fill = jnp.min(local)
    if H >= h and W >= w:
        # The map holds a whole window: place the window's on-map part directly, without a
        # padded copy of the map (the same cells: the window's values, the rest ``fill``).
        full = _placed(local, center_cell, (H, W), fill)
        window = None if outside_mass is None else _placed(jnp.ones((h, w), bool), center_cell, (H, W), False)
    else:
        big = jnp.full((H + 2 * pad_r, W + 2 * pad_c), fill, local.dtype)
        r0 = jnp.asarray(center_cell[0], jnp.int32) - h // 2 + pad_r
        c0 = jnp.asarray(center_cell[1], jnp.int32) - w // 2 + pad_c
        # Clamp only so that dynamic_update_slice never shifts the window (the pad covers +-h, w).
        r0 = jnp.clip(r0, 0, H + 2 * pad_r - h)
        c0 = jnp.clip(c0, 0, W + 2 * pad_c - w)
        big = jax.lax.dynamic_update_slice(big, local, (r0, c0))
        full = big[pad_r : pad_r + H, pad_c : pad_c + W]
        window = jnp.zeros((H + 2 * pad_r, W + 2 * pad_c), bool)
        window = jax.lax.dynamic_update_slice(window, jnp.ones((h, w), bool), (r0, c0))[
            pad_r : pad_r + H, pad_c : pad_c + W
        ]
    on = None
    if on_map is not None:
        lim = jnp.asarray(on_map, jnp.int32)
        on = (jnp.arange(H, dtype=jnp.int32)[:, None] < lim[0]) & (jnp.arange(W, dtype=jnp.int32)[None, :] < lim[1])
        full = jnp.where(on, full, 0.0)
    if outside_mass is None or window is None:
        return full / jnp.sum(full)
    q = jnp.asarray(outside_mass, local.dtype)
    outside = ~window if on is None else ~window & on
    n_out = jnp.sum(outside)
    q = jnp.where(n_out > 0, q, 0.0)
    inner = jnp.where(window, full, 0.0)
    inner = inner / jnp.maximum(jnp.sum(inner), jnp.finfo(local.dtype).tiny)
    out = jnp.where(window, (1.0 - q) * inner, q / jnp.maximum(n_out, 1).astype(local.dtype))
    return out if on is None else jnp.where(on, out, 0.0)


def _placed(local, center_cell, shape, fill):
    """An (H, W) grid of ``fill`` with the (h, w) window ``local`` centred on ``center_cell``
    (its cell [h // 2, w // 2] there); the window's cells off the map are dropped (H >= h,
    W >= w). dynamic_update_slice moves an update that sticks out back onto the grid, so the
    window is first shifted by as much the other way, its vacated cells ``fill``."""
    h, w = local.shape
    H, W = shape
    r0 = jnp.asarray(center_cell[0], jnp.int32) - h // 2
    c0 = jnp.asarray(center_cell[1], jnp.int32) - w // 2
    r0c, c0c = jnp.clip(r0, 0, H - h), jnp.clip(c0, 0, W - w)
    padded = jnp.pad(local, ((h, h), (w, w)), constant_values=fill)
    # Map cell (r0c + i, c0c + j) is window cell (r0c - r0 + i, c0c - c0 + j): padded row h + that.
    block = jax.lax.dynamic_slice(padded, (jnp.clip(h + r0c - r0, 0, 2 * h), jnp.clip(w + c0c - c0, 0, 2 * w)), (h, w))
    return jax.lax.dynamic_update_slice(jnp.full(shape, fill, local.dtype), block, (r0c, c0c))


class LocalDistribution(NamedTuple):
    """A robot-centred window of cell weights standing for the whole map's distribution, as
    :func:`embed_local_distribution` (``outside_mass=None``, the thesis' rule) would make it:
    the window's cells keep their weights, every other cell of the map gets the window's minimum,
    cells past ``on_map`` (a padded grid's padding) get none, all renormalised. The roadmap
    draws its samples, reads their densities and weighs its edges by ``-log p`` from the window
    alone, so a replan reads the window's 25,600 cells and a few per sample, not the millions
    of a campus map (:meth:`full` makes the (H, W) grid when one is wanted).

    local: (h, w) weights >= 0 with a positive sum; corner: (2,) int32 map cell (row, col) of
    ``local[0, 0]`` (may lie off the map); on_map: (2,) int32 rows and columns of the map (the
    leading ones of the grid it is used on). Make one with :meth:`centred`. A pytree: it goes
    through ``jit`` and ``vmap`` as it is.
    """

    local: jax.Array
    corner: jax.Array
    on_map: jax.Array

    @classmethod
    def centred(cls, local, center_cell, on_map) -> LocalDistribution:
        """The window ``local`` (h, w) whose cell [h // 2, w // 2] lies on map cell
        ``center_cell`` (row, col), on a map of ``on_map`` (rows, cols) cells (the cells of
        :func:`embed_local_distribution`'s window)."""
        local = jnp.asarray(local)
        if local.ndim != 2:
            raise ValueError(f"local: expected an (h, w) window, got shape {tuple(local.shape)}")
        half = jnp.asarray([local.shape[0] // 2, local.shape[1] // 2], jnp.int32)
        return cls(local, jnp.asarray(center_cell, jnp.int32) - half, jnp.asarray(on_map, jnp.int32))

    def full(self, shape) -> jax.Array:
        """The (H, W) distribution over a grid of ``shape`` (at least ``on_map``), summing to 1:
        :func:`embed_local_distribution` of the window."""
        h, w = self.local.shape
        centre = self.corner + jnp.asarray([h // 2, w // 2], jnp.int32)
        return embed_local_distribution(self.local, centre, tuple(int(x) for x in shape), on_map=self.on_map)


def _window_cells(d: LocalDistribution):
    """The window's map rows (h,) and columns (w,), and where its cells lie on the map (h, w)
    (``d.on_map`` within the grid: :func:`check_local_distribution`)."""
    h, w = d.local.shape
    rows = d.corner[0] + jnp.arange(h, dtype=jnp.int32)
    cols = d.corner[1] + jnp.arange(w, dtype=jnp.int32)
    on = ((rows >= 0) & (rows < d.on_map[0]))[:, None] & ((cols >= 0) & (cols < d.on_map[1]))[None, :]
    return rows, cols, on


def _local_total(d: LocalDistribution):
    """(the window's weights (h, w) with 0 off the map, the fill, the map's total weight), in
    the window's dtype."""
    _, _, on = _window_cells(d)
    local = d.local
    fill = jnp.min(local)
    inner = jnp.where(on, local, 0.0)
    cells = d.on_map[0].astype(local.dtype) * d.on_map[1].astype(local.dtype)
    outside = cells - jnp.sum(on).astype(local.dtype)
    return inner, fill, jnp.sum(inner) + fill * outside


def check_local_distribution(d: LocalDistribution, shape) -> None:
    """Refuses a :class:`LocalDistribution` that does not fit a grid of ``shape``, or whose
    weights are not finite, non-negative with a positive sum (``ValueError`` naming
    ``distribution``; the weights are read on the device when they live there: one pass
    over the window)."""
    local = d.local
    if getattr(local, "ndim", 0) != 2 or not jnp.issubdtype(jnp.result_type(local), jnp.floating):
        raise ValueError(
            f"distribution: expected a float (h, w) window, got {jnp.shape(local)} {jnp.result_type(local)}"
        )
    if jnp.shape(d.corner) != (2,) or jnp.shape(d.on_map) != (2,):
        raise ValueError("distribution: corner and on_map must be (2,) cell counts")
    on_map = np.asarray(d.on_map)
    if not (1 <= on_map[0] <= shape[0] and 1 <= on_map[1] <= shape[1]):
        raise ValueError(f"distribution: on_map {tuple(on_map)} does not fit the map's shape {tuple(shape)}")
    if not bool(_window_ok(local)):
        raise ValueError("distribution: expected finite, non-negative weights with a positive sum")


@jax.jit
def _window_ok(local):
    return jnp.all(jnp.isfinite(local) & (local >= 0)) & (jnp.sum(local) > 0)


def _local_values(d: LocalDistribution, rows, cols):
    """The normalised distribution at cells (rows, cols) of the grid: the window's weight, the
    fill elsewhere on the map, 0 on the padding; divided by the map's total."""
    inner, fill, total = _local_total(d)
    return _window_read(inner, d.corner, d.on_map, fill, 0.0, rows, cols) / total


def _window_read(window, corner, on_map, outside, padding, rows, cols):
    """Cells (rows, cols) of the grid a window stands for: ``window`` (h, w) placed at map cell
    ``corner``, ``outside`` elsewhere on the map's ``on_map`` rows and columns, ``padding``
    past them."""
    h, w = window.shape
    i, j = rows - corner[0], cols - corner[1]
    inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
    v = jnp.take(window.reshape(-1), jnp.clip(i, 0, h - 1) * w + jnp.clip(j, 0, w - 1))
    on = (rows < on_map[0]) & (cols < on_map[1])
    return jnp.where(inside, v, jnp.where(on, outside, padding))


class WindowCost(NamedTuple):
    """``-log p`` of a :class:`LocalDistribution` as the edge weights read it (the values of
    :func:`_cost_grid` of the full grid, read cell by cell, :func:`_read_cost`): the window's
    cells, one value for the rest of the map and one for the padding."""

    window: jax.Array
    corner: jax.Array
    on_map: jax.Array
    outside: jax.Array
    padding: jax.Array


def _local_cost(d: LocalDistribution) -> WindowCost:
    """:func:`_cost_grid` of ``d``'s full grid, as a :class:`WindowCost`."""
    inner, fill, total = _local_total(d)
    _, _, on = _window_cells(d)
    nlog = lambda v: -jnp.log(jnp.maximum(v / total, 1e-30))
    pad = jnp.asarray(-math.log(1e-30), d.local.dtype)
    window = jnp.where(on, nlog(inner), pad)
    return WindowCost(window, d.corner, d.on_map, nlog(fill), pad)


def _read_cost(cost: WindowCost, rows, cols):
    """``cost`` at cells (rows, cols) of the grid (on it)."""
    return _window_read(cost.window, cost.corner, cost.on_map, cost.outside, cost.padding, rows, cols)


def sample_local(key, d: LocalDistribution, blocked, words, counts, n: int, grid):
    """``n`` world points (n, 2) drawn as :func:`sample_points` draws them from the full grid of
    ``d`` restricted to the cells not ``blocked`` (:func:`_sampling_weights`), reading the window
    and the map's free-cell words (:func:`_free_words` ``(words, counts)`` of ``blocked``, at
    least one free cell): a draw falls in the window with its share of the mass (the inverse
    CDF of its free cells' weights), else on a uniform free cell outside it (a rank among the
    free cells outside the window, mapped to its cell past the window's free cells row by row).
    The same distribution, other draws than the full grid's. Jittable."""
    k_cell, k_in = jax.random.split(key)
    return _in_cells(k_in, _local_cells(k_cell, d, blocked, words, counts, n, grid.shape, grid.origin.dtype), grid)


def _local_cells(k_cell, d: LocalDistribution, blocked, words, counts, n: int, shape, dtype):
    """The flat cells (n,) int32 of :func:`sample_local`'s draws (before each is given a uniform
    point inside its cell)."""
    H, W = shape
    h, w = d.local.shape
    d = d._replace(local=d.local.astype(dtype))
    rows, cols, on = _window_cells(d)
    rc, cc = jnp.clip(rows, 0, H - 1), jnp.clip(cols, 0, W - 1)
    free_win = on & ~blocked[rc[:, None], cc[None, :]]
    inner, fill, _ = _local_total(d)
    wts = jnp.where(free_win, inner, 0.0).reshape(-1)
    cdf = jax.lax.associative_scan(jnp.add, wts)
    mass_in = cdf[-1]
    per_row = jnp.sum(free_win, axis=1, dtype=jnp.int32)  # (h,) the window's free cells per row
    free_total = counts[-1]
    n_out = free_total - jnp.sum(per_row, dtype=jnp.int32)
    mass_out = jnp.where(n_out > 0, fill * n_out.astype(dtype), 0.0)
    total = mass_in + mass_out
    u01 = jax.random.uniform(k_cell, (n,), dtype)
    u = u01 * total
    # In the window: the first cell whose running mass passes u. The scan's rounding can raise
    # the running mass at a cell without weight (or leave u past the total): the draw then goes
    # to the last cell with weight at or before it (the first one, if none is).
    found = jnp.minimum(jnp.searchsorted(cdf, u, side="right").astype(jnp.int32), h * w - 1)
    flat_w = _weighted_at_or_before(wts > 0, found)
    in_flat = rc[flat_w // w] * W + cc[flat_w % w]
    # Outside: rank among the free cells outside the window, then past each row's block of the
    # window's free cells that comes before it in flat order.
    rank = jnp.floor((u - mass_in) / jnp.where(fill > 0, fill, 1.0)).astype(jnp.int32)
    rank = jnp.clip(rank, 0, jnp.maximum(n_out - 1, 0))
    first = _free_before(words, counts, rc * W + jnp.clip(cols[0], 0, W - 1))  # (h,) rank of each row's block
    start = first - (jnp.cumsum(per_row, dtype=jnp.int32) - per_row)  # the block's place among the outside ranks
    skip = jnp.sum(jnp.where(start[None, :] <= rank[:, None], per_row[None, :], 0), axis=1, dtype=jnp.int32)
    out_flat = _rank_to_flat(words, counts, rank + skip)
    # Nothing to draw from (no weight on a free cell): uniform over the free cells.
    any_rank = jnp.minimum(jnp.floor(u01 * free_total.astype(dtype)).astype(jnp.int32), free_total - 1)
    uni_flat = _rank_to_flat(words, counts, any_rank)
    use_in = (u < mass_in) | ~(mass_out > 0)
    return jnp.where(total > 0, jnp.where(use_in, in_flat, out_flat), uni_flat)

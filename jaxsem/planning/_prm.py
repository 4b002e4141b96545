"""Probabilistic roadmap on a partial grid map, vectorised and jitted at a fixed vertex count.

Build (one jitted call, :func:`build_roadmap`):

1. vertices: the start (index 0), the goal (index 1) and ``n`` samples drawn from a distribution
   over cells (inverse CDF over the flattened grid), each placed uniformly inside its cell; or
   uniformly over the map when no distribution is given;
2. state check: a vertex in a *known occupied* cell is invalid (unknown counts as free);
3. neighbours: the ``k`` nearest vertices within ``radius``, found through a bucket grid of cell
   size ``radius`` (each vertex looks at the 3 x 3 buckets around its own, at most ``bucket_cap``
   vertices per bucket), so the cost is O(n * 9 * bucket_cap) instead of the O(n^2) of brute
   force (which measured 418 ms at n = 5000 on this CPU);
4. edge check: ``edge_samples`` points along each edge, at most half a cell apart, must all lie in
   cells that are not known occupied, and so must both side cells of any diagonal step between
   consecutive samples (so the check is exact: a valid edge touches no known-occupied cell);
5. edge weight: Euclidean length, or the integral of ``-log p`` along the edge (mean over the
   samples times the length; thesis eq. 3.3) when ``weight='neglogp'``.

Search (:func:`roadmap_shortest_path`) runs scipy's Dijkstra on the sparse roadmap on the host:
at n = 5000 it takes a few milliseconds (most of it building the sparse matrix), below a jitted JAX
alternative (a Bellman-Ford style relaxation needs O(n) sweeps over all edges).

Default k = 15: the k nearest of the *final* vertex set give a sparser graph than OMPL's PRM
with its default k = 10, which links each new milestone to the k nearest of those inserted
before it (so early milestones get long edges). Measured on test buildings at n = 5000: OMPL's
roadmap has about 16 distinct edges per vertex, ours 14.4 at k = 15 (see
``benchmarks/lsd_speed.py``). Checking 2k candidates and keeping the k nearest clear edges
raised success on 24 Inside-Inside queries from 21 to 22 for 60 % more build time, so it is
not done.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from ._grid import OCCUPIED, check_point


class Roadmap(NamedTuple):
    """A roadmap (pytree). M = n + 2 vertices: index 0 is the start, 1 the goal.

    points: (M, 2) world (x, y); valid: (M,) bool (state check passed);
    neighbors: (M, k) int32 vertex indices (M where there is none);
    edge_valid: (M, k) bool; edge_weight: (M, k) float (inf where invalid).
    """

    points: jax.Array
    valid: jax.Array
    neighbors: jax.Array
    edge_valid: jax.Array
    edge_weight: jax.Array


def default_radius(n: int, shape, resolution: float) -> float:
    """Connection radius (m) for ``n`` samples on a map of ``shape`` cells: 2.5 x the mean sample
    spacing, within [1, 8] m, rounded up to 0.5 m so that few distinct values (each a compile)
    occur."""
    area = shape[0] * shape[1] * resolution**2
    r = min(8.0, max(1.0, 2.5 * math.sqrt(area / max(n, 1))))
    return math.ceil(r * 2.0) / 2.0


def sample_points(key, distribution, n: int, origin, resolution: float):
    """``n`` world points (n, 2): a cell drawn with probability ``distribution`` (H, W) (need
    not be normalised, must be >= 0), then a uniform point inside the cell. Jittable."""
    H, W = distribution.shape
    k_cell, k_in = jax.random.split(key)
    p = distribution.reshape(-1).astype(origin.dtype)
    # associative_scan, not cumsum: XLA's CPU cumsum is a quadratic reduce-window.
    cdf = jax.lax.associative_scan(jnp.add, p)
    u = jax.random.uniform(k_cell, (n,), origin.dtype) * cdf[-1]
    flat = jnp.clip(jnp.searchsorted(cdf, u, side="right"), 0, H * W - 1)
    rc = jnp.stack([flat // W, flat % W], -1)
    jitter = jax.random.uniform(k_in, (n, 2), origin.dtype)
    return origin + (rc[:, ::-1].astype(origin.dtype) + jitter) * resolution


def _cells(points, origin, resolution, shape):
    H, W = shape
    cr = jnp.floor((points - origin) / resolution).astype(jnp.int32)
    on = (cr[..., 0] >= 0) & (cr[..., 0] < W) & (cr[..., 1] >= 0) & (cr[..., 1] < H)
    return jnp.clip(cr[..., 1], 0, H - 1), jnp.clip(cr[..., 0], 0, W - 1), on


def knn_within_radius(points, valid, k: int, radius, bucket_cap: int, extent):
    """(M, k) indices of the k nearest valid points within ``radius`` (M where fewer), by bucket
    grid. points: (M, 2) local coordinates in [0, extent); extent: (2,) Python floats."""
    M = points.shape[0]
    gx = max(1, int(math.ceil(extent[0] / radius)))
    gy = max(1, int(math.ceil(extent[1] / radius)))
    b = jnp.floor(points / radius).astype(jnp.int32)
    bx, by = jnp.clip(b[:, 0], 0, gx - 1), jnp.clip(b[:, 1], 0, gy - 1)
    bid = jnp.where(valid, by * gx + bx, gx * gy)  # invalid vertices go to a bucket never read
    order = jnp.argsort(bid)
    sorted_bid = bid[order]
    ids = jnp.arange(gx * gy)
    start = jnp.searchsorted(sorted_bid, ids, side="left")
    count = jnp.searchsorted(sorted_bid, ids, side="right") - start
    off = jnp.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], jnp.int32)  # (9, 2)
    nx, ny = bx[:, None] + off[None, :, 0], by[:, None] + off[None, :, 1]  # (M, 9)
    inside = (nx >= 0) & (nx < gx) & (ny >= 0) & (ny < gy)
    nb = jnp.where(inside, ny * gx + nx, 0)
    j = jnp.arange(bucket_cap)
    slot = start[nb][..., None] + j  # (M, 9, cap)
    ok = inside[..., None] & (j < count[nb][..., None])
    cand = order[jnp.clip(slot, 0, M - 1)].reshape(M, -1)
    ok = ok.reshape(M, -1) & (cand != jnp.arange(M)[:, None]) & valid[:, None]
    d2 = jnp.sum((points[cand] - points[:, None, :]) ** 2, -1)
    d2 = jnp.where(ok & (d2 <= radius**2), d2, jnp.inf)
    neg, pos = jax.lax.top_k(-d2, k)
    return jnp.where(jnp.isfinite(neg), cand[jnp.arange(M)[:, None], pos], M)


@functools.partial(
    jax.jit,
    static_argnames=("n", "k", "resolution", "radius", "edge_samples", "bucket_cap", "neglogp", "uniform"),
)
def _build(key, blocked, distribution, start, goal, origin, *, n, k, resolution, radius,
           edge_samples, bucket_cap, neglogp, uniform):
    H, W = blocked.shape
    dtype = origin.dtype
    if uniform:
        u = jax.random.uniform(key, (n, 2), dtype)
        samples = origin + u * jnp.array([W, H], dtype) * resolution
    else:
        samples = sample_points(key, distribution, n, origin, resolution)
    pts = jnp.concatenate([start[None], goal[None], samples], 0)
    M = n + 2
    r, c, on = _cells(pts, origin, resolution, (H, W))
    valid = on & ~blocked[r, c]
    valid = valid.at[0].set(True).at[1].set(True)
    extent = (W * resolution, H * resolution)
    nbr = knn_within_radius(pts - origin, valid, k, radius, bucket_cap, extent)
    has = nbr < M
    other = pts[jnp.minimum(nbr, M - 1)]  # (M, k, 2)
    t = (jnp.arange(edge_samples, dtype=dtype) / (edge_samples - 1))[None, None, :, None]
    along = pts[:, None, None, :] + t * (other - pts[:, None, :])[:, :, None, :]  # (M, k, S, 2)
    er, ec, eon = _cells(along, origin, resolution, (H, W))
    clear = jnp.all(eon & ~blocked[er, ec], axis=-1)
    # Consecutive samples are at most half a cell apart, so they lie in the same or 8-adjacent
    # cells and the segment between them stays inside the 2 x 2 block they span; on a diagonal
    # move it may cross either side cell, so both must be free: the check is then exact
    # (conservative), no edge passes through a known-occupied cell.
    diag = (er[..., 1:] != er[..., :-1]) & (ec[..., 1:] != ec[..., :-1])
    sides = blocked[er[..., :-1], ec[..., 1:]] | blocked[er[..., 1:], ec[..., :-1]]
    clear &= ~jnp.any(diag & sides, axis=-1)
    length = jnp.sqrt(jnp.sum((other - pts[:, None, :]) ** 2, -1) + 1e-30)
    edge_valid = has & clear & valid[:, None]
    if neglogp:
        p = distribution / jnp.sum(distribution)
        cost_per_m = jnp.mean(-jnp.log(jnp.maximum(p[er, ec], 1e-30)), axis=-1)
        w = length * cost_per_m
    else:
        w = length
    w = jnp.where(edge_valid, w, jnp.inf)
    return Roadmap(pts, valid, nbr.astype(jnp.int32), edge_valid, w)


def _blocked_from(name, known_map):
    arr = known_map
    if isinstance(arr, jax.core.Tracer):
        raise ValueError(f"{name}: build_roadmap runs at the Python boundary; pass a concrete map")
    arr = np.asarray(arr)
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D grid (H, W), got shape {arr.shape}")
    if arr.dtype == np.bool_:
        return arr
    if arr.dtype == np.int8:
        return arr == OCCUPIED
    raise ValueError(
        f"{name}: expected a bool obstacle grid or an int8 partial map (UNKNOWN/FREE/OCCUPIED), "
        f"got dtype {arr.dtype}"
    )


def build_roadmap(key, known_map, start, goal, n: int, origin, resolution: float, *,
                  distribution=None, k: int = 15, radius: float | None = None,
                  weight: str = "euclidean", bucket_cap: int = 32) -> Roadmap:
    """Builds a PRM of ``n`` samples plus the start and goal on a partial map.

    known_map: (H, W) int8 partial map (OCCUPIED blocks; UNKNOWN and FREE are free) or a bool
    obstacle grid; start, goal: (2,) world (x, y): on the map, not in a known-occupied cell;
    distribution: (H, W) non-negative cell weights (``None``: uniform over the map); k: neighbours
    per vertex (default 15, see the module docstring); radius: connection radius in metres (``None``: :func:`default_radius`);
    weight: 'euclidean' or 'neglogp' (needs ``distribution``). Returns a :class:`Roadmap`.
    """
    blocked = _blocked_from("known_map", known_map)
    H, W = blocked.shape
    origin_np = np.asarray(origin, np.float64)
    if origin_np.shape != (2,):
        raise ValueError(f"origin: expected shape (2,), got shape {origin_np.shape}")
    start = check_point("start", start, blocked, origin_np, resolution)
    goal = check_point("goal", goal, blocked, origin_np, resolution)
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n: expected a positive int number of samples, got {n!r}")
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"k: expected a positive int number of neighbours, got {k!r}")
    k = min(int(k), int(n) + 1)  # there are only n + 1 other vertices
    if weight not in ("euclidean", "neglogp"):
        raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
    if distribution is None:
        if weight == "neglogp":
            raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
        dist = jnp.ones((1, 1))
        uniform = True
    else:
        dist = distribution
        if not isinstance(dist, jax.core.Tracer):
            d = np.asarray(dist)
            if d.shape != (H, W):
                raise ValueError(f"distribution: expected shape {(H, W)} (the map's), got shape {d.shape}")
            if not np.issubdtype(d.dtype, np.floating):
                raise ValueError(f"distribution: expected a float grid, got dtype {d.dtype}")
            if not (np.all(np.isfinite(d)) and np.all(d >= 0) and d.sum() > 0):
                raise ValueError("distribution: expected finite, non-negative weights with a positive sum")
        uniform = False
    radius = float(radius) if radius is not None else default_radius(n, (H, W), resolution)
    edge_samples = max(2, int(math.ceil(radius / (0.5 * resolution))) + 1)
    origin_j = jnp.asarray(origin_np, jnp.result_type(float))
    return _build(
        key, jnp.asarray(blocked), jnp.asarray(dist, origin_j.dtype), jnp.asarray(start, origin_j.dtype),
        jnp.asarray(goal, origin_j.dtype), origin_j, n=int(n), k=int(k), resolution=float(resolution),
        radius=radius, edge_samples=edge_samples, bucket_cap=int(bucket_cap),
        neglogp=weight == "neglogp", uniform=uniform,
    )


def make_roadmap_builder(n: int, shape, resolution: float, *, k: int = 15, radius: float | None = None,
                         weight: str = "euclidean", uniform: bool = True, bucket_cap: int = 32):
    """A pure, jittable and vmappable roadmap builder for a fixed ``n`` and map ``shape``.

    Returns ``build(key, blocked, distribution, start, goal, origin) -> Roadmap`` with
    blocked: (H, W) bool known obstacles; distribution: (H, W) cell weights (ignored when
    ``uniform``); start, goal: (2,); origin: (2,) float. No input checks (use
    :func:`build_roadmap` at the Python boundary); ``jax.vmap`` it to build the roadmaps of many
    trials at once, e.g. ``jax.vmap(build)(keys, blocked_maps, dists, starts, goals, origins)``.
    """
    if weight not in ("euclidean", "neglogp"):
        raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
    if weight == "neglogp" and uniform:
        raise ValueError("uniform: weight='neglogp' needs a distribution (uniform=False)")
    H, W = (int(s) for s in shape)
    radius = float(radius) if radius is not None else default_radius(n, (H, W), resolution)
    edge_samples = max(2, int(math.ceil(radius / (0.5 * resolution))) + 1)

    def build(key, blocked, distribution, start, goal, origin):
        return _build.__wrapped__(
            key, blocked, distribution, start, goal, origin, n=int(n), k=int(k),
            resolution=float(resolution), radius=radius, edge_samples=edge_samples,
            bucket_cap=int(bucket_cap), neglogp=weight == "neglogp", uniform=bool(uniform),
        )

    return build


class RoadmapPath(NamedTuple):
    """vertices: (K,) roadmap indices from start (0) to goal (1); points: (K, 2) world;
    cost: summed edge weights; length: metres; found: bool (False: empty path, inf cost)."""

    vertices: np.ndarray
    points: np.ndarray
    cost: float
    length: float
    found: bool


def roadmap_shortest_path(roadmap: Roadmap, source: int = 0, target: int = 1) -> RoadmapPath:
    """Shortest path on the roadmap by scipy Dijkstra (host). Default: start (0) to goal (1)."""
    pts = np.asarray(roadmap.points)
    M = pts.shape[0]
    nbr = np.asarray(roadmap.neighbors)
    ok = np.asarray(roadmap.edge_valid)
    w = np.asarray(roadmap.edge_weight)
    src = np.repeat(np.arange(M), nbr.shape[1])[ok.ravel()]
    dst = nbr.ravel()[ok.ravel()]
    # A zero weight would vanish from the sparse matrix; weights are lengths, so clamp tiny ones.
    wt = np.maximum(w.ravel()[ok.ravel()], 1e-12)
    graph = scipy.sparse.csr_matrix((wt, (src, dst)), shape=(M, M))
    dist, pred = scipy.sparse.csgraph.dijkstra(
        graph, directed=False, indices=int(source), return_predecessors=True
    )
    if not np.isfinite(dist[target]):
        return RoadmapPath(np.zeros(0, np.int64), np.zeros((0, 2)), float("inf"), float("inf"), False)
    path = [int(target)]
    while path[-1] != source:
        path.append(int(pred[path[-1]]))
    path = np.array(path[::-1])
    p = pts[path]
    length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=-1)))
    return RoadmapPath(path, p, float(dist[target]), length, True)


def embed_local_distribution(local, center_cell, full_shape):
    """Embeds a robot-centred local distribution into the full map (thesis section 3.2.5).

    local: (h, w) probabilities (e.g. the network's 160 x 160 softmax), centred on the robot's
    cell ``center_cell`` (row, col) of the full map (the local cell [h // 2, w // 2] is the
    robot's); full_shape: (H, W). Cells outside the window get the window's minimum; the result
    (H, W) is renormalised to sum to 1. Jittable (``center_cell`` may be traced).
    """
    local = jnp.asarray(local)
    h, w = local.shape
    H, W = full_shape
    pad_r, pad_c = h, w
    fill = jnp.min(local)
    big = jnp.full((H + 2 * pad_r, W + 2 * pad_c), fill, local.dtype)
    r0 = jnp.asarray(center_cell[0], jnp.int32) - h // 2 + pad_r
    c0 = jnp.asarray(center_cell[1], jnp.int32) - w // 2 + pad_c
    # Clamp only so that dynamic_update_slice never shifts the window (the pad covers +-h, w).
    r0 = jnp.clip(r0, 0, H + 2 * pad_r - h)
    c0 = jnp.clip(c0, 0, W + 2 * pad_c - w)
    big = jax.lax.dynamic_update_slice(big, local, (r0, c0))
    full = big[pad_r:pad_r + H, pad_c:pad_c + W]
    return full / jnp.sum(full)

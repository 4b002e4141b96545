"""Exact neighbour search of the PRM: buckets of the connection radius, the direction-first
connection policy (sectors), brute force where buckets would not pay (see
:mod:`jaxsem.planning._roadmap` for the policy).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


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
):
    """k nearest ``db_ok`` points of ``db`` (M, 2) within ``radius`` of each query (Q, 2),
    excluding index ``q_self`` (Q,) (-1: none). Returns ((Q, k) indices, ``M`` where fewer;
    overflow). ``cap=None``: brute force. Local coordinates in [0, extent)."""
    M = db.shape[0]
    Q = queries.shape[0]
    if cap is None or 9 * cap >= M:
        cand = jnp.broadcast_to(jnp.arange(M)[None, :], (Q, M))
        ok = jnp.broadcast_to(db_ok[None, :], (Q, M))
        overflow = jnp.zeros((), bool)
    else:
        gx = max(1, int(math.ceil(extent[0] / radius)))
        gy = max(1, int(math.ceil(extent[1] / radius)))

        def bucket(p):
            b = jnp.floor(p / radius).astype(jnp.int32)
            return jnp.clip(b[:, 0], 0, gx - 1), jnp.clip(b[:, 1], 0, gy - 1)

        bx, by = bucket(db)
        bid = jnp.where(db_ok, by * gx + bx, gx * gy)  # unusable points: a bucket never read
        order = jnp.argsort(bid)
        sorted_bid = bid[order]
        ids = jnp.arange(gx * gy, dtype=bid.dtype)
        start = jnp.searchsorted(sorted_bid, ids, side="left")
        count = jnp.searchsorted(sorted_bid, ids, side="right") - start
        overflow = jnp.max(count) > cap
        qx, qy = bucket(queries)
        off = jnp.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], jnp.int32)  # (9, 2)
        nx, ny = qx[:, None] + off[None, :, 0], qy[:, None] + off[None, :, 1]  # (Q, 9)
        inside = (nx >= 0) & (nx < gx) & (ny >= 0) & (ny < gy)
        nb = jnp.where(inside, ny * gx + nx, 0)
        j = jnp.arange(cap, dtype=start.dtype)
        slot = start[nb][..., None] + j  # (Q, 9, cap)
        ok = (inside[..., None] & (j < count[nb][..., None])).reshape(Q, -1)
        cand = order[jnp.clip(slot, 0, M - 1)].reshape(Q, -1)
    ok = ok & (cand != q_self.astype(cand.dtype)[:, None])
    diff = db[cand] - queries[:, None, :]
    d2 = jnp.sum(diff**2, -1)
    d2 = jnp.where(ok & (d2 <= radius**2), d2, jnp.inf)
    want = keep or k
    kk = min(want, cand.shape[1])
    sparser = None
    if density is not None:  # (M,) sampling density of db points; queries are db[q_self]
        sparser = density[cand] <= density[jnp.maximum(q_self, 0)][:, None] * 1.001
    pos, fin = _select(d2, diff, k, sectors, want, sparser)
    idx = jnp.where(fin, jnp.take_along_axis(cand, pos, axis=1), M)
    if kk < want:
        idx = jnp.concatenate([idx, jnp.full((Q, want - kk), M, idx.dtype)], 1)
    return idx.astype(jnp.int32), overflow


def knn_within_radius(points, valid, k: int, radius: float, extent, bucket_cap: int | None = None, sectors: int = 0):
    """(M, k) indices of the k nearest valid points within ``radius`` of every valid point (``M``
    where fewer; invalid points get none) and the overflow flag (see :class:`Roadmap`).

    points: (M, 2) local coordinates in [0, extent); extent: (2,) Python floats; bucket_cap: slots
    per bucket (None: brute force); sectors: 0 (the k nearest) or the number of direction sectors
    whose nearest points come first (module docstring). Jittable with k, radius, extent,
    bucket_cap, sectors static.
    """
    M = points.shape[0]
    idx, overflow = _knn(points, valid, points, jnp.arange(M), k, radius, extent, bucket_cap, sectors)
    return jnp.where(valid[:, None], idx, M), overflow

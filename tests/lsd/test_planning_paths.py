"""Soft-cost shortest paths (vs a pure-Python Dijkstra) and the PRM."""

import functools
import heapq
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem import quadrics as Q
from jaxsem.planning import (
    OCCUPIED,
    PRM,
    UNKNOWN,
    SoftCostGraph,
    build_roadmap,
    embed_local_distribution,
    generate_building,
    roadmap_shortest_path,
    shortest_path,
)
from jaxsem.planning._edges import polyline_clear  # layers: white-box
from jaxsem.planning._neighbours import knn_within_radius  # layers: white-box
from jaxsem.planning._roadmap import (  # layers: white-box
    DEFAULT_SECTORS,
    default_radius,
    prm_star_k,
    roadmap_connect,
    roadmap_grow,
    roadmap_init,
)
from jaxsem.planning._shortest_path import soft_cost  # layers: white-box

RES = 0.1
ORIGIN = np.array([0.0, 0.0])


def grid_of(known_map) -> Q.Grid:
    """The test maps' grid: ``ORIGIN``, ``RES`` and the map's (H, W)."""
    return Q.Grid.host(ORIGIN, RES, np.shape(known_map)[-2:])


# One map shape, sample count and radius for all PRM tests: each combination is one compile.
N, RADIUS = 1000, 1.5


def _roadmap(seed, occ, start, goal, **kw):
    """``build_roadmap`` at the shared ``N``, ``ORIGIN``, ``RES`` and ``RADIUS``."""
    return build_roadmap(jax.random.PRNGKey(seed), occ, start, goal, N, grid_of(occ), radius=RADIUS, **kw)


def _blocks(seed, shape=(32, 36), n=10):
    rng = np.random.default_rng(seed)
    occ = np.zeros(shape, bool)
    for _ in range(n):
        r, c = rng.integers(0, shape[0] - 3), rng.integers(0, shape[1] - 3)
        occ[r : r + rng.integers(1, 6), c : c + rng.integers(1, 4)] = True
    return occ


def _python_dijkstra(occ, cost, start):
    """Independent reference: heapq Dijkstra over 8 neighbours, no corner cutting."""
    H, W = occ.shape
    dist = np.full((H, W), np.inf)
    dist[start] = 0.0
    heap = [(0.0, start)]
    while heap:
        d, (r, c) = heapq.heappop(heap)
        if d > dist[r, c]:
            continue
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr == dc == 0:
                    continue
                rr, cc = r + dr, c + dc
                if not (0 <= rr < H and 0 <= cc < W) or occ[rr, cc]:
                    continue
                if dr and dc and (occ[r + dr, c] or occ[r, c + dc]):
                    continue
                step = RES * (math.sqrt(2) if dr and dc else 1.0)
                nd = d + step * 0.5 * (cost[r, c] + cost[rr, cc])
                if nd < dist[rr, cc] - 1e-15:
                    dist[rr, cc] = nd
                    heapq.heappush(heap, (nd, (rr, cc)))
    return dist


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_soft_cost_dijkstra_matches_python_reference(seed):
    occ = _blocks(seed)
    free = np.argwhere(~occ)
    start = tuple(free[seed * 7 % len(free)])
    g = SoftCostGraph(occ, grid_of(occ))
    tree = g.search(ORIGIN + (np.array(start[::-1]) + 0.5) * RES)
    ref = _python_dijkstra(occ, soft_cost(occ, RES), start)
    np.testing.assert_allclose(tree.dist, ref, rtol=1e-12, atol=1e-12)
    # Paths: 8-connected cell chains from start to goal whose edge costs add up to the distance.
    cost = g.cost
    for goal in free[::37]:
        p = tree.path_to_cell(goal)
        if not np.isfinite(ref[tuple(goal)]):
            assert not p.found
            continue
        assert tuple(p.cells[0]) == start and tuple(p.cells[-1]) == tuple(goal)
        steps = np.diff(p.cells, axis=0)
        assert np.all(np.abs(steps).max(1) == 1)
        lens = RES * np.linalg.norm(steps, axis=1)
        c = np.sum(lens * 0.5 * (cost[tuple(p.cells[:-1].T)] + cost[tuple(p.cells[1:].T)]))
        assert c == pytest.approx(ref[tuple(goal)], rel=1e-12)
        assert p.length == pytest.approx(lens.sum(), rel=1e-12)


def _segment_cells(a, b, samples=400):
    """Cells a straight segment between two cell centres passes through (dense sampling)."""
    t = np.linspace(0.0, 1.0, samples)[:, None]
    pts = (1 - t) * np.asarray(a, float) + t * np.asarray(b, float)
    return np.unique(np.floor(pts + 0.5).astype(int), axis=0)


@given(seed=st.integers(0, 10_000), n=st.integers(0, 14))
@settings(max_examples=25, deadline=None)
def test_sixteen_connected_lengths_against_straight_lines_and_segments(seed, n):
    """connectivity=16 (knight moves): on any map its paths are no longer than the 8-connected
    ones, no shorter than the straight line, and every segment stays in free cells (checked by
    dense sampling of the segment); on an empty map they are within 2.7 % of the straight line."""
    occ = _blocks(seed, n=n)
    free = np.argwhere(~occ)
    rng = np.random.default_rng(seed)
    a, b = free[rng.integers(len(free), size=2)]
    to_world = lambda rc: ORIGIN + (np.asarray(rc)[::-1] + 0.5) * RES
    p8 = SoftCostGraph(occ, grid_of(occ), weight=0.0).path(to_world(a), to_world(b))
    p16 = SoftCostGraph(occ, grid_of(occ), weight=0.0, connectivity=16).path(to_world(a), to_world(b))
    assert p16.found == p8.found
    if not p8.found:
        return
    straight = RES * float(np.hypot(*(b - a)))
    assert straight - 1e-9 <= p16.length <= p8.length + 1e-9
    assert p16.cost == pytest.approx(p16.length, rel=1e-12)  # weight 0: cost is length
    for c0, c1 in zip(p16.cells[:-1], p16.cells[1:]):
        assert np.abs(c1 - c0).max() <= 2 and np.abs(c1 - c0).min() <= 1
        crossed = _segment_cells(c0, c1)
        assert not occ[tuple(crossed.T)].any()
    empty = np.zeros_like(occ)
    e16 = SoftCostGraph(empty, grid_of(empty), weight=0.0, connectivity=16).path(to_world(a), to_world(b))
    e8 = SoftCostGraph(empty, grid_of(empty), weight=0.0).path(to_world(a), to_world(b))
    assert e16.length <= straight * 1.0275 + 1e-9
    assert e8.length <= straight * 1.0824 + 1e-9


def test_knight_move_needs_the_cells_it_crosses():
    """A knight move whose segment crosses an occupied cell is not taken (a drawn case)."""
    occ = np.ones((4, 5), bool)
    occ[1, 1] = occ[2, 3] = False  # the two ends: (1, 1) -> (2, 3)
    occ[1, 2] = occ[2, 2] = False  # the two cells its segment crosses
    g = lambda o: SoftCostGraph(o, grid_of(o), weight=0.0, connectivity=16)
    ends = ORIGIN + (np.array([[1, 1], [3, 2]]) + 0.5) * RES
    p = g(occ).path(ends[0], ends[1])
    assert p.found and len(p.cells) == 2 and p.length == pytest.approx(RES * math.sqrt(5))
    blocked = occ.copy()
    blocked[2, 2], blocked[1, 3] = True, False  # the way round: along row 1, then down
    q = g(blocked).path(ends[0], ends[1])
    assert q.found and len(q.cells) == 4 and q.length == pytest.approx(3 * RES)
    with pytest.raises(ValueError, match="connectivity"):
        SoftCostGraph(occ, grid_of(occ), connectivity=4)
    with pytest.raises(ValueError, match="limit"):
        g(occ).search(ends[0], limit=0.0)
    # limit: cells beyond it read as unreachable
    assert not g(occ).search(ends[0], limit=0.1).path_to(ends[1]).found


def test_soft_cost_rises_near_walls():
    occ = np.zeros((20, 20), bool)
    occ[:, 0] = True
    c = soft_cost(occ, RES)
    assert np.isinf(c[0, 0])
    assert np.all(np.diff(c[5, 1:]) <= 0) and c[5, 1] > c[5, 19] >= 1.0
    # The optimal path keeps away from the wall when it can.
    p = shortest_path(occ, [0.15, 0.15], [0.15, 1.85], grid_of(occ))
    assert p.found and p.cells[:, 1].max() > 2


def test_shortest_path_bad_input():
    occ = _blocks(0)
    occ[0, 0] = True
    occ[5, 5] = False
    with pytest.raises(ValueError, match="start"):
        shortest_path(occ, [0.05, 0.05], [0.55, 0.55], grid_of(occ))
    with pytest.raises(ValueError, match="goal"):
        shortest_path(occ, [0.55, 0.55], [50.0, 0.55], grid_of(occ))
    with pytest.raises(ValueError, match="occupancy"):
        shortest_path(occ.astype(np.uint8), [0.55, 0.55], [0.55, 0.55], grid_of(occ.astype(np.uint8)))
    with pytest.raises(ValueError, match="occupancy"):
        shortest_path(occ[None], [0.55, 0.55], [0.55, 0.55], grid_of(occ[None]))


# ----------------------------------------------------------------------------------------- PRM


def _one_route_map():
    """10 x 6 m room split by a wall with one 0.6 m gap; start and goal on a line through it."""
    occ = np.zeros((60, 100), bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    occ[:, 49:51] = True
    occ[27:33, 49:51] = False
    return occ


@pytest.mark.slow
def test_prm_finds_the_corridor_path():
    occ = _one_route_map()
    start, goal = np.array([1.0, 3.0]), np.array([9.0, 3.0])
    found = 0
    for seed in range(3):
        rm = _roadmap(seed, occ, start, goal)
        p = roadmap_shortest_path(rm)
        found += p.found
        if p.found:
            assert p.length <= 8.0 * 1.06, p.length  # the straight route through the gap is 8 m
            assert np.allclose(p.points[0], start) and np.allclose(p.points[-1], goal)
            crossing = np.interp(5.0, p.points[:, 0], p.points[:, 1])
            assert 2.7 <= crossing <= 3.3
    assert found >= 2
    # With the gap closed there is no route.
    closed = occ.copy()
    closed[:, 49:51] = True
    rm = _roadmap(0, closed, start, goal)
    assert not roadmap_shortest_path(rm).found


@pytest.mark.slow
def test_query_returns_the_roadmaps_shortest_path():
    """Regression: with float32 weights scipy's Dijkstra summed the two stored copies of an edge
    that both endpoints list, so a query preferred one-sided edges and returned paths several
    percent longer than the roadmap's shortest. Reference: heapq Dijkstra over the roadmap's
    edge lists (undirected, the start's and the goal's edges as made)."""
    occ = _blocks(3, shape=(60, 100), n=25)
    free = np.argwhere(~occ)
    rng = np.random.default_rng(3)
    # float32, as the PRM runs without x64 (the tests enable x64)
    grown = roadmap_grow(
        roadmap_init(N, prm_star_k(N), jnp.float32), jax.random.PRNGKey(5), occ, N, grid_of(occ), radius=RADIUS
    )
    checked = 0
    for _ in range(4):
        s, g = (ORIGIN + (free[rng.integers(len(free))][::-1] + 0.5) * RES for _ in range(2))
        rm = roadmap_connect(grown, s, g, occ, grid_of(occ), radius=RADIUS)
        p = roadmap_shortest_path(rm)
        nbr, ok = np.asarray(rm.neighbors), np.asarray(rm.edge_valid)
        w = np.asarray(rm.edge_weight, np.float64)
        M = nbr.shape[0]
        adj = [[] for _ in range(M)]
        for i, j in zip(*np.nonzero(ok)):
            v = int(nbr[i, j])
            adj[i].append((v, w[i, j]))
            if i != 0 and v != 1:  # the start's edges lead out, the goal's lead in
                adj[v].append((int(i), w[i, j]))
            if i == 1:
                adj[v].append((1, w[i, j]))
        dist = np.full(M, np.inf)
        dist[0] = 0.0
        heap = [(0.0, 0)]
        while heap:
            d, u = heapq.heappop(heap)
            if d > dist[u]:
                continue
            for v, wt in adj[u]:
                if d + wt < dist[v]:
                    dist[v] = d + wt
                    heapq.heappush(heap, (dist[v], v))
        assert p.found == np.isfinite(dist[1])
        if p.found:
            np.testing.assert_allclose(p.cost, dist[1], rtol=1e-5)
            checked += 1
    assert checked >= 2


@pytest.mark.slow  # two roadmaps on a building-sized grid (about 10 s)
def test_unknown_counts_as_free():
    occ = _one_route_map()
    partial = np.full(occ.shape, UNKNOWN, np.int8)
    partial[occ] = UNKNOWN
    partial[:, 49:51] = OCCUPIED
    partial[27:33, 49:51] = UNKNOWN
    rm = _roadmap(1, partial, [1.0, 3.0], [9.0, 3.0])
    assert roadmap_shortest_path(rm).found


@pytest.mark.slow
def test_concentrated_distribution_places_vertices_there():
    occ = np.zeros((60, 100), bool)
    dist = np.zeros(occ.shape)
    dist[10:20, 70:80] = 1.0
    rm = _roadmap(0, occ, [0.5, 0.5], [9.5, 5.5], distribution=dist)
    pts = np.asarray(rm.points)[2:]
    assert np.all((pts[:, 0] >= 7.0) & (pts[:, 0] < 8.0) & (pts[:, 1] >= 1.0) & (pts[:, 1] < 2.0))
    # Uniform inside the cells: the in-cell offsets fill the cells.
    frac = (pts / RES) % 1.0
    assert frac.std(0).min() > 0.25
    # A 90 / 10 split of mass shows up in the counts.
    dist2 = np.full(occ.shape, 0.1 / (6000 - 100))
    dist2[10:20, 70:80] = 0.9 / 100
    rm = _roadmap(1, occ, [0.5, 0.5], [9.5, 5.5], distribution=dist2)
    pts = np.asarray(rm.points)[2:]
    inside = (pts[:, 0] >= 7.0) & (pts[:, 0] < 8.0) & (pts[:, 1] >= 1.0) & (pts[:, 1] < 2.0)
    assert abs(inside.mean() - 0.9) < 0.03


@pytest.mark.slow
@pytest.mark.parametrize("weight", ["euclidean", "neglogp"])
def test_edges_never_cross_known_obstacles(weight):
    occ = _blocks(4, shape=(60, 100), n=50)
    free = np.argwhere(~occ)
    start = ORIGIN + (free[0][::-1] + 0.5) * RES
    goal = ORIGIN + (free[-1][::-1] + 0.5) * RES
    dist = np.random.default_rng(0).random(occ.shape) + 0.1
    rm = _roadmap(2, occ, start, goal, distribution=dist, weight=weight)
    pts = np.asarray(rm.points)
    nbr, ok = np.asarray(rm.neighbors), np.asarray(rm.edge_valid)
    assert ok.sum() > 3000
    t = np.linspace(0.0, 1.0, 801)[None, :, None]
    ii, jj = np.nonzero(ok)
    for chunk in np.array_split(np.arange(len(ii)), 20):
        a, b = pts[ii[chunk]][:, None], pts[nbr[ii[chunk], jj[chunk]]][:, None]
        u = (a + t * (b - a) - ORIGIN) / RES  # (E, 801, 2) dense points along each edge
        interior = np.all(np.abs(u - np.round(u)) > 1e-7, axis=-1)  # not on a cell boundary
        rc = np.floor(u).astype(int)
        hit = occ[rc[..., 1], rc[..., 0]] & interior
        assert not hit.any(), chunk[np.any(hit, axis=1)]
    # Invalid vertices are exactly those in occupied cells.
    rc = np.floor((pts - ORIGIN) / RES).astype(int)[:, ::-1]
    np.testing.assert_array_equal(np.asarray(rm.valid), ~occ[rc[:, 0], rc[:, 1]])
    # Weights: lengths, or the -log p integral that is larger where p is small.
    w = np.asarray(rm.edge_weight)[ok]
    lengths = np.linalg.norm(pts[nbr[ok]] - pts[np.nonzero(ok)[0]], axis=1)
    if weight == "euclidean":
        np.testing.assert_allclose(w, lengths, rtol=1e-9)
    else:
        p = dist / dist.sum()
        assert np.all(w >= lengths * -np.log(p.max()) - 1e-9)
        assert np.all(w <= lengths * -np.log(p.min()) + 1e-9)


def _brute_knn(pts, valid, k, radius, queries=None, self_idx=None):
    q = pts if queries is None else queries
    d = np.linalg.norm(q[:, None] - pts[None], axis=-1)
    d[:, ~valid] = np.inf
    if self_idx is not None:
        d[np.arange(len(q)), self_idx] = np.inf
    d[d > radius] = np.inf
    return np.sort(d, axis=1)[:, :k]


def _sorted_dists(pts, queries, idx):
    M = len(pts)
    d = np.where(
        idx < M,
        np.linalg.norm(queries[:, None] - pts[np.minimum(idx, M - 1)], axis=-1),
        np.inf,
    )
    return np.sort(d, axis=1)


def _samples(kind, rng, n):
    if kind == "uniform":
        return rng.random((n, 2)) * np.array([12.0, 7.0])
    # Concentrated as under a confident learned distribution: 80 % in one 0.3 m cell.
    pts = rng.random((n, 2)) * np.array([12.0, 7.0])
    hot = rng.random(n) < 0.8
    pts[hot] = np.array([6.0, 3.0]) + rng.random((hot.sum(), 2)) * 0.3
    return pts


@pytest.mark.parametrize("kind", ["uniform", "concentrated"])
def test_knn_matches_brute_force(kind):
    rng = np.random.default_rng(0)
    pts = _samples(kind, rng, 700)
    valid = rng.random(700) > 0.1
    knn = jax.jit(knn_within_radius, static_argnums=(2, 3, 4, 5))
    ref = _brute_knn(pts, valid, 6, 0.9, self_idx=np.arange(700))
    for cap in (None, 8, 512):
        nb, overflow = knn(jnp.asarray(pts), jnp.asarray(valid), 6, 0.9, (12.0, 7.0), cap)
        nb = np.asarray(nb)
        got = _sorted_dists(pts, pts, nb)[valid]
        if cap == 8:  # 8 slots per bucket cannot hold these samples: flagged, never silent
            assert bool(overflow)
            continue
        assert not bool(overflow)
        np.testing.assert_allclose(got, ref[valid], rtol=1e-12)
        assert np.all(nb[~valid] == 700)


@pytest.mark.slow
@pytest.mark.parametrize("sectors,k", [(8, 22), (0, 22)])
def test_host_rows_hold_the_same_candidates(sectors, k):
    """The lazy grow finds on the host (a k-d tree) the candidates of the rows with at most k
    of them, where the order decides nothing, and leaves the others to the device's ranked
    search: every host row holds the ranked search's candidates, exactly the rows with more than
    k are left, and a cap too small is raised as the device search's reruns would (x4)."""
    from jaxsem.planning._neighbours import _candidates_host, _knn  # layers: white-box (lazy grow)

    rng = np.random.default_rng(0)
    M, radius = 1500, 1.0
    p = rng.uniform(0.0, 17.0, (M, 2)).astype(np.float32)
    p[7] = p[8]  # a point drawn twice: each is the other's candidate at distance 0
    ok = np.ones(M, bool)
    ok[[3, 100]] = False  # unusable points: never a candidate, no candidates of their own
    pts = jnp.asarray(p)
    slots = jnp.arange(M)
    keep = 2 * k if sectors else k
    args = (pts, jnp.asarray(ok), pts, slots, k, radius, (17.0, 17.0), 96, sectors, keep)
    ranked, over = jax.jit(lambda: _knn(*args))()
    ranked = np.where(ok[:, None], np.asarray(ranked), M)
    assert not bool(over)
    rows = np.arange(M)
    host, need, cap = _candidates_host(p, ok, rows, k, radius, (17.0, 17.0), keep, 96)
    assert cap == 96
    d = p[None, :, :] - p[:, None, :]
    near = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] <= np.float32(radius**2)) & ok[None, :] & ok[:, None]
    count = near.sum(1) - ok  # not itself
    np.testing.assert_array_equal(need, count > k)
    assert 0 < need.sum() < M // 2 and 7 in host[8] and 8 in host[7]
    assert np.all(host[need] == M) and np.all(host[[3, 100]] == M)
    assert all(set(a) == set(b) for a, b in zip(host[~need].tolist(), ranked[~need].tolist()))
    _, _, raised = _candidates_host(p, ok, rows, k, radius, (17.0, 17.0), keep, 4)
    assert raised == 64  # 4 -> 16 -> 64: a strip of 3 buckets holds ~55 points here


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["uniform", "concentrated"])
def test_grown_roadmap_neighbours_are_exact(kind):
    """Two batches, a tiny starting bucket cap (forces the rerun): every vertex holds the k
    nearest of the vertices present when its batch was added, as brute force finds them."""
    occ = np.zeros((70, 120), bool)
    dist = np.ones(occ.shape)
    if kind == "concentrated":
        dist[30:33, 60:63] = 1e4
    rm = roadmap_init(800, 6)
    for seed in (0, 1):  # two batches of 400
        rm = roadmap_grow(
            rm,
            jax.random.PRNGKey(seed),
            occ,
            400,
            grid_of(occ),
            distribution=dist,
            radius=0.9,
            bucket_cap=2,
            sectors=0,  # the plain k nearest, checked against brute force
        )
    assert not bool(rm.overflow) and int(rm.num_samples) == 800
    pts = np.asarray(rm.points)
    nbr = np.asarray(rm.neighbors)
    valid = np.array(rm.valid)
    valid[:2] = False  # query slots
    for lo, hi in ((2, 402), (402, 802)):
        present = valid.copy()
        present[hi:] = False
        ref = _brute_knn(pts, present, 6, 0.9, queries=pts[lo:hi], self_idx=np.arange(lo, hi))
        np.testing.assert_allclose(_sorted_dists(pts, pts[lo:hi], nbr[lo:hi]), ref, rtol=1e-12)


@pytest.mark.slow
def test_prm_reuse_grow_and_update():
    occ = _one_route_map()
    prm = PRM(occ, grid_of(occ), capacity=2 * N, radius=RADIUS)
    prm.grow(jax.random.PRNGKey(0), N)
    queries = [
        ([1.0, 3.0], [9.0, 3.0]),
        ([1.0, 1.0], [9.0, 5.0]),
        ([2.0, 5.0], [8.0, 1.0]),
    ]
    for s, g in queries:
        p = prm.query(s, g)
        assert p.found and np.allclose(p.points[0], s) and np.allclose(p.points[-1], g)
        # The cached search equals an undirected Dijkstra over the whole edge list.
        ref = roadmap_shortest_path(prm.roadmap, 0, 1)
        assert p.cost == pytest.approx(ref.cost, rel=1e-12)
    before = (
        np.asarray(prm.roadmap.neighbors)[2 : N + 2],
        np.asarray(prm.roadmap.edge_valid)[2 : N + 2],
    )
    prm.grow(jax.random.PRNGKey(1), N)
    rm = prm.roadmap
    # Growing adds the new vertices' links and leaves the old vertices' lists as they were.
    assert prm.count == 2 * N and int(rm.num_samples) == 2 * N
    np.testing.assert_array_equal(np.asarray(rm.neighbors)[2 : N + 2], before[0])
    np.testing.assert_array_equal(np.asarray(rm.edge_valid)[2 : N + 2], before[1])
    assert np.asarray(rm.edge_valid)[N + 2 :].sum() > 0.5 * before[1].sum()
    # Closing the gap in a newer map removes every edge through it: no route any more.
    closed = occ.copy()
    closed[:, 49:51] = True
    assert prm.update_map(closed) and not prm.update_map(closed)
    assert not prm.query([1.0, 3.0], [9.0, 3.0]).found
    assert prm.query([1.0, 3.0], [4.0, 1.0]).found
    with pytest.raises(ValueError, match="capacity"):
        prm.grow(jax.random.PRNGKey(2), 1)


def test_roadmap_shapes_and_no_nan():
    occ = _one_route_map()
    rm = _roadmap(0, occ, [1.0, 3.0], [9.0, 3.0], distribution=np.ones(occ.shape), weight="neglogp")
    w = np.asarray(rm.edge_weight)
    assert not np.isnan(w).any() and np.isfinite(w[np.asarray(rm.edge_valid)]).all()
    assert rm.points.shape == (N + 2, 2) and rm.neighbors.shape == (
        N + 2,
        prm_star_k(N),
    )
    assert not bool(rm.overflow) and int(rm.num_samples) == N


def test_embed_local_distribution():
    local = np.random.default_rng(0).random((16, 16)) + 0.5
    local /= local.sum()
    full = np.asarray(embed_local_distribution(local, (10, 30), (40, 50)))
    assert full.shape == (40, 50) and full.sum() == pytest.approx(1.0)
    window = full[2:18, 22:38]
    scale = window.sum() / local.sum()
    np.testing.assert_allclose(window, local * scale, rtol=1e-12)
    outside = np.ones(full.shape, bool)
    outside[2:18, 22:38] = False
    np.testing.assert_allclose(full[outside], local.min() * scale, rtol=1e-12)
    # Near the border the window is clipped, not shifted.
    full = np.asarray(embed_local_distribution(local, (0, 0), (40, 50)))
    np.testing.assert_allclose(full[:8, :8] / full[:8, :8].sum(), local[8:, 8:] / local[8:, 8:].sum())
    # Jittable with a traced centre.
    f = jax.jit(embed_local_distribution, static_argnums=2)
    np.testing.assert_allclose(
        np.asarray(f(local, jnp.array([10, 30]), (40, 50))),
        np.asarray(embed_local_distribution(local, (10, 30), (40, 50))),
    )


@pytest.mark.parametrize("on_device", [False, True])
@pytest.mark.parametrize("bad", ["nan", "negative", "zero", "inf"])
def test_bad_distribution_weights_are_refused_on_the_host_and_on_the_device(bad, on_device):
    occ = _one_route_map()
    dist = np.ones(occ.shape)
    if bad == "zero":
        dist[:] = 0.0
    else:
        dist[2, 3] = {"nan": np.nan, "negative": -1.0, "inf": np.inf}[bad]
    grow = lambda d: PRM(occ, grid_of(occ), capacity=20).grow(jax.random.PRNGKey(0), 10, d)
    with pytest.raises(ValueError, match="distribution: expected finite"):
        grow(jnp.asarray(dist) if on_device else dist)
    assert grow(jnp.asarray(np.ones(occ.shape)) if on_device else np.ones(occ.shape)) == 10


def test_prm_bad_input():
    occ = _one_route_map()
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="start"):
        build_roadmap(key, occ, [5.0, 1.0], [9.0, 3.0], 10, grid_of(occ))  # in the wall
    with pytest.raises(ValueError, match="goal"):
        build_roadmap(key, occ, [1.0, 3.0], [19.0, 3.0], 10, grid_of(occ))  # off the map
    with pytest.raises(ValueError, match="known_map"):
        build_roadmap(key, occ.astype(np.float32), [1.0, 3.0], [9.0, 3.0], 10, grid_of(occ.astype(np.float32)))
    with pytest.raises(ValueError, match="known_map"):
        build_roadmap(key, occ[None], [1.0, 3.0], [9.0, 3.0], 10, grid_of(occ[None]))
    with pytest.raises(ValueError, match="distribution"):
        build_roadmap(
            key,
            occ,
            [1.0, 3.0],
            [9.0, 3.0],
            10,
            grid_of(occ),
            distribution=np.ones((3, 3)),
        )
    with pytest.raises(ValueError, match="distribution"):
        build_roadmap(key, occ, [1.0, 3.0], [9.0, 3.0], 10, grid_of(occ), weight="neglogp")
    with pytest.raises(ValueError, match="n"):
        build_roadmap(key, occ, [1.0, 3.0], [9.0, 3.0], 0, grid_of(occ))
    with pytest.raises(ValueError, match="weight"):
        build_roadmap(key, occ, [1.0, 3.0], [9.0, 3.0], 10, grid_of(occ), weight="l1")
    with pytest.raises(ValueError, match="k"):
        build_roadmap(key, occ, [1.0, 3.0], [9.0, 3.0], 10, grid_of(occ), k=0)


def _lazy_and_eager(occ, sectors, k, grows=((5, 500), (6, 500))):
    eager = PRM(occ, grid_of(occ), capacity=N, radius=RADIUS, sectors=sectors, k=k)
    lazy = PRM(occ, grid_of(occ), capacity=N, radius=RADIUS, sectors=sectors, k=k, lazy=True)
    for seed, n in grows:  # two grows: the second batch's candidates include the first's vertices
        eager.grow(jax.random.PRNGKey(seed), n)
        lazy.grow(jax.random.PRNGKey(seed), n)
    return eager, lazy


def _assert_same_roadmap(eager, lazy):
    """The lazy PRM's fully checked roadmap is the eager one edge for edge, weights bit for bit
    (the slots may differ: the lazy grow does not rank a row's candidates when the order decides
    nothing, and after a map update the eager PRM leaves a dropped edge in its slot)."""
    full = lazy.checked_roadmap()
    for field in ("points", "valid"):
        np.testing.assert_array_equal(
            np.asarray(getattr(full, field))[2:], np.asarray(getattr(eager.roadmap, field))[2:]
        )

    def edges(rm):
        ev = np.asarray(rm.edge_valid)[2:]
        rows = np.nonzero(ev)[0] + 2
        return sorted(
            zip(rows.tolist(), np.asarray(rm.neighbors)[2:][ev].tolist(), np.asarray(rm.edge_weight)[2:][ev].tolist())
        )

    assert edges(full) == edges(eager.roadmap)


@pytest.mark.slow
@pytest.mark.parametrize("sectors,k,x64", [(8, None, True), (8, 6, True), (0, 6, True), (8, 6, False)])
def test_lazy_prm_returns_the_eager_prms_paths(sectors, k, x64, monkeypatch):
    """Lazy PRM (check only what the query's shortest path needs) against the eager PRM on the
    same samples: every query finds the same shortest cost (the lazy search's answer is a
    shortest path of the eager roadmap), a second identical query checks nothing new, and once
    every edge is checked the lazy roadmap is the eager one edge for edge (candidates, the
    first-k-clear rule, weights). k = 6 with 8 sectors: rows hold more candidates than k, so later slots
    only count once the slots before them are checked. In float32 (``x64`` False) the lazy PRM's
    edges and both PRMs' query links are checked by the host's rule, the eager grow's by the
    device's."""
    with jax.enable_x64(x64):
        _lazy_returns_the_eager_paths(sectors, k, monkeypatch)


def _lazy_returns_the_eager_paths(sectors, k, monkeypatch):
    from jaxsem.planning import _map_setup  # layers: white-box

    occ = _blocks(3, shape=(60, 100), n=25)
    free = np.argwhere(~occ)
    rng = np.random.default_rng(3)
    eager, lazy = _lazy_and_eager(occ, sectors, k)
    # Its own per-map setup, no table yet, and windows at any size: the first query's start and
    # goal edges are checked through tables made on windows around them, with the eager answers;
    # later queries share the map's table (made once).
    monkeypatch.setattr(_map_setup, "_WHOLE_TABLE_SHARE", 0)
    lazy._setup = _map_setup._MapSetup(occ, lazy.roadmap.points.dtype)
    for i in range(5):
        s, g = (ORIGIN + (free[rng.integers(len(free))][::-1] + 0.5) * RES for _ in range(2))
        pe, pl = eager.query(s, g), lazy.query(s, g)
        assert lazy._setup.has_table == (i > 0)
        for field in ("neighbors", "edge_valid", "edge_weight"):
            np.testing.assert_array_equal(
                np.asarray(getattr(lazy.roadmap, field))[:2], np.asarray(getattr(eager.roadmap, field))[:2]
            )
        assert pe.found == pl.found
        if pe.found:
            np.testing.assert_allclose(pl.cost, pe.cost, rtol=1e-9)
            np.testing.assert_allclose(pl.length, pl.cost, rtol=1e-5)  # Euclidean weights
            assert pl.vertices[0] == 0 and pl.vertices[-1] == 1
        assert lazy._lazy is not None
        before = lazy._lazy.status.copy()
        again = lazy.query(s, g)
        np.testing.assert_array_equal(lazy._lazy.status, before)
        assert again.found == pl.found and (not pl.found or again.cost == pl.cost)
    # Only part of the roadmap was checked.
    assert 0 < np.count_nonzero(lazy._lazy.status == 0)
    _assert_same_roadmap(eager, lazy)


@pytest.mark.slow
def test_lazy_prm_after_a_map_update_and_without_a_path():
    """A newer map (a wall with a gap, then closed): the lazy PRM forgets what it checked clear,
    drops what the map blocks, and still returns the eager PRM's paths; with no route it finds
    none."""
    occ = _one_route_map()
    start, goal = np.array([1.0, 3.0]), np.array([9.0, 3.0])
    open_map = np.zeros_like(occ)
    eager, lazy = _lazy_and_eager(open_map, DEFAULT_SECTORS, None)
    pe, pl = eager.query(start, goal), lazy.query(start, goal)
    np.testing.assert_allclose(pl.cost, pe.cost, rtol=1e-9)
    for m in (occ, np.where(np.arange(occ.shape[1])[None, :] == 50, True, occ)):
        assert eager.update_map(m) and lazy.update_map(m)
        pe, pl = eager.query(start, goal), lazy.query(start, goal)
        assert pe.found == pl.found
        if pe.found:
            np.testing.assert_allclose(pl.cost, pe.cost, rtol=1e-9)
    assert not pl.found
    _assert_same_roadmap(eager, lazy)


def test_lazy_prm_bad_input():
    occ = _one_route_map()
    with pytest.raises(ValueError, match="lazy"):
        PRM(occ, grid_of(occ), capacity=N, lazy=1)
    with pytest.raises(ValueError, match="lazy"):
        PRM(occ, grid_of(occ), capacity=N, lazy=True, weight="neglogp")


@pytest.mark.slow
def test_roadmap_builder_vmaps_over_trials():
    from jaxsem.planning import make_roadmap_builder

    occ = _one_route_map()
    build = make_roadmap_builder(N, occ.shape, RES, radius=RADIUS, weight="neglogp", uniform=False)
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    dist = np.random.default_rng(0).random((3,) + occ.shape) + 0.1
    starts = np.array([[1.0, 3.0], [1.5, 2.0], [2.0, 4.0]])
    goals = np.array([[9.0, 3.0], [8.5, 1.0], [9.0, 5.0]])
    batch = jax.jit(jax.vmap(build, in_axes=(0, None, 0, 0, 0, None)))(
        keys, jnp.asarray(occ), dist, starts, goals, jnp.asarray(ORIGIN)
    )
    for i in range(3):
        one = build_roadmap(
            keys[i],
            occ,
            starts[i],
            goals[i],
            N,
            grid_of(occ),
            distribution=dist[i],
            weight="neglogp",
            radius=RADIUS,
        )
        np.testing.assert_allclose(np.asarray(batch.points[i]), np.asarray(one.points), rtol=1e-12)
        np.testing.assert_array_equal(np.asarray(batch.edge_valid[i]), np.asarray(one.edge_valid))
        np.testing.assert_allclose(np.asarray(batch.edge_weight[i]), np.asarray(one.edge_weight), rtol=1e-9)


def _switch_sizes(jaxpr) -> list[int]:
    """Branch counts of every cond/switch in a closed jaxpr, nested ones included."""
    out = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "cond":
            out.append(len(eqn.params["branches"]))
        for v in eqn.params.values():
            for sub in v if isinstance(v, (tuple, list)) else [v]:
                inner = getattr(sub, "jaxpr", None)
                if inner is not None and hasattr(inner, "eqns"):
                    out += _switch_sizes(inner)
                elif hasattr(sub, "eqns"):
                    out += _switch_sizes(sub)
    return out


def test_the_vmappable_builder_searches_neighbours_without_a_switch():
    """The host PRM's brute-force search picks its row width by a switch among four rankings;
    under ``vmap`` a switch runs every branch, so the vmappable builder ranks the whole width."""
    from jaxsem.planning import make_roadmap_builder
    from jaxsem.planning._grid import static_grid  # layers: white-box (the grow's program)
    from jaxsem.planning._roadmap import _grow_impl, roadmap_init  # layers: white-box

    occ = np.zeros((120, 160), bool)
    build = make_roadmap_builder(300, occ.shape, RES, radius=4.0, weight="neglogp", uniform=False)
    args = (jax.random.PRNGKey(0), jnp.asarray(occ), jnp.ones(occ.shape), jnp.ones(2), jnp.full(2, 5.0), jnp.zeros(2))
    built = jax.make_jaxpr(build)(*args)
    grid = static_grid(grid_of(occ))

    def host_grow(key, blocked, dist):
        return _grow_impl(
            roadmap_init(300, 12),
            key,
            blocked,
            dist,
            grid,
            n=300,
            radius=4.0,
            edge_samples=81,
            extent=(16.0, 12.0),
            cap=None,
            neglogp=True,
            sectors=8,
        )

    grown = jax.make_jaxpr(host_grow)(*args[:2], jnp.ones(occ.shape))
    assert 4 in _switch_sizes(grown.jaxpr)
    assert 4 not in _switch_sizes(built.jaxpr)


@pytest.mark.slow
def test_found_paths_pass_the_navigation_check():
    """Regression (issue 11): the loop re-checked plans with a second, stricter segment test, so a
    path grazing a wall corner was 'blocked' right after the PRM found it clear and a robot on a
    reused roadmap replanned the same path forever without moving. Both now share one check."""
    from jaxsem.planning._edges import polyline_clear  # layers: white-box

    occ = _blocks(7, shape=(60, 100), n=60)
    prm = PRM(occ, grid_of(occ), capacity=N, radius=RADIUS)
    prm.grow(jax.random.PRNGKey(5), N)
    free = np.argwhere(~occ)
    rng = np.random.default_rng(0)
    found = 0
    for _ in range(25):
        s, g = (ORIGIN + (free[rng.integers(len(free))][::-1] + rng.random(2)) * RES for _ in range(2))
        p = prm.query(s, g)
        if p.found:
            found += 1
            assert polyline_clear(p.points, occ, grid_of(occ), RADIUS)
            # Every sub-leg from a point part-way along the first segment too (the robot moved).
            mid = p.points[0] + 0.37 * (p.points[1] - p.points[0])
            q = prm.query(mid, g)
            assert q.found and polyline_clear(q.points, occ, grid_of(occ), RADIUS)
    assert found >= 15


def _brute_sector_knn(pts, valid, k, radius, sectors, self_idx):
    """Reference for the direction-first rule: the nearest ceil(k / 2S) of each of S sectors,
    then the nearest of the rest, k in all (distances, sorted)."""
    m = max(1, -(-k // (2 * sectors)))
    out = []
    for i, q in enumerate(pts):
        d = np.linalg.norm(pts - q, axis=1)
        ok = valid & (d <= radius)
        ok[self_idx[i]] = False
        ang = np.arctan2(pts[:, 1] - q[1], pts[:, 0] - q[0])
        sec = np.clip(np.floor((ang + np.pi) * sectors / (2 * np.pi)).astype(int), 0, sectors - 1)
        first = []
        for s in range(sectors):
            idx = np.flatnonzero(ok & (sec == s))
            first += list(idx[np.argsort(d[idx])][:m])
        first = sorted(first, key=lambda j: d[j])[:k]
        rest = np.flatnonzero(ok)
        rest = [j for j in rest[np.argsort(d[rest])] if j not in set(first)][: k - len(first)]
        dd = np.sort(d[first + rest]) if first or rest else np.zeros(0)
        out.append(np.concatenate([dd, np.full(k - len(dd), np.inf)]))
    return np.array(out)


@pytest.mark.parametrize("kind", ["uniform", "concentrated"])
def test_knn_sectors_match_brute_force(kind):
    """The direction-first neighbour rule (issue 11), bucketed and brute force, against numpy."""
    rng = np.random.default_rng(1)
    pts = _samples(kind, rng, 400)
    valid = rng.random(400) > 0.1
    knn = jax.jit(knn_within_radius, static_argnums=(2, 3, 4, 5, 6))
    ref = _brute_sector_knn(pts, valid, 10, 0.9, 4, np.arange(400))
    for cap in (None, 512):
        nb, overflow = knn(jnp.asarray(pts), jnp.asarray(valid), 10, 0.9, (12.0, 7.0), cap, 4)
        assert not bool(overflow)
        got = _sorted_dists(pts, pts, np.asarray(nb))[valid]
        np.testing.assert_allclose(got, ref[valid], rtol=1e-9)


@pytest.mark.parametrize(
    "spread,fullest", [(3.0, (1, 32)), (2.2, (32, 32)), (1.6, (33, 64)), (1.2, (65, 128)), (0.9, (129, 299))]
)
def test_brute_force_rows_rank_alike_at_every_width(spread, fullest, monkeypatch):
    """A brute-force search ranks its rows in blocks sorted by their counts of candidates within
    the radius, each block narrowed to the fewest columns that hold its fullest row's: at every
    width (the fullest row's count in ``fullest``: each width, one at its edge, and one past
    them all) the same neighbours in the same order as ranking the whole width, with the
    direction sectors and a sampling density, and the sector rule's distances."""
    from jaxsem.planning import _neighbours  # layers: white-box (the search's branches)

    rng = np.random.default_rng(int(spread * 10))
    M, k, radius = 300, 10, 1.0
    pts = np.clip(np.array([6.0, 3.5]) + rng.normal(0.0, spread, (M, 2)), 0.01, [11.99, 6.99])
    valid = rng.random(M) > 0.05
    density = jnp.asarray(rng.uniform(0.5, 1.5, M), jnp.float32)
    args = (jnp.asarray(pts, jnp.float32), jnp.asarray(valid), jnp.asarray(pts, jnp.float32), jnp.arange(M))
    kw = dict(k=k, radius=radius, extent=(12.0, 7.0), cap=None, sectors=4, keep=2 * k)
    got = np.asarray(jax.jit(lambda *a: _neighbours._knn(*a, **kw, density=density)[0])(*args))
    monkeypatch.setattr(_neighbours, "_NARROW", ())  # every block ranked over the whole width
    want = np.asarray(jax.jit(lambda *a: _neighbours._knn(*a, **kw, density=density)[0])(*args))
    np.testing.assert_array_equal(got, want)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    d[:, ~valid] = np.inf
    np.fill_diagonal(d, np.inf)
    assert fullest[0] <= np.max(np.sum(d <= radius, axis=1)) <= fullest[1]
    # Without the density the first k are the direction-first rule's (distances, sorted).
    got = np.asarray(jax.jit(lambda *a: _neighbours._knn(*a, **kw)[0])(*args))[:, :k]
    ref = _brute_sector_knn(pts.astype(np.float32).astype(np.float64), valid, k, radius, 4, np.arange(M))
    np.testing.assert_allclose(_sorted_dists(pts, pts, got)[valid], ref[valid], rtol=1e-5, atol=1e-5)


def _cluster_behind_wall():
    """10 x 6 m: a wall at x = 4 m with a 1 m door; a learned-like distribution, e^5 denser in a
    3 x 3 m patch left of the wall than elsewhere (an LSD window and the world around it: the
    patch draws 94 % of the samples, the rest of the map is as sparse as outside the window)."""
    occ = np.zeros((60, 100), bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    occ[:, 40:42] = True
    occ[25:35, 40:42] = False  # the door, y 2.5-3.5 m
    dist = np.ones(occ.shape)
    dist[15:45, 10:40] = math.exp(5.0)
    return occ, dist


@pytest.mark.slow
def test_sparse_side_of_a_learned_distribution_is_linked():
    """Regression (issue 11, Inside-Outside 'no plan'): with samples concentrated by a learned
    distribution, the few samples beyond the dense patch lay further apart than the uniform
    planner's radius, so they formed islands, and the plain k nearest of vertices near the wall
    all lay in the patch; the goal beyond the door was cut off in most roadmaps. The online
    planner's rule for a learned sampler (twice the radius, direction-first links, query edges
    at any distance) links it."""
    from jaxsem.planning import NavConfig, Trial

    occ, dist = _cluster_behind_wall()
    base = 1.2
    learned = NavConfig(radius=None)
    assert Trial.connection_radius(learned, (372, 520), RES, True) == 2 * Trial.connection_radius(
        learned, (372, 520), RES, False
    )
    start, goal = np.array([2.5, 3.0]), np.array([9.0, 5.0])
    found = {"old": 0, "new": 0}
    for seed in range(8):
        for name, sectors, radius in (("old", 0, base), ("new", learned.sectors, 2 * base)):
            prm = PRM(occ, grid_of(occ), capacity=300, k=12, radius=radius, sectors=sectors)
            prm.grow(jax.random.PRNGKey(seed), 300, dist)
            p = prm.query(start, goal)
            if p.found:
                found[name] += 1
                assert polyline_clear(p.points, occ, grid_of(occ), radius)
                assert np.allclose(p.points[[0, -1]], [start, goal])
    assert found["new"] >= 7 and found["old"] <= 2, found


@pytest.mark.slow
def test_query_links_to_samples_beyond_radius():
    occ = np.zeros((60, 100), bool)
    dist = np.zeros(occ.shape)
    dist[:, :30] = 1.0  # samples only in x < 3 m
    prm = PRM(occ, grid_of(occ), capacity=200, k=8, radius=1.0)
    prm.grow(jax.random.PRNGKey(0), 200, dist)
    goal = np.array([9.5, 3.0])  # > 6 m from every sample
    p = prm.query(np.array([1.0, 3.0]), goal)
    assert p.found and np.linalg.norm(p.points[-2] - goal) > 6.0
    assert polyline_clear(p.points, occ, grid_of(occ), 1.0)
    occ[:, 50:52] = True  # a wall across the map: no edge may cross it
    prm2 = PRM(occ, grid_of(occ), capacity=200, k=8, radius=1.0)
    prm2.grow(jax.random.PRNGKey(0), 200, dist)
    assert not prm2.query(np.array([1.0, 3.0]), goal).found


@pytest.mark.slow
def test_uniform_growth_spreads_samples_but_keeps_the_learned_weights():
    # NavConfig.growth='uniform': a failed roadmap of a learned sampler grows with uniform
    # samples; its edges keep the distribution's -log p weights.
    from jaxsem.planning import NavConfig

    occ = np.zeros((60, 100), bool)
    dist = np.full(occ.shape, 1e-6)
    dist[10:20, 70:80] = 1.0  # 1/60 of the map holds almost all the mass
    prm = PRM(occ, grid_of(occ), capacity=600, k=10, radius=1.0, weight="neglogp")
    prm.grow(jax.random.PRNGKey(0), 300, dist)
    prm.grow(jax.random.PRNGKey(1), 300, uniform_samples=True)
    pts = np.asarray(prm.roadmap.points)[2:]
    inside = (pts[:, 0] >= 7.0) & (pts[:, 0] < 8.0) & (pts[:, 1] >= 1.0) & (pts[:, 1] < 2.0)
    assert inside[:300].mean() > 0.95  # the sampler's own samples
    assert abs(inside[300:].mean() - 1 / 60) < 0.03  # the uniform growth's
    assert prm.distribution is not None  # weights still -log p of the distribution
    with pytest.raises(ValueError, match="growth"):
        from jaxsem.planning import Trial

        Trial(_two_rooms_world(), [1.0, 1.0], [2.0, 2.0], jax.random.PRNGKey(0), NavConfig(growth="bogus"))


def _two_rooms_world():
    import types

    occ = np.zeros((30, 30), bool)
    return types.SimpleNamespace(
        occupancy=occ, semantic=np.zeros(occ.shape, np.int8), indoor=np.ones_like(occ), origin=ORIGIN, resolution=RES
    )


@pytest.mark.slow
@pytest.mark.parametrize("n", [1000, 5000])
def test_one_shot_neighbours_exact_on_concentrated_samples(n):
    """Issue 25 item 5: building 7307 of the test family made obstacle-free, 80 % of the mass on
    a 3 x 3-cell patch (hundreds of samples within centimetres), ``sectors=0``: every sample's
    neighbour list holds exactly its k nearest of all samples within the radius."""
    b = generate_building(7307, "test")
    free = np.zeros(b.occupancy.shape, bool)
    dist = np.ones(free.shape)
    r0, c0 = free.shape[0] // 2, free.shape[1] // 2
    dist[r0 : r0 + 3, c0 : c0 + 3] = 0.8 * free.size / 9 / 0.2
    start = b.origin + np.array([0.05, 0.05])
    goal = b.origin + np.array([1.05, 1.05])
    k, radius = prm_star_k(n), default_radius(n, free.shape, b.resolution)
    rm = build_roadmap(
        jax.random.PRNGKey(7307),
        free,
        start,
        goal,
        n,
        b,
        distribution=dist,
        sectors=0,  # the plain k nearest, checked against brute force
    )
    pts = np.asarray(rm.points)
    valid = np.asarray(rm.valid).copy()
    valid[:2] = False  # query slots: samples never link to them
    assert valid[2:].all()
    ref = _brute_knn(pts, valid, k, radius, queries=pts[2:], self_idx=np.arange(2, n + 2))
    got = _sorted_dists(pts, pts[2:], np.asarray(rm.neighbors)[2:])
    hot = np.sum(ref[:, -1] < 0.05)
    assert hot > n // 2  # the case of the issue: most k-th neighbours within centimetres
    np.testing.assert_allclose(got, ref, rtol=1e-12)


def _thin_wall_map(rng):
    occ = np.zeros((60, 80), bool)
    for _ in range(6):  # one-cell walls at random angles: easy to skip between samples
        r, c = rng.integers(5, 55), rng.integers(5, 75)
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        for s in np.linspace(0, 25, 200):
            rr, cc = int(r + s * d[0]), int(c + s * d[1])
            if 0 <= rr < 60 and 0 <= cc < 80:
                occ[rr, cc] = True
    occ[20:40, 30:50] = False
    occ[25:35, 35:45] = True  # a block with open space around it
    return occ


def test_segment_check_never_crosses_walls_and_accepts_open_space():
    """The edge rule on many segments of thin-wall maps (most decided without reading every
    sample): an accepted segment touches no occupied cell (dense sampling); a segment that has
    a point deep inside an occupied cell is rejected; one far from every wall is accepted."""
    rng = np.random.default_rng(25)
    accepted = rejected = 0
    for m in range(3):
        occ = _thin_wall_map(rng)
        free_cells = np.argwhere(~occ)
        t = np.linspace(0.0, 1.0, 2001)[:, None]
        for _ in range(60):
            a = (free_cells[rng.integers(len(free_cells))][::-1] + rng.random(2)) * RES
            b = a + rng.normal(size=2) * 1.5
            b = np.clip(b, 1e-3, np.array([80, 60]) * RES - 1e-3)
            ok = polyline_clear(np.stack([a, b]), occ, grid_of(occ), RADIUS)
            u = (a + t * (b - a)) / RES
            rc = np.floor(u).astype(int)
            inside = occ[rc[:, 1], rc[:, 0]]
            deep = inside & np.all(np.abs(u - np.floor(u) - 0.5) < 0.3, axis=1)
            if ok:
                interior = np.all(np.abs(u - np.round(u)) > 1e-7, axis=1)
                assert not np.any(inside & interior), (m, a, b)
                accepted += 1
            else:
                rejected += 1
            if deep.any():
                assert not ok, (m, a, b)
    assert accepted > 20 and rejected > 20
    open_map = np.zeros((60, 80), bool)
    assert polyline_clear(np.array([[1.0, 1.0], [7.0, 5.0], [2.0, 5.0]]), open_map, grid_of(open_map), RADIUS)


def _dense_rule(a, b, occ, samples):
    """The edge rule read at every sample (numpy, float32 like the PRM): each sample's cell
    free and on the map, both side cells of every diagonal step free."""
    f = np.float32
    t = np.arange(samples, dtype=f) / f(samples - 1)
    a, b = a.astype(f), b.astype(f)
    u = np.floor((a + t[:, None] * (b - a) - ORIGIN.astype(f)) / f(RES)).astype(int)
    r, c = u[:, 1], u[:, 0]
    H, W = occ.shape
    if np.any((r < 0) | (r >= H) | (c < 0) | (c >= W)) or occ[r, c].any():
        return False
    diag = (r[1:] != r[:-1]) & (c[1:] != c[:-1])
    return not np.any(diag & (occ[r[:-1], c[1:]] | occ[r[1:], c[:-1]]))


def test_segment_check_equals_the_dense_rule():
    """The edge check reads most samples through the clearance table and only the intervals
    near a wall densely; its answer must be the dense rule's on every segment (short ones at
    the roadmap's samples, long ones at the query reach's), walls grazed included."""
    rng = np.random.default_rng(7)
    occ = _thin_wall_map(rng)
    free_cells = np.argwhere(~occ)
    reach = 2.0 ** math.ceil(math.log2(math.hypot(6.0, 8.0)))
    counts = {True: 0, False: 0}
    for i in range(240):
        a = (free_cells[rng.integers(len(free_cells))][::-1] + rng.random(2)) * RES
        long = i % 3 == 0
        b = a + rng.normal(size=2) * (3.0 if long else 0.6)
        b = np.clip(b, 1e-3, np.array([80, 60]) * RES - 1e-3)
        length = np.linalg.norm(b - a)
        if long == (length <= RADIUS):
            continue
        r = reach if long else RADIUS
        samples = max(2, int(math.ceil(r / (0.5 * RES))) + 1)
        ok = polyline_clear(np.stack([a, b]), occ, grid_of(occ), RADIUS)
        assert ok == _dense_rule(a, b, occ, samples), (a, b)
        counts[ok] += 1
    assert counts[True] > 20 and counts[False] > 20


def test_host_clearance_table_equals_the_jitted_one():
    """The PRM makes the edge check's clearance table on the host once per map; its values
    must be the jitted table's (odd shapes, empty to dense maps, walls of one cell)."""
    from jaxsem.planning._edges import _clearance_table, _clearance_table_np  # layers: white-box

    rng = np.random.default_rng(5)
    table = jax.jit(_clearance_table)  # one compile per shape: two shapes
    maps = [_thin_wall_map(rng), np.ones((60, 80), bool)]
    maps += [rng.random(shape) < p for shape in [(60, 80), (33, 65)] for p in (0.0, 0.002, 0.02, 0.3)]
    for occ in maps:
        np.testing.assert_array_equal(_clearance_table_np(occ), np.asarray(table(jnp.asarray(occ))))


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.sampled_from([(300, 260), (257, 97), (64, 500)]),
    st.lists(st.tuples(st.floats(0, 1), st.floats(0, 1), st.integers(1, 40), st.integers(1, 40)), max_size=3),
)
def test_a_map_seen_again_with_changes_updates_its_clearance_table(seed, shape, changes):
    """A robot's map changes between two looks in a few windows: the clearance table of the
    newer map is remade only around them, from the older map's; its values are the table made
    anew (changes anywhere: the middle, the edges, corners, several at once, none)."""
    from jaxsem.planning._edges import _clearance_table_np  # layers: white-box
    from jaxsem.planning._map_setup import _MapSetup, _table_update  # layers: white-box

    rng = np.random.default_rng(seed)
    old = rng.random(shape) < rng.choice([0.0, 0.001, 0.01, 0.05])
    new = old.copy()
    for fr, fc, h, w in changes:
        r, c = int(fr * (shape[0] - 1)), int(fc * (shape[1] - 1))
        new[r : r + h, c : c + w] = rng.random(new[r : r + h, c : c + w].shape) < 0.5
    want = _clearance_table_np(new)
    np.testing.assert_array_equal(_table_update(_clearance_table_np(old), old, new), want)
    first = _MapSetup(old, np.float32)
    first.table()
    np.testing.assert_array_equal(np.asarray(_MapSetup(new, np.float32, first).table()), want)


def test_the_per_map_setup_is_kept_by_content():
    """The PRM keeps its per-map setup for the latest maps, matched cell for cell: a map edited
    in place (the same array object) gets its own setup, the original map's comes back from
    the cache, and clear_map_cache forgets it."""
    from jaxsem.planning import clear_map_cache
    from jaxsem.planning._edges import _clearance_table_np  # layers: white-box

    occ = np.zeros((60, 80), bool)
    first = PRM(occ, grid_of(occ), capacity=50)
    assert PRM(occ.copy(), grid_of(occ.copy()), capacity=50)._setup is first._setup
    occ[10:50, 40] = True  # edited in place
    edited = PRM(occ, grid_of(occ), capacity=50)
    assert edited._setup is not first._setup
    np.testing.assert_array_equal(np.asarray(edited._setup.table()), _clearance_table_np(occ))
    assert PRM(np.zeros((60, 80), bool), grid_of(np.zeros((60, 80), bool)), capacity=50)._setup is first._setup
    clear_map_cache()
    again = PRM(occ, grid_of(occ), capacity=50)
    assert again._setup is not edited._setup
    np.testing.assert_array_equal(np.asarray(again._setup.table()), np.asarray(edited._setup.table()))
    for a, b in zip(again._setup.aids(table=False), edited._setup.aids(table=False)):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@settings(max_examples=40, deadline=None)
@given(shape=st.tuples(st.integers(1, 23), st.integers(1, 23)), seed=st.integers(0, 2**16), which=st.floats(0, 1))
def test_a_map_one_cell_apart_is_not_taken_for_the_cached_one(shape, seed, which):
    """The per-map cache matches maps eight cells to a word: a map differing from a cached one
    in any single cell (the last cells too, past the last whole word) gets a setup of its own;
    a copy of it, the cached one; a map of other shape with the same cells, its own."""
    from jaxsem.planning._map_setup import _same_cells  # layers: white-box

    occ = np.random.default_rng(seed).random(shape) < 0.3
    other = occ.copy()
    other.flat[min(int(which * occ.size), occ.size - 1)] ^= True
    assert _same_cells(occ, occ.copy()) and not _same_cells(occ, other)
    if occ.shape[0] > 1:
        assert not _same_cells(occ, occ.reshape(1, -1))


def test_free_cell_sampling_draws_the_cdf_samples():
    """Uniform samples come from the free cells' bit words (no CDF over every cell): the same
    points as the CDF search draws, bit for bit, on maps from empty to nearly full and with a
    single free cell (the last one)."""
    from jaxsem.planning._edges import _grid  # layers: white-box
    from jaxsem.planning._sampling import (  # layers: white-box
        _free_words,
        _sampling_weights,
        sample_free_cells,
        sample_points,
    )

    rng = np.random.default_rng(0)
    origin = jnp.asarray(ORIGIN, jnp.float32) + 0.37
    one = np.ones((33, 65), bool)
    one[32, 64] = False
    maps = [rng.random((33, 65)) < p for p in (0.3, 0.0, 0.99)] + [one]
    grid = _grid(Q.Grid.host(origin, RES, (33, 65)), jnp.float32)
    by_cdf = jax.jit(lambda key, occ: sample_points(key, _sampling_weights(occ, None), 3000, grid))
    by_words = jax.jit(lambda key, w, c: sample_free_cells(key, w, c, 3000, grid))
    for occ in maps:
        words, counts = _free_words(~occ)
        for seed in range(2):
            key = jax.random.PRNGKey(seed)
            want = by_cdf(key, jnp.asarray(occ))
            got = by_words(key, jnp.asarray(words), jnp.asarray(counts))
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_a_query_table_on_windows_gives_the_edge_checks_answers():
    """A lazy PRM's query on a new map reads the clearance table only around its start and goal
    (made on windows, 0 elsewhere): every value is at most the whole table's, and the edge check
    gives the rule's answers with it on edges inside, across and outside the windows."""
    from jaxsem.planning._edges import _clearance_table_np, _edges_clear, _edges_dense, _grid  # layers: white-box
    from jaxsem.planning._map_setup import _MapSetup  # layers: white-box

    occ = _blocks(11, shape=(150, 260), n=80)
    setup = _MapSetup(occ, np.float32)
    window = setup.query_table([(0, 40, 0, 40), (100, 150, 200, 260)])
    assert not setup.has_table
    whole = _clearance_table_np(occ)
    w = np.asarray(window)
    assert w.shape == whole.shape and np.all(w <= whole) and w[:16, :16].any() and not w[34:, 34:90].any()
    rng = np.random.default_rng(4)
    a = rng.random((400, 2)) * [8.0, 6.0]
    b = a + rng.normal(0.0, 2.0, (400, 2))
    grid = _grid(grid_of(occ), jnp.float32)
    a, b = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
    want, got = jax.jit(
        lambda blocked, table: (
            _edges_dense(blocked, a, b, grid, 61)[0],
            _edges_clear(blocked, a, b, grid, 61, table=table),
        )
    )(jnp.asarray(occ), window)
    assert 0 < int(np.sum(want)) < 400
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


@pytest.mark.parametrize("chunk", [64, 300, 2048, 8192])
def test_the_edge_check_answers_alike_at_any_work_list_width(chunk):
    """The work lists' static width sets only how many edges a step reads: masked edges, several
    steps and a part-filled last one give the dense rule's answers at every width."""
    from jaxsem.planning._edges import _edges_clear, _edges_dense, _grid  # layers: white-box

    occ = _blocks(5, shape=(150, 260), n=80)
    rng = np.random.default_rng(chunk)
    a = rng.random((700, 2)) * [12.0, 7.0]
    b = a + rng.normal(0.0, 2.0, (700, 2))
    mask = rng.random(700) < 0.6
    grid = _grid(grid_of(occ), jnp.float32)
    a, b = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
    want = np.asarray(_edges_dense(jnp.asarray(occ), a, b, grid, 61)[0]) & mask
    got = jax.jit(lambda blocked: _edges_clear(blocked, a, b, grid, 61, jnp.asarray(mask), chunk=chunk))(
        jnp.asarray(occ)
    )
    assert 0 < int(want.sum()) < int(mask.sum())
    np.testing.assert_array_equal(np.asarray(got), want)


@functools.partial(jax.jit, static_argnames=("grid", "samples"))
def _edges_clear_jit(blocked, a, b, *, grid, samples):
    """The edge rule under ``jit`` with the grid's numbers compile-time constants, compiled once
    for every example of one shape (a closure over the edges would compile per example)."""
    from jaxsem.planning._edges import _edges_clear, _grid  # layers: white-box

    return _edges_clear(blocked, a, b, _grid(grid, a.dtype), samples)


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_edges_the_sparse_discs_settle_are_clear_under_the_dense_rule(seed):
    """Long edges over open ground with a few thin walls: the edge check settles most of them
    from the clearance discs of a sparse subset of samples alone, and those are clear under the
    dense rule; every answer, settled or not, is the dense rule's."""
    from jaxsem.planning._edges import _edges_dense, _grid  # layers: white-box
    from jaxsem.planning._grid import static_grid  # layers: white-box

    rng = np.random.default_rng(seed)
    occ = np.zeros((300, 400), bool)
    for _ in range(rng.integers(2, 7)):  # thin walls, some diagonal
        r, c = rng.integers(20, 280), rng.integers(20, 380)
        dr, dc = rng.choice([-1, 0, 1]), rng.choice([0, 1])
        for i in range(rng.integers(20, 120)):
            occ[np.clip(r + dr * i, 0, 299), np.clip(c + dc * i + (dr == 0) * i, 0, 399)] = True
    a = rng.random((600, 2)) * [40.0, 30.0]
    b = np.clip(a + rng.normal(0.0, 6.0, (600, 2)), 0.0, [39.99, 29.99])
    grid = _grid(grid_of(occ), jnp.float32)
    a, b = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
    S = 301  # 15 m at half a cell
    want = np.asarray(_edges_dense(jnp.asarray(occ), a, b, grid, S)[0])
    got = np.asarray(_edges_clear_jit(jnp.asarray(occ), a, b, grid=static_grid(grid_of(occ)), samples=S))
    np.testing.assert_array_equal(got, want)
    assert 0 < want.sum() < len(want)
    # The sparse discs alone settle a share of the edges (the path above is exercised), and
    # settle nothing the dense rule calls blocked.
    from jaxsem.planning._edges import _clearance_table, _covered_whole, _sparse_subset, _subset  # layers: white-box

    sp = _sparse_subset(_subset(S)[0])
    t = jnp.asarray(sp / (S - 1), jnp.float32)
    gap = jnp.asarray(np.diff(sp) / (S - 1), jnp.float32)
    settled = np.asarray(_covered_whole(_clearance_table(jnp.asarray(occ)), a, b, grid, t, gap))
    assert 0.2 < settled.mean() < 0.98
    assert np.all(want[settled])


def test_a_one_shot_learned_roadmap_links_like_the_navigation_loop():
    """Regression (issue 23, friction 5): ``PRM(weight='neglogp')`` took the uniform radius, so
    a one-shot LSD roadmap on a user's grid left its few samples outside the window unlinked; the
    navigation loop's learned radius lived only in ``NavConfig``."""
    from jaxsem.planning import NavConfig, Trial

    occ = np.zeros((200, 300), bool)
    uniform = PRM(occ, grid_of(occ), capacity=500, weight="euclidean")
    learned = PRM(occ, grid_of(occ), capacity=500, weight="neglogp")
    loop = Trial.connection_radius(NavConfig(n_samples=500, max_growth=0), occ.shape, RES, learned=True)
    assert learned.radius == loop
    assert learned.radius >= 1.9 * uniform.radius


@pytest.mark.slow
def test_a_large_grow_keeps_the_first_k_clear_of_the_direction_rule():
    """A grow of more vertices than the neighbour search and the edge check take at a time (both
    work through blocks of rows): every vertex's list is, in order, the first k of its 2k
    direction-first candidates (numpy) whose edge passes the dense rule (numpy)."""
    rng = np.random.default_rng(3)
    occ = _thin_wall_map(rng)
    n, k, radius, sectors = 2600, 6, 0.5, 4
    prm = PRM(occ, grid_of(occ), capacity=n, k=k, radius=radius, sectors=sectors)
    prm.grow(jax.random.PRNGKey(0), n)
    pts = np.asarray(prm.roadmap.points)
    valid = np.asarray(prm.roadmap.valid)
    nbr, ev = np.asarray(prm.roadmap.neighbors), np.asarray(prm.roadmap.edge_valid)
    M = len(pts)
    samples = max(2, int(math.ceil(radius / (0.5 * RES))) + 1)
    m = max(1, -(-k // (2 * sectors)))
    for i in range(2, M):
        d = np.linalg.norm(pts - pts[i], axis=1)
        ok = valid & (d <= radius) & (np.arange(M) >= 2)
        ok[i] = False
        ang = np.arctan2(pts[:, 1] - pts[i, 1], pts[:, 0] - pts[i, 0])
        sec = np.clip(np.floor((ang + np.pi) * sectors / (2 * np.pi)).astype(int), 0, sectors - 1)
        first = []
        for s in range(sectors):
            idx = np.flatnonzero(ok & (sec == s))
            first += list(idx[np.argsort(d[idx])][:m])
        first = sorted(first, key=lambda j: d[j])
        rest = np.flatnonzero(ok)
        rest = [j for j in rest[np.argsort(d[rest])] if j not in set(first)]
        cands = (first + rest)[: 2 * k]
        want = [j for j in cands if _dense_rule(pts[i], pts[j], occ, samples)][:k]
        assert list(nbr[i][ev[i]]) == want, i
        assert not ev[i][len(want) :].any() and np.all(nbr[i][len(want) :] == M)


def _half_known_map():
    """The 10 x 6 m walled room (int8 partial map) with a 4 x 3 m block in it: the lower half
    (y < 3 m) known free, the upper half unknown. All the unknown-weight tests grow their
    roadmaps on this one map with the same ``N`` and ``RADIUS``, so they share the compiled grows
    (with and without the unknown cells' weights): each different map's free-cell count is a
    different strip size, i.e. another compile of the grow (about 10 s each)."""
    known = np.zeros((60, 100), np.int8)  # FREE
    known[30:, :] = UNKNOWN
    known[[0, -1], :] = OCCUPIED
    known[:, [0, -1]] = OCCUPIED
    known[12:42, 30:70] = OCCUPIED
    return known


def _unknown_share(a, b, unknown, samples=2000, rows=512):
    """Share of each segment's length (a, b: (E, 2)) over unknown cells, by dense sampling (the
    reference; numpy, ``rows`` segments at a time)."""
    t = (np.arange(samples) + 0.5) / samples
    out = np.empty(len(a))
    for i in range(0, len(a), rows):
        p, q = a[i : i + rows], b[i : i + rows]
        pts = p[:, None] + t[None, :, None] * (q - p)[:, None]
        cell = np.floor((pts - ORIGIN) / RES).astype(int)
        out[i : i + rows] = unknown[cell[..., 1], cell[..., 0]].mean(-1)
    return out


def _edge_list(rm):
    pts, nbr = np.asarray(rm.points, np.float64), np.asarray(rm.neighbors)
    ev, w = np.asarray(rm.edge_valid), np.asarray(rm.edge_weight, np.float64)
    i, j = np.nonzero(ev)
    i, j = i[i >= 2], j[i >= 2]  # the samples' own edges
    return pts[i], pts[nbr[i, j]], w[i, j]


@pytest.mark.slow  # over 10 s of compiles: the fast suite keeps its margin
def test_unknown_weight_charges_metres_through_unknown_cells():
    known = _half_known_map()
    unknown = known == UNKNOWN
    key = jax.random.PRNGKey(4)
    plain = PRM(known, grid_of(known), capacity=N, radius=RADIUS)
    plain.grow(key, N)
    for weight, dist in (("euclidean", None), ("neglogp", np.ones(known.shape))):
        prm = PRM(known, grid_of(known), capacity=N, radius=RADIUS, weight=weight, unknown_weight=3.0)
        prm.grow(key, N, dist)
        # The same links as the plain roadmap (only the weights change).
        np.testing.assert_array_equal(np.asarray(prm.roadmap.edge_valid), np.asarray(plain.roadmap.edge_valid))
        a, b, w = _edge_list(prm.roadmap)
        length = np.linalg.norm(b - a, axis=1)
        unit = 1.0 if dist is None else np.log(known.size)  # -log p of a uniform distribution
        share = _unknown_share(a, b, unknown)
        # The PRM reads 31 points per edge (half a cell apart at the radius): the share is
        # theirs, within about one point's worth of the dense one.
        err = np.abs(w - unit * length * (1 + 2 * share))
        assert np.all(err <= unit * 2 * length * 1.5 / 30 + 1e-5), err.max()
        assert (share == 0).sum() > 100 and (share == 1).sum() > 100 and ((share > 0) & (share < 1)).sum() > 20
        np.testing.assert_allclose(w[share == 0], unit * length[share == 0], rtol=1e-5)
        np.testing.assert_allclose(w[share == 1], 3 * unit * length[share == 1], rtol=1e-5)


def test_unknown_weight_reweighs_edges_when_cells_become_known():
    known = _half_known_map()
    prm = PRM(known, grid_of(known), capacity=N, radius=RADIUS, unknown_weight=3.0)
    prm.grow(jax.random.PRNGKey(4), N)
    links = np.asarray(prm.roadmap.edge_valid).copy()
    seen = np.where(known == UNKNOWN, np.int8(0), known)  # the same obstacles, everything seen
    assert prm.update_map(seen) and not prm.update_map(seen)
    np.testing.assert_array_equal(np.asarray(prm.roadmap.edge_valid), links)
    a, b, w = _edge_list(prm.roadmap)
    np.testing.assert_allclose(w, np.linalg.norm(b - a, axis=1), rtol=1e-5)


@pytest.mark.slow
def test_unknown_weight_takes_the_route_seen_free():
    # The 4 x 3 m block in the room: the way over it is 0.7 m shorter but all unknown, the way
    # under it known free. The thesis' weights go over, unknown cells charged 4x go under.
    known = _half_known_map()
    start, goal = np.array([1.0, 3.0]), np.array([9.0, 3.0])
    ys = {}
    for uw in (1.0, 4.0):
        prm = PRM(known, grid_of(known), capacity=N, radius=RADIUS, unknown_weight=uw)
        prm.grow(jax.random.PRNGKey(0), N)
        p = prm.query(start, goal)
        assert p.found
        ys[uw] = p.points[:, 1]
    assert ys[1.0].max() > 4.0  # over the block
    assert ys[4.0].min() < 1.3 and ys[4.0].max() <= 3.1  # under it, never into the unknown half


def test_unknown_weight_bad_input():
    known = _half_known_map()
    for bad in (0.0, -1.0, float("inf"), float("nan"), True, "2"):
        with pytest.raises(ValueError, match="unknown_weight"):
            PRM(known, grid_of(known), capacity=10, unknown_weight=bad)
    with pytest.raises(ValueError, match="known_map"):
        PRM(known == OCCUPIED, grid_of(known == OCCUPIED), capacity=10, unknown_weight=2.0)
    with pytest.raises(ValueError, match="lazy"):
        PRM(known, grid_of(known), capacity=10, unknown_weight=2.0, lazy=True)
    prm = PRM(known, grid_of(known), capacity=10, unknown_weight=2.0)
    with pytest.raises(ValueError, match="known_map"):
        prm.update_map(known == OCCUPIED)

"""The roadmap search's compiled A* against a brute-force reference (scipy's Dijkstra over the
same edges written as a plain undirected edge list)."""

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.csgraph
from hypothesis import given, settings, strategies as st

from jaxsem.planning._astar import _z_order, astar_path, search_graph  # layers: white-box


def random_roadmap(rng, M, K, *, p_use, stretch):
    """Rows 0 and 1 are the query slots (no rows of their own); sample rows name samples."""
    pts = rng.uniform(0, 10, (M, 2)).astype(np.float32)
    nbr = rng.integers(2, M + 3, (M, K)).astype(np.int32)  # some entries past M: none
    nbr[nbr >= M] = M
    nbr[:2] = M
    usable = (rng.random((M, K)) < p_use) & (nbr < M) & (nbr != np.arange(M)[:, None])
    usable[:2] = False
    d = pts[np.minimum(nbr, M - 1)].astype(np.float64) - pts[:, None, :]
    length = np.hypot(d[..., 0], d[..., 1])
    w = np.maximum(length * (1 + stretch * rng.random((M, K))), 1e-12)
    return pts, nbr, usable, w


def reference(pts, nbr, usable, w, s_dst, s_w, g_dst, g_w):
    """Dijkstra over every usable edge both ways, the start's edges out and the goal's in."""
    M = len(pts)
    r, s = np.nonzero(usable)
    src = [r, nbr[r, s], np.zeros(len(s_dst), int), g_dst]
    dst = [nbr[r, s], r, s_dst, np.ones(len(g_dst), int)]
    wt = [w[r, s], w[r, s], s_w, g_w]
    src, dst, wt = (np.concatenate(x) for x in (src, dst, wt))
    keep = (src != 1) & (dst != 0)  # the goal is only entered, the start only left
    # Parallel entries: keep the cheapest (a sparse matrix would sum them).
    best = {}
    for a, b, c in zip(src[keep], dst[keep], wt[keep], strict=True):
        best[(a, b)] = min(best.get((a, b), np.inf), c)
    a, b = np.array([k[0] for k in best]), np.array([k[1] for k in best])
    g = scipy.sparse.csr_matrix((np.array(list(best.values())), (a, b)), shape=(M, M))
    return scipy.sparse.csgraph.dijkstra(g, directed=True, indices=0)[1]


def path_cost(path, pts, nbr, usable, w, s_dst, s_w, g_dst, g_w):
    """The cost of ``path`` over the edges it may use (inf if it uses one it may not)."""
    total = 0.0
    for a, b in zip(path[:-1], path[1:], strict=True):
        if a == 0:
            c = s_w[s_dst == b]
        elif b == 1:
            c = g_w[g_dst == a]
        else:
            c = np.concatenate([w[a][(nbr[a] == b) & usable[a]], w[b][(nbr[b] == a) & usable[b]]])
        if not len(c):
            return np.inf
        total += float(c.min())
    return total


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    M=st.integers(3, 60),
    K=st.integers(1, 6),
    p_use=st.floats(0.2, 1.0),
    stretch=st.sampled_from([0.0, 0.5, 3.0]),
    n_s=st.integers(0, 4),
    n_g=st.integers(0, 4),
)
def test_astar_finds_the_shortest_path_of_a_brute_force_search(seed, M, K, p_use, stretch, n_s, n_g):
    rng = np.random.default_rng(seed)
    pts, nbr, usable, w = random_roadmap(rng, M, K, p_use=p_use, stretch=stretch)
    q = rng.uniform(0, 10, (2, 2))
    pts64 = pts.astype(np.float64).copy()
    pts64[:2] = q
    s_dst = rng.integers(1, M, n_s)  # the start may reach the goal straight (slot 1)
    g_dst = rng.integers(2, M, n_g)
    other_s = np.where((s_dst == 1)[:, None], q[1], pts64[s_dst])
    s_w = np.hypot(*(other_s - q[0]).T) * (1 + stretch * rng.random(n_s)) + 1e-9
    g_w = np.hypot(*(pts64[g_dst] - q[1]).T) * (1 + stretch * rng.random(n_g)) + 1e-9
    graph = search_graph(nbr, usable, np.where(usable, w, np.inf), pts, usable)
    cost, path = astar_path(graph, q, s_dst, s_w, g_dst, g_w)
    want = reference(pts64, nbr, usable, w, s_dst, s_w, g_dst, g_w)
    if not np.isfinite(want):
        assert cost == np.inf and len(path) == 0
        return
    np.testing.assert_allclose(cost, want, rtol=1e-12)
    assert path[0] == 0 and path[-1] == 1 and len(set(path.tolist())) == len(path)
    np.testing.assert_allclose(path_cost(path, pts64, nbr, usable, w, s_dst, s_w, g_dst, g_w), cost, rtol=1e-12)


def test_flags_are_read_at_each_search():
    """A lazy roadmap flips an edge's flag in place: the next search avoids it, with no new graph."""
    pts = np.array([[0, 0], [0, 0], [0, 0], [1, 0], [2, 0], [1, 1]], np.float32)
    # 2 - 3 - 4 straight, or 2 - 5 - 4 over a detour.
    nbr = np.full((6, 2), 6, np.int32)
    nbr[2] = [3, 5]
    nbr[4] = [3, 5]
    usable = nbr < 6
    d = pts[np.minimum(nbr, 5)] - pts[:, None]
    w = np.hypot(d[..., 0], d[..., 1]).astype(np.float64)
    graph = search_graph(nbr, usable, w, pts, usable.copy())
    q = np.array([[-1.0, 0.0], [3.0, 0.0]])
    args = (q, np.array([2]), np.array([1.0]), np.array([4]), np.array([1.0]))
    cost, path = astar_path(graph, *args)
    assert path.tolist() == [0, 2, 3, 4, 1] and cost == 4.0
    usable[4, 0] = False  # the edge 4 - 3 is blocked
    cost, path = astar_path(graph, *args)
    assert path.tolist() == [0, 2, 5, 4, 1]
    np.testing.assert_allclose(cost, 2 + 2 * np.sqrt(2), rtol=1e-6)
    usable[2, 1] = False
    cost, path = astar_path(graph, *args)
    assert cost == np.inf and len(path) == 0


def test_a_straight_start_to_goal_edge_and_no_edges():
    pts = np.zeros((4, 2), np.float32)
    nbr = np.full((4, 1), 4, np.int32)
    graph = search_graph(nbr, nbr < 4, np.ones((4, 1)), pts, nbr < 4)
    q = np.array([[0.0, 0.0], [1.0, 0.0]])
    cost, path = astar_path(graph, q, np.array([1]), np.array([1.0]), np.zeros(0, int), np.zeros(0))
    assert cost == 1.0 and path.tolist() == [0, 1]
    cost, path = astar_path(graph, q, np.array([2]), np.array([1.0]), np.zeros(0, int), np.zeros(0))
    assert cost == np.inf and path.shape == (0,)


def mutual_roadmap(rng, M, K, *, stretch):
    """A roadmap whose rows often name each other (an edge both its ends chose) with one weight
    per edge, as an eager roadmap's: its entries are its edges, fixed."""
    pts, nbr, usable, w = random_roadmap(rng, M, K, p_use=1.0, stretch=0.0)
    for r in range(2, M):  # copy some of each row's entries into the rows they name
        for s in range(K):
            c = nbr[r, s]
            if c < M and rng.random() < 0.6:
                free = np.flatnonzero(~usable[c])
                if len(free):
                    nbr[c, free[0]] = r
                    usable[c, free[0]] = c != r
    d = pts[np.minimum(nbr, M - 1)].astype(np.float64) - pts[:, None, :]
    # One weight per edge, whichever end names it (a stretch drawn per unordered pair).
    lo, hi = np.minimum(nbr, np.arange(M)[:, None]), np.maximum(nbr, np.arange(M)[:, None])
    pair = (lo * 7919 + hi * 104729) % 1000 / 1000
    w = np.maximum(np.hypot(d[..., 0], d[..., 1]) * (1 + stretch * pair), 1e-12)
    return pts, nbr, usable, np.where(usable, w, np.inf)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    M=st.integers(3, 60),
    K=st.integers(1, 6),
    stretch=st.sampled_from([0.0, 0.5]),
    n_s=st.integers(1, 4),
    n_g=st.integers(1, 4),
)
def test_a_fixed_graph_keeps_an_edge_once_and_searches_the_same(seed, M, K, stretch, n_s, n_g):
    """``fixed=True`` (an eager roadmap) drops the second entry of an edge both ends chose: fewer
    entries, the same costs and paths, vertex for vertex."""
    rng = np.random.default_rng(seed)
    pts, nbr, usable, w = mutual_roadmap(rng, M, K, stretch=stretch)
    q = rng.uniform(0, 10, (2, 2))
    s_dst = rng.integers(2, M, n_s)
    g_dst = rng.integers(2, M, n_g)
    s_w = np.hypot(*(pts[s_dst] - q[0]).T) + 1e-9
    g_w = np.hypot(*(pts[g_dst] - q[1]).T) + 1e-9
    both = search_graph(nbr, usable, w, pts, usable)
    once = search_graph(nbr, usable, w, pts, usable, fixed=True)
    r, s = np.nonzero(usable)
    edges = {(min(a, b), max(a, b)) for a, b in zip(r, nbr[r, s], strict=True)}
    assert np.sum(once.stop - once.start) == 2 * len(edges) <= np.sum(both.stop - both.start)
    for _ in range(3):
        got = astar_path(once, q, s_dst, s_w, g_dst, g_w)
        want = astar_path(both, q, s_dst, s_w, g_dst, g_w)
        assert got[0] == want[0] and got[1].tolist() == want[1].tolist()
        g_dst = rng.integers(2, M, n_g)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    M=st.integers(3, 40),
    K=st.integers(1, 5),
    n_s=st.integers(1, 4),
    n_g=st.integers(1, 4),
)
def test_a_fixed_graph_keeps_both_weights_of_an_edge_its_ends_weigh_apart(seed, M, K, n_s, n_g):
    """An edge both ends chose with a weight of its own in each row (as ``-log p`` integrals read
    from either end may be): ``fixed=True`` keeps both entries, and the search costs what the
    brute force finds (the cheaper entry, whichever row lists it first)."""
    rng = np.random.default_rng(seed)
    pts, nbr, usable, _ = mutual_roadmap(rng, M, K, stretch=0.0)
    d = pts[np.minimum(nbr, M - 1)].astype(np.float64) - pts[:, None, :]
    w = np.maximum(np.hypot(d[..., 0], d[..., 1]) * (1 + 3 * rng.random((M, K))), 1e-12)
    q = rng.uniform(0, 10, (2, 2))
    pts64 = pts.astype(np.float64).copy()
    pts64[:2] = q
    s_dst = rng.integers(2, M, n_s)
    g_dst = rng.integers(2, M, n_g)
    s_w = np.hypot(*(pts64[s_dst] - q[0]).T) + 1e-9
    g_w = np.hypot(*(pts64[g_dst] - q[1]).T) + 1e-9
    graph = search_graph(nbr, usable, np.where(usable, w, np.inf), pts, usable, fixed=True)
    cost, _ = astar_path(graph, q, s_dst, s_w, g_dst, g_w)
    want = reference(pts64, nbr, usable, w, s_dst, s_w, g_dst, g_w)
    if np.isfinite(want):
        np.testing.assert_allclose(cost, want, rtol=1e-12)
    else:
        assert cost == np.inf


def test_a_fixed_graph_refuses_flags_that_are_not_its_entries():
    pts = np.zeros((4, 2), np.float32)
    nbr = np.full((4, 1), 4, np.int32)
    nbr[2, 0] = 3
    entries = nbr < 4
    with pytest.raises(ValueError, match="usable"):
        search_graph(nbr, np.zeros_like(entries), np.ones((4, 1)), pts, entries, fixed=True)


@pytest.mark.parametrize("M", [1, 2, 3, 50])
def test_the_search_numbers_vertices_by_place_keeping_the_query_slots(M):
    """The search's own numbering: a permutation that keeps slots 0 and 1, for any count and for
    samples all at one point; on a lattice, vertices a step apart get ids closer than at random."""
    rng = np.random.default_rng(M)
    for pts in (rng.uniform(0, 10, (M, 2)), np.ones((M, 2))):
        order = _z_order(pts)
        assert sorted(order.tolist()) == list(range(M))
        assert order[: min(M, 2)].tolist() == list(range(min(M, 2)))
    g = np.stack(np.meshgrid(np.arange(32), np.arange(32)), -1).reshape(-1, 2).astype(float)
    shuffled = np.concatenate([np.zeros((2, 2)), g[rng.permutation(len(g))]])
    rank = np.argsort(_z_order(shuffled))
    right = np.flatnonzero(shuffled[:, 0] < 31)[2:]  # each sample with a right-hand neighbour
    step = {tuple(p): i for i, p in enumerate(shuffled[2:], 2)}
    gaps = [abs(rank[i] - rank[step[(shuffled[i, 0] + 1, shuffled[i, 1])]]) for i in right]
    assert np.median(gaps) <= 4  # slot order: about a third of 1,024 apart


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    M=st.integers(3, 80),
    K=st.integers(1, 6),
    fixed=st.booleans(),
    parts=st.integers(2, 5),
)
def test_a_graph_made_in_blocks_lists_what_one_block_lists(seed, M, K, fixed, parts):
    """The search graph is made in blocks of vertices (on threads for a large roadmap): made in
    several, every vertex lists the same entries in the same order, with the same weights and
    entry ids, as made in one."""
    import jaxsem.planning._astar as _astar  # layers: white-box

    rng = np.random.default_rng(seed)
    pts, nbr, usable, w = mutual_roadmap(rng, M, K, stretch=0.5)
    graphs = []
    try:
        for p in (1, parts):
            _astar._PARTS = p
            graphs.append(search_graph(nbr, usable, w, pts, usable, fixed=fixed))
    finally:
        _astar._PARTS = None
    one, many = graphs
    assert one.ratio == many.ratio
    for v in range(M):
        a, b = slice(one.start[v], one.stop[v]), slice(many.start[v], many.stop[v])
        assert one.adj[a].tolist() == many.adj[b].tolist()
        assert one.wt[a].tolist() == many.wt[b].tolist()
        assert one.eid[a].tolist() == many.eid[b].tolist()

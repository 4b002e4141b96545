"""PRM queries: a batch of queries in one call (``PRM.query_many``) gives the paths of one
``query`` call each, eager and lazy; a query gives the roadmap's shortest path as the pure
pipeline (``roadmap_connect``, then a full undirected Dijkstra) finds it; a second batch of the
same shape compiles nothing, and the host search and edge check compile once."""

import jax
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.csgraph

import jaxsem.planning._astar_kernels as _kernels  # layers: white-box (compile counts)
import jaxsem.planning._edges_kernels as _edge_kernels  # layers: white-box (compile counts)
import jaxsem.planning._roadmap as _roadmap  # layers: white-box (compile counts)
from jaxsem import quadrics as Q
from jaxsem.planning import PRM
from jaxsem.planning._roadmap import roadmap_connect  # layers: white-box

RES = 0.1
ORIGIN = np.array([0.0, 0.0])
SHAPE = (60, 100)
CAPACITY, RADIUS, QUERIES = 400, 1.0, 6


def _grid():
    return Q.Grid.host(ORIGIN, RES, SHAPE)


def _blocks(seed):
    """A map with random wall blocks (the PRM tests' kind)."""
    rng = np.random.default_rng(seed)
    occ = np.zeros(SHAPE, bool)
    for _ in range(25):
        r, c = rng.integers(0, SHAPE[0] - 3), rng.integers(0, SHAPE[1] - 3)
        occ[r : r + rng.integers(1, 8), c : c + rng.integers(1, 4)] = True
    return occ


def _ends(occ, seed, count=QUERIES):
    free = np.argwhere(~occ)
    rng = np.random.default_rng(seed)
    pick = free[rng.integers(len(free), size=(count, 2))]
    pts = ORIGIN + (pick[..., ::-1] + 0.5) * RES  # (count, 2, 2) world
    return pts[:, 0], pts[:, 1]


def _prm(occ, lazy, seed):
    prm = PRM(occ, _grid(), capacity=CAPACITY, radius=RADIUS, lazy=lazy)
    prm.grow(jax.random.PRNGKey(seed), CAPACITY)
    return prm


def _full_dijkstra(rm):
    """Shortest START -> GOAL path over every edge of ``rm`` as an undirected graph."""
    nbr, ok, w = (np.asarray(x) for x in (rm.neighbors, rm.edge_valid, rm.edge_weight))
    M = nbr.shape[0]
    src = np.repeat(np.arange(M), nbr.shape[1])[ok.ravel()]
    # No (row, column) pair repeats (a row lists a vertex once): nothing is summed.
    g = scipy.sparse.csr_matrix((np.maximum(w[ok].astype(np.float64), 1e-12), (src, nbr[ok])), shape=(M, M))
    dist = scipy.sparse.csgraph.dijkstra(g, directed=False, indices=0)
    return dist[1]


@pytest.mark.parametrize("lazy", [False, True])
def test_a_batch_gives_the_paths_of_one_query_each(lazy):
    for seed in (0, 1):
        occ = _blocks(seed)
        starts, goals = _ends(occ, 10 + seed)
        one, many = _prm(occ, lazy, seed), _prm(occ, lazy, seed)
        paths = many.query_many(starts, goals)
        assert paths.vertices.shape[0] == QUERIES and paths.found.shape == (QUERIES,)
        for i, (s, g) in enumerate(zip(starts, goals)):
            p, b = one.query(s, g), paths.path(i)
            assert p.found == b.found == bool(paths.found[i])
            np.testing.assert_array_equal(b.vertices, p.vertices)
            np.testing.assert_array_equal(b.points, p.points)
            assert b.cost == p.cost and b.length == p.length
            n = int(paths.size[i])
            assert (paths.vertices[i, n:] == -1).all() and np.isnan(paths.points[i, n:]).all()
        assert paths.found.any()
        # The roadmap's query rows are the last query's, as after that query alone.
        for field in ("points", "neighbors", "edge_valid", "edge_weight"):
            np.testing.assert_array_equal(
                np.asarray(getattr(many.roadmap, field))[:2], np.asarray(getattr(one.roadmap, field))[:2]
            )


def test_query_is_the_pure_pipelines_shortest_path():
    """The PRM's links (two compiled calls and the host) equal ``roadmap_connect``'s bit for
    bit, and its A* finds the cost of a full undirected search over every edge."""
    for seed in (2, 3, 4):
        occ = _blocks(seed)
        prm = _prm(occ, False, seed)
        starts, goals = _ends(occ, 20 + seed)
        found = 0
        for s, g in zip(starts, goals):
            p = prm.query(s, g)
            ref = roadmap_connect(prm.roadmap, s, g, occ, _grid(), radius=RADIUS)
            for field in ("points", "neighbors", "edge_valid", "edge_weight"):
                np.testing.assert_array_equal(
                    np.asarray(getattr(prm.roadmap, field))[:2], np.asarray(getattr(ref, field))[:2]
                )
            cost = _full_dijkstra(ref)
            assert p.found == np.isfinite(cost)
            if p.found:
                found += 1
                np.testing.assert_allclose(p.cost, cost, rtol=1e-9)
                np.testing.assert_allclose(p.length, p.cost, rtol=1e-5)  # Euclidean weights
                assert p.vertices[0] == 0 and p.vertices[-1] == 1
        assert found >= 3


@pytest.mark.parametrize("x64", [True, False])  # float64: the device checks the links; float32: the host
def test_a_second_batch_compiles_nothing(x64):
    with jax.enable_x64(x64):
        _second_batch_compiles_nothing()


def _second_batch_compiles_nothing():
    occ = _blocks(5)
    prm = _prm(occ, False, 5)
    starts, goals = _ends(occ, 30)

    def sizes():
        jitted = (_roadmap._links_ends_jit, _roadmap._links_coarse, _roadmap._intervals_jit)
        return tuple(f._cache_size() for f in jitted) + (len(_edge_kernels.edges_clear.signatures),)

    prm.query_many(starts, goals)
    first = sizes()
    s2, g2 = _ends(occ, 31)
    prm.query_many(s2, g2)
    prm.query(s2[0], g2[0])
    prm.query(s2[1], g2[1])
    # The single query's shape, once.
    assert all(b <= a + 1 for a, b in zip(first, sizes(), strict=True))
    before = sizes()
    prm.query_many(s2, g2)
    prm.query(starts[1], goals[1])
    assert sizes() == before


def test_the_host_search_compiles_once_for_eager_and_lazy_roadmaps():
    """The search's and the edge check's numba kernels see one set of argument types whatever
    the roadmap: a new roadmap, eager or lazy, compiles nothing more (a numba compile costs
    seconds)."""

    def signatures():
        kernels = (
            _kernels.adjacency_count,
            _kernels.adjacency_scatter,
            _kernels.adjacency_lists,
            _kernels.astar,
            _edge_kernels.edges_clear,
            _edge_kernels.first_clear_pairs,
        )
        return tuple(len(f.signatures) for f in kernels)

    def queries(seed):
        for lazy in (False, True):
            occ = _blocks(seed)
            starts, goals = _ends(occ, 50 + seed, 3)
            with jax.enable_x64(False):  # float32: the edges are checked on the host
                prm = _prm(occ, lazy, seed)
                prm.query_many(starts, goals)
                prm.query(starts[0], goals[0])

    queries(7)
    before = signatures()
    assert min(before) >= 1
    queries(8)
    assert signatures() == before


@pytest.mark.parametrize("lazy", [False, True])
def test_queries_keep_their_rows_on_the_host_until_the_roadmap_is_read(lazy, monkeypatch):
    """A query leaves its start's and goal's rows on the host: they reach the roadmap pytree
    (a device call) only when :attr:`PRM.roadmap` is read, once for any number of queries."""
    import jaxsem.planning._prm as _prm_mod  # layers: white-box

    calls = []
    write = _prm_mod._with_query_jit
    monkeypatch.setattr(_prm_mod, "_with_query_jit", lambda *a: calls.append(1) or write(*a))
    occ = _blocks(9)
    starts, goals = _ends(occ, 60, 3)
    with jax.enable_x64(False):  # float32: the edges are checked on the host
        prm = _prm(occ, lazy, 9)
        for s, g in zip(starts, goals, strict=True):
            prm.query(s, g)
        assert calls == []
        rows = np.asarray(prm.roadmap.points[:2])
        np.testing.assert_allclose(rows, np.stack([starts[-1], goals[-1]]), atol=1e-6)
        assert calls == [1]


def test_the_maps_bits_are_made_for_a_grows_edges_not_for_a_querys():
    """The host rule's bit grids (per-map setup, several milliseconds on a large map) are made
    by an eager grow, which reads thousands of edges; a lazy roadmap's queries, a few edges on
    a map a robot sees once, read theirs by samples and make none."""
    occ = _blocks(10)
    starts, goals = _ends(occ, 70, 2)
    with jax.enable_x64(False):  # float32: the edges are checked on the host
        lazy = _prm(occ, True, 10)
        lazy.query_many(starts, goals)
        assert lazy._setup.bits(make=False) is None
        eager = PRM(occ[::-1].copy(), _grid(), capacity=CAPACITY, radius=RADIUS)  # another map
        eager.grow(jax.random.PRNGKey(10), CAPACITY)
        assert eager._setup.bits(make=False) is not None


def test_query_many_bad_input():
    occ = _blocks(6)
    prm = _prm(occ, False, 6)
    starts, goals = _ends(occ, 40, 3)
    with pytest.raises(ValueError, match="starts"):
        prm.query_many(starts[0], goals)
    with pytest.raises(ValueError, match="goals"):
        prm.query_many(starts, goals[:2])
    with pytest.raises(ValueError, match="starts"):
        prm.query_many(np.zeros((0, 2)), np.zeros((0, 2)))
    blocked = ORIGIN + (np.argwhere(occ)[0][::-1] + 0.5) * RES
    with pytest.raises(ValueError, match=r"goals\[1\]"):
        prm.query_many(starts, np.stack([goals[0], blocked, goals[2]]))
    with pytest.raises(ValueError, match="starts"):
        prm.query_many([[np.nan, 1.0]], [[1.0, 1.0]])

"""A PRM grown from a distribution concentrated in a window (LSD's) on a large map: the neighbour
search's strips are sized from the distribution, so the grow runs once, and its roadmap is the
one a search with every slot gives; the cost-weighted links keep their exact weights."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsem.planning._roadmap as _roadmap  # layers: white-box
from jaxsem import quadrics as Q
from jaxsem.planning import PRM, embed_local_distribution
from jaxsem.planning._sampling import sample_points  # layers: white-box

SHAPE = (240, 320)
RES = 0.1

# The draws below run jitted (one compile per map shape and count): run op by op, the sampler's
# scans compiled over a hundred small programs per test.
_sample_points = jax.jit(sample_points, static_argnums=2)


def _concentrated(seed, centre=(120, 200), k=40):
    local = np.random.default_rng(seed).dirichlet(np.full(k * k, 0.5)).reshape(k, k)
    return np.asarray(embed_local_distribution(jnp.asarray(local), jnp.asarray(centre), SHAPE))


def _free_map():
    occ = np.zeros(SHAPE, bool)
    occ[:, 150:153] = True  # a wall with a door
    occ[100:120, 150:153] = False
    return occ


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_strip_cap_holds_the_fullest_strip(seed):
    dist = _concentrated(seed)
    radius, n = 1.5, 400
    cap = _roadmap._strip_cap(dist, n, RES, radius)
    grid = Q.Grid.create((0.0, 0.0), RES, SHAPE)
    gx = int(np.ceil(SHAPE[1] * RES / radius))
    for draw in range(5):
        pts = np.asarray(_sample_points(jax.random.PRNGKey(100 * seed + draw), jnp.asarray(dist), n, grid))
        b = np.floor(pts / radius).astype(int)
        counts = np.zeros((b[:, 1].max() + 1, gx + 2), int)
        np.add.at(counts, (b[:, 1], b[:, 0] + 1), 1)
        strips = counts[:, :-2] + counts[:, 1:-1] + counts[:, 2:]  # brute force: every 3 x-adjacent buckets
        assert strips.max() <= cap
    assert cap % 16 == 0 and cap <= 2 * 16 * max(1, n // 8)


@pytest.fixture
def grow_caps(monkeypatch):
    """The strip slots (``cap``) of every jitted grow, in call order."""
    caps = []
    real = _roadmap._grow_jit

    def counted(*args, **kwargs):
        caps.append(kwargs["cap"])
        return real(*args, **kwargs)

    monkeypatch.setattr(_roadmap, "_grow_jit", counted)
    return caps


@pytest.mark.slow
def test_concentrated_grow_runs_once_and_matches_a_full_search(grow_caps):
    occ = _free_map()
    dist = _concentrated(3)
    calls = grow_caps
    grid = Q.Grid.create((0.0, 0.0), RES, SHAPE)
    prm = PRM(occ, grid, capacity=6000, radius=1.5, weight="neglogp", sectors=8)
    prm.grow(jax.random.PRNGKey(7), 1200, dist)
    assert len(calls) == 1  # no strip overflowed: no second grow
    # The same roadmap as a search with a slot for every vertex (no strips at all).
    full = PRM(occ, grid, capacity=6000, radius=1.5, weight="neglogp", sectors=8)
    full._cap = 6000  # every vertex a candidate of every query: the brute-force search
    full.grow(jax.random.PRNGKey(7), 1200, dist)
    a, b = prm.roadmap, full.roadmap
    np.testing.assert_array_equal(np.asarray(a.neighbors), np.asarray(b.neighbors))
    np.testing.assert_array_equal(np.asarray(a.edge_valid), np.asarray(b.edge_valid))
    np.testing.assert_array_equal(np.asarray(a.edge_weight), np.asarray(b.edge_weight))


def test_cost_weights_are_the_mean_cost_along_each_link():
    occ = _free_map()
    dist = _concentrated(4)
    grid = Q.Grid.create((0.0, 0.0), RES, SHAPE)
    # The sizes of test_small_roadmaps_from_any_distribution_share_one_search's roadmaps (1,500
    # vertices, grown by 500): the two tests share one compiled grow (about 10 s each).
    prm = PRM(occ, grid, capacity=1500, radius=1.5, weight="neglogp", sectors=8)
    prm.grow(jax.random.PRNGKey(2), 500, dist)
    rm = prm.roadmap
    pts, nb, ev, w = (np.asarray(x) for x in (rm.points, rm.neighbors, rm.edge_valid, rm.edge_weight))
    cost = -np.log(np.maximum(dist / dist.sum(), 1e-30))
    S = int(np.ceil(1.5 / (0.5 * RES))) + 1
    rows, cols = np.nonzero(ev)
    assert len(rows) > 500
    for i, j in zip(rows[::37], cols[::37]):  # an independent integral: dense samples on the host
        a, b = pts[i], pts[nb[i, j]]
        t = np.linspace(0.0, 1.0, S)[:, None]
        cells = np.floor((a + t * (b - a)) / RES).astype(int)
        want = np.linalg.norm(b - a) * cost[cells[:, 1], cells[:, 0]].mean()
        np.testing.assert_allclose(w[i, j], want, rtol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_draws_are_the_flat_inverse_cdf_search(seed):
    # The reference: the cell where the running mass over the flattened map first exceeds each
    # draw's u (numpy, float64), with the jitter of the same key.
    rng = np.random.default_rng(seed)
    dist = rng.random((37, 53)) * (rng.random((37, 53)) < 0.3)  # many zero cells
    grid = Q.Grid.create((1.0, -2.0), 0.25, dist.shape)
    key = jax.random.PRNGKey(seed)
    pts = np.asarray(_sample_points(key, jnp.asarray(dist), 2000, grid))
    k_cell, _ = jax.random.split(key)
    u = np.asarray(jax.random.uniform(k_cell, (2000,), jnp.float64)) * dist.sum()
    cells = np.minimum(np.searchsorted(np.cumsum(dist.reshape(-1)), u, side="right"), dist.size - 1)
    got = np.floor((pts - np.array([1.0, -2.0])) / 0.25).astype(int)
    got = got[:, 1] * dist.shape[1] + got[:, 0]
    assert np.mean(got == cells) > 0.999  # rounding may move a draw that falls on a cell boundary
    assert np.all(dist.reshape(-1)[got] > 0)  # never a cell without weight


def test_small_roadmaps_from_any_distribution_share_one_search(grow_caps):
    # navigate's roadmaps (1,500 vertices): whatever the window's distribution, the neighbour
    # search is the brute-force one, so its program is compiled once, not once per strip size.
    caps = grow_caps
    grid = Q.Grid.create((0.0, 0.0), RES, SHAPE)
    for seed, centre in ((5, (120, 200)), (6, (60, 40))):
        prm = PRM(_free_map(), grid, capacity=1500, radius=1.5, weight="neglogp", sectors=8)
        prm.grow(jax.random.PRNGKey(seed), 500, _concentrated(seed, centre))
    assert caps == [None, None]


@pytest.mark.slow
@pytest.mark.parametrize("n", [1000, 5000])
def test_each_vertex_links_its_k_nearest_under_a_gaussian_blob(n):
    # sectors=0 on an obstacle-free map, every sample from a 12-cell Gaussian blob: each row holds
    # min(k, neighbours within the radius) links, none farther than the k-th nearest by brute
    # force (up to float32 rounding of the squared distance: near-ties may go either way).
    occ = np.zeros(SHAPE, bool)
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]]
    dist = np.exp(-0.5 * ((yy - 120.0) ** 2 + (xx - 200.0) ** 2) / 12.0**2)
    grid = Q.Grid.create((0.0, 0.0), RES, SHAPE)
    for seed in range(2):
        prm = PRM(occ, grid, capacity=n, sectors=0)
        prm.grow(jax.random.PRNGKey(seed), n, dist / dist.sum())
        rm = prm.roadmap
        pts = np.asarray(rm.points, np.float64)
        ids = np.flatnonzero(np.asarray(rm.valid) & (np.arange(len(pts)) >= _roadmap._QUERY))
        nb, ev = np.asarray(rm.neighbors), np.asarray(rm.edge_valid)
        k = nb.shape[1]
        assert len(ids) == n
        where = np.full(len(pts), -1)
        where[ids] = np.arange(n)
        for chunk in np.array_split(ids, 8):
            d2 = np.sum((pts[chunk, None, :] - pts[None, ids, :]) ** 2, -1)
            d2[np.arange(len(chunk)), where[chunk]] = np.inf
            # A neighbour within rounding of the radius may count either way: the row's size lies
            # between the counts strictly inside and just outside it.
            want = np.minimum(k, (d2 <= prm.radius**2 * (1 + 1e-5)).sum(1))
            least = np.minimum(k, (d2 <= prm.radius**2 * (1 - 1e-5)).sum(1))
            kth = np.sort(d2, 1)[np.arange(len(chunk)), np.maximum(want - 1, 0)]
            for i, r in enumerate(chunk):
                row = nb[r][ev[r]]
                assert least[i] <= len(row) <= want[i], (r, len(row), least[i], want[i])
                if len(row):
                    assert d2[i, where[row]].max() <= kth[i] * (1 + 1e-5), r

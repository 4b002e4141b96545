"""The PRM's edge rule on the host (numba) against the device's rule read at every sample
(``_edges_dense`` under jit): the same clear flags on random maps, edges and sample counts, with
and without the clearance table's skips; and queries checked either way give the same paths."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from test_prm_query_many import _blocks  # the PRM tests' maps of random wall blocks

import jaxsem.planning._edges as _edges  # layers: white-box
import jaxsem.planning._roadmap as _roadmap  # layers: white-box
from jaxsem import quadrics as Q
from jaxsem.planning import PRM
from jaxsem.planning._grid import static_grid  # layers: white-box


@functools.partial(jax.jit, static_argnames=("grid", "samples"))
def _dense_jit(blocked, a, b, grid, samples):
    clear, _, _ = _edges._edges_dense(blocked, a, b, _edges._grid(grid, jnp.float32), samples)
    return clear


def _dense(blocked, a, b, grid, samples):
    """The device rule, every sample read, on a static grid (its resolution a constant of the
    program, as in every roadmap's)."""
    return np.asarray(_dense_jit(jnp.asarray(blocked), a, b, static_grid(grid), samples))


def _map(rng, shape, density):
    """Random wall blocks and single cells: edges that graze corners and cross diagonals."""
    occ = rng.random(shape) < density / 4
    for _ in range(int(density * 40)):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        occ[r : r + rng.integers(1, 12), c : c + rng.integers(1, 4)] = True
    return occ


def _edges_on(rng, grid, n, reach):
    """Edges from points on (and a few off) the map, some exactly on cell borders."""
    H, W = grid.shape
    res = float(grid.resolution)
    lo = np.asarray(grid.origin)
    a = lo + rng.uniform(-0.05, 1.05, (n, 2)) * [W * res, H * res]
    border = rng.random(n) < 0.3
    a[border] = lo + np.round((a[border] - lo) / res) * res  # on a cell corner
    ang = rng.uniform(0, 2 * np.pi, n)
    axis = rng.random(n) < 0.2  # along a row, a column or a diagonal
    ang[axis] = rng.integers(0, 8, int(axis.sum())) * np.pi / 4
    length = rng.uniform(0, reach, n)
    b = a + length[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    return a.astype(np.float32), b.astype(np.float32)


def test_the_host_rule_is_found_on_this_backend():
    """The probe matches the device's float32 arithmetic here (else every query would fall back
    to the device's rule and the host path would go untested)."""
    assert _edges._host_rule() is not None


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    density=st.sampled_from([0.0, 0.3, 1.0, 3.0]),
    res=st.sampled_from([0.1, 0.05, 0.37]),
    origin=st.tuples(st.floats(-500, 500), st.floats(-500, 500)),
    samples=st.sampled_from([2, 9, 33, 200]),
)
def test_the_host_rule_gives_the_device_rules_flags(seed, density, res, origin, samples):
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(8, 90)), int(rng.integers(8, 90)))
    grid = Q.Grid.host(origin, res, shape)
    occ = _map(rng, shape, density)
    reach = (samples - 1) * 0.5 * res  # the rule's spacing: samples at most half a cell apart
    a, b = _edges_on(rng, grid, 300, reach)
    want = _dense(occ, a, b, grid, samples)
    n = np.full(len(a), samples)
    every = np.ones(len(a), bool)
    got = _edges._edges_clear_host(occ, a, b, n, every, grid)
    np.testing.assert_array_equal(got, want)
    table = _edges._clearance_table_np(occ)
    got_t = _edges._edges_clear_host(occ, a, b, n, every, grid, table)
    np.testing.assert_array_equal(got_t, want)
    if want.any() and not want.all():
        # The edges not wanted come back False whatever they are.
        some = rng.random(len(a)) < 0.5
        np.testing.assert_array_equal(_edges._edges_clear_host(occ, a, b, n, some, grid, table), want & some)


def test_long_edges_in_open_space_are_skipped_through_not_misread():
    """A map with one wall: long edges beside it (clear, read through the table's discs) and
    across it (blocked) at the query edges' sample count."""
    shape = (400, 600)
    grid = Q.Grid.host((-3.3, 7.1), 0.1, shape)
    occ = np.zeros(shape, bool)
    occ[150:250, 300] = True
    rng = np.random.default_rng(3)
    a, b = _edges_on(rng, grid, 400, 70.0)
    S = _edges._edge_samples(128.0, 0.1)
    want = _dense(occ, a, b, grid, S)
    assert 0 < want.sum() < len(want)
    table = _edges._clearance_table_np(occ)
    got = _edges._edges_clear_host(occ, a, b, np.full(len(a), S), np.ones(len(a), bool), grid, table)
    np.testing.assert_array_equal(got, want)


@pytest.fixture
def float32():
    """The roadmap in float32, a user's default (the suite runs under x64, where the roadmap is
    float64 and its edges are checked by the device: the host rule is float32's)."""
    with jax.enable_x64(False):
        yield


@pytest.mark.parametrize("lazy", [False, True])
def test_queries_checked_on_the_host_or_the_device_find_the_same_paths(lazy, monkeypatch, float32):
    calls = []
    monkeypatch.setattr(_roadmap, "_edges_clear_host", _counted(_roadmap._edges_clear_host, calls))
    occ = _blocks(11)
    grid = Q.Grid.host((0.0, 0.0), 0.1, occ.shape)
    free = np.argwhere(~occ)
    rng = np.random.default_rng(12)
    pick = free[rng.integers(len(free), size=(8, 2))]
    ends = (pick[..., ::-1] + 0.5) * 0.1
    runs = []
    for host in (True, False):
        if not host:
            monkeypatch.setattr(_roadmap, "_host_edges", lambda dtype: False)
            monkeypatch.setattr("jaxsem.planning._lazy._host_edges", lambda dtype: False)
        prm = PRM(occ, grid, capacity=300, radius=1.0, lazy=lazy)
        prm.grow(jax.random.PRNGKey(4), 300)
        paths = prm.query_many(ends[:, 0], ends[:, 1])
        runs.append([(float(paths.path(i).cost), tuple(paths.path(i).vertices)) for i in range(len(ends))])
        assert prm.roadmap.points.dtype == np.float32
    assert runs[0] == runs[1]
    assert any(np.isfinite(c) for c, _ in runs[0])
    assert calls  # the first run's links were checked on the host


def _edge_set(rm):
    """(row, neighbour, weight) of every edge of the samples' rows (the slots may differ)."""
    ev = np.asarray(rm.edge_valid)[2:]
    rows = np.nonzero(ev)[0] + 2
    nbr, w = np.asarray(rm.neighbors)[2:][ev], np.asarray(rm.edge_weight)[2:][ev]
    return sorted(zip(rows.tolist(), nbr.tolist(), w.tolist(), strict=True))


# Rows of 2k candidates in order (the defaults); rows of k (slow: a second set of compiles).
@pytest.mark.parametrize("sectors,k", [(8, None), pytest.param(0, 6, marks=pytest.mark.slow)])
def test_a_grow_checked_on_the_host_is_the_devices_roadmap(sectors, k, monkeypatch, float32):
    """Two grows (the second's rows among the first's vertices) with the edges checked on the
    host, then on the device: the same vertices, edges and weights, bit for bit."""
    import jaxsem.planning._prm as _prm  # layers: white-box

    occ = _blocks(21)
    grid = Q.Grid.host((-3.7, 1.3), 0.1, occ.shape)
    maps, calls = [], []
    monkeypatch.setattr(_prm, "_grow_checked_host", _counted(_prm._grow_checked_host, calls))
    for host in (True, False):
        if not host:
            assert len(calls) == 2  # both grows checked on the host
            monkeypatch.setattr(_prm, "_host_edges", lambda dtype: False)
        prm = PRM(occ, grid, capacity=700, k=k, sectors=sectors)
        prm.grow(jax.random.PRNGKey(8), 400)
        prm.grow(jax.random.PRNGKey(9), 300)
        assert prm.roadmap.points.dtype == np.float32
        maps.append(prm.roadmap)
    host, device = maps
    for field in ("points", "valid"):
        np.testing.assert_array_equal(np.asarray(getattr(host, field)), np.asarray(getattr(device, field)))
    edges = _edge_set(host)
    assert len(edges) > 1000
    assert edges == _edge_set(device)
    assert len(calls) == 2


def _counted(f, calls):
    def wrapped(*args, **kw):
        calls.append(1)
        return f(*args, **kw)

    return wrapped

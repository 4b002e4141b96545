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
    table = _edges._clearance_table_np(occ)
    bits = _edges._bit_grids(occ)
    # By samples (with and without the table's skips) and by lines of cells.
    for tab, bit in ((None, None), (table, None), (None, bits), (table, bits)):
        np.testing.assert_array_equal(_edges._edges_clear_host(occ, a, b, n, every, grid, tab, bits=bit), want)
    if want.any() and not want.all():
        # The edges not wanted come back False whatever they are.
        some = rng.random(len(a)) < 0.5
        np.testing.assert_array_equal(_edges._edges_clear_host(occ, a, b, n, some, grid, table, bits=bits), want & some)


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
    for bits in (None, _edges._bit_grids(occ)):
        got = _edges._edges_clear_host(occ, a, b, np.full(len(a), S), np.ones(len(a), bool), grid, table, bits=bits)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed,with_table", [(0, True), (1, False), (2, True)])
def test_each_rows_first_k_clear_edges_are_the_device_rules(seed, with_table):
    """A grow's rows of candidates among old and new vertices (each pair of new ones in both
    rows, many on cell corners, where an edge and its reversal round into different cells):
    the host's first k clear edges of each row (each edge between new vertices read once where
    its reversal surely agrees) are the device rule's, read edge by edge at every sample."""
    from jaxsem.planning import _edges_kernels as kern  # layers: white-box

    rng = np.random.default_rng(seed)
    shape = (60, 80)
    grid = Q.Grid.host((-1.3, 2.1), 0.1, shape)
    occ = _map(rng, shape, 0.2)
    M, s0, k, K, radius = 330, 30, 6, 24, 1.5
    lo = np.asarray(grid.origin)
    p = lo + rng.uniform(0.0, 1.0, (M, 2)) * [8.0, 6.0]
    corner = rng.random(M) < 0.4
    p[corner] = lo + np.round((p[corner] - lo) / 0.1) * 0.1
    p = p.astype(np.float32)
    _, first_of = np.unique(p, axis=0, return_index=True)
    p = p[np.sort(first_of)]  # no two vertices at one point (an edge of length 0)
    M = len(p)
    d = np.linalg.norm(p[s0:, None].astype(np.float64) - p[None], axis=-1)
    d[np.arange(M - s0), np.arange(s0, M)] = np.inf
    cand = np.argsort(d, axis=1, kind="stable")[:, :K].astype(np.int32)
    cand[np.take_along_axis(d, cand, 1) > radius] = M
    S = _edges._edge_samples(radius, 0.1)
    table = _edges._clearance_table_np(occ) if with_table else None
    nbr, ok, w = _edges._first_clear_host(occ, p, cand, s0, k, S, grid, table)

    rows = np.repeat(np.arange(s0, M), K)
    flat = cand.ravel()
    clear = _dense(occ, p[rows], p[np.minimum(flat, M - 1)], grid, S) & (flat < M)
    clear = clear.reshape(-1, K)
    first = np.cumsum(clear, 1) <= k
    for i in range(M - s0):
        want = cand[i][clear[i] & first[i]]
        np.testing.assert_array_equal(nbr[i][ok[i]], want)
        np.testing.assert_array_equal(w[i][ok[i]], np.linalg.norm(p[want] - p[s0 + i], axis=1).astype(np.float32))
    assert 0.2 < clear.sum() / (flat < M).sum() < 0.9
    # Some edges' reversals were not sure to agree: the second pass read them again.
    state = np.zeros(cand.shape, np.uint8)
    grids = _edges._host_grids(occ, table, _edges._bit_grids(occ))
    consts = _edges._host_call(grid)[1]
    rows = np.arange(M - s0)
    out = (np.full((M - s0, k), M, np.int32), np.zeros((M - s0, k), bool), np.full((M - s0, k), np.inf, np.float32))
    kern.first_clear_pairs(*grids, p, cand, rows + s0, rows, s0, k, S, *consts, rows, state, out, False)
    pairs = (state & kern._READ > 0) & (cand >= s0) & (cand < M)
    assert np.any(pairs & (state & kern._BOTH == 0)) and np.any(pairs & (state & kern._BOTH > 0))


def test_an_edge_whose_reversal_reads_another_answer_is_read_both_ways():
    """Edges from a vertex on a cell corner beside blocked cells: the reversed edge's last sample
    rounds to a neighbouring cell of the corner, and the rule's answers differ with the
    direction. Each row of the pair keeps the other end exactly when its own direction is clear."""
    shape = (60, 80)
    grid = Q.Grid.host((-1.3, 2.1), 0.1, shape)
    occ = np.zeros(shape, bool)
    occ[::2, ::2] = np.random.default_rng(0).random((30, 40)) < 0.5
    a = np.array([[-0.8, 2.9], [-0.4, 6.3], [1.9, 7.1], [-0.8, 7.5], [-0.4, 4.7]], np.float32)
    b = np.array(
        [
            [0.43067107, 3.51397395],
            [0.14826399, 6.57386494],
            [0.54635257, 6.57387066],
            [-0.1785281, 7.77992058],
            [-0.14453362, 4.4650898],
        ],
        np.float32,
    )
    S = _edges._edge_samples(1.5, 0.1)
    forward, backward = _dense(occ, a, b, grid, S), _dense(occ, b, a, grid, S)
    assert np.all(forward != backward)
    s0 = 2
    p = np.concatenate([np.zeros((s0, 2), np.float32), a, b])
    M, n = len(p), len(a)
    cand = np.full((2 * n, 4), M, np.int32)
    cand[:n, 1] = s0 + n + np.arange(n)  # a's row: its b
    cand[n:, 2] = s0 + np.arange(n)  # b's row: its a
    for table in (None, _edges._clearance_table_np(occ)):
        nbr, ok, _ = _edges._first_clear_host(occ, p, cand, s0, 1, S, grid, table)
        np.testing.assert_array_equal(ok[:, 0], np.concatenate([forward, backward]))
        np.testing.assert_array_equal(nbr[ok], cand[cand < M][np.concatenate([forward, backward])])


def _pair_rows(a, b, s0=2):
    """Points and candidate rows for edges a[i] <-> b[i] (E, 2): a's row names its b, b's row
    its a (the grow's pairs of new vertices, each edge read once where its reversal surely
    agrees)."""
    n = len(a)
    p = np.concatenate([np.zeros((s0, 2), np.float32), a, b])
    M = len(p)
    cand = np.full((2 * n, 3), M, np.int32)
    cand[:n, 0] = s0 + n + np.arange(n)
    cand[n:, 1] = s0 + np.arange(n)
    return p, cand, s0


def test_a_box_free_one_way_is_not_trusted_the_other_way():
    """Edges ending on a cell corner, where the float32 sample at the far end rounds into the
    cell before the corner's and the reversed edge starts in the corner's cell: that cell lies
    outside the box of the edge's own samples. Blocked, it makes the edge clear one way only;
    a box free of blocked cells is trusted for the reversal only where it also spans the
    reversed edge's end cells (answers: the device's rule at every sample)."""
    from jaxsem.planning import _edges_kernels as kern  # layers: white-box

    shape = (60, 80)
    grid = Q.Grid.host((-1.3, 2.1), 0.1, shape)
    lo = np.asarray(grid.origin, np.float64)
    rng = np.random.default_rng(4)
    S = _edges._edge_samples(1.5, 0.1)
    consts = _edges._host_call(grid)[1]
    n = 20_000
    b = (lo + rng.integers(20, 40, (n, 2)) * 0.1).astype(np.float32)  # on a corner
    a = (b - rng.uniform(0.3, 1.4, (n, 2))).astype(np.float32)  # below and left: b's corner ends the box
    fr, fc = kern.sample_cells(a, b, S, *consts)
    br, bc = kern.sample_cells(b, a, S, *consts)
    outside = (br.max(1) > fr.max(1)) | (bc.max(1) > fc.max(1))
    pick = np.flatnonzero(outside)[:6]
    assert len(pick) == 6
    for i in pick:
        occ = np.zeros(shape, bool)
        occ[br[i].max(), bc[i].max()] = True  # read by the reversal only
        forward, backward = (
            _dense(occ, a[i : i + 1], b[i : i + 1], grid, S),
            _dense(occ, b[i : i + 1], a[i : i + 1], grid, S),
        )
        assert forward[0] and not backward[0]
        p, cand, s0 = _pair_rows(a[i : i + 1], b[i : i + 1])
        _, ok, _ = _edges._first_clear_host(occ, p, cand, s0, 1, S, grid, None)
        np.testing.assert_array_equal(ok[:, 0], [True, False])


def test_a_box_of_more_cells_than_its_sums_count_is_read():
    """The box sums count modulo 2**16: a box of more cells holding exactly 2**16 blocked ones
    (one of them on the edge) sums to zero, and is read instead of trusted."""
    shape = (300, 300)
    grid = Q.Grid.host((0.0, 0.0), 0.1, shape)
    occ = np.zeros(shape, bool)
    occ[150, 150] = True  # on the diagonal
    rest = np.flatnonzero(~np.eye(300, dtype=bool).ravel() & ~occ.ravel())
    occ.ravel()[np.random.default_rng(0).choice(rest, 2**16 - 1, replace=False)] = True
    a = np.array([[0.05, 0.05]], np.float32)
    b = np.array([[29.95, 29.95]], np.float32)
    S = _edges._edge_samples(45.0, 0.1)
    assert not _dense(occ, a, b, grid, S)[0]
    got = _edges._edges_clear_host(occ, a, b, np.full(1, S), np.ones(1, bool), grid, None, bits=_edges._bit_grids(occ))
    assert not got[0]


def _read_set(rows, cols):
    """The cells the edge rule reads for an edge whose samples fall in cells (rows, cols) (S,):
    every sample's, and both side cells of each diagonal step (brute force)."""
    cells = set(zip(rows.tolist(), cols.tolist(), strict=True))
    for k in range(1, len(rows)):
        if rows[k] != rows[k - 1] and cols[k] != cols[k - 1]:
            cells |= {(int(rows[k - 1]), int(cols[k])), (int(rows[k]), int(cols[k - 1]))}
    return cells


@pytest.mark.parametrize("seed", [0, 1])
def test_a_reversal_read_by_lines_is_sure_only_where_it_reads_the_same(seed):
    """Edges of which some middle sample rounds into another cell read from the other end (found
    among many edges with a middle sample near a row or column border), each on a map with one
    blocked cell that only one direction reads: the walk by lines gives each direction's answer
    and never says the reversal surely agrees there; on a map of random cells, wherever it says
    so, the answers agree. Answers by brute force over the samples' cells in the rule's float32
    arithmetic (the device's: the probe), not by the device: under the suite's XLA flags a
    program may round a sample near a border one way for its cells and the other for its side
    cells."""
    from jaxsem.planning import _edges_kernels as kern  # layers: white-box

    rng = np.random.default_rng(seed)
    shape = (80, 80)
    res = 0.1
    grid = Q.Grid.host((-3.3, 17.9), res, shape)
    lo = np.asarray(grid.origin, np.float64)
    n, S = 100_000, 33
    mid = lo + rng.integers(20, 60, (n, 2)) * res  # a grid corner
    along = rng.random(n) < 0.5
    mid[along, 0] += rng.uniform(0, res, int(along.sum()))  # on a row border
    mid[~along, 1] += rng.uniform(0, res, int((~along).sum()))  # on a column border
    t = rng.uniform(0, 2 * np.pi, n)
    h = rng.uniform(0.2, 1.5, (n, 1)) * np.stack([np.cos(t), np.sin(t)], 1)
    at = rng.integers(1, S - 1, (n, 1)) / (S - 1)  # the middle sample put near the border
    a, b = (mid - at * 2 * h).astype(np.float32), (mid + (1 - at) * 2 * h).astype(np.float32)
    consts = _edges._host_call(grid)[1]
    fr, fc = kern.sample_cells(a, b, S, *consts)
    br, bc = kern.sample_cells(b, a, S, *consts)
    reads = lambda i: (_read_set(fr[i], fc[i]), _read_set(br[i], bc[i]))
    found = 0
    for i in np.flatnonzero(np.any((fr != br[:, ::-1]) | (fc != bc[:, ::-1]), axis=1)):
        fwd, bwd = reads(i)
        if fwd == bwd:
            continue
        for cell, forward in ((min(fwd - bwd, default=None), False), (min(bwd - fwd, default=None), True)):
            if cell is None:
                continue
            occ = np.zeros(shape, bool)
            occ[cell] = True
            rows, cols, _ = _edges._bit_grids(occ)
            st, sure = kern._lines(rows, cols, *shape, *a[i], *b[i], S, *consts, True)
            assert st in (-1, forward) and not sure
            found += 1
        if found >= 40:
            break
    assert found >= 40
    # Random cells: sure where the answers agree, never where they differ.
    occ = rng.random(shape) < 0.1
    rows, cols, _ = _edges._bit_grids(occ)
    blocked = {tuple(x) for x in np.argwhere(occ).tolist()}
    differ = sure_differ = sure_n = 0
    for i in rng.choice(n, 2000, replace=False):
        fwd, bwd = (not (x & blocked) for x in reads(i))
        st, sure = kern._lines(rows, cols, *shape, *a[i], *b[i], S, *consts, True)
        assert st in (-1, fwd)
        differ += fwd != bwd
        sure_differ += sure and fwd != bwd
        sure_n += sure
    assert sure_differ == 0 and sure_n > 1000


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


def test_the_hosts_copy_of_the_grown_rows_is_the_roadmap(float32):
    """The eager grows checked on the host keep a copy of the rows they write: after each grow it
    is the device's roadmap (points and sample rows), and a query searched on it finds the path
    searched on the device's arrays; a map update drops the copy, and the queries after it
    search the updated roadmap."""
    from jaxsem.planning._roadmap_search import roadmap_shortest_path  # layers: white-box

    occ = _blocks(21)
    grid = Q.Grid.host((-3.7, 1.3), 0.1, occ.shape)
    free = np.argwhere(~occ)
    s, g = ((free[np.random.default_rng(1).integers(len(free), size=2)][:, ::-1] + 0.5) * 0.1) + [-3.7, 1.3]
    prm = PRM(occ, grid, capacity=700)

    def same_path():
        path = prm.query(s, g)
        ref = roadmap_shortest_path(prm.roadmap)  # the search graph of the device's arrays
        assert path.found == ref.found and path.cost == ref.cost
        np.testing.assert_array_equal(path.vertices, ref.vertices)
        return path

    for key, n in ((8, 400), (9, 300)):
        prm.grow(jax.random.PRNGKey(key), n)
        assert prm._rows is not None
        rm = prm.roadmap
        np.testing.assert_array_equal(prm._rows[0], np.asarray(rm.points))
        for mine, theirs in zip(prm._rows[1:], (rm.neighbors, rm.edge_valid, rm.edge_weight), strict=True):
            np.testing.assert_array_equal(mine[2:], np.asarray(theirs)[2:])
        assert same_path().found
    changed = occ.copy()
    changed[:, occ.shape[1] // 2 : occ.shape[1] // 2 + 3] = True  # a wall across the map
    changed[tuple(np.floor((np.array([s, g]) - [-3.7, 1.3]) / 0.1).astype(int)[:, ::-1].T)] = False
    assert prm.update_map(changed) and prm._rows is None
    same_path()


def _counted(f, calls):
    def wrapped(*args, **kw):
        calls.append(1)
        return f(*args, **kw)

    return wrapped

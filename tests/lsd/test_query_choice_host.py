"""A query's candidates chosen on the host (numba) against the device's choice (``_links_ends``
under jit): the same candidates in the same order, ends, flags and weights, over random
roadmaps, sector counts and ``k``, with exact ties of distance; a sample on a sector border
leaves the choice to the device."""

import jax
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import jaxsem.planning._roadmap as _roadmap  # layers: white-box
from jaxsem import quadrics as Q
from jaxsem.planning import PRM
from jaxsem.planning._grid import static_grid  # layers: white-box

GRID = Q.Grid.host((-4.0, -4.0), 0.1, (400, 400))


@pytest.fixture
def float32():
    """float32 roadmaps (the host choice is float32's; the suite runs under x64)."""
    with jax.enable_x64(False):
        yield


def _both(points, valid, starts, goals, k, sectors, radius=2.0):
    rm = _roadmap._unlinked(points, valid, k)
    want = _roadmap._links_ends_jit(
        rm, starts, goals, None, static_grid(GRID), radius=radius, edge_samples=41, long_samples=321, sectors=sectors
    )
    choice = _roadmap._host_choice()
    assert choice is not None  # the probe matched the device here
    got = _roadmap._links_ends_host(points, valid, starts, goals, k, radius=radius, sectors=sectors, choice=choice)
    return got, [np.asarray(x) for x in want]


def _assert_same(got, want):
    names = ("q", "nbr", "a", "other", "short", "cand", "w")
    for name, g, w in zip(names, got, want, strict=True):
        cand = want[5]
        if name in ("other", "short", "w"):  # unread where there is no candidate
            g, w = g[cand], w[cand]
        if name == "w":  # a device program may fuse a product into the length's sum: one unit
            np.testing.assert_array_max_ulp(g, w, maxulp=1)
        else:
            np.testing.assert_array_equal(g, w, err_msg=name)


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    M=st.sampled_from([3, 300]),  # few shapes: each is a device program (fewer samples: flags)
    k=st.sampled_from([1, 6, 12]),
    sectors=st.sampled_from([0, 1, 3, 8, 8, 11]),
    lattice=st.booleans(),
)
def test_the_host_choice_is_the_devices(seed, M, k, sectors, lattice):
    """Random samples, or samples and queries on a lattice of eighths with the starts off it by
    (8, 4) / 128 and the goals by (3, 1) / 128: many samples tie in distance (mirror images
    through a query), and with borders on the axes and diagonals no sample lies on one of
    either end's, nor the goal on one of the start's (no difference of the offsets is zero or
    equal to the other's, +-, modulo an eighth)."""
    with jax.enable_x64(False):
        _check_random(seed, M, k, sectors, lattice)


def _check_random(seed, M, k, sectors, lattice):
    rng = np.random.default_rng(seed)
    if lattice:
        points = (rng.integers(0, 80, (M, 2)) / 8).astype(np.float32)
        offsets = np.array([[8, 4], [3, 1]]) / 128  # start, goal
        ends = (rng.integers(0, 80, (3, 2, 2)) / 8 + offsets).astype(np.float32)
    else:
        points = rng.uniform(0, 10, (M, 2)).astype(np.float32)
        ends = rng.uniform(0, 10, (3, 2, 2)).astype(np.float32)
    valid = rng.random(M) < rng.uniform(0.05, 0.95)
    got, want = _both(points, valid, ends[:, 0], ends[:, 1], k, sectors)
    if got is None:
        # Declined only where a direction lies on a border (none with 0 or 1 sector, none on
        # the lattice's when the borders are the axes and diagonals), within a band far wider
        # than the kernel's.
        assert sectors > 1 and not (lattice and 8 % sectors == 0)
        assert _on_a_border(points[valid], ends, sectors, 1e-3)
    else:
        _assert_same(got, want)


def _on_a_border(samples, ends, sectors, band):
    """Whether a direction from a query's start to a sample or its goal, or from its goal to a
    sample, lies within ``band`` radians of a sector border."""
    rays = [samples[None] - ends[:, None, 0], ends[:, None, 1] - ends[:, None, 0], samples[None] - ends[:, None, 1]]
    ang = np.concatenate([np.arctan2(r[..., 1], r[..., 0]).astype(np.float64).ravel() for r in rays])
    width = 2 * np.pi / sectors
    off = np.mod(ang + np.pi, width)
    return bool(np.any(np.minimum(off, width - off) < band))


def test_ties_in_distance_go_to_the_lower_slot_as_on_the_device(float32):
    """Samples on every point of a lattice around the start: mirror images tie in distance and
    the choice among them is the slot order's, on both."""
    g = np.arange(-6, 7) / 8
    points = np.stack(np.meshgrid(g + 2, g + 2), -1).reshape(-1, 2).astype(np.float32)
    points = np.concatenate([np.zeros((2, 2), np.float32), points])
    valid = np.ones(len(points), bool)
    start = np.float32([[2 + 1 / 16, 2 + 1 / 32]])
    goal = np.float32([[3.0 + 1 / 16, 1.0 + 1 / 32]])
    for sectors in (0, 8):
        got, want = _both(points, valid, start, goal, 12, sectors)
        assert got is not None
        _assert_same(got, want)
        n = want[1][0, 0]
        d2 = np.sum((points[n] - start[0]) ** 2, -1)
        assert len(np.unique(d2)) < len(d2)  # ties among the chosen


def test_a_sample_on_a_sector_border_is_left_to_the_device(float32):
    """A sample straight along a diagonal from the start, its nearest: either side of the border
    may be the device's sector, so the host declines; an equal roadmap without it is chosen."""
    rng = np.random.default_rng(5)
    points = rng.uniform(0, 10, (60, 2)).astype(np.float32)
    valid = np.ones(60, bool)
    start = np.float32([[5.0, 5.0]])
    goal = np.float32([[9.0, 1.0]])
    points[7] = [5.25, 5.25]
    got, want = _both(points, valid, start, goal, 6, 8)
    assert got is None
    assert 7 in want[1][0, 0]  # the device chose it
    points[7] = [5.25, 5.3]  # off the border
    got, want = _both(points, valid, start, goal, 6, 8)
    assert got is not None
    _assert_same(got, want)


def test_queries_on_a_prm_use_the_host_choice(monkeypatch, float32):
    """A float32 PRM's queries choose their candidates on the host, and the paths are those of the
    device's choice."""
    occ = np.zeros((60, 60), bool)
    occ[20:40, 30] = True
    grid = Q.Grid.host((0.0, 0.0), 0.1, occ.shape)
    rng = np.random.default_rng(2)
    starts = rng.uniform(0.3, 5.7, (6, 2))
    goals = rng.uniform(0.3, 5.7, (6, 2))
    starts[:, 0] = np.minimum(starts[:, 0], 2.5)
    goals[:, 0] = np.maximum(goals[:, 0], 3.5)
    calls = []
    host = _roadmap._links_ends_host
    monkeypatch.setattr(_roadmap, "_links_ends_host", lambda *a, **kw: calls.append(1) or host(*a, **kw))
    runs = []
    for on in (True, False):
        if not on:
            monkeypatch.setattr(_roadmap, "_host_choice", lambda: None)
        prm = PRM(occ, grid, capacity=400, radius=0.8)
        prm.grow(jax.random.PRNGKey(3), 400)
        paths = prm.query_many(starts, goals)
        runs.append([(float(paths.path(i).cost), tuple(paths.path(i).vertices)) for i in range(len(starts))])
    assert calls and runs[0] == runs[1]
    assert all(np.isfinite(c) for c, _ in runs[0])

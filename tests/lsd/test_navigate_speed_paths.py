"""The navigation loop's faster paths give the old answers: the brute-force neighbour search over
the filled slots only, grid reads through one flat index, the plan check on the device's partial
map, and sensing in place."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_prm_concentrated import RES, SHAPE, _concentrated, _free_map  # the same maps and draws

import jaxsem.planning._edges as _edges  # layers: white-box
import jaxsem.planning._navigate as _navigate  # layers: white-box
import jaxsem.planning._roadmap as _roadmap  # layers: white-box
from jaxsem import quadrics as Q
from jaxsem.planning import (
    CROP_SIZE,
    FREE,
    OCCUPIED,
    PRM,
    UNKNOWN,
    NavConfig,
    SensorConfig,
    embed_local_distribution,
    empty_map_state,
    generate_building,
    navigate,
    sample_tasks,
)
from jaxsem.planning._grid import static_grid  # layers: white-box
from jaxsem.planning._sampling import WindowCost  # layers: white-box
from jaxsem.planning._sensors import _sense_in_place, _sense_jit, _sense_sizes  # layers: white-box


def _walled_map():
    occ = _free_map()  # a wall with a door
    occ[30:60, 200:260] = True  # a block
    return occ


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_read_is_the_grid_indexing(seed):
    rng = np.random.default_rng(seed)
    values = rng.random((17, 23)).astype(np.float32)
    rows, cols = rng.integers(0, 17, (5, 40)), rng.integers(0, 23, (5, 40))
    got = jax.jit(_edges._read)(jnp.asarray(values), jnp.asarray(rows), jnp.asarray(cols))
    np.testing.assert_array_equal(np.asarray(got), values[rows, cols])
    flags = values > 0.5
    got = jax.jit(_edges._read)(jnp.asarray(flags), jnp.asarray(rows), jnp.asarray(cols))
    np.testing.assert_array_equal(np.asarray(got), flags[rows, cols])


def _neglogp_roadmap(dist, capacity, grows):
    """navigate's kind of roadmap on the walled map: cost weights, 8 sectors, grown by
    ``grows`` ((key, count) pairs) from ``dist``."""
    prm = PRM(
        _walled_map(), Q.Grid.create((0.0, 0.0), RES, SHAPE), capacity=capacity, radius=3.0, weight="neglogp", sectors=8
    )
    for key, count in grows:
        prm.grow(jax.random.PRNGKey(key), count, dist)
    return prm.roadmap


@pytest.mark.slow  # two grows compiled twice (about 20 s)
def test_brute_force_over_the_filled_slots_is_the_full_search(monkeypatch):
    # navigate's roadmap (capacity 1,500: brute force), grown twice from a concentrated
    # distribution with cost weights (the first grow within the first 512 slots, the second
    # past them): the same roadmap as a search over every slot.
    dist = _concentrated(5)
    grown = lambda: _neglogp_roadmap(dist, 1500, [(3, 500), (4, 500)])

    fast = grown()
    monkeypatch.setattr(_roadmap, "_ACTIVE_STEP", 10**9)  # never the prefix: every slot
    jax.clear_caches()
    full = grown()
    jax.clear_caches()
    for name in ("points", "valid", "neighbors", "edge_valid", "edge_weight"):
        np.testing.assert_array_equal(np.asarray(getattr(fast, name)), np.asarray(getattr(full, name)), err_msg=name)
    assert int(np.sum(np.asarray(fast.edge_valid))) > 1000


def _partial_map(seed, shape=(90, 130)):
    rng = np.random.default_rng(seed)
    occ = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=shape, p=[0.5, 0.498, 0.002])
    occ[40:45, 20:110] = OCCUPIED  # a wall most lines cross
    return occ


@pytest.mark.parametrize("seed", [0, 1])
def test_plan_check_on_the_devices_partial_map_is_the_bool_check(seed):
    occ = _partial_map(seed)
    grid = Q.Grid.host((-1.0, 2.0), RES, occ.shape)
    rng = np.random.default_rng(10 + seed)
    answers = []
    for _ in range(16):
        steps = rng.normal(0.0, 1.0, (int(rng.integers(2, 5)), 2))
        pts = np.array([-1.0, 2.0]) + np.clip(np.array([6.5, 4.5]) + np.cumsum(steps, 0), 0.0, 12.9)
        want = _edges.polyline_clear(pts, occ == OCCUPIED, grid, 1.5)
        assert _edges.polyline_clear(pts, jnp.asarray(occ), grid, 1.5) == want
        assert _edges.polyline_clear(pts, occ, grid, 1.5) == want  # an int8 map on the host too
        answers.append(want)
    assert 0 < sum(answers) < len(answers)  # both answers occur


def test_sensing_in_place_is_sensing_and_leaves_a_given_state_alone():
    b = generate_building(3, "train")
    occ_true, sem_true = jnp.asarray(b.occupancy), jnp.asarray(b.semantic, jnp.int8)
    grid = static_grid(b.grid)
    sizes = _sense_sizes(b.grid, SensorConfig())
    start = empty_map_state(b.occupancy.shape)
    keep = np.array(start.occupancy)
    xy = b.cell_center(np.argwhere(~b.occupancy)[len(np.argwhere(~b.occupancy)) // 2])
    state_a = _sense_jit(occ_true, sem_true, start, jnp.asarray([*xy, 0.3]), grid, SensorConfig(), **sizes)
    state_b = _sense_jit(occ_true, sem_true, start, jnp.asarray([*xy, 0.3]), grid, SensorConfig(), **sizes)
    for yaw in (1.2, 2.9, -1.0):
        pose = jnp.asarray([*xy, yaw])
        state_a = _sense_jit(occ_true, sem_true, state_a, pose, grid, SensorConfig(), **sizes)
        state_b = _sense_in_place(occ_true, sem_true, state_b, pose, grid, SensorConfig(), **sizes)
        np.testing.assert_array_equal(np.asarray(state_a.occupancy), np.asarray(state_b.occupancy))
        np.testing.assert_array_equal(np.asarray(state_a.semantic), np.asarray(state_b.semantic))
    np.testing.assert_array_equal(np.asarray(start.occupancy), keep)


def _window_sampler(inputs):
    """A concentrated stand-in for the network: a Gaussian ridge along the goal's heading."""
    ctx = np.asarray(inputs.context)
    rr, cc = np.mgrid[0:CROP_SIZE, 0:CROP_SIZE] - CROP_SIZE // 2
    along = cc * ctx[0] + rr * ctx[1]
    across = -cc * ctx[1] + rr * ctx[0]
    p = np.exp(-0.5 * (across / 8.0) ** 2) * (along > -10) + 1e-4
    return jnp.asarray(p / p.sum(), jnp.float32)


@pytest.mark.slow  # compiles the loop twice on a generated building (minutes)
def test_fast_loop_drives_the_old_loops_paths(monkeypatch):
    # The same trials with the old mechanisms (a full copy of the maps at every look, the
    # brute-force search over every slot, fused grid reads): identical paths, step for step.
    b = generate_building(5, "train")
    tasks = sample_tasks(b, "II", 2, 4, min_distance=8.0)
    cfg = NavConfig(n_samples=300, max_steps=400)

    def drive():
        out = []
        for i, t in enumerate(tasks):
            for smp in (_window_sampler, None):
                r = navigate(b, t.start, t.goal, jax.random.PRNGKey(i), cfg, sampler=smp)
                out.append((r.path, r.success, r.plans, r.searches))
        return out

    fast = drive()
    monkeypatch.setattr(_navigate, "_sense_in_place", _sense_jit)
    monkeypatch.setattr(_roadmap, "_ACTIVE_STEP", 10**9)
    window_read = _edges._read  # a window's cost (the learned sampler's) has one reading
    monkeypatch.setattr(
        _edges,
        "_read",
        lambda values, rows, cols: (
            window_read(values, rows, cols) if isinstance(values, WindowCost) else values[rows, cols]
        ),
    )
    jax.clear_caches()
    old = drive()
    jax.clear_caches()
    for (pa, sa, na, qa), (pb, sb, nb, qb) in zip(fast, old):
        np.testing.assert_array_equal(pa, pb)
        assert (sa, na, qa) == (sb, nb, qb)
    assert any(s for _, s, _, _ in fast)


def _embed_reference(local, centre, shape, q=None):
    """numpy: the window's cells where they fall on the map, the window's minimum elsewhere."""
    h, w = local.shape
    full = np.full(shape, local.min(), np.float64)
    window = np.zeros(shape, bool)
    for i in range(h):
        for j in range(w):
            r, c = centre[0] - h // 2 + i, centre[1] - w // 2 + j
            if 0 <= r < shape[0] and 0 <= c < shape[1]:
                full[r, c], window[r, c] = local[i, j], True
    if q is None:
        return full / full.sum()
    inner = np.where(window, full, 0.0)
    inner = inner / max(inner.sum(), np.finfo(np.float32).tiny)  # a window off the map: none
    n_out = (~window).sum()
    return np.where(window, (1.0 - q) * inner, q / max(n_out, 1)) if n_out else inner


@pytest.mark.parametrize("shape", [(40, 50), (12, 9)])
@pytest.mark.parametrize("q", [None, 0.3])
def test_embedded_window_against_a_cell_by_cell_reference(shape, q):
    rng = np.random.default_rng(len(shape) + shape[0])
    local = rng.random((16, 16)) + 0.01
    embed = jax.jit(embed_local_distribution, static_argnames=("full_shape", "outside_mass"))
    for centre in [(20, 25), (0, 0), (3, 48), (39, 1), (-5, 30), (45, 60), (8, 8), (32, 42), (-30, -30)]:
        got = np.asarray(embed(jnp.asarray(local, jnp.float32), jnp.asarray(centre), shape, q))
        want = _embed_reference(local.astype(np.float32).astype(np.float64), centre, shape, q)
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-12, err_msg=str(centre))
        assert np.all(np.isfinite(got))


def test_cost_grid_made_apart_gives_the_grow_made_inside(monkeypatch):
    # The grow reads its -log p cost grid made by a program of its own (XLA would otherwise
    # compute the log again at every sample it gathers): the same roadmap, weight for weight,
    # as the grow that makes the grid inside its own program.
    dist = _concentrated(7)
    grown = lambda: _neglogp_roadmap(dist, 600, [(5, 300)])

    apart = grown()
    monkeypatch.setattr(_roadmap, "_edge_cost_jit", lambda *args: None)  # made inside the grow
    inside = grown()
    for name in ("points", "neighbors", "edge_valid", "edge_weight"):
        np.testing.assert_array_equal(np.asarray(getattr(apart, name)), np.asarray(getattr(inside, name)), err_msg=name)
    w = np.asarray(apart.edge_weight)[np.asarray(apart.edge_valid)]
    d = np.asarray(apart.points)
    assert w.size > 500 and np.all(np.isfinite(w))
    # -log p weights, not lengths: the cost integral is read (a length-only weight fails this)
    nb = np.minimum(np.asarray(apart.neighbors), len(d) - 1)
    lengths = np.linalg.norm(d[nb] - d[:, None], axis=-1)[np.asarray(apart.edge_valid)]
    assert np.median(w / lengths) > 2.0

"""The navigation loop's faster paths give the old answers: the brute-force neighbour search over
the filled slots only, grid reads through one flat index, the plan check on the device's partial
map, and sensing in place."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsem.planning._edges as _edges  # layers: white-box
import jaxsem.planning._roadmap as _roadmap  # layers: white-box
from jaxsem import quadrics as Q
from jaxsem.planning import PRM, embed_local_distribution

SHAPE = (240, 320)
RES = 0.1


def _concentrated(seed, centre=(120, 200), k=40):
    local = np.random.default_rng(seed).dirichlet(np.full(k * k, 0.5)).reshape(k, k)
    return np.asarray(embed_local_distribution(jnp.asarray(local), jnp.asarray(centre), SHAPE))


def _walled_map():
    occ = np.zeros(SHAPE, bool)
    occ[:, 150:153] = True  # a wall with a door
    occ[100:120, 150:153] = False
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


@pytest.mark.parametrize(
    "filled,M,want", [(2, 1502, 512), (502, 1502, 512), (513, 1502, 1024), (1502, 1502, 1502), (30, 20, 20)]
)
def test_active_slots(filled, M, want):
    assert _roadmap._active_slots(M, filled) == want


@pytest.mark.slow  # two grows compiled twice (about 20 s)
def test_brute_force_over_the_filled_slots_is_the_full_search(monkeypatch):
    # navigate's roadmap (capacity 1,500: brute force), grown twice from a concentrated
    # distribution with cost weights: the same roadmap as a search over every slot.
    grid = Q.Grid.create((0.0, 0.0), RES, SHAPE)
    occ, dist = _walled_map(), _concentrated(5)

    def grown():
        prm = PRM(occ, grid, capacity=1500, radius=3.0, weight="neglogp", sectors=8)
        prm.grow(jax.random.PRNGKey(3), 500, dist)
        prm.grow(jax.random.PRNGKey(4), 500, dist)
        return prm.roadmap

    fast = grown()
    monkeypatch.setattr(_roadmap, "_active_slots", lambda M, filled: M)
    full = grown()
    for name in ("points", "valid", "neighbors", "edge_valid", "edge_weight"):
        np.testing.assert_array_equal(np.asarray(getattr(fast, name)), np.asarray(getattr(full, name)), err_msg=name)
    assert int(np.sum(np.asarray(fast.edge_valid))) > 1000

"""``slam.solve_many``: a batch of maps in one program; with ``strategy="map"`` every map gets
the answer it gets solved alone (the same steps and outcome, the values to float64 rounding: XLA
compiles the map's body and the solo solve apart), including maps cut by the step budget (where a
vmapped loop's batched kernels may move the answer)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import slam
from jaxsem.slam._batch import default_strategy  # layers: white-box

CFG = slam.SolverConfig(max_steps=12)  # small budget: some maps stop on it, some converge


@pytest.fixture(scope="module")
def batch():
    maps = [slam.toy_map(s, num_objects=3, num_frames=10, capacity=(10, 40, 3))[0] for s in (900, 901, 902)]
    initialize = jax.jit(slam.initialize)  # op by op: some hundred small programs
    inits = [initialize(p, CFG) for p in maps]
    return maps, inits, slam.stack_problems(maps), jax.tree_util.tree_map(lambda *x: jnp.stack(x), *inits)


@pytest.mark.slow
def test_map_strategy_equals_solo_solves(batch):
    maps, inits, problems, stacked = batch
    # Called from a user's jit with a traced tolerance (CFG's first): one solver compile serves
    # the comparison below and the no-recompile check after it.
    user = jax.jit(lambda p, i, rtol: slam.solve_many(p, i, CFG.replace(rtol=rtol), strategy="map"))
    est_m, info_m = user(problems, stacked, jnp.asarray(CFG.rtol))
    solo = jax.jit(lambda p, i: slam.solve_batch(p, i, CFG))
    for k, (p, i) in enumerate(zip(maps, inits)):
        est, info = solo(p, i)
        assert int(info_m.steps[k]) == int(info.steps)
        assert int(info_m.result._value[k]) == int(info.result._value)  # pyright: ignore[reportAttributeAccessIssue]
        np.testing.assert_allclose(info_m.cost[k], info.cost, rtol=1e-8)
        np.testing.assert_allclose(est_m.center[k], est.center, rtol=0, atol=1e-8)
        np.testing.assert_allclose(est_m.radii[k], est.radii, rtol=0, atol=1e-8)
    # A second call with another tolerance compiles nothing.
    size = user._cache_size()
    user(problems, stacked, jnp.asarray(1e-4))
    assert user._cache_size() == size == 1


@pytest.mark.slow
def test_strategy_by_backend_and_bad_arguments():
    assert default_strategy("cpu") == "map" and default_strategy("gpu") == "vmap"
    maps = [slam.toy_map(s, num_objects=2, num_frames=4, capacity=(4, 8, 2))[0] for s in (0, 1)]
    problems = slam.stack_problems(maps)
    with pytest.raises(ValueError, match="strategy"):
        slam.solve_many(problems, problems, CFG, strategy="pmap")  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="problems, inits"):
        slam.solve_many(problems, maps[0], CFG)  # pyright: ignore[reportArgumentType]

"""The navigation loop pads every map to a size bucket: maps of two shapes in one bucket share
every compiled program, and a trial on a padded map drives the unpadded map's path."""

import dataclasses
from types import SimpleNamespace

import jax
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem.planning import OCCUPIED, NavConfig, Trial, navigate
from jaxsem.planning._navigate import bucket_shape  # layers: white-box

RES = 0.1
CFG = NavConfig(n_samples=200, radius=1.5, max_steps=200)


def _room(h: int, w: int, resolution: float = RES) -> SimpleNamespace:
    """A walled room of h x w cells with a wall across its middle, open at the bottom."""
    occ = np.zeros((h, w), bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    occ[: h * 2 // 3, w // 2] = True
    sem = np.where(occ, 1, 0).astype(np.int8)
    return SimpleNamespace(
        occupancy=occ, semantic=sem, indoor=np.ones_like(occ), origin=np.zeros(2), resolution=resolution
    )


def _window_sampler(inputs):
    """A learned sampler's stand-in: mass on the window's free cells."""
    return jax.numpy.where(inputs.occupancy == OCCUPIED, 1e-3, 1.0)


def _run(world, sampler):
    h, w = world.occupancy.shape
    start, goal = np.array([0.5, 0.5]), np.array([(w - 5) * world.resolution, 0.5])
    return navigate(world, start, goal, jax.random.PRNGKey(0), CFG, sampler=sampler)


@pytest.mark.slow  # two planners' whole loops compiled
def test_two_map_shapes_in_one_bucket_share_every_compile(compiles):
    # (The suite runs without JAX's persistent cache: every program new to the process compiles.)
    # Both in the (64, 128) bucket; their diagonals (16.8 and 15.99 m) round up to query reaches
    # of 32 and 16 m: the long links and plan segments are sampled over the bucket's reach.
    a, b = _room(60, 120, 0.125), _room(58, 114, 0.125)
    for sampler in (None, _window_sampler):
        assert _run(a, sampler).success
        with compiles() as c:
            res = _run(b, sampler)
        assert res.success
        assert c.count == 0
        assert res.final_state.occupancy.shape == (58, 114)
        if sampler is not None:
            assert res.last_distribution is not None and res.last_distribution.shape == (58, 114)
            np.testing.assert_allclose(res.last_distribution.sum(), 1.0, rtol=1e-5)


@pytest.mark.slow  # the loop compiled twice (padded and not)
def test_a_padded_trial_drives_the_unpadded_path():
    # Uniform samples: the padding is occupied, so the free cells and their order are the
    # unpadded map's and every draw is the same cell; the paths are equal bit for bit.
    world = _room(60, 120)
    start, goal = np.array([0.5, 0.5]), np.array([11.5, 0.5])
    paths = []
    for bucket in (1, 256):
        cfg = dataclasses.replace(CFG, shape_bucket=bucket)
        trial = Trial(world, start, goal, jax.random.PRNGKey(3), cfg)
        while trial.step():
            pass
        assert trial.state.occupancy.shape == (60, 120)
        paths.append(trial.result().path)
    np.testing.assert_array_equal(paths[0], paths[1])


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 3000), st.integers(1, 3000), st.sampled_from([1, 16, 100, 256]))
def test_a_bucket_holds_its_map_without_padding_a_small_map_to_a_large_ones_size(h, w, bucket):
    bh, bw = bucket_shape((h, w), bucket)
    for n, b in ((h, bh), (w, bw)):
        assert b >= n
        if bucket == 1:
            assert b == n
        elif n >= bucket:
            assert b % bucket == 0 and b - n < bucket
        else:  # a small side grows by at most half again, or to the smallest rung
            assert b <= max(32, (3 * n) // 2 + 1) and b <= bucket
    assert bucket_shape((bh, bw), bucket) == (bh, bw)  # a bucket is its own bucket


@pytest.mark.parametrize("bucket", [16, 100, 256])
def test_every_side_up_to_3000_cells_falls_in_a_handful_of_buckets(bucket):
    sizes = {bucket_shape((n, n), bucket)[0] for n in range(1, 3001)}
    assert len(sizes) <= 8 + 3000 // bucket

"""Compiled once per user: the stretches of a sequence padded to at most two capacities, so every
solver compiles at most two programs over them (``jaxsem.slam.bucket_capacities``)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxsem import slam
from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._problem import bucket_capacity  # layers: white-box

# The LM-O test split's four stretches (poses, boxes, objects): 603-756, 757-969, 972-1001, 1012-1212.
LMO_TEST = [(26, 165, 17), (47, 308, 21), (5, 25, 6), (25, 159, 15)]
CFG = slam.SolverConfig(max_steps=4)


def _stretch(rng, sizes, capacity):
    """A problem of these ``(poses, boxes, objects)`` sizes padded to ``capacity``: cameras along a
    line, boxes inside the image, odometry between consecutive poses."""
    T, M, J = sizes
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, 0, 3] = -0.1 * np.arange(T)
    corner = rng.uniform(0, 400, (M, 2))
    return slam.make_problem(
        np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]),
        (640, 480),
        poses,
        np.concatenate([corner, corner + rng.uniform(20, 200, (M, 2))], -1),
        np.arange(M) % T,
        np.arange(M) % J,
        ["car"] * J,
        capacity=capacity,
        odometry=np.tile(np.eye(4), (T - 1, 1, 1)),
    )


def _twenty_stretches():
    """A user's sequence of twenty stretches of 3-60 poses, each padded to the capacity
    ``bucket_capacities`` gives it among them all."""
    rng = np.random.default_rng(7)
    sizes = []
    for _ in range(20):
        T, J = int(rng.integers(3, 61)), int(rng.integers(2, 25))
        sizes.append((T, int(rng.integers(J, 8 * T + J)), J))
    return [_stretch(rng, s, c) for s, c in zip(sizes, slam.bucket_capacities(sizes))]


def test_lmo_test_split_takes_two_capacities():
    caps = slam.bucket_capacities(LMO_TEST)
    assert caps == [(32, 192, 24), (48, 384, 24), (32, 192, 24), (32, 192, 24)]
    assert slam.bucket_capacities(LMO_TEST, 4) == [bucket_capacity(*s) for s in LMO_TEST]
    assert set(slam.bucket_capacities(LMO_TEST, 1)) == {(48, 384, 24)}


def test_capacities_hold_every_problem_in_at_most_max_programs():
    rng = np.random.default_rng(0)
    sizes = [(int(rng.integers(1, 90)), int(rng.integers(1, 700)), int(rng.integers(1, 40))) for _ in range(20)]
    for k in (1, 2, 3):
        caps = slam.bucket_capacities(sizes, k)
        assert len(caps) == len(sizes) and len(set(caps)) <= k
        for s, c in zip(sizes, caps):
            assert all(a <= b for a, b in zip(bucket_capacity(*s), c))
    assert slam.bucket_capacities([]) == []
    with pytest.raises(ValueError, match="max_programs"):
        slam.bucket_capacities(sizes, 0)


def test_twenty_stretches_compile_twice():
    # Any jitted function of the problem compiles once per argument signature: a cheap one counts
    # what every solver would (the slow test below runs the batch solve itself).
    seen = jax.jit(lambda p: jax.tree_util.tree_reduce(lambda a, x: a + x.size, p, 0))
    for p in _twenty_stretches():
        seen(p)
    assert seen._cache_size() <= 2  # pyright: ignore[reportAttributeAccessIssue]


@pytest.mark.slow
def test_twenty_stretches_compile_the_batch_solve_twice():
    # One LM step each: what is counted is the programs, not the answers.
    cfg = slam.SolverConfig(max_steps=1)
    problems = _twenty_stretches()
    solve = jax.jit(solve_schur)
    init = jax.jit(slam.initialize)
    for p in problems:
        _, info = solve(p, init(p, cfg), cfg)
        assert np.isfinite(float(info.cost))
    assert solve._cache_size() <= 2  # pyright: ignore[reportAttributeAccessIssue]


@pytest.mark.slow
def test_batch_solve_kept_on_disk_gives_the_same_answer(tmp_path):
    problem, _ = slam.toy_map(0, num_objects=3, num_frames=6)
    init = slam.initialize(problem, CFG)
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))  # conftest turns it off after
    est, info = slam.solve_batch(problem, init, CFG)
    assert list((tmp_path / "jaxsem-exports").glob("solve_schur-*.jaxexport"))
    ref, ref_info = solve_schur(problem, init, CFG)
    np.testing.assert_allclose(np.asarray(est.center), np.asarray(ref.center), rtol=0, atol=1e-12)
    assert int(info.steps) == int(ref_info.steps) and bool(info.result == ref_info.result)

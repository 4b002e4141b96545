"""Batch solves (issue 12): a vmapped member's answer is its solo answer and does not depend on the
other members of the batch; compact_boxes changes speed, not answers; no recompile within a
bucket after compaction."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import slam
from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._problem import bucket_capacity, compact_boxes  # layers: white-box
from jaxsem.slam._results import result_code  # layers: white-box

CAP = (16, 32, 2)
CFG = slam.SolverConfig(max_steps=40)
# The config an argument of the jitted solve_schur (its tolerances are traced floats, max_steps
# static): the tight config of test_compact_boxes_keeps_the_answer_and_shares_a_bucket, with the
# same max_steps, runs SOLVE's compiled program (one compile of some 20 s fewer).
SOLVE = lambda p, i: solve_schur(p, i, CFG)
VSOLVE = jax.jit(jax.vmap(lambda p, i: solve_schur(p, i, CFG)))


def _map(seed, num_frames):
    problem, _ = slam.toy_map(seed, num_objects=2, num_frames=num_frames, path="orbit", capacity=CAP)
    return problem, slam.initialize(problem, CFG)


def _stack(items):
    return slam.stack_problems([p for p, _ in items]), jax.tree_util.tree_map(
        lambda *x: jnp.stack(x), *[i for _, i in items]
    )


@pytest.mark.slow
def test_vmapped_member_equals_its_solo_solve_and_ignores_the_other_members():
    # Members of different real sizes and step counts; the default (GTSAM-like) stopping rule.
    a, b, c = _map(0, 8), _map(1, 12), _map(2, 16)
    est_ab, info_ab = VSOLVE(*_stack([a, b]))
    est_ac, info_ac = VSOLVE(*_stack([a, c]))
    # Member a is the same whoever it is batched with (a finished member's carry is frozen and
    # each member keeps its own damping and stopping decision).
    for f in ("camera_T_world", "rotation", "center", "radii"):
        np.testing.assert_allclose(getattr(est_ab, f)[0], getattr(est_ac, f)[0], rtol=0, atol=1e-12)
    assert int(info_ab.steps[0]) == int(info_ac.steps[0])
    # ... and equals its solo solve (to rounding of the batched arithmetic).
    for k, (p, i) in enumerate([a, b]):
        est, info = SOLVE(p, i)
        assert int(info_ab.steps[k]) == int(info.steps) and int(info_ab.accepted[k]) == int(info.accepted)
        assert int(result_code(info_ab.result)[k]) == int(result_code(info.result))
        np.testing.assert_allclose(est_ab.center[k], est.center, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(est_ab.radii[k], est.radii, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(est_ab.camera_T_world[k], est.camera_T_world, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(info_ab.cost[k], info.cost, rtol=1e-6)


def _with_holes(problem):
    """Drops every third real box (mask False, slot kept): padding interleaved with real boxes."""
    m = np.asarray(problem.box_mask).copy()
    real = np.flatnonzero(m)
    m[real[::3]] = False
    tm = np.asarray(problem.texture_mask) & m
    return eqx.tree_at(lambda p: (p.box_mask, p.texture_mask), problem, (jnp.asarray(m), jnp.asarray(tm)))


@pytest.mark.slow
def test_compact_boxes_keeps_the_answer_and_shares_a_bucket():
    cfg = CFG.tight(max_steps=CFG.max_steps)
    solve = lambda p, i: solve_schur(p, i, cfg)
    p1, i1 = _map(3, 12)
    p1 = _with_holes(p1)
    n_real = int(p1.box_mask.sum())
    cap = bucket_capacity(12, n_real, 2)[1]
    assert cap < p1.box.shape[0]
    c1 = compact_boxes(p1, cap)
    assert c1.box.shape == (cap, 4) and bool(jnp.all(c1.box_mask[:n_real])) and not bool(jnp.any(c1.box_mask[n_real:]))
    e_full, info_full = solve(p1, i1)
    e_c, info_c = solve(c1, i1)
    np.testing.assert_allclose(e_c.center, e_full.center, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(e_c.radii, e_full.radii, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(info_c.cost, info_full.cost, rtol=1e-6)
    # A second problem of another real size compacted to the same bucket: no recompile.
    p2, i2 = _map(4, 7)
    c2 = compact_boxes(p2, cap)
    before = solve_schur._cache_size()
    solve(c2, i2)
    assert solve_schur._cache_size() == before
    # Batched problems compact too (vmap or leading axes), and too small a capacity is an error.
    both = compact_boxes(slam.stack_problems([p1, p2]), cap)
    np.testing.assert_array_equal(both.box_mask[0], c1.box_mask)
    with pytest.raises(ValueError, match="max_boxes"):
        compact_boxes(p1, n_real - 1)

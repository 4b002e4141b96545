"""Which box edges read one-sided: ``make_problem(box_cut=...)`` and the overlap rule.

The overlap rule is checked against points sampled densely along each edge; the cost against the
same problem read wholly symmetrically or wholly one-sided, and the linearised cost against
the residuals it is built from."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import slam
from jaxsem.slam._cost import linearize, residual_blocks  # layers: white-box
from jaxsem.slam._problem import compact_boxes, overlapped_edges  # layers: white-box

# Jitted (the solver's configuration static): run op by op they compiled some 300 small programs.
_residual_blocks = jax.jit(residual_blocks, static_argnums=2)
_linearize = jax.jit(linearize, static_argnums=2)


def _edge_points(b, e, n=2001):
    """Points along edge e of box b, ends left out (a corner touch is no cut)."""
    s = np.linspace(0.0, 1.0, n)[1:-1]
    x0, y0, x1, y1 = b
    return {
        0: np.stack([np.full_like(s, x0), y0 + s * (y1 - y0)], -1),
        1: np.stack([x0 + s * (x1 - x0), np.full_like(s, y0)], -1),
        2: np.stack([np.full_like(s, x1), y0 + s * (y1 - y0)], -1),
        3: np.stack([x0 + s * (x1 - x0), np.full_like(s, y1)], -1),
    }[e]


@pytest.mark.parametrize("seed", range(4))
def test_overlapped_edges_are_those_with_points_strictly_inside_another_box_of_the_frame(seed):
    rng = np.random.default_rng(seed)
    M = 30
    lo = rng.uniform(0, 200, (M, 2)).round()  # whole pixels: shared edge lines happen
    box = np.concatenate([lo, lo + rng.uniform(5, 80, (M, 2)).round()], -1)
    pose = rng.integers(0, 4, M)
    mask = rng.uniform(size=M) > 0.15
    got = overlapped_edges(box, pose, mask)
    for i in range(M):
        for e in range(4):
            want = False
            if mask[i]:
                pts = _edge_points(box[i], e)
                for j in np.flatnonzero(mask & (pose == pose[i])):
                    if j != i:
                        b = box[j]
                        inside = (b[0] < pts[:, 0]) & (pts[:, 0] < b[2]) & (b[1] < pts[:, 1]) & (pts[:, 1] < b[3])
                        want |= bool(inside.any())
            assert got[i, e] == want, (i, e)
    assert got.any() and not got.all()


def _problem(box_cut=None, capacity=None):
    problem, truth = slam.toy_map(3, num_objects=3, num_frames=6, capacity=capacity)
    M = int(problem.box_mask.sum())
    args = dict(
        K=problem.K,
        image_size=problem.image_size,
        pose_prior=problem.pose_prior[: problem.num_poses],
        box=np.asarray(problem.box)[:M],
        box_pose=np.asarray(problem.box_pose)[:M],
        box_object=np.asarray(problem.box_object)[:M],
        object_class=np.asarray(problem.object_class),
        texture_depth=np.where(np.asarray(problem.texture_mask), np.asarray(problem.texture_depth), np.nan)[:M],
    )
    return slam.make_problem(**args, box_cut=box_cut, capacity=capacity, dtype=jnp.float64), truth, M


def _off(truth):
    # Every object 12 % larger and a little shifted: some edges overshoot their boxes, some fall short.
    return dataclasses.replace(truth, radii=truth.radii * 1.12, center=truth.center + jnp.array([0.05, -0.03, 0.02]))


def test_one_sided_reading_applies_to_the_flagged_edges_only():
    plain, truth, M = _problem()
    est = _off(truth)
    cfg = slam.SolverConfig()
    one_sided = cfg.replace(box_outward_scale=4.0)
    none_cut, _, _ = _problem(np.zeros((M, 4), bool))
    all_cut, _, _ = _problem(np.ones((M, 4), bool))
    rows = lambda p, c: np.asarray(_residual_blocks(p, est, c)[0])
    np.testing.assert_array_equal(rows(none_cut, one_sided), rows(plain, cfg))
    np.testing.assert_array_equal(rows(all_cut, one_sided), rows(plain, one_sided))
    assert not np.allclose(rows(plain, one_sided), rows(plain, cfg))  # the scale does act here
    # Half the edges flagged: each row is either its symmetric or its one-sided value.
    rng = np.random.default_rng(0)
    cut = rng.uniform(size=(M, 4)) < 0.5
    mixed = rows(_problem(cut)[0], one_sided)[:M, :4]
    np.testing.assert_array_equal(mixed, np.where(cut, rows(plain, one_sided)[:M, :4], rows(plain, cfg)[:M, :4]))


def test_the_linearised_cost_reads_the_same_flags():
    rng = np.random.default_rng(1)
    plain, truth, M = _problem()
    problem, _, _ = _problem(rng.uniform(size=(M, 4)) < 0.5)
    est = _off(truth)
    cfg = slam.SolverConfig().replace(box_outward_scale=4.0)
    want = 0.5 * sum(float(jnp.sum(jnp.square(b))) for b in _residual_blocks(problem, est, cfg))
    got = float(_linearize(problem, est, cfg, jnp.ones(problem.num_poses)).cost)
    assert got == pytest.approx(want, rel=1e-10)
    assert got != pytest.approx(float(_linearize(plain, est, cfg, jnp.ones(plain.num_poses)).cost), rel=1e-6)


def test_box_cut_pads_compacts_and_is_checked():
    problem, _, M = _problem("overlapped", capacity=(8, 40, 4))
    assert problem.box_cut.shape == (40, 4) and not bool(problem.box_cut[M:].any())
    want = overlapped_edges(np.asarray(problem.box)[:M], np.asarray(problem.box_pose)[:M])
    np.testing.assert_array_equal(np.asarray(problem.box_cut)[:M], want)
    small = compact_boxes(problem, 32)
    np.testing.assert_array_equal(np.asarray(small.box_cut)[:M], want)
    assert jax.jit(compact_boxes, static_argnums=1)(problem, 48).box_cut.shape == (48, 4)
    with pytest.raises(ValueError, match="box_cut"):
        _problem(np.zeros((M, 3), bool))
    with pytest.raises(ValueError, match="box_cut"):
        _problem("occluded")

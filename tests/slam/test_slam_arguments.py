"""The solver's arguments named and checked at the boundary: ``make_problem``'s capacity given by
name (a :class:`jaxsem.slam.Capacity`) or as a ``(poses, boxes, objects)`` tuple, and
``roshan_solver``'s typed ``args`` with its public residual function."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import slam
from jaxsem.slam._cost import RoshanArgs, roshan_residuals  # layers: white-box

K = np.array([[400.0, 0.0, 160.0], [0.0, 400.0, 120.0], [0.0, 0.0, 1.0]])


def _problem(**kwargs):
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = -0.2
    boxes = np.array([[100.0, 80.0, 140.0, 130.0], [120.0, 80.0, 160.0, 130.0], [30.0, 40.0, 60.0, 70.0]])
    return slam.make_problem(K, (320, 240), poses, boxes, [0, 1, 0], [0, 0, 1], [0, 1], **kwargs)


def test_capacity_by_name_and_as_a_tuple_give_the_same_padding():
    named = _problem(capacity=slam.Capacity(max_poses=4, max_objects=3, max_boxes=8))
    plain = _problem(capacity=(4, 8, 3))  # (poses, boxes, objects)
    for p in (named, plain):
        assert (p.num_poses, p.num_boxes, p.num_objects) == (4, 8, 3)
        assert p.box_mask.tolist() == [True] * 3 + [False] * 5 and p.object_mask.tolist() == [True, True, False]


@pytest.mark.parametrize("capacity", [(4, 8), (4, 8, 3, 16)], ids=["two-sizes", "four-sizes"])
def test_capacity_of_the_wrong_length_is_refused(capacity):
    with pytest.raises(ValueError, match=r"capacity: expected a Capacity or \(poses, boxes, objects\)"):
        _problem(capacity=capacity)


def test_roshan_args_are_named_and_checked():
    problem = _problem()
    cfg = slam.SolverConfig()
    args = RoshanArgs.create(problem, cfg)
    assert args.pose_free.tolist() == [1.0, 1.0] and args.obj_free.tolist() == [True, True]
    problem_, cfg_, pose_free, obj_free = args  # still unpacks as the 4-tuple the solver reads
    assert problem_ is problem and cfg_ is cfg
    structure = slam.roshan_solver(cfg).structure(args)
    assert structure.pose_free.tolist() == [1.0, 1.0]
    with pytest.raises(ValueError, match=r"pose_free: expected shape \(2,\)"):
        RoshanArgs.create(problem, cfg, pose_free=jnp.ones(3))
    with pytest.raises(ValueError, match=r"obj_free: expected shape \(2,\)"):
        RoshanArgs.create(problem, cfg, obj_free=[True])


def test_roshan_residuals_are_the_cost_of_the_problem():
    problem = _problem()
    cfg = slam.SolverConfig()
    dtype = problem.box.dtype
    est = slam.SlamEstimate(
        problem.pose_prior,
        jnp.broadcast_to(jnp.eye(3, dtype=dtype), (2, 3, 3)),
        jnp.array([[0.0, 0.0, 2.0], [-0.5, -0.3, 2.5]], dtype),
        jnp.full((2, 3), 0.1, dtype),
    )

    @jax.jit
    def both(est):
        blocks = roshan_residuals(est, RoshanArgs.create(problem, cfg))
        return 0.5 * sum(jnp.sum(jnp.square(b)) for b in blocks), slam.total_cost(problem, est, cfg)

    cost, total = both(est)
    assert float(cost) == pytest.approx(float(total), rel=1e-6)
    assert cost > 0  # boxes of two views of an unsolved map: not at the optimum

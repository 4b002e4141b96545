"""The online smoother with the batch solve's pose factors: between factors from each frame to the
next (measured as the relative motion of their integrated pose priors), an absolute prior on the
first frame only, new poses started where the odometry carries the previous estimate, the ring's
wrap (the oldest kept pose anchored), the same optimum as the batch solve of the same graph,
one compiled step and no NaN."""

import functools

import equinox as eqx
import jax
import numpy as np
import pytest

from jaxsem import quadrics as Q, slam
from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._cost import odometry_rows  # layers: white-box
from jaxsem.slam._online import _insert  # layers: white-box (the graph one frame adds)
from jaxsem.slam._toy import frames_from_problem  # layers: white-box

CFG = slam.SolverConfig(max_steps=100)
FIRST = [[1.0, 1.0], [0.0, 0.0]]  # a prior on the first frame, the chain carries the rest
INSERT = jax.jit(_insert)
# The between rows of every slot t (to slot t + 1, the ring's next), as the solvers build them.
ODOMETRY = jax.jit(
    lambda g, cams: jax.vmap(odometry_rows, in_axes=(0, 0, 0, 0, None))(
        cams, jax.numpy.roll(cams, -1, axis=0), g.odometry, g.odometry_mask, CFG
    )
)


@functools.cache
def _drifting(T=6, seed=1, step_noise=(0.01, 0.3)):
    """A toy forward map whose pose priors are integrated odometry with noisy steps (the first
    pose true), as a batch problem with those steps as odometry and a prior on the first pose."""
    base, truth = slam.toy_map(seed, num_objects=3, num_frames=T, path="forward", pose_noise=(0.0, 0.0))
    rng = np.random.default_rng(seed)
    true = np.asarray(truth.camera_T_world)[:T]
    steps = []
    for t in range(T - 1):
        noise = Q.rigid_transform(Q.so3_exp(rng.normal(0, step_noise[0], 3)), rng.normal(0, step_noise[1], 3))
        steps.append(np.asarray(noise) @ true[t] @ np.linalg.inv(true[t + 1]))
    poses = [true[0]]
    for s in steps:
        poses.append(np.linalg.inv(s) @ poses[-1])
    weight = np.zeros((T, 2))
    weight[0] = FIRST[0]
    bm = np.asarray(base.box_mask)
    problem = slam.make_problem(
        base.K,
        base.image_size,
        np.stack(poses),
        np.asarray(base.box)[bm],
        np.asarray(base.box_pose)[bm],
        np.asarray(base.box_object)[bm],
        ["car"] * 3,
        texture_depth=np.asarray(base.texture_depth)[bm],
        odometry=np.stack(steps),
        pose_prior_weight=weight,
    )
    return problem, truth


def _state(problem, max_poses=8, **kw):
    cap = slam.Capacity(max_poses=max_poses, max_objects=3, max_boxes=64, max_detections=4)
    return slam.online_init(CFG, cap, problem.K, problem.image_size, odometry=True, prior_weights=FIRST, **kw)


def test_odometry_rows_vanish_on_the_integrated_chain_and_not_on_a_shifted_pose():
    problem, _ = _drifting()
    state = _state(problem)
    for frame in frames_from_problem(problem, max_detections=4)[:5]:
        state = INSERT(state, frame)
    graph = state.problem
    assert graph.odometry_mask is not None and graph.pose_prior_weight is not None
    np.testing.assert_array_equal(np.asarray(graph.odometry_mask), [True] * 4 + [False] * 4)
    np.testing.assert_array_equal(np.asarray(graph.pose_prior_weight)[:5], [FIRST[0]] + [FIRST[1]] * 4)
    # The measured steps are the batch problem's, and the poses start on the integrated chain.
    np.testing.assert_allclose(np.asarray(graph.odometry)[:4], np.asarray(problem.odometry)[:4], atol=1e-9)
    np.testing.assert_allclose(
        np.asarray(state.estimate.camera_T_world)[:5], np.asarray(problem.pose_prior)[:5], atol=1e-9
    )
    odo = np.asarray(ODOMETRY(graph, state.estimate.camera_T_world))
    np.testing.assert_allclose(odo, 0.0, atol=1e-6)
    # Pose 2 moved 5 cm: exactly the steps 1 -> 2 and 2 -> 3 see it.
    cams = np.asarray(state.estimate.camera_T_world).copy()
    cams[2, 0, 3] += 0.05
    shifted = ODOMETRY(graph, jax.numpy.asarray(cams))
    moved = np.linalg.norm(np.asarray(shifted), axis=1) > 1.0
    np.testing.assert_array_equal(moved, [False, True, True, False, False, False, False, False])
    assert np.all(np.isfinite(np.asarray(shifted)))


def test_a_new_pose_starts_from_the_previous_estimate_moved_by_the_odometry():
    problem, _ = _drifting()
    frames = frames_from_problem(problem, max_detections=4)
    state = INSERT(INSERT(_state(problem), frames[0]), frames[1])
    # The smoother has moved pose 1 (a correction of the drift): pose 2 follows it.
    fix = np.asarray(Q.rigid_transform(Q.so3_exp(np.array([0.0, 0.02, 0.0])), np.array([0.1, 0.0, -0.2])))
    cams = np.asarray(state.estimate.camera_T_world).copy()
    cams[1] = fix @ cams[1]
    state = eqx.tree_at(lambda s: s.estimate.camera_T_world, state, jax.numpy.asarray(cams))
    state = INSERT(state, frames[2])
    step = np.asarray(problem.odometry)[1]  # camera 1 -> camera 2
    np.testing.assert_allclose(np.asarray(state.estimate.camera_T_world)[2], np.linalg.inv(step) @ cams[1], atol=1e-9)


def test_the_ring_wrap_drops_the_old_step_and_anchors_the_oldest_pose():
    problem, _ = _drifting()
    state = _state(problem, max_poses=4)
    for frame in frames_from_problem(problem, max_detections=4):
        state = INSERT(state, frame)
    graph = state.problem
    # Frames 2..5 in slots 2, 3, 0, 1: steps 2->3 (slot 2), 3->4 (slot 3), 4->5 (slot 0); none
    # from slot 1 (frame 5, the newest) to slot 2 (frame 2, the oldest).
    np.testing.assert_array_equal(np.asarray(state.pose_frame), [4, 5, 2, 3])
    np.testing.assert_array_equal(np.asarray(graph.odometry_mask), [True, False, True, True])
    # Frame 2, now the oldest, holds the gauge at its estimate with the first frame's weights.
    np.testing.assert_array_equal(np.asarray(graph.pose_prior_weight)[2], FIRST[0])
    np.testing.assert_allclose(np.asarray(graph.pose_prior)[2], np.asarray(state.estimate.camera_T_world)[2])
    np.testing.assert_array_equal(np.asarray(graph.pose_prior_weight)[[0, 1, 3]], [FIRST[1]] * 3)


def test_bad_prior_weights_are_refused_by_name():
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    for bad in ([1.0, 1.0], [[1.0, -1.0], [0.0, 0.0]], [[1.0, np.nan], [0.0, 0.0]], [[0.0, 1.0], [0.0, 0.0]]):
        with pytest.raises(ValueError, match="prior_weights"):
            slam.online_init(
                CFG,
                slam.Capacity(8, 3, 64, 4),
                K,
                [640, 480],
                odometry=True,
                prior_weights=bad,
            )


@pytest.mark.slow
def test_online_with_odometry_reaches_the_batch_optimum_with_one_program(compiles):
    """End to end on a tiny drifting map: the online smoother's graph is the batch problem's (same
    boxes, steps, first-pose prior), every update after the first runs the one compiled step,
    nothing is NaN, and the final optimisation reaches the batch solve's cost."""
    problem, _ = _drifting(T=8)
    state = _state(problem, optimize_every=3, iterations=2)
    frames = frames_from_problem(problem, max_detections=4)
    state = slam.online_update(state, frames[0])  # compiles the step
    with compiles() as c:
        for frame in frames[1:]:
            state = slam.online_update(state, frame)
            assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(state.estimate))
    assert c.count == 0
    state = slam.online_optimize(state, 100)
    est, info = jax.jit(lambda p: solve_schur(p, slam.initialize(p, CFG), CFG))(problem)
    c_online = float(jax.jit(slam.total_cost)(problem, _as_batch(state, problem), CFG))  # op by op: some 170 programs
    assert np.isfinite(c_online) and c_online <= 1.01 * float(info.cost)
    np.testing.assert_allclose(np.asarray(state.estimate.center), np.asarray(est.center), atol=0.05 * 30)


def _as_batch(state, problem):
    """The online estimate in the batch problem's pose order (no wrap here: slot t is frame t)."""
    T = int(problem.pose_mask.shape[0])
    return eqx.tree_at(lambda e: e.camera_T_world, state.estimate, state.estimate.camera_T_world[:T])
